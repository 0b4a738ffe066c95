"""The pymoo: bridge: pymoo's single-objective algorithms by name, seeded, in the unit box, within
the budget, with pymoo's batch as the evaluator's, and one-line errors for an unknown name, a
setting that does not apply, a missing extra and a failure inside pymoo. The engine contract
(seeds, budgets, workers, ...) runs on pymoo:DE and pymoo:GA in tests/core/test_engine_contract.py."""

from __future__ import annotations

import builtins

import numpy as np
import pytest
from numerics import assert_same_bits

import heurtune
from heurtune.core import registry
from heurtune.core.errors import ConfigError

pytest.importorskip("pymoo")


def sphere(X):
    return ((X - 0.3) ** 2).sum(axis=1)


def test_a_bridged_algorithm_runs_seeded_within_its_budget_in_the_box_in_pymoos_batches():
    lower, upper = np.array([-1.0, 0.0, 5.0]), np.array([1.0, 2.0, 6.0])
    batches = []

    def fun(X):
        batches.append(X.copy())
        return sphere(X)

    a = heurtune.minimize(fun, lower, upper, "pymoo:DE", max_evals=250, seed=3, settings={"pop_size": 20})
    b = heurtune.minimize(sphere, lower, upper, "pymoo:DE", max_evals=250, seed=3, settings={"pop_size": 20})
    c = heurtune.minimize(sphere, lower, upper, "pymoo:DE", max_evals=250, seed=4, settings={"pop_size": 20})
    X = np.vstack(batches)
    assert a.n_evals == len(X) == 250 and np.all((X >= lower) & (X <= upper))
    assert [len(B) for B in batches[:-1]] == [20] * 12 and len(batches[-1]) == 10  # the budget cuts the last
    assert_same_bits(a.f, b.f, because="same seed")
    assert_same_bits(a.x, b.x, because="same seed")
    assert a.f != c.f


def test_the_run_does_not_touch_numpys_global_random_state():
    # the legacy global state is what is checked here
    np.random.seed(11)  # noqa: NPY002
    before = np.random.random()  # noqa: NPY002
    np.random.seed(11)  # noqa: NPY002
    heurtune.minimize(sphere, -np.ones(3), np.ones(3), "pymoo:GA", max_evals=200, seed=1)
    assert_same_bits(np.random.random(), before, because="same seed")  # noqa: NPY002 - the legacy state untouched


def test_it_converges_and_an_algorithm_that_stops_itself_ends_the_run():
    de = heurtune.minimize(sphere, -np.ones(4), np.ones(4), "pymoo:DE", max_evals=4000, seed=1)
    assert de.f < 1e-3
    cma = heurtune.minimize(sphere, -np.ones(4), np.ones(4), "pymoo:CMAES", max_evals=20000, seed=1)
    assert cma.stop_reason == "finished" and cma.n_evals < 20000 and cma.f < 1e-10


def test_unknown_names_and_bad_settings_are_one_line_errors():
    with pytest.raises(ConfigError, match=r"the pymoo bridge has no algorithm 'Nope'; allowed: DE, GA, "):
        registry.get("pymoo:Nope")
    with pytest.raises(ConfigError, match="pop_size must be 0"):
        registry.make_settings("pymoo:DE", {"pop_size": 1})
    with pytest.raises(ConfigError, match="pop_size does not apply"):
        heurtune.minimize(sphere, -np.ones(3), np.ones(3), "pymoo:CMAES", max_evals=50, settings={"pop_size": 8})
    with pytest.raises(ConfigError, match=r"pymoo:<name> \(pymoo's single-objective"):
        registry.get("nope")


def test_a_failure_inside_pymoo_ends_the_run_with_one_line(monkeypatch):
    from pymoo.algorithms.soo.nonconvex.ga import GA

    def broken(self, *args, **kwargs):
        raise ValueError("broken\nsecond line")

    monkeypatch.setattr(GA, "_advance", broken)
    with pytest.raises(ConfigError, match=r"^pymoo:GA failed inside pymoo \S+: ValueError: broken$"):
        heurtune.minimize(sphere, -np.ones(3), np.ones(3), "pymoo:GA", max_evals=300, seed=1)


def test_a_missing_extra_names_the_install(monkeypatch):
    from heurtune.algorithms import pymoo_bridge

    real_import = builtins.__import__

    def no_pymoo(name, *args, **kwargs):
        if name == "pymoo":
            raise ImportError("no pymoo")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pymoo)
    with pytest.raises(ConfigError, match=r"pip install 'heurtune\[pymoo\]'"):
        pymoo_bridge.resolve("DE")
