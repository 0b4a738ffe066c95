"""``python -m heurtune.suite``: run optimisers on the suite of controller-tuning problems and
write the leaderboard (the command; the code is :mod:`heurtune.runner.suite`, the measures
:mod:`heurtune.analysis.leaderboard`; docs/suite.md)."""

from heurtune.runner.suite import main

if __name__ == "__main__":
    main()
