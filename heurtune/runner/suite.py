"""The suite of controller-tuning problems: problems, instances, targets and the runs.

``experiments/suite/problems.toml`` lists the problems (:class:`SuiteProblem`: a shipped
experiment's problem for one plant case, with config overrides) and the suite's settings
(:class:`Suite`: instances per problem, the budget multiplier, runs, the root seed, how instances
perturb the plant). For each problem and algorithm, :func:`problem_config` writes an experiment
config whose cases are the problem's instances (``i1`` .. ``iK``, each its plant as
``plant.custom``) and whose only optimiser is the algorithm with ``budget_multiplier x dim``
evaluations; the experiment runner runs it into ``OUT/<problem>/<algorithm>/`` (resume,
fingerprints, atomic writes, as for every experiment). One algorithm per folder: every
algorithm gets the same seeds (common random numbers), and adding one never touches the others'
results.

Targets (:func:`make_targets`, ``experiments/suite/targets.csv``): per problem and instance, the
best value known (the best of long reference runs of strong optimisers) and the median best
value random search reaches at the budget; :func:`targets_of` spaces ``N_TARGETS`` targets
logarithmically between the two, as COCO does. The measures and the leaderboard are in
:mod:`heurtune.analysis.leaderboard`; the command (``python -m heurtune.suite``) is :func:`main`.

A problem whose config names several objectives (``[problem] objectives`` with a
``reference_point``) is a multi-objective row: only the optimisers registered as
multi-objective (and random search, the floor of both kinds) run it, and its value is the
hypervolume deficit ``1 - HV / prod(reference_point)`` of the run's front (lower is better, in
[0, 1]), so that the same targets, ECDF, ERT and Friedman test apply; its leaderboard is written
apart (``OUT/multiobjective/``), since its algorithms are not the single-objective rows'.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import dataclasses
import datetime
import io
import json
import math
import os
import sys
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.analysis.leaderboard import N_TARGETS, targets_of
from heurtune.core.errors import ConfigError
from heurtune.core.io import atomic_path
from heurtune.runner.config import experiments_dir, list_experiments, load_config
from heurtune.runner.resultdir import ResultsOfAnotherConfig

__all__ = ["Suite", "SuiteProblem", "load_suite", "instance_plant", "problem_config", "run_suite", "make_targets",
           "load_targets", "load_reference_runs", "reference_run_rows", "write_reference_runs", "reference_agreement",
           "targets_of", "takes", "N_TARGETS", "SMOKE"]

# --smoke: three problems (one with two objectives), two instances, two runs, a budget of 5 x dim.
SMOKE = dict(problems=("iolqi-min-limits", "pid-min", "pid-min-iae-tv"), instances=(1, 2), runs=2,
             budget_multiplier=5.0)


def suite_dir() -> Path:
    """The folder of the suite's tables (``problems.toml``, ``targets.csv``)."""
    return experiments_dir() / "suite"


@dataclasses.dataclass(frozen=True)
class SuiteProblem:
    """One problem of the suite: ``experiment``'s problem on plant ``case`` with ``overrides``
    merged into its config, in ``group`` (for the figures)."""

    name: str
    experiment: str
    case: str
    group: str = ""
    overrides: dict = dataclasses.field(default_factory=dict)
    objectives: tuple = ()
    reference_point: tuple = ()

    @property
    def multi_objective(self) -> bool:
        """Whether the problem has several objectives (scored by hypervolume)."""
        return len(self.objectives) > 1

    @property
    def volume(self) -> float:
        """The volume of the box between the origin and the reference point (several objectives):
        the hypervolume of a front that reached the origin."""
        return float(np.prod(self.reference_point)) if self.multi_objective else float("nan")


@dataclasses.dataclass(frozen=True)
class Suite:
    """The suite's problems and settings (``experiments/suite/problems.toml``)."""

    problems: tuple
    instances: int
    budget_multiplier: float
    runs: int
    seed: int
    perturbation: dict
    random_runs: int = 5
    """Random search's runs per instance behind a targets row's ``f_random`` (their median)."""

    def problem(self, name: str) -> SuiteProblem:
        """The problem called ``name`` (ConfigError naming the allowed ones otherwise)."""
        for p in self.problems:
            if p.name == name:
                return p
        raise ConfigError(f"unknown suite problem {name!r}; allowed: {', '.join(p.name for p in self.problems)}")


def load_suite(path=None) -> Suite:
    """Read and check the suite's table.

    Parameters
    ----------
    path : str or Path, optional
        Default ``experiments/suite/problems.toml``.

    Returns
    -------
    Suite

    Raises
    ------
    ConfigError
        One line naming the bad key and what it allows.
    """
    path = Path(path) if path is not None else suite_dir() / "problems.toml"
    src = path.name
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{src}: cannot read it: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{src}: not valid TOML: {exc}") from None
    settings = raw.get("suite", {})
    unknown = sorted(set(settings) - {"instances", "budget_multiplier", "runs", "random_runs", "seed",
                                      "perturbation"})
    if unknown:
        raise ConfigError(f"{src}: suite.{unknown[0]}: unknown key; allowed: budget_multiplier, instances, "
                          f"perturbation, random_runs, runs, seed")
    instances = _positive_int(settings.get("instances", 5), f"{src}: suite.instances")
    runs = _positive_int(settings.get("runs", 3), f"{src}: suite.runs")
    random_runs = _positive_int(settings.get("random_runs", 5), f"{src}: suite.random_runs")
    seed = settings.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ConfigError(f"{src}: suite.seed must be an integer >= 0, got {seed!r}")
    multiplier = _multiplier(settings.get("budget_multiplier", 200), f"{src}: suite.budget_multiplier")
    perturbation = dict(settings.get("perturbation", {}))
    for model, table in perturbation.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{src}: suite.perturbation.{model} must be a table of half-widths (one per plant "
                              f"model: [suite.perturbation.qtp], [suite.perturbation.tito])")
        for key, value in table.items():
            _half_width(value, f"{src}: suite.perturbation.{model}.{key}")
    problems, seen = [], set()
    shipped = set(list_experiments())
    for i, row in enumerate(raw.get("problem", [])):
        where = f"{src}: problem {i + 1}"
        unknown = sorted(set(row) - {"name", "experiment", "case", "group", "overrides"})
        if unknown:
            raise ConfigError(f"{where}: unknown key {unknown[0]!r}; allowed: case, experiment, group, name, "
                              f"overrides")
        for key in ("name", "experiment", "case"):
            if not isinstance(row.get(key), str) or not row[key]:
                raise ConfigError(f"{where}: {key} must be a non-empty string")
        name = row["name"]
        if name in seen:
            raise ConfigError(f"{where}: name {name!r} is used twice")
        if not all(ch.isalnum() or ch in "-_" for ch in name):
            raise ConfigError(f"{where}: name {name!r} may hold only letters, digits, '-' and '_'")
        if row["experiment"] not in shipped:
            raise ConfigError(f"{where} ({name}): unknown experiment {row['experiment']!r}; allowed: "
                              f"{', '.join(sorted(shipped))}")
        if not isinstance(row.get("overrides", {}), dict):
            raise ConfigError(f"{where} ({name}): overrides must be a table")
        seen.add(name)
        objectives, reference = _objectives(row, f"{where} ({name})")
        problems.append(SuiteProblem(name, row["experiment"], row["case"], row.get("group", ""),
                                     row.get("overrides", {}), objectives, reference))
    if not problems:
        raise ConfigError(f"{src}: no [[problem]] tables")
    return Suite(tuple(problems), instances, multiplier, runs, seed, perturbation, random_runs)


