"""The optimisation engine: one loop for every optimiser.

A *population* optimiser only proposes and learns: ``ask()`` returns candidates, ``tell(X, f,
v)`` receives their objective values and constraint violations and says whether a generation
is complete. The engine owns everything else: bound repair, evaluation (in-process, joblib or
Dask), budgets, termination, the best-so-far and the per-generation history. A *driver*
(multistart local solvers) runs its own loop through a :class:`RunContext` that evaluates,
counts and records the same way.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pandas as pd

from heurtune.core import registry
from heurtune.core.errors import ConfigError
from heurtune.core.evaluator import Evaluator
from heurtune.core.pareto import asf_choice, hypervolume, update_front

__all__ = ["SearchSpace", "Comparator", "Optimizer", "Driver", "RunContext", "Checkpoint", "Result", "minimize",
           "run", "evaluate_generation", "convergence_epoch", "CONSTRAINT_HANDLING", "BOUND_HANDLING"]

CONSTRAINT_HANDLING = ("deb", "penalty")
BOUND_HANDLING = ("clip", "reflect")
DEFAULT_MAX_EPOCHS = 100
DEFAULT_TOL = 1e-6
DEFAULT_TOL_WINDOW = 20


@dataclasses.dataclass(frozen=True, eq=False)
class SearchSpace:
    """Box ``lower <= x <= upper`` and how proposals outside it are repaired."""

    lower: np.ndarray
    upper: np.ndarray
    bound_handling: str = "clip"

    def __post_init__(self):
        lo = np.asarray(self.lower, dtype=np.float64).ravel()
        hi = np.asarray(self.upper, dtype=np.float64).ravel()
        if lo.shape != hi.shape or lo.size == 0:
            raise ConfigError(f"lower and upper must have the same positive length, got {lo.size} and {hi.size}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ConfigError("bounds must be finite")
        bad = np.flatnonzero(lo > hi)
        if bad.size:
            raise ConfigError(f"bound {bad[0]}: lower {lo[bad[0]]} > upper {hi[bad[0]]}")
        if self.bound_handling not in BOUND_HANDLING:
            raise ConfigError(f"unknown bound_handling {self.bound_handling!r}; allowed: {', '.join(BOUND_HANDLING)}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @property
    def dim(self) -> int:
        return self.lower.size

    @property
    def width(self) -> np.ndarray:
        return self.upper - self.lower

    def uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n points drawn uniformly in the box."""
        return self.lower + rng.random((n, self.dim)) * self.width

    def repair(self, X: np.ndarray) -> np.ndarray:
        """Clip to the box, or reflect at its faces (then clip what is still out)."""
        X = np.array(X, dtype=np.float64, copy=True)
        if self.bound_handling == "reflect":
            w = np.where(self.width > 0, self.width, 1.0)
            y = np.mod(X - self.lower, 2.0 * w)
            y = np.where(y > w, 2.0 * w - y, y)
            X = np.where(np.isfinite(X), self.lower + y, X)
        X = np.clip(X, self.lower, self.upper)
        return np.where(np.isnan(X), self.lower, X)


class Comparator:
    """Ranks candidates by objective ``f`` and total constraint violation ``v >= 0``.

    ``"deb"`` (default): Deb's feasibility rules - feasible beats infeasible, two feasible
    compare by f, two infeasible by v. ``"penalty"``: static penalty, compare ``f + penalty * v``.
    """

    def __init__(self, mode: str = "deb", penalty: float = 1e6):
        if mode not in CONSTRAINT_HANDLING:
            raise ConfigError(f"unknown constraint_handling {mode!r}; allowed: {', '.join(CONSTRAINT_HANDLING)}")
        if not (isinstance(penalty, (int, float)) and penalty > 0):
            raise ConfigError(f"penalty must be a positive number, got {penalty!r}")
        self.mode = mode
        self.penalty = float(penalty)

    def merit(self, f, v):
        """Penalised objective (used by the penalty mode and by gradient methods)."""
        return np.asarray(f) + self.penalty * np.asarray(v)

    def better(self, fa, va, fb, vb):
        """Elementwise: is a strictly better than b?"""
        fa, va, fb, vb = map(np.asarray, (fa, va, fb, vb))
        if self.mode == "penalty":
            return self.merit(fa, va) < self.merit(fb, vb)
        fea_a, fea_b = va <= 0, vb <= 0
        return (fea_a & ~fea_b) | (fea_a & fea_b & (fa < fb)) | (~fea_a & ~fea_b & (va < vb))

    def order(self, f, v) -> np.ndarray:
        """Indices from best to worst (stable)."""
        f, v = np.asarray(f), np.asarray(v)
        if self.mode == "penalty":
            return np.argsort(self.merit(f, v), kind="stable")
        infeasible = v > 0
        return np.lexsort((np.where(infeasible, v, f), infeasible))

    def best(self, f, v) -> int:
        return int(self.order(f, v)[0])


