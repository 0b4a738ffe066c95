"""The plant-family contract: what every registered family's experiments and problems must do,
as checks that run on any family given one of its experiment configs (the test suite runs them
on every shipped family and the example plugin; ``python -m heurtune.check_plugin FAMILY.py
--config EXPERIMENT.toml`` on a plugin's).

Each check takes the loaded config (a dict, as :func:`heurtune.runner.config.load_config`
gives it) and raises ``AssertionError`` with a one-line reason when the family breaks the
contract:

- ``protocol``: the experiment is an ExperimentBase with cases, and its first case's problem a
  TuningProblem with the protocol attributes (names, bounds, scenarios with ``"nominal"``, the
  tuning scenario among them, objective, constraint names);
- ``bad_candidates``: NaN, inf and far out-of-bounds candidates come back finite and infeasible,
  with reasons among FAILURE_REASONS, and ``problem(X)`` gives the same ``(f, g)``;
- ``identity``: the identity is JSON and the problem_id reproducible;
- ``report``: ``report`` and ``simulate`` have the documented columns (``t``, outputs
  ``y1 .. ym`` and inputs ``u1 .. un``, any numbers of each);
- ``robust``: ``[problem] tuning_scenarios`` (every scenario, worst case) works by config alone,
  its objective is the worst of the scenarios' and its problem_id differs from the nominal one;
- ``objectives``: ``[problem] objectives`` (two of the family's ``objective_metrics``) works by
  config alone, giving ``F`` per candidate (skipped for a family that declares none);
- ``workers``: the same seed gives the same PSO result in-process and on two workers.
"""

from __future__ import annotations

import copy
import json
import re

import numpy as np

from heurtune.core.contract import run_named_checks
from heurtune.core.engine import SearchSpace, run
from heurtune.core.evaluator import Evaluator
from heurtune.core.families import make_experiment
from heurtune.core.problem import (
    FAILED_OBJECTIVE,
    FAILURE_REASONS,
    Evaluation,
    ExperimentBase,
    TuningProblem,
    problem_fingerprint,
)

__all__ = ["CHECKS", "run_checks"]

PROTOCOL = ("case", "controller", "names", "lower", "upper", "scenarios", "tuning_scenario", "objective",
            "constraint_names")


def _problem(config: dict):
    exp = make_experiment(copy.deepcopy(config))
    assert isinstance(exp, ExperimentBase), f"the family builds {type(exp).__name__}, not an ExperimentBase"
    assert exp.cases, "the experiment has no cases"
    prob = exp.problem(exp.cases[0])
    assert isinstance(prob, TuningProblem), f"problem() returns {type(prob).__name__}, not a TuningProblem"
    return prob


def _centre(prob) -> np.ndarray:
    return 0.5 * (prob.lower + prob.upper)


def check_protocol(config):
    prob = _problem(config)
    missing = [a for a in PROTOCOL if not hasattr(prob, a)]
    assert not missing, f"the problem lacks {', '.join(missing)}"
    assert prob.dim == len(prob.names) == prob.lower.size == prob.upper.size, "names and bounds differ in length"
    assert np.all(prob.lower <= prob.upper), "a lower bound exceeds its upper bound"
    assert "nominal" in prob.scenarios, "the scenarios have no 'nominal'"
    assert prob.tuning_scenario in prob.scenarios, "the tuning scenario is not among the scenarios"


def check_bad_candidates(config):
    prob = _problem(config)
    lo, hi = prob.lower, prob.upper
    X = np.vstack([np.full(prob.dim, np.nan), np.full(prob.dim, np.inf), lo - 1e6 * (hi - lo + 1),
                   hi + 1e6 * (hi - lo + 1), -np.abs(hi) * 1e9])
    ev = prob.evaluate(X)
    assert isinstance(ev, Evaluation), f"evaluate returns {type(ev).__name__}, not an Evaluation"
    assert ev.f.shape == (5,) and ev.g.shape == (5, len(prob.constraint_names)), "f or g has the wrong shape"
    assert np.all(np.isfinite(ev.f)) and np.all(np.isfinite(ev.g)), "a bad candidate got a non-finite f or g"
    assert not ev.feasible[:2].any(), "a NaN or inf candidate is feasible"
    assert set(ev.reason[:2]) <= set(FAILURE_REASONS) and all(ev.reason[:2]), \
        f"NaN and inf candidates need a reason among {', '.join(FAILURE_REASONS)}"
    failed = ev.reason != ""
    assert np.all(ev.f[failed] == FAILED_OBJECTIVE), "a failed candidate's f is not FAILED_OBJECTIVE"
    assert np.all(ev.g[failed].max(axis=1) > 0), "a failed candidate has no violated constraint"
    f, g = prob(X)
    assert np.array_equal(f, ev.f) and np.array_equal(g, ev.g), "problem(X) differs from evaluate(X)"


