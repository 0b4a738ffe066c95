"""Robust stability: spectral-radius test, Hurwitz criterion, Kharitonov, Pade, interval boxes."""

import math

import numpy as np
import pytest
from numerics import assert_exact
from scipy.interpolate import pade as scipy_pade

from heurtune.core.errors import ConfigError
from heurtune.objectives.robustness import (
    complementary_sensitivity,
    frequency_response,
    hurwitz_determinants,
    hurwitz_matrix,
    interval_characteristic_polynomial,
    is_hurwitz,
    kharitonov_polynomials,
    kharitonov_test,
    max_singular_value,
    pade,
    spectral_radius,
    spectral_radius_test,
)

W = np.concatenate([[0.0], np.logspace(-3, 3, 400)])


def _stable_by_roots(coeffs):
    return bool(np.all(np.roots(coeffs).real < 0))


# ---------------------------------------------------------------------------- spectral radius


def test_spectral_radius_matches_eigvals_on_random_complex_matrices():
    rng = np.random.default_rng(0)
    M = rng.normal(size=(200, 2, 2)) + 1j * rng.normal(size=(200, 2, 2))
    expected = np.array([np.max(np.abs(np.linalg.eigvals(m))) for m in M])
    np.testing.assert_allclose(spectral_radius(M), expected, rtol=1e-12)
    np.testing.assert_allclose(max_singular_value(M), [np.linalg.norm(m, 2) for m in M], rtol=1e-12)
    assert np.all(spectral_radius(M) <= max_singular_value(M) + 1e-12)


def test_pipeline_matches_direct_formulas_on_random_responses():
    rng = np.random.default_rng(1)
    n = 50
    w = np.linspace(0.0, 5.0, n)
    G = rng.normal(size=(n, 2, 2)) + 1j * rng.normal(size=(n, 2, 2))
    K = rng.normal(size=(n, 2, 2)) + 1j * rng.normal(size=(n, 2, 2))
    wt = rng.uniform(0.1, 0.5, size=(n, 2))
    res = spectral_radius_test(G, K, w, wt)
    for k in range(n):
        Wd = np.diag(wt[k])
        To = G[k] @ K[k] @ np.linalg.inv(np.eye(2) + G[k] @ K[k])
        Ti = K[k] @ G[k] @ np.linalg.inv(np.eye(2) + K[k] @ G[k])
        assert res.rho_output[k] == pytest.approx(np.max(np.abs(np.linalg.eigvals(Wd @ To))), rel=1e-9)
        assert res.rho_input[k] == pytest.approx(np.max(np.abs(np.linalg.eigvals(Wd @ Ti))), rel=1e-9)
        assert res.sigma_output[k] == pytest.approx(np.linalg.norm(Wd @ To, 2), rel=1e-9)
        assert res.sigma_input[k] == pytest.approx(np.linalg.norm(Wd @ Ti, 2), rel=1e-9)
    # T_i = K (I + G K)^-1 G (the paper's eq. 38 up to sign)
    Ti = complementary_sensitivity(G, K, "input")
    alt = K @ np.linalg.inv(np.eye(2) + G @ K) @ G
    np.testing.assert_allclose(Ti, alt, atol=1e-9)


@pytest.mark.parametrize("k, weight, stable", [(1.0, 1.5, True), (3.0, 1.5, False), (9.0, 0.3, True)])
def test_siso_reduces_to_weighted_complementary_sensitivity(k, weight, stable):
    def G(w):
        return 1.0 / (1j * w + 1.0)

    res = spectral_radius_test(G, k, W, weight)
    T = k / (1j * W + 1.0 + k)
    for arr in (res.rho_input, res.rho_output, res.sigma_input, res.sigma_output):
        np.testing.assert_allclose(arr, weight * np.abs(T), rtol=1e-12)
    assert res.rho_output_peak == pytest.approx(weight * k / (1 + k))
    assert res.rho_output_peak_w == 0.0 and res.sigma_input_peak_w == 0.0
    assert res.robustly_stable is stable and res.sigma_robustly_stable is stable


