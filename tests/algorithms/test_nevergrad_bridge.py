"""The ng: bridge: nevergrad's optimisers by name, seeded, in the unit box, within the budget, with
one-line errors for an unknown name, a missing extra and a failure inside nevergrad. The engine
contract (seeds, budgets, workers, ...) runs on ng:CMA, ng:TwoPointsDE and ng:PSO in
tests/core/test_engine_contract.py."""

from __future__ import annotations

import builtins

import numpy as np
import pytest
from numerics import assert_same_bits

import heurtune
from heurtune.core import registry
from heurtune.core.errors import ConfigError

pytest.importorskip("nevergrad")


def sphere(X):
    return ((X - 0.3) ** 2).sum(axis=1)


def test_a_bridged_optimiser_runs_seeded_within_its_budget_in_the_box():
    lower, upper = np.array([-1.0, 0.0, 5.0]), np.array([1.0, 2.0, 6.0])
    seen = []

    def fun(X):
        seen.append(X.copy())
        return sphere(X)

    a = heurtune.minimize(fun, lower, upper, "ng:TwoPointsDE", max_evals=97, seed=3, settings={"batch": 8})
    b = heurtune.minimize(sphere, lower, upper, "ng:TwoPointsDE", max_evals=97, seed=3, settings={"batch": 8})
    c = heurtune.minimize(sphere, lower, upper, "ng:TwoPointsDE", max_evals=97, seed=4, settings={"batch": 8})
    X = np.vstack(seen)
    assert a.n_evals == len(X) == 97 and np.all((X >= lower) & (X <= upper))
    assert_same_bits(a.f, b.f, because="same seed")
    assert_same_bits(a.x, b.x, because="same seed")
    assert a.f != c.f
    assert registry.get("ng:TwoPointsDE").settings().batch == 10


def test_the_budget_reaches_ngopt_which_picks_cma_for_ten_variables():
    res = heurtune.minimize(sphere, -np.ones(10), np.ones(10), "ng:NGOpt", max_evals=1000, seed=1)
    assert res.n_evals == 1000 and res.f < 1e-4


def test_unknown_names_and_bad_settings_are_one_line_errors():
    with pytest.raises(ConfigError, match="nevergrad has no optimiser 'Nope'"):
        registry.get("ng:Nope")
    with pytest.raises(ConfigError, match="batch must be >= 1"):
        registry.make_settings("ng:CMA", {"batch": 0})
    with pytest.raises(ConfigError, match=r"ng:<name> \(nevergrad's optimisers"):
        registry.get("nope")


def test_a_failure_inside_nevergrad_ends_the_run_with_one_line():
    """NGOpt picks nevergrad's MetaModel here, which fails under NumPy 2 in nevergrad 1.0.12;
    where it runs (a fixed nevergrad), the run simply finishes."""
    try:
        heurtune.minimize(sphere, -np.ones(4), np.ones(4), "ng:NGOpt", max_evals=2000, seed=1)
    except ConfigError as exc:
        assert str(exc).startswith("ng:NGOpt failed inside nevergrad ") and "\n" not in str(exc)


def test_a_missing_extra_names_the_install(monkeypatch):
    from heurtune.algorithms import nevergrad_bridge

    real_import = builtins.__import__

    def no_nevergrad(name, *args, **kwargs):
        if name == "nevergrad":
            raise ImportError("no nevergrad")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_nevergrad)
    with pytest.raises(ConfigError, match=r"pip install 'heurtune\[nevergrad\]'"):
        nevergrad_bridge.resolve("CMA")
