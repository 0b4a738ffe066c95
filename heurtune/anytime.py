"""``python -m heurtune.anytime``: anytime measures of finished experiments (the command; the code is
:mod:`heurtune.analysis.anytime`)."""

from heurtune.analysis.anytime import main

if __name__ == "__main__":
    main()
