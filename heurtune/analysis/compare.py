"""Statistical comparison of optimisers across experiment results.

Usage::

    python -m heurtune.compare DIR [DIR ...] [--format md|csv|latex] [--metric best_f]
                               [--alpha 0.05] [--out FILE] [--cd-diagram PNG] [--by controller]

Each ``DIR`` is an experiment output folder holding ``runs.parquet`` (one row per case,
algorithm and run; a path to a ``.parquet`` file is accepted too). The folders are merged. Only
successful runs (not failed, best candidate feasible: :func:`successful_runs`) enter the
statistics; the others are counted. Per plant case the report gives

* a summary of the metric per algorithm: successful runs, mean, standard deviation (ddof=1),
  median with its bootstrap confidence interval, best (minimum), worst (maximum), mean
  convergence epoch, feasible rate, runs, failed and infeasible runs, success rate and the mean
  rank in the pooled ranking of the case;
* the Kruskal-Wallis test (the runs of different algorithms are independent samples: each run
  has its own seed);
* for every pair of algorithms: Dunn's post-hoc test and the two-sided Wilcoxon rank-sum
  (Mann-Whitney U) test, each Holm-corrected within the case, and the Vargha-Delaney A12 effect
  size with its bootstrap confidence interval and magnitude;
* the winner, marked with an asterisk, only when it wins against every other algorithm of the
  case: Holm-adjusted Dunn and rank-sum p < alpha and an effect at least small
  (``|A12 - 0.5| >= 0.06``);
* the best run of every algorithm re-evaluated per scenario (``Mp1 ... J`` columns read from
  the ``<metric>@<scenario>`` columns of ``runs.parquet``);
* the loop margins of that best run per interaction loop (input i, output j): gain-crossover
  frequency and phase margin (thesis Tables 4.11, 5.8-5.10), read from each folder's
  ``margins.parquet`` as the experiment runner wrote it; a folder without that file (or with
  margins not per input and output, as TITO experiments write) adds none.

Across cases, the Friedman test on the per-case medians (cases are the blocks) with Nemenyi's
post-hoc test and critical difference, when at least 2 cases and 3 algorithms share them; the
critical-difference diagram is written with ``--cd-diagram``. docs/statistics.md describes
every statistic.

Lower metric values are better. Runs are comparable only if their ``problem_id`` (plant case,
controller, scenarios, objective, constraints, bounds) matches: a case mixing problem ids is
refused, and so is a run (experiment, case, algorithm, run) found twice in one folder, or one
folder given twice. Each folder is a *variant*: when the same algorithm name comes from several
folders in one case, its rows are labelled ``"name [experiment]"`` if the experiment names tell
the folders apart, otherwise ``"name [label]"`` with the folder name as label, or the one given
by ``--label NAME=DIR`` (``load_runs(dirs, labels={NAME: DIR})``); the variants are compared,
never pooled.

``--by controller`` compares controller structures instead of optimisers: the treatments are
the structures (``pid``, ``fopid``, ``folqi``; ``"pid [cs]"`` where a case holds a structure
under several optimisers), the cases the plant cases (a config with ``type = [...]`` names its
cases ``<case>-<type>``), with the same statistics. The folders must pose the same problem but
for the controller and its bounds (plant, scenarios, objective and constraints: their
``meta.json`` configs are compared, and the first keys that differ are named).

Mistakes (no folders, a missing ``runs.parquet``, an unknown format or metric column) give a
one-line ``error: ...`` on stderr and exit code 2. All steps are reusable from Python::

    from heurtune.analysis.runs import load_runs
    from heurtune.analysis.stats import summary_table, pairwise_tests
    from heurtune.analysis.render import report
    runs = load_runs(["results/cs_folqi_qtp", "results/pso_folqi_qtp"])
    print(report(runs, metric="best_f", fmt="md"))
"""

from __future__ import annotations

import argparse
import sys

