"""MIMO Kharitonov test of paper 000 (``heurtune.objectives.tito.kharitonov``).

Hand-computed polynomials and Hurwitz determinants, an independent python-control check of the
closed-loop poles, the interval bounds against interior samples, the row-reduced Hurwitz matrix,
and what the paper's printed numbers (eq. 59-70, eq. 46-58) do and do not support.
"""

import math

import control
import numpy as np
import pytest
from numerics import assert_exact
from scipy.optimize import linear_sum_assignment

from heurtune.core.errors import ConfigError
from heurtune.objectives.robustness import hurwitz_determinants, hurwitz_matrix, is_hurwitz
from heurtune.objectives.tito import kharitonov as kh
from heurtune.objectives.tito.model import (
    FOPDT,
    ParallelPID,
    PIController,
    PIDController,
    TFElement,
    inverted_decoupler,
    preset,
)

# ----------------------------------------------------------------------------------------------
# Hand example (no delay)
# ----------------------------------------------------------------------------------------------
#
#   a11 = a22 = 1/(s + 1),  a12 = a21 = 1/2,  c1 = 2 + 1/s = (2s + 1)/s,  c2 = 1 + 2/s = (s + 2)/s
#
#   N = (d_c1 d11 + n_c1 n11)(d_c2 d22 + n_c2 n22) d12 d21 - n_c1 n_c2 n12 n21 d11 d22
#   b1 = s (s + 1) + (2s + 1) = s^2 + 3s + 1
#   b2 = s (s + 1) + (s + 2)  = s^2 + 2s + 2
#   b1 b2 = s^4 + 5 s^3 + 9 s^2 + 8 s + 2                       (d12 = d21 = 1)
#   (2s + 1)(s + 2) = 2 s^2 + 5 s + 2,  (s + 1)^2 = s^2 + 2 s + 1
#   (2 s^2 + 5 s + 2)(s^2 + 2 s + 1) = 2 s^4 + 9 s^3 + 14 s^2 + 9 s + 2,  times 1/4:
#   0.5 s^4 + 2.25 s^3 + 3.5 s^2 + 2.25 s + 0.5
#   N = 0.5 s^4 + 2.75 s^3 + 5.5 s^2 + 5.75 s + 1.5
#
#   Hurwitz determinants of a0 s^4 + a1 s^3 + a2 s^2 + a3 s + a4:
#   D1 = a1 = 2.75
#   D2 = a1 a2 - a0 a3 = 15.125 - 2.875 = 12.25
#   D3 = a3 D2 - a1^2 a4 = 70.4375 - 11.34375 = 59.09375
#   D4 = a4 D3 = 88.640625

HAND_A = [[TFElement(K=1.0, lags=(1.0,)), 0.5], [0.5, TFElement(K=1.0, lags=(1.0,))]]
HAND_C = [(2.0, 1.0), (1.0, 2.0)]
HAND_N = [0.5, 2.75, 5.5, 5.75, 1.5]
HAND_DETS = [2.75, 12.25, 59.09375, 88.640625]


def test_hand_example_polynomial_and_hurwitz_determinants():
    p = kh.characteristic_polynomial(HAND_A, HAND_C)
    np.testing.assert_allclose(p, HAND_N, rtol=1e-15)
    np.testing.assert_allclose(hurwitz_determinants(p), HAND_DETS, rtol=1e-14)
    assert np.all(np.roots(p).real < 0)
    # The same controllers in every accepted form give the same polynomial.
    forms = [
        [ParallelPID(2.0, 1.0), ParallelPID(1.0, 2.0)],
        [PIController(Kc=2.0, Ti=2.0), PIController(Kc=1.0, Ti=0.5)],
        [kh.DelayTerm([2.0, 1.0], [1.0, 0.0]), kh.DelayTerm([1.0, 2.0], [1.0, 0.0])],
    ]
    for C in forms:
        np.testing.assert_allclose(kh.characteristic_polynomial(HAND_A, C), HAND_N, rtol=1e-15)
    # FOPDT with T and DelayTerm elements are the same plant.
    A2 = [[FOPDT(K=1.0, T=1.0, L=0.0), kh.DelayTerm([0.5], [1.0])], [[0.25, 0.25], kh.DelayTerm([1.0], [1.0, 1.0])]]
    np.testing.assert_allclose(kh.characteristic_polynomial(A2, HAND_C), HAND_N, rtol=1e-15)


