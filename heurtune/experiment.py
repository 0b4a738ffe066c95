"""``python -m heurtune.experiment``: run a named experiment (the command; the code is
:mod:`heurtune.runner.experiment`)."""

from heurtune.runner.experiment import main

if __name__ == "__main__":
    main()