def test_decoupled_system_rho_is_largest_diagonal_entry():
    k1, k2 = 2.0, 5.0

    def G(w):
        s = 1j * np.asarray(w)
        z = np.zeros_like(s)
        return np.array([[1 / (s + 1), z], [z, 2 / (s + 2)]])  # (2, 2, n) layout

    K = np.diag([k1, k2])
    res = spectral_radius_test(G, K, W, 0.3)
    s = 1j * W
    t11 = k1 / (s + 1 + k1)
    t22 = 2 * k2 / (s + 2 + 2 * k2)
    hand = 0.3 * np.maximum(np.abs(t11), np.abs(t22))
    for arr in (res.rho_input, res.rho_output, res.sigma_input, res.sigma_output):
        np.testing.assert_allclose(arr, hand, rtol=1e-12)
    # peak at w = 0: max(2/3, 10/12)
    assert res.rho_input_peak == pytest.approx(0.3 * 10 / 12)
    assert res.robustly_stable


def test_per_channel_weight_on_decoupled_system():
    G = np.array([[[1.0, 0.0], [0.0, 1.0]]])  # a single frequency
    K = np.diag([1.0, 3.0])
    res = spectral_radius_test(G, K, [0.0], weight=[[1.0, 1.2]])
    # t = (1/2, 3/4) -> weighted (0.5, 0.9)
    assert res.rho_output_peak == pytest.approx(0.9)
    res = spectral_radius_test(G, K, [0.0], weight_input=[[1.0, 1.5]], weight_output=0.1)
    assert res.rho_input_peak == pytest.approx(1.125) and not res.input_stable
    assert res.output_stable and not res.robustly_stable


def test_rho_passes_where_sigma_is_conservative():
    # Strongly non-normal T: eigenvalues 0.5 but a large off-diagonal coupling.
    T = np.array([[0.5, 4.0], [0.0, 0.5]])
    L = T @ np.linalg.inv(np.eye(2) - T)  # so that L (I + L)^-1 = T
    res = spectral_radius_test(L, np.eye(2), [0.0, 1.0])
    np.testing.assert_allclose(res.rho_output, 0.5)
    assert res.sigma_output_peak > 1.0
    assert res.robustly_stable and not res.sigma_robustly_stable


def test_delay_plant_and_scalar_only_callable():
    # A callable written for scalars only (math.*) is evaluated per frequency.
    def G(w):
        return complex(math.cos(w), -math.sin(w)) / complex(1.0, 10.0 * w)

    Gw = frequency_response(G, W)
    np.testing.assert_allclose(Gw[:, 0, 0], np.exp(-1j * W) / (1 + 10j * W))
    res = spectral_radius_test(G, 2.0, W, 0.3)
    assert res.rho_output_peak == pytest.approx(0.3 * np.max(np.abs(2 * Gw / (1 + 2 * Gw))))


def test_singular_loop_gives_inf_and_fails():
    res = spectral_radius_test(np.array([-1.0, 0.5]), 1.0, [0.0, 1.0])
    assert np.isinf(res.rho_output[0]) and res.rho_output[1] == pytest.approx(1 / 3)
    assert not res.robustly_stable


@pytest.mark.parametrize("kwargs", [
    {"G": np.ones((3, 2, 2)), "K": np.ones((3, 3, 3)), "w": [0, 1, 2]},
    {"G": 1.0, "K": 1.0, "w": []},
    {"G": 1.0, "K": 1.0, "w": [-1.0]},
    {"G": np.ones(4), "K": 1.0, "w": [0, 1, 2]},
    {"G": 1.0, "K": 1.0, "w": [0, 1], "weight": [1, 2, 3]},
])
def test_spectral_radius_validation(kwargs):
    with pytest.raises(ConfigError):
        spectral_radius_test(**kwargs)


# ---------------------------------------------------------------------------- Hurwitz


def test_hurwitz_matrix_and_determinants_of_known_cubic():
    c = [1.0, 6.0, 11.0, 6.0]  # (s+1)(s+2)(s+3)
    assert_exact(hurwitz_matrix(c), [[6, 6, 0], [1, 11, 0], [0, 6, 6]])  # the coefficients, placed
    # Delta1 = a1, Delta2 = a1 a2 - a0 a3, Delta3 = a3 Delta2
    np.testing.assert_allclose(hurwitz_determinants(c), [6.0, 60.0, 360.0])
    assert is_hurwitz(c)
    # s^3 + s^2 + s + 2: Delta2 = 1 - 2 < 0
    np.testing.assert_allclose(hurwitz_determinants([1, 1, 1, 2]), [1.0, -1.0, -2.0])
    assert not is_hurwitz([1, 1, 1, 2])
    # negative leading coefficient is normalised (same roots)
    assert is_hurwitz([-1.0, -6.0, -11.0, -6.0])
    assert is_hurwitz([5.0]) and hurwitz_determinants([5.0]).size == 0
    assert is_hurwitz([2.0, 3.0]) and not is_hurwitz([2.0, -3.0])