def test_loop_polynomial_by_hand_and_p_controller_cancels_s():
    # 1/(s+1) with Pade(1) of L = 0.5: (1 - 0.25 s)/(1 + 0.25 s); PI 10 + 1/s:
    # s (s + 1)(0.25 s + 1) + (10 s + 1)(1 - 0.25 s) = 0.25 s^3 - 1.25 s^2 + 10.75 s + 1
    p = kh.loop_polynomial(FOPDT(K=1.0, T=1.0, L=0.5), (10.0, 1.0), delay="pade", pade_order=1)
    np.testing.assert_allclose(p, [0.25, -1.25, 10.75, 1.0], rtol=1e-15)
    # Taylor 1 - 0.5 s: s (s + 1) + (10 s + 1)(1 - 0.5 s) = -4 s^2 + 10.5 s + 1
    np.testing.assert_allclose(kh.loop_polynomial(FOPDT(1.0, 1.0, 0.5), (10.0, 1.0)), [-4.0, 10.5, 1.0])
    # Ki = 0: (Kd s^2 + Kp s)/(s (Tf s + 1)) is used as (Kd s + Kp)/(Tf s + 1): no root at 0.
    np.testing.assert_allclose(kh.loop_polynomial(FOPDT(1.0, 1.0, 0.0), (2.0, 0.0)), [1.0, 3.0])
    # The series PID with its filter equals the ParallelPID with the same gains and Tf.
    pid = PIDController(Kc=2.0, Ti=4.0, Td=1.0, Tf=0.1)
    Kp, Ki, Kd = pid.parallel()
    e = TFElement(K=1.5, lags=(3.0, 1.0), L=0.7)
    np.testing.assert_allclose(kh.loop_polynomial(e, pid, delay="pade", pade_order=3),
                               kh.loop_polynomial(e, ParallelPID(Kp, Ki, Kd, 0.1), delay="pade", pade_order=3))


def test_hand_box_kharitonov_hurwitz():
    # Box around 2 s^4 + 11 s^3 + 22 s^2 + 23 s + 6 (4 x the hand polynomial):
    #   c0 in [5, 7], c1 in [22, 24], c2 in [20, 24], c3 in [10, 12], c4 = 2.
    # Increasing powers, K1 = l l u u l, K2 = u u l l u, K3 = l u u l l, K4 = u l l u u:
    #   K1 = 2 s^4 + 12 s^3 + 24 s^2 + 22 s + 5: D = 12, 12*24 - 2*22 = 244, 22*244 - 144*5 = 4648, 5*4648
    #   K2 = 2 s^4 + 10 s^3 + 20 s^2 + 24 s + 7: D = 10, 200 - 48 = 152, 24*152 - 100*7 = 2948, 7*2948
    #   K3 = 2 s^4 + 10 s^3 + 24 s^2 + 24 s + 5: D = 10, 240 - 48 = 192, 24*192 - 100*5 = 4108, 5*4108
    #   K4 = 2 s^4 + 12 s^3 + 20 s^2 + 22 s + 7: D = 12, 240 - 44 = 196, 22*196 - 144*7 = 3304, 7*3304
    res = kh.kharitonov_hurwitz([2, 10, 20, 22, 5], [2, 12, 24, 24, 7], nominal=[2, 11, 22, 23, 6])
    expected = ([2, 12, 24, 22, 5], [2, 10, 20, 24, 7], [2, 10, 24, 24, 5], [2, 12, 20, 22, 7])
    dets = ([12, 244, 4648, 23240], [10, 152, 2948, 20636], [10, 192, 4108, 20540], [12, 196, 3304, 23128])
    for k in range(4):
        assert_exact(res.polynomials[k], expected[k])  # the bounds' coefficients, picked
        np.testing.assert_allclose(res.determinants[k], dets[k], rtol=1e-12)
        np.testing.assert_allclose(np.diag(res.reduced_matrices[k]), np.array(dets[k]) / np.r_[1, dets[k][:-1]],
                                   rtol=1e-12)
    # Hurwitz matrix of K1 by hand: rows a1 a3 0 0 / a0 a2 a4 0 / 0 a1 a3 0 / 0 a0 a2 a4
    assert_exact(res.hurwitz_matrices[0], [[12, 22, 0, 0], [2, 24, 5, 0], [0, 12, 22, 0], [0, 2, 24, 5]])  # placed
    assert res.hurwitz == (True, True, True, True)
    assert res.robustly_stable and res.failing == () and res.nominal_hurwitz
    assert res.summary().startswith("Kharitonov, degree 4: robustly stable")


