"""Multistart SQP: ``scipy.optimize.minimize(method="SLSQP")`` from many starts in the box.

Each local solve runs whole on a worker (``RunContext.map_unordered``) and calls the user's
objective itself, evaluating f and g together once per point (a small cache serves SLSQP's
separate requests for f, g and their finite-difference Jacobians, which use the same points).
Constraints ``g(x) <= 0`` go to SLSQP as inequalities ``-g(x) >= 0``; the box as bounds.
Gradients are SLSQP's own forward differences (absolute step ``fd_step``, scipy's default
``sqrt(machine eps)``, one-sided away from the faces). Where scipy's SLSQP takes a map for them
(``workers``, scipy >= 1.16), the difference points of a gradient go to the objective as one
batch, which saves its per-call overhead; SLSQP still takes their values one by one, so the
counts, caps, best points and every iterate are those of one-point calls (for an objective that
evaluates each row on its own, as every batch in heurtune assumes).

Starts and budget
-----------------
Starts are drawn in the parent from the run's generator, ``batch`` at a time (a Latin
hypercube, or uniform); a batch is one epoch of the history, and its solves are spread over
the workers.

Without an evaluation budget there are no caps, so every batch is drawn (in the same order) and
handed to the workers at once: no worker waits for the slowest solve of a batch. The batches
are still closed in order (offered, recorded as epochs), so the run is the same as batch by
batch; a stop after a batch (``max_epochs``) cancels the solves not yet begun. Such a run keeps
every worker busy by itself (``spreads_work``), and the experiment runner gives it all the
workers of its local pool in turn (not under Dask, an executor or lockstep).

With an evaluation budget each start of a batch gets a cap: the budget remaining when the batch
begins, split evenly in start order (the first ``remaining % k`` get one more). A start that
reaches its cap stops gracefully ("evaluation cap reached") and keeps its best point; what a
batch did not use rolls over to the next. After ``starts`` starts the run ends, unless
``fill_budget`` (default) and budget remain: then further batches are launched until the budget
is spent exactly.

Caps depend only on the seed, the budget and ``batch`` (a fixed number, not the worker count),
so ``x``, ``f``, ``n_evals``, ``details`` and the history are identical for any ``n_jobs``.

The point kept from a local solve is its best *evaluated* point under the run's comparator
(Deb's rules or penalty), not necessarily SLSQP's last iterate. ``details`` (a DataFrame, one
row per start): start, round, cap, x0, x, f, violation, nfev, nit, success, message.

Resuming
--------
Each local solve is handed to the run's checkpoint (``ctx.checkpoint.save``) as soon as it
ends, in whatever order the workers finish. The experiment runner backs the checkpoint with a
file (``parts/<run>.starts.parquet``); outside it (``heurtune.minimize``) nothing is kept. A
rerun draws the same start points and caps, takes the solves found in ``ctx.checkpoint.load()``
instead of solving them again (their start point and cap must match) and feeds them to the run
context exactly like fresh ones, so budgets, best, history and ``details`` equal an
uninterrupted run's.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import warnings

import numpy as np
import pandas as pd

from heurtune.core.engine import Driver, violation
from heurtune.core.errors import ConfigError
from heurtune.core.registry import register

SAMPLING = ("lhs", "uniform")
# A local solve is a dict: start, round, cap, x0, x, f, violation, g, nfev, nit, success,
# message; the checkpoint saves all of it (g, the constraints at x, so that a resumed run's best
# has them too), ``details`` all but g.
DETAIL_COLUMNS = ["start", "round", "cap", "x0", "x", "f", "violation", "nfev", "nit", "success", "message"]


@dataclasses.dataclass(frozen=True)
class SQPSettings:
    starts: int = dataclasses.field(default=1000, metadata={"help": "local solves (thesis: 1000)"})
    max_iter: int = dataclasses.field(default=100, metadata={"help": "SLSQP iterations per start"})
    ftol: float = dataclasses.field(default=1e-6, metadata={"help": "SLSQP precision goal on f (thesis: 1e-6)"})
    sampling: str = dataclasses.field(default="lhs", metadata={"help": "start points: 'lhs' or 'uniform'"})
    batch: int = dataclasses.field(default=16, metadata={"help": "starts per epoch (run in parallel)"})
    fd_step: float = dataclasses.field(default=0.0, metadata={
        "help": "absolute finite-difference step of SLSQP's gradients; 0 = scipy's sqrt(eps)"})
    fill_budget: bool = dataclasses.field(default=True, metadata={
        "help": "with max_evals, keep launching rounds of starts until the budget is spent"})

    def __post_init__(self):
        if self.starts < 1:
            raise ValueError(f"starts must be >= 1, got {self.starts}")
        if self.max_iter < 1:
            raise ValueError(f"max_iter must be >= 1, got {self.max_iter}")
        if not self.ftol > 0:
            raise ValueError(f"ftol must be positive, got {self.ftol}")
        if self.sampling not in SAMPLING:
            raise ValueError(f"sampling must be one of {', '.join(SAMPLING)}, got {self.sampling!r}")
        if self.batch < 1:
            raise ValueError(f"batch must be >= 1, got {self.batch}")
        if not self.fd_step >= 0:
            raise ValueError(f"fd_step must be >= 0 (0 = scipy's default), got {self.fd_step}")


class _CapReached(Exception):
    """A local solve asked for an evaluation beyond its cap."""


class _BadIterate(Exception):
    """SLSQP produced a non-finite iterate."""


@dataclasses.dataclass(frozen=True)
class _Task:
    """Everything a worker needs for a local solve except the start (picklable)."""

    objective: object  # RunContext.objective: X -> (f, g)
    lower: np.ndarray
    upper: np.ndarray
    compare: object
    max_iter: int
    ftol: float
    fd_step: float


class _Tracked:
    """The user's objective as SLSQP sees it, point by point: caches, counts, caps, keeps the best."""

    def __init__(self, task: _Task, cap):
        self.task = task
        self.cap = cap
        self.nfev = 0
        self.cache = collections.OrderedDict()
        self.cache_size = 2 * task.lower.size + 4  # x and both sets of difference points
        self.best = None  # (x, f, v, g)
        self.prefetched = {}  # values of points a finite difference is about to ask for

    def _key(self, x):
        x = np.clip(np.asarray(x, dtype=np.float64).reshape(-1), self.task.lower, self.task.upper)
        if not np.all(np.isfinite(x)):
            raise _BadIterate
        return x, x.tobytes()

    def values(self, x):
        x, key = self._key(x)
        hit = self.cache.get(key)
        if hit is not None:
            return hit
        if self.cap is not None and self.nfev >= self.cap:
            raise _CapReached
        fg = self.prefetched.pop(key, None)
        if fg is None:
            f, g = self.task.objective(x[None, :])
            fg = f[0], g[0]
        f, g = fg
        self.nfev += 1
        f = float(np.where(np.isnan(f), np.inf, f))
        v = float(violation(g[None, :])[0])
        if self.best is None or self.task.compare.better(f, v, self.best[1], self.best[2]):
            self.best = (x, f, v, g)
        self.cache[key] = (f, g)
        if len(self.cache) > self.cache_size:
            self.cache.popitem(last=False)
        return f, g

    def objective(self, x):
        return self.values(x)[0]

    def ineq(self, x):
        return -self.values(x)[1]

    def map(self, fun, points):
        """The map SLSQP's finite differences call (its ``workers``): the points that calls one
        by one would evaluate (not cached, within the cap, up to a non-finite one) go to the
        objective as one batch, then ``fun`` takes every point in order exactly as one-by-one
        calls would, reading the batch's values when it evaluates. Counts, caps, the best point
        and the cache are those of one-by-one calls: only the objective's calls are fewer (for
        an objective that evaluates each row on its own, as heurtune's batches assume)."""
        points = [np.array(p, dtype=np.float64) for p in points]
        cached = collections.OrderedDict.fromkeys(self.cache)  # the cache's keys, as calls would leave them
        todo = []
        for p in points:
            try:
                x, key = self._key(p)
            except _BadIterate:
                break
            if key in cached:
                continue
            if self.cap is not None and self.nfev + len(todo) >= self.cap:
                break
            todo.append(x)
            cached[key] = None
            if len(cached) > self.cache_size:
                cached.popitem(last=False)
        if len(todo) > 1:
            F, G = self.task.objective(np.array(todo))
            self.prefetched = {x.tobytes(): (f, g) for x, f, g in zip(todo, F, G)}
        try:
            return [fun(p) for p in points]
        finally:
            self.prefetched = {}


