"""What one evaluation costs as a study sees it: the candidates an optimiser visits, not the
thesis' gains. Side by side in one process, one core, BLAS on one thread.

Run with ``python benchmarks/bench_study_candidates.py`` (part of ``make bench``). Candidate
sets, each on the one-candidate path (``--device cpu``) and the batched path (``cpu-batch``):

* ``thesis``: the thesis' CS/FOLQI minimum-phase gains (``cs_folqi_qtp`` only);
* ``uniform``: random candidates uniform in the problem's bounds, the stable ones kept (a
  candidate rejected before simulation costs microseconds and is not what a study waits for);
* ``at bounds``: the same with each coordinate pushed to a bound with probability 0.3 (where
  clipping optimisers spend their time);
* ``visited``: the candidates a cuckoo-search run of the problem evaluated (``heurtune.minimize``,
  seed 0, 1,500 evaluations), recorded, the simulated ones kept, spread over the run.

For ``cs_folqi_qtp`` each set is also timed, on a subsample, against the independent
continuous-time loop of ``tests/reference_qtp.py`` integrated by scipy LSODA at its default
tolerances (rtol 1e-3, atol 1e-6) on the same output grid: the ratio the issue asks for
(>= 1,000x at 0.4 ms per candidate). ``benchmark_qtp`` (IOLQI with pairing and physical
limits) has no such reference here (the projected-ODE reference of the tests covers the
limits of one loop at a time); its rows give heurtune's times alone. Per set: median
milliseconds per candidate over the repeats, the mean and largest number of kept steps; for
``cs_folqi_qtp`` also the one-candidate path with ``[scenario] integrator = "linearised"``
(milliseconds, the switching path's time over it, mean steps; ``benchmark_qtp`` has physical
limits, which that integrator does not follow).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import heurtune  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import reference_qtp  # noqa: E402
from bench_evaluate import GAINS, forget_designs  # noqa: E402


def _stable(prob, X, n):
    """The first ``n`` rows of ``X`` that the problem simulates (not rejected before)."""
    keep = []
    for start in range(0, len(X), 64):
        ev = prob.evaluate(X[start:start + 64])
        keep.extend(X[start:start + 64][ev.reason == ""])
        if len(keep) >= n:
            break
    return np.array(keep[:n]).reshape(-1, prob.dim)


def candidate_sets(prob, n, seed, thesis):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(prob.lower, float), np.asarray(prob.upper, float)
    sets = {}
    if thesis:
        sets["thesis"] = np.array([[GAINS[name] for name in prob.names]])
    sets["uniform"] = _stable(prob, lo + rng.random((40 * n, prob.dim)) * (hi - lo), n)
    X = lo + rng.random((40 * n, prob.dim)) * (hi - lo)
    at = rng.random(X.shape) < 0.3
    X = np.where(at, np.where(rng.random(X.shape) < 0.5, lo, hi), X)
    sets["at bounds"] = _stable(prob, X, n)
    visited = []

    def fun(Y):
        visited.append(np.array(Y, float))
        ev = prob.evaluate(Y)
        return ev.f, ev.g

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        heurtune.minimize(fun, lo, hi, "cs", max_evals=1500, seed=0)
    V = np.vstack(visited)
    V = V[np.linspace(0, len(V) - 1, min(len(V), 40 * n)).astype(int)]
    sets["visited"] = _stable(prob, V, n)
    return sets


def per_candidate_ms(prob, X, repeats, device):
    prob.set_device(device)
    prob.evaluate(X)  # compile / load the kernels of this path
    times = []
    for _ in range(repeats):
        forget_designs(filters=True)  # every candidate designed afresh, as in a study
        t0 = time.perf_counter()
        prob.evaluate(X)
        times.append(time.perf_counter() - t0)
    prob.set_device("cpu")
    return 1e3 * float(np.median(times)) / len(X)


def steps_of(prob, X):
    loop, sc = prob.loop, prob.scenario(prob.tuning_scenario)
    steps = []
    for x in X:
        sim = loop.run(loop.controller(prob.values(x)), sc, record=False)
        steps.append(sim.steps)
    return np.array(steps)


def lsoda_ms(prob, X, repeats):
    p = prob.loop.plant
    plant = dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))
    sc = prob.scenario(prob.tuning_scenario)
    t = np.linspace(0.0, sc.horizon, int(round(sc.horizon / 0.01)) + 1)
    times = []
    for x in X:
        gains = prob.values(x)
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            reference_qtp.reference_loop(plant, gains, t, method="LSODA", rtol=1e-3, atol=1e-6)
            best = min(best, time.perf_counter() - t0)
        times.append(best)
    return 1e3 * float(np.median(times))


def linearised_problem(name):
    """The experiment's problem on its min case with ``[scenario] integrator = "linearised"``."""
    from heurtune.core.families import make_experiment
    from heurtune.runner.config import load_config

    config = load_config(name)
    config["scenario"]["integrator"] = "linearised"
    return make_experiment(config).problem("min")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--candidates", type=int, default=40, help="candidates per set")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--reference", type=int, default=8, help="candidates per set timed against LSODA")
    args = ap.parse_args(argv)
    print(f"Per simulated candidate, as a study sees it; one core, BLAS one thread, {cpu_name()}")
    print(f"{'problem':14} {'set':10} {'n':>3} {'cpu ms':>8} {'batch ms':>9} {'batch gain':>10} "
          f"{'steps mean/max':>15} {'LSODA ms':>9} {'vs LSODA':>9} {'lin. ms':>8} {'lin. gain':>9} {'lin. steps':>10}")
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in ("cs_folqi_qtp", "benchmark_qtp"):
            prob = heurtune.load_experiment(name).problem("min")
            lin = linearised_problem(name) if name == "cs_folqi_qtp" else None
            for label, X in candidate_sets(prob, args.candidates, 1, name == "cs_folqi_qtp").items():
                one = per_candidate_ms(prob, X, args.repeats, "cpu")
                batch = per_candidate_ms(prob, X, args.repeats, "cpu-batch")
                steps = steps_of(prob, X)
                ref = ratio = lin_ms = lin_gain = lin_steps = ""
                if name == "cs_folqi_qtp":
                    ms = lsoda_ms(prob, X[:args.reference], 1)
                    ref, ratio = f"{ms:9.1f}", f"{ms / one:8.0f}x"
                    t_lin = per_candidate_ms(lin, X, args.repeats, "cpu")
                    lin_ms, lin_gain = f"{t_lin:8.3f}", f"{one / t_lin:8.2f}x"
                    lin_steps = f"{steps_of(lin, X).mean():10.0f}"
                print(f"{name:14} {label:10} {len(X):3d} {one:8.3f} {batch:9.3f} {one / batch:9.2f}x "
                      f"{steps.mean():8.0f}/{steps.max():<6d} {ref:>9} {ratio:>9} {lin_ms:>8} {lin_gain:>9} "
                      f"{lin_steps:>10}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