def test_box_containing_an_unstable_polynomial_fails_and_names_it():
    # c1 in [22, 26], c2 in [12, 24], c3 in [4, 12]: K2 = 2 s^4 + 4 s^3 + 12 s^2 + 26 s + 7
    #   D1 = 4, D2 = 4*12 - 2*26 = -4, D3 = 26*(-4) - 16*7 = -216, D4 = 7*(-216) = -1512
    # K1 = 2 s^4 + 12 s^3 + 24 s^2 + 22 s + 5 (as above), K3 = 2 s^4 + 4 s^3 + 24 s^2 + 26 s + 5:
    #   D = 4, 96 - 52 = 44, 26*44 - 16*5 = 1064, 5320; K4 = 2 s^4 + 12 s^3 + 12 s^2 + 22 s + 7:
    #   D = 12, 144 - 44 = 100, 22*100 - 144*7 = 1192, 8344.
    res = kh.kharitonov_hurwitz([2, 4, 12, 22, 5], [2, 12, 24, 26, 7])
    assert_exact(res.polynomials[1], [2, 4, 12, 26, 7])  # picked from the bounds
    np.testing.assert_allclose(res.determinants[1], [4, -4, -216, -1512], rtol=1e-12)
    np.testing.assert_allclose(res.determinants[2], [4, 44, 1064, 5320], rtol=1e-12)
    np.testing.assert_allclose(res.determinants[3], [12, 100, 1192, 8344], rtol=1e-12)
    assert res.hurwitz == (True, False, True, True)
    assert not res.robustly_stable
    assert res.failing == ("K2: Delta_2 = -4",)
    assert "NOT robustly stable (K2: Delta_2 = -4)" in res.summary()
    assert not is_hurwitz(res.polynomials[1]) and np.max(np.roots(res.polynomials[1]).real) > 0
    # A leading interval through 0 lets the degree drop: not robustly stable, said so.
    res0 = kh.kharitonov_hurwitz([-1, 2, 3], [1, 3, 4])
    assert not res0.robustly_stable and res0.polynomials == ()
    assert "leading coefficient interval [-1, 1] contains 0" in res0.failing[0]


def test_gains_too_large_give_a_negative_hurwitz_determinant():
    # Loop 1: 1/(s+1) e^{-0.5 s}, Pade(1), PI 10 + 1/s: 0.25 s^3 - 1.25 s^2 + 10.75 s + 1 (D1 = -1.25).
    # Loop 2: the same plant with PI 1 + 0.5/s: 0.25 s^3 + s^2 + 1.875 s + 0.5 (stable).
    A = [[FOPDT(1.0, 1.0, 0.5), 0.0], [0.0, FOPDT(1.0, 1.0, 0.5)]]
    C = [(10.0, 1.0), (1.0, 0.5)]
    nominal = kh.characteristic_polynomial(A, C, delay="pade", pade_order=1)
    np.testing.assert_allclose(nominal, np.polymul([0.25, -1.25, 10.75, 1.0], [0.25, 1.0, 1.875, 0.5]),
                               rtol=1e-14)
    # Its D1 = a1 = -1.25 * 0.25 + 0.25 * 1.0 = -0.0625.
    assert hurwitz_determinants(nominal)[0] == pytest.approx(-0.0625, rel=1e-14)
    res = kh.mimo_kharitonov_test(A, C, 0.1, delay="pade", pade_order=1)
    assert res.nominal_hurwitz is False and not res.robustly_stable and res.exact_bounds
    # a1 (the s^7 coefficient) ranges over [-0.294, ...]: the K-polynomials with its lower end fail first.
    assert res.lower[1] == pytest.approx(-0.29418125, rel=1e-12)
    assert res.failing == ("K1: Delta_1 = -0.294181", "K3: Delta_2 = -0.461346", "K4: Delta_1 = -0.294181")
    assert "NOT robustly stable" in res.summary() and "nominal not Hurwitz" in res.summary()


