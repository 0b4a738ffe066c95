"""The continuous loop's step rule on random candidates: the error it leaves, and what a longer
step would leave.

For each case of an experiment, draws candidates in the experiment's bounds (half uniform,
half pushed to the bounds as optimisers push them), keeps the stable ones and simulates each
under the tuning scenario:

* at the step the rule picks (``tolerance = 0.005``: the structure's 0.125 s, halved by
  ``continuous.feedback_step`` while the plant under the effective static feedback is fast);
* at the structure's fixed step, the rule of earlier versions;
* at twice that step, to show what a rule that lengthened steps would risk;
* at 0.02 s, the reference (within 1e-7 cm of scipy Radau at rtol 1e-11 on the cases of
  tests/objectives/qtp/test_continuous.py).

It prints, per case, the largest level error of each, how many candidates exceed the tolerance,
how many steps the rule shortened, and the spectral radius ``rho`` of the worst candidates; and,
for the rule with its adaptive pairs and for the rule's step alone, the largest level, IAE, J
and ts errors, how many candidates exceed the issue's targets (0.005 cm, 0.05 %, 0.005 s), and
the time of a simulation with and without the pairs (median of three, per candidate).
Run with ``python benchmarks/step_rule.py [--experiment cs_folqi_qtp] [--samples 100]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.qtp import continuous  # noqa: E402

REFERENCE_STEP = 0.02


def draw(rng, lower, upper):
    """A candidate: uniform in the bounds, or (half the time) with each coordinate at a bound
    with probability 0.7."""
    u = rng.random(lower.size)
    if rng.random() < 0.5:
        at_bound = rng.random(lower.size) < 0.7
        u = np.where(at_bound, (rng.random(lower.size) < 0.5).astype(float), u)
    return lower + (upper - lower) * u


# metrics compared: IAE and J of both outputs (relative), ts of both (absolute, s)
_IAE, _J, _TS = (6, 7), (12, 13), (2, 3)


def level_error(loop, ctrl, scenario, ref):
    sim = loop.run(ctrl, scenario)
    if sim.diverged or not np.all(np.isfinite(sim.h)):
        return np.inf
    return float(np.max(np.abs(sim.h - ref.h)))


def metric_errors(loop, ctrl, scenario, ref):
    """Largest level error (cm), largest relative IAE and J error, largest ts error (s), and
    the median time of three runs without records (ms)."""
    sim = loop.run(ctrl, scenario)
    if sim.diverged or not np.all(np.isfinite(sim.h)):
        return np.inf, np.inf, np.inf, np.inf, np.nan
    m, r = sim.metrics, ref.metrics
    rel = [abs(m[i] / r[i] - 1.0) if r[i] != 0 else abs(m[i]) for i in _IAE + _J]
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        loop.run(ctrl, scenario, record=False)
        times.append(time.perf_counter() - t0)
    return (float(np.max(np.abs(sim.h - ref.h))), max(rel[:2]), max(rel[2:]),
            max(abs(m[i] - r[i]) for i in _TS), 1e3 * float(np.median(times)))


def study_case(prob, samples, rng, tolerance):
    loop, sc = prob.loop, prob.scenario(prob.tuning_scenario)
    h_fixed = sc.continuous_step_for(loop.kind)
    rows = []
    for _ in range(samples):
        x = draw(rng, np.asarray(prob.lower, float), np.asarray(prob.upper, float))
        ctrl, reason, _ = prob._design(x)
        if ctrl is None:
            continue
        ref = loop.run(ctrl, dataclasses.replace(sc, tolerance=None, step=REFERENCE_STEP))
        if ref.diverged:
            continue
        cc = continuous.ContinuousController.from_linear(ctrl)
        h_rule = float(loop.step_plan(ctrl, sc, cc).h.max())
        rho = float(np.max(np.abs(np.linalg.eigvals(
            loop.A + loop.B / sc.uncertainty @ continuous.folded_feedback(cc, h_fixed)))))
        errs = [level_error(loop, ctrl, sc, ref)]
        for h in (h_fixed, 2 * h_fixed):
            errs.append(level_error(loop, ctrl, dataclasses.replace(sc, tolerance=None, step=h), ref))
        adaptive = metric_errors(loop, ctrl, sc, ref)
        plain = metric_errors(loop, ctrl, dataclasses.replace(sc, tolerance=None, step=h_rule), ref)
        rows.append((h_rule, rho, *errs, *adaptive, *plain))
    return h_fixed, np.array(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--experiment", default="cs_folqi_qtp")
    ap.add_argument("--samples", type=int, default=100, help="candidates drawn per case")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    exp = heurtune.load_experiment(args.experiment)
    rng = np.random.default_rng(args.seed)
    tol = continuous.DEFAULT_TOLERANCE
    print(f"{args.experiment}: level error (cm) against the loop at {REFERENCE_STEP} s, tolerance {tol} cm")
    for case in exp.cases:
        prob = exp.problem(case)
        h_fixed, rows = study_case(prob, args.samples, rng, tol)
        if rows.size == 0:
            print(f"{case}: no stable candidate among {args.samples}")
            continue
        h_rule, rho, e_rule, e_fixed, e_double = rows.T[:5]
        adaptive, plain = rows[:, 5:10], rows[:, 10:15]
        print(f"{case}: {rows.shape[0]} stable candidates of {args.samples}; the rule shortened "
              f"{int(np.sum(h_rule < h_fixed))} (steps {sorted(set(np.round(h_rule, 6).tolist()))} s)")
        for label, e in (("rule", e_rule), (f"fixed {h_fixed:g} s", e_fixed), (f"fixed {2 * h_fixed:g} s", e_double)):
            print(f"  {label:>14}: largest {np.max(e):.2e}, median {np.median(e):.2e}, "
                  f"over the tolerance {int(np.sum(e > tol))}")
        for label, m in (("rule", adaptive), ("rule's step", plain)):
            print(f"  {label:>14}: largest level {np.max(m[:, 0]):.2e} cm, IAE {np.max(m[:, 1]):.2e}, J "
                  f"{np.max(m[:, 2]):.2e} (relative), ts {np.max(m[:, 3]):.2e} s; over: level "
                  f"{int(np.sum(m[:, 0] > tol))}, IAE {int(np.sum(m[:, 1] > 5e-4))}, J {int(np.sum(m[:, 2] > 5e-4))}, "
                  f"ts {int(np.sum(m[:, 3] > 5e-3))}; median {np.nanmedian(m[:, 4]):.3f} ms, mean "
                  f"{np.nanmean(m[:, 4]):.3f} ms")
        ratio = plain[:, 4] / adaptive[:, 4]
        print(f"  time at the rule's step / with adaptive pairs: median {np.nanmedian(ratio):.2f}, "
              f"smallest {np.nanmin(ratio):.2f}, largest {np.nanmax(ratio):.2f}")
        worst = np.argsort(-e_fixed)[:3]
        print("  worst at the fixed step: " + "; ".join(
            f"rho {rho[k]:.2f} 1/s, fixed {e_fixed[k]:.1e}, rule {e_rule[k]:.1e} at {h_rule[k]:g} s" for k in worst))
        ok = e_double <= tol
        print(f"  at {2 * h_fixed:g} s: {int(ok.sum())} of {ok.size} within the tolerance; rho of those "
              f"that are not: {np.round(np.sort(rho[~ok]), 2).tolist()[:12]}")


if __name__ == "__main__":
    main()
