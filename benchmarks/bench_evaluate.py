"""Speed of one full FOLQI evaluation against a scipy LSODA reference, side by side.

Run with ``make bench`` (or ``python benchmarks/bench_evaluate.py [--repeats N]``). BLAS is
pinned to one thread: the 4x4 Riccati and 30x30 eigenvalue problems are too small to gain from
threads and lose to their start-up on a 2-core machine.

What is timed, each as the median of repeated runs in this process:

* heurtune: ``Problem.evaluate(x)`` for the thesis CS/FOLQI minimum-phase gains: LQR (Riccati),
  Oustaloup filters, closed-loop eigenvalue check, exact discretisation, 35,000-step jitted
  simulation, metrics. Also its parts.
* reference: the independent continuous-time model of tests/reference_qtp.py integrated by
  ``solve_ivp(method="LSODA")`` at its default tolerances (rtol 1e-3, atol 1e-6), sampled at the
  same 35,001 instants; and once with Radau at tight tolerances, as the accuracy yardstick.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import heurtune  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import reference_qtp  # noqa: E402

GAINS = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
             Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


def median_ms(fn, repeats):
    times = []
    for _ in range(repeats):
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
    p = prob.loop.plant
    plant = dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))
    with threadpool_limits(1):
        prob.evaluate(x)  # compile / load the kernels
        ctrl = loop.controller(GAINS)
        sim = loop.run(ctrl, sc)
        parts = {
            "design (Riccati + filters)": median_ms(lambda: loop.controller(GAINS), args.repeats),
            "stability check (eigenvalues)": median_ms(lambda: loop.stability_margin(ctrl), args.repeats),
            "discretisation": median_ms(lambda: ctrl.discretise(sc.dt), args.repeats),
            "simulation (incl. discretisation)": median_ms(lambda: loop.run(ctrl, sc), args.repeats),
            "metrics": median_ms(lambda: loop.metrics(sim, sc, prob.settling_band), args.repeats),
        }
        full = median_ms(lambda: prob.evaluate(x), args.repeats)
        t = sim.t
        ref = median_ms(lambda: reference_qtp.reference_loop(plant, GAINS, t, method="LSODA", rtol=1e-3, atol=1e-6),
                        args.reference_repeats)
        y_lsoda, _ = reference_qtp.reference_loop(plant, GAINS, t, method="LSODA", rtol=1e-3, atol=1e-6)
        y_tight, _ = reference_qtp.reference_loop(plant, GAINS, t, method="Radau", rtol=1e-9, atol=1e-11)
    err_jit = float(np.max(np.abs(sim.y - y_tight)))
    err_lsoda = float(np.max(np.abs(y_lsoda - y_tight)))
    print(f"FOLQI evaluation, QTP minimum phase, {sc.n_steps} steps of {sc.dt} s, BLAS threads = 1")
    print(f"{'part':40s} {'median ms':>10s}")
    for name, ms in parts.items():
        print(f"  {name:38s} {ms:10.3f}")
    print(f"{'heurtune Problem.evaluate (full)':40s} {full:10.3f}")
    print(f"{'scipy LSODA reference (default tol.)':40s} {ref:10.1f}")
    print(f"speed-up: {ref / full:.0f}x")
    print(f"max |y - y_Radau(1e-9)|: heurtune {err_jit:.4f} cm, LSODA default {err_lsoda:.4f} cm")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(dict(parts_ms=parts, evaluate_ms=full, lsoda_ms=ref,
                                                   speedup=ref / full, err_heurtune_cm=err_jit,
                                                   err_lsoda_cm=err_lsoda), indent=2))


if __name__ == "__main__":
    main()