# ----------------------------------------------------------------------------------------------
# Independent check: python-control closed loop
# ----------------------------------------------------------------------------------------------


def _control_block(e: TFElement, order: int):
    num, den = np.array([e.K]), np.array([1.0])
    for t in e.leads:
        num = np.polymul(num, [t, 1.0])
    for t in e.lags:
        den = np.polymul(den, [t, 1.0])
    return control.tf(num, den) * control.tf(*control.pade(e.L, order))


def test_roots_match_python_control_closed_loop_poles():
    els = {
        (0, 0): TFElement(K=2.0, lags=(10.0,), L=1.0),
        (0, 1): TFElement(K=0.5, lags=(15.0,), L=2.0),
        (1, 0): TFElement(K=-0.4, lags=(12.0,), L=3.0),
        (1, 1): TFElement(K=1.5, leads=(2.0,), lags=(8.0, 4.0), L=1.5),
    }
    A = [[els[0, 0], els[0, 1]], [els[1, 0], els[1, 1]]]
    C = [ParallelPID(1.2, 0.1, 0.5, 0.05), ParallelPID(0.8, 0.08)]
    order = 3
    blocks = [control.ss(control.tf([0.5, 1.2, 0.1], [0.05, 1.0, 0.0]), inputs="e1", outputs="u1"),
              control.ss(control.tf([0.8, 0.08], [1.0, 0.0]), inputs="e2", outputs="u2")]
    for (i, j), e in els.items():
        blocks.append(control.ss(_control_block(e, order), inputs=f"u{j + 1}", outputs=f"y{i + 1}{j + 1}"))
    blocks.append(control.summing_junction(inputs=["r1", "-y11", "-y12"], output="e1"))
    blocks.append(control.summing_junction(inputs=["r2", "-y21", "-y22"], output="e2"))
    cl = control.interconnect(blocks, inplist=["r1", "r2"], outlist=["y11", "y12", "y21", "y22"])
    eig = np.linalg.eigvals(cl.A)

    p = kh.characteristic_polynomial(A, C, delay="pade", pade_order=order)
    roots = np.roots(p)
    assert roots.size == eig.size == 20
    dist = np.abs(eig[:, None] - roots[None, :])
    i, j = linear_sum_assignment(dist)
    assert np.max(dist[i, j] / np.abs(eig[i])) < 1e-8
    np.testing.assert_allclose(np.real(np.poly(eig)), p / p[0], rtol=1e-8)
    assert np.max(roots.real) < 0  # this loop is stable
    cl_poles = kh.closed_loop_poles(A, C, pade_order=order)
    assert np.all(np.diff(cl_poles.real) >= 0)
    np.testing.assert_allclose(np.sort_complex(cl_poles), np.sort_complex(roots))


def test_decoupled_elements_match_the_decoupler():
    w = np.array([1e-4, 0.01, 0.1, 1.0])
    s = 1j * w
    for name, case in (("qts", 1), ("ccts", 1), ("ccts", 2), ("csts", 1)):
        dec = inverted_decoupler(preset(name), delay_compensation=True, case=case)
        A = kh.decoupled_elements(dec)
        assert A[0][1] == 0.0 and A[1][0] == 0.0
        for k, z in ((0, dec.z11), (1, dec.z22)):
            val = sum(np.polyval(t.num, s) / np.polyval(t.den, s) * np.exp(-t.L * s) for t in A[k][k])
            np.testing.assert_allclose(val, z(w), rtol=1e-12)


# ----------------------------------------------------------------------------------------------
# Interval bounds
# ----------------------------------------------------------------------------------------------

BOX_A = [[TFElement(K=2.0, lags=(10.0,), L=1.0), FOPDT(K=0.5, T=15.0, L=2.0)],
         [0.3, TFElement(K=1.5, leads=(2.0,), lags=(8.0,), L=1.5)]]
BOX_C = [(1.2, 0.1, 0.5, 0.05), (0.8, 0.08)]


