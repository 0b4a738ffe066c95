"""Gradient-based optimisers: steepest descent, DFP, BFGS, Newton-Raphson (algorithms/_gradient.py).

Update formulas against the textbook, finite differences against exact derivatives, and each
method on a 4-D ill-conditioned quadratic and the 2-D Rosenbrock function from fixed starts.
Accuracies were measured first (default settings, ``start="center"``, seed 0):

* quadratic (condition 1000, f = 1216 at the start 0): f < 1e-10 after 97 evaluations (DFP,
  5 iterations), 113 (BFGS, 6), 75 (Newton-Raphson, 2; f = 1.5e-10 after the first, 38
  evaluations); steepest descent f = 2.8e-2 after 3000 and 3.0e-3 after 10000 evaluations.
* Rosenbrock from (-1.2, 1) (f = 24.2): f < 1e-10 after 409 evaluations (DFP), 337 (BFGS),
  267 (Newton-Raphson), |x - 1| ~ 4e-10 at 1000 (the floor set by the finite-difference
  gradient); steepest descent f = 0.19 after 3000 and 1.4e-2 after 10000 evaluations.
"""

import numpy as np
import pytest
from numerics import assert_close, assert_exact, assert_same_bits

import heurtune
from heurtune.algorithms._gradient import (
    bfgs_update,
    dfp_update,
    finite_difference_gradient,
    finite_difference_hessian,
    gradient_from_stencil,
    gradient_stencil,
    modify_eigenvalues,
)
from heurtune.core import registry

METHODS = ["steepest_descent", "dfp", "bfgs", "newton_raphson"]

# 4-D quadratic, condition number 1000, rotated axes; minimum c inside the box [-5, 5]^4
_Q = np.linalg.qr(np.random.default_rng(7).normal(size=(4, 4)))[0]
A = _Q @ np.diag([1.0, 10.0, 100.0, 1000.0]) @ _Q.T
C = np.array([0.5, -1.0, 1.5, 0.2])
QLO, QHI = np.full(4, -5.0), np.full(4, 5.0)  # centre 0: the fixed start


def quad(X):
    D = X - C
    return 0.5 * np.einsum("ni,ij,nj->n", D, A, D)


def rosen(X):
    return 100.0 * (X[:, 1] - X[:, 0] ** 2) ** 2 + (1.0 - X[:, 0]) ** 2


RLO, RHI = np.array([-4.4, -2.0]), np.array([2.0, 4.0])  # centre (-1.2, 1): the classic start


def random_spd(rng, d):
    M = rng.normal(size=(d, d))
    return M @ M.T + d * np.eye(d)


def secant_pair(rng, d):
    s = rng.normal(size=d)
    y = random_spd(rng, d) @ s  # s^T y > 0
    return s, y


# --------------------------------------------------------------------------------------------
# update formulas


@pytest.mark.parametrize("seed", range(5))
def test_bfgs_update_textbook_and_secant(seed):
    rng = np.random.default_rng(seed)
    d = 5
    H = np.linalg.inv(random_spd(rng, d))
    s, y = secant_pair(rng, d)
    Hn = bfgs_update(H, s, y)
    sy = s @ y
    # expanded form (Fletcher 1987, eq. 3.4.12)
    expanded = (H + (1 + y @ H @ y / sy) * np.outer(s, s) / sy
                - (np.outer(H @ y, s) + np.outer(s, H @ y)) / sy)
    np.testing.assert_allclose(Hn, expanded, rtol=1e-10, atol=1e-12)
    # its inverse is the direct BFGS update of B = H^-1
    B = np.linalg.inv(H)
    Bn = B - np.outer(B @ s, B @ s) / (s @ B @ s) + np.outer(y, y) / sy
    np.testing.assert_allclose(np.linalg.inv(Hn), Bn, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(Hn @ y, s, rtol=1e-10, atol=1e-12)  # secant condition
    assert np.all(np.linalg.eigvalsh(Hn) > 0)


@pytest.mark.parametrize("seed", range(5))
def test_dfp_update_textbook_and_secant(seed):
    rng = np.random.default_rng(seed)
    d = 5
    H = np.linalg.inv(random_spd(rng, d))
    s, y = secant_pair(rng, d)
    Hn = dfp_update(H, s, y)
    sy = s @ y
    # Davidon-Fletcher-Powell: H - H y y^T H / y^T H y + s s^T / s^T y
    np.testing.assert_allclose(Hn, H - np.outer(H @ y, y @ H) / (y @ H @ y) + np.outer(s, s) / sy,
                               rtol=1e-10, atol=1e-12)
    # its inverse is the direct DFP update of B = H^-1 (the dual of inverse BFGS)
    B = np.linalg.inv(H)
    V = np.eye(d) - np.outer(y, s) / sy
    np.testing.assert_allclose(np.linalg.inv(Hn), V @ B @ V.T + np.outer(y, y) / sy, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(Hn @ y, s, rtol=1e-10, atol=1e-12)  # secant condition
    assert np.all(np.linalg.eigvalsh(Hn) > 0)


def test_quasi_newton_update_is_skipped_without_curvature():
    opt = _make("bfgs", dim=3)
    H0 = opt.H.copy()
    opt.learn(np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]))  # s^T y < 0
    opt.learn(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))  # s^T y = 0
    assert_exact(opt.H, H0)  # both updates skipped: H untouched
    assert opt.n_skipped == 2 and opt.n_updates == 0
    opt.learn(np.array([1.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0]))
    assert opt.n_updates == 1 and opt.H[0, 0] == pytest.approx(0.5)


