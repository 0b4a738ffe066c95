"""``python -m heurtune.report``: hTML report of finished experiments (the command; the code is
:mod:`heurtune.analysis.report`)."""

from heurtune.analysis.report import main

if __name__ == "__main__":
    main()
