"""Speed of one full FOLQI evaluation, the default continuous-time loop against the sampled
loop of earlier versions and a scipy LSODA reference, side by side.

Run with ``make bench`` (or ``python benchmarks/bench_evaluate.py [--repeats N]``). BLAS is
pinned to one thread: the 4x4 Riccati and 30x30 eigenvalue problems are too small to gain from
threads and lose to their start-up on a 2-core machine.

What is timed, each as the median of repeated runs in this process, for the thesis CS/FOLQI
minimum-phase gains:

* heurtune, the default: ``Problem.evaluate(x)`` of ``cs_folqi_qtp`` (LQR by Riccati, Oustaloup
  filters, closed-loop eigenvalue check, the continuous-time loop at ``tolerance = 0.005``,
  metrics), and its parts;
* heurtune, ``[controller] sample_time = 0.01``: the same evaluation with the sampled loop
  (exact discretisation, 35,000 steps), the default before the continuous loop;
* reference: the independent continuous-time model of tests/reference_qtp.py integrated by
  ``solve_ivp(method="LSODA")`` at its default tolerances (rtol 1e-3, atol 1e-6), sampled at the
  same 35,001 instants; and once with Radau at tight tolerances (rtol 1e-11), as the accuracy
  yardstick.
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
from heurtune.objectives.qtp import controllers  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import reference_qtp  # noqa: E402

GAINS = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
             Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


def forget_designs(filters=False):
    """Empty the design's caches of recent weights and orders (``controllers._lqr_cache``,
    ``_folqi_layout``), which a study's finite-difference gradients hit but a benchmark that
    repeats one candidate would hit every time; the filters of an order stay cached, as
    before those caches existed, unless ``filters`` (``_integrator_modal``: a batch of new
    candidates has new orders)."""
    controllers._lqr_cache.clear()
    controllers._folqi_layout.cache_clear()
    if filters:
        controllers._integrator_modal.cache_clear()


def median_ms(fn, repeats):
    times = []
    for _ in range(repeats):
        forget_designs()  # each timed call designs its controller as a new candidate would
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=50, help="timed runs of the jitted evaluation")
    ap.add_argument("--reference-repeats", type=int, default=5, help="timed runs of the LSODA reference")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    x = np.array([GAINS[n] for n in prob.names])
    loop, sc = prob.loop, prob.scenario("nominal")
    sampled = dataclasses.replace(sc, dt=0.01, tolerance=None)
    p = prob.loop.plant
    plant = dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))
    with threadpool_limits(1):
        prob.evaluate(x)  # compile / load the kernels
        prob.evaluate(x, sampled)
        ctrl = loop.controller(GAINS)
        sim = loop.run(ctrl, sc)
        sim_sampled = loop.run(ctrl, sampled)
        parts = {
            "design (Riccati + filters)": median_ms(lambda: loop.controller(GAINS), args.repeats),
            "stability check (eigenvalues)": median_ms(lambda: loop.stability_margin(ctrl), args.repeats),
            "continuous loop, simulation and metrics": median_ms(lambda: loop.run(ctrl, sc, record=False),
                                                                 args.repeats),
            "sampled loop, simulation and metrics": median_ms(lambda: loop.run(ctrl, sampled, record=False),
                                                              args.repeats),
        }
        full = median_ms(lambda: prob.evaluate(x), args.repeats)
        full_sampled = median_ms(lambda: prob.evaluate(x, sampled), args.repeats)
        t = sim.t
        ref = median_ms(lambda: reference_qtp.reference_loop(plant, GAINS, t, method="LSODA", rtol=1e-3, atol=1e-6),
                        args.reference_repeats)
        y_lsoda, _ = reference_qtp.reference_loop(plant, GAINS, t, method="LSODA", rtol=1e-3, atol=1e-6)
        y_tight, _ = reference_qtp.reference_loop(plant, GAINS, t, method="Radau", rtol=1e-11, atol=1e-12)
    err = {"continuous": float(np.max(np.abs(sim.y - y_tight))),
           "sampled": float(np.max(np.abs(sim_sampled.y - y_tight))),
           "lsoda": float(np.max(np.abs(y_lsoda - y_tight)))}
    steps = sim.steps
    print(f"FOLQI evaluation, QTP minimum phase, BLAS threads = 1, {cpu_name()}")
    print(f"continuous loop: tolerance {sc.tolerance} cm, {steps} steps kept (the rule's step alone: "
          f"{loop.step_plan(ctrl, sc).n_steps}); sampled loop: {sampled.n_steps} steps of {sampled.dt} s")
    print(f"{'part':44s} {'median ms':>10s}")
    for name, ms in parts.items():
        print(f"  {name:42s} {ms:10.3f}")
    print(f"{'Problem.evaluate, continuous (default)':44s} {full:10.3f}")
    print(f"{'Problem.evaluate, sample_time = 0.01':44s} {full_sampled:10.3f}")
    print(f"{'scipy LSODA reference (default tol.)':44s} {ref:10.1f}")
    print(f"continuous against sampled: {full_sampled / full:.2f}x faster; against LSODA: {ref / full:.0f}x "
          f"(sampled: {ref / full_sampled:.0f}x)")
    print(f"max |y - y_Radau(1e-11)|: continuous {err['continuous']:.2e} cm, sampled {err['sampled']:.2e} cm, "
          f"LSODA default {err['lsoda']:.2e} cm")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(dict(steps=steps, parts_ms=parts, evaluate_ms=full,
                                                   evaluate_sampled_ms=full_sampled,
                                                   lsoda_ms=ref, speedup=ref / full, speedup_sampled=ref / full_sampled,
                                                   err_cm=err), indent=2))


if __name__ == "__main__":
    main()
