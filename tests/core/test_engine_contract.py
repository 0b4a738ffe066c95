"""Contract tests over every registered optimiser (and a toy plugin defined here).

Every optimiser, merely by being registered, must: keep its evaluations inside the bounds,
survive NaN and inf objective values, give the same history for the same seed (even after the
global NumPy RNG is disturbed), different histories for different seeds, and spend a budget of
evaluations exactly.
"""

import dataclasses

import numpy as np
import pytest

import heurtune
from heurtune.core import registry
from heurtune.core.engine import Optimizer
from heurtune.core.plugins import load_plugin

LOWER = np.array([-2.0, -1.0, 0.0, 5.0])
UPPER = np.array([3.0, 1.0, 0.5, 6.0])


@dataclasses.dataclass(frozen=True)
class ToySettings:
    n: int = 6


class ToyRandomSearch(Optimizer):
    """Uniform random search: the smallest possible plugin."""

    def ask(self):
        return self.space.uniform(self.rng, self.settings.n)

    def tell(self, X, f, v):
        self.X, self.f, self.v = X, f, v
        return True


registry.register("toy_random_search", settings=ToySettings, description="test plugin")(ToyRandomSearch)


def budgets(name):
    """Small but non-trivial settings so each contract test stays fast."""
    small = {"cs": dict(n=6), "apso": dict(n=6), "firefly": dict(n=6), "pso": dict(n=6),
             "ga": dict(n=6), "sqp_multistart": dict(starts=4, max_iter=5)}
    return small.get(name, {})


NAMES = registry.available()


class Recorder:
    """Objective that remembers every point it saw."""

    def __init__(self, fun):
        self.fun = fun
        self.seen = []

    def __call__(self, X):
        self.seen.append(np.array(X))
        return self.fun(X)


def sphere(X):
    return ((X - 0.3) ** 2).sum(axis=1)


@pytest.mark.parametrize("name", NAMES)
def test_bounds_are_respected(name):
    rec = Recorder(sphere)
    heurtune.minimize(rec, LOWER, UPPER, name, max_evals=300, seed=1, settings=budgets(name))
    X = np.vstack(rec.seen)
    assert np.all(X >= LOWER) and np.all(X <= UPPER)


@pytest.mark.parametrize("name", NAMES)
def test_nan_and_inf_values_are_survived(name):
    def nasty(X):
        f = sphere(X)
        f[X[:, 0] > 1.0] = np.nan
        f[X[:, 1] > 0.5] = np.inf
        return f

    res = heurtune.minimize(nasty, LOWER, UPPER, name, max_evals=300, seed=2, settings=budgets(name))
    assert np.isfinite(res.f) and np.all(res.x >= LOWER) and np.all(res.x <= UPPER)
    assert res.x[0] <= 1.0 and res.x[1] <= 0.5


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_history_different_seed_different_history(name):
    kw = dict(max_evals=200, settings=budgets(name))
    a = heurtune.minimize(sphere, LOWER, UPPER, name, seed=5, **kw)
    np.random.seed(123)
    np.random.random(10)  # a global-RNG poke must change nothing
    b = heurtune.minimize(sphere, LOWER, UPPER, name, seed=5, **kw)
    c = heurtune.minimize(sphere, LOWER, UPPER, name, seed=6, **kw)
    cols = ["epoch", "n_evals", "best_f", "mean_f", "sd_f"]
    assert a.history[cols].equals(b.history[cols])
    np.testing.assert_array_equal(a.x, b.x)
    assert not a.history[cols].equals(c.history[cols])


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("budget", [1, 37, 250])
def test_evaluation_budget_is_exact(name, budget):
    calls = []

    def counting(X):
        calls.append(len(X))
        return sphere(X)

    res = heurtune.minimize(counting, LOWER, UPPER, name, max_evals=budget, seed=3, settings=budgets(name))
    assert sum(calls) == res.n_evals == budget
    assert res.stop_reason == "max_evals"
    assert res.history["n_evals"].iloc[-1] == budget


@pytest.mark.parametrize("name", NAMES)
def test_constraints_steer_to_the_feasible_side(name):
    # minimise x0 subject to x0 >= 1 (g = 1 - x0 <= 0): the optimum sits on the constraint
    res = heurtune.minimize(lambda X: (X[:, 0], (1.0 - X[:, 0])[:, None]), LOWER, UPPER, name,
                            max_evals=400, seed=4, settings=budgets(name))
    assert res.feasible and res.x[0] >= 1.0 and res.f < 2.5


def test_registry_is_strict():
    with pytest.raises(ValueError, match="already registered"):
        registry.register("cs", settings=ToySettings, description="dup")(ToyRandomSearch)
    with pytest.raises(heurtune.ConfigError, match="unknown optimiser 'nope'; allowed: .*cs"):
        registry.get("nope")
    with pytest.raises(heurtune.ConfigError, match="cs: unknown setting 'npop'; allowed: n, pa"):
        registry.make_settings("cs", {"npop": 3})
    with pytest.raises(heurtune.ConfigError, match="cs: setting n must be int"):
        registry.make_settings("cs", {"n": 2.5})
    with pytest.raises(heurtune.ConfigError, match="pa must lie in"):
        registry.make_settings("cs", {"pa": 1.5})


def test_plugin_from_a_file(tmp_path):
    path = tmp_path / "my_opt.py"
    path.write_text(
        "import dataclasses\n"
        "from heurtune.core.engine import Optimizer\n"
        "from heurtune.core.registry import register\n"
        "@dataclasses.dataclass(frozen=True)\n"
        "class S:\n    n: int = 4\n"
        "@register('file_plugin_demo', settings=S, description='demo')\n"
        "class Demo(Optimizer):\n"
        "    def ask(self):\n        return self.space.uniform(self.rng, self.settings.n)\n"
        "    def tell(self, X, f, v):\n        self.X, self.f, self.v = X, f, v\n        return True\n"
    )
    load_plugin(str(path))
    load_plugin(str(path))  # loading the same file twice is harmless
    res = heurtune.minimize(sphere, LOWER, UPPER, "file_plugin_demo", max_evals=20)
    assert res.n_evals == 20


def test_termination_reasons_and_history():
    res = heurtune.minimize(sphere, LOWER, UPPER, "cs", max_epochs=7, seed=0)
    assert res.stop_reason == "max_epochs" and res.n_epochs == 7
    assert list(res.history.epoch) == list(range(8))  # epoch 0 is the initial population
    assert res.history.best_f.is_monotonic_decreasing
    res = heurtune.minimize(lambda X: np.ones(len(X)), LOWER, UPPER, "cs", tol=1e-6, tol_window=5, seed=0)
    assert res.stop_reason == "tolerance" and res.n_epochs == 5
    assert res.convergence_epoch == 0


def test_convergence_epoch_definition():
    from heurtune.core.engine import convergence_epoch

    best = [10.0, 5.0, 2.0, 1.0000001, 1.0, 1.0]
    assert convergence_epoch(best, 1e-6) == 3  # after epoch 3 it improves by 1e-7 relative only
    assert convergence_epoch(best, 1e-9) == 4


def test_wall_time_budget_stops_the_run():
    import time as _time

    def slow(X):
        _time.sleep(0.01)
        return sphere(X)

    res = heurtune.minimize(slow, LOWER, UPPER, "cs", max_time=0.1, seed=0, settings=dict(n=4))
    assert res.stop_reason == "max_time" and res.wall_time_s < 1.0 and res.n_epochs >= 1