@functools.cache
def _slsqp_takes_workers() -> bool:
    """Whether scipy's SLSQP takes a map for its finite differences (scipy >= 1.16); asked on a
    worker's first solve, so that importing this module does not import scipy.optimize."""
    import inspect

    try:
        from scipy.optimize._slsqp_py import _minimize_slsqp
    except ImportError:
        return False
    return "workers" in inspect.signature(_minimize_slsqp).parameters



def _local_solve(task: _Task, item):
    """One SLSQP run from ``item = (start, x0, cap)``; executed on a worker.

    BLAS is pinned to one thread here, in-process as on the workers: scipy's SLSQP calls
    OpenBLAS, whose results differ in the last bits between one and several threads, even on
    3-vectors - and a last-bit difference in an iterate changes the whole local solve.
    """
    from scipy.optimize import Bounds, minimize
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        return _solve_pinned(task, item, Bounds, minimize)


def _solve_pinned(task: _Task, item, Bounds, minimize):

    start, x0, cap = item
    tracked = _Tracked(task, cap)
    nit = [0]
    options = dict(maxiter=task.max_iter, ftol=task.ftol)
    if task.fd_step > 0:
        options["eps"] = task.fd_step
    if _slsqp_takes_workers():  # the gradient's difference points in one call of the objective
        options["workers"] = tracked.map
    success, message = False, ""
    try:
        f0, g0 = tracked.values(x0)
        cons = [{"type": "ineq", "fun": tracked.ineq}] if g0.size else []
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            res = minimize(tracked.objective, x0, method="SLSQP", bounds=Bounds(task.lower, task.upper),
                           constraints=cons, options=options,
                           callback=lambda xk: nit.__setitem__(0, nit[0] + 1))
        nit[0], success, message = int(res.nit), bool(res.success), str(res.message)
    except _CapReached:
        message = "evaluation cap reached"
    except _BadIterate:
        message = "non-finite iterate"
    x, f, v, g = tracked.best
    return dict(start=start, x0=np.array(x0), x=x, f=f, violation=v, g=g, nfev=tracked.nfev,
                nit=nit[0], success=success, message=message)


