"""Runs in lockstep: one batch per generation across runs, each run's results as if alone."""

import functools
import threading

import numpy as np
import pandas as pd
import pytest
from numerics import assert_same_bits

from heurtune.core.engine import SearchSpace, run
from heurtune.core.evaluator import Evaluator
from heurtune.core.lockstep import Lockstep, LockstepAborted


def rosenbrock_with_constraint(X):
    X = np.atleast_2d(X)
    f = np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)
    g = (X.sum(axis=1) - 2.0)[:, None]  # sum(x) <= 2
    return f, g


def shifted_sphere(X):
    return ((np.atleast_2d(X) - 0.3) ** 2).sum(axis=1)


PROBLEMS = {"rosen": rosenbrock_with_constraint, "sphere": shifted_sphere}
RUNS = [("rosen", "cs", 1, {}), ("rosen", "pso", 2, {}), ("sphere", "firefly", 3, {}), ("sphere", "ga", 4, {}),
        ("rosen", "sqp_multistart", 5, {"starts": 4, "batch": 2, "max_iter": 15})]
SPACE = SearchSpace(np.full(3, -2.0), np.full(3, 2.0))


def one_run(evaluator, algorithm, seed, settings):
    budget = dict(max_evals=400) if algorithm == "sqp_multistart" else dict(max_epochs=12)
    return run(algorithm, evaluator, SPACE, settings=settings, seed=seed, **budget)


def assert_same_result(a, b):
    assert_same_bits(a.x, b.x, because="lockstep")
    assert_same_bits([a.f, a.violation], [b.f, b.violation], because="lockstep")
    assert (a.n_evals, a.n_epochs, a.stop_reason) == (b.n_evals, b.n_epochs, b.stop_reason)
    cols = [c for c in a.history.columns if c != "wall_time_s"]  # wall_time_s is a clock reading
    assert_same_bits(a.history[cols], b.history[cols], because="lockstep")


def test_runs_in_lockstep_equal_runs_alone_and_share_batches():
    alone, alone_calls = [], []
    for group, algorithm, seed, settings in RUNS:
        sizes = []

        def counted(X, fun=PROBLEMS[group], sizes=sizes):
            sizes.append(len(X))
            return fun(X)

        with Evaluator(counted) as ev:
            alone.append(one_run(ev, algorithm, seed, settings))
        alone_calls.append(sizes)
    calls = []

    def evaluate(batches):
        out = {}
        for group, X in batches.items():
            calls.append((group, X.shape[0]))
            with Evaluator(PROBLEMS[group]) as ev:
                out[group] = ev(X)
        return out

    hub = Lockstep(evaluate)
    targets = [lambda g=g, a=a, s=s, st=st: one_run(hub.client(g), a, s, st) for g, a, s, st in RUNS]
    together = dict(hub.run(targets))
    for i, res in enumerate(alone):
        assert_same_result(together[i], res)
    # The batches gather the runs of a group: fewer, larger calls than the runs make alone.
    assert sum(n for _, n in calls) == sum(sum(c) for c in alone_calls)
    assert len(calls) < sum(len(c) for c in alone_calls) / 2
    assert max(n for _, n in calls) > max(max(c) for c in alone_calls)


def test_an_error_in_one_run_stops_the_others_and_is_raised():
    def evaluate(batches):
        if "bad" in batches:
            raise ValueError("boom in the objective")
        return {group: (shifted_sphere(X), np.zeros((X.shape[0], 0))) for group, X in batches.items()}

    hub = Lockstep(evaluate)
    targets = [lambda: one_run(hub.client("good"), "cs", 1, {}), lambda: one_run(hub.client("bad"), "cs", 2, {})]
    with pytest.raises(ValueError, match="boom in the objective"):
        list(hub.run(targets))
    # the other run's thread unwinds instead of waiting for ever
    for t in threading.enumerate():
        if t is not threading.current_thread() and t.daemon:
            t.join(timeout=5)
    with pytest.raises(LockstepAborted):
        hub.submit("good", np.zeros((1, 3)))


def test_runner_lockstep_gives_the_same_files(tmp_path):
    from heurtune.runner.experiment import run_experiment

    out = {}
    for lockstep in (False, True):
        out[lockstep] = run_experiment("sqp_folqi_qtp", smoke=True, seed=3, out=tmp_path / str(lockstep),
                                       progress_stream=open("/dev/null", "w"), figures=False, lockstep=lockstep)
    for name in ("runs", "history", "starts"):
        a, b = (pd.read_parquet(out[k] / f"{name}.parquet") for k in (False, True))
        cols = [c for c in a.columns if "wall" not in c]  # wall-clock times are not results
        assert_same_bits(a[cols], b[cols], because="lockstep")


@pytest.mark.parametrize("width", [1, 3, 32])
def test_fan_out_runs_a_window_of_items_and_starts_none_after_an_early_stop(width):
    """A driver's items run at most ``fan_out_width`` at once, each item's values are its own
    whatever shares its batches, and a consumer that stops early (a multistart run at its
    ``max_epochs``) leaves the items not yet started unstarted."""
    started, running, most = [], [0], [0]
    guard = threading.Lock()

    def evaluate(batches):
        return {group: (X.sum(axis=1), np.zeros((X.shape[0], 0))) for group, X in batches.items()}

    hub = Lockstep(evaluate)
    hub.fan_out_width = width

    def solve(client, k):
        with guard:
            started.append(k)
            running[0] += 1
            most[0] = max(most[0], running[0])
        total = 0.0
        for step in range(3):  # a few evaluations per item, as a local solve makes
            f, _ = client(np.full((1 + step, 2), float(k)))
            total += float(f.sum())
        with guard:
            running[0] -= 1
        return total

    def driver():
        client = hub.client("g")
        got = {}
        for j, value in client.imap_unordered(functools.partial(solve, client), range(40)):
            got[j] = value
            if len(got) == 5:
                break
        return got

    [(_, got)] = list(hub.run([driver]))
    assert most[0] <= width
    # exact: sums of small integers
    assert len(got) == 5 and all(v == 2.0 * j * (1 + 2 + 3) for j, v in got.items())
    assert len(started) <= 5 + width - 1  # at most the window that was running at the stop
    assert running[0] == 0  # the running items ended before the driver went on
