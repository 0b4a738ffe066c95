"""Numba kernels of the linearised integrator of the continuous-time QTP loop.

The loop in deviations from the operating point, ``Y = (xi, z)`` (plant state minus its
operating value, in state units, and the controller's state), is

    Y' = L Y + g + [r(xi); 0],

``L`` the whole loop linearised at the operating point (the plant's Jacobian, the static
feedback ``Dc``, the controller's input ``Bc``, dynamics ``Ac`` and drive ``Cc`` of the pumps),
``g`` the constant drive of a segment (operating voltages, disturbances, set-points) and ``r``
what the square-root outflows leave beyond their linearisation, second order in ``xi`` (written
without cancellation). ETDRK4 (Cox and Matthews) integrates ``L`` and ``g`` exactly and only
``r`` explicitly. The switching kernel (:mod:`~heurtune.objectives.qtp.continuous_kernels`)
integrates the plant and the feedback from the levels explicitly instead; where a loop
oscillates for the whole horizon its error constant is set by that feedback, here only by the
outflows' curvature (docs/model.md, "The linearised integrator").

Coordinates: the real modal ones of ``L``, from LAPACK ``dgeev`` with right eigenvectors: one
per real mode, two per complex-conjugate pair. Steps: ``h_top 2^-l``, each resolving
(``|lambda| h <= kappa``) only the modes whose transient still weighs in the level errors and
voltages (:func:`_step_level`); the others are integrated exactly and only the quadrature sees
them. Each stage is folded into tables per step level (what it reads of the modal state, and
4 x 4 products of the residuals), so that a step costs two thin products of the modal state,
its update and one readout. The metrics are the switching kernel's own helpers, folding each
step's end and midpoint (the method's dense output at theta = 1/2).

Not simulated here: saturation and level limits (the scenario refuses them with this
integrator), measurement noise (refused by every continuous scenario). Arrays and scalars in,
preallocated arrays out; float64 unless stated.
"""

import functools
import math

import numpy as np
from numba import njit
from numba.core.cpu import CPUTargetOptions

from heurtune.objectives.qtp.continuous_kernels import (
    _N_SIG,
    SEG_DIST,
    SEG_POST,
    SEG_REF,
    SEG_T0,
    SEG_UIN,
    _final_metrics,
    _measure,
    _nan_records,
    _signals,
    _simpson_step,
    _visit,
)
from heurtune.objectives.qtp.design_kernels import _N, _V, _data, _dgeev, _kept
from heurtune.objectives.qtp.kernels import (
    LEVEL_LIMIT,
    N_METRICS,
    P_COEF,
    P_HORIZON,
    P_T_DIST,
    P_UOP,
    STATUS_DIVERGED,
    STATUS_OK,
)

