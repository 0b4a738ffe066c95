"""jSO: its update steps against the formulas of Brest, Maucec & Boskovic (2017) and runs on
standard functions."""

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.algorithms.jso import (
    JSO,
    cr_floor,
    current_to_pbest_w,
    f_cap,
    initial_population,
    jso_p,
    update_memory,
    weighted_f,
)
from heurtune.algorithms.lshade import TERMINAL, lehmer_mean


def test_initial_population_is_25_ln_d_sqrt_d():
    assert initial_population(10) == round(25 * np.log(10) * np.sqrt(10)) == 182
    assert initial_population(30) == 466
    assert initial_population(2) == 25  # round(25 * 0.693 * 1.414) = round(24.5)
    assert initial_population(1) == 4  # ln 1 = 0: the floor N_min


def test_schedules_of_cr_f_fw_and_p():
    cr = np.array([0.1, 0.65, 0.9])
    # floors and caps pick the value or the literal: no arithmetic
    assert_exact(cr_floor(cr, 0.0), [0.7, 0.7, 0.9])
    assert_exact(cr_floor(cr, 0.2499), [0.7, 0.7, 0.9])
    assert_exact(cr_floor(cr, 0.25), [0.6, 0.65, 0.9])
    assert_exact(cr_floor(cr, 0.5), cr)
    f = np.array([0.5, 0.8, 1.0])
    assert_exact(f_cap(f, 0.59), [0.5, 0.7, 0.7])
    assert_exact(f_cap(f, 0.6), f)
    # one numpy multiplication on each side, the same operands: one correctly rounded product
    assert_same_bits(weighted_f(f, 0.1), 0.7 * f, because="same code")
    assert_same_bits(weighted_f(f, 0.2), 0.8 * f, because="same code")
    assert_same_bits(weighted_f(f, 0.4), 1.2 * f, because="same code")
    # exact: 0.125 + 0.125 * {0, 1} involves only binary fractions
    assert jso_p(0.0) == 0.125 and jso_p(1.0) == 0.25 and jso_p(0.5) == pytest.approx(0.1875, rel=1e-15)
    assert jso_p(2.0) == 0.25  # past the budget: p_max


def test_weighted_mutation_follows_the_formula():
    X = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, -1.0], [2.0, 2.0]])
    F = np.array([0.5, 1.0, 0.2, 0.3])
    Fw = 0.7 * F
    pbest, r1 = np.array([3, 3, 1, 0]), np.array([1, 2, 3, 1])
    r2v = np.array([[1.0, 1.0], [0.0, 0.0], [3.0, -1.0], [5.0, 5.0]])
    V = current_to_pbest_w(X, F, Fw, pbest, r1, r2v)
    # the paper's formula as the same numpy operations in the same order (element-wise, each correctly rounded)
    assert_same_bits(V, X + Fw[:, None] * (X[pbest] - X) + F[:, None] * (X[r1] - r2v), because="same code")


def test_memory_is_the_mean_of_old_and_lehmer_mean():
    assert update_memory(0.8, 0.3, [], [], []) == (0.8, 0.3)  # exact: the old values handed back
    cr, f = update_memory(0.8, 0.3, [0.2, 0.8], [0.4, 0.9], [1.0, 3.0])
    assert cr == pytest.approx(0.5 * (lehmer_mean([0.2, 0.8], [1.0, 3.0]) + 0.8), rel=1e-15)
    assert f == pytest.approx(0.5 * (lehmer_mean([0.4, 0.9], [1.0, 3.0]) + 0.3), rel=1e-15)
    assert update_memory(0.8, 0.3, [0.0], [0.5], [1.0])[0] == TERMINAL  # exact: the sentinel -1.0
    assert update_memory(TERMINAL, 0.3, [0.4], [0.5], [1.0])[0] == TERMINAL


def test_memories_start_at_the_papers_values_and_the_last_slot_stays_fixed():
    from heurtune.algorithms.jso import JSOSettings
    from heurtune.core.engine import Comparator, SearchSpace

    space = SearchSpace(np.full(10, -100.0), np.full(10, 100.0))
    opt = JSO(space, JSOSettings(), np.random.default_rng(0), Comparator())
    assert opt.n_init == 182 and list(opt.m_f) == [0.3] * 4 + [0.9] and list(opt.m_cr) == [0.8] * 4 + [0.9]
    opt.set_budget(20000)
    X = opt.ask()
    opt.tell(X, np.sum(X * X, axis=1), np.zeros(len(X)))
    for _ in range(40):
        X = opt.ask()
        opt.tell(X, np.sum(X * X, axis=1), np.zeros(len(X)))
    # exact: the fixed slot keeps its literal
    assert opt.m_f[-1] == opt.m_cr[-1] == 0.9 and opt.k < 4 and not np.all(opt.m_f[:4] == 0.3)


def sphere(X):
    return np.sum(X * X, axis=1)


def rosenbrock(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


def test_sphere_and_rosenbrock_at_the_cec_budget():
    """10-D, [-100, 100]^10, 10,000 D evaluations (the CEC 2017 budget): the sphere below 1e-8
    and Rosenbrock below 1e-4 (CEC 2017's F1 and F4 are shifted and rotated versions, on which
    jSO's reported errors at D = 10 are 0)."""
    assert heurtune.minimize(sphere, [-100.0] * 10, [100.0] * 10, "jso", max_evals=100000, seed=3).f < 1e-8
    assert heurtune.minimize(rosenbrock, [-100.0] * 10, [100.0] * 10, "jso", max_evals=100000, seed=1).f < 1e-4


@pytest.mark.long  # 7 s on the EPYC: `make test` has the sphere and Rosenbrock at the CEC budget
def test_shifted_rotated_rastrigin_10d():
    """CEC 2017's F5 form, ``z = M (0.0512 (x - o))``, with a rotation and shift of our own (the
    competition's matrices are not here): the CEC 2017 entries of the SHADE family end a few
    units of error above the optimum at D = 10. Measured over seeds 0-7: jSO mean 2.2, L-SHADE
    2.7; the test asks for a mean below 4 over four seeds."""
    rng = np.random.default_rng(12345)
    rotation, _ = np.linalg.qr(rng.standard_normal((10, 10)))
    shift = rng.uniform(-80.0, 80.0, 10)

    def rastrigin(X):
        Z = (X - shift) @ rotation.T * 0.0512
        return 10.0 * Z.shape[1] + np.sum(Z * Z - 10.0 * np.cos(2 * np.pi * Z), axis=1)

    errors = [heurtune.minimize(rastrigin, [-100.0] * 10, [100.0] * 10, "jso", max_evals=100000, seed=s).f
              for s in range(4)]
    assert np.mean(errors) < 4.0