def _objectives(row: dict, where: str) -> tuple:
    """The objectives and reference point of a row's merged config (several objectives: every
    reference value a finite number > 0, since the score is ``1 - HV / prod(reference_point)``
    with the objectives >= 0)."""
    problem = _merge(load_config(row["experiment"]).get("problem", {}), row.get("overrides", {}).get("problem", {}))
    objectives = tuple(problem.get("objectives") or ())
    if len(objectives) < 2:
        return (), ()
    reference = problem.get("reference_point")
    if (not isinstance(reference, (list, tuple)) or len(reference) != len(objectives)
            or not all(isinstance(r, (int, float)) and not isinstance(r, bool) and math.isfinite(r) and r > 0
                       for r in reference)):
        raise ConfigError(f"{where}: problem.reference_point must be {len(objectives)} numbers > 0 (one per "
                          f"objective, the suite scores a front by 1 - HV / their product), got {reference!r}")
    return objectives, tuple(float(r) for r in reference)


def _half_width(value, where) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 <= value < 1:
        raise ConfigError(f"{where} must be a number in [0, 1), got {value!r}")


def _positive_int(value, where) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"{where} must be an integer >= 1, got {value!r}")
    return value


def _multiplier(value, where) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{where} must be a number > 0, got {value!r}")
    return float(value)


# -- instances ---------------------------------------------------------------------------------
def instance_plant(case: str, instance: int, suite: Suite, model: str = "qtp") -> dict:
    """The plant of ``instance`` (1-based) of ``case``, as ``plant.custom`` takes it: the plant
    family's ``suite_instance`` hook (the QTP's: :mod:`heurtune.objectives.qtp.instances`), with the
    suite's seed and perturbation.

    Parameters
    ----------
    case : str
    instance : int
    suite : Suite
    model : str
        The ``[plant] model`` of the problem's experiment.

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        A family without instances, or the hook's own errors.
    """
    from heurtune.core.families import get_family

    family = get_family(model)
    hook = getattr(family.cls, "suite_instance", None)
    if hook is None:
        raise ConfigError(f"suite: plant family {family.name!r} defines no instances (suite_instance); "
                          f"its problems cannot join the suite yet")
    return hook(case, instance, suite.seed, suite.perturbation.get(model, {}))


# -- configs -----------------------------------------------------------------------------------
def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"TOML cannot hold {value!r}")
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{json.dumps(str(k))} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def _toml_table(prefix: str, table: dict, lines: list) -> None:
    scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
    if prefix and scalars:
        lines.append(f"[{prefix}]")
    for key, value in scalars.items():
        lines.append(f"{json.dumps(str(key))} = {_toml_value(value)}")
    for key, value in table.items():
        if isinstance(value, dict):
            _toml_table(f"{prefix}.{json.dumps(str(key))}" if prefix else json.dumps(str(key)), value, lines)


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for key, value in over.items():
        out[key] = _merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def problem_config(suite: Suite, problem: SuiteProblem, algorithm: str, instances, multiplier: float, runs: int,
                   path) -> Path:
    """Write the experiment config of one problem and algorithm (see the module docstring).

    Parameters
    ----------
    suite : Suite
    problem : SuiteProblem
    algorithm : str
        A registered optimiser, run with its default settings.
    instances : sequence of int
        The instances to run, 1-based (cases ``i<k>``). Every instance of the suite is a case of
        the config, so that instance k's runs have the same seeds whichever are selected; the
        optimiser entry's ``cases`` restricts it to these.
    multiplier : float
        Budget per run, in evaluations per dimension.
    runs : int
        Runs per instance.
    path : str or Path
        The ``.toml`` file to write (its stem is the experiment's name).

    Returns
    -------
    Path
    """
    path = Path(path)
    # Every instance is a case, in order, whatever the selection: a run's seed follows its case's
    # place in the config (``SeedSequence(seed, spawn_key=(case index, ...))``), so instance k is
    # the same runs in a full suite and alone; the optimiser tunes the selected ones.
    everyone = list(range(1, suite.instances + 1))
    cases = [f"i{k}" for k in everyone]
    selected = [f"i{k}" for k in sorted(set(instances))]
    bad = sorted(set(instances) - set(everyone))
    if bad:
        raise ConfigError(f"suite: instance {bad[0]} out of range; allowed: 1 to {suite.instances}")
    model = load_config(problem.experiment).get("plant", {}).get("model", "qtp")
    table = {"plant": {"cases": cases, "custom": {c: instance_plant(problem.case, k, suite, model)
                                                  for c, k in zip(cases, everyone)}}}
    table = _merge(table, problem.overrides)
    head = [f"extends = {json.dumps(problem.experiment)}",
            f"description = {json.dumps(f'suite problem {problem.name}: {problem.experiment}, plant {problem.case}')}",
            f"runs = {runs}", f"seed = {suite.seed}"]

    def write(budget: int) -> None:
        lines = list(head)
        _toml_table("", table, lines)
        lines += ["[[optimisers]]", f"name = {json.dumps(algorithm)}", f"max_evals = {budget}"]
        if selected != cases:
            lines.append(f"cases = {json.dumps(selected)}")
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".toml.tmp")
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
        tmp.replace(path)

    write(1)
    from heurtune.core.families import make_experiment

    dim = make_experiment(load_config(str(path))).problem(selected[0]).dim
    write(max(1, int(round(multiplier * dim))))
    return path