class Optimizer:
    """Base class of population optimisers (ask/tell).

    Subclasses set ``self.X``, ``self.f``, ``self.v`` (the current population, used by the
    history) and implement :meth:`ask` and :meth:`tell`. All randomness comes from ``self.rng``.

    An optimiser that handles constraints itself (``cmaes``' augmented Lagrangian) sets the class
    attribute ``uses_constraint_values = True``: before each :meth:`tell` the engine then sets
    ``self.constraint_values``, the (n, m) constraint values ``g`` of the told candidates
    (``g <= 0`` feasible; NaN rows for candidates the budget left unevaluated).
    """

    uses_constraint_values = False

    def __init__(self, space: SearchSpace, settings, rng: np.random.Generator, compare: Comparator):
        self.space = space
        self.settings = settings
        self.rng = rng
        self.compare = compare
        self.X = np.zeros((0, space.dim))
        self.f = np.zeros(0)
        self.v = np.zeros(0)

    def ask(self) -> np.ndarray:
        raise NotImplementedError

    def tell(self, X: np.ndarray, f: np.ndarray, v: np.ndarray) -> bool:
        """Learn from evaluated candidates; return True when a generation is complete."""
        raise NotImplementedError


class Driver:
    """Base class of optimisers that own their loop (``run(ctx)``), e.g. multistart SQP."""

    def __init__(self, space: SearchSpace, settings, rng: np.random.Generator, compare: Comparator):
        self.space = space
        self.settings = settings
        self.rng = rng
        self.compare = compare

    def run(self, ctx: RunContext) -> None:
        raise NotImplementedError

    @staticmethod
    def spreads_work(budget: dict) -> bool:
        """Whether a run under ``budget`` (``max_evals``, ``max_epochs``, ...) keeps every
        worker busy by itself through :meth:`RunContext.map_unordered`. The experiment runner
        then runs it alone over all the workers instead of whole on one. Default: False."""
        return False


class BudgetExhausted(Exception):
    """Raised by RunContext.evaluate when no evaluation is left."""


@dataclasses.dataclass
class Result:
    """Outcome of one optimisation run.

    Attributes
    ----------
    x, f, g, violation, feasible : the best candidate (Deb's rules or penalty, as configured);
        ``feasible`` is False when no candidate had a finite objective (see ``status``)
    n_evals, n_epochs : evaluations and completed generations (epoch 0 is the initial one)
    convergence_epoch : first epoch after which the best objective improves by at most ``tol``
        (relative) until the end
    stop_reason : "max_epochs", "max_evals", "max_time", "tolerance" or "finished"
    history : DataFrame, one row per epoch: epoch, n_evals, best_f, best_violation, mean_f,
        sd_f, feasible_fraction, wall_time_s
    details : DataFrame or None, optimiser-specific records (e.g. every SQP local solve)
    front : dict or None, several objectives only: the final front, arrays ``X`` (p, d),
        ``F`` (p, k), ``v`` (p,), ``g`` (p, m), and ``chosen`` (the index of ``x`` in it);
        ``f`` is then minus its hypervolume and ``objectives`` the chosen point's objectives
    population : dict or None, population optimisers only: the optimiser's population at the
        end of the run, arrays ``X`` (n, d), ``f`` (n,) (or (n, k) with several objectives:
        what the optimiser selects on, which for NSGA-II and SMS-EMOA differs from ``front``,
        the archive of every non-dominated point seen) and ``v`` (n,) total violation;
        None for drivers (multistart SQP, the gradient methods' restarts keep no population)
    """

    x: np.ndarray
    f: float
    g: np.ndarray
    violation: float
    feasible: bool
    n_evals: int
    n_epochs: int
    convergence_epoch: int
    stop_reason: str
    history: pd.DataFrame
    algorithm: str
    settings: object
    seed: object
    wall_time_s: float
    details: pd.DataFrame | None = None
    front: dict | None = None
    objectives: np.ndarray | None = None
    population: dict | None = None

    @property
    def status(self) -> str:
        """``"failed"`` when no evaluated candidate had a finite objective (an objective that
        is NaN or inf everywhere, or no evaluation at all), else ``"feasible"`` or
        ``"infeasible"``."""
        if not math.isfinite(self.f) or self.n_evals == 0:
            return "failed"
        return "feasible" if self.feasible else "infeasible"


