"""Batch evaluation in-process, in a persistent joblib (loky) process pool, or on a Dask cluster.

The evaluator splits a batch into contiguous chunks, evaluates them where configured and
concatenates the results in order, so the numbers never depend on the number of workers.
"""

from __future__ import annotations

import numpy as np

from heurtune.errors import ConfigError

__all__ = ["Evaluator", "BACKENDS", "normalise"]

BACKENDS = ("loky", "dask")
CHUNKS_PER_WORKER = 4


def normalise(result, constraints, X):
    """``(f, g)`` from a user function's output: f (n,), g (n, m) with m >= 0."""
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
    f = np.asarray(f, dtype=np.float64).reshape(-1)
    if f.shape != (n,):
        raise ValueError(f"the objective returned {f.size} values for {n} candidates")
    g = np.zeros((n, 0)) if g is None else np.asarray(g, dtype=np.float64).reshape(n, -1)
    return f, g


# Worker-process state: the objective is shipped once, when the worker starts.
_WORKER = {}


def _init_worker(fun, constraints):
    """Loky worker initialiser: pin BLAS to one thread, keep the objective, warm its kernels."""
    from threadpoolctl import threadpool_limits

    _WORKER["limits"] = threadpool_limits(1)
    _WORKER["fun"] = (fun, constraints)
    warm = getattr(fun, "warm_up", None)
    if callable(warm):
        warm()


def _worker_block(X):
    fun, constraints = _WORKER["fun"]
    return normalise(fun(X), constraints, X)


def _run_task(fn, item):
    return fn(item)


def _dask_block(fun_and_constraints, X):
    from threadpoolctl import threadpool_limits

    fun, constraints = fun_and_constraints
    with threadpool_limits(1):
        return normalise(fun(X), constraints, X)


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

    Use as a context manager to keep one pool for many batches (and runs)::

        with Evaluator(problem, n_jobs=2) as ev:
            f, g = ev(X)
    """

    def __init__(self, fun, constraints=None, *, n_jobs: int = 1, backend: str = "loky", scheduler=None):
        if backend not in BACKENDS:
            raise ConfigError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
        if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
            raise ConfigError(f"n_jobs must be a positive integer, got {n_jobs!r}")
        if backend == "dask" and scheduler is None:
            raise ConfigError("backend 'dask' needs a scheduler address (e.g. tcp://host:8786)")
        self.fun = fun
        self.constraints = constraints
        self.n_jobs = n_jobs
        self.backend = backend
        self.scheduler = scheduler
        self._parallel = None
        self._client = None
        self._owns_client = False
        self._remote_fun = None
        self._controller = None

    # -- lifecycle ------------------------------------------------------------------------
    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def workers(self) -> int:
        """Number of parallel workers (1 in-process)."""
        if self._client is not None:
            return max(1, len(self._client.scheduler_info().get("workers", {})))
        return self.n_jobs

    def open(self):
        """Warm the jitted kernels here, then start the pool or connect to the cluster."""
        warm = getattr(self.fun, "warm_up", None)
        if callable(warm):
            warm()
        if self.backend == "dask":
            if self._client is None:
                from distributed import Client

                if isinstance(self.scheduler, Client):
                    self._client = self.scheduler
                else:
                    self._client = Client(self.scheduler)
                    self._owns_client = True
                self._remote_fun = self._client.scatter((self.fun, self.constraints), broadcast=True, hash=False)
        elif self.n_jobs > 1 and self._parallel is None:
            # joblib's process pool (loky), reused across calls and across evaluators of the
            # same objective; the objective travels once per worker, in the initialiser.
            from joblib.externals.loky import get_reusable_executor

            self._parallel = get_reusable_executor(max_workers=self.n_jobs, initializer=_init_worker,
                                                   initargs=(self.fun, self.constraints))
        return self

    def close(self):
        """Forget the pool (its processes stay alive for reuse until the interpreter exits)."""
        self._parallel = None
        if self._client is not None:
            if self._owns_client:
                self._client.close()
            self._client = None
            self._remote_fun = None

    def _blas_one_thread(self):
        """BLAS pinned to one thread in-process too, so that n_jobs never changes a number."""
        if self._controller is None:
            from threadpoolctl import ThreadpoolController

            self._controller = ThreadpoolController()
        return self._controller.limit(limits=1, user_api="blas")

    # -- work -------------------------------------------------------------------------------
    def _chunks(self, n: int):
        # Several chunks per worker even out candidates of unequal cost (a failed design
        # returns in 0.1 ms, a full simulation takes milliseconds); order is kept.
        k = min(n, self.workers * (CHUNKS_PER_WORKER if self.workers > 1 else 1))
        bounds = np.linspace(0, n, k + 1).round().astype(int)
        return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]

    def __call__(self, X):
        """Evaluate X (n, d); returns f (n,) and g (n, m)."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        if X.shape[0] == 0:
            return np.zeros(0), np.zeros((0, 0))
        if self._parallel is None and self._client is None:
            if self.backend == "dask" or self.n_jobs > 1:
                self.open()
        if self._client is not None:
            futures = [self._client.submit(_dask_block, self._remote_fun, X[a:b], pure=False)
                       for a, b in self._chunks(X.shape[0])]
            parts = self._client.gather(futures)
        elif self._parallel is not None:
            futures = [self._parallel.submit(_worker_block, X[a:b]) for a, b in self._chunks(X.shape[0])]
            parts = [fut.result() for fut in futures]
        else:
            with self._blas_one_thread():
                parts = [normalise(self.fun(X), self.constraints, X)]
        f = np.concatenate([p[0] for p in parts])
        widths = {p[1].shape[1] for p in parts}
        if len(widths) != 1:
            raise ValueError("the constraint function returned different numbers of constraints")
        return f, np.vstack([p[1] for p in parts])

    def map(self, fn, items) -> list:
        """Run ``fn(item)`` for every item on the workers (in order); for whole local solves."""
        items = list(items)
        if self._parallel is None and self._client is None and (self.backend == "dask" or self.n_jobs > 1):
            self.open()
        if self._client is not None:
            futures = self._client.map(_run_task, [fn] * len(items), items, pure=False)
            return self._client.gather(futures)
        if self._parallel is not None:
            futures = [self._parallel.submit(_run_task, fn, item) for item in items]
            return [fut.result() for fut in futures]
        with self._blas_one_thread():
            return [fn(item) for item in items]

    def imap_unordered(self, fn, items):
        """Run ``fn(item)`` for every item on the workers; yield ``(index, result)`` as each ends.

        Results come in the order the workers finish them (in-process: in item order), so a
        caller can save each one at once; what is computed does not depend on that order.
        Items not yet started are cancelled if the caller stops early (e.g. on Ctrl-C).
        """
        items = list(items)
        if self._parallel is None and self._client is None and (self.backend == "dask" or self.n_jobs > 1):
            self.open()
        if self._client is None and self._parallel is None:
            for i, item in enumerate(items):
                with self._blas_one_thread():
                    result = fn(item)
                yield i, result
            return
        if self._client is not None:
            from distributed import as_completed

            futures = self._client.map(_run_task, [fn] * len(items), items, pure=False)
            index = {fut.key: i for i, fut in enumerate(futures)}
            done = as_completed(futures)
        else:
            import concurrent.futures

            futures = [self._parallel.submit(_run_task, fn, item) for item in items]
            index = {fut: i for i, fut in enumerate(futures)}
            done = concurrent.futures.as_completed(futures)
        try:
            for fut in done:
                yield index[fut.key if self._client is not None else fut], fut.result()
        finally:
            for fut in futures:
                fut.cancel()