# -- targets -----------------------------------------------------------------------------------
# problem_id: the runner's fingerprint of the case (core.problem.problem_fingerprint, the
# ``problem_id`` of runs.parquet): a row is the answer for that definition of the problem only.
TARGET_COLUMNS = ["problem", "instance", "problem_id", "f_best", "f_random", "random_runs", "random_feasible",
                  "reference", "reference_multiplier", "budget_multiplier", "commit", "date"]


# One row per reference algorithm and case: what each reference algorithm reached, beside the best
# of them that targets.csv keeps (the evidence of how far independent optimisers agree).
REFERENCE_RUN_COLUMNS = ["problem", "instance", "problem_id", "algorithm", "f_best", "runs", "evaluations",
                         "converged_at", "seconds", "reference_multiplier", "budget_multiplier", "commit", "date"]


# Hex strings that read_csv would otherwise take for numbers when their digits allow (a commit
# 3554307, a problem_id 123e4567...: an integer, a float).
_TEXT_COLUMNS = {"problem": str, "problem_id": str, "commit": str, "reference": str, "algorithm": str, "date": str}


def load_targets(path=None) -> pd.DataFrame:
    """``experiments/suite/targets.csv`` (columns :data:`TARGET_COLUMNS`), empty when absent; a
    table written before a column existed gets it empty (a row without ``problem_id`` is then
    used for no case: the leaderboard marks it ``stale``)."""
    path = Path(path) if path is not None else suite_dir() / "targets.csv"
    if not path.is_file():
        return pd.DataFrame(columns=TARGET_COLUMNS)
    return pd.read_csv(path, dtype=_TEXT_COLUMNS).reindex(columns=TARGET_COLUMNS)


def _commit() -> str:
    """The checkout's commit, short, as this process read it first (the runner's cached read:
    a checkout pulled during a long make_targets call does not relabel it)."""
    from heurtune.runner.experiment import _git_commit

    return _git_commit()[:7] or "unknown"


def _best_feasible(results_dir: Path, problem: SuiteProblem) -> pd.DataFrame:
    """Per case and run: the best feasible value, the suite's score of it (the hypervolume
    deficit for several objectives), inf for a run that found none."""
    from heurtune.analysis.leaderboard import suite_value

    runs = pd.read_parquet(results_dir / "runs.parquet")
    f = suite_value(runs["best_f"], problem.volume if problem.multi_objective else None)
    f = f.where(runs["feasible"].astype(bool), np.inf)
    return pd.DataFrame({"case": runs["case"], "run": runs["run"], "f": f})


def reference_run_rows(results_dir, problem: SuiteProblem, reference_multiplier: float,
                       budget_multiplier: float) -> list:
    """Rows of :data:`REFERENCE_RUN_COLUMNS` for one reference algorithm's results folder (one
    per case): its best feasible score over the runs (inf where none was feasible), the number
    of runs, their evaluations, the best run's ``convergence_evals``, the median seconds per
    run, the commit of the process that ran the best run and its date (``meta.json``'s
    ``run_origins``; the folder's ``git_commit`` and date for runs made before heurtune recorded
    them).

    Parameters
    ----------
    results_dir : str or Path
        ``OUT/reference/<problem>/<algorithm>`` of :func:`make_targets`.
    problem : SuiteProblem
    reference_multiplier, budget_multiplier : float
        The budgets the runs had (recorded with the rows).

    Returns
    -------
    list of dict
    """
    from heurtune.runner.experiment import part_name

    results_dir = Path(results_dir)
    runs = pd.read_parquet(results_dir / "runs.parquet")
    scores = _best_feasible(results_dir, problem)
    meta = json.loads((results_dir / "meta.json").read_text(encoding="utf-8"))
    folder_commit = str(meta.get("git_commit") or "unknown")[:7]
    origins = meta.get("run_origins") or {}
    folder_date = str(meta.get("written", ""))[:10] or datetime.date.today().isoformat()
    rows = []
    for case, g in runs.groupby("case", sort=True):
        f = scores.loc[g.index, "f"].to_numpy(float)
        best = int(np.argmin(f))
        # the commit and date of the process that ran the best run where its part records them (a
        # folder gathered again later names the later process), else the folder's
        r = g.iloc[best]
        origin = origins.get(part_name(str(case), r["optimiser_index"], str(r["algorithm"]), r["run"])) or {}
        commit = str(origin.get("git_commit") or "")[:7] or folder_commit
        date = str(origin.get("written") or "")[:10] or folder_date
        rows.append(dict(problem=problem.name, instance=int(str(case).lstrip("i")),
                         problem_id=str(g["problem_id"].iloc[0]), algorithm=str(g["algorithm"].iloc[0]),
                         f_best=float(f[best]), runs=int(len(g)),
                         evaluations=int(g["n_evals"].max()), converged_at=int(g["convergence_evals"].iloc[best]),
                         seconds=float(g["wall_time_s"].median()), reference_multiplier=float(reference_multiplier),
                         budget_multiplier=float(budget_multiplier), commit=commit, date=date))
    return rows


def load_reference_runs(path=None) -> pd.DataFrame:
    """``experiments/suite/reference_runs.csv`` (columns :data:`REFERENCE_RUN_COLUMNS`), empty when
    absent (a column it lacks, empty)."""
    path = Path(path) if path is not None else suite_dir() / "reference_runs.csv"
    if not path.is_file():
        return pd.DataFrame(columns=REFERENCE_RUN_COLUMNS)
    return pd.read_csv(path, dtype=_TEXT_COLUMNS).reindex(columns=REFERENCE_RUN_COLUMNS)