def test_hurwitz_matches_numpy_roots_on_random_polynomials():
    rng = np.random.default_rng(2)
    agree = 0
    for _ in range(400):
        n = int(rng.integers(1, 7))
        roots = rng.normal(-0.3, 1.0, size=n) + 1j * rng.normal(0, 1, size=n) * (rng.random(n) < 0.5)
        roots = np.concatenate([roots, np.conj(roots[np.iscomplex(roots)])])
        c = np.real(np.poly(roots))
        if np.min(np.abs(np.roots(c).real)) < 1e-3:
            continue  # too close to the boundary for either method to be decisive
        assert is_hurwitz(c) == _stable_by_roots(c), c
        agree += 1
    assert agree > 300


@pytest.mark.parametrize("bad", [[], [0.0, 1.0], [1.0, np.nan], [1 + 1j, 2], "abc"])
def test_hurwitz_validation(bad):
    with pytest.raises(ConfigError):
        hurwitz_matrix(bad)


# ---------------------------------------------------------------------------- Kharitonov

# p(s) = s^3 + a2 s^2 + a1 s + a0, highest power first
STABLE_BOX = ([1.0, 2.0, 5.0, 1.0], [1.0, 3.0, 7.0, 3.0])
UNSTABLE_BOX = ([1.0, 1.0, 0.5, 1.0], [1.0, 2.0, 1.0, 3.0])


def test_kharitonov_sign_patterns():
    lo = [10.0, 20.0, 30.0, 40.0, 50.0]  # c4 c3 c2 c1 c0
    hi = [11.0, 21.0, 31.0, 41.0, 51.0]
    K1, K2, K3, K4 = kharitonov_polynomials(lo, hi)
    # increasing powers c0..c4: K1 l l u u l, K2 u u l l u, K3 l u u l l, K4 u l l u u (picked, not computed)
    assert_exact(K1[::-1], [50, 40, 31, 21, 10])
    assert_exact(K2[::-1], [51, 41, 30, 20, 11])
    assert_exact(K3[::-1], [50, 41, 31, 20, 10])
    assert_exact(K4[::-1], [51, 40, 30, 21, 11])


def test_kharitonov_stable_textbook_cubic():
    res = kharitonov_test(*STABLE_BOX)
    assert res.robustly_stable and all(res.hurwitz)
    for p, d in zip(res.polynomials, res.determinants):
        a0, a1, a2, a3 = p
        np.testing.assert_allclose(d, [a1, a1 * a2 - a0 * a3, a3 * (a1 * a2 - a0 * a3)])
        assert _stable_by_roots(p)


def test_kharitonov_unstable_textbook_cubic():
    res = kharitonov_test(*UNSTABLE_BOX)
    assert not res.robustly_stable
    # K1 = s^3 + 2 s^2 + 0.5 s + 1 (a2 a1 = a0: boundary), K2 = s^3 + s^2 + s + 3,
    # K3 = s^3 + 2 s^2 + s + 1 (stable), K4 = s^3 + s^2 + 0.5 s + 3
    assert_exact(res.polynomials[1], [1, 1, 1, 3])  # picked from the bounds
    assert res.hurwitz[1:] == (False, True, False)
    assert res.determinants[0][1] == pytest.approx(0.0, abs=1e-12)  # K1 sits on the boundary
    assert not is_hurwitz(res.polynomials[0], tol=1e-9)
    assert not _stable_by_roots(res.polynomials[1]) and not _stable_by_roots(res.polynomials[3])
    assert _stable_by_roots(res.polynomials[2])


def test_monte_carlo_members_of_stable_box_are_stable():
    rng = np.random.default_rng(3)
    lo, hi = map(np.asarray, STABLE_BOX)
    samples = rng.uniform(lo, hi, size=(2000, lo.size))
    assert all(_stable_by_roots(c) for c in samples)
    # and a 4th-order box checked the same way
    lo4, hi4 = np.array([1.0, 4.0, 8.0, 6.0, 1.0]), np.array([1.2, 5.0, 9.0, 7.0, 2.0])
    assert kharitonov_test(lo4, hi4).robustly_stable
    assert all(_stable_by_roots(c) for c in rng.uniform(lo4, hi4, size=(2000, 5)))