def check_identity(config):
    prob = _problem(config)
    text = json.dumps(prob.identity(), sort_keys=True, default=list)
    assert text, "the identity is empty"
    assert problem_fingerprint(prob) == problem_fingerprint(_problem(config)), "the problem_id is not reproducible"


def check_report(config):
    prob = _problem(config)
    x = _centre(prob)
    table = prob.report(x, ["nominal"])
    assert list(table.index) == ["nominal"], "report's index is not the scenario names"
    assert {"f", "feasible", "reason"} <= set(table.columns), "report lacks f, feasible or reason"
    if prob.report_columns is not None:
        missing = set(prob.report_columns) - set(table.columns)
        assert not missing, f"report lacks its report_columns {sorted(missing)}"
    if table.loc["nominal", "reason"] == "":
        df = prob.simulate(x, "nominal")
        assert "t" in df.columns and len(df) > 1, "simulate lacks t or gives one row"
        for prefix in ("y", "u"):
            numbers = sorted(int(m.group(1)) for m in (re.fullmatch(rf"{prefix}(\d+)", str(c)) for c in df.columns)
                             if m)
            assert numbers and numbers == list(range(1, len(numbers) + 1)), \
                f"simulate's {prefix} columns must be {prefix}1 .. {prefix}n, got {numbers}"


def check_robust(config):
    nominal = _problem(config)
    names = list(nominal.scenarios)
    robust_config = copy.deepcopy(config)
    table = robust_config.setdefault("problem", {})
    table.pop("tuning_scenario", None)
    table.update(tuning_scenarios=names, aggregate="worst")
    prob = _problem(robust_config)
    assert prob.robust is not None and list(prob.robust.scenarios) == names, \
        "problem.tuning_scenarios did not make a robust problem"
    X = np.vstack([_centre(prob), prob.lower + 0.25 * (prob.upper - prob.lower)])
    worst = np.max([prob.evaluate(X, s).f for s in names], axis=0)
    assert np.array_equal(prob.evaluate(X).f, worst), "the robust objective is not the worst scenario's"
    assert problem_fingerprint(prob) != problem_fingerprint(nominal), \
        "robust and nominal tuning share a problem_id"


def check_objectives(config):
    prob = _problem(config)
    metrics = getattr(prob, "objective_metrics", None)
    if prob.objective_names is not None or not metrics:
        return  # several objectives already, or a family without declared objectives
    names = [prob.objective] + [n for n in metrics if n != prob.objective][:1]
    assert len(names) == 2, "objective_metrics needs at least two objectives"
    mo_config = copy.deepcopy(config)
    mo_config.setdefault("problem", {}).update(objectives=names, reference_point=[1e9, 1e9])
    mo_config["optimisers"] = [{"name": "nsga2", "settings": {"n": 8}, "max_evals": 16}]
    mo = _problem(mo_config)
    assert mo.objective_names == tuple(names), "problem.objectives did not give the problem its objectives"
    ev = mo.evaluate(np.vstack([_centre(mo), mo.lower]))
    assert ev.F is not None and ev.F.shape == (2, 2), "evaluate gives no F (n, 2)"
    assert np.allclose(ev.F[:, 0], ev.f), "F's first objective differs from f"
    assert problem_fingerprint(mo) != problem_fingerprint(prob), "one and two objectives share a problem_id"


def check_workers(config):
    prob = _problem(config)
    space = SearchSpace(prob.lower, prob.upper)
    seed = np.random.SeedSequence(2026, spawn_key=(1,))
    results = []
    for n_jobs in (1, 2, 1):
        with Evaluator(prob, n_jobs=n_jobs) as ev:
            results.append(run("pso", ev, space, settings={"n": 6}, seed=seed, max_epochs=2))
    a, b, c = results
    assert np.array_equal(a.x, b.x) and a.f == b.f and a.n_evals == b.n_evals, "two workers gave another result"
    assert np.array_equal(a.x, c.x) and a.f == c.f, "the same seed gave another result"
    assert np.isfinite(a.f), "the result is not finite"


CHECKS = {"protocol": check_protocol, "bad_candidates": check_bad_candidates, "identity": check_identity,
          "report": check_report, "robust": check_robust, "objectives": check_objectives, "workers": check_workers}


def run_checks(config: dict, checks=None) -> list:
    """``[(check, passed, reason), ...]`` of :data:`CHECKS` (or the names in ``checks``) on the
    family of ``config``; a check that raises anything counts as failed, with its message.

    Parameters
    ----------
    config : dict
        A loaded experiment config of the family.
    checks : iterable of str, optional
        The names of the checks to run; all by default.

    Returns
    -------
    list of (str, bool, str)
    """
    return run_named_checks({name: CHECKS[name] for name in checks or CHECKS}, config)
