"""Run a named experiment: many seeded tuning runs, logged to parquet, resumable.

Usage::

    python -m heurtune.experiment NAME [--runs N] [--max-epochs E] [--jobs J] [--seed S]
        [--out DIR] [--smoke] [--fresh] [--backend loky|dask --scheduler ADDRESS]
        [--plugin FILE_OR_MODULE ...] [--device cpu|cpu-batch|gpu] [--lockstep] [--force]
        [--list] [--list-algorithms] [--status]

Every (case, optimiser, run) is one tuning run with its own seed,
``SeedSequence(root_seed, spawn_key=(case index, optimiser index, run))``, so a run's result
depends on nothing but the config and the root seed: not on the order, on the number of workers
or on which runs were already done. Each finished run is written at once, atomically, to
``DIR/parts/``; re-running the same command skips finished runs (``--fresh`` starts over), so an
interrupt loses at most the runs in flight. At the end the parts are gathered into
``runs.parquet`` and ``history.parquet``, with ``summary.parquet`` (the printed summary as data),
``meta.json`` (resolved config, seeds, package versions, git commit and whether the tree was
dirty, platform and BLAS), ``margins.parquet`` and figures. TITO experiments also write
``design.parquet`` (decoupled loops' FOPDT fits, GPM design and its exact margins),
``robustness.parquet`` (spectral-radius and Kharitonov verdicts of each best design),
``performance.parquet`` / ``performance.md`` (IAE, ISE, ITAE per loop, papers' table layout)
and spectral-radius plots. Analytic designs named in ``controller.baselines`` (e.g. ``gpm``) are
written as runs of their own (one each, algorithm = the baseline's name).

On the local pool with several workers (not Dask, an executor or lockstep), runs whose driver
keeps every worker busy by itself (multistart SQP without an evaluation budget: its local
solves are handed out all at once) go first, one after the other, each over all the workers, so
that runs of unequal length never leave a worker idle. Of the other runs, with at least as many
as workers, whole runs go to the workers; otherwise the runs go one after the other, each
evaluating its batches on all workers.

Before the first run, one evaluation of every case is calibrated on this machine and device and
the planned work printed (runs, evaluations, estimated time; :mod:`heurtune.runner.workplan`);
a case whose single evaluation would take more than a minute is refused with a one-line error
naming the scenario keys, unless ``--force``. The progress line (:mod:`heurtune.runner.progress`)
then counts the evaluations done of the total and the time left, from inside running runs.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import dataclasses
import functools
import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune import _startup
from heurtune.analysis import figures
from heurtune.analysis.runs import best_runs, failed_runs, successful_runs
from heurtune.core import registry
from heurtune.core.cli import exit_codes
from heurtune.core.dead_variables import dead_variables
from heurtune.core.engine import Checkpoint, SearchSpace
from heurtune.core.engine import run as run_optimiser
from heurtune.core.errors import ConfigError, config_warning, quiet_config_warnings
from heurtune.core.evaluator import CHUNKS_PER_WORKER, Evaluator, Objective, Objectives, evaluate_groups
from heurtune.core.execution import BACKENDS, Pool, WorkerDied, is_worker_death, kill_workers
from heurtune.core.families import load_registering_plugin, make_experiment
from heurtune.core.io import atomic_path, write_parquet
from heurtune.core.lockstep import Lockstep
from heurtune.core.plugins import load_plugins
from heurtune.core.problem import StructureWarning, problem_fingerprint
from heurtune.runner.config import list_experiments, load_config
from heurtune.runner.progress import HEARTBEAT_SUFFIX, Heartbeat, Progress, clear_heartbeats
from heurtune.runner.resultdir import (
    METADATA_KEY,
    ORIGIN_KEY,
    FolderLock,
    check_parts,
    clear_folder,
    differing_keys,
    fingerprint_digest,
    matching_parts,
    part_origin,
    read_part,
    run_fingerprint,
    set_aside_file,
)
from heurtune.runner.workplan import (
    CompileNotice,
    borrow_step_cost,
    calibrate,
    check_evaluation_time,
    estimate_line,
    planned_evaluations,
)

__all__ = ["RunSpec", "plan", "execute", "problem_id", "run_status", "RUN_STATUSES", "run_experiment", "summary_table",
           "status_table",
           "main"]

# The most runs one command may plan (each costs a few kB of bookkeeping before it starts).
MAX_PLANNED_RUNS = 1_000_000
# An optimiser's population may use at most this share of the machine's memory (estimated).
MEMORY_SHARE = 0.5
# Bytes per candidate of a population, estimated: its vector, constraints and objectives, a
# few working copies, and the evaluation's arrays.
_BYTES_PER_VALUE = 8 * 16

# Budgets of --smoke: the same problem, a quick check.
SMOKE_RUNS = 2
SMOKE_EPOCHS = 2
SMOKE_SETTINGS = {"n": 6, "starts": 2, "max_iter": 5, "batch": 2}


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One tuning run of an experiment."""

    case: str
    case_index: int
    algorithm: str
    optimiser_index: int
    run: int
    settings: dict
    budget: dict
    root_seed: int
    baseline: bool = False

    @property
    def spawn_key(self) -> tuple:
        return (self.case_index, self.optimiser_index, self.run)

    @property
    def seed_key(self) -> str:
        return ".".join(map(str, self.spawn_key))

    @property
    def part_name(self) -> str:
        return part_name(self.case, self.optimiser_index, self.algorithm, self.run)


def part_name(case: str, optimiser_index: int, algorithm: str, run: int) -> str:
    """The name of a run's part files in ``parts/`` (and its key in ``meta.json``)."""
    return f"{case.replace('/', '_')}__{int(optimiser_index)}-{algorithm}__{int(run):04d}"


def problem_id(exp, case: str) -> str:
    """A short hash of everything that defines a case's tuning problem (for comparisons).

    Parameters
    ----------
    exp : ExperimentBase
    case : str

    Returns
    -------
    str
    """
    return problem_fingerprint(exp.problem(case))


def plan(exp, *, runs=None, max_epochs=None, seed=None, smoke=False) -> list:
    """All runs of an experiment, in a fixed order (case, optimiser, run), then one run per
    case and baseline: an analytic design (``controller.baselines`` of TITO experiments) or a
    fixed controller (``[[baselines]]`` of QTP experiments, e.g. printed gains).

    An optimiser entry with ``cases`` tunes only those cases; its index (and hence its runs'
    seeds) is its place in the config all the same.

    Parameters
    ----------
    exp : ExperimentBase
    runs : int, optional
        Runs per case and optimiser (default: the config's).
    max_epochs : int, optional
        Overrides every optimiser's generations.
    seed : int, optional
        The root seed (default: the config's).
    smoke : bool
        The smoke budgets (2 runs, 2 generations, small populations).

    Returns
    -------
    list of RunSpec
    """
    if not exp.optimisers and not any(exp.baseline_names(c) for c in exp.cases):
        raise ConfigError(f"{exp.name}: no [[optimisers]] to run")
    n_runs = runs if runs is not None else exp.config.get("runs", 10)
    root = seed if seed is not None else exp.config.get("seed", 0)
    if n_runs < 1 or root < 0:
        raise ConfigError(f"{exp.name}: runs must be >= 1 and seed >= 0, got runs = {n_runs}, seed = {root}")
    if smoke:
        n_runs = min(n_runs, SMOKE_RUNS)
    n_planned = n_runs * sum(len(exp.optimisers_of(c)) for c in exp.cases)
    if n_planned > MAX_PLANNED_RUNS:
        raise ConfigError(f"{exp.name}: {n_planned:,} runs planned (runs = {n_runs:,}); at most "
                          f"{MAX_PLANNED_RUNS:,} in one command: lower runs or split the experiment")
    _check_population_memory(exp)
    specs = []
    for ci, case in enumerate(exp.cases):
        for oi, opt in exp.optimisers_of(case):
            name = opt["name"]
            settings = dataclasses.asdict(opt["settings"])
            budget = {k: opt[k] for k in ("max_epochs", "max_evals", "max_time", "tol", "tol_window",
                                          "constraint_handling", "penalty", "bound_handling") if k in opt}
            if max_epochs is not None:
                budget["max_epochs"] = max_epochs
                budget.pop("max_evals", None)
            if smoke:
                budget["max_epochs"] = min(budget.get("max_epochs", SMOKE_EPOCHS), SMOKE_EPOCHS)
                if "max_evals" in budget:
                    budget["max_evals"] = min(budget["max_evals"], 200)
                for key, small in SMOKE_SETTINGS.items():
                    if key in settings:
                        settings[key] = min(settings[key], small)
            for r in range(n_runs):
                specs.append(RunSpec(case, ci, name, oi, r, settings, budget, root))
        for bi, name in enumerate(exp.baseline_names(case)):
            specs.append(RunSpec(case, ci, name, len(exp.optimisers) + bi, 0, {}, {}, root, baseline=True))
    return specs


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def _check_population_memory(exp) -> None:
    """Refuse an optimiser whose population cannot fit in memory (estimated from its sizes:
    ``n``, ``n_offspring``, ``batch``, ``starts``), before anything is written."""
    total = _physical_memory()
    if total is None:
        return
    dims = {}
    for i, opt in enumerate(exp.optimisers):
        settings = dataclasses.asdict(opt["settings"]) if dataclasses.is_dataclass(opt["settings"]) else {}
        sizes = {k: v for k, v in settings.items() if k in ("n", "n_offspring", "batch", "starts")
                 and isinstance(v, int) and not isinstance(v, bool)}
        if not sizes:
            continue
        key, size = max(sizes.items(), key=lambda kv: kv[1])
        for c in opt.get("cases", exp.cases):
            if c not in dims:
                dims[c] = len(exp.problem(c).names)
        width = max((dims[c] + 16 for c in opt.get("cases", exp.cases)), default=0)
        need = size * width * _BYTES_PER_VALUE
        if need > MEMORY_SHARE * total:
            raise ConfigError(f"{exp.name}: optimisers[{i}].settings.{key} = {size:,} needs about "
                              f"{need / 2**30:,.0f} GiB for its population; this machine has "
                              f"{total / 2**30:,.0f} GiB: lower it")


