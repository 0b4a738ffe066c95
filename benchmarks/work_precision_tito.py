"""Work-precision of the TITO loop on the CCTS, and the cost of an IAE evaluation on either loop:
the continuous loop and the sampled one side by side in this process.

Run with ``python benchmarks/work_precision_tito.py`` (part of ``make bench``). BLAS is pinned to
one thread. The case is ``ga_pi_ccts``'s tuning scenario (CCTS behind its inverted decoupler,
1,200 s: unit set-point steps, input and output disturbances of 0.1 at 500 s and 800 s).

1. Work and precision under the CCTS's GPM PI. The reference is the independent method-of-steps
   solution of ``tests/tito_dde_reference.py`` (LSODA, rtol 1e-10). Per loop and step: the
   milliseconds of one simulation (the continuous loop: building its path matrices, which a PI
   problem pays once per step and scenario, and running it, apart), the largest output
   difference from the reference at the loop's own samples, and the relative difference of
   IAE1 + IAE2 against the reference's (trapezoid on a 0.01 s grid between the jumps). The
   continuous loop's IAE is exact on its error cubics; the sampled loop's is the trapezoid rule
   on its samples, as the tuning problems compute each. The tolerance rows are the loop a
   config gets by default: each run's step chosen to ``tolerance`` (the runs at the coarser
   steps that checked it included in its time).
2. ``TITOProblem.evaluate`` per candidate (stability check, exact loop margins, simulation,
   metrics), the sampled loop at ``dt = 0.5`` s (``ga_pi_ccts`` of the release) against the
   continuous loop to 1e-3 (``ga_pi_ccts`` now), on the same candidates: the GPM PI and random
   stable candidates of the problem's bounds; median of the repeats, per candidate.
3. The same for PID candidates (``gpm_pid_ccts``'s problem, its derivative gains drawn in
   its bounds): a PID's loop is built per candidate and step, and large derivative gains need
   short steps; the sampled loop at 0.5 s (``allow_coarse_sampling``, as that config ships)
   beside it, with the steps the continuous runs kept.
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
from heurtune.objectives.tito.continuous import ContinuousTITOLoop, ContinuousTITOSimulator, ErrorCubics  # noqa: E402
from heurtune.runner.config import experiments_dir  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from timing import median_seconds  # noqa: E402
from tito_dde_reference import DDELoop  # noqa: E402


def _median_ms(fn, repeats):
    return 1e3 * median_seconds(fn, repeats)


def _iae(t, y):
    """IAE1 + IAE2 of unit set-points by the trapezoid rule on the samples ``t``."""
    e = np.abs(1.0 - y)
    return float(np.sum(0.5 * (e[1:] + e[:-1]) * np.diff(t)[:, None]))


def _problem(sample_time=None, base="ga_pi_ccts"):
    text = "" if sample_time is None else f"[scenario]\nsample_time = {sample_time}\n"
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"wp_tito_{os.getpid()}_{sample_time}.toml"
    if base == "ga_pi_ccts":
        path.write_text(f'extends = "ga_pi_ccts"\n{text}')
    else:  # a shipped config with sample_time = 0.5 and allow_coarse_sampling: its text, edited
        src = (experiments_dir() / f"{base}.toml").read_text()
        if sample_time is None:
            src = src.replace("sample_time = 0.5\n", "").replace("allow_coarse_sampling = true\n", "")
        path.write_text(src)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prob = heurtune.load_experiment(str(path)).problem("ccts")
    path.unlink()
    return prob


def work_precision(prob, repeats):
    x = prob.baseline("gpm")
    gains = ((x[0], x[1], 0.0), (x[2], x[3], 0.0))
    controllers = prob.controllers(x)
    sc = prob.scenario(prob.tuning_scenario)
    t0 = time.perf_counter()
    ref = DDELoop(prob.chain.plant, prob.chain.decoupler, gains, prob.N, sc).solve(rtol=1e-10, atol=1e-12,
                                                                                   method="LSODA")
    ref_s = time.perf_counter() - t0
    iae_ref = float(ref.error_integrals(0.01)[:, 0].sum())
    cache = {}

    def y_ref(t):
        key = (t.size, float(t[1]))
        if key not in cache:
            cache[key] = ref.outputs(t)
        return cache[key]
    print(f"1. work-precision, CCTS under its GPM PI, 1,200 s, BLAS threads = 1, {cpu_name()}")
    print(f"reference: method of steps (LSODA, rtol 1e-10), {ref_s:.1f} s; IAE1 + IAE2 = {iae_ref:.6f}")
    print(f"{'loop':22} {'step s':>7} {'build ms':>9} {'run ms':>8} {'output err':>11} {'IAE rel err':>12}")

    def row(label, h, build, run, t, y, iae):
        err = float(np.abs(y - y_ref(t)).max())
        b = f"{build:9.2f}" if build == build else f"{'':>9}"
        print(f"{label:22} {h:7.3f} {b} {run:8.2f} {err:11.2e} {abs(iae / iae_ref - 1):12.2e}")

    base = dataclasses.replace(sc, loop="continuous", dt=0.5)
    for h in (100 / 9, 50 / 9, 25 / 9, 1.0, 0.5, 0.1):
        scenario = dataclasses.replace(base, dt=h)
        build = _median_ms(lambda s=scenario: ContinuousTITOLoop.from_gains(
            prob.chain.plant, prob.chain.decoupler, gains, prob.N, s), repeats)
        loop = ContinuousTITOLoop.from_gains(prob.chain.plant, prob.chain.decoupler, gains, prob.N, scenario)
        run = _median_ms(lambda lp=loop: lp.run(None, "yu"), repeats)
        t, y, _, _ = loop.run()
        cubics = ErrorCubics(loop.errors, h)
        row("continuous", h, build, run, t, y, sum(cubics.integrals(i)[0] for i in (0, 1)))
    for tol in (1e-2, 1e-3, 1e-4):
        sim = ContinuousTITOSimulator(prob.chain.plant, prob.chain.decoupler,
                                      dataclasses.replace(base, tolerance=tol), controller_outputs=False)
        res = sim.run(controllers)  # builds the ladder's loops (once per problem and scenario)
        run = _median_ms(lambda s=sim: s.run(controllers), repeats)
        row(f"continuous, tol {tol:g}", res.step, np.nan, run, res.t, res.y,
            sum(res.errors.integrals(i)[0] for i in (0, 1)))
    for dt in (0.5, 0.1, 0.02):
        scenario = dataclasses.replace(sc, dt=dt, loop="sampled", tolerance=None)
        sim = prob._simulator(scenario)
        run = _median_ms(lambda s=sim: s.arrays(controllers), repeats)
        status, y, _, _, _ = sim.arrays(controllers)
        row("sampled", dt, np.nan, run, sim.t, y, _iae(sim.t, y))


def evaluation_cost(repeats, n_random, base="ga_pi_ccts", title="2. TITOProblem.evaluate per candidate, CCTS IAE"):
    sampled, continuous = _problem(0.5, base), _problem(None, base)
    rng = np.random.default_rng(0)
    X = sampled.lower + rng.random((20 * n_random, sampled.dim)) * (sampled.upper - sampled.lower)
    X = X[sampled.evaluate(X).reason == ""][:n_random]
    X = np.vstack([sampled.baseline("gpm")[None, :], X])
    print(f"\n{title} (1,200 s): the GPM design and {len(X) - 1} random stable candidates, {cpu_name()}")
    print(f"{'loop':30} {'ms per candidate':>17} {'IAE1 + IAE2 (GPM)':>18}")
    out = {}
    for label, prob in (("sampled, dt = 0.5 s", sampled), ("continuous, tolerance 1e-3", continuous)):
        assert (prob.evaluate(X).reason == "").all()  # builds the PI loops once
        ms = _median_ms(lambda p=prob: p.evaluate(X), repeats) / len(X)
        out[label] = ms
        print(f"{label:30} {ms:17.2f} {prob.evaluate(X[:1]).f[0]:18.6f}")
    a, b = out.values()
    print(f"continuous / sampled: {b / a:.2f}")
    sim = continuous._simulator(continuous.scenario(continuous.tuning_scenario))
    steps = [sim.run(continuous.controllers(x)).step for x in X]
    print("steps kept (s):", ", ".join(f"{h:.3g}" for h in steps))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--candidates", type=int, default=20, help="random stable candidates of part 2")
    args = parser.parse_args(argv)
    with threadpool_limits(1):
        work_precision(_problem(), args.repeats)
        evaluation_cost(args.repeats, args.candidates)
        evaluation_cost(max(1, args.repeats // 2), args.candidates // 2, "gpm_pid_ccts",
                        "3. TITOProblem.evaluate per candidate, CCTS PID IAE")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
