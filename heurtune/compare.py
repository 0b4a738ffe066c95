"""``python -m heurtune.compare``: compare the optimisers of finished experiments (the command; the code is
:mod:`heurtune.analysis.compare`)."""

from heurtune.analysis.compare import main

if __name__ == "__main__":
    main()
