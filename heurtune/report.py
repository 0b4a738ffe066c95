"""``python -m heurtune.report``: hTML report of finished experiments (the command; the code is
:mod:`heurtune.analysis.report`)."""

from heurtune.analysis.report import main

if __name__ == "__main__":
    from heurtune import _startup

    _startup.release()  # the imports are done: the command's own interrupt handling takes over
    main()
