"""APSO, firefly and constriction PSO: update steps against hand-written reference formulas,
characteristic behaviour, and solution quality on a shifted sphere."""

import copy

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.core import registry
from heurtune.core.engine import Comparator, SearchSpace

registry.load_algorithms()
from heurtune.algorithms import apso, firefly, pso  # noqa: E402


def make(name, lower, upper, seed=0, mode="deb", **settings):
    info = registry.get(name)
    space = SearchSpace(np.asarray(lower, float), np.asarray(upper, float))
    return info.cls(space, registry.make_settings(name, settings), np.random.default_rng(seed), Comparator(mode))


def step(opt, fun):
    """One ask/evaluate/tell round as the engine does it (unconstrained)."""
    X = opt.space.repair(opt.ask())
    f = fun(X)
    return X, f, opt.tell(X, f, np.zeros(len(X)))


def shifted_sphere(X):
    return ((X - 1.3) ** 2).sum(axis=1)


def rastrigin(X):
    return (X ** 2 - 10 * np.cos(2 * np.pi * X) + 10).sum(axis=1)


# ---------------------------------------------------------------- APSO


def test_apso_move_matches_reference_formula():
    X = np.array([[0.5, -1.0], [2.0, 0.25], [-3.0, 1.5]])
    g = np.array([1.0, 0.5])
    z = np.array([[0.3, -1.2], [0.0, 2.0], [-0.7, 0.1]])
    width = np.array([10.0, 4.0])
    alpha, beta = 0.19, 0.5
    expected = np.empty_like(X)
    for i in range(3):
        for k in range(2):
            expected[i, k] = X[i, k] + beta * (g[k] - X[i, k]) + alpha * z[i, k] * width[k]
    np.testing.assert_allclose(apso.apso_move(X, g, z, alpha, beta, width), expected, rtol=0, atol=1e-15)


def test_apso_ask_uses_decayed_alpha_and_best_so_far():
    opt = make("apso", [-5, -2], [5, 2], seed=3, n=3)
    X0, f0, done = step(opt, shifted_sphere)
    assert done and X0.shape == (3, 2)
    twin = copy.deepcopy(opt.rng)
    proposal = opt.ask()
    z = twin.normal(size=(3, 2))
    g = X0[np.argmin(f0)]
    alpha = 0.2 * 0.95  # decay happens before the first move
    expected = X0 + 0.5 * (g - X0) + alpha * z * np.array([10.0, 4.0])
    np.testing.assert_allclose(proposal, expected, rtol=0, atol=1e-14)


def test_apso_alpha_decays_geometrically_and_best_never_worsens():
    opt = make("apso", [-5] * 3, [5] * 3, seed=1, n=5, alpha0=0.3, gamma=0.9)
    step(opt, rastrigin)
    seen_best = opt.g_f
    for k in range(1, 15):
        X, f, _ = step(opt, rastrigin)
        assert opt.alpha == pytest.approx(0.3 * 0.9 ** k, rel=1e-12)
        assert opt.g_f <= seen_best and opt.g_f == min(seen_best, f.min())  # exact: g_f is a told value, copied
        seen_best = opt.g_f
        assert_exact(opt.X, X)  # no greedy selection: the swarm is the moved one (a copy)


# ---------------------------------------------------------------- firefly


def reference_firefly_move(Xs, fs, U, alpha, beta0, beta_min, gamma, scale):
    """Yang's double loop, written out scalar by scalar (snapshot distances)."""
    n, d = Xs.shape
    out = Xs.copy()
    for i in range(n):
        x = [float(c) for c in Xs[i]]
        for j in range(n):
            if fs[j] < fs[i]:
                r2 = sum((x[k] - Xs[j, k]) ** 2 for k in range(d))
                beta = (beta0 - beta_min) * np.exp(-gamma * r2) + beta_min
                x = [x[k] * (1 - beta) + Xs[j, k] * beta + alpha * (U[i, j, k] - 0.5) * scale[k]
                     for k in range(d)]
        out[i] = x
    return out


def test_move_fireflies_matches_reference_loop():
    rng = np.random.default_rng(11)
    Xs = np.array([[0.1, 0.2], [1.0, -0.5], [-0.8, 0.9]])
    fs = np.array([0.5, 1.0, 1.0])  # sorted best-first, with a tie (the tie does not attract)
    U = rng.random((3, 3, 2))
    scale = np.array([4.0, 2.0])
    args = (0.25, 0.9, 0.2, 1.3, scale)
    brighter = fs[None, :] < fs[:, None]
    got = firefly.move_fireflies(Xs, brighter, U, *args)
    np.testing.assert_allclose(got, reference_firefly_move(Xs, fs, U, *args), rtol=0, atol=1e-14)
    assert_exact(got[0], Xs[0])  # nothing is brighter than the best: its row is copied