@pytest.mark.parametrize(("delay", "order"), [("taylor", 2), ("pade", 1)])
def test_interval_bounds_contain_interior_samples_when_multilinear(delay, order):
    delta = {"K": 0.2, "T": 0.1, "L": 0.3}
    box = kh.parameter_box(BOX_A, delta)
    assert len(box) == 10 and box["a11.K"] == pytest.approx((1.6, 2.4))
    assert box["a22.lead0"] == pytest.approx((1.8, 2.2)) and box["a12.L"] == pytest.approx((1.4, 2.6))
    lo, hi = kh.interval_characteristic_bounds(BOX_A, BOX_C, delta, delay=delay, pade_order=order)
    nominal = kh.characteristic_polynomial(BOX_A, BOX_C, delay=delay, pade_order=order)
    assert lo.size == nominal.size and np.all(lo <= nominal) and np.all(nominal <= hi)
    scale = np.maximum(np.abs(lo), np.abs(hi))
    rng = np.random.default_rng(7)
    names = list(box)
    for _ in range(300):
        x = {n: rng.uniform(*box[n]) for n in names}
        c = kh.characteristic_polynomial(kh.perturbed_plant(BOX_A, x), BOX_C, delay=delay, pade_order=order)
        assert np.all(c >= lo - 1e-12 * scale) and np.all(c <= hi + 1e-12 * scale)
    res = kh.mimo_kharitonov_test(BOX_A, BOX_C, delta, delay=delay, pade_order=order)
    assert res.exact_bounds is True
    np.testing.assert_allclose(res.nominal, nominal)


def test_pade_order_two_vertex_bounds_are_only_an_inner_estimate():
    # The coefficients hold L^2 with Pade(2): an interior dead time leaves the vertex bounds
    # (documented limitation); interior samples widen the bounds.
    A = [[FOPDT(K=1.0, T=0.5, L=3.0), 0.0], [0.0, FOPDT(K=1.0, T=1.0, L=0.5)]]
    C = [(2.0, 1.0, 0.5, 0.05), (1.0, 0.5)]
    lo, hi = kh.interval_characteristic_bounds(A, C, {"L": 0.5}, delay="pade", pade_order=2)
    box = kh.parameter_box(A, {"L": 0.5})
    assert list(box) == ["a11.L", "a22.L"]
    outside = 0.0
    for L in np.linspace(*box["a11.L"], 201):
        c = kh.characteristic_polynomial(kh.perturbed_plant(A, {"a11.L": L}), C, delay="pade", pade_order=2)
        outside = max(outside, float(np.max(np.maximum(lo - c, c - hi) / np.maximum(np.abs(lo), np.abs(hi)))))
    assert outside == pytest.approx(0.0344, abs=1e-3)
    lo2, hi2 = kh.interval_characteristic_bounds(A, C, {"L": 0.5}, delay="pade", pade_order=2, samples=50)
    assert np.all(lo2 <= lo) and np.all(hi2 >= hi) and (np.any(lo2 < lo) or np.any(hi2 > hi))
    assert kh.mimo_kharitonov_test(A, C, {"L": 0.5}, delay="pade", pade_order=2).exact_bounds is False


# ----------------------------------------------------------------------------------------------
# Row-reduced Hurwitz matrix
# ----------------------------------------------------------------------------------------------


def test_row_reduced_diagonal_is_the_ratio_of_successive_hurwitz_determinants():
    rng = np.random.default_rng(3)
    polys = [HAND_N, kh.paper000_qts_chain("eq64"), *kh.PAPER000_EQ67_70, kh.PAPER000_EQ66]
    for n in (3, 5, 8):
        polys.append(np.poly(-rng.uniform(0.1, 3.0, n)))
    for p in polys:
        U = kh.row_reduced_hurwitz(p)
        d = hurwitz_determinants(p)
        assert np.allclose(np.tril(U, -1), 0.0)
        np.testing.assert_allclose(np.diag(U), d / np.r_[1.0, d[:-1]], rtol=1e-9)
        # Paper 000 prints the transpose (eq. 36, Table 4): same leading minors, same pivots.
        HT = hurwitz_matrix(p).T
        minors = [np.linalg.det(HT[:k, :k]) for k in range(1, HT.shape[0] + 1)]
        np.testing.assert_allclose(minors, d, rtol=1e-9)
    # A zero pivot stops the elimination: s^3 + s + 1 has D1 = a1 = 0.
    U = kh.row_reduced_hurwitz([1.0, 0.0, 1.0, 1.0])
    assert U[0, 0] == 0.0 and np.all(np.isnan(U[1:]))