def write_reference_runs(path, new) -> pd.DataFrame:
    """Merge rows (:func:`reference_run_rows`) into the table at ``path``, read and written under a
    lock, atomically: a row replaces the one of the same problem, instance, algorithm and budgets
    unless its value is the same (then the earlier row, with the commit that made it, stays). The
    rows of a case whose ``problem_id`` differs from a new row's are dropped, every algorithm's:
    they answered an earlier definition of the problem.

    Parameters
    ----------
    path : str or Path
    new : list of dict or pandas.DataFrame

    Returns
    -------
    pandas.DataFrame
        The table written.
    """
    path = Path(path)
    new = pd.DataFrame(new, columns=REFERENCE_RUN_COLUMNS)
    key = ["problem", "instance", "algorithm", "reference_multiplier", "budget_multiplier"]
    case = ["problem", "instance", "reference_multiplier", "budget_multiplier"]
    with _table_lock(path):
        old = load_reference_runs(path)
        redefined = old.merge(new[case + ["problem_id"]].drop_duplicates(), on=case, how="left",
                              suffixes=("", "_new"))["problem_id_new"]
        old = old[(redefined.isna() | (redefined == old["problem_id"])).to_numpy()]
        # the same value again (a resumed call that ran nothing new) keeps the row's commit and date
        same = new.merge(old[key + ["problem_id", "f_best"]], on=key + ["problem_id", "f_best"], how="left",
                         indicator=True)["_merge"] == "both"
        table = pd.concat([old, new[~same.to_numpy()]], ignore_index=True)
        table = table.drop_duplicates(key, keep="last")
        table = table.sort_values(["problem", "instance", "algorithm"], kind="mergesort").reset_index(drop=True)
        with atomic_path(path) as tmp:
            table.to_csv(tmp, index=False)
    return table


def reference_agreement(runs=None, *, gap: float = 1e-6) -> pd.DataFrame:
    """Per problem (and budgets), how far its reference algorithms agree.

    Columns: ``reference`` (the algorithms, ``+``-joined), ``cases``, ``largest_gap`` (over the
    cases, the largest relative distance of an algorithm's best from the best of all),
    ``cases_apart`` (cases where some algorithm is more than ``gap`` from the best), ``won``
    (per algorithm, the cases where it holds the best value, ``name:count``), ``converged_by``
    (per algorithm, the largest fraction of its budget at its best run's ``convergence_evals``,
    after which that run's best improved by less than the engine's tolerance, 1e-6 relative)
    and ``seconds`` (median seconds per run).

    Parameters
    ----------
    runs : pandas.DataFrame, optional
        :func:`load_reference_runs` (default the shipped table).
    gap : float
        Relative distance counted in ``cases_apart``.

    Returns
    -------
    pandas.DataFrame
    """
    runs = load_reference_runs() if runs is None else runs
    out = []
    for (name, ref_m, budget_m), g in runs.groupby(["problem", "reference_multiplier", "budget_multiplier"],
                                                   sort=True):
        algs = sorted(g["algorithm"].unique())
        piv = g.pivot_table(index="instance", columns="algorithm", values="f_best", aggfunc="min")
        best = piv.min(axis=1)
        rel = piv.sub(best, axis=0).div(best.abs().where(best.abs() > 0, 1.0), axis=0)
        won = (piv.eq(best, axis=0)).sum()
        conv = (g["converged_at"] / g["evaluations"]).groupby(g["algorithm"]).max()
        out.append(dict(problem=name, reference="+".join(algs), cases=int(len(piv)),
                        largest_gap=float(rel.max().max()) if len(algs) > 1 else float("nan"),
                        cases_apart=int((rel > gap).any(axis=1).sum()),
                        won=", ".join(f"{a}:{int(won[a])}" for a in algs),
                        converged_by=", ".join(f"{a}:{conv[a]:.0%}" for a in algs),
                        seconds=float(g["seconds"].median()), reference_multiplier=ref_m, budget_multiplier=budget_m))
    return pd.DataFrame(out)


# Random search runs both kinds of rows (the floor of each); every other optimiser runs the rows
# of its kind: the multi-objective ones (registered so) the rows with several objectives.
BOTH_KINDS = ("random_search",)
REFERENCE = ("cmaes_sqp", "lshade", "jso")
MULTI_OBJECTIVE_REFERENCE = ("nsga2", "sms_emoa")


def takes(algorithm: str, problem: SuiteProblem) -> bool:
    """Whether the suite runs ``algorithm`` on ``problem`` (see :data:`BOTH_KINDS`).

    Parameters
    ----------
    algorithm : str
        A registered optimiser.
    problem : SuiteProblem

    Returns
    -------
    bool
    """
    from heurtune.core import registry

    return algorithm in BOTH_KINDS or registry.get(algorithm).multi_objective == problem.multi_objective