def convergence_epoch(best_f, tol: float = DEFAULT_TOL) -> int:
    """The convergence epoch of a run.

    Parameters
    ----------
    best_f : sequence of float
        The best objective after each epoch.
    tol : float
        Relative tolerance.

    Returns
    -------
    int
        The first epoch e with ``best_f[e] - best_f[-1] <= tol * max(|best_f[-1]|, 1e-300)``.
    """
    best_f = np.asarray(best_f, dtype=np.float64)
    if best_f.size == 0:
        return 0
    final = best_f[-1]
    if not np.isfinite(final):
        return int(best_f.size - 1)
    slack = tol * max(abs(final), 1e-300)
    ok = (best_f - final) <= slack
    # first index from which all later ones are ok
    bad = np.flatnonzero(~ok)
    return int(bad[-1] + 1) if bad.size else 0


class Checkpoint:
    """Where a driver keeps the work units (e.g. local solves) it has finished, for resuming.

    This base class keeps nothing: :meth:`load` returns no records and :meth:`save` does
    nothing, which is what a run outside the experiment runner (:func:`minimize`) gets. The
    experiment runner supplies one backed by a file, so that an interrupted run, started again
    with the same seed, takes its finished units from there instead of redoing them.

    A driver using it must stay deterministic: it recomputes everything it would have done
    (random draws included) and replaces only the finished units' work by their records, then
    replays them into the :class:`RunContext` exactly as if it had just done them.
    """

    def load(self) -> list:
        """The records saved by an earlier, interrupted attempt at this run (a list of dicts).

        Returns
        -------
        list of dict
            Each record as given to :meth:`save` (arrays come back as float64 arrays).
        """
        return []

    def save(self, records) -> None:
        """Keep ``records`` (all finished units so far, a list of dicts), replacing earlier ones.

        Parameters
        ----------
        records : list of dict
            One dict per finished unit, in the driver's own format.
        """