# ----------------------------------------------------------------------------------------------
# Paper 000: eq. 59-70 and the printed controllers
# ----------------------------------------------------------------------------------------------


def _mantissa(x: float) -> float:
    """|x| with its power of ten shifted to three integer digits, to one decimal."""
    return round(abs(x) / 10 ** (math.floor(math.log10(abs(x))) - 2), 1)


def test_paper_qts_chain_and_eq66():
    eq62 = kh.paper000_qts_chain("eq62")
    eq59 = kh.paper000_qts_chain("eq59")
    eq64 = kh.paper000_qts_chain("eq64")
    for p in (eq62, eq59, eq64, kh.paper000_qts_chain("eq62", off_diagonal=0.0)):
        assert p.size == 7  # degree 6
    # Eqs. 62-63 as printed (found):
    np.testing.assert_allclose(eq62, [-859243.334, -5896701.01, -10195696.2, -376050.133, -202.448014,
                                      59.8817513, 0.342615583], rtol=1e-8)
    np.testing.assert_allclose(eq59, [-859315.670, -5896992.30, -10197237.6, -380513.697, -330.326199,
                                      61.1284533, 0.358844742], rtol=1e-8)
    # Eq. 64's printed diagonal entries (sign error on the s terms, 0.129 for loop 2):
    np.testing.assert_allclose(eq64, [-859245.776, -5896513.67, -10194530.3, -408507.092, -485.818895,
                                      -129.858225, 0.342075], rtol=1e-8)
    printed = [_mantissa(c) for c in kh.PAPER000_EQ66]  # 859.2 589.7 101.9 408.5 485.8 129.9 342.1
    # Eq. 66 does not follow from eqs. 62-63: only the first two mantissas agree.
    assert [_mantissa(c) for c in eq62] == [859.2, 589.7, 102.0, 376.1, 202.4, 598.8, 342.6]
    assert eq62[5] > 0 and eq64[5] < 0
    # Eq. 66 is eq. 64's polynomial with the signs and the powers of ten dropped, to every digit.
    assert [_mantissa(c) for c in eq64] == printed
    np.testing.assert_allclose(np.abs(eq64) / kh.PAPER000_EQ66, [1e3, 1e4, 1e5, 1e3, 1, 1, 1], rtol=5e-4)
    # None of them is Hurwitz: sign changes, roots in the right half-plane.
    for p in (eq62, eq59, eq64, kh.PAPER000_EQ66):
        assert not is_hurwitz(p)
    assert np.max(np.roots(eq62).real) == pytest.approx(0.0128532, rel=1e-4)
    r66 = np.roots(kh.PAPER000_EQ66)
    assert np.max(r66.real) == pytest.approx(0.492247, rel=1e-5)
    assert np.max(np.abs(r66[r66.real > 0].imag)) == pytest.approx(0.717752, rel=1e-5)
    # Even with a zero coupling (the decoupled reading) the Taylor term leaves a spurious RHP root.
    assert not is_hurwitz(kh.paper000_qts_chain("eq62", off_diagonal=0.0))


