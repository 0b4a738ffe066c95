"""Clear outcomes of the Python API where a run cannot succeed: an objective that is NaN
everywhere, a zero budget, a negative seed, a candidate that cannot be designed."""

import numpy as np
import pytest
from numerics import assert_same_bits

import heurtune
from heurtune.core import registry
from heurtune.core.errors import ConfigError, DesignError

SINGLE = [n for n in registry.available() if not registry.get(n).multi_objective
          and n not in ("newton_raphson", "dfp", "steepest_descent", "bfgs")]


@pytest.mark.parametrize("name", SINGLE)
def test_an_objective_that_is_nan_everywhere_ends_failed(name):
    res = heurtune.minimize(lambda X: np.full(len(X), np.nan), [0.0, 0.0], [1.0, 1.0], name, max_evals=60, seed=1)
    assert res.status == "failed" and not res.feasible and res.f == np.inf  # exact: the literal inf


@pytest.mark.parametrize("name", ["newton_raphson", "bfgs"])
def test_gradient_methods_on_a_nan_objective_end_failed(name):
    res = heurtune.minimize(lambda X: np.full(len(X), np.nan), [0.0, 0.0], [1.0, 1.0], name, max_evals=60, seed=1)
    assert res.status == "failed" and not res.feasible


def test_a_good_run_is_feasible():
    res = heurtune.minimize(lambda X: (X ** 2).sum(axis=1), [-1.0, -1.0], [1.0, 1.0], "cs", max_evals=100, seed=1)
    assert res.status == "feasible" and res.feasible


@pytest.mark.parametrize("kwargs, message", [
    (dict(max_evals=0), "max_evals must be an integer >= 1, got 0"),
    (dict(max_epochs=-1), "max_epochs must be an integer >= 0, got -1"),
    (dict(seed=-1), "seed must be an integer >= 0 or a numpy SeedSequence, got -1"),
    (dict(seed=1.5), "seed must be an integer >= 0"),
])
def test_budgets_and_seeds_are_checked(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        heurtune.minimize(lambda X: X.sum(axis=1), [0.0, 0.0], [1.0, 1.0], "cs", **kwargs)


def test_simulate_raises_the_reason_evaluate_reports():
    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    x = (prob.lower + prob.upper) / 2
    x[0] = np.nan
    assert prob.evaluate(x[None, :]).reason[0] == "invalid_parameter"
    with pytest.raises(DesignError) as info:
        prob.simulate(x)
    assert info.value.reason == "invalid_parameter"


def test_result_carries_the_final_population():
    """``Result.population``: a population optimiser's last population (the objective it selects
    on: one column, or one per objective); None for a driver."""
    import heurtune

    def sphere(X):
        return np.sum(X * X, axis=1)

    def two(X):
        return np.column_stack([X[:, 0], 1.0 - np.sqrt(np.clip(X[:, 0], 0, 1)) + X[:, 1:].sum(axis=1)])

    res = heurtune.minimize(sphere, [-5.0] * 3, [5.0] * 3, "cs", max_evals=500, seed=1)
    pop = res.population
    assert pop["X"].shape == (25, 3) and pop["f"].shape == (25,) and pop["v"].shape == (25,)
    # the values belong to the points: sphere again on the stored rows (a row's value is its own, whatever
    # batch it was evaluated in)
    assert_same_bits(pop["f"], sphere(pop["X"]), because="same code")
    assert pop["f"].min() >= res.f and np.all((pop["X"] >= -5) & (pop["X"] <= 5))
    mo = heurtune.minimize(two, [0.0] * 4, [1.0] * 4, "nsga2", max_evals=800, seed=2, reference_point=[1.1, 5.0])
    assert mo.population["f"].shape == (len(mo.population["X"]), 2) and mo.front["F"].shape[1] == 2
    assert heurtune.minimize(sphere, [-5.0] * 3, [5.0] * 3, "sqp_multistart", max_evals=300, seed=1).population is None
