"""Batch evaluation of candidates, wherever :class:`heurtune.core.execution.Pool` runs tasks.

The evaluator splits a batch into contiguous chunks, evaluates them where configured and
concatenates the results in order, so the numbers never depend on the number of workers.
"""

from __future__ import annotations

import numpy as np

from heurtune.core.execution import BACKENDS, Pool, shared

__all__ = ["Evaluator", "BACKENDS", "normalise", "Objectives", "evaluate_in", "evaluate_groups", "chunk_bounds"]

CHUNKS_PER_WORKER = 4


def normalise(result, constraints, X):
    """``(f, g)`` from a user function's output: f (n,), or (n, k) for k >= 2 objectives, and
    g (n, m) with m >= 0.

    Parameters
    ----------
    result : array_like or tuple
        What the function returned: f, or ``(f, g)``.
    constraints : callable or None
        ``constraints(X)`` -> g, when the function returns f alone.
    X : ndarray (n, d)
        The candidates it was called with.

    Returns
    -------
    f : ndarray
    g : ndarray (n, m)
    """
    n = X.shape[0]
    if isinstance(result, tuple):
        if len(result) != 2:
            raise ValueError("the objective must return f or (f, g)")
        f, g = result
    else:
        f, g = result, None
    if constraints is not None:
        if g is not None:
            raise ValueError("give constraints either as fun's second output or as constraints=, not both")
        g = constraints(X)
    f = np.asarray(f, dtype=np.float64)
    if f.ndim == 2 and f.shape[0] == n and f.shape[1] > 1:
        pass  # several objectives: (n, k)
    else:
        f = f.reshape(-1)
        if f.shape != (n,):
            raise ValueError(f"the objective returned {f.size} values for {n} candidates")
    g = np.zeros((n, 0)) if g is None else np.asarray(g, dtype=np.float64).reshape(n, -1)
    return f, g


class Objective:
    """``fun`` with optional ``constraints``: ``(f, g)`` of a batch, normalised. Picklable as
    long as ``fun`` is; ``warm_up`` is passed on (workers compile jitted kernels once)."""

    def __init__(self, fun, constraints=None):
        self.fun = fun
        self.constraints = constraints

    def __call__(self, X):
        return normalise(self.fun(X), self.constraints, X)

    def warm_up(self):
        warm = getattr(self.fun, "warm_up", None)
        if callable(warm):
            warm()


def _evaluate_block(X):
    return shared()(X)


def _evaluate_named_block(item):
    name, X = item
    return shared()[name](X)


def chunk_bounds(n: int, workers: int, per_worker: int = CHUNKS_PER_WORKER) -> list:
    """Contiguous ``(start, stop)`` chunks of a batch of ``n``: several per worker even out
    candidates of unequal cost (a failed design returns in 0.1 ms, a full simulation takes
    milliseconds).

    Parameters
    ----------
    n : int
        Candidates in the batch.
    workers : int
        Worker processes.
    per_worker : int
        Chunks per worker.

    Returns
    -------
    list of (int, int)
    """
    k = min(n, workers * (per_worker if workers > 1 else 1))
    bounds = np.linspace(0, n, k + 1).round().astype(int)
    return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def _joined(parts) -> tuple:
    """``(f, g)`` of consecutive chunks' results."""
    if len({p[1].shape[1] for p in parts}) != 1:
        raise ValueError("the constraint function returned different numbers of constraints")
    return np.concatenate([p[0] for p in parts]), np.vstack([p[1] for p in parts])


def evaluate_in(pool: Pool, X):
    """Evaluate X (n, d) with the objective shared by ``pool``, in contiguous chunks, in
    order. Returns f (n,) and g (n, m).

    Parameters
    ----------
    pool : Pool
        A pool sharing the objective.
    X : ndarray (n, d)

    Returns
    -------
    f : ndarray (n,)
    g : ndarray (n, m)
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.shape[0] == 0:
        return np.zeros(0), np.zeros((0, 0))
    chunks = [X] if pool.in_process else [X[a:b] for a, b in chunk_bounds(X.shape[0], pool.workers)]
    return _joined(pool.map(_evaluate_block, chunks))


class Objectives(dict):
    """Several named objectives shared by one pool (see :func:`evaluate_groups`); ``warm_up``
    warms them all."""

    def warm_up(self):
        for objective in self.values():
            objective.warm_up()


def evaluate_groups(pool: Pool, batches: dict, per_worker: int = CHUNKS_PER_WORKER) -> dict:
    """Evaluate several batches, ``{name: X}``, each with the objective ``name`` of the pool's
    :class:`Objectives`, all chunks in one round of the pool; returns ``{name: (f, g)}``.
    A batched simulation gains from long chunks: give it ``per_worker = 1``.

    Parameters
    ----------
    pool : Pool
        A pool sharing an :class:`Objectives`.
    batches : dict of str to ndarray
        ``{name: X}``.
    per_worker : int
        Chunks per worker.

    Returns
    -------
    dict
        ``{name: (f, g)}``.
    """
    items, spans = [], {}
    for name, X in batches.items():
        X = np.ascontiguousarray(X, dtype=np.float64)
        bounds = [(0, X.shape[0])] if pool.in_process else chunk_bounds(X.shape[0], pool.workers, per_worker)
        spans[name] = (len(items), len(items) + len(bounds))
        items += [(name, X[a:b]) for a, b in bounds]
    parts = pool.map(_evaluate_named_block, items)
    return {name: _joined(parts[a:b]) if b > a else (np.zeros(0), np.zeros((0, 0)))
            for name, (a, b) in spans.items()}


class Evaluator:
    """Evaluate batches of candidates with ``fun`` (and optional ``constraints``).

    Parameters
    ----------
    fun : callable
        ``fun(X)`` with X (n, d) returns f (n,) or (f, g) with g (n, m), ``g <= 0`` feasible.
    constraints : callable, optional
        ``constraints(X)`` returns g (n, m) when fun returns only f.
    n_jobs : int
        Workers; 1 evaluates in this process (same code path, no pool).
    backend : {"loky", "dask"}
    scheduler : str or distributed.Client, optional
        Dask scheduler address (or a Client) for ``backend="dask"``.
    executor : concurrent.futures.Executor, optional
        Evaluate there instead (see :class:`heurtune.core.execution.Pool`).

    Use as a context manager to keep one pool for many batches (and runs)::

        with Evaluator(problem, n_jobs=2) as ev:
            f, g = ev(X)
    """

    def __init__(self, fun, constraints=None, *, n_jobs: int = 1, backend: str = "loky", scheduler=None,
                 executor=None):
        self.objective = Objective(fun, constraints)
        self.pool = Pool(n_jobs, backend, scheduler, executor=executor, shared=self.objective)

    # -- lifecycle ------------------------------------------------------------------------
    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def workers(self) -> int:
        """Number of parallel workers (1 in-process)."""
        return self.pool.workers

    def open(self):
        """Warm the jitted kernels here, then start the pool or connect to the cluster."""
        self.objective.warm_up()
        self.pool.open()
        return self

    def close(self):
        """Forget the pool (its processes stay alive for reuse until the interpreter exits)."""
        self.pool.close()

    # -- work -------------------------------------------------------------------------------
    def __call__(self, X):
        """Evaluate X (n, d); returns f (n,) and g (n, m)."""
        return evaluate_in(self.pool, X)