# Per-process cache: workers rebuild each case's problem once. The problems used last are kept:
# a worker that serves many experiments (the suite's folders side by side, every instance of each)
# would otherwise hold every problem it ever built, and loky restarts a worker whose memory grows
# by 300 MB. The threads of the suite's folders share it (a lock).
_PROBLEMS = collections.OrderedDict()
_PROBLEMS_KEPT = 32
_PROBLEMS_LOCK = threading.Lock()


class Terminated(BaseException):
    """SIGTERM, raised in the main thread while an experiment runs (like KeyboardInterrupt)."""


def _raise_terminated(signum, frame):
    raise Terminated


@contextlib.contextmanager
def sigterm_raises():
    """While the block runs, SIGTERM raises :class:`Terminated` in the main thread, as Ctrl-C
    raises KeyboardInterrupt, so that a command stops its workers and exits with 143; the previous
    handler is restored after. Nothing is installed in another thread (Python only lets the main
    thread set handlers) or where SIGTERM was ignored at start (a caller that ignores it keeps
    it so)."""
    previous = None
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) != signal.SIG_IGN:
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _signal_of(exc: BaseException):
    """The KeyboardInterrupt or Terminated behind ``exc``: itself, or the cause of the
    SystemError that a C function raises when a signal handler raised while it ran (``...
    returned a result with an exception set``); None for anything else."""
    seen = 0
    while exc is not None and seen < 8:
        if isinstance(exc, (KeyboardInterrupt, Terminated)):
            return exc
        if not isinstance(exc, SystemError):
            return None
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def signal_exit(exc: BaseException):
    """The exit code of a command that ``exc`` stopped, its workers killed.

    Parameters
    ----------
    exc : BaseException
        What the command caught: KeyboardInterrupt, Terminated, or a SystemError a signal caused.

    Returns
    -------
    int or None
        130 after Ctrl-C, 143 after SIGTERM; None when ``exc`` is no signal (the caller raises
        it again).
    """
    signal_exc = _signal_of(exc)
    if signal_exc is None:
        return None
    kill_workers()
    return 143 if isinstance(signal_exc, Terminated) else 130


class Interrupted(Exception):
    """An experiment stopped by Ctrl-C (``code`` 130) or SIGTERM (143), its workers killed:
    ``kept`` of ``planned`` runs are on disk in ``out_dir`` and a rerun resumes from them."""

    def __init__(self, code: int, kept: int, planned: int, out_dir):
        super().__init__(f"interrupted: {kept} of {planned} runs kept in {out_dir}")
        self.code, self.kept, self.planned, self.out_dir = code, kept, planned, out_dir


def _problem(config: dict, case: str):
    key = (config["name"], json.dumps(config, sort_keys=True, default=str), case)
    with _PROBLEMS_LOCK:
        prob = _PROBLEMS.get(key)
        if prob is not None:
            _PROBLEMS.move_to_end(key)
            return prob
    with quiet_config_warnings():  # the command loaded this config, and warned, before any run
        prob = make_experiment(config).problem(case)
    prob.set_device(config.get("device", "cpu"))
    with _PROBLEMS_LOCK:
        prob = _PROBLEMS.setdefault(key, prob)  # one built meanwhile by another thread is kept
        _PROBLEMS.move_to_end(key)
        while len(_PROBLEMS) > _PROBLEMS_KEPT:
            _PROBLEMS.popitem(last=False)
    return prob


def execute(config: dict, spec: RunSpec, evaluator: Evaluator | None = None, *, parts=None):
    """Run one tuning run; returns its result row (dict) and history (DataFrame).

    Runs in any process: the optimiser plugins named by the config are loaded here too.

    Parameters
    ----------
    config : dict
        The resolved experiment config.
    spec : RunSpec
        The run.
    evaluator : Evaluator, optional
        An open evaluator to use (default: a new in-process one).
    parts : path, optional
        The experiment's ``parts/`` folder. Given, a driver's finished local solves are saved
        as they end to ``parts/<run>.starts.parquet`` (for ``starts.parquet``), and a rerun of
        an interrupted run takes them from there instead of solving them again.

    Returns
    -------
    row : dict
    history : pandas.DataFrame
    """
    load_plugins(config.get("plugins", []))
    prob = _problem(config, spec.case)
    if spec.baseline:
        return _execute_baseline(prob, spec)
    res, wall = optimise(config, spec, evaluator, parts=parts)
    return run_record(prob, spec, res, wall, parts=parts)


def optimise(config: dict, spec: RunSpec, evaluator: Evaluator | None = None, *, parts=None):
    """The optimisation of :func:`execute`, without its record: returns the engine's Result and
    the wall time it took. Touches the problem only through ``evaluator`` (so that runs in
    lockstep evaluate in one thread)."""
    prob = _problem(config, spec.case)
    t0 = time.perf_counter()
    seed = np.random.SeedSequence(spec.root_seed, spawn_key=spec.spawn_key)
    space = SearchSpace(prob.lower, prob.upper, spec.budget.get("bound_handling", "clip"))
    budget = {k: v for k, v in spec.budget.items() if k != "bound_handling"}
    own = evaluator is None
    ev = Evaluator(prob) if own else evaluator
    try:
        checkpoint = None if parts is None else StartsFile(
            Path(parts) / f"{spec.part_name}.starts.parquet", prob.names, _run_key(prob, spec))
        heartbeat = None if parts is None else Heartbeat(Path(parts) / f"{spec.part_name}{HEARTBEAT_SUFFIX}")
        res = run_optimiser(spec.algorithm, ev, space, settings=spec.settings, seed=seed,
                            checkpoint=checkpoint, reference_point=prob.reference_point,
                            decision_weights=prob.decision_weights, progress=heartbeat, **budget)
    finally:
        if own:
            ev.close()
    return res, time.perf_counter() - t0


