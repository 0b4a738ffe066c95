"""Quality of every registered optimiser on standard problems: the table in docs/quality.md.

``python benchmarks/quality.py [--seeds 5] [--markdown]``: for each optimiser and problem, the
final error f - f* (median and worst over the seeds) within the stated evaluation budget,
with default settings and ``seed = 0 .. seeds-1``. The pressure vessel also reports how many
runs ended feasible.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import heurtune
from heurtune.core import registry
from heurtune.core.testfunctions import BUDGETS, PROBLEMS


def measure(name, problem, seeds):
    fun, lo, hi, f_opt = PROBLEMS[problem]
    errors, feasible = [], 0
    t0 = time.perf_counter()
    for seed in range(seeds):
        res = heurtune.minimize(fun, lo, hi, name, max_evals=BUDGETS[problem], seed=seed)
        errors.append(res.f - f_opt)
        feasible += bool(res.feasible)
    return np.median(errors), np.max(errors), feasible, (time.perf_counter() - t0) / seeds


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--algorithms", nargs="*", default=None)
    ap.add_argument("--problems", nargs="*", default=list(PROBLEMS))
    args = ap.parse_args(argv)
    names = args.algorithms or registry.available()
    print("| optimiser | problem | budget | median f - f* | worst f - f* | feasible runs | s/run |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name in names:
        for problem in args.problems:
            med, worst, feas, secs = measure(name, problem, args.seeds)
            print(f"| {name} | {problem} | {BUDGETS[problem]} | {med:.3g} | {worst:.3g} | "
                  f"{feas}/{args.seeds} | {secs:.2f} |", flush=True)


if __name__ == "__main__":
    main()