class RunContext:
    """The engine's services to an optimiser run: evaluation, budgets, best, history.

    ``checkpoint`` (a :class:`Checkpoint`) lets a driver resume an interrupted run; by default
    it keeps nothing. A driver uses :meth:`evaluate`, or :attr:`objective` inside tasks run by
    :meth:`map_unordered` (then :meth:`count_evaluations` and :meth:`offer`), :meth:`record_epoch`,
    :meth:`check_stop`, :attr:`remaining` and :attr:`checkpoint`.
    """

    def __init__(self, evaluator: Evaluator, space: SearchSpace, compare: Comparator, *,
                 max_evals, max_epochs, max_time, tol, tol_window, checkpoint: Checkpoint | None = None,
                 reference_point=None, decision_weights=None, multi_objective: bool = False, progress=None):
        self.evaluator = evaluator
        self.progress = progress
        self.reference_point = reference_point
        self.decision_weights = decision_weights
        self.multi_objective = multi_objective
        self.front = None  # several objectives: (X, F, v, g) of the best candidates seen
        self.front_chosen = None  # the decision step's pick in it
        self.best_objectives = None
        self.checkpoint = checkpoint if checkpoint is not None else Checkpoint()
        self.space = space
        self.compare = compare
        self.max_evals = max_evals
        self.max_epochs = max_epochs
        self.max_time = max_time
        self.tol = tol
        self.tol_window = tol_window
        self.n_evals = 0
        self.epoch = -1
        self.best_x = None
        self.best_f = math.inf
        self.best_v = math.inf
        self.best_g = np.zeros(0)
        self.rows = []
        self.stop_reason = None
        self.t0 = time.perf_counter()

    @property
    def remaining(self):
        """Evaluations left (None: unlimited)."""
        return None if self.max_evals is None else self.max_evals - self.n_evals

    def evaluate(self, X):
        """Evaluate (at most the remaining budget of) X; returns the evaluated rows' f, v, g.

        NaN objective values count as +inf and NaN violations as +inf. Raises BudgetExhausted
        when no evaluation is left.
        """
        X = np.atleast_2d(X)
        k = X.shape[0]
        if self.remaining is not None:
            if self.remaining <= 0:
                raise BudgetExhausted
            k = min(k, self.remaining)
        f, g = self.evaluator(X[:k])
        f = np.where(np.isnan(f), np.inf, f)
        v = violation(g)
        self.n_evals += k
        self.offer(X[:k], f, v, g)
        return f, v, g

    @property
    def objective(self):
        """The run's objective as a picklable callable: ``X (n, d) -> (f (n,), g (n, m))``, for
        a driver's tasks to call on the workers (see :meth:`map_unordered`). Evaluations made
        through it are counted with :meth:`count_evaluations`."""
        return self.evaluator.objective

    def map_unordered(self, fn, items):
        """Run ``fn(item)`` for every item where the run's evaluations run (in-process, loky,
        Dask or an executor); yield ``(index, result)`` as each ends (in order in-process). For
        drivers that hand whole local solves to the workers."""
        return self.evaluator.pool.imap_unordered(fn, items)

    def count_evaluations(self, n: int) -> None:
        """Add ``n`` evaluations a driver made through :attr:`objective` to the run's count."""
        self.n_evals += int(n)
        self._report_progress()

    def _report_progress(self) -> None:
        if self.progress is not None:
            self.progress(self.n_evals, self.epoch, self.best_f, self.best_v)

    def offer(self, X, f, v, g):
        """Update the best-so-far with evaluated candidates.

        With several objectives (``f`` of shape (n, k)) the run keeps the front of the best
        candidates seen (:func:`heurtune.core.pareto.update_front`); its best candidate is the
        decision step's pick from the front (:func:`heurtune.core.pareto.asf_choice`) and its
        ``best_f`` minus the front's hypervolume with respect to ``reference_point`` (0 while
        nothing is feasible), so that lower is better as for one objective.
        """
        if len(f) == 0:
            return
        if np.ndim(f) == 2:
            self._offer_front(X, f, v, g)
            return
        i = self.compare.best(f, v)
        if self.best_x is None or self.compare.better(f[i], v[i], self.best_f, self.best_v):
            self.best_x = np.array(X[i], dtype=np.float64)
            self.best_f, self.best_v = float(f[i]), float(v[i])
            self.best_g = np.array(g[i], dtype=np.float64)

    def _offer_front(self, X, F, v, g):
        if not self.multi_objective:
            raise ConfigError(f"the problem has {F.shape[1]} objectives; this optimiser takes one "
                              "(use a multi-objective optimiser, e.g. nsga2)")
        if self.reference_point is None:
            raise ConfigError("a problem with several objectives needs a reference point for the "
                              "hypervolume (problem.reference_point)")
        self.front = update_front(self.front, np.asarray(X, dtype=np.float64), F, v, np.asarray(g, dtype=np.float64))
        FX, FF, Fv, Fg = self.front
        feasible = bool(Fv[0] <= 0)
        i = asf_choice(FF, self.decision_weights) if feasible else 0
        self.front_chosen = i
        self.best_x, self.best_g = np.array(FX[i]), np.array(Fg[i])
        self.best_v, self.best_objectives = float(Fv[i]), np.array(FF[i])
        volume = hypervolume(FF, self.reference_point) if feasible else 0.0
        self.best_f = -volume if volume > 0 else 0.0

    def record_epoch(self, pop_f, pop_v) -> bool:
        """Close an epoch: append a history row; return True when the run must stop. With
        several objectives ``mean_f`` and ``sd_f`` are those of the first objective."""
        self.epoch += 1
        pop_f = np.asarray(pop_f, dtype=np.float64)
        if pop_f.ndim == 2:
            pop_f = pop_f[:, 0]
        pop_v = np.asarray(pop_v, dtype=np.float64)
        finite = pop_f[np.isfinite(pop_f)]
        self.rows.append(dict(
            epoch=self.epoch, n_evals=self.n_evals, best_f=self.best_f, best_violation=self.best_v,
            mean_f=float(finite.mean()) if finite.size else math.nan,
            sd_f=float(finite.std(ddof=1)) if finite.size > 1 else (0.0 if finite.size else math.nan),
            feasible_fraction=float(np.mean(pop_v <= 0)) if pop_v.size else math.nan,
            wall_time_s=time.perf_counter() - self.t0,
        ))
        self._report_progress()
        return self.check_stop()

    def check_stop(self) -> bool:
        if self.stop_reason is not None:
            return True
        if self.max_evals is not None and self.n_evals >= self.max_evals:
            self.stop_reason = "max_evals"
        elif self.max_epochs is not None and self.epoch >= self.max_epochs:
            self.stop_reason = "max_epochs"
        elif self.max_time is not None and time.perf_counter() - self.t0 >= self.max_time:
            self.stop_reason = "max_time"
        elif self.tol is not None and len(self.rows) > self.tol_window:
            old = self.rows[-1 - self.tol_window]
            new = self.rows[-1]
            same_feasibility = (old["best_violation"] <= 0) == (new["best_violation"] <= 0)
            gain = old["best_f"] - new["best_f"] if same_feasibility else math.inf
            if same_feasibility and new["best_violation"] > 0:
                gain = old["best_violation"] - new["best_violation"]
            if gain <= self.tol * max(abs(new["best_f"]), 1e-300):
                self.stop_reason = "tolerance"
        return self.stop_reason is not None

    def history(self) -> pd.DataFrame:
        cols = ["epoch", "n_evals", "best_f", "best_violation", "mean_f", "sd_f", "feasible_fraction", "wall_time_s"]
        return pd.DataFrame(self.rows, columns=cols)


