"""``python -m heurtune.evaluate``: evaluate one controller of an experiment (the command; the code is
:mod:`heurtune.runner.evaluate`)."""

from heurtune.runner.evaluate import main

if __name__ == "__main__":
    main()
