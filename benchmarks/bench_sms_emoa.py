"""SMS-EMOA side by side with pymoo's, in one process: seconds per run and final hypervolume.

Run with ``python benchmarks/bench_sms_emoa.py`` (needs pymoo, the ``pymoo`` extra; ``make
bench`` runs it where pymoo is installed). BLAS is pinned to one thread. On ZDT1 (30
variables) and DTLZ2 (3 objectives, 12 variables), population 100, 5,000 evaluations, seeds
0-4: pymoo 0.6's ``SMSEMOA`` with its defaults (100 offspring per generation) against
heurtune's ``sms_emoa`` in the paper's steady state (``offspring = 1``) and with a batch of
100 offspring (``offspring = 100``). The hypervolume of each run's final population is
computed by moocore for both, against (1.1, 1.1) on ZDT1 and (1.1, 1.1, 1.1) on DTLZ2. The
medians and the time ratio to pymoo are printed.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import moocore  # noqa: E402
import numpy as np  # noqa: E402

import heurtune  # noqa: E402
from heurtune.core.testfunctions import dtlz2, zdt1  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

PROBLEMS = {"zdt1": (zdt1, 30, 2), "dtlz2": (dtlz2, 12, 3)}


def hv(F, ref):
    F = np.asarray(F)
    F = F[np.all(F < ref, axis=1)]
    return float(moocore.hypervolume(F, ref=ref)) if len(F) else 0.0


def run_pymoo(name, seed, evals):
    from pymoo.algorithms.moo.sms import SMSEMOA
    from pymoo.optimize import minimize
    from pymoo.problems import get_problem

    problem = get_problem(name) if name == "zdt1" else get_problem(name, n_var=PROBLEMS[name][1], n_obj=3)
    t0 = time.perf_counter()
    res = minimize(problem, SMSEMOA(pop_size=100), ("n_evals", evals), seed=seed)
    return time.perf_counter() - t0, res.pop.get("F")


def run_heurtune(name, seed, evals, offspring):
    fun, d, m = PROBLEMS[name]
    t0 = time.perf_counter()
    res = heurtune.minimize(fun, [0.0] * d, [1.0] * d, "sms_emoa", max_evals=evals, seed=seed,
                            reference_point=[1.1] * m, settings={"n": 100, "offspring": offspring})
    return time.perf_counter() - t0, res.population["f"]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--evals", type=int, default=5000)
    args = ap.parse_args(argv)
    print(f"SMS-EMOA against pymoo's, {args.evals} evaluations, population 100, seeds 0-{args.seeds - 1}, "
          f"BLAS threads = 1, {cpu_name()}")
    print("| problem | implementation | s per run (median) | time / pymoo | final hypervolume (median, min) |")
    print("| --- | --- | --- | --- | --- |")
    for name, (_, _, m) in PROBLEMS.items():
        ref = np.full(m, 1.1)
        rows = {"pymoo SMSEMOA": [run_pymoo(name, s, args.evals) for s in range(args.seeds)]}
        for off in (1, 100):
            rows[f"heurtune offspring={off}"] = [run_heurtune(name, s, args.evals, off) for s in range(args.seeds)]
        base = np.median([t for t, _ in rows["pymoo SMSEMOA"]])
        for label, runs in rows.items():
            t = np.median([r[0] for r in runs])
            vols = [hv(r[1], ref) for r in runs]
            print(f"| {name} | {label} | {t:.3f} | {t / base:.2f} | {np.median(vols):.4f}, {min(vols):.4f} |")


if __name__ == "__main__":
    main()