def test_eigenvalue_modification():
    rng = np.random.default_rng(1)
    B = random_spd(rng, 4)
    Q, lam = modify_eigenvalues(B, 1e-8)
    np.testing.assert_allclose(Q @ np.diag(lam) @ Q.T, B, rtol=1e-12, atol=1e-10)  # SPD untouched
    Q, lam = modify_eigenvalues(np.diag([3.0, -2.0, 0.0]), 1e-8)
    np.testing.assert_allclose(np.sort(lam), [3e-8, 2.0, 3.0])  # mirrored and floored


# --------------------------------------------------------------------------------------------
# finite differences


def _quad_affine(X):
    return quad(X) + X @ np.array([1.0, -2.0, 3.0, 0.5]) + 3.0


@pytest.mark.parametrize("x", [np.array([1.3, -2.2, 0.4, 4.1]),        # interior: central
                               np.array([-5.0, 5.0, 4.9999999, 0.0]),  # at / near bounds: one-sided
                               np.array([-5.0, -5.0, -5.0, -5.0])])
def test_fd_gradient_of_a_quadratic_is_exact(x):
    g = finite_difference_gradient(_quad_affine, x, QLO, QHI)
    exact = A @ (x - C) + np.array([1.0, -2.0, 3.0, 0.5])
    assert np.max(np.abs(g - exact)) <= 1e-8 * np.max(np.abs(exact))  # measured <= 5e-10


def test_fd_stencil_stays_in_the_box_and_is_second_order():
    x = np.array([-5.0, 5.0, 4.9999999, 0.0])
    P, a, b = gradient_stencil(x, QLO, QHI, 1e-6)
    assert np.all(P >= QLO) and np.all(P <= QHI)
    assert a[0] > 0 and b[0] > a[0]  # forward three-point at the lower bound
    assert a[1] < 0 and b[1] < a[1]  # backward at the upper bound
    assert a[3] == -b[3]  # central inside (exact: x[3] = 0, so the offsets are +h and -h unrounded)
    # a cubic along the stencil: the error is O(h^2), not O(h)
    f0, F = 1.0, np.empty(8)
    for i in range(4):
        F[2 * i] = 1.0 + 2 * a[i] + a[i] ** 3
        F[2 * i + 1] = 1.0 + 2 * b[i] + b[i] ** 3
    np.testing.assert_allclose(gradient_from_stencil(f0, F, a, b), 2.0, atol=1e-9)


def test_fd_gradient_survives_non_finite_neighbours():
    a, b = np.array([1e-3, 1e-3, 1e-3]), np.array([-1e-3, -1e-3, -1e-3])
    F = np.array([1.001, np.inf, np.nan, 0.999, np.inf, np.inf])
    g = gradient_from_stencil(1.0, F, a, b)
    np.testing.assert_allclose(g, [1.0, 1.0, 0.0])


@pytest.mark.parametrize("x", [np.array([1.3, -2.2, 0.4, 4.1]), np.array([-5.0, 5.0, 0.0, -5.0])])
def test_fd_hessian_of_a_quadratic(x):
    H = finite_difference_hessian(_quad_affine, x, QLO, QHI)
    np.testing.assert_allclose(H, H.T)
    assert np.max(np.abs(H - A)) <= 1e-5 * np.max(np.abs(A))  # measured <= 5e-7


# --------------------------------------------------------------------------------------------
# the optimisers