from heurtune import _startup
from heurtune.analysis.figures import cd_diagram  # noqa: F401  (re-exported)
from heurtune.analysis.render import FORMATS, report  # noqa: F401  (re-exported)
from heurtune.analysis.runs import (  # noqa: F401  (re-exported)
    REEVALUATION_COLUMNS,
    best_run_index,
    best_runs,
    failed_runs,
    load_histories,
    load_margins,
    load_runs,
    margins_table,
    reevaluation_table,
    successful_runs,
)
from heurtune.analysis.stats import (  # noqa: F401  (re-exported)
    A12_THRESHOLDS,
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    CI_LEVEL,
    FriedmanResult,
    a12_ci,
    bootstrap_ci,
    critical_difference,
    dunn_test,
    effect_magnitude,
    find_winners,
    friedman_across_cases,
    holm,
    kruskal_test,
    median_ci,
    pairwise_tests,
    summary_table,
    vargha_delaney_a12,
)
from heurtune.core.cli import OneLineParser, UsageError, exit_codes, parse_labels  # parse_labels re-exported
from heurtune.core.errors import ConfigError
from heurtune.core.io import atomic_path, check_output_file

# The names of the analysis this module used to hold, re-exported: ``heurtune.analysis.compare.load_runs``
# and the others keep working.
__all__ = [
    "FORMATS", "REEVALUATION_COLUMNS", "load_runs", "summary_table", "BOOTSTRAP_SEED",
    "BOOTSTRAP_RESAMPLES", "CI_LEVEL", "A12_THRESHOLDS", "failed_runs", "successful_runs",
    "vargha_delaney_a12", "effect_magnitude", "bootstrap_ci", "median_ci", "a12_ci",
    "pairwise_tests", "holm", "kruskal_test", "dunn_test", "find_winners", "FriedmanResult",
    "critical_difference", "friedman_across_cases", "cd_diagram", "best_run_index", "best_runs",
    "reevaluation_table", "load_margins", "load_histories", "parse_labels", "margins_table",
    "report", "run", "main",
]


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m heurtune.compare", description=__doc__.split("\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=exit_codes(("python -m heurtune.compare results/benchmark_qtp",
                                          "python -m heurtune.compare results/cs_folqi_qtp results/apso_folqi_qtp "
                                          "--format latex --out table.tex",
                                          "python -m heurtune.compare results/cs_pid_qtp results/cs_fopid_qtp "
                                          "--by controller")))
    ap.add_argument("dirs", nargs="+", metavar="DIR", help="experiment output folder containing runs.parquet")
    ap.add_argument("--format", default="md", help="output format: md (default), csv or latex")
    ap.add_argument("--metric", default="best_f", help="column to compare, lower is better (default best_f)")
    ap.add_argument("--alpha", type=float, default=0.05, help="significance level (default 0.05)")
    ap.add_argument("--out", help="write the report to this file (atomically) instead of stdout")
    ap.add_argument("--cd-diagram", metavar="PNG",
                    help="write the critical-difference diagram across cases to this PNG file")
    ap.add_argument("--by", default="algorithm", choices=None, metavar="AXIS",
                    help="what is compared: algorithm (default; the optimisers of each case) or controller (the "
                         "controller structures of each plant case, folders that pose the same problem otherwise)")
    ap.add_argument("--label", action="append", default=[], metavar="NAME=DIR",
                    help="name the variant in DIR (one of the folders) NAME instead of the folder name; "
                         "repeatable")
    return ap


def run(argv=None) -> int:
    """Command-line entry point; returns the process exit code (0 ok, 2 usage/input error).

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit code: 0 done, 2 a usage or input error (one line on stderr).
    """
    try:
        args = _parser().parse_args(argv)
        if not args.dirs:
            raise ConfigError("no experiment directories given")
        if args.format not in FORMATS:
            raise ConfigError(f"unknown format '{args.format}' (choose from {', '.join(FORMATS)})")
        if not 0 < args.alpha < 1:
            raise ConfigError(f"--alpha must lie in (0, 1), got {args.alpha:g}")
        runs = load_runs(args.dirs, labels=parse_labels(args.label), by=args.by)
        margins = load_margins(args.dirs, runs)
        text = report(runs, metric=args.metric, alpha=args.alpha, fmt=args.format, margins=margins,
                      cd_path=args.cd_diagram)
    except (ConfigError, UsageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.out:
        try:
            check_output_file(args.out, "--out")
            with atomic_path(args.out) as tmp:
                tmp.write_text(text, encoding="utf-8")
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except OSError as exc:
            print(f"error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        print(f"report written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