def run_record(prob, spec: RunSpec, res, wall_time_s: float, *, parts=None):
    """The result row (with the best candidate's report) and history of a finished run; with
    several objectives its front is written to ``parts``."""
    row = dict(case=spec.case, algorithm=spec.algorithm, optimiser_index=spec.optimiser_index,
               run=spec.run, seed=spec.root_seed, seed_key=spec.seed_key, best_f=float(res.f),
               feasible=bool(res.feasible), violation=float(res.violation), n_evals=int(res.n_evals),
               n_epochs=int(res.n_epochs), convergence_epoch=int(res.convergence_epoch),
               convergence_evals=_evals_at(res.history, res.convergence_epoch),
               wall_time_s=wall_time_s, stop_reason=res.stop_reason,
               settings=json.dumps(spec.settings, sort_keys=True))
    row.update(zip(prob.names, map(float, res.x)))
    _add_report(row, prob, res.x)
    hist = res.history.assign(case=spec.case, algorithm=spec.algorithm, optimiser_index=spec.optimiser_index,
                              run=spec.run)
    if res.front is not None:  # several objectives: the chosen point, the hypervolume, the front
        row.update({f"f_{name}": float(v) for name, v in zip(prob.objective_names, res.objectives)})
        row["hypervolume"] = 0.0 - float(res.f)
        hist["hypervolume"] = 0.0 - hist["best_f"]
        if parts is not None:
            write_parquet(_front_table(prob, res.front), Path(parts) / f"{spec.part_name}.pareto.parquet")
    return row, hist


def _evals_at(history: pd.DataFrame, epoch: int) -> int:
    """Evaluations spent by the end of ``epoch`` (the convergence point in evaluations, which
    compares optimisers that spend different evaluations per epoch)."""
    at = history.loc[history["epoch"] == epoch, "n_evals"]
    return int(at.iloc[0]) if len(at) else int(history["n_evals"].iloc[-1]) if len(history) else 0


def _front_table(prob, front: dict) -> pd.DataFrame:
    """The final front of a run: the gains, ``f_<objective>``, ``g_<constraint>``, violation,
    feasible and ``chosen`` (the decision step's pick)."""
    table = pd.DataFrame(front["X"], columns=list(prob.names))
    for j, name in enumerate(prob.objective_names):
        table[f"f_{name}"] = front["F"][:, j]
    for j, name in enumerate(prob.constraint_names):
        table[f"g_{name}"] = front["g"][:, j]
    table["violation"] = front["v"]
    table["feasible"] = front["v"] <= 0
    table["chosen"] = np.arange(len(table)) == front["chosen"]
    return table


def _run_key(prob, spec: RunSpec) -> str:
    """A short hash of what a run's local solves depend on: problem, optimiser, budget, seed."""
    payload = dict(
        problem=problem_fingerprint(prob),
        algorithm=spec.algorithm,
        settings=spec.settings,
        budget=spec.budget,
        seed=spec.root_seed,
        spawn_key=list(spec.spawn_key),
    )
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


class StartsFile(Checkpoint):
    """A run's finished local solves in one parquet file, rewritten atomically at each save.

    One row per solve: ``start, round, cap, x0_<name>..., <name>..., f, violation, feasible,
    nit, nfev, success, message``, then the constraint values at the kept point ``g_0, g_1,
    ...`` and ``run_key`` (what the solves depend on, see :func:`_run_key`). The records are a
    multistart driver's (``start, round, cap, x0, x, f, violation, g, nfev, nit, success,
    message``); floats go through parquet unchanged, so a resumed run is bit-identical.

    Parameters
    ----------
    path : path
        ``parts/<run>.starts.parquet``.
    names : sequence of str
        The decision variables.
    key : str
        The run's key; a file written under another key is refused (the config changed).
    """

    def __init__(self, path, names, key: str):
        self.path = Path(path)
        self.names = list(names)
        self.key = key

    def load(self) -> list:
        """The saved solves (a list of records); none when the file does not exist."""
        if not self.path.exists():
            return []
        try:
            df = pd.read_parquet(self.path)
            if len(df) and "run_key" not in df.columns:
                raise ValueError("no run_key column")
        except Exception as exc:  # truncated, empty or not parquet: its solves are redone
            set_aside_file(self.path, f"unreadable ({type(exc).__name__})")
            return []
        if len(df) and (df["run_key"] != self.key).any():
            raise ConfigError(f"{self.path} holds local solves of another configuration of this run; "
                              "use --fresh or another --out")
        gcols = sorted((c for c in df.columns if c.startswith("g_") and c[2:].isdigit()), key=lambda c: int(c[2:]))
        X0 = df[[f"x0_{n}" for n in self.names]].to_numpy(dtype=np.float64)
        X = df[self.names].to_numpy(dtype=np.float64)
        G = df[gcols].to_numpy(dtype=np.float64) if gcols else np.zeros((len(df), 0))
        records = []
        for i, r in enumerate(df.itertuples(index=False)):
            records.append(dict(start=int(r.start), round=int(r.round), cap=None if pd.isna(r.cap) else int(r.cap),
                                x0=X0[i], x=X[i], f=float(r.f), violation=float(r.violation), g=G[i],
                                nfev=int(r.nfev), nit=int(r.nit), success=bool(r.success), message=str(r.message)))
        return records

    def save(self, records) -> None:
        """Write ``records`` (every finished solve of the run) over the file, atomically."""
        n = len(records)
        X0 = np.array([r["x0"] for r in records], dtype=np.float64).reshape(n, len(self.names))
        X = np.array([r["x"] for r in records], dtype=np.float64).reshape(n, len(self.names))
        G = np.array([np.asarray(r["g"], dtype=np.float64).reshape(-1) for r in records]).reshape(n, -1)
        cols = {"start": [int(r["start"]) for r in records], "round": [int(r["round"]) for r in records],
                "cap": pd.array([r["cap"] for r in records], dtype="Int64")}
        cols.update({f"x0_{name}": X0[:, j] for j, name in enumerate(self.names)})
        cols.update({name: X[:, j] for j, name in enumerate(self.names)})
        violation = np.array([r["violation"] for r in records], dtype=np.float64)
        cols.update(f=np.array([r["f"] for r in records], dtype=np.float64), violation=violation,
                    feasible=violation == 0, nit=[int(r["nit"]) for r in records],
                    nfev=[int(r["nfev"]) for r in records], success=[bool(r["success"]) for r in records],
                    message=[str(r["message"]) for r in records])
        cols.update({f"g_{j}": G[:, j] for j in range(G.shape[1])})
        cols["run_key"] = [self.key] * n
        write_parquet(pd.DataFrame(cols), self.path)


RUN_STATUSES = ("feasible", "infeasible", "failed")


def run_status(prob, x) -> dict:
    """How a run's best candidate fares under the tuning scenario, for ``runs.parquet``.

    Parameters
    ----------
    prob : TuningProblem
    x : ndarray (d,)
        The run's best candidate.

    Returns
    -------
    dict
        ``status``: ``"feasible"``; ``"infeasible"`` (simulated, violates a constraint); or
        ``"failed"`` (no stable, simulable candidate was found: its ``best_f`` is the
        ``FAILED_OBJECTIVE`` sentinel, not a number to average). ``failure``: the reason of a
        failed candidate (``unstable``, ``diverged``, ``riccati_failed``, ...), else "".
    """
    ev = prob.evaluate(np.asarray(x, dtype=np.float64)[None, :])
    return _status(ev.reason[0], ev.feasible[0])


def _status(reason, feasible) -> dict:
    reason = str(reason)
    status = "failed" if reason else ("feasible" if bool(feasible) else "infeasible")
    return dict(status=status, failure=reason)


def _add_report(row: dict, prob, x):
    """The run's status (from its tuning scenario, or all of them aggregated when the problem
    is tuned robustly) and its metrics per scenario into ``row``."""
    with warnings.catch_warnings():  # said once, when the experiment starts
        warnings.simplefilter("ignore", StructureWarning)
        table = prob.report(x)
    if prob.robust is None:
        tuning = table.loc[prob.tuning_scenario]
        row.update(_status(tuning["reason"], tuning["feasible"]))
    else:
        row.update(run_status(prob, x))
    for scenario, values in table.iterrows():
        for key, value in values.items():
            row[f"{key}@{scenario}"] = value


