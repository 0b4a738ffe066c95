"""``python -m heurtune.export``: export finished experiments (IOHprofiler, .mat) (the command; the code is
:mod:`heurtune.analysis.export`)."""

from heurtune.analysis.export import main

if __name__ == "__main__":
    main()