def violation(g: np.ndarray) -> np.ndarray:
    """Total violation ``sum(max(g, 0))`` per row; NaN constraints count as +inf."""
    g = np.asarray(g, dtype=np.float64)
    if g.ndim != 2 or g.shape[1] == 0:
        return np.zeros(g.shape[0] if g.ndim else 0)
    return np.where(np.isnan(g), np.inf, np.maximum(g, 0.0)).sum(axis=1)


def evaluate_generation(opt: Optimizer, ctx: RunContext, X, limit: int | None = None) -> tuple:
    """Evaluate the candidates ``X`` an optimiser asked for (what the budget allows, and at most
    ``limit`` of them) and tell them to it; candidates left unevaluated rank last (objective and
    violation +inf, NaN constraint values). For drivers that run a population optimiser as one
    of their phases.

    Parameters
    ----------
    opt : Optimizer
        The optimiser that asked.
    ctx : RunContext
        The run's evaluation, budgets and records.
    X : ndarray (n, d)
        The candidates.
    limit : int, optional
        At most this many of them are evaluated.

    Returns
    -------
    evaluated : int
        How many of ``X`` were evaluated.
    generation_done : bool
        ``opt.tell``'s answer.

    Raises
    ------
    BudgetExhausted
        When no evaluation is left (nothing is told).
    """
    f, v, g = ctx.evaluate(X if limit is None else X[:max(int(limit), 0)])
    k = len(f)
    if k < len(X):
        f = np.concatenate([f, np.full((len(X) - k,) + f.shape[1:], np.inf)])
        v = np.concatenate([v, np.full(len(X) - k, np.inf)])
        g = np.concatenate([g, np.full((len(X) - k,) + g.shape[1:], np.nan)]) if g.ndim == 2 else g
    if opt.uses_constraint_values:
        opt.constraint_values = np.asarray(g, dtype=np.float64).reshape(len(X), -1)
    return k, opt.tell(X, f, v)


def _population_loop(opt: Optimizer, ctx: RunContext) -> None:
    while True:
        X = ctx.space.repair(opt.ask())
        try:
            k, generation_done = evaluate_generation(opt, ctx, X)
        except BudgetExhausted:
            ctx.stop_reason = "max_evals"
            return
        if generation_done or k < len(X) or ctx.remaining == 0:
            if ctx.record_epoch(opt.f, opt.v):
                return
            if getattr(opt, "finished", False):  # an optimiser may declare itself done
                ctx.stop_reason = "finished"
                return