def test_firefly_ask_sorts_decays_and_moves():
    opt = make("firefly", [-1, -3], [3, 1], seed=5, n=3, alpha=0.4, beta0=0.8, max_generations=10)
    X0, f0, done = step(opt, shifted_sphere)
    assert done
    twin = copy.deepcopy(opt.rng)
    proposal = opt.ask()
    U = twin.random((3, 3, 2))
    order = np.argsort(f0)
    delta = 1 - (1e-4 / 0.9) ** (1 / 10)
    expected = reference_firefly_move(X0[order], f0[order], U, 0.4 * (1 - delta), 0.8, 0.2, 1.0,
                                      np.array([4.0, 4.0]))
    np.testing.assert_allclose(proposal, expected, rtol=0, atol=1e-14)


def test_firefly_moves_only_towards_brighter_ones():
    Xs = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 3.0]])
    half = np.full((3, 3, 2), 0.5)  # draws at 0.5: the random term vanishes
    brighter = np.array([[False, False, False], [True, False, False], [False, False, False]])
    got = firefly.move_fireflies(Xs, brighter, half, 0.3, 0.3, 0.2, 1.0, np.array([10.0, 10.0]))
    assert_exact(got[[0, 2]], Xs[[0, 2]])  # no brighter neighbour: no move (copied)
    beta = 0.1 * np.exp(-4.0) + 0.2
    np.testing.assert_allclose(got[1], [2.0 * (1 - beta), 0.0])  # straight towards firefly 0
    # random draws alone move nobody who has no brighter neighbour
    noisy = np.random.default_rng(0).random((3, 3, 2))
    none = np.zeros((3, 3), dtype=bool)
    assert_exact(firefly.move_fireflies(Xs, none, noisy, 0.3, 0.3, 0.2, 1.0, 10.0), Xs)


def test_firefly_best_stays_put_and_alpha_reaches_yang_floor():
    opt = make("firefly", [-5] * 3, [5] * 3, seed=2, n=8, max_generations=20)
    step(opt, rastrigin)
    for _ in range(20):
        best_x = opt.X[np.argmin(opt.f)].copy()
        X, _, _ = step(opt, rastrigin)
        assert any(np.all(best_x == x) for x in X)  # exact: the brightest firefly is copied, not moved
    assert opt.alpha == pytest.approx(0.3 * 1e-4 / 0.9, rel=1e-9)


# ---------------------------------------------------------------- PSO


def test_pso_step_matches_reference_formula():
    X = np.array([[0.5, -1.0], [2.0, 0.25]])
    V = np.array([[0.1, 0.0], [-0.3, 0.2]])
    P = np.array([[0.4, -0.5], [1.0, 0.0]])
    g = np.array([1.0, 0.0])
    r1 = np.array([[0.2, 0.9], [0.5, 0.1]])
    r2 = np.array([[0.7, 0.3], [0.0, 1.0]])
    w, c = 0.7298, 1.49618
    Xn, Vn = pso.pso_step(X, V, P, g, r1, r2, w, c, c)
    for i in range(2):
        for k in range(2):
            vk = w * V[i, k] + c * r1[i, k] * (P[i, k] - X[i, k]) + c * r2[i, k] * (g[k] - X[i, k])
            assert Vn[i, k] == pytest.approx(vk, abs=1e-15)
            assert Xn[i, k] == pytest.approx(X[i, k] + vk, abs=1e-15)


def test_pso_initialisation_and_first_move():
    lo, hi = np.array([-5.0, 0.0]), np.array([5.0, 2.0])
    opt = make("pso", lo, hi, seed=4, n=3)
    twin = copy.deepcopy(opt.rng)
    X0 = opt.ask()
    x0 = lo + twin.random((3, 2)) * (hi - lo)
    v0 = (lo + twin.random((3, 2)) * (hi - lo) - x0) / 2  # SPSO-2006 initial velocity
    # lo + u (hi - lo): the same numpy operations in the same order (element-wise, each correctly rounded)
    assert_same_bits(X0, x0, because="same code")
    np.testing.assert_allclose(opt.V, v0)
    f0 = shifted_sphere(X0)
    opt.tell(X0, f0, np.zeros(3))
    proposal = opt.ask()
    r1, r2 = twin.random((3, 2)), twin.random((3, 2))
    g = X0[np.argmin(f0)]
    v1 = 0.7298 * v0 + 1.49618 * r1 * (X0 - X0) + 1.49618 * r2 * (g - X0)
    np.testing.assert_allclose(proposal, X0 + v1, rtol=0, atol=1e-14)


def test_pso_personal_bests_never_get_worse():
    opt = make("pso", [-5.12] * 4, [5.12] * 4, seed=8, n=10)
    step(opt, rastrigin)
    prev_f, prev_P = opt.pf.copy(), opt.P.copy()
    for _ in range(30):
        X, f, _ = step(opt, rastrigin)
        assert np.all(opt.pf <= prev_f)
        improved = f < prev_f
        assert_exact(opt.P[improved], X[improved])  # copied
        assert_exact(opt.P[~improved], prev_P[~improved])  # ties keep the old best
        # rastrigin on the same (10, 4) array layout: each stored value at the row it was computed at
        assert_same_bits(opt.pf, rastrigin(opt.P), because="same code")
        prev_f, prev_P = opt.pf.copy(), opt.P.copy()