def test_kharitonov_negative_family_and_validation():
    lo, hi = map(np.asarray, STABLE_BOX)
    assert kharitonov_test(-hi, -lo).robustly_stable
    with pytest.raises(ConfigError):
        kharitonov_test([-1.0, 1.0], [1.0, 2.0])  # leading interval contains 0
    with pytest.raises(ConfigError):
        kharitonov_test([1.0, 3.0], [1.0, 2.0])  # lower > upper
    with pytest.raises(ConfigError):
        kharitonov_test([1.0, 1.0], [1.0, 2.0, 3.0])


# ---------------------------------------------------------------------------- Pade and boxes


def test_pade_first_order_closed_form():
    num, den = pade(2.0, 1)
    np.testing.assert_allclose(num, [-1.0, 1.0])  # 1 - L s / 2
    np.testing.assert_allclose(den, [1.0, 1.0])  # 1 + L s / 2


@pytest.mark.parametrize("L, order, num_order", [(2.0, 2, None), (0.7, 3, None), (1.5, 4, None), (1.0, 3, 2)])
def test_pade_matches_scipy(L, order, num_order):
    p = order if num_order is None else num_order
    taylor = [(-L) ** k / math.factorial(k) for k in range(p + order + 1)]
    P, Q = scipy_pade(taylor, order, p)
    num, den = pade(L, order, num_order)
    scale = Q.coeffs[-1]
    np.testing.assert_allclose(num, P.coeffs / scale, rtol=1e-10)
    np.testing.assert_allclose(den, Q.coeffs / scale, rtol=1e-10)
    # and it approximates the delay at low frequency
    s = 0.05j
    assert abs(np.polyval(num, s) / np.polyval(den, s) - np.exp(-L * s)) < 1e-6


def test_pade_validation():
    assert [a.tolist() for a in pade(0.0, 3)] == [[1.0], [1.0]]
    for args in [(-1.0, 1), (1.0, -1), (1.0, 1.5), (float("nan"), 1)]:
        with pytest.raises(ConfigError):
            pade(*args)


def _pi_fopdt_char_poly(P):
    """s (T s + 1)(1 + L s / 2) + K (kp s + ki)(1 - L s / 2): PI on a Pade-1 FOPDT plant."""
    num, den = pade(P["L"], 1)
    return np.polyadd(np.polymul([P["T"], 1.0, 0.0], den), P["K"] * np.polymul([2.618, 0.2618], num))


BOX = {"K": (0.8, 1.2), "T": (8.0, 12.0), "L": (1.6, 2.4)}


def test_interval_characteristic_polynomial_bounds_are_exact_for_multilinear():
    lo, hi = interval_characteristic_polynomial(_pi_fopdt_char_poly, BOX)
    rng = np.random.default_rng(4)
    coeffs = np.array([
        _pi_fopdt_char_poly({k: rng.uniform(*v) for k, v in BOX.items()}) for _ in range(3000)
    ])
    assert np.all(coeffs >= lo - 1e-12) and np.all(coeffs <= hi + 1e-12)
    # bounds attained: leading coefficient T L / 2 in [8*1.6/2, 12*2.4/2]
    assert lo[0] == pytest.approx(6.4) and hi[0] == pytest.approx(14.4)
    assert lo[-1] == pytest.approx(0.8 * 0.2618) and hi[-1] == pytest.approx(1.2 * 0.2618)
    res = kharitonov_test(lo, hi)
    assert res.robustly_stable
    assert all(_stable_by_roots(c) for c in coeffs)


def test_interval_characteristic_polynomial_fixed_params_and_validation():
    lo, hi = interval_characteristic_polynomial(lambda P: [1.0, P["a"], P["b"]], {"a": (1, 2), "b": (3, 3)})
    # the polynomial returns the box's corners as they are: the bounds are copies of them
    assert_exact(lo, [1, 1, 3])
    assert_exact(hi, [1, 2, 3])
    for box in [{}, {"a": (2, 1)}, {"a": (1,)}, {f"p{i}": (0, 1) for i in range(17)}]:
        with pytest.raises(ConfigError):
            interval_characteristic_polynomial(lambda P: [1.0, 1.0], box)
