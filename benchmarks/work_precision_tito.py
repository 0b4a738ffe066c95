"""Work-precision of the TITO loop on the CCTS: output error against milliseconds per simulation,
the continuous loop and the sampled one side by side in this process.

Run with ``python benchmarks/work_precision_tito.py`` (part of ``make bench``). BLAS is pinned to
one thread. The case is ``ga_pi_ccts``'s tuning scenario (CCTS behind its inverted decoupler,
1,200 s: unit set-point steps, input and output disturbances of 0.1 at 500 s and 800 s) under
its GPM PI. The reference is the independent method-of-steps solution of
``tests/tito_dde_reference.py`` (LSODA, rtol 1e-10). Per method and step: milliseconds of one
simulation (the continuous loop: building its path matrices, which a new candidate pays, and
running it, apart), the largest output difference from the reference on a 10 s grid, and the
relative difference of IAE1 + IAE2 (each loop's trapezoid rule on its own samples, as the
tuning problems compute it, against the reference's on a 0.01 s grid).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.tito.continuous import ContinuousTITOLoop  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from timing import median_seconds  # noqa: E402
from tito_dde_reference import DDELoop  # noqa: E402


def _median_ms(fn, repeats):
    return 1e3 * median_seconds(fn, repeats)


def _iae(t, r, y):
    e = np.abs(r - y)
    return float(np.sum(0.5 * (e[1:] + e[:-1]) * np.diff(t)[:, None]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prob = heurtune.load_experiment("ga_pi_ccts").problem("ccts")
    x = prob.baseline("gpm")
    gains = ((x[0], x[1], 0.0), (x[2], x[3], 0.0))
    sc = prob.scenario(prob.tuning_scenario)
    grid = np.arange(0.0, sc.horizon + 1e-9, 10.0)
    fine = np.arange(0.0, sc.horizon + 1e-9, 0.01)
    with threadpool_limits(1):
        t0 = time.perf_counter()
        ref = DDELoop(prob.chain.plant, prob.chain.decoupler, gains, prob.N, sc).solve(
            rtol=1e-10, atol=1e-12, method="LSODA")
        ref_s = time.perf_counter() - t0
        y_ref = ref.outputs(grid)
        r_fine = np.ones((fine.size, 2))
        iae_ref = _iae(fine, r_fine, ref.outputs(fine))
        print(f"TITO work-precision, CCTS under its GPM PI, 1,200 s, BLAS threads = 1, {cpu_name()}")
        print(f"reference: method of steps (LSODA, rtol 1e-10), {ref_s:.1f} s; IAE1 + IAE2 = {iae_ref:.6f}")
        print(f"{'method':11} {'step s':>7} {'build ms':>9} {'run ms':>8} {'output err':>11} {'IAE rel err':>12}")
        for h in (5.0, 2.5, 1.0, 0.5, 0.1):
            scenario = dataclasses.replace(sc, dt=h)
            build = _median_ms(lambda s=scenario: ContinuousTITOLoop.from_gains(
                prob.chain.plant, prob.chain.decoupler, gains, prob.N, s), args.repeats)
            loop = ContinuousTITOLoop.from_gains(prob.chain.plant, prob.chain.decoupler, gains, prob.N, scenario)
            run = _median_ms(loop.run, args.repeats)
            t, y, _, _ = loop.run()
            rows = np.rint(grid / h).astype(int)
            err = float(np.abs(y[rows] - y_ref).max())
            iae = _iae(t, np.ones_like(y), y)
            print(f"{'continuous':11} {h:7.2f} {build:9.2f} {run:8.2f} {err:11.2e} {abs(iae / iae_ref - 1):12.2e}")
        for dt in (0.5, 0.1, 0.02):
            scenario = dataclasses.replace(sc, dt=dt)
            sim = prob._simulator(scenario)
            ctrls = prob.controllers(x)
            run = _median_ms(lambda s=sim, c=ctrls: s.arrays(c), args.repeats)
            status, y, _, _, _ = sim.arrays(ctrls)
            rows = np.rint(grid / dt).astype(int)
            err = float(np.abs(y[rows] - y_ref).max())
            iae = _iae(sim.t, np.ones_like(y), y)
            print(f"{'sampled':11} {dt:7.2f} {'':>9} {run:8.2f} {err:11.2e} {abs(iae / iae_ref - 1):12.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