# IEEE arithmetic, no reference counting in the lane (as continuous_kernels, which says why).
_kernel = functools.partial(njit, cache=True, **({"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}))

# Step levels h_top 2^-l, l = 0 .. N_LEVELS - 1 (down to 1/2048 s: LADR's observer modes, -250
# and -660 rad/s in closed loop, resolved while their transients weigh); one more slot of tables
# for a segment's shortened last step. Tables are built for the levels a run takes.
N_LEVELS = 12
# Per level and mode, the step's diagonal coefficients (z = lambda h): E = e^z, E2 = e^(z/2),
# Q = h/2 phi_1(z/2), the weights F1, F2, F3 of N(y), N(a) + N(b), N(c) at the step's end, G1,
# G2, G3 at its midpoint (the dense output: phi_k(z) replaced by theta^k phi_k(theta z)), and
# the combinations the folded stages read: E2 Q - Q, E2 Q + Q, F1 + 2 F2 + F3, G1 + 2 G2 + G3.
N_COEF = 13
C_E, C_E2, C_Q, C_F1, C_F2, C_F3, C_G1, C_G2, C_G3, C_EQM, C_EQP, C_FK, C_GK = range(N_COEF)
# Rows of a level's thin tables LT (., n): V6 E2 (the plant and voltage rows of the basis times
# diag(E2), 6), V4 E (4), then (F1 o W), (F2 o W), (F3 o W) transposed (4 each).
LT_E2, LT_E, LT_F1, LT_F2, LT_F3 = 0, 6, 10, 14, 18
N_LT = 22
# Rows of a level's small matrices SM (., 4): V4 (Q o W), V4 ((E2 Q - Q) o W), V6 (G1 o W),
# V6 (G2 o W), V6 (G3 o W).
SM_Q, SM_C, SM_G1, SM_G2, SM_G3 = 0, 4, 8, 14, 20
N_SM = 26
# A segment's constants per level SC: V4 (Q o k), V4 ((E2 Q + Q) o k), V6 ((G1 + 2 G2 + G3) o k).
SC_Q, SC_C, SC_M = 0, 4, 8
N_SC = 14
# Which pump drives each tank's equation, and its coefficient's row in c: tank 1 pump 1 (c[6]),
# tank 2 pump 2 (c[7]), tank 3 pump 2 (c[8]), tank 4 pump 1 (c[9]).
_PUMP = (0, 1, 1, 0)
_PUMP_COEF = (6, 7, 8, 9)
# Below this |z| the phi functions are summed as Taylor series (20 terms: truncation < 1e-19).
_TAYLOR_BELOW = 1.0
_TAYLOR_TERMS = 20
_INV_FACT_3 = tuple(1.0 / math.factorial(j + 3) for j in range(_TAYLOR_TERMS))
# A modal basis conditioned worse than this (1-norm estimate of T times its inverse's) is not
# used: the caller runs the switching kernel for that candidate.
COND_LIMIT = 1e8


@njit(cache=True)
def loop_matrix(c, u_op, x_op, s, Ac, Bc, Cc, Dc):
    """``L`` of the module docstring: the loop linearised at the operating point.

    Parameters
    ----------
    c : (10,) plant coefficients; u_op : (2,) operating voltages; x_op : (4,) operating state;
    s : level per unit of state; Ac (nc, nc), Bc (nc, 4), Cc (2, nc), Dc (2, 4): the controller
    on the measured deviations ``w = s xi + d``.

    Returns
    -------
    (4 + nc, 4 + nc) ndarray
    """
    nc = Ac.shape[0]
    n = 4 + nc
    L = np.zeros((n, n))
    rt = np.sqrt(np.maximum(x_op, 0.0))
    L[0, 0] = -c[0] / (2.0 * rt[0])
    L[0, 2] = c[4] / (2.0 * rt[2])
    L[1, 1] = -c[1] / (2.0 * rt[1])
    L[1, 3] = c[5] / (2.0 * rt[3])
    L[2, 2] = -c[2] / (2.0 * rt[2])
    L[3, 3] = -c[3] / (2.0 * rt[3])
    for i in range(4):
        p = _PUMP[i]
        gain = c[_PUMP_COEF[i]]
        for j in range(4):
            L[i, j] += gain * s * Dc[p, j]
        for j in range(nc):
            L[i, 4 + j] = gain * Cc[p, j]
    for i in range(nc):
        for j in range(4):
            L[4 + i, j] = s * Bc[i, j]
        for j in range(nc):
            L[4 + i, 4 + j] = Ac[i, j]
    return L


@_kernel(inline="always")
def _phi3(z):
    """``(phi_0(z), .., phi_3(z))`` of a complex ``z`` (Taylor series below |z| = 1)."""
    if abs(z) < _TAYLOR_BELOW:
        p3 = 0.0 + 0.0j
        for j in range(_TAYLOR_TERMS - 1, -1, -1):
            p3 = p3 * z + _INV_FACT_3[j]
        p2 = 0.5 + z * p3
        p1 = 1.0 + z * p2
        return 1.0 + z * p1, p1, p2, p3
    e = np.exp(z)
    p1 = (e - 1.0) / z
    p2 = (p1 - 1.0) / z
    return e, p1, p2, (p2 - 0.5) / z


@_kernel(inline="always")
def _phi3_real(z):
    """:func:`_phi3` of a real ``z``, in real arithmetic (``expm1`` above the series)."""
    if abs(z) < _TAYLOR_BELOW:
        p3 = 0.0
        for j in range(_TAYLOR_TERMS - 1, -1, -1):
            p3 = p3 * z + _INV_FACT_3[j]
        p2 = 0.5 + z * p3
        p1 = 1.0 + z * p2
        return 1.0 + z * p1, p1, p2, p3
    p1 = math.expm1(z) / z
    p2 = (p1 - 1.0) / z
    return math.exp(z), p1, p2, (p2 - 0.5) / z


@_kernel(inline="always")
def _weights(p0, p1, p2, p3, q0, q1, q2, q3, hl):
    """The ``C_*`` coefficients of a step ``hl`` from ``phi_k(z)`` (p) and ``phi_k(z/2)`` (q), in
    their order (real or complex alike)."""
    qq = 0.5 * hl * q1
    f1, f2, f3 = hl * (p1 - 3.0 * p2 + 4.0 * p3), 2.0 * hl * (p2 - 2.0 * p3), hl * (4.0 * p3 - p2)
    g1, g2 = hl * (0.5 * q1 - 0.75 * q2 + 0.5 * q3), hl * (0.5 * q2 - 0.5 * q3)
    g3 = hl * (0.5 * q3 - 0.25 * q2)
    return (p0, q0, qq, f1, f2, f3, g1, g2, g3, q0 * qq - qq, q0 * qq + qq, f1 + 2.0 * f2 + f3,
            g1 + 2.0 * g2 + g3)


@_kernel
def _coefficients(lam_r, lam_i, n_real, hl, T, lv):
    """The diagonal coefficients ``C_*`` of a step ``hl`` into ``T[lv]`` (N_COEF, n): a real
    mode's value at its coordinate (real arithmetic), a pair's real and imaginary parts at its
    two."""
    for j in range(n_real):
        z = lam_r[j] * hl
        p0, p1, p2, p3 = _phi3_real(z)
        q0, q1, q2, q3 = _phi3_real(0.5 * z)
        k = 0
        for v in _weights(p0, p1, p2, p3, q0, q1, q2, q3, hl):
            T[lv, k, j] = v
            k += 1
    for j in range(n_real, lam_r.size, 2):
        z = complex(lam_r[j], lam_i[j]) * hl
        p0, p1, p2, p3 = _phi3(z)
        q0, q1, q2, q3 = _phi3(0.5 * z)
        k = 0
        for v in _weights(p0, p1, p2, p3, q0, q1, q2, q3, hl):
            T[lv, k, j] = v.real
            T[lv, k, j + 1] = v.imag
            k += 1


@_kernel(inline="always")
def _diag_vec(T, lv, kc, v, n_real, out):
    """``out = T[kc] o v`` (real on the real modes, complex on the pairs)."""
    for j in range(n_real):
        out[j] = T[lv, kc, j] * v[j]
    for j in range(n_real, v.size, 2):
        cr, ci = T[lv, kc, j], T[lv, kc, j + 1]
        out[j] = cr * v[j] - ci * v[j + 1]
        out[j + 1] = cr * v[j + 1] + ci * v[j]


@_kernel(inline="always")
def _root_excess(a, ra, xi):
    """``sqrt(max(a + xi, 0)) - sqrt(a) - xi / (2 sqrt(a))`` without cancellation (``ra = sqrt(a)``)."""
    b = a + xi
    if b <= 0.0:
        return -ra - xi / (2.0 * ra)
    sb = math.sqrt(b)
    d = sb + ra
    return -xi * xi / (2.0 * ra * d * d)


@_kernel(inline="always")
def _residual(x0, x1, x2, x3, x_op, rt, c):
    """The outflows beyond their linearisation at plant state ``x``, per tank equation."""
    e0 = _root_excess(x_op[0], rt[0], x0 - x_op[0])
    e1 = _root_excess(x_op[1], rt[1], x1 - x_op[1])
    e2 = _root_excess(x_op[2], rt[2], x2 - x_op[2])
    e3 = _root_excess(x_op[3], rt[3], x3 - x_op[3])
    return c[4] * e2 - c[0] * e0, c[5] * e3 - c[1] * e1, -c[2] * e2, -c[3] * e3


@_kernel(inline="always")
def _readout(V6, y, x_op, du_const, x, du):
    """Plant state ``x`` and voltage deviations ``du`` of modal state ``y`` (``V6`` (n, 6): the
    plant rows and the voltage rows of the real modal basis, transposed). Two partial sums per
    row (even and odd coordinates): two short chains of additions instead of one long one."""
    a0 = a1 = a2 = a3 = a4 = a5 = 0.0
    b0 = b1 = b2 = b3 = b4 = b5 = 0.0
    n = y.size
    j = 0
    while j + 1 < n:
        v = y[j]
        a0 += V6[j, 0] * v
        a1 += V6[j, 1] * v
        a2 += V6[j, 2] * v
        a3 += V6[j, 3] * v
        a4 += V6[j, 4] * v
        a5 += V6[j, 5] * v
        v = y[j + 1]
        b0 += V6[j + 1, 0] * v
        b1 += V6[j + 1, 1] * v
        b2 += V6[j + 1, 2] * v
        b3 += V6[j + 1, 3] * v
        b4 += V6[j + 1, 4] * v
        b5 += V6[j + 1, 5] * v
        j += 2
    if j < n:
        v = y[j]
        a0 += V6[j, 0] * v
        a1 += V6[j, 1] * v
        a2 += V6[j, 2] * v
        a3 += V6[j, 3] * v
        a4 += V6[j, 4] * v
        a5 += V6[j, 5] * v
    x[0] = x_op[0] + (a0 + b0)
    x[1] = x_op[1] + (a1 + b1)
    x[2] = x_op[2] + (a2 + b2)
    x[3] = x_op[3] + (a3 + b3)
    du[0] = du_const[0] + (a4 + b4)
    du[1] = du_const[1] + (a5 + b5)


@njit(cache=True)
def modal_form(L, s, Cc, Dc):
    """The real modal form of ``L``: LAPACK ``dgeev`` with right eigenvectors, the real modes
    first, then one coordinate pair per complex-conjugate pair of eigenvalues.

    ``T`` is dgeev's real basis: a real mode's eigenvector; for a pair ``a +- ib`` (b > 0), the
    real and imaginary parts ``P``, ``Q`` of the eigenvector of ``a + ib``. In the coordinates
    ``(p, q) = T^-1 Y`` of a pair, ``zeta = p - i q`` obeys ``zeta' = (a + ib) zeta`` and the state
    is ``P Re zeta - Q Im zeta``; the lane holds ``(Re zeta, Im zeta)`` at the pair's two
    coordinates, so the basis' second column and the inverse's second row are negated, and a
    pair's diagonal coefficients multiply as complex numbers.

    Returns
    -------
    ok : bool (False: LAPACK failed, or T is conditioned worse than COND_LIMIT)
    lam_r, lam_i : (n,) eigenvalue per coordinate (a pair's on both of its coordinates)
    n_real : int
    V6 : (n, 6) plant and voltage rows of the basis, transposed (a pair's second row negated)
    W : (n, 4) plant columns of the inverse (a pair's second row negated)
    Tinv : (n, n) the inverse, the same rows (the segment's constant drive)
    gain : (n,) the largest weight of a coordinate in the level errors and voltages
    """
    n = L.shape[0]
    nc = n - 4
    a = np.asfortranarray(L)
    wr, wi = np.empty(n), np.empty(n)
    vl = np.empty(1)
    vr = np.empty((n, n)).T  # Fortran order
    jobl = np.array([_N], dtype=np.uint8)
    jobr = np.array([_V], dtype=np.uint8)
    size, one = np.array([n], dtype=np.int32), np.ones(1, dtype=np.int32)
    lwork, info = np.array([max(4 * n, 1)], dtype=np.int32), np.zeros(1, dtype=np.int32)
    work = np.empty(max(4 * n, 1))
    _dgeev(_data(jobl), _data(jobr), _data(size), _data(a), _data(size), _data(wr), _data(wi), _data(vl),
           _data(one), _data(vr), _data(size), _data(work), _data(lwork), _data(info))
    _kept(jobl, jobr, size, a, wr, wi, vl, one, vr, work, lwork, info)
    lam_r, lam_i = np.zeros(n), np.zeros(n)
    T = np.empty((n, n))
    sign = np.ones(n)
    if info[0] != 0:
        return False, lam_r, lam_i, 0, np.zeros((n, 6)), np.zeros((n, 4)), np.zeros((n, n)), np.zeros(n)
    k = 0
    for j in range(n):  # real modes first
        if wi[j] == 0.0:
            lam_r[k] = wr[j]
            T[:, k] = vr[:, j]
            k += 1
    n_real = k
    j = 0
    while j < n:
        if wi[j] != 0.0:  # dgeev: columns j, j + 1 hold P, Q of the eigenvalue with wi[j] > 0
            lam_r[k] = lam_r[k + 1] = wr[j]
            lam_i[k] = lam_i[k + 1] = wi[j]
            T[:, k] = vr[:, j]
            T[:, k + 1] = vr[:, j + 1]
            sign[k + 1] = -1.0
            k += 2
            j += 2
        else:
            j += 1
    Tinv = np.linalg.inv(T)
    cond = np.abs(T).sum(axis=0).max() * np.abs(Tinv).sum(axis=0).max()
    ok = np.isfinite(cond) and cond <= COND_LIMIT
    V6 = np.zeros((n, 6))
    W = np.empty((n, 4))
    gain = np.zeros(n)
    for j in range(n):
        for r in range(4):
            V6[j, r] = sign[j] * T[r, j]
        for r in range(2):
            acc = 0.0
            for q in range(4):
                acc += s * Dc[r, q] * T[q, j]
            for q in range(nc):
                acc += Cc[r, q] * T[4 + q, j]
            V6[j, 4 + r] = sign[j] * acc
        for r in range(n):
            Tinv[j, r] *= sign[j]
        for r in range(4):
            W[j, r] = Tinv[j, r]
    for j in range(n):
        g = max(max(s * abs(V6[j, 0]), s * abs(V6[j, 1])), max(abs(V6[j, 4]), abs(V6[j, 5])))
        gain[j] = g
    for j in range(n_real, n, 2):  # a pair: the modulus of its two rows
        g = 0.0
        for r in (0, 1, 4, 5):
            f = s if r < 2 else 1.0
            g = max(g, f * math.hypot(V6[j, r], V6[j + 1, r]))
        gain[j] = gain[j + 1] = g
    return ok, lam_r, lam_i, n_real, V6, W, Tinv, gain


@_kernel
def _level_tables(lam_r, lam_i, n_real, V6, W, hl, T, LT, SM, lv, scr):
    """The coefficients, thin tables and small matrices of a step ``hl`` into slot ``lv``
    (``scr`` (4, n) scratch)."""
    n = lam_r.size
    _coefficients(lam_r, lam_i, n_real, hl, T, lv)
    for base, kc, rows in ((LT_E2, C_E2, 6), (LT_E, C_E, 4)):  # the basis' rows times diag(c)
        for r in range(rows):
            for j in range(n_real):
                LT[lv, base + r, j] = V6[j, r] * T[lv, kc, j]
            for j in range(n_real, n, 2):
                cr, ci = T[lv, kc, j], T[lv, kc, j + 1]
                LT[lv, base + r, j] = V6[j, r] * cr + V6[j + 1, r] * ci
                LT[lv, base + r, j + 1] = V6[j + 1, r] * cr - V6[j, r] * ci
    for base, kc in ((LT_F1, C_F1), (LT_F2, C_F2), (LT_F3, C_F3)):  # (c o W), transposed
        for col in range(4):
            for j in range(n_real):
                LT[lv, base + col, j] = T[lv, kc, j] * W[j, col]
            for j in range(n_real, n, 2):
                cr, ci = T[lv, kc, j], T[lv, kc, j + 1]
                LT[lv, base + col, j] = cr * W[j, col] - ci * W[j + 1, col]
                LT[lv, base + col, j + 1] = cr * W[j + 1, col] + ci * W[j, col]
    for base, kc, rows in ((SM_Q, C_Q, 4), (SM_C, C_EQM, 4), (SM_G1, C_G1, 6), (SM_G2, C_G2, 6),
                           (SM_G3, C_G3, 6)):
        for col in range(4):  # scr[col] = (c o W)[:, col]
            for j in range(n_real):
                scr[col, j] = T[lv, kc, j] * W[j, col]
            for j in range(n_real, n, 2):
                cr, ci = T[lv, kc, j], T[lv, kc, j + 1]
                scr[col, j] = cr * W[j, col] - ci * W[j + 1, col]
                scr[col, j + 1] = cr * W[j + 1, col] + ci * W[j, col]
        for r in range(rows):
            for col in range(4):
                acc = 0.0
                for j in range(n):
                    acc += V6[j, r] * scr[col, j]
                SM[lv, base + r, col] = acc


@_kernel
def _segment_constants(T, V6, k, n_real, lv, SC, KF, tmp):
    """The k terms of slot ``lv`` for a segment's constant drive ``k`` (``tmp`` (n,) scratch)."""
    n = k.size
    for base, kc, rows in ((SC_Q, C_Q, 4), (SC_C, C_EQP, 4), (SC_M, C_GK, 6)):
        _diag_vec(T, lv, kc, k, n_real, tmp)
        for r in range(rows):
            acc = 0.0
            for j in range(n):
                acc += V6[j, r] * tmp[j]
            SC[lv, base + r] = acc
    _diag_vec(T, lv, C_FK, k, n_real, tmp)
    for j in range(n):
        KF[lv, j] = tmp[j]


@_kernel(inline="always")
def _small(SM, lv, base, r, a0, a1, a2, a3):
    """``SM[lv, base + r] . a``."""
    return SM[lv, base + r, 0] * a0 + SM[lv, base + r, 1] * a1 + SM[lv, base + r, 2] * a2 + SM[lv, base + r, 3] * a3


@_kernel(inline="always")
def _step_level(y, N, lam_r, lam_i, gain, n_real, amp_floor, kappa, h_top, n_levels):
    """The step level ``l`` (step ``h = h_top 2^-l``) for the coming step: the longest step at
    which every mode is either resolved (``|lam| h <= kappa``) or light, its transient ``a_j =
    |y_j'| / |lam_j| = |lam_j y_j + N_j| / |lam_j|`` (its distance from where the present drive
    ``N`` holds it, weighted by its largest part in the level errors and voltages) such that
    ``a_j h <= amp_floor`` (cm s or V s: what Simpson's rule can miss of a transient that decays
    within the step). A light mode is integrated exactly and left to the quadrature."""
    h_ok = h_top
    for j in range(n_real):
        lam = abs(lam_r[j])
        a = abs(lam_r[j] * y[j] + N[j]) * gain[j]
        if lam * h_ok > kappa and a * h_ok > amp_floor * lam:
            h_ok = max(kappa / lam, amp_floor * lam / a)
    for j in range(n_real, y.size, 2):
        lam = math.hypot(lam_r[j], lam_i[j])
        if lam * h_ok > kappa:
            dr = lam_r[j] * y[j] - lam_i[j] * y[j + 1] + N[j]
            di = lam_r[j] * y[j + 1] + lam_i[j] * y[j] + N[j + 1]
            a = math.hypot(dr, di) * gain[j]
            if a * h_ok > amp_floor * lam:
                h_ok = max(kappa / lam, amp_floor * lam / a)
    lv = 0
    while lv < n_levels - 1 and h_top > h_ok * 2.0 ** lv:
        lv += 1
    return lv


@_kernel(inline="always")
def _start_metrics(w2, ex, wb, sig, band_pct, h_op):
    """Empty the metric accumulators of a lane's working arrays (``w2`` rows 5..12, ``ex``,
    ``wb``, ``sig``) and set the settling band."""
    u_prev, band = w2[5], w2[4]
    ex_prev, ex_out, ex_in = ex[0], ex[1], ex[2]
    ex_has_prev, pending = wb[0], wb[1]
    lo, hi = sig[3], sig[4]
    win_v, win_t = sig[5:8], sig[8, :3]
    for j in range(2):
        u_prev[j] = 0.0
        ex_has_prev[j] = False
        pending[j] = False
        for r in range(7):
            w2[6 + r, j] = 0.0
        for r in range(2):
            ex_prev[j, r] = 0.0
            ex_out[j, r] = -1.0
            ex_in[j, r] = 0.0
        band[j] = band_pct / 100.0 * h_op[j]
    for i in range(_N_SIG):
        lo[i] = math.inf
        hi[i] = -math.inf
        for r in range(3):
            win_v[r, i] = 0.0
    for r in range(3):
        win_t[r] = 0.0


@_kernel(inline="always")
def _operating_drive(c, x_op, rt, f_op):
    """``rt = sqrt(x_op)`` and the operating point's own drive ``f_op`` (zero up to rounding for an
    exact operating point)."""
    for i in range(4):
        rt[i] = math.sqrt(max(x_op[i], 0.0))
    f_op[0] = c[4] * rt[2] - c[0] * rt[0]
    f_op[1] = c[5] * rt[3] - c[1] * rt[1]
    f_op[2] = -c[2] * rt[2]
    f_op[3] = -c[3] * rt[3]


@_kernel(inline="always")
def _visit_node(t, x, du, s, d1, d2, h_op, u_op, post, n_win, w, f, w2, ex, wb, sig, first):
    """Measure a node (plant state ``x``, voltage deviations ``du``) into ``f`` and fold it into
    the extremes, overshoot, band exits and total variation; returns the new window count."""
    _measure(x, s, d1, d2, h_op, w)
    _signals(w, x, s, u_op, du, f)
    return _visit(t, f, post, w2[4], n_win, sig[8, :3], sig[5:8], sig[3], sig[4], w2[12], ex[0], ex[1], ex[2],
                  wb[0], wb[1], w2[11], w2[5], first)


@_kernel(inline="always")
def _simpson(t, hs, u_op, w2, sig):
    """:func:`~heurtune.objectives.qtp.continuous_kernels._simpson_step` on this lane's working
    arrays (``sig[0..2]`` the step's start, midpoint and end signals)."""
    _simpson_step(t, hs, u_op, sig[0], sig[1], sig[2], w2[6], w2[7], w2[8], w2[9], w2[10])


@_kernel(inline="always")
def _finish_metrics(diverged, n_taken, w2, ex, wb, sig, h_op, horizon, t_dist, metrics):
    """The metrics from the accumulators (NaN when the run diverged); returns (status, steps)."""
    if diverged:
        for i in range(N_METRICS):
            metrics[i] = math.nan
        return STATUS_DIVERGED, n_taken
    _final_metrics(h_op, horizon, t_dist, w2[4], w2[12], sig[2], sig[3], sig[4], w2[6], w2[7], w2[8], w2[9], w2[10],
                   w2[11], ex[0], ex[1], ex[2], wb[0], wb[1], metrics)
    return STATUS_OK, n_taken


@_kernel(inline="always")
def _segment_drive(row, d1, d2, c, f_op, u_op, Dc, Bc, Br, Dr, Tinv, du_const, k):
    """A segment's constant drive in modal form, ``k = T^-1 g`` with ``g = [f_op + Bp (u_op + uin
    + du_const); Bc d + Br r]``, and the voltage deviations ``du_const = Dc d + Dr r`` of its
    output disturbance ``d`` (set-points taken off) and set-points ``r`` (``row``: the segment's
    row of the step plan; ``Br``, ``Dr`` zero for a structure that does not read the reference)."""
    n = k.size
    r1 = row[SEG_REF]
    r2 = row[SEG_REF + 1]
    for j in range(2):
        du_const[j] = Dc[j, 0] * d1 + Dc[j, 1] * d2 + Dr[j, 0] * r1 + Dr[j, 1] * r2
    for j in range(n):
        k[j] = 0.0
    for i in range(4):
        p = _PUMP[i]
        gx = f_op[i] + c[_PUMP_COEF[i]] * (u_op[p] + row[SEG_UIN + p] + du_const[p])
        for j in range(n):
            k[j] += Tinv[j, i] * gx
    for q in range(n - 4):
        gz = Bc[q, 0] * d1 + Bc[q, 1] * d2 + Br[q, 0] * r1 + Br[q, 1] * r2
        if gz != 0.0:
            for j in range(n):
                k[j] += Tinv[j, 4 + q] * gz


@_kernel
def _dense(theta, hl, lam_r, lam_i, n_real, y, Ny, Nab, Nc, out):
    """The dense output of a step ``hl`` at ``t + theta hl`` in modal coordinates: ``out = E(theta)
    y + F1(theta) N(y) + F2(theta) (N(a) + N(b)) + F3(theta) N(c)``, each ``phi_k(z)`` of the
    step's weights replaced by ``theta^k phi_k(theta z)``."""
    t2 = theta * theta
    t3 = t2 * theta
    for j in range(n_real):
        p0, p1, p2, p3 = _phi3_real(lam_r[j] * (theta * hl))
        f1 = hl * (theta * p1 - 3.0 * t2 * p2 + 4.0 * t3 * p3)
        f2 = 2.0 * hl * (t2 * p2 - 2.0 * t3 * p3)
        f3 = hl * (4.0 * t3 * p3 - t2 * p2)
        out[j] = p0 * y[j] + f1 * Ny[j] + f2 * Nab[j] + f3 * Nc[j]
    for j in range(n_real, y.size, 2):
        p0, p1, p2, p3 = _phi3(complex(lam_r[j], lam_i[j]) * (theta * hl))
        f1 = hl * (theta * p1 - 3.0 * t2 * p2 + 4.0 * t3 * p3)
        f2 = 2.0 * hl * (t2 * p2 - 2.0 * t3 * p3)
        f3 = hl * (4.0 * t3 * p3 - t2 * p2)
        v = (p0 * complex(y[j], y[j + 1]) + f1 * complex(Ny[j], Ny[j + 1]) + f2 * complex(Nab[j], Nab[j + 1])
             + f3 * complex(Nc[j], Nc[j + 1]))
        out[j] = v.real
        out[j + 1] = v.imag


@_kernel(inline="always")
def _modal_drive(r0, r1, r2, r3, W, k, out):
    """``out = k + W r``: the modal drive of residuals ``r``."""
    for j in range(k.size):
        out[j] = k[j] + W[j, 0] * r0 + W[j, 1] * r1 + W[j, 2] * r2 + W[j, 3] * r3


@_kernel(inline="always")
def _record(i, x, du, s, e1, e2, u_op, y_rec, u_rec, h_rec):
    """Row ``i`` of the records: measured levels (``e``: the output disturbance and the
    set-point, both added to the level), voltages and plant state."""
    y_rec[i, 0] = s * x[0] + e1
    y_rec[i, 1] = s * x[1] + e2
    u_rec[i, 0] = u_op[0] + du[0]
    u_rec[i, 1] = u_op[1] + du[1]
    for j in range(4):
        h_rec[i, j] = x[j]


@_kernel
def linearised_lane(P, level_per_state, x_op, h_op, lam_r, lam_i, n_real, V6, W, Tinv, gain, Bc, Dc, Br, Dr, seg,
                    n_seg, band_pct, h_top, kappa, amp_floor, metrics, out_dt, y_rec, u_rec, h_rec, work):
    """The loop of one controller under one scenario: metrics, and the dense output on a grid.

    Parameters
    ----------
    P : (NP,) the scenario table (``kernels.scenario_table``: plant coefficients, operating
        voltages, event time, horizon; its saturation and clipping are not read)
    level_per_state : float
        Level per unit of plant state (1 for the level model).
    x_op, h_op : (4,) the operating state and levels
    lam_r .. gain : :func:`modal_form` of the loop matrix (:func:`loop_matrix`)
    Bc (nc, 4), Dc (2, 4) : the controller's input matrices in that loop matrix
    Br (nc, 2), Dr (2, 2) : its reference path on the deviations measured from the set-points
        (``LinearController.reference_feed``; zeros for a structure that does not read it)
    seg : (S, N_SEG) the step plan's segments (``continuous.StepPlan.table``: starts,
        disturbances, set-points; the steps are this lane's); n_seg : rows used
    band_pct : float
        Settling band in percent of the operating level.
    h_top, kappa, amp_floor : float
        The step rule (:func:`_step_level`).
    metrics : (N_METRICS,) output, in the order of ``kernels.METRIC_NAMES``
    out_dt : float; y_rec, u_rec : (M, 2), h_rec : (M, 4) the dense output at ``t = i out_dt``
        (measured levels, voltages, plant states), or 0 rows
    work : :func:`workspace` of the loop's size (initialised here)

    Returns
    -------
    status : int, STATUS_OK or STATUS_DIVERGED (metrics and the records left NaN)
    n_steps : int
    """
    c = P[P_COEF:P_COEF + 10]
    u_op = P[P_UOP:P_UOP + 2]
    t_dist, horizon = P[P_T_DIST], P[P_HORIZON]
    s = level_per_state
    n = lam_r.size
    state_limit = LEVEL_LIMIT / s
    T, LT, SM, SC, KF, scr, vec, w4, w2, ex, wb, sig, built = work
    y, Ny, k, tmp, Na, Nab, Nc, yd = vec[0], vec[1], vec[2], vec[3], vec[4], vec[5], vec[6], vec[7]
    x, x_mid, w, rt, f_op, xr = w4[0], w4[1], w4[2], w4[3], w4[4], w4[5]
    dur = w2[13]
    rec = y_rec.shape[0]
    k_rec = 0
    du0, du_mid, du_end, du_const = w2[0], w2[1], w2[2], w2[3]
    f0, fm, f1 = sig[0], sig[1], sig[2]
    n_levels = T.shape[0] - 1  # the last slot: a segment's shortened last step
    # a level's tables are built when a step first takes it (built[0]), its segment constants
    # when a segment first takes it (built[1]: the segment they were built for)
    for lv in range(n_levels + 1):
        built[0, lv] = 0
        built[1, lv] = -1
    for j in range(n):
        y[j] = 0.0
    for i in range(4):
        x[i] = x_op[i]
    _start_metrics(w2, ex, wb, sig, band_pct, h_op)
    _operating_drive(c, x_op, rt, f_op)
    n_taken = 0
    diverged = False
    first_node = True
    t = 0.0
    for sg in range(n_seg):
        d1 = seg[sg, SEG_DIST]
        d2 = seg[sg, SEG_DIST + 1]
        post = seg[sg, SEG_POST] > 0.0
        t = seg[sg, SEG_T0]
        t_end = horizon if sg == n_seg - 1 else seg[sg + 1, SEG_T0]
        _segment_drive(seg[sg], d1, d2, c, f_op, u_op, Dc, Bc, Br, Dr, Tinv, du_const, k)
        r1 = seg[sg, SEG_REF]
        r2 = seg[sg, SEG_REF + 1]
        _readout(V6, y, x_op, du_const, x, du0)
        n_win = _visit_node(t, x, du0, s, d1, d2, h_op, u_op, post, 0, w, f0, w2, ex, wb, sig, first_node)
        first_node = False
        while t < t_end:
            ry0, ry1, ry2, ry3 = _residual(x[0], x[1], x[2], x[3], x_op, rt, c)
            _modal_drive(ry0, ry1, ry2, ry3, W, k, Ny)
            lv = _step_level(y, Ny, lam_r, lam_i, gain, n_real, amp_floor, kappa, h_top, n_levels)
            hs = h_top / 2.0 ** lv
            last = t + hs >= t_end * (1.0 - 1e-14)
            if last:
                hs = t_end - t
                lv = n_levels
                _level_tables(lam_r, lam_i, n_real, V6, W, hs, T, LT, SM, lv, scr)
                _segment_constants(T, V6, k, n_real, lv, SC, KF, tmp)
            else:
                if built[0, lv] == 0:
                    _level_tables(lam_r, lam_i, n_real, V6, W, hs, T, LT, SM, lv, scr)
                    built[0, lv] = 1
                if built[1, lv] != sg:
                    _segment_constants(T, V6, k, n_real, lv, SC, KF, tmp)
                    built[1, lv] = sg
            # V6 E2 y and V4 E y: what the stages and the midpoint read of y
            p0 = p1 = p2 = p3 = p4 = p5 = 0.0
            q0 = q1 = q2 = q3 = 0.0
            for j in range(n):
                v = y[j]
                p0 += LT[lv, LT_E2, j] * v
                p1 += LT[lv, LT_E2 + 1, j] * v
                p2 += LT[lv, LT_E2 + 2, j] * v
                p3 += LT[lv, LT_E2 + 3, j] * v
                p4 += LT[lv, LT_E2 + 4, j] * v
                p5 += LT[lv, LT_E2 + 5, j] * v
                q0 += LT[lv, LT_E, j] * v
                q1 += LT[lv, LT_E + 1, j] * v
                q2 += LT[lv, LT_E + 2, j] * v
                q3 += LT[lv, LT_E + 3, j] * v
            b0 = x_op[0] + p0 + SC[lv, SC_Q]
            b1 = x_op[1] + p1 + SC[lv, SC_Q + 1]
            b2 = x_op[2] + p2 + SC[lv, SC_Q + 2]
            b3 = x_op[3] + p3 + SC[lv, SC_Q + 3]
            ra0, ra1, ra2, ra3 = _residual(b0 + _small(SM, lv, SM_Q, 0, ry0, ry1, ry2, ry3),
                                           b1 + _small(SM, lv, SM_Q, 1, ry0, ry1, ry2, ry3),
                                           b2 + _small(SM, lv, SM_Q, 2, ry0, ry1, ry2, ry3),
                                           b3 + _small(SM, lv, SM_Q, 3, ry0, ry1, ry2, ry3), x_op, rt, c)
            rb0, rb1, rb2, rb3 = _residual(b0 + _small(SM, lv, SM_Q, 0, ra0, ra1, ra2, ra3),
                                           b1 + _small(SM, lv, SM_Q, 1, ra0, ra1, ra2, ra3),
                                           b2 + _small(SM, lv, SM_Q, 2, ra0, ra1, ra2, ra3),
                                           b3 + _small(SM, lv, SM_Q, 3, ra0, ra1, ra2, ra3), x_op, rt, c)
            rc0, rc1, rc2, rc3 = _residual(
                x_op[0] + q0 + SC[lv, SC_C] + _small(SM, lv, SM_C, 0, ry0, ry1, ry2, ry3)
                + 2.0 * _small(SM, lv, SM_Q, 0, rb0, rb1, rb2, rb3),
                x_op[1] + q1 + SC[lv, SC_C + 1] + _small(SM, lv, SM_C, 1, ry0, ry1, ry2, ry3)
                + 2.0 * _small(SM, lv, SM_Q, 1, rb0, rb1, rb2, rb3),
                x_op[2] + q2 + SC[lv, SC_C + 2] + _small(SM, lv, SM_C, 2, ry0, ry1, ry2, ry3)
                + 2.0 * _small(SM, lv, SM_Q, 2, rb0, rb1, rb2, rb3),
                x_op[3] + q3 + SC[lv, SC_C + 3] + _small(SM, lv, SM_C, 3, ry0, ry1, ry2, ry3)
                + 2.0 * _small(SM, lv, SM_Q, 3, rb0, rb1, rb2, rb3), x_op, rt, c)
            s0, s1, s2, s3 = ra0 + rb0, ra1 + rb1, ra2 + rb2, ra3 + rb3
            # recorded grid points in [t, t + hs), from the step's start
            if k_rec < rec and k_rec * out_dt < t + hs - 1e-9 * hs:
                _modal_drive(ra0, ra1, ra2, ra3, W, k, Na)
                _modal_drive(rb0, rb1, rb2, rb3, W, k, Nab)
                for j in range(n):
                    Nab[j] += Na[j]
                _modal_drive(rc0, rc1, rc2, rc3, W, k, Nc)
                while k_rec < rec and k_rec * out_dt < t + hs - 1e-9 * hs:
                    _dense(max((k_rec * out_dt - t) / hs, 0.0), hs, lam_r, lam_i, n_real, y, Ny, Nab, Nc, yd)
                    _readout(V6, yd, x_op, du_const, xr, dur)
                    _record(k_rec, xr, dur, s, d1 + r1, d2 + r2, u_op, y_rec, u_rec, h_rec)
                    k_rec += 1
            # the midpoint's levels and voltages
            pm = (p0, p1, p2, p3, p4, p5)
            for r in range(6):
                v = (pm[r] + SC[lv, SC_M + r] + _small(SM, lv, SM_G1, r, ry0, ry1, ry2, ry3)
                     + _small(SM, lv, SM_G2, r, s0, s1, s2, s3) + _small(SM, lv, SM_G3, r, rc0, rc1, rc2, rc3))
                if r < 4:
                    x_mid[r] = x_op[r] + v
                else:
                    du_mid[r - 4] = du_const[r - 4] + v
            # the step's end
            for j in range(n_real):
                y[j] = (T[lv, C_E, j] * y[j] + KF[lv, j]
                        + LT[lv, LT_F1, j] * ry0 + LT[lv, LT_F1 + 1, j] * ry1 + LT[lv, LT_F1 + 2, j] * ry2
                        + LT[lv, LT_F1 + 3, j] * ry3
                        + LT[lv, LT_F2, j] * s0 + LT[lv, LT_F2 + 1, j] * s1 + LT[lv, LT_F2 + 2, j] * s2
                        + LT[lv, LT_F2 + 3, j] * s3
                        + LT[lv, LT_F3, j] * rc0 + LT[lv, LT_F3 + 1, j] * rc1 + LT[lv, LT_F3 + 2, j] * rc2
                        + LT[lv, LT_F3 + 3, j] * rc3)
            for j in range(n_real, n, 2):
                er, ei = T[lv, C_E, j], T[lv, C_E, j + 1]
                yr, yi = y[j], y[j + 1]
                for i in (0, 1):
                    e = er * yr - ei * yi if i == 0 else er * yi + ei * yr
                    m = j + i
                    y[m] = (e + KF[lv, m]
                            + LT[lv, LT_F1, m] * ry0 + LT[lv, LT_F1 + 1, m] * ry1 + LT[lv, LT_F1 + 2, m] * ry2
                            + LT[lv, LT_F1 + 3, m] * ry3
                            + LT[lv, LT_F2, m] * s0 + LT[lv, LT_F2 + 1, m] * s1 + LT[lv, LT_F2 + 2, m] * s2
                            + LT[lv, LT_F2 + 3, m] * s3
                            + LT[lv, LT_F3, m] * rc0 + LT[lv, LT_F3 + 1, m] * rc1 + LT[lv, LT_F3 + 2, m] * rc2
                            + LT[lv, LT_F3 + 3, m] * rc3)
            n_taken += 1
            _readout(V6, y, x_op, du_const, x, du_end)
            if not (abs(x[0]) + abs(x[1]) + abs(x[2]) + abs(x[3]) < state_limit):
                diverged = True
                break
            n_win = _visit_node(t + 0.5 * hs, x_mid, du_mid, s, d1, d2, h_op, u_op, post, n_win, w, fm, w2, ex, wb,
                                sig, False)
            n_win = _visit_node(t + hs, x, du_end, s, d1, d2, h_op, u_op, post, n_win, w, f1, w2, ex, wb, sig, False)
            _simpson(t, hs, u_op, w2, sig)
            t = t_end if last else t + hs
        if diverged:
            break
    if diverged:
        _nan_records(k_rec, rec, y_rec, u_rec, h_rec)
    else:  # the end point T
        while k_rec < rec:
            _record(k_rec, x, du_end, s, d1 + r1, d2 + r2, u_op, y_rec, u_rec, h_rec)
            k_rec += 1
    return _finish_metrics(diverged, n_taken, w2, ex, wb, sig, h_op, horizon, t_dist, metrics)


def workspace(n: int, n_levels: int = N_LEVELS) -> tuple:
    """The working arrays of :func:`linearised_lane` for a loop of ``n`` states.

    Parameters
    ----------
    n : int
        States of the loop (4 plant states and the controller's).
    n_levels : int, optional

    Returns
    -------
    tuple of ndarray
    """
    L = n_levels + 1
    return (np.empty((L, N_COEF, n)), np.empty((L, N_LT, n)), np.empty((L, N_SM, 4)), np.empty((L, N_SC)),
            np.empty((L, n)), np.empty((4, n)), np.empty((8, n)), np.empty((6, 4)), np.empty((14, 2)),
            np.empty((3, 2, 2)), np.empty((2, 2), dtype=np.bool_), np.empty((9, _N_SIG)),
            np.empty((2, L), dtype=np.int64))
