"""The work an experiment plans, measured before it starts.

Two numbers tell a user what a command will cost before it spends it:

* **planned evaluations** of every run (:func:`planned_evaluations`): the run's ``max_evals``, or,
  for a population optimiser stopped by ``max_epochs``, the count of a dry run of the same
  optimiser, settings and budget on a cheap stand-in objective (population optimisers spend a
  number of evaluations per generation that does not depend on the values; a ``tol`` or
  ``max_time`` can only stop a run earlier, so the count is then an upper bound). A driver
  without ``max_evals`` (multistart SQP solving until its local solves converge) has no count
  known in advance: None.
* **seconds per evaluation** of every case (:func:`calibrate`): a handful of candidates drawn in
  the box are evaluated on the experiment's device under the tuning scenario cut to two short
  horizons. The time grows linearly in the simulated steps, so the two timings give a fixed
  cost per candidate (design, checks) and a cost per simulated step; with the steps of the
  scenarios one evaluation simulates (:meth:`TuningProblem.evaluation_scenarios`) they predict
  the cost of one evaluation of a simulated candidate, the work users wait for, however long
  the configured horizon. A configuration whose evaluation would take over
  :data:`EVALUATION_LIMIT_S` is refused with a one-line error naming the scenario keys
  (:func:`check_evaluation_time`), before anything is run.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import threading
import time

import numpy as np

from heurtune.core import registry
from heurtune.core.engine import SearchSpace
from heurtune.core.engine import run as run_optimiser
from heurtune.core.errors import ConfigError
from heurtune.core.evaluator import Evaluator

__all__ = [
    "Calibration",
    "CompileNotice",
    "calibrate",
    "borrow_step_cost",
    "check_evaluation_time",
    "planned_evaluations",
    "estimate_line",
    "format_duration",
    "EVALUATION_LIMIT_S",
]

# A single evaluation predicted to take longer than this is refused (unless --force).
EVALUATION_LIMIT_S = 60.0
# Candidates timed per case, and the simulated steps of the longer of the two calibration horizons.
CALIBRATION_CANDIDATES = 8
CALIBRATION_STEPS = 20_000
CALIBRATION_SEED = 20261128  # fixed, and apart from every run's seed


def format_duration(seconds: float) -> str:
    """``"0.8 s"``, ``"42 s"``, ``"3 min 20 s"``, ``"2 h 05 min"`` or ``"3.2 days"``.

    Parameters
    ----------
    seconds : float

    Returns
    -------
    str
    """
    if not math.isfinite(seconds):
        return "for ever"
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    if seconds < 3 * 86400:
        return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"
    return f"{seconds / 86400:.1f} days"


# -- planned evaluations -----------------------------------------------------------------------
def planned_evaluations(spec, dim: int, n_constraints: int, n_objectives: int = 1) -> tuple:
    """Evaluations a run will spend (see the module docstring): ``(count, exact)``.

    ``count`` is None when not known in advance (a driver without ``max_evals``, a run stopped
    by ``max_time`` alone); ``exact`` is
    False when the count is an estimate: the dry runs on two different stand-in objectives
    disagree (gradient methods, whose line searches depend on the values; the larger count is
    given), or a ``tol`` or ``max_time`` may stop the run earlier. A baseline is one evaluation.

    Parameters
    ----------
    spec : RunSpec
    dim : int
        Decision variables.
    n_constraints : int
    n_objectives : int

    Returns
    -------
    tuple
        ``(count, exact)``.
    """
    if spec.baseline:
        return 1, True
    budget = spec.budget
    may_stop_early = "tol" in budget or "max_time" in budget
    if registry.get(spec.algorithm).kind == "driver":
        return budget.get("max_evals"), False  # at most its cap
    if "max_evals" not in budget and "max_epochs" not in budget and "max_time" in budget:
        return None, False  # stopped by the clock alone
    key = json.dumps(dict(algorithm=spec.algorithm, settings=spec.settings, dim=dim, m=n_constraints,
                          k=n_objectives, max_evals=budget.get("max_evals"), max_epochs=budget.get("max_epochs")),
                     sort_keys=True)
    counts = {_dry_run(key, shape) for shape in STAND_INS}
    return max(counts), len(counts) == 1 and not may_stop_early


# Two stand-in objectives of different shape: a sphere, and a tilted valley with a ripple.
STAND_INS = ("sphere", "valley")


def _stand_in(X, m: int, k: int, shape: str):
    """A cheap objective for counting, one column per objective around different centres, and
    constraints that are always met."""
    cols = []
    for j in range(k):
        Z = X - 0.5 + 0.1 * j
        if shape == "sphere":
            cols.append((Z ** 2).sum(axis=1))
        else:
            cols.append(10 * ((Z[:, 1:] - Z[:, :-1] ** 2) ** 2).sum(axis=1) + np.sin(7 * Z).sum(axis=1) + 3 * Z[:, 0])
    F = np.stack(cols, axis=1)
    return (F[:, 0] if k == 1 else F), np.full((len(X), m), -1.0)


@functools.lru_cache(maxsize=256)
def _dry_run(key: str, shape: str) -> int:
    spec = json.loads(key)
    dim, k = spec["dim"], spec["k"]
    space = SearchSpace(np.zeros(dim), np.ones(dim))
    budget = dict(max_evals=spec["max_evals"], max_epochs=spec["max_epochs"])
    with Evaluator(functools.partial(_stand_in, m=spec["m"], k=k, shape=shape)) as ev:
        res = run_optimiser(spec["algorithm"], ev, space, settings=spec["settings"], seed=0,
                            reference_point=[100.0 * dim] * k if k > 1 else None, **budget)
    return int(res.n_evals)


# -- calibration --------------------------------------------------------------------------------
def _step(scenario) -> float | None:
    """Simulated seconds per kernel step of a scenario: its ``kernel_step`` where it has one (a
    QTP scenario, sampled or continuous), else its ``dt``."""
    return getattr(scenario, "kernel_step", None) or getattr(scenario, "dt", None)


def _steps(scenario) -> int | None:
    horizon, dt = getattr(scenario, "horizon", None), _step(scenario)
    try:
        return round(float(horizon) / float(dt))
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None


@dataclasses.dataclass(frozen=True)
class Calibration:
    """What one evaluation of a case costs on this machine and device.

    Attributes
    ----------
    case : str
    steps : int or None
        Simulated steps of one evaluation, summed over the scenarios it simulates (None when
        the scenarios do not say their ``horizon`` and ``dt``).
    fixed_s : float
        Seconds per candidate that do not grow with the horizon (design, stability checks).
    step_s : float or None
        Seconds per simulated step of one candidate (None when no calibration candidate was
        simulated, or the horizon could not be cut).
    simulated : int
        Distinct simulated candidates timed (candidates rejected before simulation are set
        aside; fewer than asked for are repeated to a full batch).
    candidates : int
        Candidates drawn.
    horizons : str
        The scenario lengths behind the figure, for the plan line.
    """

    case: str
    steps: int | None
    fixed_s: float
    step_s: float | None
    simulated: int
    candidates: int
    horizons: str

    @property
    def evaluation_s(self) -> float:
        """Predicted seconds of one evaluation of a simulated candidate."""
        if self.step_s is None or self.steps is None:
            return self.fixed_s
        return self.fixed_s + self.step_s * self.steps


def _timed(prob, X, scenario, repeats: int = 3) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        prob.evaluate(X, scenario)
        best = min(best, time.perf_counter() - t0)
    return best


def calibrate(prob, n: int = CALIBRATION_CANDIDATES, steps: int = CALIBRATION_STEPS,
              max_drawn: int = 8 * CALIBRATION_CANDIDATES) -> Calibration:
    """Time ``n`` simulated candidates of ``prob`` under its tuning scenario cut to ``steps`` and
    ``steps // 2`` simulated steps (its own length, and half of it, when shorter); see the
    module docstring.

    Candidates are drawn in the box from a fixed seed, ``n`` at a time and at most ``max_drawn``,
    and those rejected before simulation (unstable designs, say) are set aside: they cost only
    the fixed part. The problem's jitted kernels are warmed first, so compilation is not timed;
    the candidates and scenario copies are the calibration's own, the runs are untouched.
    ``step_s`` is None when no drawn candidate was simulated (the runner then borrows the
    figure of another case of the experiment).

    Parameters
    ----------
    prob : TuningProblem
    n : int
        Candidates to simulate.
    steps : int
        Simulated steps of the longer cut.
    max_drawn : int
        Candidates drawn at most.

    Returns
    -------
    Calibration
    """
    prob.warm_up()
    rng = np.random.default_rng(CALIBRATION_SEED)
    scenarios = prob.evaluation_scenarios()
    per_scenario = [_steps(s) for s in scenarios]
    total = None if any(s is None for s in per_scenario) else int(sum(per_scenario))
    base = scenarios[0]
    cut = []
    if per_scenario[0] is not None and per_scenario[0] >= 2:
        k_long = min(per_scenario[0], steps)
        for k in (k_long, k_long // 2):
            try:
                cut.append((k, dataclasses.replace(base, horizon=k * float(_step(base)))))
            except (ConfigError, ValueError, TypeError):  # a scenario that cannot be cut short
                cut = []
                break
    if not cut:
        if total is not None and total > 10 * steps:
            return Calibration(prob.case, total, math.nan, None, 0, 0,
                               "not calibrated: the scenario cannot be cut short")
        # The tuning scenario as configured: the fixed and per-step costs together.
        X = prob.lower + rng.random((n, prob.dim)) * (prob.upper - prob.lower)
        prob.evaluate(X[:1], base)
        return Calibration(prob.case, total, _timed(prob, X, base) / n, None, 0, n, "the configured scenario")
    (k_long, s_long), (k_short, s_short) = cut
    simulated, rejected, drawn = [], [], 0
    while len(simulated) < n and drawn < max_drawn:
        X = prob.lower + rng.random((n, prob.dim)) * (prob.upper - prob.lower)
        drawn += n
        ok = prob.evaluate(X, s_short).reason == ""
        simulated.extend(X[ok])
        rejected.extend(X[~ok])
    simulated = np.array(simulated[:n]).reshape(-1, prob.dim)
    if len(simulated) == 0:
        fixed_s = _timed(prob, np.array(rejected[:n]), s_short) / min(n, len(rejected))
        return Calibration(prob.case, total, fixed_s, None, 0, drawn, f"{k_long} and {k_short} steps")
    distinct = len(simulated)
    if distinct < n:  # repeated to a full batch, which is what a batched device is timed on
        simulated = np.resize(simulated, (n, prob.dim))
    m = len(simulated)
    t_long, t_short = _timed(prob, simulated, s_long), _timed(prob, simulated, s_short)
    if t_long > t_short:
        step_s = (t_long - t_short) / (m * (k_long - k_short))
        fixed_s = max(t_short / m - step_s * k_short, 0.0)
    else:  # timings disturbed by other load: the longer one, all of it per step (an upper bound)
        step_s, fixed_s = t_long / (m * k_long), 0.0
    return Calibration(prob.case, total, fixed_s, step_s, distinct, drawn, f"{k_long} and {k_short} steps")


# seconds of calibration after which the wait is explained (numba compiling on a first run)
COMPILE_NOTICE_S = 5.0


class CompileNotice:
    """Explain a long calibration while it lasts: numba compiling the experiment's kernels.

    A first run on a machine (or after an edit of a kernel) compiles each kernel the
    evaluations call, in the calibration, before the plan line: a minute or more of silence
    otherwise. Used as a context manager around the calibration: when it is still running after
    ``after_s`` seconds one line says why and what avoids it (``make setup`` /
    ``python -m heurtune.precompile``), and at its end one line gives the time it took; a
    calibration that loads its kernels from numba's cache finishes first and prints nothing.
    The workers of the run then load the compiled kernels from the cache.

    Parameters
    ----------
    name : str
        The experiment, named in the lines.
    stream : file-like
        Where the lines go (the run's progress stream).
    after_s : float, optional
        Seconds before the first line (default :data:`COMPILE_NOTICE_S`).
    """

    def __init__(self, name: str, stream, after_s: float | None = None):
        self.name, self.stream = name, stream
        self.after_s = COMPILE_NOTICE_S if after_s is None else float(after_s)
        self.shown = False
        self._lock = threading.Lock()

    def _show(self):
        with self._lock:
            if self._done:
                return
            self.shown = True
            print(f"{self.name}: calibrating; numba is compiling the kernels its evaluations call into its cache "
                  f"(a first run on this machine, or after an edit: a minute or two once; `make setup` or "
                  f"`python -m heurtune.precompile` compiles every shipped experiment's in advance)",
                  file=self.stream, flush=True)

    def __enter__(self):
        self._done = False
        self._start = time.perf_counter()
        self._timer = threading.Timer(self.after_s, self._show)
        self._timer.daemon = True
        self._timer.start()
        return self

    def __exit__(self, *exc):
        self._timer.cancel()
        with self._lock:
            self._done = True
            if self.shown:
                print(f"{self.name}: calibrated in {time.perf_counter() - self._start:.0f} s, the kernels compiled "
                      f"and cached (the workers load them)", file=self.stream, flush=True)
        return False


def borrow_step_cost(calibrations: dict) -> dict:
    """Cases whose drawn candidates were all rejected before simulation take the mean cost per
    step of the other cases (the same plant family's kernel); returns the completed dict.

    Parameters
    ----------
    calibrations : dict of str to Calibration
        By case.

    Returns
    -------
    dict of str to Calibration
    """
    known = [c.step_s for c in calibrations.values() if c.step_s is not None]
    if not known:
        return dict(calibrations)
    mean = float(np.mean(known))
    return {case: c if c.step_s is not None or c.steps is None else
            dataclasses.replace(c, step_s=mean, horizons=c.horizons + ", cost per step of the other cases")
            for case, c in calibrations.items()}


def check_evaluation_time(cal: Calibration, limit: float = EVALUATION_LIMIT_S) -> None:
    """Raise a one-line ConfigError when one evaluation of ``cal.case`` is predicted to take
    longer than ``limit`` seconds (a scenario horizon far too long for its step, say).

    Parameters
    ----------
    cal : Calibration
    limit : float
        Seconds.
    """
    seconds = cal.evaluation_s
    if cal.steps is not None and math.isnan(seconds):
        raise ConfigError(f"case {cal.case!r}: one evaluation simulates {cal.steps:,} steps and its cost could not "
                          f"be measured (scenario.horizon / scenario.dt); pass --force to run it anyway")
    if seconds > limit and (cal.step_s is None or cal.steps is None):
        raise ConfigError(f"case {cal.case!r}: one evaluation took {format_duration(seconds)} here ({cal.horizons}); "
                          f"shorten scenario.horizon or raise scenario.dt, or pass --force to run it anyway")
    if seconds > limit:
        raise ConfigError(f"case {cal.case!r}: one evaluation would take about {format_duration(seconds)} "
                          f"({cal.steps:,} simulated steps, scenario.horizon / scenario.dt, at "
                          f"{cal.step_s * 1e9:.0f} ns per step measured here); shorten scenario.horizon or "
                          f"raise scenario.dt, or pass --force to run it anyway")


def estimate_line(calibrations: dict, pending_evals: dict, total_runs: int, workers: int) -> tuple:
    """The plan line printed before an experiment starts, and its estimated seconds.

    Parameters
    ----------
    calibrations : dict of case to Calibration
    pending_evals : dict of case to (planned evaluations, runs with no count known in advance,
        whether any count is an estimate)
    total_runs : int
        Runs still to do.
    workers : int
        Evaluations in parallel.

    Returns
    -------
    line : str
    seconds : float or None
    """
    evals = sum(n for n, _, _ in pending_evals.values())
    unknown = sum(u for _, u, _ in pending_evals.values())
    estimated = any(e for _, _, e in pending_evals.values())
    seconds = sum(n * calibrations[c].evaluation_s for c, (n, _, _) in pending_evals.items()) / max(workers, 1)
    per_eval = ", ".join(f"{c} {calibrations[c].evaluation_s * 1e3:.3g} ms" for c in calibrations)
    how = next(iter(calibrations.values())).horizons if calibrations else ""
    counted = f"{'about ' if estimated else ''}{evals:,} evaluations"
    if unknown:
        counted = (f"{counted} + {unknown} runs with no evaluation cap (not known in advance)" if evals else
                   f"{unknown} runs with no evaluation cap: evaluations not known in advance")
    when = (
        f"estimated time {'at least ' if unknown else ''}{format_duration(seconds)} on {workers} worker(s) "
        f"if every candidate is simulated"
        if evals
        else "time left shown once a run of each such case and optimiser has ended"
    )
    line = (f"plan: {total_runs} runs, {counted}; one evaluation of a simulated candidate: {per_eval} "
            f"(calibrated on {CALIBRATION_CANDIDATES} candidates, {how}); {when}")
    return line, seconds