def test_printed_kharitonov_polynomials_are_not_kharitonov_polynomials():
    K = kh.PAPER000_EQ67_70
    perm, bad = kh.kharitonov_pattern_mismatches(K)
    # For the best of the 24 labellings, 5 of the 7 powers violate the shared end points:
    # s^1 takes four different values (141.035, 210.779, 379.7, 172.376), s^2 splits 3-1, ...
    assert len(bad) == 5
    assert [b.split(":")[0] for b in bad] == ["s^0", "s^1", "s^2", "s^3", "s^5"]
    assert len(set(np.array(K)[:, 5])) == 4  # the s^1 coefficients
    # A box's own Kharitonov polynomials pass the check.
    ok = kh.kharitonov_hurwitz([1, 2, 3, 4, 5, 6, 7], [1, 3, 4, 5, 6, 7, 8]).polynomials
    assert kh.kharitonov_pattern_mismatches(ok) == ((0, 1, 2, 3), [])
    # Monic with constants 205.6-307.1; eq. 66 has leading 859.2 and constant 0.3421, and even
    # normalised to monic it lies outside the box the printed K's span (constant 3.98e-4).
    lo, hi = np.min(K, axis=0), np.max(K, axis=0)
    assert kh.PAPER000_EQ66[0] > hi[0]
    normalised = kh.PAPER000_EQ66 / kh.PAPER000_EQ66[0]
    assert normalised[-1] == pytest.approx(3.98e-4, rel=1e-2) and normalised[-1] < lo[-1]
    # None of the printed K1..K4 is Hurwitz (the paper says all four are).
    max_re = [np.max(np.roots(k).real) for k in K]
    np.testing.assert_allclose(max_re, [0.163192, 0.476453, 0.582783, 0.362813], rtol=1e-5)
    # Table 4 prints K1's row-reduced diagonal 46.4 112 111 208.3 101 101 (all positive);
    # the printed K1 gives a negative pivot.
    np.testing.assert_allclose(np.diag(kh.row_reduced_hurwitz(K[0])),
                               [31.06, 112.346, 37.997, 44.371, -91.855, 205.585], rtol=1e-4)


def _fopdt_loops(case):
    return [FOPDT(*p) for p in kh.PAPER000_FOPDT[case]], kh.PAPER000_PID[case]


# Largest real part of the closed-loop poles, Pade(10) delays, printed FOPDT loops (eq. 46-58).
FOPDT_MAX_RE = {"qts": (-0.0101888, -0.00814354), "ccts": (-0.0396744, -0.0785586), "csts": (-0.00719827, -0.0116169)}


@pytest.mark.parametrize("case", ["qts", "ccts", "csts"])
def test_printed_controllers_are_stable_on_the_printed_fopdt_loops(case):
    f, c = _fopdt_loops(case)
    for i in range(2):
        r10 = np.roots(kh.loop_polynomial(f[i], c[i], delay="pade", pade_order=10))
        r14 = np.roots(kh.loop_polynomial(f[i], c[i], delay="pade", pade_order=14))
        assert np.max(r10.real) == pytest.approx(FOPDT_MAX_RE[case][i], rel=1e-5)
        assert np.max(r14.real) == pytest.approx(np.max(r10.real), rel=1e-8)  # converged in the order
    poles = kh.closed_loop_poles([[f[0], 0.0], [0.0, f[1]]], c, pade_order=10)
    assert poles[-1].real == pytest.approx(max(FOPDT_MAX_RE[case]), rel=1e-4)


def test_taylor_term_makes_the_qts_fopdt_loop_look_unstable():
    f, c = _fopdt_loops("qts")
    r = np.roots(kh.loop_polynomial(f[0], c[0], delay="taylor"))
    assert np.max(r.real) == pytest.approx(80.1931, rel=1e-5)  # spurious: Pade(10) above is stable


def _exact_root(terms, gains, s0):
    """Newton on the exact quasi-polynomial 1 + c(s) h(s) from a Pade root."""
    Kp, Ki, Kd = gains

    def F(s):
        h = sum(np.polyval(t.num, s) / np.polyval(t.den, s) * np.exp(-t.L * s) for t in terms)
        return 1.0 + (Kp + Ki / s + Kd * s) * h

    s = complex(s0)
    for _ in range(30):
        eps = 1e-7 * max(1.0, abs(s))
        s -= F(s) / ((F(s + eps) - F(s - eps)) / (2 * eps))
    return s, abs(F(s))


# Dominant closed-loop poles with the printed plants (eq. 44, 49, 54) and the inverted decoupler.
PLANT_DOMINANT = {"qts": (0.346808 + 0.493331j, 0.274532 + 0.399781j),
                  "ccts": (0.030055 + 0.144307j, 0.012353 + 0.115001j),
                  "csts": (-0.000253023, -0.000254383)}


