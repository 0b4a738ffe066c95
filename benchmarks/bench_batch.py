"""Candidates side by side: the batched QTP simulations against the one-candidate kernel and LSODA.

Run with ``make bench`` (or ``python benchmarks/bench_batch.py [--candidates 64] [--gpu]``). BLAS
is pinned to one thread and everything runs on one core, in this process, side by side:

* one-candidate kernel: ``ClosedLoop.run(record=False)`` for each of N stable FOLQI candidates
  (the thesis' minimum-phase plant and nominal scenario: the default continuous-time loop, or
  with ``--sample-time 0.01`` the sampled loop of 35,000 steps);
* batched CPU kernel: ``ClosedLoop.run_batch`` of the same N candidates (device ``cpu-batch``);
* the whole evaluation a user waits for (design, stability check, simulation, metrics) of the
  same N candidates by ``Problem.evaluate_scenarios`` on each device, the design's caches of
  recent weights, orders and filters emptied before each repeat (a study's new candidates find
  nothing there; the one-candidate path would otherwise reuse every Riccati solution and filter
  of the first repeat, which the batched design does not keep);
* reference: one independent scipy LSODA simulation of tests/reference_qtp.py (default
  tolerances), per candidate.
* with ``--gpu``: the CUDA kernel for 1,024 to 262,144 lanes (copies of the N candidates), in
  simulations per second, checked against the CPU kernel; without a GPU it says so.

Reports ms per candidate, the ratios, and the CPU it ran on.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.qtp import gpu  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import reference_qtp  # noqa: E402
from bench_evaluate import forget_designs  # noqa: E402

GAINS = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
             Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


def metric_differences(got, ref):
    """Largest relative difference over the metrics but ess, and largest absolute one of ess
    (the final deviation in percent of the level: near zero, so relative figures mislead)."""
    from heurtune.objectives.qtp.kernels import METRIC_NAMES

    ess = [METRIC_NAMES.index("ess1"), METRIC_NAMES.index("ess2")]
    rest = [j for j in range(len(METRIC_NAMES)) if j not in ess]
    rel = np.abs(got[:, rest] - ref[:, rest]) / np.maximum(np.abs(ref[:, rest]), 1e-300)
    return float(np.nanmax(rel)), float(np.nanmax(np.abs(got[:, ess] - ref[:, ess])))


def best_of(fn, repeats, before=None):
    """Best time of ``repeats`` calls of ``fn``, each after ``before()`` when given (not timed)."""
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def stable_candidates(prob, n, seed=0):
    """n candidates near the thesis gains (each gain scaled by 0.5..2) whose loop is stable."""
    rng = np.random.default_rng(seed)
    base = np.array([GAINS[k] for k in prob.names])
    rows = []
    while len(rows) < n:
        x = np.clip(base * np.exp(rng.uniform(np.log(0.5), np.log(2.0), base.size)), prob.lower, prob.upper)
        if prob.evaluate(x[None, :], "nominal").reason[0] == "":
            rows.append(x)
    return np.array(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--candidates", type=int, default=64, help="candidates in the batch (default 64)")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats (best of)")
    ap.add_argument("--gpu", action="store_true", help="also time the CUDA kernel (needs a GPU)")
    ap.add_argument("--sample-time", type=float, help="time the sampled loop at this sample period instead of "
                                                       "the default continuous loop")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    loop, sc = prob.loop, prob.scenario("nominal")
    X = stable_candidates(prob, args.candidates)
    ctrls = [loop.controller(prob.values(x)) for x in X]
    n = len(ctrls)
    p = loop.plant
    plant = dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))
    if args.sample_time is not None:
        sc = dataclasses.replace(sc, dt=args.sample_time, tolerance=None)
    grid = sc.dt if sc.dt is not None else sc.output_dt
    t = np.arange(round(sc.horizon / grid) + 1) * grid
    steps = sc.n_steps if sc.dt is not None else sc.step_plan("folqi").n_steps
    what = (f"the sampled loop, {steps} steps of {sc.dt} s" if sc.dt is not None else
            f"the continuous loop, tolerance {sc.tolerance} cm, {steps} steps")
    with threadpool_limits(1):
        loop.run_batch(ctrls[:2], [sc])  # compile / load the kernels
        prob.evaluate(X[:1])
        one = best_of(lambda: [loop.run(c, sc, record=False) for c in ctrls], args.repeats) / n
        batch = best_of(lambda: loop.run_batch(ctrls, [sc]), args.repeats) / n
        full = {}
        for device in ("cpu", "cpu-batch"):
            prob.set_device(device)
            full[device] = best_of(lambda: prob.evaluate_scenarios(X, [sc]), args.repeats,
                                   lambda: forget_designs(filters=True)) / n
        prob.set_device("cpu")
        lsoda = best_of(lambda: reference_qtp.reference_loop(plant, GAINS, t, method="LSODA", rtol=1e-3, atol=1e-6),
                        1)
        _, m_batch = loop.run_batch(ctrls, [sc])
        m_one = np.array([loop.run(c, sc, record=False).metrics for c in ctrls])
    diff, ess_diff = metric_differences(m_batch[:, 0], m_one)
    figures = {
        "cpu": cpu_name(), "candidates": n, "loop": what, "steps": steps,
        "one_candidate_kernel_ms": 1e3 * one, "batched_kernel_ms": 1e3 * batch,
        "evaluation_cpu_ms": 1e3 * full["cpu"], "evaluation_cpu_batch_ms": 1e3 * full["cpu-batch"],
        "lsoda_ms": 1e3 * lsoda, "largest_relative_metric_difference": diff, "largest_ess_difference_pct": ess_diff,
    }
    print(f"QTP FOLQI simulations, minimum phase, {what}, {n} stable candidates, "
          f"one core of {figures['cpu']}")
    print(f"  one-candidate kernel       {1e3 * one:8.3f} ms per candidate")
    print(f"  batched kernel (cpu-batch) {1e3 * batch:8.3f} ms per candidate   x{one / batch:.2f}")
    print(f"  full evaluation, cpu       {1e3 * full['cpu']:8.3f} ms per candidate")
    print(f"  full evaluation, cpu-batch {1e3 * full['cpu-batch']:8.3f} ms per candidate   "
          f"x{full['cpu'] / full['cpu-batch']:.2f}")
    print(f"  scipy LSODA reference      {1e3 * lsoda:8.1f} ms per candidate")
    print(f"  ratio to LSODA: one-candidate kernel x{lsoda / one:.0f}, batched kernel x{lsoda / batch:.0f}, "
          f"full batched evaluation x{lsoda / full['cpu-batch']:.0f}")
    print(f"  batched vs one-candidate: largest relative metric difference {diff:.1e} (ess left out), "
          f"largest ess difference {ess_diff:.1e} % of the operating level")
    if args.gpu:
        figures["gpu"] = bench_gpu(loop, ctrls, sc)
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2))


def bench_gpu(loop, ctrls, sc):
    """Simulations per second of the CUDA kernel for 1,024 to 262,144 lanes (copies of the
    candidates), checked against the CPU kernel on the first candidates."""
    if not gpu.available():
        print("  GPU: none found here (numba.cuda.is_available() is False); GPU figures unmeasured")
        return None
    out = {}
    loop.run_batch(ctrls[:2], [sc], device="gpu")  # compile
    _, m_gpu = loop.run_batch(ctrls, [sc], device="gpu")
    m_one = np.array([loop.run(c, sc, record=False).metrics for c in ctrls])
    diff, ess_diff = metric_differences(m_gpu[:, 0], m_one)
    print(f"  GPU vs one-candidate kernel: largest relative metric difference {diff:.1e} (ess left out), "
          f"largest ess difference {ess_diff:.1e} %")
    for lanes in (1024, 4096, 16384, 65536, 262144):
        batch = [ctrls[i % len(ctrls)] for i in range(lanes)]
        t0 = time.perf_counter()
        loop.run_batch(batch, [sc], device="gpu")
        dt = time.perf_counter() - t0
        out[lanes] = lanes / dt
        print(f"  GPU {lanes:7d} lanes: {lanes / dt:10.0f} simulations/s (design excluded, discretisation included)")
    return dict(rates=out, largest_relative_metric_difference=diff)


if __name__ == "__main__":
    main()
