"""Where work runs: this process, a persistent joblib (loky) process pool, a Dask cluster, or any
``concurrent.futures.Executor``. One layer for the evaluator (batches of candidates) and the
runner (whole tuning runs).

A :class:`Pool` runs ``fn(item)`` for a list of items, in order (:meth:`Pool.map`) or as they
finish (:meth:`Pool.imap_unordered`). An object every task needs (the objective of an
evaluator) is given once as ``shared``: it travels once per worker (loky initialiser, Dask
scatter) or with each task (a user's executor), and a task reads it with :func:`shared`.

BLAS is pinned to one thread wherever a task runs, so the number of workers never changes a
number. Workers load the plugins loaded here (:func:`heurtune.core.plugins.loaded`) before
anything else, so objects of a plugin's classes reach them intact.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import hashlib
import os
import pickle
import signal
import threading
import time

import cloudpickle

from heurtune.core.errors import ConfigError
from heurtune.core.plugins import load_plugins, loaded

__all__ = ["Pool", "BACKENDS", "shared", "kill_workers", "process_executor"]

BACKENDS = ("loky", "dask")

_SHARED = {}  # this process's shared object (set by the initialiser or the task)
_INSTALLING = threading.Lock()  # the tasks of a user's thread executor install theirs at once
_HERE = threading.local()  # the shared object of the task this thread runs, where it is not the process's


def shared():
    """The ``shared`` object of the pool this task runs in."""
    value = getattr(_HERE, "value", _HERE)
    return _SHARED["value"] if value is _HERE else value


@contextlib.contextmanager
def _shared_here(value):
    """Make ``value`` this thread's shared object while the block runs: the tasks of several
    pools may run in threads of one process at once (in-process pools of the suite's folders
    side by side, a user's thread executor)."""
    previous = getattr(_HERE, "value", _HERE)
    _HERE.value = value
    try:
        yield value
    finally:
        if previous is _HERE:
            del _HERE.value
        else:
            _HERE.value = previous


_LOKY = []  # the loky executors this process's pools have opened (see kill_workers)


def _kill(executor) -> None:
    """Kill a loky executor's worker processes here and now: ``shutdown(kill_workers=True)``
    leaves that to loky's manager thread, which an exit right after never lets run."""
    for process in list(getattr(executor, "_processes", {}).values()):
        try:
            os.kill(process.pid, signal.SIGKILL)  # loky's Popen has no kill()
            process.join(timeout=1.0)
        except (OSError, ValueError, AttributeError):  # already gone
            pass
    try:
        executor.shutdown(wait=False, kill_workers=True)
    except Exception:  # noqa: BLE001 - an executor broken by the interrupt is gone anyway
        pass


def kill_workers() -> None:
    """Kill every loky worker this process started, at once (after Ctrl-C or SIGTERM: loky
    would otherwise keep them, and its resource trackers, alive for a minute or two)."""
    while _LOKY:
        _kill(_LOKY.pop())
    # An interrupt inside loky's start-up leaves its executor unregistered above: loky keeps it
    # as its module's reusable executor.
    from joblib.externals.loky import reusable_executor

    if getattr(reusable_executor, "_executor", None) is not None:
        _kill(reusable_executor._executor)


def process_executor(n_jobs: int) -> concurrent.futures.Executor:
    """The persistent loky pool of ``n_jobs`` worker processes that a :class:`Pool` of that size
    without a shared object uses, as an executor that several Pools can share at once (the
    suite's folders side by side); :func:`kill_workers` kills it.

    Parameters
    ----------
    n_jobs : int
        Workers, at least 2 (one worker is this process: :class:`Pool` runs its tasks here).

    Returns
    -------
    concurrent.futures.Executor
        joblib's loky executor; give it to :class:`Pool` as ``executor``.
    """
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 2:
        raise ConfigError(f"a process executor needs n_jobs >= 2, got {n_jobs!r}")
    return Pool(n_jobs).open()._loky


_CONTROLLER = []  # one threadpoolctl controller per process (building one costs milliseconds)


def _blas_one_thread():
    if not _CONTROLLER:
        from threadpoolctl import ThreadpoolController

        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")


def _install(plugins, key, payload):
    """Make ``payload`` (the pickled shared object) this process's shared object, once per key.

    The plugins are loaded first: the payload may hold objects of a plugin's classes, which a
    fresh worker can only unpickle once the plugin's module exists there.
    """
    with _INSTALLING:
        if _SHARED.get("key") != key:
            load_plugins(plugins)
            _SHARED["value"] = pickle.loads(payload) if payload is not None else None
            _SHARED["key"] = key
        return _SHARED["value"]


class WorkerDied(Exception):
    """A worker process died (killed, out of memory) while it ran item ``index`` of
    :meth:`Pool.imap_unordered` (None when it is not known which)."""

    def __init__(self, index, cause):
        super().__init__(f"a worker process died ({type(cause).__name__})")
        self.index = index


def is_worker_death(exc: BaseException) -> bool:
    """Whether ``exc`` says that a worker process of the pool died (loky, concurrent.futures)."""
    return type(exc).__name__ in ("TerminatedWorkerError", "BrokenProcessPool", "BrokenExecutor")


# How often a worker checks that the process that started it still runs (s).
PARENT_CHECK_S = 0.5


def _watch_parent(parent: int) -> None:
    """Exit this worker once its parent is gone (killed by SIGKILL, which no handler sees; the
    worker is then adopted by another process), instead of finishing its run for no one."""
    while True:
        if os.getppid() != parent:
            os._exit(1)
        time.sleep(PARENT_CHECK_S)


def _init_worker(plugins, key, payload, parent=None):
    """Loky worker initialiser: watch the parent (the pid of the process that opened the pool:
    a worker that starts after its parent died sees another parent at once), pin BLAS to one
    thread, install the shared object, warm it."""
    from threadpoolctl import threadpool_limits

    threading.Thread(target=_watch_parent, args=(os.getppid() if parent is None else parent,), daemon=True,
                     name="heurtune-parent-watch").start()
    _SHARED["limits"] = threadpool_limits(1)
    value = _install(plugins, key, payload)
    warm = getattr(value, "warm_up", None)  # an objective's jitted kernels, compiled once per worker
    if callable(warm):
        warm()


def _task(fn, item):
    return fn(item)


def _task_with(plugins, key, payload, fn, item):
    """A task that brings its plugins and shared object along (Dask, user executors)."""
    with _shared_here(_install(plugins, key, payload)), _blas_one_thread():
        return fn(item)


class Pool:
    """Run tasks in this process, a loky pool, a Dask cluster or a user's executor.

    Parameters
    ----------
    n_jobs : int
        Workers of the loky pool; 1 runs tasks in this process (no pool).
    backend : {"loky", "dask"}
    scheduler : str or distributed.Client, optional
        Dask scheduler address (or a Client), for ``backend="dask"``.
    executor : concurrent.futures.Executor, optional
        Run tasks there instead (e.g. a ``ThreadPoolExecutor``); ``n_jobs`` then only sets how
        many workers the chunking assumes (default: ``executor._max_workers`` when it has one).
    shared : object, optional
        What every task reads with :func:`shared`.
    """

    def __init__(self, n_jobs: int = 1, backend: str = "loky", scheduler=None, *, executor=None, shared=None):
        if backend not in BACKENDS:
            raise ConfigError(f"unknown backend {backend!r}; allowed: {', '.join(BACKENDS)}")
        if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
            raise ConfigError(f"n_jobs must be a positive integer, got {n_jobs!r}")
        if backend == "dask" and scheduler is None and executor is None:
            raise ConfigError("backend 'dask' needs a scheduler address (e.g. tcp://host:8786)")
        if executor is not None and not isinstance(executor, concurrent.futures.Executor):
            raise ConfigError(f"executor must be a concurrent.futures.Executor, got {type(executor).__name__}")
        self.n_jobs = n_jobs
        self.backend = backend
        self.scheduler = scheduler
        self.executor = executor
        self.value = shared
        self._key = None  # names this pool's shared object in the workers (a hash of its pickle)
        self._payload = None
        self._loky = None
        self._client = None
        self._owns_client = False
        self._remote = None

    # -- lifecycle ------------------------------------------------------------------------
    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    @property
    def in_process(self) -> bool:
        """True when tasks run in this process."""
        return self.executor is None and self.backend == "loky" and self.n_jobs == 1

    @property
    def workers(self) -> int:
        """Number of parallel workers (1 in-process)."""
        if self._client is not None:
            return max(1, len(self._client.scheduler_info().get("workers", {})))
        if self.executor is not None:
            return int(getattr(self.executor, "_max_workers", self.n_jobs) or self.n_jobs)
        return self.n_jobs

    def open(self):
        """Start the loky pool or connect to the Dask cluster (nothing for the others)."""
        if self.in_process:
            return self
        if self._key is None:
            # Pools of equal shared objects share a key, so that loky reuses its workers.
            self._payload = None if self.value is None else cloudpickle.dumps(self.value)
            self._key = hashlib.sha256(self._payload or b"").hexdigest()
        if self.executor is not None:
            return self
        if self.backend == "dask":
            if self._client is None:
                from distributed import Client

                if isinstance(self.scheduler, Client):
                    self._client = self.scheduler
                else:
                    self._client = Client(self.scheduler)
                    self._owns_client = True
                self._remote = self._client.scatter(self._payload, broadcast=True, hash=False)
        elif self._loky is None:
            # joblib's process pool, reused across calls (and across pools with the same shared
            # object); the shared object travels once per worker, in the initialiser.
            from joblib.externals.loky import get_reusable_executor

            self._loky = get_reusable_executor(max_workers=self.n_jobs, initializer=_init_worker,
                                               initargs=(loaded(), self._key, self._payload, os.getpid()))
            if self._loky not in _LOKY:
                _LOKY.append(self._loky)
        return self

    def close(self):
        """Forget the pool (loky's processes stay alive for reuse until the interpreter exits)."""
        self._loky = None
        if self._client is not None:
            if self._owns_client:
                self._client.close()
            self._client = None
            self._remote = None

    def abort(self):
        """Stop at once: cancel what has not started and kill the loky workers."""
        if self._loky is not None:
            _kill(self._loky)
            self._loky = None

    # -- work ---------------------------------------------------------------------------------
    def _run_here(self, fn, items) -> list:
        """``[fn(item) ...]`` in this process, with this pool's shared object and BLAS on one thread."""
        with _shared_here(self.value), _blas_one_thread():
            return [fn(item) for item in items]

    def _submit_all(self, fn, items):
        self.open()
        n = len(items)
        if self._client is not None:
            return self._client.map(_task_with, [loaded()] * n, [self._key] * n, [self._remote] * n, [fn] * n,
                                    items, pure=False)
        if self._loky is not None:
            return [self._loky.submit(_task, fn, item) for item in items]
        return [self.executor.submit(_task_with, loaded(), self._key, self._payload, fn, item) for item in items]

    def map(self, fn, items) -> list:
        """``[fn(item) for item in items]``, run on the workers, in order."""
        items = list(items)
        if self.in_process:
            return self._run_here(fn, items)
        futures = self._submit_all(fn, items)
        if self._client is not None:
            return self._client.gather(futures)
        try:
            return [fut.result() for fut in futures]
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise

    def imap_unordered(self, fn, items):
        """Run ``fn(item)`` for every item; yield ``(index, result)`` as each ends.

        In-process the items run in order. What is computed does not depend on the order; a
        caller can save each result at once. Items not yet started are cancelled if the caller
        stops early (e.g. on Ctrl-C).
        """
        items = list(items)
        if self.in_process:
            for i, item in enumerate(items):
                yield i, self._run_here(fn, [item])[0]
            return
        futures = self._submit_all(fn, items)
        if self._client is not None:
            from distributed import as_completed

            index = {fut.key: i for i, fut in enumerate(futures)}
            done = as_completed(futures)
        else:
            index = {fut: i for i, fut in enumerate(futures)}
            done = concurrent.futures.as_completed(futures)
        try:
            for fut in done:
                i = index[fut.key if self._client is not None else fut]
                try:
                    result = fut.result()
                except Exception as exc:
                    if is_worker_death(exc):
                        raise WorkerDied(i, exc) from exc
                    raise
                yield i, result
        finally:
            for fut in futures:
                fut.cancel()
