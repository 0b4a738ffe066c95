"""Robust tuning (heurtune.core.robust): aggregation over tuning scenarios against hand-made
evaluations and against per-scenario evaluations of QTP and TITO problems."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.core.families import make_experiment
from heurtune.core.problem import FAILED_OBJECTIVE, FAILED_VIOLATION, Evaluation, problem_fingerprint
from heurtune.core.robust import aggregate_evaluations
from heurtune.runner.config import load_config
from heurtune.runner.experiment import problem_id, run_experiment


def _ev(f, g, reason, metrics=None):
    f = np.asarray(f, float)
    g = np.asarray(g, float).reshape(len(f), -1)
    reason = np.asarray(reason, dtype=object)
    metrics = np.arange(len(f), dtype=float)[:, None] + 0.0 if metrics is None else np.asarray(metrics, float)
    feasible = (reason == "") & np.all(g <= 0, axis=1)
    return Evaluation(f, g, feasible, metrics, ("m",), ("c1", "c2"), reason)


# Three scenarios, four candidates; candidate 3 fails (unstable) in the second scenario only.
A = _ev(
    [1.0, 5.0, 2.0, 4.0],
    [[-0.5, -0.1], [0.2, -1.0], [-0.3, -0.3], [-0.1, -0.1]],
    ["", "", "", ""],
    [[10], [11], [12], [13]],
)
B = _ev([3.0, 1.0, 2.0, FAILED_OBJECTIVE], [[-0.2, -0.4], [-0.5, -0.5], [0.1, -0.9], [FAILED_VIOLATION * 2] * 2],
        ["", "", "", "unstable"], [[20], [21], [22], [np.nan]])
C = _ev(
    [2.0, 3.0, 8.0, 1.0],
    [[-0.1, -0.9], [-0.1, 0.3], [-0.2, -0.2], [-0.1, -0.1]],
    ["", "", "", "diverged"],
    [[30], [31], [32], [np.nan]],
)


def test_worst_case_objective_constraints_and_reasons():
    ev = aggregate_evaluations([A, B, C], "worst")
    # the worst case picks a scenario's value: no arithmetic
    assert_exact(ev.f, [3.0, 5.0, 8.0, FAILED_OBJECTIVE])
    assert_exact(ev.g[:3], [[-0.1, -0.1], [0.2, 0.3], [0.1, -0.2]])
    assert ev.g[3].min() == FAILED_VIOLATION * 2  # the failed scenario's (graded) violation (exact: picked)
    assert list(ev.reason) == ["", "", "", "unstable"]  # the first failing scenario, in order
    assert list(ev.feasible) == [True, False, False, False]
    assert_exact(ev.metrics[:3, 0], [20, 11, 32])  # from the worst scenario
    assert np.isnan(ev.metrics[3, 0])


def test_mean_and_cvar():
    mean = aggregate_evaluations([A, B, C], "mean")
    np.testing.assert_allclose(mean.f[:3], [2.0, 3.0, 4.0])
    # CVaR at level 0.5 over 3 scenarios: the mean of the ceil(1.5) = 2 largest values
    cvar = aggregate_evaluations([A, B, C], "cvar", 0.5)
    np.testing.assert_allclose(cvar.f[:3], [2.5, 4.0, 5.0])
    np.testing.assert_allclose(aggregate_evaluations([A, B, C], "cvar", 0.0).f[:3], mean.f[:3])
    np.testing.assert_allclose(aggregate_evaluations([A, B, C], "cvar", 0.9).f[:3], [3.0, 5.0, 8.0])
    for ev in (mean, cvar):  # constraints and failures never average
        assert_exact(ev.g[:3], [[-0.1, -0.1], [0.2, 0.3], [0.1, -0.2]])  # the worst, picked
        assert ev.f[3] == FAILED_OBJECTIVE and ev.reason[3] == "unstable"  # exact: the constant


def test_single_scenario_is_that_scenario():
    ev = aggregate_evaluations([A], "worst")
    assert_exact(ev.f, A.f)
    assert_exact(ev.g, A.g)


@pytest.mark.parametrize("name", ["robust_cs_folqi_qtp", "robust_ga_pi_ccts"])
def test_robust_problem_equals_its_scenarios_aggregated(name):
    exp = heurtune.load_experiment(name)
    prob = exp.problem(exp.cases[0])
    rng = np.random.default_rng(4)
    X = prob.lower + rng.random((8, prob.dim)) * (prob.upper - prob.lower)
    if name == "robust_ga_pi_ccts":
        X[0] = prob.baseline("gpm")  # a stable design, so that some candidates simulate
    ev = prob.evaluate(X)
    per = [prob.evaluate(X, s) for s in prob.robust.scenarios]
    ok = ~np.any([e.reason != "" for e in per], axis=0)
    assert ok.any()
    # the robust problem evaluates its scenarios together (one kernel, several scenarios), then takes
    # the largest: each scenario's numbers as its own evaluation gives them
    assert_same_bits(ev.f[ok], np.max([e.f for e in per], axis=0)[ok], because="shared kernel")
    assert_same_bits(ev.g, np.max([e.g for e in per], axis=0), because="shared kernel")
    assert_exact(ev.feasible, np.all([e.feasible for e in per], axis=0))
    assert np.all(ev.f[~ok] == FAILED_OBJECTIVE) and np.all(ev.reason[~ok] != "")  # exact: the constant


def test_robust_problems_have_their_own_problem_id():
    nominal, robust = heurtune.load_experiment("cs_folqi_qtp"), heurtune.load_experiment("robust_cs_folqi_qtp")
    assert problem_id(nominal, "min") != problem_id(robust, "min")
    assert robust.problem("min").identity()["robust"] == {
        "scenarios": ["nominal", "-30%", "+30%"],
        "aggregate": "worst",
    }
    assert "robust" not in nominal.problem("min").identity()  # earlier problem ids unchanged


@pytest.mark.parametrize(
    "problem, message",
    [
        (
            {"tuning_scenarios": ["nominal", "worst"]},
            r"tuning_scenarios: unknown scenario 'worst'; allowed: nominal, -30%, \+30%",
        ),
        ({"aggregate": "worst"}, "problem.aggregate needs problem.tuning_scenarios"),
        ({"tuning_scenarios": ["-30%", "+30%"], "tuning_scenario": "nominal"}, "tuning_scenario must be one of"),
        ({"tuning_scenarios": ["-30%", "-30%"]}, "must name distinct scenarios"),
        ({"tuning_scenarios": ["-30%"], "cvar_level": 0.5}, "cvar_level needs problem.aggregate = 'cvar'"),
        ({"tuning_scenarios": ["-30%"], "aggregate": "cvar", "cvar_level": 1.0}, r"cvar_level must lie in \[0, 1\)"),
    ],
)
def test_robust_config_errors_are_one_line(problem, message):
    config = load_config("cs_folqi_qtp")
    config["problem"] = {k: v for k, v in config["problem"].items() if k != "tuning_scenario"}
    config["problem"].update(problem)
    with pytest.raises(ConfigError, match=message) as info:
        make_experiment(config)
    assert "\n" not in str(info.value)


def test_robust_smoke_run_reports_the_aggregated_status(tmp_path):
    out = run_experiment("robust_cs_folqi_qtp", smoke=True, out=tmp_path / "r", figures=False)
    runs = pd.read_parquet(out / "runs.parquet")
    exp = heurtune.load_experiment("robust_cs_folqi_qtp")
    for _, r in runs.iterrows():
        prob = exp.problem(r["case"])
        ev = prob.evaluate(np.array([r[n] for n in prob.names]))
        # the best candidate again, alone, on this CPU: the run evaluated it among others
        assert_same_bits(r["best_f"], ev.f[0], because="shared kernel")
        assert r["feasible"] == ev.feasible[0]
        expected = "failed" if ev.reason[0] else ("feasible" if ev.feasible[0] else "infeasible")
        assert r["status"] == expected
        assert r["problem_id"] == problem_fingerprint(prob)


def test_qtp_scenarios_together_equal_one_by_one():
    """The QTP designs, checks and discretises a candidate's controller once for all its
    scenarios; every number equals the scenario's own evaluation."""
    prob = heurtune.load_experiment("robust_cs_folqi_qtp").problem("min")
    rng = np.random.default_rng(5)
    X = prob.lower + rng.random((12, prob.dim)) * (prob.upper - prob.lower)
    X[0] = np.nan
    good = prob.parse("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,"
                      "Ki2=7.1716,alpha1=0.9814,alpha2=0.8437")  # the thesis' CS/FOLQI gains
    X[1:4] = good * rng.uniform(0.95, 1.05, (3, prob.dim))
    names = ["nominal", "-30%", "+30%"]
    for together, name in zip(prob.evaluate_scenarios(X, names), names):
        alone = prob.evaluate(X, name)
        for field in ("f", "g", "metrics", "feasible"):
            assert_same_bits(getattr(together, field), getattr(alone, field), because="shared kernel")
        assert list(together.reason) == list(alone.reason)
    assert {"invalid_parameter", ""} <= set(prob.evaluate(X).reason)


