"""Tests of heurtune.objectives.qtp.oustaloup against independent references.

Every reference here is computed anew: the exact (jw)^r with numpy, the transfer function of the
state-space matrices with numpy.linalg.solve, a Grunwald-Letnikov solution and a Mittag-Leffler
series for the fractional step response (REFERENCE.md section 3).

Measured on this machine (N = 5, band [1e-3, 1e3], grid [1e-2, 1e2] rad/s), for comparison with
the tolerances:
    max |dB error|:  r=-0.9 0.0390, -0.5 0.0238, -0.2 0.0102, 0.3 0.0151, 0.8 0.0351
    max |phase err|: r=-0.9 5.09,   -0.5 2.75,   -0.2 1.09,   0.3 1.63,   0.8 4.48 degrees
    state space vs freqresp: max relative error 4.0e-13
    GL (h = 1e-3): y(1) - 0.61305 = -1.4e-4, y(2) - 0.77645 = -7.7e-5
    Oustaloup closed loop step: y(1) - 0.61305 = -2.0e-4, y(2) - 0.77645 = -5.2e-4
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal
from numerics import assert_close
from scipy.special import gamma

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.oustaloup import (
    REALISATIONS,
    fractional_integrator,
    oustaloup_zpk,
)

N = 5
BAND = (1e-3, 1e3)
ALPHAS = (0.3, 0.8437, 0.9814, 1.0, 1.5, 2.0)

# Published values of the step response 1 - E_0.8(-t^0.8) of 1/(s^0.8 + 1).
ML_STEP = {1.0: 0.61305, 2.0: 0.77645}


def zpk_response(z, p, k, w):
    """k prod (s - z) / (s - p) at s = jw, evaluated directly from the zeros and poles."""
    s = 1j * np.asarray(w, dtype=np.float64)
    return k * np.prod((s[:, None] - z[None, :]) / (s[:, None] - p[None, :]), axis=1)


def ss_response(A, B, C, D, w):
    """C (jwI - A)^-1 B + D on the grid w, by batched linear solves."""
    n = A.shape[0]
    s = 1j * np.asarray(w, dtype=np.float64)
    M = s[:, None, None] * np.eye(n)[None, :, :] - A[None, :, :]
    X = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (len(s), n))[:, :, None])[:, :, 0]
    return X @ C + D


# ---------------------------------------------------------------------------------------------
# 1. Frequency-domain accuracy of the Oustaloup filter
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("r", [-0.9, -0.5, -0.2, 0.3, 0.8])
def test_oustaloup_matches_exact_fractional_operator_in_band(r):
    z, p, k = oustaloup_zpk(r, N, BAND)
    assert z.shape == p.shape == (2 * N + 1,)
    assert np.all(z < 0) and np.all(p < 0)
    w = np.logspace(-2, 2, 2001)
    approx = zpk_response(z, p, k, w)
    exact = (1j * w) ** r
    mag_err_db = np.max(np.abs(20 * np.log10(np.abs(approx) / np.abs(exact))))
    phase_err_deg = np.max(np.abs(np.degrees(np.angle(approx / exact))))
    # REFERENCE.md sec. 3 bounds for N=5, [1e-3, 1e3] over [1e-2, 1e2]; measured worst 0.039 dB.
    assert mag_err_db < 0.05
    # REFERENCE.md sec. 3 bound; measured worst 5.09 deg (r = -0.9).
    assert phase_err_deg < 5.4


def test_oustaloup_error_grows_at_band_edges():
    # Sanity that the in-band test can fail: at wb the error is dB-sized (REFERENCE: 1.4-2.8 dB).
    z, p, k = oustaloup_zpk(0.5, N, BAND)
    w = np.array([BAND[0], BAND[1]])
    err_db = np.abs(20 * np.log10(np.abs(zpk_response(z, p, k, w)) / w**0.5))
    # Lower bound 1 dB: the edge error must be far above the 0.05 dB in-band figure.
    assert np.all(err_db > 1.0)


# ---------------------------------------------------------------------------------------------
# 2. State-space realisation reproduces freqresp
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("realisation", ["direct", "integer_split"])
@pytest.mark.parametrize("alpha", ALPHAS)
def test_state_space_reproduces_freqresp(alpha, realisation):
    F = fractional_integrator(alpha, N, BAND, realisation)
    A, B, C, D = F.state_space()
    n = F.order
    assert A.shape == (n, n) and B.shape == (n,) and C.shape == (n,)
    assert isinstance(D, float)
    w = np.logspace(-4, 4, 401)
    H_ss = ss_response(A, B, C, D, w)
    H_fr = F.freqresp(w)
    # Also pin freqresp itself to an independent zpk evaluation so both sides are checked.
    H_ref = zpk_response(F.zeros, F.poles, F.gain, w) / (1j * w) ** F.n_integrators
    # Both are exact rational identities; 1e-9 leaves room only for rounding (measured 4e-13).
    np.testing.assert_allclose(H_ss, H_fr, rtol=1e-9, atol=0)
    np.testing.assert_allclose(H_fr, H_ref, rtol=1e-9, atol=0)


# ---------------------------------------------------------------------------------------------
# 3. Low-frequency behaviour of the two realisations
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.8437, 0.9814])
def test_direct_has_finite_dc_gain_wb_to_minus_alpha(alpha):
    F = fractional_integrator(alpha, N, BAND, "direct")
    assert F.n_integrators == 0
    # Filter at s = 0: k prod(-z) / prod(-p) = k prod(z/p) (zeros and poles are all nonzero).
    dc = F.gain * np.prod(F.zeros / F.poles)
    # Closed-form identity wh^-a (wh/wb)^a = wb^-a; 1e-9 is rounding only.
    assert dc == pytest.approx(BAND[0] ** -alpha, rel=1e-9)
    # freqresp must flatten to that same DC value well below wb (1e-6 rel: next pole is 1e-3).
    assert abs(F.freqresp(np.array([1e-9]))[0]) == pytest.approx(dc, rel=1e-6)


@pytest.mark.parametrize("alpha", [0.3, 0.8437, 0.9814, 1.5])
def test_integer_split_has_exact_integral_action(alpha):
    F = fractional_integrator(alpha, N, BAND, "integer_split")
    assert F.n_integrators >= 1
    assert F.n_integrators == math.floor(alpha) + 1
    w = np.array([1e-8, 1e-7])
    sF = (1j * w) ** F.n_integrators * F.freqresp(w)
    # |s^n F| tends to the filter's DC gain wb^(1 - frac); 1e-6 rel: still 5 decades below wb.
    limit = BAND[0] ** (F.n_integrators - alpha)
    assert np.all(np.isfinite(sF))
    assert abs(sF[0]) == pytest.approx(limit, rel=1e-6)
    assert abs(sF[0]) == pytest.approx(abs(sF[1]), rel=1e-6)
    # And the response itself is unbounded: |F(j 1e-8)| >> the direct realisation's DC gain.
    direct_dc = abs(fractional_integrator(min(alpha, 0.9814), N, BAND, "direct").freqresp(w)[0])
    assert abs(F.freqresp(w)[0]) > 1e3 * direct_dc


@pytest.mark.parametrize("realisation", REALISATIONS)
@pytest.mark.parametrize("alpha", [1, 1.0, 2.0])
def test_integer_alpha_gives_exact_integrators(alpha, realisation):
    F = fractional_integrator(alpha, N, BAND, realisation)
    assert F.n_integrators == int(alpha)
    assert len(F.zeros) == 0 and len(F.poles) == 0
    assert F.gain == 1.0  # exact: the literal
    w = np.logspace(-4, 4, 9)
    # Exact 1/(jw)^alpha up to rounding.
    np.testing.assert_allclose(F.freqresp(w), 1.0 / (1j * w) ** alpha, rtol=1e-12, atol=0)
    A, B, C, D = F.state_space()
    # A pure integrator chain: nilpotent A, no feedthrough.
    assert D == 0.0  # exact: the literal
    assert np.all(np.linalg.matrix_power(A, F.order) == 0)  # exact: products of structural zeros


# ---------------------------------------------------------------------------------------------
# 4. Time-domain oracle: step response of 1 / (s^0.8 + 1)
# ---------------------------------------------------------------------------------------------

def test_published_mittag_leffler_values_match_series():
    # Check the published oracle values against the series 1 - sum (-t^a)^k / Gamma(a k + 1).
    a = 0.8
    for t, val in ML_STEP.items():
        z = -(t**a)
        series = 1.0 - sum(z**k / gamma(a * k + 1.0) for k in range(120))
        # Published to 5 decimals: half a unit in the last place plus rounding.
        assert abs(series - val) < 6e-6


def grunwald_letnikov_step(a, h, t_end):
    """Solve D^a y + y = 1, y(0) = 0, with the implicit Grunwald-Letnikov scheme."""
    n = int(round(t_end / h))
    c = np.empty(n + 1)  # c_j = (-1)^j binom(a, j)
    c[0] = 1.0
    for j in range(1, n + 1):
        c[j] = c[j - 1] * (1.0 - (a + 1.0) / j)
    y = np.zeros(n + 1)
    ha = h**-a
    for m in range(1, n + 1):
        history = np.dot(c[1 : m + 1], y[m - 1 :: -1])
        y[m] = (1.0 - ha * history) / (ha + 1.0)
    return np.arange(n + 1) * h, y


def test_grunwald_letnikov_oracle_matches_published_values():
    h = 1e-3
    t, y = grunwald_letnikov_step(0.8, h, 2.0)
    for tq, val in ML_STEP.items():
        i = int(round(tq / h))
        # GL is first order in h; measured errors 1.4e-4 (t=1) and 7.7e-5 (t=2) at h = 1e-3.
        assert abs(y[i] - val) < 1e-3


def test_oustaloup_closed_loop_step_matches_oracle():
    z, p, k = oustaloup_zpk(0.8, N, BAND)
    # F = k num/den  =>  1/(F + 1) = den / (k num + den).
    num = np.real(np.poly(z))
    den = np.real(np.poly(p))
    cl_num = den
    cl_den = np.polyadd(k * num, den)
    # The closed loop must be stable for a step response to mean anything.
    assert np.max(np.roots(cl_den).real) < 0
    t = np.linspace(0.0, 2.0, 2001)
    _, y = scipy.signal.step((cl_num, cl_den), T=t)
    for tq, val in ML_STEP.items():
        i = int(round(tq / (t[1] - t[0])))
        # Measured errors -2.0e-4 (t=1) and -5.2e-4 (t=2); 1e-3 leaves less than 2x headroom.
        assert abs(y[i] - val) < 1e-3
    # The direct realisation's finite DC gain shows up as a steady state 1/(1 + wb^0.8) < 1.
    assert np.polyval(cl_num, 0) / np.polyval(cl_den, 0) == pytest.approx(
        1.0 / (1.0 + BAND[0] ** 0.8), rel=1e-9
    )


# ---------------------------------------------------------------------------------------------
# 5. Bad inputs
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("r", [-1.0, 1.0, -1.5, 2.0, float("nan")])
def test_oustaloup_rejects_r_outside_open_unit_interval(r):
    with pytest.raises(ConfigError):
        oustaloup_zpk(r, N, BAND)


@pytest.mark.parametrize("order", [0, -1, 2.5, "5"])
def test_oustaloup_rejects_bad_order(order):
    with pytest.raises(ConfigError):
        oustaloup_zpk(0.5, order, BAND)


@pytest.mark.parametrize("band", [(1e3, 1e-3), (1.0, 1.0), (0.0, 1.0), (-1.0, 1.0),
                                  (1e-3, float("inf"))])
def test_oustaloup_rejects_bad_band(band):
    with pytest.raises(ConfigError):
        oustaloup_zpk(0.5, N, band)


@pytest.mark.parametrize("alpha", [0.0, 0.09, 2.01, 3.0, -0.5, float("nan"), float("inf")])
@pytest.mark.parametrize("realisation", REALISATIONS)
def test_fractional_integrator_rejects_alpha_outside_range(alpha, realisation):
    with pytest.raises(ConfigError):
        fractional_integrator(alpha, N, BAND, realisation)


def test_fractional_integrator_accepts_range_endpoints():
    # Counterpart of the rejection test: the closed interval [0.1, 2] is allowed.
    assert fractional_integrator(0.1, N, BAND).alpha == 0.1  # exact: stored and read back
    assert fractional_integrator(2.0, N, BAND).alpha == 2.0


@pytest.mark.parametrize("name", ["Direct", "integer-split", "", "oustaloup"])
def test_fractional_integrator_rejects_unknown_realisation(name):
    with pytest.raises(ConfigError):
        fractional_integrator(0.5, N, BAND, name)


def test_fractional_integrator_propagates_filter_errors():
    # Order and band are validated through oustaloup_zpk for a fractional alpha.
    with pytest.raises(ConfigError):
        fractional_integrator(0.5, 0, BAND)
    with pytest.raises(ConfigError):
        fractional_integrator(0.5, N, (1e3, 1e-3), "integer_split")


@pytest.mark.parametrize("alpha, realisation", [(0.3, "direct"), (0.9814, "direct"), (1.0, "direct"),
                                                (1.5, "direct"), (0.5, "integer_split")])
def test_modal_form_reproduces_the_frequency_response(alpha, realisation):
    # Partial fractions of a rational function with distinct real poles: exact up to round-off.
    fi = fractional_integrator(alpha, 5, (1e-3, 1e3), realisation)
    poles, residues, d = fi.modal()
    w = np.logspace(-4, 4, 200)
    s = 1j * w
    H = d + (residues[None, :] / (s[:, None] - poles[None, :])).sum(axis=1)
    np.testing.assert_allclose(H, fi.freqresp(w), rtol=1e-9)


def test_modal_form_is_refused_for_a_double_integrator():
    assert fractional_integrator(1.5, 5, (1e-3, 1e3), "integer_split").modal() is None
    assert fractional_integrator(2.0, 5, (1e-3, 1e3), "direct").modal() is None


def test_compiled_residues_are_numpys_products():
    """The residues come from a compiled loop that takes each product in index order; numpy's
    ``prod`` along a row, the formula before it, gives them for every order a config may ask
    for, both realisations and orders across [0.1, 2). A compiled kernel against the numpy code
    it replaced: within a tolerance, not bit for bit (numpy's reduction order is its own; the
    same products in index order do give the same bits today). Each residue is ``gain`` times a
    product of 2N + 1 differences over a product of at most 2N + 1 (N <= 20); both compute the
    differences alike, and the products, the gain and the quotient are at most 4N + 4 = 84
    roundings, so any two orders agree to 2 x 84 eps < 4e-14 relative."""
    from heurtune.objectives.qtp.oustaloup import MAX_OUSTALOUP_ORDER

    rng = np.random.default_rng(5)
    checked = 0
    for order in range(1, MAX_OUSTALOUP_ORDER + 1):
        for realisation in REALISATIONS:
            for alpha in np.concatenate([rng.uniform(0.1, 2.0, 12), [0.1, 0.9814, 1.0, 1.5]]):
                fi = fractional_integrator(float(alpha), order, BAND, realisation)
                modal = fi.modal()
                if modal is None:
                    continue
                poles, residues, _ = modal
                diff = poles[:, None] - poles[None, :]
                np.fill_diagonal(diff, 1.0)
                numpy_residues = fi.gain * np.prod(poles[:, None] - fi.zeros[None, :], axis=1) / np.prod(diff, axis=1)
                assert_close(residues, numpy_residues, rtol=1e-13,
                             because="the same products in two orders: 2 x 84 roundings < 4e-14 relative",
                             err_msg=str((order, realisation, alpha)))
                checked += 1
    assert checked > 400
