"""Contract tests applied to every registered plant family (shipped and the example plugin).

A family passes by registering: its problems take bad candidates without raising (finite,
infeasible, with a reason), describe themselves reproducibly (identity, problem_id), simulate
and report with the documented columns, and give the same optimisation result for the same
seed whether evaluated in-process or on two workers.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from heurtune.core.engine import SearchSpace, run
from heurtune.core.evaluator import Evaluator
from heurtune.core.families import families, get_family, make_experiment
from heurtune.core.problem import (
    FAILED_OBJECTIVE,
    FAILURE_REASONS,
    Evaluation,
    ExperimentBase,
    TuningProblem,
    problem_fingerprint,
)
from heurtune.runner.config import list_experiments, load_config

ROOT = Path(__file__).resolve().parents[2]
PLUGIN_EXAMPLE = ROOT / "experiments" / "example_plugin_plant.toml"


def _examples() -> dict:
    """One shipped experiment per plant family: {family name: config name or path}."""
    if PLUGIN_EXAMPLE.is_file():
        load_config(str(PLUGIN_EXAMPLE))  # registers the plugin family
    out = {}
    for name in list_experiments():
        cfg = load_config(name)
        family = get_family(cfg.get("plant", {}).get("model", "qtp")).name
        out.setdefault(family, name)
    if PLUGIN_EXAMPLE.is_file():
        cfg = load_config(str(PLUGIN_EXAMPLE))
        family = get_family(cfg["plant"]["model"]).name
        out[family] = str(PLUGIN_EXAMPLE)
    return out


EXAMPLES = _examples()


def test_every_registered_family_has_an_example_experiment():
    assert {f.name for f in families()} <= set(EXAMPLES), "a family without an experiment cannot be contract-tested"
    assert {"qtp", "tito"} <= set(EXAMPLES)


@pytest.fixture(scope="module", params=sorted(EXAMPLES))
def problem(request):
    exp = make_experiment(load_config(EXAMPLES[request.param]))
    assert isinstance(exp, ExperimentBase)
    prob = exp.problem(exp.cases[0])
    assert isinstance(prob, TuningProblem)
    return prob


def test_problem_declares_the_protocol_attributes(problem):
    for attr in ("case", "controller", "names", "lower", "upper", "scenarios", "tuning_scenario", "objective",
                 "constraint_names"):
        assert hasattr(problem, attr), attr
    assert problem.dim == len(problem.names) == problem.lower.size == problem.upper.size
    assert np.all(problem.lower <= problem.upper)
    assert problem.tuning_scenario in problem.scenarios and "nominal" in problem.scenarios


def test_bad_candidates_are_finite_and_infeasible(problem):
    lo, hi = problem.lower, problem.upper
    X = np.vstack([np.full(problem.dim, np.nan), np.full(problem.dim, np.inf), lo - 1e6 * (hi - lo + 1),
                   hi + 1e6 * (hi - lo + 1), -np.abs(hi) * 1e9])
    ev = problem.evaluate(X)
    assert isinstance(ev, Evaluation)
    assert ev.f.shape == (5,) and ev.g.shape == (5, len(problem.constraint_names))
    assert np.all(np.isfinite(ev.f)) and np.all(np.isfinite(ev.g))
    assert not ev.feasible[:2].any()
    assert set(ev.reason[:2]) <= set(FAILURE_REASONS) and all(ev.reason[:2])
    failed = ev.reason != ""
    assert np.all(ev.f[failed] == FAILED_OBJECTIVE) and np.all(ev.g[failed].max(axis=1) > 0)
    f, g = problem(X)
    assert np.array_equal(f, ev.f) and np.array_equal(g, ev.g)


def test_identity_is_json_and_reproducible(problem):
    text = json.dumps(problem.identity(), sort_keys=True, default=list)
    assert text and problem_fingerprint(problem) == problem_fingerprint(problem)


def test_simulate_and_report_have_the_documented_columns(problem):
    x = 0.5 * (problem.lower + problem.upper)
    table = problem.report(x, ["nominal"])
    assert list(table.index) == ["nominal"] and {"f", "feasible", "reason"} <= set(table.columns)
    if problem.report_columns is not None:
        assert set(problem.report_columns) <= set(table.columns)
    if table.loc["nominal", "reason"] == "":
        df = problem.simulate(x, "nominal")
        assert {"t", "y1", "y2", "u1", "u2"} <= set(df.columns) and len(df) > 1


def test_same_seed_same_result_in_process_and_on_two_workers(problem):
    space = SearchSpace(problem.lower, problem.upper)
    seed = np.random.SeedSequence(2026, spawn_key=(1,))
    results = []
    for n_jobs in (1, 2, 1):
        with Evaluator(problem, n_jobs=n_jobs) as ev:
            res = run("pso", ev, space, settings={"n": 6}, seed=seed, max_epochs=2)
        results.append(res)
    a, b, c = results
    assert np.array_equal(a.x, b.x) and a.f == b.f and a.n_evals == b.n_evals
    assert np.array_equal(a.x, c.x) and a.f == c.f
    assert np.isfinite(a.f)