def _execute_baseline(prob, spec: RunSpec):
    """An analytic design (e.g. GPM) as a run: one evaluation, no search."""
    t0 = time.perf_counter()
    x = prob.baseline(spec.algorithm)
    ev = prob.evaluate(x[None, :])
    viol = float(np.maximum(ev.g[0], 0.0).sum())
    row = dict(case=spec.case, algorithm=spec.algorithm, optimiser_index=spec.optimiser_index,
               run=spec.run, seed=spec.root_seed, seed_key=spec.seed_key, best_f=float(ev.f[0]),
               feasible=bool(ev.feasible[0]), violation=viol, n_evals=1, n_epochs=0, convergence_epoch=0,
               wall_time_s=time.perf_counter() - t0, stop_reason="analytic design",
               settings=json.dumps({}, sort_keys=True))
    row.update(zip(prob.names, map(float, x)))
    _add_report(row, prob, x)
    hist = pd.DataFrame(dict(epoch=[0], n_evals=[1], best_f=[float(ev.f[0])], best_violation=[viol],
                             mean_f=[float(ev.f[0])], sd_f=[0.0], feasible_fraction=[float(ev.feasible[0])],
                             wall_time_s=[time.perf_counter() - t0])).assign(
        case=spec.case, algorithm=spec.algorithm, optimiser_index=spec.optimiser_index, run=spec.run)
    return row, hist


def _git(*args) -> str | None:
    """Output of a git command run in the package's checkout; None outside one."""
    try:
        out = subprocess.run(["git", *args], capture_output=True, text=True,
                             cwd=Path(__file__).resolve().parent, timeout=5)
        return out.stdout.strip() if out.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


# The checkout's state is read once per process, when run_experiment first starts (before any
# run): a checkout pulled while a long process runs must not relabel what that process computed
# with the code it had imported.
@functools.lru_cache(maxsize=1)
def _git_commit() -> str:
    return _git("rev-parse", "HEAD") or ""


@functools.lru_cache(maxsize=1)
def _git_dirty() -> bool | None:
    """Whether the checkout has uncommitted changes to tracked files (None outside git)."""
    status = _git("status", "--porcelain", "--untracked-files=no")
    return None if status is None else bool(status)


def _platform() -> dict:
    """Where the experiment ran: OS, CPU, core count, and the BLAS libraries numpy loaded."""
    import os
    import platform

    from threadpoolctl import threadpool_info

    from heurtune.runner.machine import cpu_name

    blas = [{k: lib.get(k) for k in ("internal_api", "version", "threading_layer", "architecture", "num_threads")}
            for lib in threadpool_info() if lib.get("user_api") == "blas"]
    return dict(system=platform.platform(), machine=platform.machine(), cpu=cpu_name(), cpu_count=os.cpu_count(),
                blas=blas)