def run(algorithm: str, evaluator: Evaluator, space: SearchSpace, *, settings=None, seed=0,
        max_evals=None, max_epochs=None, max_time=None, tol=None, tol_window=DEFAULT_TOL_WINDOW,
        constraint_handling="deb", penalty=1e6, checkpoint: Checkpoint | None = None,
        reference_point=None, decision_weights=None, progress=None) -> Result:
    """Run one optimisation with an open evaluator.

    Parameters
    ----------
    algorithm, evaluator, space :
        A registered optimiser, an :class:`~heurtune.core.evaluator.Evaluator` and the box.
    settings, seed, max_evals, max_epochs, max_time, tol, tol_window, constraint_handling, penalty :
        As in :func:`minimize`.
    checkpoint : Checkpoint, optional
        Lets a driver (e.g. ``sqp_multistart``) save its finished local solves as it goes and,
        on a rerun with the same seed, take them from there instead of solving them again; the
        result is the same as an uninterrupted run's. Population optimisers ignore it.
    reference_point : array_like, optional
        For a problem with several objectives (``fun`` returning f of shape (n, k)): the point
        bounding the hypervolume of the front (needed then, see :class:`RunContext`).
    decision_weights : array_like, optional
        Several objectives: the weights of the decision step that picks ``Result.x`` from the
        front (:func:`heurtune.core.pareto.asf_choice`; equal by default).
    progress : callable, optional
        ``progress(n_evals, epoch, best_f, best_violation)``, called at the end of every epoch
        and whenever a driver counts evaluations (the experiment runner's progress line reads
        it from inside running runs); it only watches, the run is the same without it.

    Returns
    -------
    Result
    """
    info = registry.get(algorithm)
    if settings is None or isinstance(settings, dict):
        settings = registry.make_settings(algorithm, settings)
    elif not isinstance(settings, info.settings):
        raise ConfigError(f"{algorithm}: settings must be a dict or {info.settings.__name__}")
    for key, value, least in (("max_evals", max_evals, 1), ("max_epochs", max_epochs, 0)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < least):
            raise ConfigError(f"{key} must be an integer >= {least}, got {value!r}")
    if not isinstance(seed, np.random.SeedSequence) and (
        isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0
    ):
        raise ConfigError(f"seed must be an integer >= 0 or a numpy SeedSequence, got {seed!r}")
    if max_time is not None and not max_time > 0:
        raise ConfigError(f"max_time must be positive, got {max_time!r}")
    if tol is not None and not tol >= 0:
        raise ConfigError(f"tol must be >= 0, got {tol!r}")
    if max_evals is None and max_epochs is None and max_time is None and info.kind != "driver":
        max_epochs = DEFAULT_MAX_EPOCHS  # drivers end when their starts are done
    compare = Comparator(constraint_handling, penalty)
    seed_seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    rng = np.random.default_rng(seed_seq)
    ctx = RunContext(evaluator, space, compare, max_evals=max_evals, max_epochs=max_epochs,
                     max_time=max_time, tol=tol, tol_window=tol_window, checkpoint=checkpoint,
                     reference_point=reference_point, decision_weights=decision_weights,
                     multi_objective=info.multi_objective, progress=progress)
    opt = info.cls(space, settings, rng, compare)
    if callable(getattr(opt, "set_budget", None)):  # an optimiser that plans by its budget (L-SHADE)
        opt.set_budget(max_evals)
    details = None
    if info.kind == "driver":
        opt.run(ctx)
        details = getattr(opt, "details", None)
        if ctx.stop_reason is None:
            ctx.stop_reason = "finished"
    else:
        _population_loop(opt, ctx)
    hist = ctx.history()
    conv = convergence_epoch(hist["best_f"].to_numpy(), DEFAULT_TOL if tol is None else tol)
    x = ctx.best_x if ctx.best_x is not None else np.full(space.dim, np.nan)
    return Result(
        x=x, f=ctx.best_f, g=ctx.best_g, violation=ctx.best_v,
        feasible=bool(ctx.best_v <= 0 and math.isfinite(ctx.best_f)),
        n_evals=ctx.n_evals, n_epochs=max(ctx.epoch, 0), convergence_epoch=conv,
        stop_reason=ctx.stop_reason, history=hist, algorithm=algorithm, settings=settings,
        seed=seed_seq.entropy if isinstance(seed, np.random.SeedSequence) else seed,
        wall_time_s=time.perf_counter() - ctx.t0, details=details, front=_front(ctx),
        objectives=ctx.best_objectives, population=_population(opt),
    )


