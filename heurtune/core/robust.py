"""Robust tuning: one candidate judged over several tuning scenarios at once.

``[problem] tuning_scenarios = ["-30%", "nominal", "+30%"]`` with ``aggregate = "worst"``
(default), ``"mean"`` or ``"cvar"`` (``cvar_level``: the mean of the worst ``1 - level``
fraction of the scenarios, at least one) makes a problem's objective the aggregate of its
per-scenario objectives. The constraints must hold in every tuning scenario: each constraint
column is its worst (largest) value over the scenarios, and a candidate that fails (unstable,
diverging, undesignable) in any scenario fails, with the reason of the first scenario (in the
listed order) where it fails. This module knows no plant: a family's problem evaluates each
scenario, :func:`aggregate_evaluations` combines them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.core.problem import FAILED_OBJECTIVE, Evaluation

__all__ = ["AGGREGATES", "RobustTuning", "aggregate_evaluations", "robust_tuning", "apply_tuning", "ROBUST_SCHEMA"]

AGGREGATES = ("worst", "mean", "cvar")
DEFAULT_CVAR_LEVEL = 0.5
# The keys of a family's [problem] table that set robust tuning (merged into its schema).
ROBUST_SCHEMA = {"tuning_scenarios": ("list", str), "aggregate": AGGREGATES, "cvar_level": (int, float)}


def _tail_count(n_scenarios: int, level: float) -> int:
    """How many of the worst scenarios CVaR at ``level`` averages (at least one)."""
    return max(1, math.ceil((1.0 - level) * n_scenarios - 1e-12))


def aggregate_evaluations(evaluations, aggregate: str = "worst", level: float = DEFAULT_CVAR_LEVEL) -> Evaluation:
    """Combine the evaluations of one batch under several scenarios into one.

    Parameters
    ----------
    evaluations : sequence of Evaluation
        One per scenario, for the same candidates, in the scenarios' order.
    aggregate : {"worst", "mean", "cvar"}
        How the objective combines over the scenarios: the largest, the mean, or the mean of
        the ``ceil((1 - level) * S)`` largest values.
    level : float
        The CVaR level in [0, 1) (``aggregate = "cvar"`` only).

    Returns
    -------
    Evaluation
        ``f`` aggregated; ``g`` the elementwise largest over the scenarios; ``feasible`` when
        every scenario is; ``reason`` the first non-empty reason over the scenarios (a failed
        candidate keeps ``FAILED_OBJECTIVE``); ``metrics`` those of the scenario where the
        candidate's objective is largest (the first failing one for a failed candidate).
    """
    if aggregate not in AGGREGATES:
        raise ConfigError(f"unknown aggregate {aggregate!r}; allowed: {', '.join(AGGREGATES)}")
    evaluations = list(evaluations)
    if not evaluations:
        raise ConfigError("robust tuning needs at least one scenario")
    F = np.stack([e.f for e in evaluations])           # (S, n)
    G = np.stack([e.g for e in evaluations])           # (S, n, m)
    R = np.stack([e.reason for e in evaluations])      # (S, n)
    n = F.shape[1]
    failed = R != ""
    any_failed = failed.any(axis=0)
    first_failed = np.argmax(failed, axis=0)
    which = np.where(any_failed, first_failed, np.argmax(F, axis=0))
    reason = R[which, np.arange(n)]
    f = np.where(any_failed, FAILED_OBJECTIVE, _combine(F, aggregate, level))
    g = G.max(axis=0)
    feasible = np.all(np.stack([e.feasible for e in evaluations]), axis=0)
    metrics = np.stack([e.metrics for e in evaluations])[which, np.arange(n)]
    first = evaluations[0]
    objectives = None
    if first.F is not None:  # several objectives: each aggregated the same way
        objectives = np.where(any_failed[:, None], FAILED_OBJECTIVE,
                              _combine(np.stack([e.F for e in evaluations]), aggregate, level))
    return Evaluation(f, g, feasible, metrics, first.metric_names, first.constraint_names, reason,
                      objectives, first.objective_names)


def _combine(values: np.ndarray, aggregate: str, level: float) -> np.ndarray:
    """Aggregate ``values`` (S, ...) over its first axis (the scenarios)."""
    if aggregate == "worst":
        return values.max(axis=0)
    if aggregate == "mean":
        return values.mean(axis=0)
    k = _tail_count(values.shape[0], level)
    return np.sort(values, axis=0)[-k:].mean(axis=0)


@dataclasses.dataclass(frozen=True)
class RobustTuning:
    """The tuning scenarios of a problem and how its objective aggregates over them."""

    scenarios: tuple
    aggregate: str = "worst"
    level: float = DEFAULT_CVAR_LEVEL

    def evaluate(self, problem, X, **kwargs) -> Evaluation:
        """``problem.evaluate_scenarios(X, scenarios)``, aggregated."""
        return aggregate_evaluations(
            problem.evaluate_scenarios(X, self.scenarios, **kwargs), self.aggregate, self.level
        )

    def identity(self) -> dict:
        """What enters the problem_id."""
        out = dict(scenarios=list(self.scenarios), aggregate=self.aggregate)
        if self.aggregate == "cvar":
            out["level"] = self.level
        return out


def robust_tuning(problem: dict, scenarios, where: str) -> RobustTuning | None:
    """The robust tuning a config's ``[problem]`` table asks for, or None.

    Parameters
    ----------
    problem : dict
        The config's ``[problem]`` table: ``tuning_scenarios``, ``aggregate``, ``cvar_level``
        (and ``tuning_scenario``, which must then be one of ``tuning_scenarios``).
    scenarios : collection of str
        The experiment's scenario names.
    where : str
        Prefix of the one-line errors (the experiment's name).

    Returns
    -------
    RobustTuning or None
        None when the table asks for no robust tuning.
    """
    names = problem.get("tuning_scenarios")
    if names is None:
        for key in ("aggregate", "cvar_level"):
            if key in problem:
                raise ConfigError(f"{where}: problem.{key} needs problem.tuning_scenarios")
        return None
    if not names or len(set(names)) != len(names):
        raise ConfigError(f"{where}: problem.tuning_scenarios must name distinct scenarios, got {names}")
    unknown = [s for s in names if s not in scenarios]
    if unknown:
        raise ConfigError(f"{where}: problem.tuning_scenarios: unknown scenario {unknown[0]!r}; "
                          f"allowed: {', '.join(scenarios)}")
    if problem.get("tuning_scenario", names[0]) not in names:
        raise ConfigError(f"{where}: problem.tuning_scenario must be one of problem.tuning_scenarios "
                          f"({', '.join(names)})")
    aggregate = problem.get("aggregate", "worst")
    if aggregate not in AGGREGATES:
        raise ConfigError(f"{where}: problem.aggregate: got {aggregate!r}; allowed: {', '.join(AGGREGATES)}")
    if "cvar_level" in problem and aggregate != "cvar":
        raise ConfigError(f"{where}: problem.cvar_level needs problem.aggregate = 'cvar'")
    level = float(problem.get("cvar_level", DEFAULT_CVAR_LEVEL))
    if not 0.0 <= level < 1.0:
        raise ConfigError(f"{where}: problem.cvar_level must lie in [0, 1), got {level}")
    return RobustTuning(tuple(names), aggregate, level)


def apply_tuning(experiment, prob):
    """The config's ``[problem] tuning_scenarios`` (with ``aggregate``, ``cvar_level``) and
    ``objectives`` (with ``reference_point``, ``decision_weights``) on a family's problem, where
    the family did not set them itself: checked against the problem's scenarios and its
    ``objective_metrics`` (one-line ConfigErrors). Every registered family's ``problem`` passes
    its problems through this (:func:`heurtune.core.families.register_family`).

    Parameters
    ----------
    experiment : ExperimentBase
        The experiment whose config is read.
    prob : TuningProblem
        One of its problems.

    Returns
    -------
    TuningProblem
        ``prob``, tuned as the config asks.
    """
    table = getattr(experiment, "config", {}).get("problem", {})
    name = getattr(experiment, "name", "experiment")
    if prob.robust is None and "tuning_scenarios" in table:
        prob.robust = robust_tuning(table, prob.scenarios, name)
        if prob.tuning_scenario not in prob.robust.scenarios:
            raise ConfigError(f"{name}: problem.tuning_scenario must be one of problem.tuning_scenarios "
                              f"({', '.join(prob.robust.scenarios)})")
    if prob.objective_names is None and "objectives" in table:
        allowed = tuple(prob.objective_metrics or ())
        if not allowed:
            raise ConfigError(f"{name}: problem.objectives: this family declares no objectives "
                              "(TuningProblem.objective_metrics)")
        experiment._objectives(table, allowed)
        if experiment.objective_names[0] != prob.objective:
            raise ConfigError(f"{name}: problem.objectives must start with problem.objective "
                              f"({prob.objective!r}), got {list(experiment.objective_names)}")
        prob.set_objectives(experiment.objective_names, experiment.reference_point, experiment.decision_weights)
        if getattr(experiment, "optimisers", None) is not None:
            experiment._check_multi_objective_optimisers()
    return prob
