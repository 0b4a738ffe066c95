"""L-SHADE: its update steps against the paper's formulas (Tanabe & Fukunaga 2014) and runs on
standard functions."""

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.algorithms.lshade import (
    TERMINAL,
    binomial_crossover,
    current_to_pbest,
    halfway_repair,
    lehmer_mean,
    population_size,
    sample_cr,
    sample_f,
    update_memory,
)


def test_cr_is_normal_around_its_memory_clipped_and_zero_for_a_terminal_slot():
    rng = np.random.default_rng(1)
    m = np.full(20000, 0.5)
    m[:100] = TERMINAL
    cr = sample_cr(m, rng)
    assert np.all(cr[:100] == 0.0)  # exact: a terminal slot gives the literal 0
    assert np.all((cr >= 0) & (cr <= 1))
    assert abs(cr[100:].mean() - 0.5) < 0.005 and abs(cr[100:].std() - 0.1) < 0.005
    edge = sample_cr(np.full(20000, 0.98), rng)
    assert edge.max() == 1.0  # clipped, not redrawn (exact: the bound)


def test_f_is_cauchy_around_its_memory_redrawn_below_zero_and_cut_at_one():
    """Cauchy(0.5, 0.1): P(F <= 0) = P(F > 1) = 1/2 - atan(5)/pi = 0.0628. Redrawing the first
    makes P(F = 1) = 0.0628 / (1 - 0.0628) = 0.0670 and the median the point where the Cauchy
    distribution function is 0.0628 + (1 - 0.0628) / 2, i.e. 0.5 + 0.1 tan(pi (0.0314)) = 0.5099."""
    rng = np.random.default_rng(2)
    f = sample_f(np.full(40000, 0.5), rng)
    assert np.all((f > 0) & (f <= 1))
    tail = 0.5 - np.arctan(5.0) / np.pi
    assert abs(np.mean(f == 1.0) - tail / (1 - tail)) < 0.004  # exact: draws above 1 are cut to the literal
    median = 0.5 + 0.1 * np.tan(np.pi * (tail + (1 - tail) / 2 - 0.5))
    assert abs(np.median(f) - median) < 0.005


def test_current_to_pbest_and_crossover_and_repair_follow_the_formulas():
    X = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, -1.0], [2.0, 2.0]])
    F = np.array([0.5, 1.0, 0.2, 0.0])
    pbest = np.array([3, 3, 1, 0])
    r1 = np.array([1, 2, 3, 1])
    r2v = np.array([[1.0, 1.0], [0.0, 0.0], [3.0, -1.0], [5.0, 5.0]])
    V = current_to_pbest(X, F, pbest, r1, r2v)
    expected = X + F[:, None] * (X[pbest] - X) + F[:, None] * (X[r1] - r2v)
    # the same numpy operations in the same order (element-wise, each correctly rounded)
    assert_same_bits(V, expected, because="same code")
    U = binomial_crossover(X, V, CR=np.array([0.0, 1.0, 0.5, 0.0]), j_rand=np.array([1, 0, 0, 1]),
                           uniform=np.array([[0.9, 0.9], [0.9, 0.9], [0.4, 0.6], [0.1, 0.1]]))
    assert_exact(U, [[X[0, 0], V[0, 1]], V[1], [V[2, 0], X[2, 1]], [X[3, 0], V[3, 1]]])  # picked, not computed
    lower, upper = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    R = halfway_repair(np.array([[-3.0, 0.5], [2.0, -1.5]]), np.array([[0.0, 0.0], [0.5, 0.0]]), lower, upper)
    assert_exact(R, [[-0.5, 0.5], [0.75, -0.5]])  # halves of sums of binary fractions: no rounding


def test_memory_is_the_weighted_lehmer_mean_with_its_terminal_rule():
    # weights 1 and 3 -> 0.25, 0.75: (0.25 * 0.04 + 0.75 * 0.64) / (0.25 * 0.2 + 0.75 * 0.8)
    assert lehmer_mean([0.2, 0.8], [1.0, 3.0]) == pytest.approx(0.49 / 0.65, rel=1e-15)
    assert update_memory(0.5, 0.5, [], [], []) == (0.5, 0.5)  # exact: the old values handed back
    cr, f = update_memory(0.5, 0.5, [0.2, 0.8], [0.4, 0.9], [1.0, 3.0])
    assert cr == pytest.approx(0.49 / 0.65) and f == pytest.approx(
        (0.25 * 0.16 + 0.75 * 0.81) / (0.25 * 0.4 + 0.75 * 0.9)
    )
    assert update_memory(0.5, 0.5, [0.0, 0.0], [0.4, 0.9], [1.0, 1.0])[0] == TERMINAL  # max S_CR = 0 (exact: sentinel)
    assert update_memory(TERMINAL, 0.5, [0.3], [0.4], [1.0])[0] == TERMINAL  # terminal stays terminal


def test_linear_population_size_reduction():
    assert population_size(0, 10000, 180, 4) == 180
    assert population_size(10000, 10000, 180, 4) == 4
    assert population_size(5000, 10000, 180, 4) == 92  # round(180 - 176 / 2)
    assert population_size(123, 0, 180, 4) == 180  # no budget, no reduction


def sphere(X):
    return np.sum(X * X, axis=1)


def rosenbrock(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


def test_a_budgeted_run_shrinks_to_n_min_and_solves_the_sphere():
    """10-D sphere on [-100, 100]^10 (CEC 2014's box): below 1e-8 within 30,000 evaluations; the
    last generation has N_min = 4 members."""
    res = heurtune.minimize(sphere, [-100.0] * 10, [100.0] * 10, "lshade", max_evals=30000, seed=3)
    assert res.f < 1e-8 and res.n_evals == 30000


def test_rosenbrock_10d():
    """10-D Rosenbrock on [-100, 100]^10 with CEC 2014's budget of 10,000 D evaluations (the
    budget of the competition L-SHADE won): below 1e-4 (unshifted and unrotated here; the
    competition's shifted, rotated F4 is not reproduced)."""
    res = heurtune.minimize(rosenbrock, [-100.0] * 10, [100.0] * 10, "lshade", max_evals=100000, seed=1)
    assert res.f < 1e-4
