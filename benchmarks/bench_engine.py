"""Engine overhead per generation and parallel speed-up on the QTP FOLQI problem.

Run with ``make bench`` (or ``python benchmarks/bench_engine.py``). BLAS is pinned to one
thread here and in the workers. Pool start-up is excluded: one evaluator (one pool) serves all
timed runs, as it does across the runs of an experiment.

* Overhead: cuckoo search (n = 25) on a trivial vectorised objective; everything measured is
  the engine and the optimiser (ask, repair, bookkeeping, tell, history).
* Speed-up: cuckoo search on the QTP FOLQI problem (case min) at population 25 and 50, with 1
  and 2 workers; median over three seeds of the wall time per generation, and the ratio.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import heurtune  # noqa: E402
from heurtune.core.engine import SearchSpace, run  # noqa: E402
from heurtune.core.evaluator import Evaluator  # noqa: E402


def trivial(X):
    return (X * X).sum(axis=1)


def per_generation(evaluator, space, n, epochs, seed=0):
    t0 = time.perf_counter()
    res = run("cs", evaluator, space, settings=dict(n=n), max_epochs=epochs, seed=seed)
    return (time.perf_counter() - t0) / (res.n_epochs + 0.5), res  # epoch 0 is half a generation


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--generations", type=int, default=10, help="CS generations per QTP timing")
    args = ap.parse_args(argv)
    with threadpool_limits(1):
        space = SearchSpace([-5.0] * 10, [5.0] * 10)
        with Evaluator(trivial) as ev:
            per_generation(ev, space, 25, 20)
            overhead, _ = per_generation(ev, space, 25, 500)
        prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
        qspace = SearchSpace(prob.lower, prob.upper)
        rng = np.random.default_rng(0)
        X = prob.lower + rng.random((50, prob.dim)) * (prob.upper - prob.lower)
        prob.warm_up()
        prob.evaluate(X[:2])
        t0 = time.perf_counter()
        prob.evaluate(X)
        eval_ms = (time.perf_counter() - t0) / 50 * 1e3
        rows = []
        for jobs in (1, 2):
            with Evaluator(prob, n_jobs=jobs) as ev:
                for _ in range(3):  # start the workers and let them load the compiled kernels
                    ev(X)
                for n in (25, 50):
                    times = [per_generation(ev, qspace, n, args.generations, seed=s)[0] for s in range(3)]
                    rows.append((n, jobs, float(np.median(times))))
    print(f"engine overhead per CS generation (n = 25, trivial objective): {overhead * 1e3:.3f} ms")
    print(f"QTP FOLQI evaluation in-process: {eval_ms:.2f} ms each (random candidates)")
    print(f"  -> overhead relative to a generation's evaluation time (2 x 25 evals): "
          f"{overhead / (50 * eval_ms / 1e3) * 100:.2f} %")
    print(f"{'population':>10s} {'workers':>8s} {'s/generation':>13s} {'speed-up':>9s}")
    base = {n: t for n, jobs, t in rows if jobs == 1}
    for n, jobs, t in rows:
        print(f"{n:10d} {jobs:8d} {t:13.3f} {base[n] / t:9.2f}")


if __name__ == "__main__":
    main()