def _make(name, dim=4, **settings):
    from heurtune.core.engine import Comparator, SearchSpace

    info = registry.get(name)
    space = SearchSpace(np.full(dim, -1.0), np.full(dim, 1.0))
    return info.cls(space, registry.make_settings(name, settings), np.random.default_rng(0), Comparator())


# budget, accuracy on f (measured values in the module docstring)
QUAD_TARGETS = {"steepest_descent": (3000, 5e-2), "dfp": (400, 1e-10), "bfgs": (400, 1e-10),
                "newton_raphson": (400, 1e-10)}
ROSEN_TARGETS = {"steepest_descent": (10000, 5e-2), "dfp": (1000, 1e-10), "bfgs": (1000, 1e-10),
                 "newton_raphson": (1000, 1e-10)}


@pytest.mark.parametrize("name", METHODS)
def test_ill_conditioned_quadratic(name):
    budget, target = QUAD_TARGETS[name]
    res = heurtune.minimize(quad, QLO, QHI, name, max_evals=budget, settings=dict(start="center"))
    assert res.f < target
    if target <= 1e-10:
        np.testing.assert_allclose(res.x, C, atol=1e-4)


@pytest.mark.parametrize("name", METHODS)
def test_rosenbrock(name):
    budget, target = ROSEN_TARGETS[name]
    res = heurtune.minimize(rosen, RLO, RHI, name, max_evals=budget, settings=dict(start="center"))
    assert res.f < target
    if target <= 1e-10:
        np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-4)


def test_newton_raphson_solves_a_quadratic_in_two_iterations():
    res = heurtune.minimize(quad, QLO, QHI, "newton_raphson", max_epochs=3, settings=dict(start="center"))
    best = res.history.best_f.to_numpy()
    assert best[0] < 1e-9  # after the first iteration (epoch 0, 38 evaluations): measured 1.5e-10
    assert best[1] < 1e-20  # after the second: measured 0
    assert res.history.n_evals.iloc[0] == 1 + 8 + 21 + 8  # x0, gradient, Hessian, line search
    np.testing.assert_allclose(res.x, C, atol=1e-6)


@pytest.mark.parametrize("name", ["steepest_descent", "bfgs"])
def test_optimum_on_a_bound(name):
    # unconstrained minimiser (2, -3, 0.5) lies outside the box in two coordinates
    target = np.array([2.0, -3.0, 0.5])
    res = heurtune.minimize(lambda X: ((X - target) ** 2 * [1.0, 10.0, 100.0]).sum(axis=1),
                            [-1.0] * 3, [1.0] * 3, name, max_evals=600, seed=0)
    np.testing.assert_allclose(res.x, [1.0, -1.0, 0.5], atol=1e-5)


def test_batches_derivatives_then_line_search():
    sizes = []

    def rec(X):
        sizes.append(len(X))
        return quad(X)

    heurtune.minimize(rec, QLO, QHI, "bfgs", max_epochs=2, settings=dict(start="center"))
    assert sizes[:4] == [1 + 8, 8, 8, 8]  # start point + gradient, line search, gradient, ...
    sizes.clear()
    heurtune.minimize(rec, QLO, QHI, "newton_raphson", max_epochs=1, settings=dict(start="center"))
    assert sizes[:3] == [1 + 8 + 21, 8, 8 + 21]
    sizes.clear()
    heurtune.minimize(rec, QLO, QHI, "dfp", max_epochs=1,
                      settings=dict(start="center", line_search_points=5))
    assert sizes[:2] == [9, 5]


def test_restarts_use_the_budget_and_polishing_stays():
    res = heurtune.minimize(quad, QLO, QHI, "bfgs", max_evals=2000, seed=3)
    mean_f = res.history.mean_f.to_numpy()  # the current iterate: jumps up at each restart
    assert np.sum(np.diff(mean_f) > 1.0) >= 2 and res.n_evals == 2000 and res.f < 1e-10
    res = heurtune.minimize(quad, QLO, QHI, "bfgs", max_evals=2000, seed=3, settings=dict(restart=False))
    assert res.history.mean_f.is_monotonic_decreasing and res.n_evals == 2000 and res.f < 1e-10


def test_center_start_is_deterministic_until_the_first_restart():
    a = heurtune.minimize(rosen, RLO, RHI, "dfp", max_evals=200, seed=1, settings=dict(start="center"))
    b = heurtune.minimize(rosen, RLO, RHI, "dfp", max_evals=200, seed=2, settings=dict(start="center"))
    assert_same_bits(a.history.best_f, b.history.best_f, because="same code")  # the seed is not used yet


