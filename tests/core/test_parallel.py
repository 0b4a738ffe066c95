"""Parallel evaluation: joblib pool, Dask cluster and user executors give bit-identical runs."""

import concurrent.futures
import operator
import threading

import numpy as np
import pytest
from numerics import assert_same_bits

import heurtune
from heurtune.core.evaluator import Evaluator
from heurtune.core.execution import Pool, shared


@pytest.fixture(scope="module")
def qtp():
    return heurtune.load_experiment("cs_folqi_qtp").problem("min")


def test_evaluator_chunks_give_the_same_numbers(qtp):
    rng = np.random.default_rng(0)
    X = qtp.lower + rng.random((7, qtp.dim)) * (qtp.upper - qtp.lower)
    serial = Evaluator(qtp)(X)
    with Evaluator(qtp, n_jobs=2) as ev:
        pooled = ev(X)
        again = ev(X[:3])  # the pool is reused
    assert_same_bits(serial[0], pooled[0], because="workers")
    assert_same_bits(serial[1], pooled[1], because="workers")
    assert_same_bits(serial[0][:3], again[0], because="shared kernel")  # three candidates without the other four


def test_minimize_is_bit_identical_with_one_and_two_workers(qtp):
    kw = dict(max_evals=40, seed=11, settings=dict(n=5))
    a = heurtune.minimize(qtp, qtp.lower, qtp.upper, "cs", n_jobs=1, **kw)
    b = heurtune.minimize(qtp, qtp.lower, qtp.upper, "cs", n_jobs=2, **kw)
    cols = ["epoch", "n_evals", "best_f", "best_violation", "mean_f", "sd_f", "feasible_fraction"]
    assert_same_bits(a.history[cols], b.history[cols], because="workers")
    assert_same_bits(a.x, b.x, because="workers")
    assert a.n_evals == b.n_evals == 40


def test_dask_backend_on_a_local_cluster(qtp):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        kw = dict(max_evals=30, seed=3, settings=dict(n=5))
        local = heurtune.minimize(qtp, qtp.lower, qtp.upper, "cs", **kw)
        remote = heurtune.minimize(qtp, qtp.lower, qtp.upper, "cs", backend="dask",
                                   scheduler=cluster.scheduler_address, **kw)
    assert_same_bits(local.x, remote.x, because="workers")
    assert_same_bits(local.history["best_f"], remote.history["best_f"], because="workers")


def test_bad_parallel_settings_are_clear_errors():
    with pytest.raises(heurtune.ConfigError, match="n_jobs must be a positive integer"):
        Evaluator(lambda X: X[:, 0], n_jobs=0)
    with pytest.raises(heurtune.ConfigError, match="unknown backend 'mpi'; allowed: loky, dask"):
        Evaluator(lambda X: X[:, 0], backend="mpi")
    with pytest.raises(heurtune.ConfigError, match="needs a scheduler address"):
        Evaluator(lambda X: X[:, 0], backend="dask")
    with pytest.raises(heurtune.ConfigError, match="executor must be a concurrent.futures.Executor"):
        Evaluator(lambda X: X[:, 0], executor=object())


def test_any_executor_gives_the_same_numbers(qtp):
    """A user's concurrent.futures executor (threads here, processes below) evaluates the same
    chunks; the results are bit-identical to the in-process ones."""
    rng = np.random.default_rng(1)
    X = qtp.lower + rng.random((9, qtp.dim)) * (qtp.upper - qtp.lower)
    serial = Evaluator(qtp)(X)
    with concurrent.futures.ThreadPoolExecutor(2) as pool, Evaluator(qtp, executor=pool) as ev:
        assert ev.workers == 2
        threaded = ev(X)
    with concurrent.futures.ProcessPoolExecutor(2) as pool, Evaluator(qtp, executor=pool) as ev:
        forked = ev(X)
    for got in (threaded, forked):
        assert_same_bits(serial[0], got[0], because="workers")
        assert_same_bits(serial[1], got[1], because="workers")


def test_pool_runs_tasks_in_order_and_as_they_finish():
    for pool in (Pool(1), Pool(2)):
        with pool:
            assert pool.map(operator.neg, [1, 2, 3]) == [-1, -2, -3]
            assert sorted(pool.imap_unordered(operator.neg, [5, 6])) == [(0, -5), (1, -6)]
    assert Pool(1, shared=10).map(_plus_shared, [1, 2]) == [11, 12]  # in-process: the shared object


def _plus_shared(x):
    return x + shared()


def test_in_process_pools_in_threads_each_see_their_own_shared_object():
    # the suite's folders side by side: each thread's in-process pools (the work plan's dry runs)
    both_inside = threading.Barrier(2)

    def read(_):
        both_inside.wait(timeout=30)
        return shared()

    def one(value):
        with Pool(1, shared=value) as pool:
            return pool.map(read, [0])[0]

    with concurrent.futures.ThreadPoolExecutor(2) as threads:
        assert list(threads.map(one, ["first", "second"])) == ["first", "second"]