def even_caps(budget: int, k: int) -> list:
    """``budget`` split over ``k`` starts in order: the first ``budget % k`` get one more.

    Parameters
    ----------
    budget : int
    k : int

    Returns
    -------
    list of int
    """
    q, r = divmod(budget, k)
    return [q + (1 if i < r else 0) for i in range(k)]


@register("sqp_multistart", kind="driver", settings=SQPSettings,
          source="scipy SLSQP (Kraft 1988) from Latin-hypercube starts; thesis: 1000 starts, ftol 1e-6",
          description="Multistart SLSQP, each local solve whole on a worker; exact evaluation budgets")
class SQPMultistart(Driver):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.details = []

    @staticmethod
    def spreads_work(budget: dict) -> bool:
        """Without an evaluation budget every start is known at once (see
        :meth:`_run_unbudgeted`), so the local solves keep all the workers busy."""
        return budget.get("max_evals") is None

    def _sample(self, k: int) -> np.ndarray:
        if self.settings.sampling == "uniform":
            return self.space.uniform(self.rng, k)
        from scipy.stats import qmc

        try:
            sampler = qmc.LatinHypercube(d=self.space.dim, rng=self.rng)
        except TypeError:  # scipy < 1.15
            sampler = qmc.LatinHypercube(d=self.space.dim, seed=self.rng)
        return self.space.lower + sampler.random(k) * self.space.width

    def run(self, ctx):
        records = self.details = []
        try:
            self._run(ctx, records)
        finally:
            self.details = pd.DataFrame(records, columns=DETAIL_COLUMNS)

    def _run(self, ctx, records):
        s = self.settings
        task = _Task(ctx.objective, self.space.lower, self.space.upper,
                     self.compare, s.max_iter, s.ftol, s.fd_step)
        solve = functools.partial(_local_solve, task)
        # Local solves finished by an earlier, interrupted attempt at this run, by start number.
        finished = {int(r["start"]): r for r in ctx.checkpoint.load()}
        if ctx.remaining is None:
            self._run_unbudgeted(ctx, records, solve, finished)
            return
        launched, round_no = 0, 0
        while True:
            left = ctx.remaining
            if left <= 0:
                ctx.check_stop()
                return
            more = s.starts - launched
            if more <= 0 and not s.fill_budget:
                return
            k = min(s.batch if more <= 0 else min(s.batch, more), left)
            X0 = self._sample(k)
            caps = even_caps(left, k)
            items = [(launched + i, X0[i], caps[i]) for i in range(k)]
            results = [_reuse(finished.get(item[0]), item, round_no) for item in items]
            todo = [i for i in range(k) if results[i] is None]
            for j, res in ctx.map_unordered(solve, [items[i] for i in todo]):
                i = todo[j]
                res["round"], res["cap"] = round_no, caps[i]
                results[i] = finished[items[i][0]] = res
                ctx.checkpoint.save([finished[n] for n in sorted(finished)])
            launched += k
            round_no += 1
            if _close_round(ctx, records, results):
                return

    def _run_unbudgeted(self, ctx, records, solve, finished):
        """No evaluation budget: no caps, so every round's starts are known before any solve
        ends. They are drawn in the same order as round by round and handed to the workers all
        at once, so that no worker waits at the end of a round; the rounds are still closed
        (offered, recorded as epochs) in order, and a stop after a round cancels the solves
        not yet begun."""
        s = self.settings
        sizes = [min(s.batch, s.starts - first) for first in range(0, s.starts, s.batch)]
        items, round_of = [], []
        for round_no, k in enumerate(sizes):
            first, X0 = len(items), self._sample(k)
            items.extend((first + i, X0[i], None) for i in range(k))
            round_of.extend([round_no] * k)
        rounds = np.split(np.arange(len(items)), np.cumsum(sizes)[:-1])
        results = [_reuse(finished.get(i), items[i], round_of[i]) for i in range(len(items))]
        todo = [i for i in range(len(items)) if results[i] is None]
        closed = 0

        def close_ready():
            nonlocal closed
            while closed < len(rounds) and all(results[i] is not None for i in rounds[closed]):
                stop = _close_round(ctx, records, [results[i] for i in rounds[closed]])
                closed += 1
                if stop:
                    return True
            return False

        if close_ready():
            return
        for j, res in ctx.map_unordered(solve, [items[i] for i in todo]):
            i = todo[j]
            res["round"], res["cap"] = round_of[i], None
            results[i] = finished[i] = res
            ctx.checkpoint.save([finished[n] for n in sorted(finished)])
            if close_ready():
                return


