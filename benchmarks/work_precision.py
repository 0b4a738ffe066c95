"""Work-precision of the QTP loop: error against milliseconds per evaluation, side by side.

Run with ``make bench`` (or ``python benchmarks/work_precision.py [--quick] [--out DIR]``).
BLAS is pinned to one thread. For each case (the thesis' FOLQI gains on min and nmp, and two
weakly damped FOLQI candidates inside the thesis bounds) and each method, in this process:

* ``continuous``: heurtune's continuous-time loop (``[scenario] tolerance``) at several
  tolerances; the time is a full evaluation of a simulated candidate: design, eigenvalue
  check, simulation and metrics (called on the loop directly, so that a candidate the check
  would reject, as the thesis' nmp gains are, is still timed as simulated);
* ``sampled``: the sampled-data loop (``[scenario] dt``) at steps from 0.05 to 0.00125 s; the
  same work;
* ``lsoda``, ``radau``: the independent model of ``tests/reference_qtp.py`` integrated by scipy
  at several rtol; the time is its simulation alone (it has no metrics).

The errors are measured against a tight continuous reference written here: the same
independent model by Radau at rtol 1e-11, with IAE_i and J_j as quadrature states and ts
located on its dense output by brentq. Reported: the largest level error (cm, on a 0.1 s grid),
the relative errors of J and IAE (summed over both loops) and the largest ts error (s); the
scipy runs report the level error only. Writes ``work_precision.json`` and
``work_precision.png`` (docs/img/ holds the copy docs/model.md shows).
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
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import brentq  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.qtp.loop import METRIC_NAMES, Scenario  # noqa: E402
from heurtune.objectives.qtp.model import preset  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import reference_qtp as ref  # noqa: E402
from bench_batch import cpu_name  # noqa: E402  (this folder is on the path of a script run)

CASES = {
    "min (thesis)": ("min", dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
                                 Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)),
    "nmp (thesis)": ("nmp", dict(Q11=1.0788, Q22=1.0036, Q33=0.1676, Q44=1.7933, R11=3.6276, R22=3.7317,
                                 Ki1=6.9248, Ki2=2.6781, alpha1=0.8020, alpha2=0.8700)),
    "weak 1 (alpha 1.8)": ("min", dict(Q11=2.5, Q22=2.5, Q33=2.5, Q44=2.5, R11=0.1, R22=0.1, Ki1=8.0, Ki2=8.0,
                                       alpha1=1.8, alpha2=1.8)),
    "weak 2 (alpha 1.6)": ("min", dict(Q11=2.5, Q22=2.5, Q33=2.5, Q44=2.5, R11=0.1, R22=0.1, Ki1=10.0, Ki2=10.0,
                                       alpha1=1.6, alpha2=1.6)),
}
TOLERANCES = (0.08, 0.02, 0.005, 0.00125, 0.0003)
SAMPLE_STEPS = (0.05, 0.02, 0.01, 0.005, 0.0025, 0.00125)
RTOLS = (1e-3, 1e-5, 1e-7)
GRID = 0.1


def best_ms(fn, repeats):
    """Best of ``repeats`` timings in ms (the least disturbed by other load)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return 1e3 * best


def plant_dict(case):
    p = preset(case)
    return dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))


def tight_reference(case, ctrl, horizon=350.0, t_d=50.0, band_pct=3.0):
    """Levels on the grid, J, IAE and ts of the loop by Radau at rtol 1e-11 (independent plant
    model; the controller's own state-space matrices)."""
    P = plant_dict(case)
    h0, u0 = ref.equilibrium(P)
    A, B, C, D = ctrl.A, ctrl.B, ctrl.C, ctrl.D
    nz = A.shape[0]

    def rhs(t, s, d):
        h, z = s[:4], s[4:4 + nz]
        w = h - h0
        w[:2] += d
        u = u0 + C @ z + D @ w
        return np.concatenate([ref.plant_rhs(h, u, P), A @ z + B @ w, np.abs(w[:2]), u * u])

    t = np.arange(0.0, horizon + 1e-9, GRID)
    y = np.empty((t.size, 2))
    s0 = np.concatenate([h0, np.zeros(nz + 4)])
    ts = [0.0, 0.0]
    for t0, t1, d in [(0.0, t_d, np.zeros(2)), (t_d, horizon, np.ones(2))]:
        sol = solve_ivp(rhs, (t0, t1), s0, method="Radau", args=(d,), rtol=1e-11, atol=1e-12, dense_output=True)
        mask = (t >= t0) & ((t < t1) if t1 < horizon else (t <= t1))
        y[mask] = sol.sol(t[mask])[:2].T + d
        if t0 == t_d:
            fine = np.linspace(t0, t1, 350_001)
            Y = sol.sol(fine)
            for i in range(2):
                band = band_pct / 100.0 * h0[i]
                out = np.flatnonzero(np.abs(Y[i] - h0[i] + d[i]) > band)
                if out.size:
                    j = out[-1]
                    ts[i] = brentq(lambda tt: abs(sol.sol(tt)[i] - h0[i] + d[i]) - band, fine[j], fine[j + 1],  # noqa: B023 - called within this iteration
                                   xtol=1e-12) - t0
        s0 = sol.y[:, -1]
    q = s0[-4:]
    return dict(t=t, y=y, IAE=q[0] + q[1], J=q[2] + q[3], ts=np.array(ts))