def make_targets(suite: Suite, problems, instances, out, *, reference=REFERENCE,
                 reference_multiplier: float = 50.0, reference_runs: int = 1, runs: int | None = None,
                 jobs: int = 1, path=None, stream=None) -> pd.DataFrame:
    """Run the reference and random-search runs and write the targets table.

    Per problem and instance: ``f_best``, the best feasible value of the ``reference``
    algorithms' runs (those of them that take the problem's kind, else :data:`REFERENCE` or
    :data:`MULTI_OBJECTIVE_REFERENCE`; values are the suite's scores, the hypervolume deficit for
    several objectives) at ``reference_multiplier`` times the suite's budget, and ``f_random``, the
    median of random search's best feasible values at the budget (a run that found none counts
    as infinite, so the median is infinite when half of them failed).

    The table is written after each problem (a long call interrupted keeps the problems it
    finished; the runs themselves resume from ``out``), and each reference algorithm's own
    values (:func:`reference_run_rows`) to ``reference_runs.csv`` beside it. A row's commit and
    date are those its best run's results folder records. A row already in the table for the same
    budgets and problem definition (``problem_id``) is merged, not replaced: ``f_best`` is the
    better of the two, ``reference`` names the algorithms of both and ``commit``/``date`` are
    those of the better value, so the reference algorithms can be run by separate calls (or
    sessions, or machines) into one table. A row of another definition is replaced. Rows of
    other problems and instances are kept.

    Parameters
    ----------
    suite : Suite
    problems : sequence of SuiteProblem
    instances : sequence of int
    out : str or Path
        Where the reference runs' results go (``OUT/reference/...``).
    reference : sequence of str
    reference_multiplier : float
    reference_runs : int
        Runs per reference algorithm and instance (default 1: one long run, as COCO's best
        known values come from the best long runs).
    runs : int, optional
        Random search's runs per instance (default the suite's ``random_runs``).
    jobs : int
    path : str or Path, optional
        The table written (default ``experiments/suite/targets.csv``).
    stream : file-like, optional
        Progress lines (default stderr).

    Returns
    -------
    pandas.DataFrame
        The table written.
    """
    runs = suite.random_runs if runs is None else runs
    base = Path(out) / "reference"
    reference = tuple(reference)
    path = Path(path) if path is not None else suite_dir() / "targets.csv"
    table = load_targets(path)
    started = _commit()
    for p in problems:
        best, per_algorithm = {}, []
        used = tuple(a for a in reference if takes(a, p)) or (MULTI_OBJECTIVE_REFERENCE if p.multi_objective
                                                              else REFERENCE)
        for alg in used:
            d = _run_one(suite, p, alg, instances, suite.budget_multiplier * reference_multiplier, reference_runs,
                         base, jobs, stream)
            for case, g in _best_feasible(d, p).groupby("case"):
                best[case] = min(best.get(case, np.inf), float(g["f"].min()))
            per_algorithm += reference_run_rows(d, p, reference_multiplier, suite.budget_multiplier)
        d = _run_one(suite, p, "random_search", instances, suite.budget_multiplier, runs, base, jobs, stream)
        rand = _best_feasible(d, p)
        ids = _problem_ids(per_algorithm, d)
        rows = []
        for k in instances:
            g = rand[rand["case"] == f"i{k}"]["f"].to_numpy(float)
            # the commit and date of the run that holds the best value (its results folder's, so a
            # checkout pulled while a long call ran does not relabel what the call computed)
            made = min((r for r in per_algorithm if r["instance"] == k), key=lambda r: r["f_best"],
                       default=dict(commit=started, date=datetime.date.today().isoformat()))
            rows.append(dict(problem=p.name, instance=k, problem_id=ids[k], f_best=best.get(f"i{k}", np.inf),
                             f_random=float(np.median(g)) if g.size else np.inf, random_runs=int(g.size),
                             random_feasible=int(np.isfinite(g).sum()), reference="+".join(used),
                             reference_multiplier=reference_multiplier, budget_multiplier=suite.budget_multiplier,
                             commit=made["commit"], date=made["date"]))
        write_reference_runs(path.with_name("reference_runs.csv"), per_algorithm)
        table = _write_targets(path, pd.DataFrame(rows, columns=TARGET_COLUMNS))
    return table


def _problem_ids(per_algorithm: list, random_dir: Path) -> dict:
    """Per instance, the ``problem_id`` that the reference and random-search runs of one
    :func:`make_targets` call solved (they must agree: one definition of the problem)."""
    seen = {}
    rand = pd.read_parquet(random_dir / "runs.parquet", columns=["case", "problem_id"])
    pairs = [(r["instance"], r["problem_id"]) for r in per_algorithm]
    pairs += [(int(str(c).lstrip("i")), str(i)) for c, i in rand.drop_duplicates().itertuples(index=False)]
    for k, pid in pairs:
        seen.setdefault(k, set()).add(pid)
    split = {k: v for k, v in seen.items() if len(v) > 1}
    if split:
        raise RuntimeError(f"suite: the reference and random runs of instance(s) {sorted(split)} solved different "
                           f"problems ({split}); the problem's definition changed between them")
    return {k: v.pop() for k, v in seen.items()}


def _merge_target(old: dict, new: dict) -> dict:
    """One case's row from an earlier call and this one (:func:`make_targets`)."""
    if str(old.get("problem_id")) != str(new["problem_id"]):
        return new  # the problem was redefined: the earlier value answers another problem
    same = all(float(old[k]) == float(new[k]) for k in ("reference_multiplier", "budget_multiplier"))
    if not same:
        return new
    order = REFERENCE + MULTI_OBJECTIVE_REFERENCE
    names = sorted(set(str(old["reference"]).split("+") + str(new["reference"]).split("+")),
                   key=lambda a: (order.index(a) if a in order else len(order), a))
    # a tie keeps the earlier row's commit and date: a resumed call that ran nothing new made nothing
    better = new if float(new["f_best"]) < float(old["f_best"]) else old
    return {**new, "f_best": float(better["f_best"]), "commit": better["commit"], "date": better["date"],
            "reference": "+".join(names)}


def _write_targets(path: Path, new: pd.DataFrame) -> pd.DataFrame:
    """Merge ``new`` rows into the table at ``path`` (read and written under a lock, atomically)."""
    with _table_lock(path):
        old = load_targets(path)
        rows = {(str(r["problem"]), int(r["instance"])): r for r in old.to_dict("records")}
        for r in new.to_dict("records"):
            key = (str(r["problem"]), int(r["instance"]))
            rows[key] = _merge_target(rows[key], r) if key in rows else r
        table = pd.DataFrame(list(rows.values()), columns=TARGET_COLUMNS)
        table = table.sort_values(["problem", "instance"], kind="mergesort").reset_index(drop=True)
        with atomic_path(path) as tmp:
            table.to_csv(tmp, index=False)
    return table


