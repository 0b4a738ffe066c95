"""Cost of robust tuning: one batch evaluated on the nominal problem and worst-case over three
plants, side by side in this process, for the QTP (cs_folqi_qtp / robust_cs_folqi_qtp, case
min) and the TITO CCTS (ga_pi_ccts / robust_ga_pi_ccts).

Run with ``python benchmarks/bench_robust.py [--repeats N]`` (part of ``make bench``). BLAS is
pinned to one thread. Each batch is 25 candidates around a good design (the thesis' CS/FOLQI
minimum-phase gains; the GPM PI of the CCTS), each gain times a factor in [0.9, 1.1], all of
which pass the stability check and are simulated in every scenario: the work a user waits for,
not early rejections. Reported: milliseconds per candidate on each problem, per scenario of
the robust one, and the ratio robust / nominal.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402
from timing import median_seconds  # noqa: E402

import heurtune  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

GAINS = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
             Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


def _ms_per_candidate(fn, n, repeats) -> float:
    return 1e3 * median_seconds(fn, repeats) / n


def _compare(label, nominal, robust, X, repeats):
    assert np.all(robust.evaluate(X).reason == ""), "every candidate must be simulated"
    base = _ms_per_candidate(lambda: nominal.evaluate(X), len(X), repeats)
    total = _ms_per_candidate(lambda: robust.evaluate(X), len(X), repeats)
    per = {s: _ms_per_candidate(lambda s=s: robust.evaluate(X, s), len(X), repeats) for s in robust.robust.scenarios}
    print(f"{label}: nominal problem {base:.2f} ms per candidate; robust ({robust.robust.aggregate} over "
          f"{len(per)} scenarios) {total:.2f} ms, ratio {total / base:.2f}")
    print("    per scenario: " + ", ".join(f"{s} {v:.2f} ms" for s, v in per.items())
          + f"; robust minus their sum {total - sum(per.values()):+.2f} ms")


def _python_overhead(prob, x, scenario, repeats=40):
    """Milliseconds per simulation spent in ``ClosedLoop.run`` outside the jitted kernel: what
    one kernel call for several scenarios could save at most."""
    from heurtune.objectives.qtp import continuous_kernels, kernels

    ctrl = prob.loop.controller(prob.values(x))
    sc = prob.scenario(scenario)
    module, name = (continuous_kernels, "simulate_continuous") if sc.continuous else (kernels, "simulate_loop")
    kernel, spent = getattr(module, name), [0.0]

    def timed(*args):
        t0 = time.perf_counter()
        out = kernel(*args)
        spent[0] += time.perf_counter() - t0
        return out

    setattr(module, name, timed)
    try:
        for _ in range(5):
            prob.loop.run(ctrl, sc, record=False)
        spent[0] = 0.0
        t0 = time.perf_counter()
        for _ in range(repeats):
            prob.loop.run(ctrl, sc, record=False)
        total = time.perf_counter() - t0
    finally:
        setattr(module, name, kernel)
    return 1e3 * total / repeats, 1e3 * (total - spent[0]) / repeats


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="timed evaluations of each batch")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"CPU: {cpu_name()}; 25 simulated candidates per batch, median of {args.repeats}; BLAS threads = 1")
    with threadpool_limits(1):
        nominal = heurtune.load_experiment("cs_folqi_qtp").problem("min")
        robust = heurtune.load_experiment("robust_cs_folqi_qtp").problem("min")
        x = np.array([GAINS[n] for n in nominal.names])
        _compare("QTP min FOLQI", nominal, robust, x * rng.uniform(0.9, 1.1, (25, x.size)), args.repeats)
        run_ms, outside_ms = _python_overhead(robust, x, "+30%")
        print(f"    one simulation (ClosedLoop.run) {run_ms:.3f} ms, of which outside the jitted kernel "
              f"{outside_ms:.3f} ms ({100 * outside_ms / run_ms:.1f} %)")
        nominal = heurtune.load_experiment("ga_pi_ccts").problem("ccts")
        robust = heurtune.load_experiment("robust_ga_pi_ccts").problem("ccts")
        x = nominal.baseline("gpm")
        _compare("TITO CCTS PI", nominal, robust, x * rng.uniform(0.9, 1.1, (25, x.size)), args.repeats)


if __name__ == "__main__":
    main()
