"""``python -m heurtune.experiment``: run a named experiment (the command; the code is
:mod:`heurtune.runner.experiment`)."""

from heurtune.runner.experiment import main

if __name__ == "__main__":
    from heurtune import _startup

    _startup.release()  # the imports are done: the command's own interrupt handling takes over
    main()
