"""QTP loop margins with exact crossovers against python-control's spline route, side by side.

For 12 random candidates of the bounds of ``cs_folqi_qtp`` and ``cs_pid_qtp`` (min and nmp) that
have a controller: the four element loops (``heurtune.objectives.qtp.margins.element_loop``),
each sampled on its default grid, and their gain and phase margins by

* heurtune: crossovers found by Brent's method on ``L(jw)`` itself (``siso_margins``, what
  every experiment's ``margins.parquet`` and the thesis' margin tables use);
* reference: ``control.stability_margins((mag, phase, omega))``, which finds them on a spline
  through the same samples (and also computes the stability margin); heurtune used it before.

Reported per experiment and case: milliseconds per loop for both, their ratio, the largest
relative difference of the gain-crossover frequencies and the largest difference of the gain
margins in dB (the spline's error), over crossovers within 100 dB of |L| = 1: beyond, at
w ~ 1e-7 rad/s where the integrators make |L| ~ 1e10, or where |L| is at the level of rounding,
neither route finds a root of anything (their counts agree; the reported margin is the crossover
closest to 0 dB). Where the two differ by more than a few hundredths of a dB, it is the spline's
"root" that is none: on PID loops with resonances between the samples, arg(-L) is 0.5-0.7 rad at
the spline's crossover and 1e-10 at heurtune's (checked by evaluating L there).
Run with ``python benchmarks/bench_qtp_margins.py [--repeats N]`` (part of ``make bench``).
BLAS is pinned to one thread.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import warnings  # noqa: E402

import control  # noqa: E402
import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402
from timing import median_seconds  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.qtp import margins  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

LOOPS = ("loop_1_1", "loop_1_2", "loop_2_1", "loop_2_2")


def _loops(prob, n, rng):
    """The element loops and their grids of the first ``n`` random candidates with a controller."""
    out = []
    while len(out) < 4 * n:
        x = prob.lower + rng.random(prob.dim) * (prob.upper - prob.lower)
        try:
            systems = margins.linear_systems(prob, x)
        except Exception:  # no controller for this candidate: not a loop anyone reads
            continue
        for name in LOOPS:
            L = systems[name]
            out.append((L, margins.frequency_grid(control.poles(L))))
    return out


def _reference(L, omega):
    resp = control.frequency_response(L, omega)
    mag, phase = np.asarray(resp.magnitude).ravel(), np.degrees(np.asarray(resp.phase).ravel())
    gm, pm, _sm, wpc, wgc, _ws = control.stability_margins((mag, phase, omega), returnall=True)
    return np.atleast_1d(wgc), np.atleast_1d(gm)


def _db_gap(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        return float("nan")
    ok = np.isfinite(a) & np.isfinite(b) & (b > 0) & (a > 1e-5) & (a < 1e5)
    return float(np.max(np.abs(20.0 * np.log10(a[ok] / b[ok])), initial=0.0))


def _relative(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.size == 0:
        return 0.0 if a.shape == b.shape else float("nan")
    ok = np.isfinite(a) & np.isfinite(b) & (np.abs(a) > 0)
    return float(np.max(np.abs(a[ok] - b[ok]) / np.abs(a[ok]), initial=0.0))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--candidates", type=int, default=12)
    args = parser.parse_args(argv)
    print(f"QTP element-loop margins per loop, BLAS threads = 1, {cpu_name()}")
    print(f"{'experiment':13} {'case':4} {'exact ms':>9} {'spline ms':>10} {'ratio':>6} {'wgc diff':>9} {'GM dB':>9}")
    rng = np.random.default_rng(5)
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in ("cs_folqi_qtp", "cs_pid_qtp"):
            exp = heurtune.load_experiment(name)
            for case in ("min", "nmp"):
                loops = _loops(exp.problem(case), args.candidates, rng)
                exact = median_seconds(lambda loops=loops: [margins._crossings(L, w) for L, w in loops], args.repeats)
                spline = median_seconds(lambda loops=loops: [_reference(L, w) for L, w in loops], args.repeats)
                wgc = gm = 0.0
                for L, w in loops:
                    _, g_new, w_new, _ = margins._crossings(L, w)
                    w_ref, g_ref = _reference(L, w)
                    wgc = max(wgc, _relative(w_ref, w_new))
                    gm = max(gm, _db_gap(g_ref, g_new))
                per = 1e3 / len(loops)
                print(f"{name:13} {case:4} {exact * per:9.2f} {spline * per:10.2f} {spline / exact:6.1f} "
                      f"{wgc:9.1e} {gm:9.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