def _versions() -> dict:
    from importlib import metadata

    out = {"python": sys.version.split()[0]}
    for pkg in ("heurtune", "numpy", "scipy", "numba", "joblib", "control", "pandas", "pyarrow", "matplotlib"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


PLANNED_FILE = "planned.json"


def status_table(root, name: str | None = None) -> pd.DataFrame:
    """The result folders under ``root`` (those with a ``parts/`` folder; only ``root/name``
    when a name is given): runs done, runs planned by the last command that ran there, and
    whether all of them are done and gathered into ``runs.parquet``.

    Parameters
    ----------
    root : str or Path
        The folder holding result folders (``results``).
    name : str, optional
        Only this experiment's folder.

    Returns
    -------
    pandas.DataFrame
        Columns folder, experiment, done, planned (None when the folder predates
        ``planned.json``), complete, smoke (whether the last command was ``--smoke``, whose
        tiny budgets make results that are a check, not a study; None when not recorded).
    """
    root = Path(root)
    folders = [root / name] if name else sorted(p for p in root.iterdir() if (p / "parts").is_dir()) \
        if root.is_dir() else []
    rows = []
    for folder in folders:
        if not (folder / "parts").is_dir():
            raise ConfigError(f"{folder} holds no experiment results (no parts/ folder)")
        planned_file = folder / PLANNED_FILE
        try:
            planned = json.loads(planned_file.read_text()) if planned_file.exists() else None
            runs = None if planned is None else list(planned["runs"])
        except (ValueError, KeyError, TypeError):
            print(f"warning: {planned_file} is damaged; counting the run parts alone", file=sys.stderr)
            planned, runs = None, None
        names = sorted(_finished(folder / "parts")) if runs is None else runs
        done = matching_parts(folder / "parts", names, None if planned is None else planned.get("fingerprints"))
        rows.append(dict(folder=str(folder), experiment=planned["experiment"] if planned else folder.name,
                         done=len(done),
                         planned=None if runs is None else len(runs),
                         complete=runs is not None and set(runs) <= done and (folder / "runs.parquet").exists(),
                         smoke=planned.get("smoke") if isinstance(planned, dict) else None))
    return pd.DataFrame(rows, columns=["folder", "experiment", "done", "planned", "complete", "smoke"])


def _print_status(table: pd.DataFrame, stream=None) -> None:
    stream = stream or sys.stdout
    if table.empty:
        print("no result folders", file=stream)
    for r in table.itertuples(index=False):
        planned = "?" if r.planned is None or pd.isna(r.planned) else int(r.planned)
        state = "complete" if r.complete else "incomplete: run the same command to resume"
        smoke = "  (--smoke: tiny budgets, a check)" if r.smoke is True else ""
        print(f"{r.folder:40s} {r.experiment:24s} {r.done}/{planned} runs  {state}{smoke}", file=stream)


def _finished(parts: Path) -> set:
    return {p.name[:-len(".run.parquet")] for p in parts.glob("*.run.parquet")}


def _persist(parts: Path, spec: RunSpec, row: dict, hist: pd.DataFrame, fingerprint: dict):
    # History first; the run file marks the run finished. Both carry what made them: the run's
    # fingerprint, the source of this process (the parent's, read when it started) and when.
    origin = dict(git_commit=_git_commit(), git_dirty=_git_dirty(), written=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    meta = {METADATA_KEY: json.dumps(fingerprint, sort_keys=True).encode(),
            ORIGIN_KEY: json.dumps(origin).encode()}
    write_parquet(hist, parts / f"{spec.part_name}.history.parquet", meta)
    write_parquet(pd.DataFrame([row]), parts / f"{spec.part_name}.run.parquet", meta)
    (parts / f"{spec.part_name}{HEARTBEAT_SUFFIX}").unlink(missing_ok=True)


def run_experiment(name: str, *, runs=None, max_epochs=None, jobs: int = 1, seed=None, out=None,
                   smoke=False, fresh=False, backend="loky", scheduler=None, plugins=(),
                   progress_stream=None, figures=True, executor=None, device: str = "cpu",
                   lockstep: bool | None = None, force: bool = False, cases_alike: bool = False) -> Path:
    """Run (or resume) an experiment; returns its output folder. See the module docstring.

    ``jobs``, ``backend`` and ``scheduler`` say where the runs go (:class:`heurtune.core.execution.Pool`);
    an ``executor`` (any ``concurrent.futures.Executor``) takes whole runs instead. ``device``
    says where each evaluation's simulations run (:meth:`TuningProblem.set_device`). With
    ``lockstep`` the pending runs advance together, each generation's candidates of all runs of
    a case evaluated as one batch (:mod:`heurtune.core.lockstep`; same results); by default on
    for the batched devices.

    Before any run starts, one evaluation of every case is calibrated and the planned work
    printed (:mod:`heurtune.runner.workplan`); a case whose evaluation would take more than a
    minute is a ConfigError unless ``force``.

    Parameters
    ----------
    name : str
        A shipped experiment's name or a path to its ``.toml`` file.
    runs, max_epochs, seed : int, optional
        Override the config's runs per case and optimiser, generations and root seed.
    jobs : int
        Runs in parallel.
    out : str or Path, optional
        The output folder (default ``results/<name>``).
    smoke : bool
        Tiny budgets: a check, not a study.
    fresh : bool
        Start over: the folder's earlier results are removed.
    backend : {"loky", "dask"}
    scheduler : str, optional
        The Dask scheduler's address.
    plugins : sequence of str
        Plugins to load first (``--plugin``).
    progress_stream : file-like, optional
        Where the plan and the progress line go (default ``sys.stderr``).
    figures : bool
        Draw the figures.
    executor : concurrent.futures.Executor, optional
        Takes whole runs instead of the pool.
    device : {"cpu", "cpu-batch", "gpu"}
    lockstep : bool, optional
        Advance the pending runs together (default: on for the batched devices).
    force : bool
        Run even when one evaluation is predicted to take more than a minute.
    cases_alike : bool
        The cases are instances of one problem (the suite's): the first case with runs to do is
        calibrated (and checked for dead variables) for all of them.

    Returns
    -------
    Path
        The output folder.
    """
    if lockstep is None:
        lockstep = device != "cpu"
    _git_commit(), _git_dirty()  # the source this process runs, read before any run (see _git_commit)
    progress_stream = sys.stdout if progress_stream is None else progress_stream  # the current one
    load_plugins(plugins)
    config = load_config(name)
    if device != "cpu":
        config["device"] = device
    if plugins:
        config["plugins"] = list(config.get("plugins", [])) + [str(Path(p).resolve()) if p.endswith(".py") else p
                                                              for p in plugins]
    exp = make_experiment(config)
    exp.smoke = bool(smoke)
    if device != "cpu":  # an unknown device, or a GPU this machine lacks, fails here
        for case in exp.cases:
            _problem(config, case)
    out_dir = Path(out) if out else Path("results") / exp.name
    parts = out_dir / "parts"
    specs = plan(exp, runs=runs, max_epochs=max_epochs, seed=seed, smoke=smoke)
    # the cases with runs (a suite's config holds every instance, its optimiser tunes some)
    planned_cases = {s.case for s in specs}
    problems = {case: exp.problem(case) for case in exp.cases if case in planned_cases}
    ids = {case: problem_fingerprint(prob) for case, prob in problems.items()}
    fingerprints = {s.part_name: run_fingerprint(s, problems[s.case].identity()) for s in specs}
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"--out {out_dir} is a file, not a folder")
    # A first look, writing nothing: parts of another config are refused here. Each part file is
    # read once per command while it is unchanged (`part_tables`, :func:`read_part`).
    part_tables = {}
    if not fresh and parts.is_dir():
        check_parts(parts, specs, fingerprints, dry=True, cache=part_tables).refuse_mismatch(out_dir)
    done = set() if fresh or not parts.is_dir() else {s.part_name for s in specs} & _finished(parts)
    # Measured before anything is written: a config too costly to evaluate is refused here.
    with CompileNotice(exp.name, progress_stream):
        calibrations, shapes = _calibrate(exp, config, [s for s in specs if s.part_name not in done], force=force,
                                          alike=cases_alike)
    _make_folder(out_dir)
    lock = FolderLock(out_dir)
    lock.acquire()
    try:
        return _run_locked(exp, config, specs, fingerprints, ids, out_dir, parts, fresh=fresh, jobs=jobs,
                           backend=backend, scheduler=scheduler, executor=executor, device=device,
                           lockstep=lockstep, progress_stream=progress_stream, figures=figures,
                           calibrations=calibrations, shapes=shapes, cases_alike=cases_alike,
                           plan_key=dict(max_epochs=max_epochs, seed=seed, smoke=smoke), part_tables=part_tables)
    finally:
        lock.release()


def _make_folder(out_dir: Path) -> None:
    """Create the output folder, or say in one line why it cannot be."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe = out_dir / f".heurtune-write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"cannot write in {out_dir}: {exc.strerror or exc}") from None


def _run_locked(exp, config, specs, fingerprints, ids, out_dir, parts, *, fresh, jobs, backend, scheduler,
                executor, device, lockstep, progress_stream, figures, calibrations, shapes, plan_key, part_tables,
                cases_alike=False):
    """:func:`run_experiment` once it holds the folder's lock: check the parts, run what is
    missing, gather."""
    if fresh:
        clear_folder(out_dir)
    parts.mkdir(parents=True, exist_ok=True)
    check = check_parts(parts, specs, fingerprints, cache=part_tables)
    check.refuse_mismatch(out_dir)  # written meanwhile by another config
    done = check.reusable
    pending = [s for s in specs if s.part_name not in done]
    if any(s.case not in calibrations and not s.baseline for s in pending):  # parts set aside
        more, more_shapes = _calibrate(exp, config, [s for s in pending if s.case not in calibrations], force=True,
                                       alike=cases_alike)
        calibrations, shapes = {**calibrations, **more}, {**shapes, **more_shapes}
    with atomic_path(out_dir / "plan.json") as tmp:
        tmp.write_text(json.dumps(plan_key))
    with atomic_path(out_dir / PLANNED_FILE) as tmp:  # what --status compares the parts with
        tmp.write_text(
            json.dumps(
                dict(
                    experiment=exp.name,
                    runs=[s.part_name for s in specs],
                    fingerprints={s.part_name: fingerprint_digest(fingerprints[s.part_name]) for s in specs},
                    smoke=bool(plan_key.get("smoke")),
                )
            )
        )
    structure_warnings = exp.structure_warnings()
    for case, msg in structure_warnings.items():
        print(f"warning: {case}: {msg}", file=sys.stderr)
    clear_heartbeats(parts)
    kept = [read_part(parts / f"{s.part_name}.run.parquet", cache=part_tables)[0].iloc[0] for s in specs
            if s.part_name in done]
    on_pool = backend != "dask" and executor is None
    workers = (jobs if on_pool or not pending else  # a Dask cluster is asked only when there is work
               _dask_workers(scheduler) if executor is None else getattr(executor, "_max_workers", jobs))
    planned, plan_line, rate = _planned_work(pending, calibrations, shapes, workers)
    bar = Progress(len(specs), len(specs) - len(pending), progress_stream, finished_rows=kept, planned=planned,
                   parts=parts, predicted_rate=rate)
    try:
        if pending:
            where = (f"{jobs} worker(s)" if on_pool else
                     f"the Dask cluster at {scheduler} ({workers} workers)" if executor is None
                     else "the given executor")
            if device != "cpu":
                where += f", simulations on {device}"
            if lockstep:
                where += ", runs in lockstep"
            print(f"{exp.name}: {len(pending)} of {len(specs)} runs to do ({len(done)} already done), "
                  f"{where}, output {out_dir}", file=progress_stream)
            if plan_line:
                print(plan_line, file=progress_stream)
            bar.start()
            pending_runs = [s for s in pending if not s.baseline]  # the items of the whole-runs pool
            try:
                _run_pending(config, pending, parts, bar, fingerprints, jobs=jobs, backend=backend,
                             scheduler=scheduler, executor=executor, lockstep=lockstep)
            except Exception as exc:
                if not (isinstance(exc, WorkerDied) or is_worker_death(exc)):
                    raise
                kill_workers()
                kept = len(_finished(parts) & {s.part_name for s in specs})
                index = getattr(exc, "index", None)
                which = f"run {pending_runs[index].part_name}" if index is not None else "one of the runs"
                raise ConfigError(f"a worker process died (killed, or out of memory?) during {which}; "
                                  f"the {kept} finished run(s) are kept in {out_dir}: run the same command "
                                  "again to resume") from None
        bar.close()  # the line ends before the summary
        _gather(exp, specs, parts, out_dir, ids, config, plan_key, structure_warnings, fingerprints, figures=figures,
                part_tables=part_tables)
    except (KeyboardInterrupt, Terminated, SystemError) as exc:
        signal_exc = _signal_of(exc)
        if signal_exc is None:
            raise
        kill_workers()
        kept = len(_finished(parts) & {s.part_name for s in specs})
        raise Interrupted(143 if isinstance(signal_exc, Terminated) else 130, kept, len(specs), out_dir) from None
    finally:
        bar.close()
    return out_dir


def _calibrate(exp, config, pending, *, force: bool, alike: bool = False) -> dict:
    """Calibrate one evaluation of every case with runs to do (a fresh problem each, on the
    configured device); refuse a case whose evaluation would exceed the limit unless ``force``.
    With ``alike`` (instances of one problem) the first such case stands for all of them."""
    cases = sorted({s.case for s in pending if not s.baseline}, key=list(exp.cases).index)
    calibrations, shapes = {}, {}
    for case in cases[:1] if alike else cases:
        prob = exp.problem(case)
        prob.set_device(config.get("device", "cpu"))
        calibrations[case] = calibrate(prob)
        shapes[case] = (prob.dim, len(prob.constraint_names), len(prob.objective_names or ()) or 1)
    if alike and cases:
        first = calibrations[cases[0]]
        for case in cases[1:]:
            calibrations[case] = dataclasses.replace(first, case=case)
            shapes[case] = shapes[cases[0]]
        cases = cases[:1]
    calibrations = borrow_step_cost(calibrations)
    if not force:
        for cal in calibrations.values():
            check_evaluation_time(cal)
    if not getattr(exp, "smoke", False):  # a smoke run is a quick check; check_plugin checks structures
        for case in cases:  # after the cost check: a case too costly to evaluate is refused first
            _warn_dead_variables(exp, case, calibrations[case], shapes[case][0])
    return calibrations, shapes


# The dead-variable check (heurtune.core.dead_variables) is left out where its evaluations
# (8 draws, then about one move per variable and point) would take longer than this.
DEAD_VARIABLE_CHECK_S = 10.0


def _warn_dead_variables(exp, case, cal, dim: int) -> None:
    """One warning line for the case's variables that change nothing its problem reports."""
    per_eval = cal.evaluation_s
    if not (math.isfinite(per_eval) and per_eval * (8 + 2 * dim) <= DEAD_VARIABLE_CHECK_S):
        return
    dead = dead_variables(exp.problem(case))
    if dead:
        one = len(dead) == 1
        config_warning(f"{exp.name}: case {case!r}: {', '.join(dead)} change{'s' if one else ''} nothing the problem "
                       f"reports (the structure does not read {'it' if one else 'them'}, or the scenario does not "
                       f"exercise {'it' if one else 'them'}, as a set-point weight without a set-point step); the "
                       f"optimisers search {'it' if one else 'them'} in vain")


def _planned_work(pending, calibrations, shapes, workers) -> tuple:
    """The planned evaluations of every pending run (part name to ``(case, algorithm, count or
    None)``), the plan line (None with nothing calibrated) and the predicted evaluations per
    second."""
    planned, per_case = {}, {}
    for spec in pending:
        n, exact = planned_evaluations(spec, *shapes[spec.case]) if not spec.baseline else (1, True)
        planned[spec.part_name] = (spec.case, spec.algorithm, n)
        if spec.case in calibrations:
            count, unknown, estimated = per_case.get(spec.case, (0, 0, False))
            per_case[spec.case] = (count + (n or 0), unknown + (n is None), estimated or (n is not None and not exact))
    if not calibrations:
        return planned, None, None
    line, seconds = estimate_line(calibrations, per_case, len(pending), workers)
    evals = sum(n for n, _, _ in per_case.values())
    return planned, line, evals / seconds if seconds > 0 and math.isfinite(seconds) else None


def _dask_workers(scheduler) -> int:
    """The number of workers of the Dask cluster at ``scheduler`` (an address or a Client)."""
    with Pool(1, "dask", scheduler) as pool:
        return pool.workers


def _run_pending(config, pending, parts, bar, fingerprints, *, jobs, backend, scheduler, executor=None,
                 lockstep=False):
    for spec in [s for s in pending if s.baseline]:  # analytic designs: one evaluation each
        row, hist = execute(config, spec)
        _persist(parts, spec, row, hist, fingerprints[spec.part_name])
        bar.update(row, spec.part_name)
    pending = [s for s in pending if not s.baseline]
    if not pending:
        return
    if lockstep:
        _run_lockstep(config, pending, parts, bar, fingerprints, jobs=jobs, backend=backend, scheduler=scheduler,
                      executor=executor)
        return
    # Runs whose driver keeps every worker busy by itself (multistart SQP without a budget): one
    # after another, each over all the workers. The others: whole runs on the workers when there
    # are enough of them, else one after another, each spreading its batches.
    on_pool = backend != "dask" and executor is None
    spread = [i for i, s in enumerate(pending) if jobs > 1 and on_pool and _spreads_work(s)]
    rest = sorted(set(range(len(pending))) - set(spread))
    whole_runs = backend == "dask" or executor is not None or (jobs > 1 and len(rest) >= jobs)
    for i in spread + ([] if whole_runs else rest):
        spec = pending[i]
        prob = _problem(config, spec.case)
        try:
            with Evaluator(prob, n_jobs=jobs) as ev:
                row, hist = execute(config, spec, ev, parts=parts)
        except Exception as exc:
            if is_worker_death(exc) or isinstance(exc, WorkerDied):  # a worker of this run's evaluations died
                raise WorkerDied(i, exc) from exc
            raise
        _persist(parts, spec, row, hist, fingerprints[spec.part_name])
        bar.update(row, spec.part_name)
    if not whole_runs or not rest:
        return
    # Whole runs on the workers (each evaluating in its own process); the kernels are warmed
    # here first, so that the workers load them from the cache.
    whole = [pending[i] for i in rest]
    _problem(config, whole[0].case).warm_up()
    pool = Pool(jobs, backend, scheduler, executor=executor)
    try:
        with pool:
            for j, (row, hist) in pool.imap_unordered(functools.partial(execute, config, parts=parts), whole):
                _persist(parts, whole[j], row, hist, fingerprints[whole[j].part_name])
                bar.update(row, whole[j].part_name)
    except WorkerDied as exc:
        pool.abort()
        raise WorkerDied(rest[exc.index], exc) from exc
    except BaseException:
        pool.abort()
        raise


def _spreads_work(spec: RunSpec) -> bool:
    """Whether the run's optimiser keeps every worker busy by itself (a driver whose
    ``spreads_work(budget)`` says so), so that it runs alone over all the workers."""
    spreads = getattr(registry.get(spec.algorithm).cls, "spreads_work", None)
    return bool(spreads is not None and spreads(spec.budget))


def _run_lockstep(config, pending, parts, bar, fingerprints, *, jobs, backend, scheduler, executor=None):
    """All pending runs in lockstep (:class:`heurtune.core.lockstep.Lockstep`): each generation,
    the candidates of every run of a case are evaluated as one batch, spread over the workers
    of one pool that holds every case's problem."""
    objectives = Objectives({case: Objective(_problem(config, case)) for case in sorted({s.case for s in pending})})
    objectives.warm_up()
    pool = Pool(jobs, backend, scheduler, executor=executor, shared=objectives)
    # A batched simulation gains from long chunks: one per worker and case on those devices.
    per_worker = CHUNKS_PER_WORKER if config.get("device", "cpu") == "cpu" else 1
    hub = Lockstep(functools.partial(evaluate_groups, pool, per_worker=per_worker))
    try:
        with pool:
            # The runs' threads only optimise; each finished run is recorded here, so that the
            # problems are used by this thread alone (their simulators keep scratch state).
            targets = [functools.partial(optimise, config, spec, hub.client(spec.case), parts=parts)
                       for spec in pending]
            for i, (res, wall) in hub.run(targets):
                spec = pending[i]
                row, hist = run_record(_problem(config, spec.case), spec, res, wall, parts=parts)
                _persist(parts, spec, row, hist, fingerprints[spec.part_name])
                bar.update(row, spec.part_name)
    except BaseException:
        pool.abort()
        raise


def _gather(exp, specs, parts, out_dir, ids, config, plan_key, structure_warnings, fingerprints, *, figures,
            part_tables=None):
    rows, hists, origins = [], [], {}
    for spec in specs:
        run_file = parts / f"{spec.part_name}.run.parquet"
        if not run_file.exists():
            continue
        try:  # each part against its file name and the run the config plans under it
            row, found = read_part(run_file, spec, cache=part_tables)
            hist, hist_found = read_part(parts / f"{spec.part_name}.history.parquet", cache=part_tables)
            origins[spec.part_name] = part_origin(run_file, cache=part_tables)
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(f"{run_file} changed while the experiment ran ({exc}); run the same command "
                              "again to redo it") from None
        keys = differing_keys(found or {}, fingerprints[spec.part_name])
        if keys or hist_found != found:
            raise ConfigError(f"{run_file} was written by another config while the experiment ran "
                              f"(differing: {', '.join(keys) or 'history'}); run the same command again")
        rows.append(row)
        hists.append(hist)
    runs = pd.concat(rows, ignore_index=True)
    runs.insert(0, "experiment", exp.name)
    runs.insert(3, "controller", [exp.controller_of(c) for c in runs["case"]])
    runs.insert(4, "problem_id", [ids[c] for c in runs["case"]])
    history = pd.concat(hists, ignore_index=True)
    history.insert(0, "experiment", exp.name)
    lead = ["experiment", "case", "algorithm", "optimiser_index", "run"]
    history = history[lead + [c for c in history.columns if c not in lead]]
    write_parquet(runs, out_dir / "runs.parquet")
    write_parquet(history, out_dir / "history.parquet")
    _gather_starts(exp, specs, parts, out_dir, history)
    pareto = _gather_parts(exp, specs, parts, "pareto")
    if pareto is not None:
        write_parquet(pareto, out_dir / "pareto.parquet")
    meta = dict(experiment=exp.name, config=config, plan=plan_key, root_seed=specs[0].root_seed,
                structure_warnings=structure_warnings,
                seeds={s.part_name: dict(seed=s.root_seed, spawn_key=list(s.spawn_key)) for s in specs},
                problem_ids=ids, versions=_versions(), git_commit=_git_commit(), git_dirty=_git_dirty(),
                run_origins=origins, platform=_platform(),
                written=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    with atomic_path(out_dir / "meta.json") as tmp:
        tmp.write_text(json.dumps(meta, indent=2, default=str))
    best = best_runs(runs)
    tables = []
    for _, r in best.iterrows():
        prob = exp.problem(r["case"])
        try:
            m = prob.margins(np.array([r[n] for n in prob.names]))
        except Exception as exc:  # a best candidate whose design fails: recorded, not raised
            print(f"warning: {r['case']}: no margins for the best {r['algorithm']} run ({type(exc).__name__}: "
                  f"{exc})", file=sys.stderr)
            m = pd.DataFrame([dict(failure=f"{type(exc).__name__}: {exc}")])
        if m is not None:
            tables.append(m.assign(experiment=exp.name, case=r["case"], algorithm=r["algorithm"], run=r["run"]))
    if tables:
        margins = pd.concat(tables, ignore_index=True)
        lead = ["experiment", "case", "algorithm", "run"]
        write_parquet(margins[lead + [c for c in margins.columns if c not in lead]], out_dir / "margins.parquet")
    exp.write_outputs(out_dir, runs=runs, history=history, best=best, figures=figures)
    if figures:
        _figures(exp, runs, history, best, out_dir)
    write_parquet(summary_table(runs, exp), out_dir / "summary.parquet")
    print_summary(runs, exp)


def _gather_parts(exp, specs, parts, kind: str) -> pd.DataFrame | None:
    """The ``parts/<run>.<kind>.parquet`` tables of the finished runs in one table, led by
    experiment, case, algorithm, optimiser_index, run (None when there are none)."""
    tables = []
    for spec in specs:
        path = parts / f"{spec.part_name}.{kind}.parquet"
        if (parts / f"{spec.part_name}.run.parquet").exists() and path.exists():
            tables.append(pd.read_parquet(path).assign(experiment=exp.name, case=spec.case, algorithm=spec.algorithm,
                                                       optimiser_index=spec.optimiser_index, run=spec.run))
    if not tables:
        return None
    table = pd.concat(tables, ignore_index=True)
    lead = ["experiment", "case", "algorithm", "optimiser_index", "run"]
    return table[lead + [c for c in table.columns if c not in lead]]


def _gather_starts(exp, specs, parts, out_dir, history):
    """``starts.parquet``: every local solve of the finished multistart runs (none: no file).

    Columns: experiment, case, algorithm, optimiser_index, run, start, round, cap, x0_<name>
    (start point), <name> (the point kept), f, violation, feasible, nit, nfev, success, message.

    Only the rounds the run closed (its epochs in ``history``) are kept. A run that stops at
    ``max_epochs`` lets the solves already begun end, and they are saved for a resume; how
    many of them there are depends on the workers and the scheduling, so they are left out
    here and the file is the same whatever the number of workers, with or without lockstep.
    """
    starts = _gather_parts(exp, specs, parts, "starts")
    if starts is not None:
        kept_apart = [c for c in starts.columns if c == "run_key" or (c.startswith("g_") and c[2:].isdigit())]
        starts = starts.drop(columns=kept_apart)
        key = ["case", "algorithm", "optimiser_index", "run"]
        last = history.groupby(key)["epoch"].max().rename("_last_epoch").reset_index()
        starts = starts.merge(last, on=key, how="left")
        starts = starts[starts["round"] <= starts["_last_epoch"]].drop(columns="_last_epoch").reset_index(drop=True)
        write_parquet(starts, out_dir / "starts.parquet")


def _figures(exp, runs, history, best, out_dir):
    for case in exp.cases:
        h = history[history["case"] == case]
        if h.empty:  # no run of this case (e.g. its only baseline has no design for it)
            continue
        prob = exp.problem(case)
        failed = runs[(runs["case"] == case) & (runs.get("status") == "failed")] if "status" in runs else runs[:0]
        ylabel, sign = figures.best_f_axis(prob)  # several objectives: the hypervolume
        figures.convergence_figure(figures.shown_best_f(h, sign), out_dir / f"convergence_{_slug(case)}.png", case=case,
                                   failures={case: list(failed.get("failure", []))}, ylabel=ylabel)
        b = best[best["case"] == case].sort_values(["feasible", "best_f"], ascending=[False, True]).head(1)
        if len(b):
            r = b.iloc[0]
            x = np.array([r[n] for n in prob.names])
            title = f"{exp.name} / {case}: best of {r['algorithm']} (run {r['run']})"
            if r.get("status", "feasible") != "feasible":  # say so: the "best" is not a solution
                title += f": {r['status']}" + (f" ({r['failure']})" if r.get("failure") else "")
            figures.response_figure(prob, x, out_dir / f"responses_{_slug(case)}.png",
                                    scenarios=tuple(prob.scenarios), title=title)
    axes = {figures.best_f_axis(exp.problem(case)) for case in exp.cases}
    (ylabel, sign), = axes if len(axes) == 1 else ((None, 1.0),)  # the cases' common axis, if any
    if sign < 0 and "hypervolume" in runs:  # several objectives: the runs' hypervolume column
        figures.boxplot_figure(runs, out_dir / "boxplot_best_f.png", metric="hypervolume", ylabel=ylabel)
    else:
        figures.boxplot_figure(runs, out_dir / "boxplot_best_f.png", ylabel=ylabel if sign > 0 else None)
    if (out_dir / "pareto.parquet").exists():  # several objectives: the best front per optimiser
        fronts = pd.read_parquet(out_dir / "pareto.parquet")
        for case in exp.cases:
            keys = best.loc[best["case"] == case, ["algorithm", "run"]].itertuples(index=False)
            sel = fronts[
                (fronts["case"] == case)
                & pd.Series(list(zip(fronts["algorithm"], fronts["run"])), index=fronts.index).isin(list(keys))
            ]
            if len(sel):
                prob = exp.problem(case)
                figures.pareto_figure(sel, out_dir / f"pareto_{_slug(case)}.png", prob.objective_names,
                                      title=f"{exp.name} / {case}: final fronts of the best runs (star: chosen)",
                                      axis_labels=[prob.objective_axis_label(n) for n in prob.objective_names])



def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in text)


def summary_table(runs: pd.DataFrame, exp) -> pd.DataFrame:
    """One row per (case, optimiser): the statistics of the printed summary, as data.

    Columns: case, algorithm, optimiser_index, runs, successes (runs that did not fail and whose
    best candidate is feasible), feasible_runs (runs whose best candidate is feasible: a count,
    where ``runs.parquet``'s ``feasible`` is each run's flag), failed (no
    stable, simulable candidate), best, mean, sd, median, worst (of
    ``best_f`` over the successful runs, :func:`heurtune.analysis.compare.successful_runs`: a failed
    run's ``best_f`` is a sentinel and an infeasible run's answers another question, so both are
    counted, not averaged; NaN when no run succeeded, and sd NaN below two successes, as in
    ``compare``), conv_epoch, conv_evals (the convergence
    point in evaluations; NaN for runs written before it was recorded) and n_evals (means over
    all runs), wall_s (summed), best_run, and the best run's gains (one column per variable).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of ``runs.parquet``.
    exp : ExperimentBase
        The experiment (its variable names).

    Returns
    -------
    pandas.DataFrame
    """
    rows = []
    for (case, oi), grp in runs.groupby(["case", "optimiser_index"], sort=False):
        failed = failed_runs(grp)
        f = grp.loc[successful_runs(grp), "best_f"]
        best = best_runs(grp).iloc[0]
        row = {
            "case": case, "algorithm": grp["algorithm"].iloc[0], "optimiser_index": int(oi), "runs": len(grp),
            "successes": int(successful_runs(grp).sum()),
            "feasible_runs": int(grp["feasible"].sum()), "failed": int(failed.sum()),
            "best": f.min(), "mean": f.mean(), "sd": f.std(ddof=1) if len(f) > 1 else np.nan,
            "median": f.median(), "worst": f.max(),
            "conv_epoch": grp["convergence_epoch"].mean(),
            "conv_evals": grp["convergence_evals"].mean() if "convergence_evals" in grp else np.nan,
            "n_evals": grp["n_evals"].mean(),
            "wall_s": grp["wall_time_s"].sum(), "best_run": int(best["run"]),
        }
        row.update({n: float(best[n]) for n in exp.problem(case).names})
        rows.append(row)
    return pd.DataFrame(rows)


def print_summary(runs: pd.DataFrame, exp, stream=None):
    """Per case and optimiser: best, mean, SD, median, worst objective over the successful runs,
    feasible runs, failed runs, mean convergence epoch and evaluations, wall time and the best gains
    (:func:`summary_table`), to ``stream`` (default: the ``sys.stdout`` of the call)."""
    stream = sys.stdout if stream is None else stream
    summary = summary_table(runs, exp)
    table = summary[["case", "algorithm", "runs", "best", "mean", "sd", "median", "worst"]].assign(
        feasible=[f"{a}/{b}" for a, b in zip(summary["feasible_runs"], summary["runs"])], failed=summary["failed"],
        conv_epoch=summary["conv_epoch"], conv_evals=summary["conv_evals"], wall_s=summary["wall_s"])
    table["best gains"] = [" ".join(f"{n}={row[n]:.4g}" for n in exp.problem(row["case"]).names)
                           for _, row in summary.iterrows()]
    with pd.option_context("display.width", 250, "display.max_columns", 20, "display.max_colwidth", 120,
                           "display.float_format", "{:.2f}".format):
        print(table.to_string(index=False), file=stream)


def _parser():
    ap = argparse.ArgumentParser(prog="python -m heurtune.experiment", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=exit_codes(("python -m heurtune.experiment cs_folqi_qtp --jobs 2",
                                                    "python -m heurtune.experiment thesis_ch5 --smoke --out /tmp/ch5",
                                                    "python -m heurtune.experiment my_config.toml --plugin my_opt.py",
                                                    "python -m heurtune.experiment --status"),
                                                   c130="interrupted by Ctrl-C",
                                                   c143="stopped by SIGTERM (after either, the finished runs are "
                                                        "kept and the same command resumes)"))
    ap.add_argument("name", nargs="?", help="experiment name (experiments/<name>.toml) or a .toml path")
    ap.add_argument("--runs", type=int, help="runs per case and optimiser (overrides the config)")
    ap.add_argument("--max-epochs", type=int, help="generation budget of every optimiser (overrides the config)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--seed", type=int, help="root seed (overrides the config)")
    ap.add_argument("--out", help="output folder (default results/NAME)")
    ap.add_argument("--smoke", action="store_true", help="tiny budgets, same problem: a quick check")
    ap.add_argument("--fresh", action="store_true", help="discard earlier results in the output folder")
    ap.add_argument("--backend", default="loky", help="loky (default) or dask")
    ap.add_argument("--device", default="cpu",
                    help="where the simulations run: cpu (default, one candidate at a time), cpu-batch "
                         "(a batch of candidates in one compiled call) or gpu (CUDA; pip install 'heurtune[gpu]')")
    ap.add_argument("--lockstep", action=argparse.BooleanOptionalAction, default=None,
                    help="advance the runs together, each generation of all runs evaluated as one batch "
                         "(same results; default: on with --device cpu-batch or gpu)")
    ap.add_argument("--scheduler", help="Dask scheduler address, with --backend dask")
    ap.add_argument(
        "--plugin",
        action="append",
        default=[],
        help="plugin (optimisers, a plant family or controller structures): a .py file or module; repeatable",
    )
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    ap.add_argument("--force", action="store_true",
                    help="run even when one evaluation is calibrated to take over a minute")
    ap.add_argument("--list", action="store_true", help="list the experiments")
    ap.add_argument("--status", action="store_true",
                    help="list the result folders under results/ (or --out) with runs done / planned; "
                         "with NAME only that experiment's")
    ap.add_argument("--list-algorithms", action="store_true", help="list the optimisers with their settings")
    return ap


def run(argv=None) -> int:
    """Command-line entry point; returns the exit code (130 after Ctrl-C, 143 after SIGTERM)."""
    args = _parser().parse_args(argv)
    with sigterm_raises():
        return _run(args)


def _run(args) -> int:
    """:func:`run` on parsed arguments, SIGTERM raising :class:`Terminated`."""
    try:
        for spec in args.plugin:
            load_registering_plugin(spec)
        if args.list:
            for name in list_experiments():
                print(f"{name:24s} {load_config(name).get('description', '')}")
            return 0
        if args.status:
            root = Path(args.out) if args.out else Path("results")
            if args.out and (root / "parts").is_dir():  # --out names one result folder
                root, only = root.parent, root.name
            else:
                only = args.name
            _print_status(status_table(root, only))
            return 0
        if args.list_algorithms:
            for name in registry.available():
                print(registry.describe(name))
            return 0
        if not args.name:
            raise ConfigError("name an experiment (--list shows them)")
        for key in ("runs", "max_epochs", "jobs", "seed"):
            value = getattr(args, key)
            if value is not None and value < (0 if key in ("max_epochs", "seed") else 1):
                least = ">= 0" if key in ("max_epochs", "seed") else ">= 1"
                raise ConfigError(f"--{key.replace('_', '-')} must be {least}, got {value}")
        if args.backend not in BACKENDS:
            raise ConfigError(f"unknown backend {args.backend!r}; allowed: {', '.join(BACKENDS)}")
        if args.backend == "dask" and not args.scheduler:
            raise ConfigError("--backend dask needs --scheduler ADDRESS")
        run_experiment(args.name, runs=args.runs, max_epochs=args.max_epochs, jobs=args.jobs, seed=args.seed,
                       out=args.out, smoke=args.smoke, fresh=args.fresh, backend=args.backend,
                       scheduler=args.scheduler, plugins=args.plugin, figures=not args.no_figures,
                       device=args.device, lockstep=args.lockstep, force=args.force)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # stdout closed by its reader (--list | head): main() ends quietly
        raise
    except OSError as exc:  # a full or read-only disk, a folder removed under the run
        kill_workers()
        where = exc.filename or args.out or "the output folder"
        print(f"error: {where}: {exc.strerror or exc}; the finished runs are kept: fix that and run the same "
              "command again", file=sys.stderr)
        return 2
    except Interrupted as exc:
        print(f"\ninterrupted: {exc.kept} of {exc.planned} runs kept in {exc.out_dir}; "
              "run the same command again to resume", file=sys.stderr)
        return exc.code
    except (KeyboardInterrupt, Terminated, SystemError) as exc:
        code = signal_exit(exc)
        if code is None:
            raise
        print("\ninterrupted before any run started", file=sys.stderr)
        return code
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    code = _startup.run_command(run)
    if code in (130, 143):
        # Leave at once: loky's manager threads and the runs' threads may still be winding
        # down, and the interpreter's exit would wait for them; the finished runs are on disk.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
