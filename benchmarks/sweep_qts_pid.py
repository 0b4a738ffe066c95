"""Where a decentralised PID works on paper 000's QTS: the sweep behind the suite's
``tito-qts-pid`` box.

Usage::

    python benchmarks/sweep_qts_pid.py [--samples 300] [--box-samples 200] [--seed 1]

The QTS has no GPM design (no FOPDT fits its loop 1), so the suite cannot take its PID box from
one, as the CSTS and CCTS rows do. The script evaluates ``ga_pi_ccts``' problem (IAE over paper
000's scenario, Ms <= 2, the continuous loop) with a PID (N = 100) on the QTS: first
``--samples`` candidates with each gain's magnitude log-uniform (Kp in [1e-2, 3], Ki in [1e-4,
0.1], Kd in [1e-2, 5]; both decoupled loops have negative static gains, so every gain is
negative), printing the share simulated (stable) and feasible and the 0/5/50/95/100th
percentiles of each gain over the feasible ones; then ``--box-samples`` candidates uniform in the
suite row's box (instance 1), printing the share feasible, the IAE percentiles and the time per
evaluation. docs/suite.md ("The QTS row") quotes its output.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from heurtune.core.families import make_experiment  # noqa: E402
from heurtune.runner import suite as S  # noqa: E402
from heurtune.runner.config import load_config  # noqa: E402

# Magnitude ranges of the log-uniform sweep, per gain kind.
RANGES = {"Kp": (1e-2, 3.0), "Ki": (1e-4, 0.1), "Kd": (1e-2, 5.0)}


def row_problem(instance: int = 1):
    """The suite's ``tito-qts-pid`` problem on ``instance``, built as the suite builds it."""
    suite = S.load_suite()
    with tempfile.TemporaryDirectory() as tmp:
        path = S.problem_config(suite, suite.problem("tito-qts-pid"), "random_search", [instance], 1.0, 1,
                                Path(tmp) / "qts.toml")
        return make_experiment(load_config(str(path))).problem(f"i{instance}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--box-samples", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    prob = row_problem()
    rng = np.random.default_rng(args.seed)
    lo = np.array([np.log(RANGES[n[:2]][0]) for n in prob.names])
    hi = np.array([np.log(RANGES[n[:2]][1]) for n in prob.names])
    X = -np.exp(lo + rng.random((args.samples, prob.dim)) * (hi - lo))
    prob.lower, prob.upper = X.min(axis=0), X.max(axis=0)  # the sweep reaches past the row's box
    ev = prob.evaluate(X)
    print(f"log-uniform sweep, {args.samples} candidates: {100 * np.mean(ev.reason == ''):.0f} % stable, "
          f"{100 * ev.feasible.mean():.0f} % feasible (Ms <= 2)")
    feasible = X[ev.feasible]
    for j, name in enumerate(prob.names):
        print(f"  {name}: " + " ".join(f"{v:.4g}" for v in np.percentile(feasible[:, j], [0, 5, 50, 95, 100])))
    prob = row_problem()
    draws = np.random.default_rng(args.seed + 1).random((args.box_samples, prob.dim))
    X = prob.lower + draws * (prob.upper - prob.lower)
    t0 = time.perf_counter()
    ev = prob.evaluate(X)
    ms = 1e3 * (time.perf_counter() - t0) / len(X)
    iae = np.percentile(ev.f[ev.feasible], [0, 5, 50, 95, 100])
    print(f"the row's box, {args.box_samples} uniform candidates: {100 * ev.feasible.mean():.0f} % feasible, IAE "
          + " ".join(f"{v:.0f}" for v in iae) + f" (0/5/50/95/100th), {ms:.1f} ms an evaluation")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