def _close_round(ctx, records, results) -> bool:
    """Hand a finished round of local solves to the run: details, evaluations, best, epoch.
    Returns whether the run stops after it."""
    records.extend(results)
    f = np.array([r["f"] for r in results])
    v = np.array([r["violation"] for r in results])
    X = np.array([r["x"] for r in results])
    G = np.array([r["g"] for r in results]).reshape(len(results), -1)
    ctx.count_evaluations(sum(r["nfev"] for r in results))
    ctx.offer(X, f, v, G)
    return ctx.record_epoch(f, v)


def _reuse(record, item, round_no):
    """The saved record of start ``item = (start, x0, cap)``, or None when it was not solved.

    A saved solve must come from the same start point and cap, else the checkpoint belongs to
    another run (other settings, seed or problem) and using it would corrupt this one.
    """
    if record is None:
        return None
    start, x0, cap = item
    saved_cap = record["cap"]
    saved_cap = None if saved_cap is None or (isinstance(saved_cap, float) and np.isnan(saved_cap)) else int(saved_cap)
    if not np.array_equal(np.asarray(record["x0"], dtype=np.float64), x0) or saved_cap != cap:
        raise ConfigError(f"saved local solve {start} started from another point or cap: "
                          "the checkpoint belongs to another run; start this run afresh")
    return dict(
        record,
        start=start,
        round=round_no,
        cap=cap,
        x0=np.array(x0),
        x=np.asarray(record["x"], dtype=np.float64),
        g=np.asarray(record["g"], dtype=np.float64).reshape(-1),
    )