@pytest.mark.parametrize("name", METHODS)
def test_constraint_by_static_penalty(name):
    # min x0 + x1 s.t. x0 >= 0.5: the merit f + penalty*v is minimised, so the result is feasible
    fun = lambda X: (X[:, 0] + X[:, 1], (0.5 - X[:, 0])[:, None])  # noqa: E731
    res = heurtune.minimize(fun, [-1.0, -1.0], [1.0, 1.0], name, max_evals=600, seed=0,
                            constraint_handling="penalty")
    assert res.feasible
    np.testing.assert_allclose(res.x, [0.5, -1.0], atol=1e-3)


@pytest.mark.parametrize("bad, match", [
    (dict(start="middle"), "start must be one of"), (dict(fd_step=0.0), "fd_step"),
    (dict(line_search_points=0), "line_search_points"), (dict(step_ratio=1.0), "step_ratio"),
    (dict(armijo=1.5), "armijo"), (dict(max_step=-1.0), "max_step"), (dict(gtol=-1.0), "gtol"),
    (dict(extrapolation=8), "extrapolation"), (dict(line_search="exact"), "line_search must be one of"),
    (dict(xtol=-1.0), "xtol"),
])
def test_settings_are_validated(bad, match):
    for name in METHODS:
        with pytest.raises(heurtune.ConfigError, match=match):
            registry.make_settings(name, bad)


def test_newton_settings_are_validated():
    with pytest.raises(heurtune.ConfigError, match="hess_step"):
        registry.make_settings("newton_raphson", dict(hess_step=0.0))
    with pytest.raises(heurtune.ConfigError, match="eig_floor"):
        registry.make_settings("newton_raphson", dict(eig_floor=2.0))
    with pytest.raises(heurtune.ConfigError, match="unknown setting 'hess_step'"):
        registry.make_settings("bfgs", dict(hess_step=1e-4))


# --------------------------------------------------------------------------------------------
# line_search="unit": the thesis' alpha_k = 1 (chapter 6)

# Small quadratic for hand computations: box [0, 2] x [-1, 3] (widths 2, 4), curvature in box
# units diag(w) A2 diag(w) = [[0.8, 0.4], [0.4, 1.6]], minimum C2 inside; the start is the
# centre (1, 1). Every iterate computed below stays inside the box (no projection).
A2 = np.array([[0.2, 0.05], [0.05, 0.1]])
C2 = np.array([1.3, 0.2])
LO2, HI2 = np.array([0.0, -1.0]), np.array([2.0, 3.0])
W2 = HI2 - LO2


def quad2(X):
    D = X - C2
    return 0.5 * np.einsum("ni,ij,nj->n", D, A2, D)


def _recorded(fun):
    batches = []

    def rec(X):
        batches.append(np.array(X, copy=True))
        return fun(X)

    return rec, batches


def _hand_quasi_newton(update):
    """x1, x2 of a unit-step quasi-Newton method on quad2, by hand in box units u = (x - lo)/w."""
    x0 = 0.5 * (LO2 + HI2)
    gu = lambda x: W2 * (A2 @ (x - C2))  # noqa: E731 - exact gradient in box units
    H = np.eye(2)
    x1 = x0 + W2 * (-H @ gu(x0))
    s, y = (x1 - x0) / W2, gu(x1) - gu(x0)
    rho = 1.0 / (s @ y)
    if update == "bfgs":  # H+ = (I - rho s y') H (I - rho y s') + rho s s'
        V = np.eye(2) - rho * np.outer(s, y)
        H = V @ H @ V.T + rho * np.outer(s, s)
    else:  # DFP: H+ = H - H y y' H / (y' H y) + s s' / (s' y)
        H = H - np.outer(H @ y, H @ y) / (y @ H @ y) + rho * np.outer(s, s)
    x2 = x1 + W2 * (-H @ gu(x1))
    return x1, x2