@contextlib.contextmanager
def _table_lock(path: Path):
    """Hold an exclusive lock on the folder of ``path`` (waits for another writer; none on
    systems without ``fcntl``, where one writer at a time is the user's to keep)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


# -- running -----------------------------------------------------------------------------------
class _Notices(io.TextIOBase):
    """A progress stream that passes on only the lines about compiling (a first run's minute)."""

    def __init__(self, stream):
        self.stream, self._buf = stream, ""

    def writable(self):
        return True

    def write(self, text):
        self._buf += text
        while "\n" in self._buf:
            line, self._buf = self._buf.split("\n", 1)
            if "numba is compiling" in line or "calibrated in" in line:
                print(line, file=self.stream, flush=True)
        return len(text)


def _run_one(suite, problem, algorithm, instances, multiplier, runs, base, jobs, stream, plugins=(),
             executor=None) -> Path:
    """Run (or resume) one problem and algorithm; returns its results folder. With an
    ``executor`` (:func:`_side_by_side`) its runs go there, and the caller silences stdout."""
    from heurtune.runner.experiment import run_experiment

    stream = sys.stderr if stream is None else stream
    folder = Path(base) / problem.name / algorithm
    config = problem_config(suite, problem, algorithm, instances, multiplier, runs,
                            Path(base) / "configs" / f"{problem.name}__{algorithm}.toml")
    # each experiment's summary table goes nowhere: the leaderboard says it
    silent = contextlib.redirect_stdout(io.StringIO()) if executor is None else contextlib.nullcontext()
    try:
        with silent:
            run_experiment(str(config), jobs=jobs, out=folder, figures=False, progress_stream=_Notices(stream),
                           plugins=tuple(plugins), cases_alike=True, executor=executor)
    except ResultsOfAnotherConfig as err:  # the suite has no --fresh: it never discards results itself
        raise ConfigError(f"{err.out_dir} holds {err.runs} run(s) of {problem.name} made with another config "
                          f"(differing: {err.differing}; its row in problems.toml or the budget changed since); "
                          f"remove that folder to run it again, or use another --out") from None
    print(f"suite: {problem.name} / {algorithm}: {len(instances)} instance(s) x {runs} run(s) in {folder}",
          file=stream, flush=True)
    return folder


def run_suite(suite: Suite, problems, algorithms, instances, out, *, multiplier=None, runs=None, jobs: int = 1,
              stream=None, plugins=()) -> list:
    """Run (or resume) every problem with every algorithm; returns the results folders.

    Parameters
    ----------
    suite : Suite
    problems : sequence of SuiteProblem
    algorithms : sequence of str
    instances : sequence of int
    out : str or Path
        ``OUT/<problem>/<algorithm>/`` per pair, ``OUT/configs/`` their configs.
    multiplier : float, optional
        Budget per run in evaluations per dimension (default the suite's).
    runs : int, optional
        Runs per instance (default the suite's).
    jobs : int
    stream : file-like, optional
    plugins : sequence of str
        Plugins the runs load first (an optimiser outside the package).

    Returns
    -------
    list of (SuiteProblem, str, Path)
        The pairs run: each problem with the algorithms that take it (:func:`takes`); a problem
        that none takes is named on ``stream`` and skipped.

    Raises
    ------
    ConfigError
        No algorithm takes any of the problems.
    """
    multiplier = suite.budget_multiplier if multiplier is None else multiplier
    runs = suite.runs if runs is None else runs
    pairs = [(p, alg) for p in problems for alg in algorithms if takes(alg, p)]
    if not pairs:
        raise ConfigError(f"--algorithms: none of {', '.join(algorithms)} takes these problems (several objectives "
                          f"need a multi-objective optimiser, e.g. {', '.join(MULTI_OBJECTIVE_REFERENCE)}; one "
                          f"objective a single-objective one)")
    for p in problems:
        if not any(q is p for q, _ in pairs):
            kind = f"{len(p.objectives)} objectives" if p.multi_objective else "one objective"
            print(f"suite: {p.name}: skipped, no algorithm of --algorithms takes {kind}", file=stream or sys.stderr,
                  flush=True)
    if jobs > 1 and len(pairs) > 1:
        folders = _side_by_side(suite, pairs, instances, multiplier, runs, out, jobs, stream, plugins)
    else:
        folders = [_run_one(suite, p, alg, instances, multiplier, runs, out, jobs, stream, plugins) for p, alg in pairs]
    return [(p, alg, folder) for (p, alg), folder in zip(pairs, folders)]


# Seconds a stopped suite waits for its folders' threads to let go of their folders (each sees its
# runs fail once the workers are killed; one calibrating finishes its calibration first).
STOP_WAIT_S = 10.0


def _side_by_side(suite, pairs, instances, multiplier, runs, out, jobs, stream, plugins) -> list:
    """Run the pairs' folders side by side (:func:`run_suite` with several workers); returns
    their folders in the pairs' order.

    Up to ``jobs + 1`` folders are open at once, each in a thread of this process that
    prepares, calibrates and gathers it as :func:`run_experiment` does, and all their runs go,
    whole and first come first served, to one pool of ``jobs`` worker processes. So the workers
    wait only for the first folders' calibrations and for the suite's last runs, not for each
    folder's calibration, gathering and last run as one folder after another made them. Each
    run's numbers are those of any other way of running it (its seed is its own).

    The first folder that fails stops the others (their workers are killed, their finished runs
    kept) and its error is raised; Ctrl-C or SIGTERM in this thread does the same and is raised.
    """
    from heurtune.core.execution import kill_workers, process_executor

    executor = process_executor(jobs)
    threads = concurrent.futures.ThreadPoolExecutor(max_workers=jobs + 1, thread_name_prefix="heurtune-suite")
    futures = []

    def stop():
        for fut in futures:
            fut.cancel()
        kill_workers()
        threads.shutdown(wait=False)
        concurrent.futures.wait(futures, timeout=STOP_WAIT_S)

    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():  # summaries: see _run_one
        # loky replaces a worker whose memory grew 300 MB past its first task's (a worker that
        # serves every folder loads the kernels of every plant); its queued runs go on on the new
        # worker, but with runs queued loky warns of a "too short worker timeout or memory leak"
        warnings.filterwarnings("ignore", message="A worker stopped while some jobs were given", category=UserWarning)
        try:
            futures += [threads.submit(_run_one, suite, p, alg, instances, multiplier, runs, out, jobs, stream,
                                       plugins, executor) for p, alg in pairs]
            waiting = set(futures)
            while waiting:  # a timeout, so that a signal reaches this thread between waits
                done, waiting = concurrent.futures.wait(waiting, timeout=1.0,
                                                        return_when=concurrent.futures.FIRST_EXCEPTION)
                failed = [fut for fut in futures if fut in done and fut.exception() is not None]
                if failed:
                    raise failed[0].exception()
        except BaseException:
            stop()
            raise
    threads.shutdown()
    return [fut.result() for fut in futures]


# -- the command -------------------------------------------------------------------------------
# random search is the floor of both boards, and gives f_random where the targets table has no row
DEFAULT_ALGORITHMS = ("cs", "pso", "cmaes", "cmaes_sqp", "lshade", "jso", "random_search") + MULTI_OBJECTIVE_REFERENCE


def _parser():
    from heurtune.core.cli import OneLineParser, exit_codes

    ap = OneLineParser(
        prog="python -m heurtune.suite",
        description="Run optimisers on heurtune's suite of controller-tuning problems and write the leaderboard.",
        epilog=exit_codes(("python -m heurtune.suite --list",
                           "python -m heurtune.suite --smoke --algorithms random_search,cs,pso",
                           "python -m heurtune.suite --algorithms cs,cmaes --problems pid-min,iolqi-min-limits "
                           "--instances 1-3 --jobs 2"),
                          c130="interrupted by Ctrl-C (the finished runs are kept; the same command resumes)"),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algorithms", default=",".join(DEFAULT_ALGORITHMS),
                    help=f"optimisers, comma-separated (default {','.join(DEFAULT_ALGORITHMS)})")
    ap.add_argument("--problems", help="problems, comma-separated (default all; --list names them)")
    ap.add_argument("--instances", help="instances, e.g. 1,2 or 1-3 (default 1..K of the suite)")
    ap.add_argument("--budget-multiplier", type=float, help="evaluations per run per dimension (default the suite's)")
    ap.add_argument("--runs", type=int, help="runs per algorithm and instance (default the suite's)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--out", help="output folder (default results/suite, results/suite-smoke with --smoke)")
    ap.add_argument("--smoke", action="store_true",
                    help=f"problems {', '.join(SMOKE['problems'])}, instances 1-2, 2 runs, budget 5 x dimension")
    ap.add_argument("--make-targets", action="store_true",
                    help="run the reference algorithms and random search and write experiments/suite/targets.csv")
    ap.add_argument("--reference", default=",".join(REFERENCE + MULTI_OBJECTIVE_REFERENCE),
                    help="reference algorithms of --make-targets, each on the rows of its kind (default "
                         f"{','.join(REFERENCE + MULTI_OBJECTIVE_REFERENCE)})")
    ap.add_argument("--reference-multiplier", type=float, default=50.0,
                    help="their budget, in multiples of the suite's (default 50)")
    ap.add_argument("--reference-runs", type=int, default=1,
                    help="runs per reference algorithm and instance (default 1; --runs sets random search's)")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    ap.add_argument("--no-ioh", action="store_true", help="skip the IOHprofiler export")
    ap.add_argument("--plugin", action="append", default=[],
                    help="plugin module or .py file registering an optimiser (repeatable)")
    ap.add_argument("--list", action="store_true", help="list the problems and stop")
    ap.add_argument("--reference-report", action="store_true",
                    help="print how far the reference algorithms agree per problem "
                         "(experiments/suite/reference_runs.csv) as a markdown table and stop")
    return ap


def _reference_report(agreement: pd.DataFrame) -> str:
    """:func:`reference_agreement` as the markdown table of docs/suite.md."""
    from heurtune.analysis.render import _md_table

    if agreement.empty:
        return "no reference runs recorded (experiments/suite/reference_runs.csv)"
    table = agreement.rename(columns={"largest_gap": "largest gap", "cases_apart": "cases > 1e-6 apart",
                                      "won": "best value held by", "converged_by": "converged by",
                                      "seconds": "s per run"})
    table = table.drop(columns=["reference_multiplier", "budget_multiplier"])
    return _md_table(table, {"largest gap": 2, "s per run": 3})


def _instances(text, k_max: int) -> list:
    if text is None:
        return list(range(1, k_max + 1))
    out = []
    for part in text.split(","):
        part = part.strip()
        try:
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                out.extend(range(a, b + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise ConfigError(f"--instances: {part!r} is not an instance number or range (e.g. 1,2 or 1-3)") from None
    bad = [k for k in out if not 1 <= k <= k_max]
    if bad or not out:
        raise ConfigError(f"--instances: {bad[0] if bad else text!r} out of range; allowed: 1 to {k_max}")
    return list(dict.fromkeys(out))


def _algorithms(text) -> list:
    from heurtune.core import registry

    names = [a.strip() for a in text.split(",") if a.strip()]
    known = registry.available()
    for name in names:
        if name not in known:
            raise ConfigError(f"--algorithms: unknown optimiser {name!r}; allowed: {', '.join(known)}")
    if not names:
        raise ConfigError("--algorithms: name at least one optimiser")
    return list(dict.fromkeys(names))


def run(argv=None) -> int:
    """Command-line entry point; returns the exit code (130 after Ctrl-C, 143 after SIGTERM)."""
    from heurtune.runner.experiment import sigterm_raises

    with sigterm_raises():
        return _run(argv)


def _run(argv) -> int:
    """:func:`run`, SIGTERM raising ``Terminated``."""
    from heurtune.core.cli import UsageError
    from heurtune.runner.experiment import Interrupted, Terminated, signal_exit

    stream = sys.stderr
    try:
        args = _parser().parse_args(argv)
        from heurtune.core.families import load_registering_plugin

        for spec in args.plugin:
            load_registering_plugin(spec)
        suite = load_suite()
        if args.reference_report:
            print(_reference_report(reference_agreement()))
            return 0
        if args.list:
            for p in suite.problems:
                print(f"{p.name:26s} {p.group:14s} {p.experiment} ({p.case})"
                      + (f", {json.dumps(p.overrides)}" if p.overrides else ""))
            return 0
        if args.smoke:
            names = args.problems.split(",") if args.problems else list(SMOKE["problems"])
            instances = _instances(args.instances, suite.instances) if args.instances else list(SMOKE["instances"])
            runs = SMOKE["runs"] if args.runs is None else args.runs  # 0 is refused below, not replaced
            multiplier = SMOKE["budget_multiplier"] if args.budget_multiplier is None else args.budget_multiplier
        else:
            names = args.problems.split(",") if args.problems else [p.name for p in suite.problems]
            instances = _instances(args.instances, suite.instances)
            runs = args.runs
            multiplier = args.budget_multiplier
        problems = [suite.problem(n.strip()) for n in names]
        if multiplier is not None:
            _multiplier(multiplier, "--budget-multiplier")
        if runs is not None and runs < 1:
            raise ConfigError(f"--runs must be >= 1, got {runs}")
        if args.jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {args.jobs}")
        algorithms = _algorithms(args.algorithms)
        out = Path(args.out or ("results/suite-smoke" if args.smoke else "results/suite"))
        if args.make_targets:
            reference = _algorithms(args.reference)
            _multiplier(args.reference_multiplier, "--reference-multiplier")
            if args.reference_runs < 1:
                raise ConfigError(f"--reference-runs must be >= 1, got {args.reference_runs}")
            table = make_targets(suite, problems, instances, out, reference=reference,
                                 reference_multiplier=args.reference_multiplier, reference_runs=args.reference_runs,
                                 runs=runs, jobs=args.jobs, stream=stream)
            print(f"suite: targets of {len(problems)} problem(s) x {len(instances)} instance(s) written "
                  f"({len(table)} rows in experiments/suite/targets.csv)", file=stream)
            return 0
        multiplier = suite.budget_multiplier if multiplier is None else multiplier
        done = run_suite(suite, problems, algorithms, instances, out, multiplier=multiplier, runs=runs,
                         jobs=args.jobs, stream=stream, plugins=args.plugin)
        written = leaderboard(suite, done, out, multiplier=multiplier, figures=not args.no_figures,
                              ioh=not args.no_ioh)
        print(f"suite: leaderboard in {out / 'leaderboard.md'} ({len(written)} files)", file=stream)
        print((out / "leaderboard.md").read_text(encoding="utf-8"))
    except (ConfigError, UsageError) as exc:
        print(f"error: {exc}", file=stream)
        return 2
    except BrokenPipeError:  # stdout closed by its reader (--list | head): main() ends quietly
        raise
    except OSError as exc:
        print(f"error: {exc.filename or 'the output folder'}: {exc.strerror or exc}; the finished runs are kept: "
              f"fix that and run the same command again", file=stream)
        return 2
    except Interrupted as exc:  # one folder at a time: its run_experiment stopped
        print(f"\ninterrupted: {exc.kept} of {exc.planned} runs kept in {exc.out_dir}, and every finished run "
              "of the suite; run the same command again to resume", file=stream)
        return exc.code
    except (KeyboardInterrupt, Terminated, SystemError) as exc:
        code = signal_exit(exc)
        if code is None:
            raise
        print("\ninterrupted: the finished runs are kept; run the same command again to resume", file=stream)
        return code
    return 0


def leaderboard(suite: Suite, done, out, *, multiplier: float, figures: bool = True, ioh: bool = True,
                targets_path=None) -> list:
    """Measures, leaderboard and figures of finished suite runs (:func:`run_suite`'s list).

    The rows with several objectives get their own measures and leaderboard in
    ``OUT/multiobjective/`` (their algorithms are not the other rows'), appended to
    ``OUT/leaderboard.md`` a heading level down (or that page alone when no other row ran).

    Parameters
    ----------
    suite : Suite
    done : list of (SuiteProblem, str, Path)
    out : str or Path
    multiplier : float
        The budget per dimension the runs had.
    figures, ioh : bool
        Draw the figures; write the IOHprofiler export (``OUT/ioh/<problem>__<algorithm>/``).
    targets_path : str or Path, optional
        The targets table (default ``experiments/suite/targets.csv``).

    Returns
    -------
    list of Path
    """
    out = Path(out)
    single = [d for d in done if not d[0].multi_objective]
    multi = [d for d in done if d[0].multi_objective]
    written = []
    if single:
        written += _board(suite, single, out, multiplier, figures, targets_path, "Suite leaderboard", "")
    if multi:
        sub = out / MULTI_OBJECTIVE_FOLDER
        written += _board(suite, multi, sub, multiplier, figures, targets_path,
                          "Suite leaderboard: multi-objective problems",
                          "Values: the hypervolume deficit 1 - HV / prod(reference point) of each run's front "
                          "(lower is better; the objectives are >= 0, so a front at the origin scores 0).")
        text = (sub / "leaderboard.md").read_text(encoding="utf-8")
        if single:  # one page: the single-objective board, then this one a heading level down
            lines = ["#" + line if line.startswith("#") else line for line in text.splitlines()]
            lines[1:1] = ["", f"Its figures and tables are in `{MULTI_OBJECTIVE_FOLDER}/`."]
            text = (out / "leaderboard.md").read_text(encoding="utf-8") + "\n" + "\n".join(lines) + "\n"
        with atomic_path(out / "leaderboard.md") as tmp:
            tmp.write_text(text, encoding="utf-8")
    if ioh:
        from heurtune.analysis.export import export_ioh

        for p, alg, folder in done:
            written += export_ioh(folder, out / "ioh" / f"{p.name}__{alg}")
    return written


# Where the leaderboard of the rows with several objectives goes, inside the suite's folder.
MULTI_OBJECTIVE_FOLDER = "multiobjective"


def _board(suite, done, out, multiplier, figures, targets_path, title, note) -> list:
    """The measures and leaderboard of one kind of rows (:func:`leaderboard`)."""
    from heurtune.analysis import leaderboard as lb
    from heurtune.core.families import make_experiment

    runs, history = lb.collect([(p.name, alg, folder) for p, alg, folder in done],
                               {p.name: p.volume for p, _, _ in done if p.multi_objective})
    dims = {}
    for p, _, folder in done:
        if p.name not in dims:
            config = json.loads((folder / "meta.json").read_text(encoding="utf-8")).get("config", {})
            dims[p.name] = make_experiment(config).problem(sorted(set(runs.loc[runs["problem"] == p.name, "case"]
                                                                      .str.split("/").str[1]))[0]).dim \
                if config else None
    if any(d is None for d in dims.values()):
        raise ConfigError("suite: a results folder has no config in its meta.json; rerun the suite")
    targets, sources = lb.targets_table(load_targets(targets_path), runs, N_TARGETS, multiplier=multiplier)
    measures = lb.suite_measures(runs, history, targets, dims, multiplier, {p.name: p.group or "all"
                                                                           for p in suite.problems})
    return lb.write_leaderboard(out, runs, measures, lb.friedman_final(runs), sources, multiplier=multiplier,
                                figures=figures, title=title, note=note)


def main() -> None:
    """Run the command line and exit with its code."""
    from heurtune import _startup

    _startup.release()
    code = _startup.run_command(run)
    if code in (130, 143):  # leave at once, as an experiment does (heurtune.runner.experiment.main)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
