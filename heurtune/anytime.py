"""``python -m heurtune.anytime``: anytime measures of finished experiments (the command; the code is
:mod:`heurtune.analysis.anytime`)."""

from heurtune.analysis.anytime import main

if __name__ == "__main__":
    from heurtune import _startup

    _startup.release()  # the imports are done: the command's own interrupt handling takes over
    main()