@pytest.mark.parametrize("name", ["bfgs", "dfp"])
def test_unit_step_quasi_newton_iterates_match_a_hand_computation(name):
    rec, batches = _recorded(quad2)
    heurtune.minimize(rec, LO2, HI2, name, max_epochs=1, settings=dict(start="center", line_search="unit"))
    assert [len(b) for b in batches[:4]] == [1 + 4, 1, 4, 1]
    x1, x2 = _hand_quasi_newton(name)
    assert np.all((x1 > LO2) & (x1 < HI2) & (x2 > LO2) & (x2 < HI2))  # no projection involved
    # the finite-difference gradient is exact for a quadratic up to rounding (~1e-10 here)
    np.testing.assert_allclose(batches[1][0], x1, rtol=0, atol=1e-8)
    np.testing.assert_allclose(batches[3][0], x2, rtol=0, atol=1e-8)
    # pinned values of the hand computation (guards the test itself)
    np.testing.assert_allclose(x1, [1.08, -0.04], atol=1e-12)
    pinned_x2 = {"bfgs": [1.2427225204294183, 0.22061989264540927],
                 "dfp": [1.2228987145596595, 0.22775646275852252]}
    np.testing.assert_allclose(x2, pinned_x2[name], rtol=1e-12)


def test_unit_step_bfgs_and_dfp_differ_only_by_the_update():
    (b1, b2), (d1, d2) = _hand_quasi_newton("bfgs"), _hand_quasi_newton("dfp")
    assert_same_bits(b1, d1, because="same code")  # same first step (H0 = I), computed before the update
    assert np.max(np.abs(b2 - d2)) > 1e-3  # different second step


def test_unit_step_newton_raphson_solves_a_quadratic_in_one_iteration():
    rec, batches = _recorded(quad)
    res = heurtune.minimize(rec, QLO, QHI, "newton_raphson", max_epochs=0,
                            settings=dict(start="center", line_search="unit"))
    assert [len(b) for b in batches] == [1 + 8 + 21, 1]  # x0 + gradient + Hessian, one trial
    # the full Newton step lands on C up to the finite-difference Hessian's error (entries within
    # 5e-7 relative, condition 1000): measured |x1 - C| = 1.2e-5, f(x1) = 1.5e-10
    np.testing.assert_allclose(batches[1][0], C, atol=5e-5)
    assert res.f < 1e-9 and res.n_evals == 31
    # well conditioned (quad2): measured |x1 - C2| < 1e-9
    rec, batches = _recorded(quad2)
    heurtune.minimize(rec, LO2, HI2, "newton_raphson", max_epochs=0, settings=dict(start="center", line_search="unit"))
    np.testing.assert_allclose(batches[1][0], C2, atol=1e-8)


@pytest.mark.parametrize("name, per_iteration", [("steepest_descent", 2 * 4 + 1), ("dfp", 2 * 4 + 1),
                                                 ("bfgs", 2 * 4 + 1),
                                                 ("newton_raphson", 2 * 4 + 4 ** 2 + 4 + 1 + 1)])
def test_unit_step_evaluations_per_iteration(name, per_iteration):
    # iteration = one derivative batch + one trial; the start point adds one evaluation
    rec, batches = _recorded(quad)
    res = heurtune.minimize(rec, QLO, QHI, name, max_epochs=5,  # gtol = 0: no convergence, no restart
                            settings=dict(start="center", line_search="unit", gtol=0.0))
    sizes = [len(b) for b in batches]
    assert sizes[1::2] == [1] * 6
    assert res.n_evals == 1 + 6 * per_iteration


def test_unit_steepest_descent_is_the_full_gradient_step_in_box_units():
    rec, batches = _recorded(quad2)
    heurtune.minimize(rec, LO2, HI2, "steepest_descent", max_epochs=1,
                      settings=dict(start="center", line_search="unit"))
    x0 = 0.5 * (LO2 + HI2)
    x1 = x0 - W2 * (W2 * (A2 @ (x0 - C2)))  # u1 = u0 - grad_u f(u0)
    np.testing.assert_allclose(batches[1][0], x1, atol=1e-8)
    np.testing.assert_allclose(batches[1][0], _hand_quasi_newton("bfgs")[0], atol=1e-8)  # = QN with H0 = I


def test_unit_steepest_descent_converges_when_the_box_curvature_is_below_two():
    # curvature in box units has eigenvalues 0.63 and 1.77 < 2: the fixed step contracts
    res = heurtune.minimize(quad2, LO2, HI2, "steepest_descent", max_evals=2000,
                            settings=dict(start="center", line_search="unit", restart=False))
    assert res.f < 1e-14
    np.testing.assert_allclose(res.x, C2, atol=1e-6)