def _population(opt) -> dict | None:
    """The final population of a population optimiser (copies), None for a driver."""
    if not isinstance(opt, Optimizer):
        return None
    return dict(X=np.array(opt.X, dtype=np.float64), f=np.array(opt.f, dtype=np.float64),
                v=np.array(opt.v, dtype=np.float64))


def _front(ctx: RunContext) -> dict | None:
    """The final front of a run with several objectives (None otherwise)."""
    if ctx.front is None:
        return None
    X, F, v, g = ctx.front
    return dict(X=X, F=F, v=v, g=g, chosen=ctx.front_chosen)


def minimize(fun, lower, upper, algorithm: str = "cs", *, constraints=None, max_evals=None,
             max_epochs=None, tol=None, seed=0, n_jobs: int = 1, settings=None, max_time=None,
             tol_window: int = DEFAULT_TOL_WINDOW, constraint_handling: str = "deb",
             penalty: float = 1e6, bound_handling: str = "clip", backend: str = "loky",
             scheduler=None, reference_point=None) -> Result:
    """Minimise ``fun`` over the box ``[lower, upper]`` with a registered optimiser.

    Parameters
    ----------
    fun : callable
        ``fun(X)`` maps an (n, d) array to (n,) objective values, or to ``(f, g)`` with
        constraint values g (n, m), ``g <= 0`` feasible. Must be picklable for ``n_jobs > 1``.
        With several objectives f is (n, k): a multi-objective optimiser (``nsga2``) and a
        ``reference_point`` are then needed, and the result holds the front.
    lower, upper : array_like (d,)
    algorithm : str
        A registered name (``python -m heurtune.algorithms`` lists them).
    constraints : callable, optional
        ``constraints(X)`` -> g (n, m), when ``fun`` returns only f.
    max_evals, max_epochs, max_time, tol, tol_window :
        Termination: evaluations, generations after the initial one, wall seconds, and no
        improvement of the best above ``tol`` (relative) over ``tol_window`` generations.
        With none given, ``max_epochs = 100``.
    seed : int or numpy.random.SeedSequence
        The run's only source of randomness; the same seed gives the same history whatever
        ``n_jobs``.
    n_jobs : int
        Parallel workers for evaluation (a persistent joblib pool); 1 = in-process.
    settings : dict or the optimiser's settings dataclass
        Hyperparameters; an unknown name is an error listing the allowed ones.
    constraint_handling : {"deb", "penalty"}
        Deb's feasibility rules, or ``f + penalty * violation``.
    penalty : float
        The penalty factor of ``constraint_handling="penalty"``.
    bound_handling : {"clip", "reflect"}
    backend : {"loky", "dask"}
        Where the evaluations run: a local process pool, or a Dask cluster.
    scheduler : str or distributed.Client, optional
        The cluster of ``backend="dask"`` (``"tcp://host:8786"``).
    reference_point : array_like, optional
        Several objectives: the point bounding the hypervolume (``Result.f`` is minus it).

    Returns
    -------
    Result

    Examples
    --------
    >>> import numpy as np, heurtune
    >>> res = heurtune.minimize(lambda X: (X ** 2).sum(axis=1), [-5] * 3, [5] * 3, "cs",
    ...                         max_epochs=50, seed=1)
    >>> res.f < 1e-3
    True
    """
    space = SearchSpace(lower, upper, bound_handling)
    with Evaluator(fun, constraints, n_jobs=n_jobs, backend=backend, scheduler=scheduler) as ev:
        return run(algorithm, ev, space, settings=settings, seed=seed, max_evals=max_evals,
                   max_epochs=max_epochs, max_time=max_time, tol=tol, tol_window=tol_window,
                   constraint_handling=constraint_handling, penalty=penalty, reference_point=reference_point)
