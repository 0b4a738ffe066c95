"""Contract tests over every registered optimiser (and a toy plugin defined here).

Every optimiser, merely by being registered, must pass the checks of heurtune.core.contract:
keep its evaluations inside the bounds, survive NaN and inf objective values, give the same
history for the same seed (even after the global NumPy RNG is disturbed) and different
histories for different seeds, spend a budget of evaluations exactly, respect a constraint,
and give the same history on one and two workers.
"""

import dataclasses
import importlib.util

import numpy as np
import pytest

import heurtune
from heurtune.core import registry
from heurtune.core.contract import CHECKS, LOWER, UPPER, run_checks, sphere
from heurtune.core.engine import Optimizer
from heurtune.core.plugins import load_plugin


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


# Bridged optimisers of optional libraries (the test extra installs nevergrad and pymoo): the
# names each bridge declares checked (ng:NGOpt is not, and its module says why).
BRIDGE_LIBRARY = {"ng": "nevergrad", "pymoo": "pymoo"}
NAMES = [n for n in registry.available() if ":" not in n] + [
    n for n in registry.bridge_checked() if importlib.util.find_spec(BRIDGE_LIBRARY[n.split(":")[0]]) is not None]


@pytest.mark.parametrize("check", sorted(CHECKS))
@pytest.mark.parametrize("name", NAMES)
def test_contract(name, check):
    """heurtune.core.contract's checks (bounds, NaN/inf, seeds, exact budgets, constraints, one
    and two workers) on every registered optimiser."""
    CHECKS[check](name, budgets(name))


def test_a_broken_optimiser_fails_the_checks():
    @registry.register("toy_broken", settings=ToySettings, description="test plugin breaking the contract")
    class Broken(ToyRandomSearch):
        def ask(self):
            return np.random.default_rng().uniform(-10, 10, (self.settings.n, self.space.dim))  # unseeded

    failed = {check for check, ok, _ in run_checks("toy_broken") if not ok}
    assert {"seeds", "workers"} <= failed and "budget" not in failed


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
