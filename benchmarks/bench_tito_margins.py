"""Exact TITO loop metrics against the shared grid they replaced, side by side in this process.

For every decoupled preset loop of ``paper_001`` (CCTS, CSTS, QTS) and 25 candidates around a
reference design (the GPM PI, or the printed PI where the QTS has none), each gain times a factor
in [0.7, 1.3]: the loop metrics on each candidate's own grid with exact crossings
(``heurtune.objectives.tito.margins``, what ``TITOProblem.evaluate`` computes) and on the
problem's shared grid (``design.bandwidth_design_eval``, what it computed before). Reported per
case: milliseconds per candidate and loop for both, their ratio, the points of the candidate
grids, and the largest relative difference of the gain margin (the shared grid's error).

Run with ``python benchmarks/bench_tito_margins.py [--repeats N]`` (part of ``make bench``).
BLAS is pinned to one thread.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402
from timing import median_seconds  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.tito import design as tito_design  # noqa: E402
from heurtune.objectives.tito import margins as tito_margins  # noqa: E402
from heurtune.objectives.tito.papers import simulated  # noqa: E402
from heurtune.objectives.tito.problem import _controller_tail  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402


def _candidates(prob, n=25):
    if all(c is not None for c in prob.chain.gpm):
        x0 = prob.baseline("gpm")
    else:
        x0 = simulated.decision_vector(prob, simulated.printed_controllers("001", prob.case)["Proposed PI"])
    rng = np.random.default_rng(3)
    return x0 * rng.uniform(0.7, 1.3, (n, x0.size))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exp = heurtune.load_experiment("paper_001")
    print(f"TITO loop metrics per candidate and loop, BLAS threads = 1, {cpu_name()}")
    print(f"{'case':6} {'loop':>4} {'exact ms':>9} {'shared ms':>10} {'ratio':>6} {'points':>13} {'GM diff':>9}")
    with threadpool_limits(1):
        for case in exp.cases:
            prob = exp.problem(case)
            X = _candidates(prob)
            per = X.shape[1] // 2
            for i in (1, 2):
                Xi = X[:, (i - 1) * per:i * per]
                w, Pw, Pt = prob._grids[i - 1]

                def exact(Xi=Xi, i=i, prob=prob):
                    return [prob._exact_loop_metrics(i, x) for x in Xi]

                def shared(Xi=Xi, w=w, Pw=Pw, Pt=Pt, prob=prob):
                    tail = Pt[None, :] * _controller_tail(Xi, prob.kind, prob.N, w)
                    return tito_design.bandwidth_design_eval(Pw, w, Xi, prob.kind, prob.N, 1.0, 1.0, 1e9,
                                                             return_metrics=True, tail=tail)[3]

                t_exact = median_seconds(exact, args.repeats) / len(Xi)
                t_shared = median_seconds(shared, args.repeats) / len(Xi)
                ms = exact()
                ok = [m for m in ms if m is not None]
                gm_exact = np.array([m.gain_margin[0] for m in ok])
                gm_shared = shared().gain_margin[[m is not None for m in ms]]
                diff = np.nanmax(np.abs(gm_shared / gm_exact - 1.0)) if ok else np.nan
                grids = [tito_margins.candidate_grid(prob._terms[i - 1], list(x) + [0.0] * (3 - per), prob.N,
                                                     w[0], w[-1]) for x in Xi]
                sizes = [g[0].size for g in grids if g is not None] or [0]
                print(f"{case:6} {i:>4} {1e3 * t_exact:9.2f} {1e3 * t_shared:10.2f} {t_exact / t_shared:6.2f} "
                      f"{min(sizes):>6}-{max(sizes):<6} {diff:9.2e}")
    print("(shared: the problem's one grid for the whole gain box, 12,000-48,000 points, vectorised over the"
          " batch; exact: each candidate's own grid and brentq)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