@pytest.mark.parametrize("case", ["qts", "ccts", "csts"])
def test_printed_controllers_on_the_printed_decoupled_plants(case):
    A = kh.decoupled_elements(inverted_decoupler(preset(case), delay_compensation=True))
    gains = kh.PAPER000_PID[case]
    for i in range(2):
        r = np.roots(kh.loop_polynomial(A[i][i], gains[i], delay="pade", pade_order=10))
        top = r[np.argmax(r.real + 1e-9 * r.imag)]
        expected = PLANT_DOMINANT[case][i]
        assert top.real == pytest.approx(expected.real, rel=1e-4)
        assert abs(top.imag) == pytest.approx(abs(expected.imag), rel=1e-4, abs=1e-9)
        s, residual = _exact_root(A[i][i], gains[i], top)  # a root of the exact (delayed) loop too
        assert residual < 1e-10 and abs(s - top) < 1e-5
    # QTS and CCTS: unstable (docs/tito.md); CSTS: stable.
    assert (max(PLANT_DOMINANT[case], key=lambda z: z.real).real > 0) == (case in ("qts", "ccts"))


# ----------------------------------------------------------------------------------------------
# Errors
# ----------------------------------------------------------------------------------------------

_A = [[FOPDT(1.0, 1.0, 0.5), 0.0], [0.0, FOPDT(1.0, 1.0, 0.5)]]
_C = [(1.0, 0.5), (1.0, 0.5)]


@pytest.mark.parametrize(("call", "needle"), [
    (lambda: kh.characteristic_polynomial([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], _C), "A must be"),
    (lambda: kh.characteristic_polynomial([[1.0, 2.0]], _C), "A must be"),
    (lambda: kh.characteristic_polynomial([["x", 0.0], [0.0, 1.0]], _C), "A[0][0]"),
    (lambda: kh.characteristic_polynomial(_A, [(1.0, 0.5)]), "controllers must be a pair"),
    (lambda: kh.characteristic_polynomial(_A, [(1.0, 0.5, 0.1, -1.0), (1.0, 0.5)]), "controllers[0]"),
    (lambda: kh.characteristic_polynomial(_A, [(1.0, float("nan")), (1.0, 0.5)]), "controllers[0]"),
    (lambda: kh.characteristic_polynomial(_A, _C, delay="exact"), "delay must be"),
    (lambda: kh.characteristic_polynomial(_A, _C, delay="pade", pade_order=0), "pade_order"),
    (lambda: kh.parameter_box(_A, 0.0), "delta"),
    (lambda: kh.parameter_box(_A, -0.1), "delta"),
    (lambda: kh.parameter_box(_A, 1.5), "delta"),
    (lambda: kh.parameter_box(_A, {"X": 0.1}), "unknown kind"),
    (lambda: kh.parameter_box(_A, {"K": 0.0}), "at least one positive"),
    (lambda: kh.parameter_box(_A, {"K": -0.2}), "delta['K']"),
    (lambda: kh.parameter_box(inverted_decoupler(preset("ccts")), 0.1), "Decoupler"),
    (lambda: kh.interval_characteristic_bounds(_A, _C, 0.1, samples=-1), "samples"),
    (lambda: kh.interval_characteristic_bounds([[1.0, 0.0], [0.0, 1.0]], _C, 0.1), "no parameter"),
    (lambda: kh.perturbed_plant(_A, {"a11.Q": 1.0}), "params"),
    (lambda: kh.kharitonov_hurwitz([1.0, 2.0], [0.0, 3.0]), "lower"),
    (lambda: kh.kharitonov_hurwitz([1.0, 2.0, 3.0], [1.0, 3.0]), "lower and upper"),
    (lambda: kh.kharitonov_hurwitz([1.0, 2.0], [1.0, 3.0], tol=-1.0), "tol"),
    (lambda: kh.DelayTerm([1.0], [0.0]), "DelayTerm.den"),
    (lambda: kh.DelayTerm([1.0], [1.0, 1.0], L=-1.0), "DelayTerm.L"),
    (lambda: kh.delay_approximation(-1.0), "L must be"),
    (lambda: kh.paper000_qts_chain("eq99"), "source"),
    (lambda: kh.kharitonov_pattern_mismatches([[1.0, 2.0]] * 3), "polys"),
])
def test_errors_are_one_line_and_name_the_argument(call, needle):
    with pytest.raises(ValueError) as info:
        call()
    assert isinstance(info.value, ConfigError)
    assert needle in str(info.value) and "\n" not in str(info.value)
