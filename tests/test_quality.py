"""Quality of every optimiser on standard problems, within the budgets of docs/quality.md.

Thresholds are three times the worst error measured over seeds 0-4 by
``benchmarks/quality.py`` (floor 1e-8); the test runs seed 0 with default settings, so a change
that degrades an optimiser fails here. The measured table is in docs/quality.md.
"""

import pytest

import heurtune
from heurtune.core.testfunctions import BUDGETS, PROBLEMS

# every optimiser on every standard problem at its full budget: `make test-long` (docs/testing.md, "Two tiers")
pytestmark = pytest.mark.long

THRESHOLD = {
    ("apso", "ackley"): 3.48,
    ("apso", "pressure_vessel"): 1.69e+03,
    ("apso", "rastrigin"): 74.7,
    ("apso", "rosenbrock"): 255,
    ("apso", "sphere"): 1e-08,
    ("bfgs", "ackley"): 10.2,
    ("bfgs", "pressure_vessel"): 4.26e+03,
    ("bfgs", "rastrigin"): 107,
    ("bfgs", "rosenbrock"): 0.000151,
    ("bfgs", "sphere"): 1e-08,
    ("cmaes", "ackley"): 1e-08,
    ("cmaes", "pressure_vessel"): 1.41,
    ("cmaes", "rastrigin"): 6.93,
    ("cmaes", "rosenbrock"): 1e-08,
    ("cmaes", "sphere"): 1e-08,
    ("cs", "ackley"): 0.0606,
    ("cs", "pressure_vessel"): 160,
    ("cs", "rastrigin"): 24.3,
    ("cs", "rosenbrock"): 1.86,
    ("cs", "sphere"): 0.0172,
    ("dfp", "ackley"): 9.66,
    ("dfp", "pressure_vessel"): 1.58e+03,
    ("dfp", "rastrigin"): 107,
    ("dfp", "rosenbrock"): 0.000378,
    ("dfp", "sphere"): 1e-08,
    ("firefly", "ackley"): 1.23e-07,
    ("firefly", "pressure_vessel"): 2.24e+04,
    ("firefly", "rastrigin"): 41.7,
    ("firefly", "rosenbrock"): 246,
    ("firefly", "sphere"): 2.67e-07,
    ("ga", "ackley"): 0.0148,
    ("ga", "pressure_vessel"): 1.4e+03,
    ("ga", "rastrigin"): 0.00125,
    ("ga", "rosenbrock"): 18.8,
    ("ga", "sphere"): 0.00118,
    ("jso", "ackley"): 1e-08,
    ("jso", "pressure_vessel"): 0.000221,
    ("jso", "rastrigin"): 1e-08,
    ("jso", "rosenbrock"): 1e-08,
    ("jso", "sphere"): 1e-08,
    ("lshade", "ackley"): 1e-08,
    ("lshade", "pressure_vessel"): 0.000221,
    ("lshade", "rastrigin"): 1e-08,
    ("lshade", "rosenbrock"): 1e-08,
    ("lshade", "sphere"): 1.82e-08,
    ("newton_raphson", "ackley"): 14.6,
    ("newton_raphson", "pressure_vessel"): 3.33e+03,
    ("newton_raphson", "rastrigin"): 131,
    ("newton_raphson", "rosenbrock"): 1e-08,
    ("newton_raphson", "sphere"): 1e-08,
    ("pso", "ackley"): 1e-08,
    ("pso", "pressure_vessel"): 1.2e+03,
    ("pso", "rastrigin"): 69.9,
    ("pso", "rosenbrock"): 16.3,
    ("pso", "sphere"): 1e-08,
    ("sqp_multistart", "ackley"): 6.96,
    ("sqp_multistart", "pressure_vessel"): 0.000549,
    ("sqp_multistart", "rastrigin"): 68.7,
    ("sqp_multistart", "rosenbrock"): 3.66e-08,
    ("sqp_multistart", "sphere"): 1e-08,
    ("steepest_descent", "ackley"): 11.2,
    ("steepest_descent", "pressure_vessel"): 3.81e+04,
    ("steepest_descent", "rastrigin"): 116,
    ("steepest_descent", "rosenbrock"): 248,
    ("steepest_descent", "sphere"): 1e-08,
}


@pytest.mark.parametrize("name, problem", sorted(THRESHOLD))
def test_reaches_the_stated_accuracy(name, problem):
    fun, lo, hi, f_opt = PROBLEMS[problem]
    res = heurtune.minimize(fun, lo, hi, name, max_evals=BUDGETS[problem], seed=0)
    assert res.n_evals == BUDGETS[problem]
    assert res.feasible
    assert res.f - f_opt <= THRESHOLD[(name, problem)]