@pytest.mark.parametrize("model", ["qtp", "qtp_bond_graph"])
def test_qtp_kernel_call_for_several_scenarios_equals_one_call_each(model):
    """ClosedLoop.run_scenarios: one kernel call for scenarios that share dt, horizon and the
    form of their noise (here uncertainty, physical limits, saturation, disturbances), one
    call each otherwise (a noisy scenario); every metric equals ClosedLoop.run's."""
    import dataclasses

    config = load_config("cs_folqi_qtp")
    config["plant"]["model"] = model
    config["controller"]["sample_time"] = 0.01  # the sampled loop (the continuous one runs scenarios alone)
    prob = make_experiment(config).problem("min")
    x = prob.parse("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,Ki2=7.1716,"
                   "alpha1=0.9814,alpha2=0.8437")
    ctrl = prob.loop.controller(prob.values(x))
    base = prob.scenario("nominal")
    scenarios = [base, prob.scenario("+30%"), prob.scenario("-30%"),
                 dataclasses.replace(base, limits="physical"),
                 dataclasses.replace(base, saturation=(1.0, 4.0), input_disturbance=(0.2, -0.1))]
    for group in (scenarios, scenarios[:2] + [dataclasses.replace(base, noise_sd=0.01, noise_seed=3)]):
        together = prob.loop.run_scenarios(ctrl, group, settling_band=3.0)
        for sc, (diverged, metrics) in zip(group, together):
            alone = prob.loop.run(ctrl, sc, settling_band=3.0, record=False)
            assert diverged == alone.diverged
            assert_same_bits(metrics, alone.metrics, because="shared kernel")