def test_unit_steps_are_taken_even_uphill_and_the_best_is_kept():
    # box [-5, 5]^4 of quad: curvature up to 1000 * 100 in box units, so the unit steepest-descent
    # step overshoots and the current merit rises; the engine keeps the best-so-far
    res = heurtune.minimize(quad, QLO, QHI, "steepest_descent", max_epochs=4,
                            settings=dict(start="center", line_search="unit", restart=False))
    mean_f = res.history.mean_f.to_numpy()  # the current iterate
    assert mean_f[0] > quad(np.zeros((1, 4)))[0]  # first step went uphill
    best = res.history.best_f.to_numpy()  # best of all evaluations (start and stencils)
    assert np.all(np.diff(best) <= 0) and best[-1] <= quad(np.zeros((1, 4)))[0]
    assert np.all(mean_f > best)


def _drive(opt, fun, n_batches):
    sizes = []
    for _ in range(n_batches):
        X = opt.ask()
        sizes.append(len(X))
        f = fun(X)
        opt.tell(X, f, np.zeros(len(X)))
    return sizes


def test_unit_step_xtol_counts_as_converged_and_restarts():
    # Newton lands on C after one iteration; the second unit step moves < xtol: restart
    opt = _make("newton_raphson", line_search="unit", xtol=1e-6, start="center")
    opt.space.lower[:], opt.space.upper[:] = -1.0, 1.0
    target = np.array([0.3, -0.2, 0.1, 0.5])
    fun = lambda X: ((X - target) ** 2 * [1.0, 2.0, 3.0, 4.0]).sum(axis=1)  # noqa: E731
    _drive(opt, fun, 4)  # derivatives + trial (lands on target), derivatives + trial (tiny)
    assert opt.n_restarts == 1
    opt = _make("newton_raphson", line_search="unit", start="center")  # xtol = 0: off
    _drive(opt, fun, 4)
    assert opt.n_restarts == 0


def test_unit_step_with_non_finite_merit_falls_back_then_restarts():
    # the Newton step from the centre lands where f is inf; the unit steepest-descent step
    # too: the method restarts (restart=True) from a random point
    opt = _make("newton_raphson", dim=2, line_search="unit", start="center")
    fun = lambda X: np.where(np.abs(X[:, 0]) > 0.5, np.inf, ((X - 0.9) ** 2).sum(axis=1))  # noqa: E731
    sizes = _drive(opt, fun, 3)
    assert sizes == [1 + 4 + 7, 1, 1] and opt.n_restarts == 1


@pytest.mark.parametrize("name", METHODS)
def test_default_settings_are_unchanged(name):
    """The defaults are the Armijo line search without an xtol, as before those settings were
    added: the two runs are equal bit for bit (the same seed). The values pinned then (seed 5,
    300 evaluations, random start) are one CPU's path: OpenBLAS picks its kernels by CPU, the
    quasi-Newton updates' products round with them, and an iteration then takes another path (an
    AVX2 AMD EPYC gives DFP f = 3.2e-6 instead of 0.085, and yet another run with
    ``OPENBLAS_CORETYPE=Sandybridge``). So they are not compared: on every CPU the runs that had
    converged must converge to the same minimum, and the others must improve on the start a hundredfold."""
    pinned = {
        "steepest_descent": (0.2924673368576982, [1.5406947331964878, 2.3748198087273185]),
        "dfp": (0.08530144813946423, [1.2919623584630935, 1.6683958311510119]),
        "bfgs": (3.947847863603137e-20, [0.9999999998013367, 0.9999999996030106]),
        "newton_raphson": (3.9965731785391925e-20, [0.9999999998000857, 0.9999999996001675]),
    }
    res = heurtune.minimize(rosen, RLO, RHI, name, max_evals=300, seed=5)
    explicit = heurtune.minimize(rosen, RLO, RHI, name, max_evals=300, seed=5,
                                 settings=dict(line_search="armijo", xtol=0.0))
    assert res.n_evals == explicit.n_evals == 300
    assert_same_bits(explicit.f, res.f, because="same seed")
    assert_same_bits(explicit.x, res.x, because="same seed")
    f, x = pinned[name]
    if f < 1e-15:  # converged (Rosenbrock's minimum is f = 0 at x = (1, 1))
        assert res.f < 1e-15
        assert_close(res.x, x, rtol=0.0, atol=1e-8,
                     because="both within the finite-difference gradient's floor (|x - 1| ~ 4e-10) of (1, 1)")
    else:  # at least a hundredfold better than the start (f = 520.9 there)
        start = heurtune.minimize(rosen, RLO, RHI, name, max_evals=1, seed=5)
        assert start.n_evals == 1 and res.f < 0.01 * start.f
