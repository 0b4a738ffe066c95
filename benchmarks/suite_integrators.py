"""The QTP integrators on a suite problem: cost per evaluation and error, side by side.

Run with ``python benchmarks/suite_integrators.py [PROBLEM ...] [--instance K] [--candidates N]``
(default: the suite's plain QTP rows, instance 1, up to 30 candidates). For each problem the
suite's config is evaluated three ways in one process, one core (BLAS threads set to 1 unless
the environment already sets them): the switching integrator and the linearised one at the
problem's tolerance, and the switching integrator at tolerance 1e-7 as the reference. The
candidates are uniform in the problem's bounds, the first ones that the switching integrator
simulates kept (an early rejection costs microseconds and is not what a study waits for; a
needle problem may give fewer than asked). Prints milliseconds per evaluation (median of 3
repeats) and the objective's relative error against the reference, median and largest, per
integrator. docs/suite.md, "Integrators", quotes it.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from heurtune.core.families import make_experiment  # noqa: E402
from heurtune.runner import suite as S  # noqa: E402
from heurtune.runner.config import load_config  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

PLAIN = ("pid-min", "pid-nmp", "lqi-min", "lqi-nmp", "iolqi-min", "iolqi-nmp", "folqi-min", "folqi-nmp",
         "fopid-min", "fopid-nmp")


def _problem(config: dict, case: str, integrator: str, tolerance=None):
    config = copy.deepcopy(config)
    config.setdefault("scenario", {})["integrator"] = integrator
    if tolerance is not None:
        config["scenario"]["tolerance"] = tolerance
    return make_experiment(config).problem(case)


def _ms_per_evaluation(prob, X, repeats=3) -> float:
    prob.evaluate(X[:2])  # compile or load the kernels outside the timing
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        prob.evaluate(X)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)) / len(X)


def compare(name: str, instance: int, n: int, seed: int = 0) -> dict:
    """Time and error of both integrators on ``n`` simulated candidates of one suite problem."""
    suite = S.load_suite()
    with tempfile.TemporaryDirectory() as tmp:
        path = S.problem_config(suite, suite.problem(name), "random_search", [instance], 1.0, 1,
                                Path(tmp) / f"{name}.toml")
        config = load_config(str(path))
    case = f"i{instance}"
    switching = _problem(config, case, "switching")
    linearised = _problem(config, case, "linearised")
    reference = _problem(config, case, "switching", 1e-7)
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(switching.lower, float), np.asarray(switching.upper, float)
    X = lo + rng.random((40 * n, switching.dim)) * (hi - lo)
    X = X[switching.evaluate(X).reason == ""][:n]
    row = {"problem": name, "candidates": len(X)}
    if not len(X):
        return row
    f_ref = reference.evaluate(X).f
    for label, prob in (("switching", switching), ("linearised", linearised)):
        err = np.abs(prob.evaluate(X).f / f_ref - 1.0)
        row[label] = (_ms_per_evaluation(prob, X), float(np.median(err)), float(err.max()))
    return row


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("problems", nargs="*", default=list(PLAIN))
    ap.add_argument("--instance", type=int, default=1)
    ap.add_argument("--candidates", type=int, default=30)
    args = ap.parse_args(argv)
    print(f"# {cpu_name()}, one core; instance {args.instance}; error: |f / f(switching, tol 1e-7) - 1|")
    print("| problem | candidates | switching ms | linearised ms | ratio | switching error median, max "
          "| linearised error median, max |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name in args.problems:
        r = compare(name, args.instance, args.candidates)
        if "switching" not in r:
            print(f"| {name} | 0 | | | | | |")
            continue
        (ts, ms, xs), (tl, ml, xl) = r["switching"], r["linearised"]
        print(f"| {name} | {r['candidates']} | {ts:.2f} | {tl:.2f} | {ts / tl:.1f}x | {ms:.1e}, {xs:.1e} "
              f"| {ml:.1e}, {xl:.1e} |", flush=True)


if __name__ == "__main__":
    main()