def test_pso_keeps_velocity_after_clipping():
    opt = make("pso", [0.0, 0.0], [1.0, 1.0], seed=0, n=2)
    step(opt, shifted_sphere)  # optimum (1.3, 1.3) lies outside: particles get pushed to the face
    clipped = 0
    for _ in range(5):
        raw = opt.ask()
        V = opt.V.copy()
        X = opt.space.repair(raw)
        clipped += int(np.any(X != raw))
        opt.tell(X, shifted_sphere(X), np.zeros(2))
        assert_exact(opt.V, V)  # clipping leaves the velocity as it was
        assert_exact(opt.X, X)  # a copy of the told positions
    assert clipped > 0


# ---------------------------------------------------------------- quality

# 10-D shifted sphere sum((x - 1.3)^2) on [-5, 5]^10, default settings. Measured over seeds 0-29:
#   apso     5000 evals: worst 4.6e-8  (median 2.8e-8)
#   firefly 10000 evals: worst 1.0e-7  (median 7.4e-8)   (100 generations of n = 100)
#   pso     10000 evals: worst 2.6e-11 (median 1.1e-12)
@pytest.mark.parametrize("name, budget, accuracy", [
    ("apso", 5000, 1e-6),
    ("firefly", 10000, 1e-6),
    ("pso", 10000, 1e-9),
])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reaches_shifted_sphere_optimum(name, budget, accuracy, seed):
    res = heurtune.minimize(shifted_sphere, [-5.0] * 10, [5.0] * 10, name, max_evals=budget, seed=seed)
    assert res.n_evals == budget
    assert res.f < accuracy
    np.testing.assert_allclose(res.x, 1.3, atol=10 * np.sqrt(accuracy))


def test_pso_bound_rules_reflect_and_redraw_what_leaves_the_box():
    lower, upper = np.array([0.0, 0.0]), np.array([1.0, 2.0])
    X = np.array([[1.25, 0.5], [-0.5, 2.5], [0.5, -4.5], [0.5, 1.0]])
    V = np.array([[0.3, 0.1], [-0.7, 0.6], [0.2, -5.0], [0.1, 0.1]])
    same = pso.handle_bounds(X, V, lower, upper, "engine")
    assert same[0] is X and same[1] is V
    Xr, Vr = pso.handle_bounds(X, V, lower, upper, "reflect")
    # 1.25 -> 0.75 (mirrored at 1), -0.5 -> 0.5, 2.5 -> 1.5, -4.5 -> folded twice: 0.5
    np.testing.assert_allclose(Xr, [[0.75, 0.5], [0.5, 1.5], [0.5, 0.5], [0.5, 1.0]], rtol=0, atol=1e-15)
    assert_exact(Vr, [[-0.3, 0.1], [0.7, -0.6], [0.2, 5.0], [0.1, 0.1]])  # sign flips of literals
    uniform = np.full((4, 2), 0.25)
    Xn, Vn = pso.handle_bounds(X, V, lower, upper, "random", uniform)
    # 0 + 0.25 * 1 and 0 + 0.25 * 2 are exact in binary; the rest are copies or zeros
    assert_exact(Xn, [[0.25, 0.5], [0.25, 0.5], [0.5, 0.5], [0.5, 1.0]])
    assert_exact(Vn, [[0.0, 0.1], [0.0, 0.0], [0.2, 0.0], [0.1, 0.1]])


@pytest.mark.parametrize("rule", ["reflect", "random"])
def test_pso_with_a_bound_rule_keeps_its_particles_inside_and_solves_a_corner_optimum(rule):
    """The optimum of the shifted sphere lies at a corner of the box. Clipping lands on it
    exactly (f = 0 for seeds 0-3); reflection approaches it to 2e-9, random redraws, which
    stop the particle, to 2e-4 (measured over seeds 0-3)."""
    def corner(X):
        return np.sum((X - np.array([1.0, 1.0, -1.0])) ** 2, axis=1)

    res = heurtune.minimize(corner, [-1.0] * 3, [1.0] * 3, "pso", settings={"bounds": rule}, max_evals=4000, seed=2)
    assert res.f < {"reflect": 1e-7, "random": 1e-3}[rule]
    assert np.all(np.abs(res.x) <= 1.0)


def test_pso_default_bound_rule_draws_nothing_more():
    """``bounds = "engine"`` is the earlier PSO: same numbers for the same seed."""
    def sphere(X):
        return np.sum(X * X, axis=1)

    a = heurtune.minimize(sphere, [-5.0] * 4, [5.0] * 4, "pso", max_evals=800, seed=7)
    b = heurtune.minimize(sphere, [-5.0] * 4, [5.0] * 4, "pso", settings={"bounds": "engine"}, max_evals=800, seed=7)
    assert_same_bits(a.f, b.f, because="same seed")
    assert_same_bits(a.x, b.x, because="same seed")