def errors(sim, reference):
    m = dict(zip(METRIC_NAMES, sim.metrics))
    k = max(1, int(round(GRID / (sim.t[1] - sim.t[0]))))
    level = float(np.max(np.abs(sim.y[::k] - reference["y"])))
    return dict(level_cm=level,
                J_rel=abs(m["J1"] + m["J2"] - reference["J"]) / reference["J"],
                IAE_rel=abs(m["IAE1"] + m["IAE2"] - reference["IAE"]) / reference["IAE"],
                ts_s=float(np.max(np.abs(np.array([m["ts1"], m["ts2"]]) - reference["ts"]))))


def run_case(label, case, gains, repeats, quick):
    prob = heurtune.load_experiment("cs_folqi_qtp").problem(case)
    loop = prob.loop
    ctrl = loop.controller(gains)

    def evaluation(sc):  # what Problem.evaluate does for a simulated candidate
        c = loop.controller(gains)
        loop.stability_margin(c)
        return loop.run_scenarios(c, [sc], settling_band=prob.settling_band)

    reference = tight_reference(case, ctrl)
    rows = []
    for tol in TOLERANCES if not quick else TOLERANCES[1:4]:
        sc = Scenario(tolerance=tol, output_dt=GRID)
        sim = loop.run(ctrl, sc)
        evaluation(sc)
        rows.append(dict(case=label, method="continuous", setting=f"tolerance {tol:g}",
                         ms=best_ms(lambda: evaluation(sc), repeats), **errors(sim, reference)))  # noqa: B023 - called within this iteration
    # the rule's step for every step, without the adaptive pairs above it
    sc = Scenario(step=loop.step_plan(ctrl, Scenario(tolerance=0.005)).h.max(), output_dt=GRID)
    sim = loop.run(ctrl, sc)
    rows.append(dict(case=label, method="continuous, no pairs", setting=f"step {sc.step:g}",
                     ms=best_ms(lambda: evaluation(sc), repeats), **errors(sim, reference)))
    for dt in SAMPLE_STEPS if not quick else SAMPLE_STEPS[1:4]:
        sc = Scenario(dt=dt)
        sim = loop.run(ctrl, sc)
        evaluation(sc)
        rows.append(dict(case=label, method="sampled", setting=f"dt {dt:g}",
                         ms=best_ms(lambda: evaluation(sc), max(1, repeats // 5)), **errors(sim, reference)))  # noqa: B023 - called within this iteration
    plant = plant_dict(case)
    for method in ("LSODA", "Radau"):
        for rtol in RTOLS if not quick else RTOLS[:2]:
            def run(method=method, rtol=rtol):
                return ref.reference_loop(plant, gains, reference["t"], method=method, rtol=rtol, atol=rtol * 1e-3)
  # noqa: B023 - called within this iteration
            t0 = time.perf_counter()
            y, _ = run()
            ms = 1e3 * (time.perf_counter() - t0)
            rows.append(dict(case=label, method=method.lower(), setting=f"rtol {rtol:g}", ms=ms,
                             level_cm=float(np.max(np.abs(y - reference["y"]))), J_rel=np.nan, IAE_rel=np.nan,
                             ts_s=np.nan))
    return rows


def figure(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"continuous": "C0", "continuous, no pairs": "C1", "sampled": "C3", "lsoda": "C2", "radau": "C7"}
    markers = dict(zip(CASES, "osD^"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, key, label in [(axes[0], "level_cm", "largest level error (cm)"),
                           (axes[1], "J_rel", "relative error of J")]:
        for method, color in colors.items():
            for case, marker in markers.items():
                pts = [(r["ms"], r[key]) for r in rows if r["method"] == method and r["case"] == case
                       and np.isfinite(r[key]) and r[key] > 0]
                if pts:
                    ms, err = zip(*pts)
                    ax.loglog(ms, err, marker=marker, color=color, lw=1, ms=5,
                              label=f"{method}, {case}" if ax is axes[0] else None)
        ax.set_xlabel("ms per evaluation (one core)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].axhline(0.005, color="k", ls=":", lw=1)
    axes[1].axhline(5e-4, color="k", ls=":", lw=1)
    fig.legend(loc="lower center", ncol=4, fontsize=7, frameon=False)
    fig.suptitle("QTP loop: work against precision (dotted: the targets 0.005 cm and 0.05 %)")
    fig.tight_layout(rect=(0, 0.16, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=10, help="timings per heurtune evaluation (best is kept)")
    ap.add_argument("--quick", action="store_true", help="fewer settings (a check that the benchmark runs)")
    ap.add_argument("--out", default="results/bench", help="folder for work_precision.json and .png")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with threadpool_limits(1):
        for label, (case, gains) in CASES.items():
            rows += run_case(label, case, gains, args.repeats, args.quick)
    print(f"QTP work-precision, {cpu_name()}, one core, BLAS 1 thread; reference Radau rtol 1e-11")
    print("| case | method | setting | ms / evaluation | level error (cm) | J rel. error | IAE rel. error "
          "| ts error (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        cells = [f"{r[k]:.2e}" if np.isfinite(r[k]) else "" for k in ("level_cm", "J_rel", "IAE_rel", "ts_s")]
        print(f"| {r['case']} | {r['method']} | {r['setting']} | {r['ms']:.3g} | " + " | ".join(cells) + " |")
    (out / "work_precision.json").write_text(json.dumps({"cpu": cpu_name(), "rows": rows}, indent=1, default=float))
    figure(rows, out / "work_precision.png")
    print(f"wrote {out / 'work_precision.json'} and {out / 'work_precision.png'}")


if __name__ == "__main__":
    main()
