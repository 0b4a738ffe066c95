"""The order in which the two workers of ``make test`` take the test files.

``make test`` hands out whole files (``--dist loadfile``) in collection order
(``--no-loadscope-reorder``; xdist's own order, most tests first, left the one-test files that
take minutes to the end, where one worker ran them while the other sat idle). The files below
take the longest (``--durations``, 2026-12-06, Intel Xeon, 2 workers; of each tier, the files
whose tests it runs) and go first, longest first, so that the rest fill in around them; every
other file keeps its place.
"""

from pathlib import Path

LONGEST_FIRST = (
    # `make test-long` (the tests marked `long`)
    "objectives/qtp/test_compiled_cache.py",
    "objectives/tito/test_papers.py",
    "runner/test_sampled_release.py",
    "objectives/tito/test_exact_margins.py",
    "test_quality.py",
    # `make test`
    "runner/test_results_folder.py",
    "runner/test_interrupts.py",
    "runner/test_experiment.py",
    "objectives/qtp/test_continuous.py",
    "runner/test_sqp_starts.py",
    "core/test_family_contract.py",
    "objectives/qtp/test_thesis_configs.py",
    "runner/test_progress.py",
    "objectives/tito/test_tito_problem.py",
    "objectives/qtp/test_ladr.py",
    "objectives/qtp/test_thesis_tables.py",
    "analysis/test_report.py",
)
_RANK = {name: i for i, name in enumerate(LONGEST_FIRST)}
_TESTS = Path(__file__).parent


def pytest_collection_modifyitems(session, config, items):
    """Move the files of :data:`LONGEST_FIRST` to the front, in that order (a stable sort)."""
    def rank(item):
        try:
            name = Path(item.fspath).relative_to(_TESTS).as_posix()
        except ValueError:
            return len(_RANK)
        return _RANK.get(name, len(_RANK))

    items.sort(key=rank)
