"""The linearised integrator (``scenario.integrator = "linearised"``) against the switching one:
accuracy and time per candidate, side by side in one process.

Run with ``python benchmarks/linearised_lane.py [--rule H_TOP KAPPA FLOOR]`` (one core, BLAS
one thread). Two tables:

* per case (the thesis' FOLQI min gains, the weakly damped FOLQI candidate, the IOLQI nmp
  loop whose tank 3 runs dry) and step rule ``(h_top, kappa, amp_floor)`` of
  ``linearised_kernels._step_level``: steps and the relative errors of IAE, J and TV and the
  settling time against the switching integrator at 0.125/16 s (itself within 1e-8 of Radau in
  IAE for these loops), beside the switching integrator at its default tolerance;
* ``cs_folqi_qtp`` min's candidate sets of ``bench_study_candidates.py`` (thesis, uniform in the
  bounds, pushed to them, visited by cuckoo search; the simulated ones) under one rule (default:
  the shipped rule of the default tolerance): the largest IAE error against the same reference
  and how many exceed 1e-4, the steps, and the milliseconds per candidate of a whole
  evaluation with each integrator (``Problem.evaluate``, designs forgotten between repeats, as
  in a study), of the switching loop within it and of the linearised form and lane.

The findings are in docs/model.md ("The linearised integrator"). Not part of ``make bench``:
``bench_study_candidates.py`` gives the evaluation times of both integrators there.
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from heurtune.objectives.qtp import linearised  # noqa: E402
from heurtune.objectives.qtp.kernels import N_METRICS  # noqa: E402

# The step rules of the first table: (h_top, kappa, amp_floor in cm s or V s); the first is the
# shipped rule at the default tolerance.
RULES = ((1.0, 0.35, 2.5e-4), (1.0, 0.25, 2.5e-4), (1.0, 0.5, 2.5e-4), (1.0, 0.35, 1e-3), (2.0, 0.35, 2.5e-4))


def run_rule(loop, ctrl, scenario, rule):
    """Metrics of the linearised integrator under ``rule``: (ok, status, steps, metrics)."""
    table = loop._scenario_table(scenario)
    form = linearised.linearised_form(ctrl, table, loop._state_op(), loop._level_per_state)
    metrics = np.empty(N_METRICS)
    empty2, empty4 = np.empty((0, 2)), np.empty((0, 4))
    status, steps = linearised.simulate(form, table, loop._level_per_state, loop._state_op(), loop.op.h,
                                        scenario.step_plan(loop.kind), 3.0, rule, metrics, 1.0, empty2, empty2,
                                        empty4)
    return form.ok, status, steps, metrics


def _median_ms(fn, repeats=30):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _rel(m, ref, idx, name):
    return m[idx[name]] / ref[idx[name]] - 1.0


def named_cases(idx):
    """The three loops of docs/model.md at each rule, against the switching loop at 0.125/16 s."""
    from qtp_cases import IOLQI_NMP, THESIS_MIN, WEAK

    from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
    from heurtune.objectives.qtp.model import preset

    print("| case | integrator | rule (h_top, kappa, floor) | steps | IAE1, IAE2 rel. | J1 rel. | TV1 rel. | ts1 (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    cases = {"FOLQI min, thesis": ("min", "folqi", THESIS_MIN), "FOLQI min, weakly damped": ("min", "folqi", WEAK),
             "IOLQI nmp": ("nmp", "iolqi", IOLQI_NMP)}
    scenario = Scenario()

    def row(label, kind, rule, steps, m, ref):
        rel = [_rel(m, ref, idx, k) for k in ("IAE1", "IAE2", "J1", "TV1")]
        print(f"| {label} | {kind} | {rule} | {steps} | {rel[0]:+.1e}, {rel[1]:+.1e} | {rel[2]:+.1e} | "
              f"{rel[3]:+.1e} | {m[idx['ts1']]:.4f} (ref. {ref[idx['ts1']]:.4f}) |")

    for label, (case, kind, gains) in cases.items():
        loop = ClosedLoop(preset(case), kind)
        ctrl = loop.controller(gains)
        ref = loop.run(ctrl, Scenario(step=0.125 / 16), record=False).metrics
        sim = loop.run(ctrl, scenario, record=False)
        row(label, "switching, default tolerance", "", sim.steps, sim.metrics, ref)
        for rule in RULES:
            ok, _, steps, m = run_rule(loop, ctrl, scenario, rule)
            row(label, "linearised" + ("" if ok else " (ill-conditioned basis)"), rule, steps, m, ref)


def study_sets(idx, n, rule):
    """cs_folqi_qtp min's candidate sets: IAE errors, steps and times of both integrators."""
    from bench_evaluate import forget_designs
    from bench_study_candidates import candidate_sets

    from heurtune.core.families import make_experiment
    from heurtune.runner.config import load_config

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        config = load_config("cs_folqi_qtp")
        prob = make_experiment(config).problem("min")
        config["scenario"]["integrator"] = "linearised"
        prob_lin = make_experiment(config).problem("min")
        sets = candidate_sets(prob, n, 1, True)
    loop = prob.loop
    scenario = prob.scenario(prob.tuning_scenario)
    tight = dataclasses.replace(scenario, step=0.125 / 16, tolerance=None)
    print(f"\ncs_folqi_qtp min, linearised rule (h_top, kappa, floor) = {rule}; IAE relative errors against the "
          "switching loop at 0.125/16 s; ms per candidate, one core")
    print("| set | n | ill-cond. | steps mean / max: linearised (switching) | max abs IAE rel. err.: linearised "
          "(switching) | > 1e-4 | evaluate ms: switching | evaluate ms: linearised | ratio | switching loop ms | "
          "linearised form + lane ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, X in sets.items():
        ctrls = [loop.controller(prob.values(x)) for x in X]
        errs, errs_s, steps, steps_s, bad = [], [], [], [], 0
        for ctrl in ctrls:
            ref = loop.run(ctrl, tight, record=False).metrics
            sim = loop.run(ctrl, scenario, record=False)
            ok, _, st, m = run_rule(loop, ctrl, scenario, rule)
            bad += not ok
            errs.append(max(abs(_rel(m, ref, idx, "IAE1")), abs(_rel(m, ref, idx, "IAE2"))))
            errs_s.append(max(abs(_rel(sim.metrics, ref, idx, "IAE1")), abs(_rel(sim.metrics, ref, idx, "IAE2"))))
            steps.append(st)
            steps_s.append(sim.steps)

        def evaluate(p, X=X):
            forget_designs(filters=True)
            p.evaluate(X)

        def switching_loops(ctrls=ctrls):
            for ctrl in ctrls:
                loop._continuous_metrics(ctrl, scenario, 3.0)

        def linearised_runs(ctrls=ctrls):
            for ctrl in ctrls:
                ctrl.__dict__.pop("_linearised_forms", None)  # the form built anew, as for a new candidate
                run_rule(loop, ctrl, scenario, rule)

        k = len(X)
        evaluate(prob_lin)  # compile / load
        ev = _median_ms(lambda: evaluate(prob), 7) / k
        ev_lin = _median_ms(lambda: evaluate(prob_lin), 7) / k
        sw, lin = (_median_ms(f, 7) / k for f in (switching_loops, linearised_runs))
        e = np.array(errs)
        print(f"| {label} | {k} | {bad} | {np.mean(steps):.0f} / {max(steps)} ({np.mean(steps_s):.0f} / "
              f"{max(steps_s)}) | {e.max():.1e} ({max(errs_s):.1e}) | {int((e > 1e-4).sum())} "
              f"({int((np.array(errs_s) > 1e-4).sum())}) | {ev:.3f} | {ev_lin:.3f} | {ev / ev_lin:.2f}x | {sw:.3f} | "
              f"{lin:.3f} |")


def main(argv=None) -> int:
    from heurtune.objectives.qtp.loop import METRIC_NAMES, Scenario
    from heurtune.runner.machine import cpu_name

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--candidates", type=int, default=40)
    ap.add_argument("--rule", type=float, nargs=3, default=linearised.step_rule(Scenario()),
                    help="h_top kappa amp_floor (default: the shipped rule at the default tolerance)")
    args = ap.parse_args(argv)
    idx = {name: i for i, name in enumerate(METRIC_NAMES)}
    print(f"CPU: {cpu_name()}, one core, BLAS one thread")
    named_cases(idx)
    study_sets(idx, args.candidates, tuple(args.rule))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
