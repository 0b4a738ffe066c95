"""Numba kernels of the continuous-time QTP closed loop: exponential integration (ETDRK4).

The loop is ``Y' = L Y + N(x)`` with ``Y = (x, z)``: the plant state ``x`` (4) and the
controller states ``z``. The linear part holds the controller's own dynamics and the way its
states drive the pumps,

    L = [[0, Bp C], [0, Lambda]],    Lambda = diag(modal lam_i) (+) dense blocks A_q,

and ``N`` depends on the plant state alone: the square-root outflows, the operating and
disturbance voltages, the static feedback ``Bp D w`` and the controller's input ``B w``, with
``w`` the measured deviations. ``L`` is block upper triangular with a zero plant block, so
``phi_k(h L)`` is known from the controller's own ``phi`` functions::

    phi_k(h L) [v_x; v_z] = [v_x / k! + h Bp C phi_{k+1}(h Lambda) v_z;  phi_k(h Lambda) v_z]

and every stage costs O(number of modal states) (plus small matrix products for dense
blocks). Cox and Matthews' ETDRK4 is then exact for the controller's fast modes and their
effect on the levels, whatever their speed, and fourth order in the slow, nonlinear rest.
The Python side (:mod:`heurtune.objectives.qtp.continuous`) plans the steps; see
docs/model.md for the method, its step rule and its validation.

Arrays and scalars in, preallocated arrays out; shapes and dtypes float64 unless stated.
"""

import functools
import math
import threading

import numpy as np
from numba import njit
from numba.core.cpu import CPUTargetOptions

from heurtune.objectives.qtp.design_kernels import spectral_radius
from heurtune.objectives.qtp.kernels import (
    LEVEL_LIMIT,
    N_METRICS,
    P_CLIP,
    P_COEF,
    P_HMAX,
    P_HORIZON,
    P_SAT,
    P_T_DIST,
    P_UMAX,
    P_UMIN,
    P_UOP,
    STATUS_DIVERGED,
    STATUS_OK,
)

# phi_0 .. phi_4 are needed: the plant rows of phi_3(h L) read phi_4 of the controller.
N_PHI = 5
# Levels of the step table: step h 2^-l for l = 0 .. N_LEVELS - 1 (the graded first steps
# after a discontinuity go down to h / 16, whose half step is h / 32).
N_LEVELS = 6
# Steps after a discontinuity, as levels: h/16, h/16, h/8, h/4, h/2 (they add up to h).
GRADED_LEVELS = (4, 4, 3, 2, 1)
# Below this |z| phi_4 is summed as its Taylor series and the lower ones follow from it (the
# upward recurrence phi_{k+1} = (phi_k - 1/k!) / z cancels there); 20 terms leave a truncation
# under 1e-19.
_TAYLOR_BELOW = 1.0
_TAYLOR_TERMS = 20
_INV_FACT = (1.0, 1.0, 0.5, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0)
# 1 / (j + 4)! for the Taylor series of phi_4
_INV_FACT_4 = tuple(1.0 / math.factorial(j + 4) for j in range(_TAYLOR_TERMS))

# The kernels keep IEEE arithmetic (no fast-math licence). A jitted function that another one
# calls without inlining is compiled twice: on its own, and as a copy inside its caller's object
# code. A freshly compiled caller runs the first, the same caller loaded from numba's cache the
# second; with reassociation allowed LLVM optimises the two differently, and results parted at
# rounding level between a first run and later ones. Without the licence both copies compute
# the same values (tests/objectives/qtp/test_compiled_cache.py); the cost in speed is within
# the spread of this project's machine (docs/model.md, "Compiled once, the same numbers").
#
# The lane and what it calls allocate no array and return none: every array they touch comes
# in from the caller, which keeps it alive. They are compiled without numba's reference
# counting (``_nrt=False``), which would otherwise increment and decrement, atomically, the
# count of every view they take (a step level's tables, a working row), some thirty times a
# step: a fifth of the lane's time, by perf (docs/model.md, "No reference counting in the
# lane"). The arithmetic is unchanged, bit for bit. A numba without the option compiles them as
# before.
_kernel = functools.partial(njit, cache=True, **({"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}))


@_kernel
def phi_scalar(z, out):
    """``out[k] = phi_k(z)`` for k = 0 .. 4, ``phi_0 = exp``, ``phi_{k+1}(z) = (phi_k(z) - 1/k!) / z``.

    Below |z| = 1, phi_4 is summed as its Taylor series and the others follow downwards by
    ``phi_k = 1/k! + z phi_{k+1}`` (no cancellation); above, upwards from ``exp`` and ``expm1``."""
    if abs(z) < _TAYLOR_BELOW:
        # phi_4(z) = sum_j z^j / (j + 4)!, by Horner from the highest term
        p4 = 0.0
        for j in range(_TAYLOR_TERMS - 1, -1, -1):
            p4 = p4 * z + _INV_FACT_4[j]
        out[4] = p4
        for k in range(3, -1, -1):
            out[k] = _INV_FACT[k] + z * out[k + 1]
        return
    out[0] = math.exp(z)
    out[1] = math.expm1(z) / z
    for k in range(1, N_PHI - 1):
        out[k + 1] = (out[k] - _INV_FACT[k]) / z


@_kernel
def _matmul(A, B, out):
    """``out = A B`` for ``A`` (n, m), ``B`` (m, p); ``out`` must not alias either."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@_kernel
def _add_c_m_b(Cq, M, Bq, tmp, out):
    """``out += Cq (M Bq)`` for ``Cq`` (2, n), ``M`` (n, n), ``Bq`` (n, 4); ``tmp`` (n, 4) scratch."""
    _matmul(M, Bq, tmp)
    for r in range(2):
        for j in range(4):
            acc = 0.0
            for i in range(Cq.shape[1]):
                acc += Cq[r, i] * tmp[i, j]
            out[r, j] += acc


# Horner terms of the phi_4 series at a scaled argument of 1-norm at most 1/2: the first
# neglected term is below 0.5^14 / 18! (2e-21).
_HORNER_TERMS = 14


@_kernel
def _phi_scaled(A, h, min_power, phi, X, T):
    """``phi[k] = phi_k(h 2^-s A)`` (k = 0 .. 4) for the least ``s >= min_power`` at which the
    argument's 1-norm is at most 1/2; returns ``s``. ``phi`` (N_PHI, n, n); ``X``, ``T`` (n, n)
    scratch.

    The series is summed as ``phi_4`` by Horner, then ``phi_k = I / k! + X phi_{k+1}``.
    """
    n = A.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(A[i, j])
        norm = max(norm, col)
    norm *= h
    s = min_power
    while norm / 2.0 ** s > 0.5:
        s += 1
    scale = h / 2.0 ** s
    for i in range(n):
        for j in range(n):
            X[i, j] = A[i, j] * scale
    P = phi[4]
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.0
        P[i, i] = 1.0 / _fact(_HORNER_TERMS + 4)
    for term in range(_HORNER_TERMS - 1, -1, -1):
        _matmul(X, P, T)
        f = 1.0 / _fact(term + 4)
        for i in range(n):
            for j in range(n):
                P[i, j] = T[i, j]
            P[i, i] += f
    for k in range(3, -1, -1):
        _matmul(X, phi[k + 1], phi[k])
        for i in range(n):
            phi[k, i, i] += _INV_FACT[k]
    return s


@_kernel
def _phi_double(phi, new):
    """``new[k] = phi_k(2X)`` from ``phi[k] = phi_k(X)``:
    ``phi_k(2X) = 2^-k (phi_0(X) phi_k(X) + sum_{j=1..k} phi_j(X) / (k-j)!)``."""
    n = phi.shape[1]
    for k in range(N_PHI):
        _matmul(phi[0], phi[k], new[k])
        scale = 1.0 / 2.0 ** k
        for a in range(n):
            for b in range(n):
                acc = new[k, a, b]
                for j in range(1, k + 1):
                    acc += phi[j, a, b] * _INV_FACT[k - j]
                new[k, a, b] = acc * scale


@_kernel
def _phi_at(A, h, phw, sqw):
    """``phi_k(h A)`` by scaling and squaring in the buffers ``phw`` (2, N_PHI, n, n); returns
    the index of the buffer that holds it. ``sqw`` (2, n, n) scratch."""
    level = _phi_scaled(A, h, 0, phw[0], sqw[0], sqw[1])
    cur = 0
    while level > 0:
        _phi_double(phw[cur], phw[1 - cur])
        cur = 1 - cur
        level -= 1
    return cur


def phi_matrix_levels(A, h, out):
    """``out[l, k] = phi_k(h 2^-l A)`` for l = 0 .. N_LEVELS - 1, k = 0 .. 4 (scaling and squaring).

    ``A`` (n, n); ``out`` (N_LEVELS, N_PHI, n, n). The argument is scaled by 2^-s until its
    1-norm is at most 1/2 (and at least to the finest level), the functions are summed as
    Taylor series there, and then doubled back with
    ``phi_k(2X) = 2^-k (phi_0(X) phi_k(X) + sum_{j=1..k} phi_j(X) / (k-j)!)``; the last
    N_LEVELS doublings are the levels. (The kernels run the same functions,
    :func:`_phi_scaled` and :func:`_phi_double`, level by level in their own buffers.)

    Parameters
    ----------
    A : ndarray (n, n)
    h : float
    out : ndarray (N_LEVELS, N_PHI, n, n)
        Written in place.
    """
    n = A.shape[0]
    if n == 0:
        return
    phw = np.empty((2, N_PHI, n, n))
    sqw = np.empty((2, n, n))
    level = _phi_scaled(np.ascontiguousarray(A, dtype=np.float64), float(h), N_LEVELS - 1, phw[0], sqw[0], sqw[1])
    cur = 0
    while True:
        if level < N_LEVELS:
            out[level] = phw[cur]
        if level == 0:
            break
        _phi_double(phw[cur], phw[1 - cur])
        cur = 1 - cur
        level -= 1


@_kernel
def _fact(n):
    f = 1.0
    for i in range(2, n + 1):
        f *= i
    return f


# Rows of the step table (see step_tables): controller state -> pump voltage after a phi
# function, at the half step c = h/2 and the full step h of each step level.
_R_C1, _R_C10, _R_C0, _R_H1, _R_H0 = 0, 2, 4, 6, 8
N_ROWS = 10
# Input couplings (2, 4) of the measured signals through the controller: C phi_k B at c for
# k = 1..4, C phi_1(c)^2 B at c, and C phi_k B at h for k = 1..4.
_G_C1, _G_C2, _G_C3, _G_C4, _G_C11, _G_H1, _G_H2, _G_H3, _G_H4 = range(9)
N_COUPLINGS = 9
# Step levels: a step of level l is h 2^-l, l = 0..4 (its half step is level l + 1).
N_STEP_LEVELS = N_LEVELS - 1
# Adaptive steps (a plan with a local tolerance, SEG_LOCAL_TOL > 0): the span's ladder of steps
# starts SEG_TOP levels (at most ADAPTIVE_TOP) above the rule's step; pairs use the levels above
# it, the rule's step and the graded steps (down to h / 16) the levels from it down.
ADAPTIVE_TOP = 4
MAX_STEP_LEVELS = ADAPTIVE_TOP + N_STEP_LEVELS
# Plain steps at the rule's step after no pair above it was kept, before the next try.
ADAPTIVE_WAIT = 16
# A pair of steps whose estimated error is below the local tolerance / ADAPTIVE_GROWTH takes
# twice the step next (a fourth-order step's local error grows 32-fold when doubled).
ADAPTIVE_GROWTH = 40.0
LOCAL_FLOOR = 1e-6
# No pairs once a level (cm) would come below this: the outflow's square root is not smooth
# near an empty tank, and step doubling misjudges a step across it.
ADAPTIVE_LOW_LEVEL = 1.0


@_kernel
def step_tables(lam, bm, mi, Cm, Aq, Bq, Cq, h, n_levels, lv_only, rows, coup, prop_m, prop_q, prop_qb, pmc, pmh,
                phw, sqw, rw, bw):
    """Everything an ETDRK4 step of the segment needs from the controller, per step level.

    Levels ``0 .. n_levels - 1``, or only ``lv_only`` when it is not negative (modal
    controllers only: the dense blocks' levels come from one sequence and are always written
    together). For each step level ``lv`` (step ``H = h 2^-lv``, half step ``c = H / 2``; Lambda the modal
    eigenvalues (+) the dense blocks, B the input matrix, C the output matrix) writes

    - ``rows[lv]`` (nd + nq, N_ROWS): ``C phi_1(c)``, ``C phi_1(c) phi_0(c)``, ``C phi_0(c)``,
      ``C phi_1(H)``, ``C phi_0(H)`` (two rows each), applied to the controller state;
    - ``coup[lv]`` (N_COUPLINGS, 2, 4): ``C phi_k(c) B`` (k = 1..4), ``C phi_1(c)^2 B``,
      ``C phi_k(H) B`` (k = 1..4), applied to measured signals;
    - ``prop_m[lv]`` (4, nd): ``phi_0(H)`` and ``phi_k(H) b`` (k = 1..3) of the modal states;
    - ``prop_q[lv]`` (nq, nq) ``phi_0(H)`` and ``prop_qb[lv]`` (3, nq, 4) ``phi_k(H) Bq`` of the dense
      part.

    Scratch: ``pmc``, ``pmh`` (N_PHI,); for the dense part ``phw`` (2, N_PHI, nq, nq), ``sqw``
    (2, nq, nq), ``rw`` (3, 2, nq) and ``bw`` (nq, 4). The dense blocks' phi functions come
    level by level from one scaling-and-squaring sequence at ``h 2^-m``, m from the finest
    level up: the one at ``h 2^-m`` is the half step of level m - 1 and the step of level m.
    """
    nd = lam.size
    nq = Aq.shape[0]
    lv_lo, lv_hi = (0, n_levels) if lv_only < 0 else (lv_only, lv_only + 1)
    for lv in range(lv_lo, lv_hi):
        H = h / 2.0 ** lv
        c = 0.5 * H
        for i in range(nd + nq):
            for r in range(N_ROWS):
                rows[lv, i, r] = 0.0
        for g in range(N_COUPLINGS):
            for r in range(2):
                for j in range(4):
                    coup[lv, g, r, j] = 0.0
        for i in range(nd):
            phi_scalar(c * lam[i], pmc)
            phi_scalar(H * lam[i], pmh)
            col = mi[i]
            for r in range(2):
                cr = Cm[r, i]
                rows[lv, i, _R_C1 + r] = cr * pmc[1]
                rows[lv, i, _R_C10 + r] = cr * pmc[1] * pmc[0]
                rows[lv, i, _R_C0 + r] = cr * pmc[0]
                rows[lv, i, _R_H1 + r] = cr * pmh[1]
                rows[lv, i, _R_H0 + r] = cr * pmh[0]
                cb = cr * bm[i]
                for k in range(1, 5):
                    coup[lv, _G_C1 + k - 1, r, col] += cb * pmc[k]
                    coup[lv, _G_H1 + k - 1, r, col] += cb * pmh[k]
                coup[lv, _G_C11, r, col] += cb * pmc[1] * pmc[1]
            prop_m[lv, 0, i] = pmh[0]
            for k in range(1, 4):
                prop_m[lv, k, i] = pmh[k] * bm[i]
    if nq == 0:
        return
    m = _phi_scaled(Aq, h, n_levels, phw[0], sqw[0], sqw[1])
    cur = 0
    while True:
        ph = phw[cur]  # phi_k(h 2^-m Aq)
        if 1 <= m <= n_levels:  # the half step of step level m - 1
            lv = m - 1
            _matmul(Cq, ph[1], rw[0])  # C phi_1(c)
            _matmul(rw[0], ph[0], rw[1])  # C phi_1(c) phi_0(c)
            _matmul(Cq, ph[0], rw[2])  # C phi_0(c)
            for r in range(2):
                for i in range(nq):
                    rows[lv, nd + i, _R_C1 + r] = rw[0, r, i]
                    rows[lv, nd + i, _R_C10 + r] = rw[1, r, i]
                    rows[lv, nd + i, _R_C0 + r] = rw[2, r, i]
            for k in range(1, 5):
                _add_c_m_b(Cq, ph[k], Bq, bw, coup[lv, _G_C1 + k - 1])
            _add_c_m_b(rw[0], ph[1], Bq, bw, coup[lv, _G_C11])
        if m <= n_levels - 1:  # the full step of step level m
            lv = m
            _matmul(Cq, ph[1], rw[0])
            _matmul(Cq, ph[0], rw[2])
            for r in range(2):
                for i in range(nq):
                    rows[lv, nd + i, _R_H1 + r] = rw[0, r, i]
                    rows[lv, nd + i, _R_H0 + r] = rw[2, r, i]
            for k in range(1, 5):
                _add_c_m_b(Cq, ph[k], Bq, bw, coup[lv, _G_H1 + k - 1])
            for i in range(nq):
                for j in range(nq):
                    prop_q[lv, i, j] = ph[0, i, j]
            for k in range(1, 4):
                _matmul(ph[k], Bq, prop_qb[lv, k - 1])
        if m == 0:
            break
        _phi_double(phw[cur], phw[1 - cur])
        cur = 1 - cur
        m -= 1


@_kernel(inline="always")
def _measure4(x0, x1, x2, x3, s, d1, d2, h_op):
    """Measured deviations of a plant state held in four scalars (levels ``s x``, disturbance
    on y1, y2); returns the four deviations."""
    return s * x0 + (d1 - h_op[0]), s * x1 + (d2 - h_op[1]), s * x2 - h_op[2], s * x3 - h_op[3]


@_kernel(inline="always")
def _measure(x, s, d1, d2, h_op, w):
    """:func:`_measure4` of plant state ``x`` into ``w``."""
    w[0], w[1], w[2], w[3] = _measure4(x[0], x[1], x[2], x[3], s, d1, d2, h_op)


@_kernel(inline="always")
def _plant_n4(x0, x1, x2, x3, w0, w1, w2, w3, c, v1, v2, Dc):
    """Plant rows of N at state ``x`` with measured deviations ``w`` (four scalars each):
    outflows, operating (and input disturbance) voltages ``v`` and the static feedback
    ``Dc w``."""
    u1 = v1 + Dc[0, 0] * w0 + Dc[0, 1] * w1 + Dc[0, 2] * w2 + Dc[0, 3] * w3
    u2 = v2 + Dc[1, 0] * w0 + Dc[1, 1] * w1 + Dc[1, 2] * w2 + Dc[1, 3] * w3
    s1 = math.sqrt(max(x0, 0.0))
    s2 = math.sqrt(max(x1, 0.0))
    s3 = math.sqrt(max(x2, 0.0))
    s4 = math.sqrt(max(x3, 0.0))
    return (c[4] * s3 - c[0] * s1 + c[6] * u1, c[5] * s4 - c[1] * s2 + c[7] * u2, c[8] * u2 - c[2] * s3,
            c[9] * u1 - c[3] * s4)


@_kernel(inline="always")
def _gw4(G, w0, w1, w2, w3, g, a0, a1):
    """``(a0, a1) + g G w`` for a (2, 4) coupling ``G`` and ``w`` in four scalars."""
    return (a0 + g * (G[0, 0] * w0 + G[0, 1] * w1 + G[0, 2] * w2 + G[0, 3] * w3),
            a1 + g * (G[1, 0] * w0 + G[1, 1] * w1 + G[1, 2] * w2 + G[1, 3] * w3))


@_kernel(inline="always")
def _gw(G, w, g, acc):
    """``acc += g G w`` for a (2, 4) coupling ``G`` (:func:`_gw4` on arrays)."""
    acc[0], acc[1] = _gw4(G, w[0], w[1], w[2], w[3], g, acc[0], acc[1])


@_kernel(inline="always")
def _pump4(y0, y1, y2, y3, c, v0, v1):
    """``y + Bp v`` for a plant state in four scalars, with ``Bp v = (c6 v1, c7 v2, c8 v2,
    c9 v1)``; returns the four components."""
    return y0 + c[6] * v0, y1 + c[7] * v1, y2 + c[8] * v1, y3 + c[9] * v0


@_kernel(inline="always")
def _add_pump(x, c, v0, v1, out):
    """``out = x + Bp v`` (:func:`_pump4` on arrays)."""
    out[0], out[1], out[2], out[3] = _pump4(x[0], x[1], x[2], x[3], c, v0, v1)


@_kernel(inline="always")
def _half_stage(x0, x1, x2, x3, n0, n1, n2, n3, w0, w1, w2, w3, e0, e1, G, half, hh, c, pm0, pm1, s, d1, d2,
                h_op, v1, v2, Dn):
    """A half-step stage of ETDRK4, ``E(h/2) Y_n + (h/2) phi_1(h/2 L) N_in`` (plant rows), from
    the plant state ``x`` at the step's start and the N and measured signals ``n``, ``w`` of the
    stage before (four scalars each). ``e0``, ``e1`` are the pumps' push ``(h/2) C phi_1(h/2) z``
    and ``G`` the coupling ``C phi_2(h/2) B``. Returns the stage's plant state, measured
    signals and plant rows of N (twelve scalars)."""
    a0, a1 = _gw4(G, w0, w1, w2, w3, hh, e0, e1)
    p0 = pm0 * a0
    p1 = pm1 * a1
    y0, y1, y2, y3 = _pump4(x0 + half * n0, x1 + half * n1, x2 + half * n2, x3 + half * n3, c, p0, p1)
    m0, m1, m2, m3 = _measure4(y0, y1, y2, y3, s, d1, d2, h_op)
    q0, q1, q2, q3 = _plant_n4(y0, y1, y2, y3, m0, m1, m2, m3, c, v1, v2, Dn)
    return y0, y1, y2, y3, m0, m1, m2, m3, q0, q1, q2, q3


@_kernel(inline="always")
def _p2_p3(vn, va, vb, vc):
    """ETDRK4's combinations of one component's stage values (start, a, b, c):
    ``P2 = -3 v_n + 2 (v_a + v_b) - v_c`` and ``P3 = 4 (v_n - v_a - v_b + v_c)``."""
    return -3.0 * vn + 2.0 * (va + vb) - vc, 4.0 * (vn - va - vb + vc)


@_kernel
def _etdrk4_step(x, z, h, rows, coup, prop_m, prop_q, prop_qb, mi, c, s, d1, d2, v1, v2, h_op, Dc, Dn, pm0, pm1,
                 scr, wst, x_new, z_new, x_mid, du_mid, du_end, full):
    """One ETDRK4 (Cox-Matthews) step of length ``h`` from plant state ``x`` and controller
    state ``z`` (modal states first, then dense), tables of the step's level from
    :func:`step_tables`.

    ``Dn`` is the static feedback as N sees it and ``pm0``, ``pm1`` (1 or 0) whether each
    pump's controller states push on the plant: a saturated pump has its row of ``Dn`` and its
    push at 0, and its voltage, the limit, in ``v``; ``Dc`` gives the controller outputs
    (unclipped, for the switching tests). The controller rows of N are ``B w`` (w the measured
    deviations at the stage), so every
    controller term reduces to the couplings of the tables applied to the stages' ``w``, and
    the controller state is read once, by the ``rows`` (one pass). Writes the state after the
    step (``x_new``, ``z_new``), the dense output at the midpoint (``x_mid``, controller output
    ``du_mid``) and the controller output at the end ``du_end``. After the step ``scr``
    (3, 4) holds N_x at the start, P2x and P3x, and ``wst`` (3, 4) the measured signals w_n,
    P2w, P3w, which :func:`_dense_at` reads. With ``full`` False only ``x_new`` and ``z_new`` are
    written (the double step of a step-doubling estimate).
    """
    nd = prop_m.shape[1]
    nz = z.size
    half = 0.5 * h
    hh = half * half
    # The stages live in scalars (the compiler keeps them in registers: working arrays, which
    # may alias one another, would be stored and loaded again between the dependent stages);
    # what the dense output reads afterwards is written to scr and wst at the end.
    # The controller state's five readings (two rows each), summed side by side: each in the
    # order of the states, as ten separate sums would, but without waiting on one another.
    r0 = r1 = r2 = r3 = r4 = r5 = r6 = r7 = r8 = r9 = 0.0
    for i in range(nz):
        zi = z[i]
        r0 += rows[i, 0] * zi
        r1 += rows[i, 1] * zi
        r2 += rows[i, 2] * zi
        r3 += rows[i, 3] * zi
        r4 += rows[i, 4] * zi
        r5 += rows[i, 5] * zi
        r6 += rows[i, 6] * zi
        r7 += rows[i, 7] * zi
        r8 += rows[i, 8] * zi
        r9 += rows[i, 9] * zi
    # (rows _R_C1, _R_C10, _R_C0, _R_H1, _R_H0 are r0/r1, r2/r3, r4/r5, r6/r7, r8/r9)
    # stage n
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    wn0, wn1, wn2, wn3 = _measure4(x0, x1, x2, x3, s, d1, d2, h_op)
    nn0, nn1, nn2, nn3 = _plant_n4(x0, x1, x2, x3, wn0, wn1, wn2, wn3, c, v1, v2, Dn)
    # E(h/2) Y_n, plant rows: x + (h/2) Bp C phi_1(h/2) z
    e0 = half * r0
    e1 = half * r1
    # a = E(h/2) Y_n + (h/2) phi_1(h/2 L) N_n, b = the same with N_a
    G = coup[_G_C2]
    xa0, xa1, xa2, xa3, wa0, wa1, wa2, wa3, na0, na1, na2, na3 = _half_stage(
        x0, x1, x2, x3, nn0, nn1, nn2, nn3, wn0, wn1, wn2, wn3, e0, e1, G, half, hh, c, pm0, pm1, s, d1, d2,
        h_op, v1, v2, Dn)
    _, _, _, _, wb0, wb1, wb2, wb3, nb0, nb1, nb2, nb3 = _half_stage(
        x0, x1, x2, x3, na0, na1, na2, na3, wa0, wa1, wa2, wa3, e0, e1, G, half, hh, c, pm0, pm1, s, d1, d2,
        h_op, v1, v2, Dn)
    # c = E(h/2) a + (h/2) phi_1(h/2 L) (2 N_b - N_n); the plant rows of E(h/2) a read
    # C phi_1(h/2) a_z with a_z = phi_0(h/2) z + (h/2) phi_1(h/2) B w_n
    a0, a1 = _gw4(coup[_G_C11], wn0, wn1, wn2, wn3, hh, half * r2, half * r3)
    a0, a1 = _gw4(G, 2.0 * wb0 - wn0, 2.0 * wb1 - wn1, 2.0 * wb2 - wn2, 2.0 * wb3 - wn3, hh, a0, a1)
    p0 = pm0 * a0
    p1 = pm1 * a1
    xc0, xc1, xc2, xc3 = _pump4(xa0 + half * (2.0 * nb0 - nn0), xa1 + half * (2.0 * nb1 - nn1),
                                xa2 + half * (2.0 * nb2 - nn2), xa3 + half * (2.0 * nb3 - nn3), c, p0, p1)
    wc0, wc1, wc2, wc3 = _measure4(xc0, xc1, xc2, xc3, s, d1, d2, h_op)
    nc0, nc1, nc2, nc3 = _plant_n4(xc0, xc1, xc2, xc3, wc0, wc1, wc2, wc3, c, v1, v2, Dn)
    # P2 = -3 N_n + 2 N_a + 2 N_b - N_c, P3 = 4 (N_n - N_a - N_b + N_c), for w and N_x
    q0, t0 = _p2_p3(wn0, wa0, wb0, wc0)
    q1, t1 = _p2_p3(wn1, wa1, wb1, wc1)
    q2, t2 = _p2_p3(wn2, wa2, wb2, wc2)
    q3, t3 = _p2_p3(wn3, wa3, wb3, wc3)
    px0, tx0 = _p2_p3(nn0, na0, nb0, nc0)
    px1, tx1 = _p2_p3(nn1, na1, nb1, nc1)
    px2, tx2 = _p2_p3(nn2, na2, nb2, nc2)
    px3, tx3 = _p2_p3(nn3, na3, nb3, nc3)
    # what the dense output and the controller update read: N_x at the start, P2x, P3x and the
    # measured signals w_n, P2w, P3w
    nx_n, p2x, p3x = scr[0], scr[1], scr[2]
    w_n, p2w, p3w = wst[0], wst[1], wst[2]
    nx_n[0], nx_n[1], nx_n[2], nx_n[3] = nn0, nn1, nn2, nn3
    p2x[0], p2x[1], p2x[2], p2x[3] = px0, px1, px2, px3
    p3x[0], p3x[1], p3x[2], p3x[3] = tx0, tx1, tx2, tx3
    w_n[0], w_n[1], w_n[2], w_n[3] = wn0, wn1, wn2, wn3
    p2w[0], p2w[1], p2w[2], p2w[3] = q0, q1, q2, q3
    p3w[0], p3w[1], p3w[2], p3w[3] = t0, t1, t2, t3
    # end of the step
    h2 = h * h
    a0, a1 = _gw4(coup[_G_H2], wn0, wn1, wn2, wn3, h2, h * r6, h * r7)
    a0, a1 = _gw4(coup[_G_H3], q0, q1, q2, q3, h2, a0, a1)
    a0, a1 = _gw4(coup[_G_H4], t0, t1, t2, t3, h2, a0, a1)
    p0 = pm0 * a0
    p1 = pm1 * a1
    x_new[0], x_new[1], x_new[2], x_new[3] = _pump4(
        x0 + h * (nn0 + 0.5 * px0 + tx0 * (1.0 / 6.0)), x1 + h * (nn1 + 0.5 * px1 + tx1 * (1.0 / 6.0)),
        x2 + h * (nn2 + 0.5 * px2 + tx2 * (1.0 / 6.0)), x3 + h * (nn3 + 0.5 * px3 + tx3 * (1.0 / 6.0)), c, p0, p1)
    for i in range(nd):
        col = mi[i]
        z_new[i] = prop_m[0, i] * z[i] + h * (prop_m[1, i] * w_n[col] + prop_m[2, i] * p2w[col]
                                              + prop_m[3, i] * p3w[col])
    for i in range(nz - nd):
        acc_i = 0.0
        for j in range(nz - nd):
            acc_i += prop_q[i, j] * z[nd + j]
        for j in range(4):
            acc_i += h * (prop_qb[0, i, j] * w_n[j] + prop_qb[1, i, j] * p2w[j] + prop_qb[2, i, j] * p3w[j])
        z_new[nd + i] = acc_i
    if not full:
        return  # the state at the end is all a step-doubling estimate reads
    u0, u1 = _gw4(coup[_G_H1], wn0, wn1, wn2, wn3, h, r8, r9)
    u0, u1 = _gw4(coup[_G_H2], q0, q1, q2, q3, h, u0, u1)
    u0, u1 = _gw4(coup[_G_H3], t0, t1, t2, t3, h, u0, u1)
    m0, m1, m2, m3 = _measure4(x_new[0], x_new[1], x_new[2], x_new[3], s, d1, d2, h_op)
    du_end[0], du_end[1] = _gw4(Dc, m0, m1, m2, m3, 1.0, u0, u1)
    # midpoint: the dense output at theta = 1/2 (see _dense_at), tables at h/2
    a0, a1 = _gw4(G, wn0, wn1, wn2, wn3, hh, e0, e1)
    a0, a1 = _gw4(coup[_G_C3], q0, q1, q2, q3, 0.5 * hh, a0, a1)
    a0, a1 = _gw4(coup[_G_C4], t0, t1, t2, t3, 0.25 * hh, a0, a1)
    p0 = pm0 * a0
    p1 = pm1 * a1
    xm0, xm1, xm2, xm3 = _pump4(
        x0 + half * (nn0 + 0.25 * px0 + tx0 * (1.0 / 24.0)), x1 + half * (nn1 + 0.25 * px1 + tx1 * (1.0 / 24.0)),
        x2 + half * (nn2 + 0.25 * px2 + tx2 * (1.0 / 24.0)), x3 + half * (nn3 + 0.25 * px3 + tx3 * (1.0 / 24.0)),
        c, p0, p1)
    x_mid[0], x_mid[1], x_mid[2], x_mid[3] = xm0, xm1, xm2, xm3
    u0, u1 = _gw4(coup[_G_C1], wn0, wn1, wn2, wn3, half, r4, r5)
    u0, u1 = _gw4(G, q0, q1, q2, q3, 0.5 * half, u0, u1)
    u0, u1 = _gw4(coup[_G_C3], t0, t1, t2, t3, 0.25 * half, u0, u1)
    m0, m1, m2, m3 = _measure4(xm0, xm1, xm2, xm3, s, d1, d2, h_op)
    du_mid[0], du_mid[1] = _gw4(Dc, m0, m1, m2, m3, 1.0, u0, u1)


@_kernel(inline="always")
def _switched(x, du, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua):
    """Whether a switching function (:func:`_event_values`) says an event has happened at a point."""
    _event_values(x, du, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua)
    for j in range(N_EVENTS):
        if g[j] > 0.0:
            return True
    return False


@_kernel
def _pair_switches(x1, u1, xm1, um1, x2, u2, xm2, um2, xb, ub, u_op, sat, asat, held, saturate, clip, u_min, u_max,
                   h_max, c, g, ua):
    """Whether a switching function has changed sign at a node of an adaptive pair: the mid
    and end points of its two steps and the end of the double step."""
    return (_switched(x1, u1, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua)
            or _switched(xm1, um1, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua)
            or _switched(x2, u2, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua)
            or _switched(xm2, um2, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua)
            or _switched(xb, ub, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua))


@_kernel(inline="always")
def _pair_error(x2, xb, z2, zb, lam, Cm, Cq, nd, nq, s, u_gain, local_per, h2):
    """Step doubling's estimate of a pair's local error (level units), per ``local_per`` seconds
    of step: the pair's end ``x2``, ``z2`` against the double step's ``xb``, ``zb``, their
    difference over 15 (fourth order). It reads the levels' difference and the controller
    states': each state's push on a pump (``u_gain``: the pump's largest effect on a level) acts
    on the levels for as long as it lasts, 1/|lam|, at most ``local_per`` seconds (an
    integrator's error stays until the loop corrects it; a fast mode's is gone within its time
    constant). ``h2`` is the double step's length."""
    est = 0.0
    for i in range(4):
        est = max(est, abs(x2[i] - xb[i]))
    est *= s
    for r in range(2):
        dv = 0.0
        for i in range(nd):
            lam_i = abs(lam[i])
            tau = local_per if lam_i * local_per <= 1.0 else 1.0 / lam_i
            dv += Cm[r, i] * (z2[i] - zb[i]) * tau
        for i in range(nq):
            dv += Cq[r, i] * (z2[nd + i] - zb[nd + i]) * local_per
        est = max(est, u_gain * abs(dv))
    return est * ((local_per / h2) / 15.0)


@_kernel(inline="always")
def _band_side(x, s, d1, d2, h_op, band, w):
    """Which errors lie outside their settling band at plant state ``x``: bit i for |e_i| > band_i."""
    _measure(x, s, d1, d2, h_op, w)
    return (1 if abs(w[0]) > band[0] else 0) + (2 if abs(w[1]) > band[1] else 0)


@_kernel
def _pair_crosses_band(x0, xm1, x1, xm2, x2, xb, s, d1, d2, h_op, band, w):
    """Whether an error crosses its settling band between the nodes of an adaptive pair (its
    start, the mid and end points of its two steps, the end of the double step)."""
    side = _band_side(x0, s, d1, d2, h_op, band, w)
    return (_band_side(xm1, s, d1, d2, h_op, band, w) != side or _band_side(x1, s, d1, d2, h_op, band, w) != side
            or _band_side(xm2, s, d1, d2, h_op, band, w) != side or _band_side(x2, s, d1, d2, h_op, band, w) != side
            or _band_side(xb, s, d1, d2, h_op, band, w) != side)


@_kernel(inline="always")
def _copy_rows(src, dst):
    """``dst[:] = src`` for (n, 4) working rows."""
    for r in range(src.shape[0]):
        for i in range(src.shape[1]):
            dst[r, i] = src[r, i]


@_kernel
def _pump_voltages(x, z, Cm, Cq, s, d1, d2, h_op, Dc, w, du):
    """Controller output ``du = C z + Dc w`` at state (x, z) (the operating voltage not added)."""
    nd = Cm.shape[1]
    _measure(x, s, d1, d2, h_op, w)
    du[0] = 0.0
    du[1] = 0.0
    _gw(Dc, w, 1.0, du)
    for i in range(nd):
        du[0] += Cm[0, i] * z[i]
        du[1] += Cm[1, i] * z[i]
    for i in range(Cq.shape[1]):
        du[0] += Cq[0, i] * z[nd + i]
        du[1] += Cq[1, i] * z[nd + i]


@_kernel
def _dense_at(theta, h, x, z, lam, bm, mi, Cm, Aq, Bq, Cq, c, s, d1, d2, h_op, Dc, pm0, pm1, scr, wst, w, x_out,
              du_out, ph, phw, sqw, vq):
    """Dense output at ``t_n + theta h`` of the step just taken from (x, z) by
    :func:`_etdrk4_step` (whose stage combinations are still in ``scr`` and ``wst``)::

        x(tau) = x + tau Bp C phi_1 z + tau (N_x + theta P2x / 2 + theta^2 P3x / 6)
                 + tau^2 Bp C (phi_2 B w_n + theta phi_3 B P2w + theta^2 phi_4 B P3w)
        z(tau) = phi_0 z + tau (phi_1 B w_n + theta phi_2 B P2w + theta^2 phi_3 B P3w),

    ``tau = theta h``, the phi functions of ``tau Lambda`` computed here (this serves the
    recorded trajectory, not the metrics). Writes the plant state ``x_out`` and the controller
    output ``du_out``. Scratch: ``ph`` (N_PHI,), and for the dense blocks ``phw``, ``sqw`` (as
    :func:`step_tables`) and ``vq`` (3, nq).
    """
    tau = theta * h
    nd = lam.size
    nq = Aq.shape[0]
    nx_n, p2x, p3x = scr[0], scr[1], scr[2]
    w_n, p2w, p3w = wst[0], wst[1], wst[2]
    g0 = 0.0
    g1 = 0.0  # C (tau phi_1 z + tau^2 (phi_2 B w_n + ...)): the controller's push on the levels
    cz0 = 0.0
    cz1 = 0.0  # C z(tau)
    t2 = theta * theta
    for i in range(nd):
        phi_scalar(tau * lam[i], ph)
        col = mi[i]
        b = bm[i]
        push = tau * ph[1] * z[i] + tau * tau * b * (ph[2] * w_n[col] + theta * ph[3] * p2w[col]
                                                     + t2 * ph[4] * p3w[col])
        zi = ph[0] * z[i] + tau * b * (ph[1] * w_n[col] + theta * ph[2] * p2w[col] + t2 * ph[3] * p3w[col])
        g0 += Cm[0, i] * push
        g1 += Cm[1, i] * push
        cz0 += Cm[0, i] * zi
        cz1 += Cm[1, i] * zi
    if nq > 0:
        tab = phw[_phi_at(Aq, tau, phw, sqw)]  # phi_k(tau Aq)
        bw, b2, b3 = vq[0], vq[1], vq[2]  # Bq w_n, Bq P2w, Bq P3w
        for i in range(nq):
            a0 = 0.0
            a2 = 0.0
            a3 = 0.0
            for j in range(4):
                a0 += Bq[i, j] * w_n[j]
                a2 += Bq[i, j] * p2w[j]
                a3 += Bq[i, j] * p3w[j]
            bw[i] = a0
            b2[i] = a2
            b3[i] = a3
        for i in range(nq):
            push = 0.0
            zt = 0.0
            for j in range(nq):
                zj = z[nd + j]
                push += tau * tab[1, i, j] * zj + tau * tau * (tab[2, i, j] * bw[j] + theta * tab[3, i, j] * b2[j]
                                                               + t2 * tab[4, i, j] * b3[j])
                zt += tab[0, i, j] * zj + tau * (tab[1, i, j] * bw[j] + theta * tab[2, i, j] * b2[j]
                                                 + t2 * tab[3, i, j] * b3[j])
            g0 += Cq[0, i] * push
            g1 += Cq[1, i] * push
            cz0 += Cq[0, i] * zt
            cz1 += Cq[1, i] * zt
    for i in range(4):
        x_out[i] = x[i] + tau * (nx_n[i] + 0.5 * theta * p2x[i] + t2 * p3x[i] / 6.0)
    _add_pump(x_out, c, pm0 * g0, pm1 * g1, x_out)
    _measure(x_out, s, d1, d2, h_op, w)
    du_out[0] = cz0
    du_out[1] = cz1
    _gw(Dc, w, 1.0, du_out)


# Signals followed at every node (step points and midpoints): |e1|, |e2|, the four levels, the
# two pump voltages (whose extremes are followed), then e1, e2 with their signs.
_N_EXT = 8
_N_SIG = 10


@_kernel(inline="always")
def _abs_moments(e0, em, e1):
    """``(int_0^1 |p|, int_0^1 s |p|)`` of the parabola p through e0, em, e1 at s = 0, 1/2, 1.

    Where the three have one sign this is Simpson's rule; where p changes sign it is split at
    its roots and integrated exactly, so that a zero crossing of the error inside a step costs
    no accuracy (IAE and ITAE of an oscillating response cross zero once per half period)."""
    if (e0 >= 0.0 and em >= 0.0 and e1 >= 0.0) or (e0 <= 0.0 and em <= 0.0 and e1 <= 0.0):
        a0, am, a1 = abs(e0), abs(em), abs(e1)
        return (a0 + 4.0 * am + a1) / 6.0, (2.0 * am + a1) / 6.0
    # p(s) = e0 + b s + c s^2
    b = -3.0 * e0 + 4.0 * em - e1
    c = 2.0 * e0 - 4.0 * em + 2.0 * e1
    r1 = 2.0
    r2 = 2.0
    if c == 0.0:
        if b != 0.0:
            r1 = -e0 / b
    else:
        disc = b * b - 4.0 * c * e0
        if disc >= 0.0:
            sq = math.sqrt(disc)
            q = -0.5 * (b + math.copysign(sq, b))
            ra = q / c
            rb = e0 / q if q != 0.0 else 2.0
            r1 = min(ra, rb)
            r2 = max(ra, rb)
    m0 = 0.0
    m1 = 0.0
    lo = 0.0
    for hi in (r1, r2, 1.0):
        if not (lo < hi <= 1.0):
            continue
        # int p and int s p over [lo, hi]
        i0 = (e0 * (hi - lo) + b * (hi * hi - lo * lo) / 2.0 + c * (hi ** 3 - lo ** 3) / 3.0)
        i1 = (e0 * (hi * hi - lo * lo) / 2.0 + b * (hi ** 3 - lo ** 3) / 3.0 + c * (hi ** 4 - lo ** 4) / 4.0)
        if i0 < 0.0:
            i0 = -i0
            i1 = -i1
        m0 += i0
        m1 += i1
        lo = hi
    return m0, m1


@_kernel(inline="always")
def _vertex(t0, f0, t1, f1, t2, f2):
    """Extreme value of the parabola through three nodes (``t0 < t1 < t2``), its vertex kept
    within [t0, t2]; ``f1`` when the three are collinear, or when two of them share a time (a
    step cut at a switch down to nothing)."""
    if not (t0 < t1 < t2):
        return f1
    s0 = (f1 - f0) / (t1 - t0)
    s1 = (f2 - f1) / (t2 - t1)
    curv = (s1 - s0) / (t2 - t0)
    if curv == 0.0:
        return f1
    tv = 0.5 * (t0 + t1) - s0 / (2.0 * curv)
    tv = min(max(tv, t0), t2)
    return f0 + s0 * (tv - t0) + curv * (tv - t0) * (tv - t1)


@_kernel(inline="always")
def _crossing(t0, f0, t1, f1, t2, f2, band, has_prev):
    """Time in [t1, t2] where the interpolant of the nodes crosses ``band`` (f1 > band >= f2):
    the parabola through (t0, t1, t2) when ``has_prev``, else the chord through t1 and t2 (the
    chord too where two of the nodes share a time: a step cut at a switch down to nothing)."""
    lin = t1 + (t2 - t1) * (f1 - band) / (f1 - f2) if f1 > f2 else t2
    if not has_prev or not (t0 < t1 < t2):
        return lin
    s0 = (f1 - f0) / (t1 - t0)
    s1 = (f2 - f1) / (t2 - t1)
    curv = (s1 - s0) / (t2 - t0)
    # p(t) = f1 + q (t - t1) + curv (t - t1)^2 with q the slope at t1 of that parabola
    q = s1 - curv * (t2 - t1)
    if curv == 0.0:
        return lin
    # solve curv r^2 + q r + (f1 - band) = 0 for r = t - t1 in [0, t2 - t1]: the smaller root there
    disc = q * q - 4.0 * curv * (f1 - band)
    if disc < 0.0:
        return lin
    sq = math.sqrt(disc)
    for r in ((-q - sq) / (2.0 * curv), (-q + sq) / (2.0 * curv)):
        if 0.0 <= r <= t2 - t1:
            return t1 + r
    return lin


@_kernel(inline="always")
def _simpson_step(t, hs, u_op, f0, fm, f1, iae, ise, itae, jj, jdev):
    """Simpson's rule over a step ``[t, t + hs]`` from the signals at its start, midpoint and end
    (``f0``, ``fm``, ``f1``), into the integrals IAE, ISE, ITAE, J, Jdev (IAE and ITAE split at
    the error's zero crossings, :func:`_abs_moments`); the end becomes the next step's start."""
    wq = hs / 6.0
    for i in range(2):
        m0, m1 = _abs_moments(f0[8 + i], fm[8 + i], f1[8 + i])
        iae[i] += hs * m0
        ise[i] += wq * (f0[i] * f0[i] + 4.0 * fm[i] * fm[i] + f1[i] * f1[i])
        itae[i] += hs * (t * m0 + hs * m1)
        a0 = f0[6 + i]
        am = fm[6 + i]
        a1 = f1[6 + i]
        jj[i] += wq * (a0 * a0 + 4.0 * am * am + a1 * a1)
        b0 = a0 - u_op[i]
        bmm = am - u_op[i]
        b1 = a1 - u_op[i]
        jdev[i] += wq * (b0 * b0 + 4.0 * bmm * bmm + b1 * b1)
    for i in range(_N_SIG):
        f0[i] = f1[i]


@_kernel(inline="always")
def _nan_records(k_rec, rec, y_rec, u_rec, h_rec):
    """Rows ``k_rec`` on of the records NaN (a run that diverged before them)."""
    for kk in range(k_rec, y_rec.shape[0]):
        for i in range(2):
            y_rec[kk, i] = math.nan
            u_rec[kk, i] = math.nan
        for i in range(4):
            h_rec[kk, i] = math.nan


@_kernel(inline="always")
def _final_metrics(h_op, horizon, t_dist, band, mp, f1, lo, hi, iae, ise, itae, jj, jdev, tv, ex_prev, ex_out,
                   ex_in, ex_has_prev, pending, metrics):
    """The metrics, in the order of ``kernels.METRIC_NAMES``, from a run's accumulators: the
    overshoot, the settling time from the last band exit (the parabola through its nodes), the
    final error, the integrals and the extremes (``f1``: the signals at the last node)."""
    for i in range(2):
        y0 = h_op[i]
        if ex_out[i, 0] < 0.0:
            ts = 0.0
        elif pending[i]:
            ts = horizon - t_dist
        else:
            ts = _crossing(ex_prev[i, 0], ex_prev[i, 1], ex_out[i, 0], ex_out[i, 1], ex_in[i, 0], ex_in[i, 1],
                           band[i], ex_has_prev[i]) - t_dist
        metrics[i] = mp[i] / y0 * 100.0
        metrics[2 + i] = ts
        metrics[4 + i] = f1[i] / y0 * 100.0
        metrics[6 + i] = iae[i]
        metrics[8 + i] = ise[i]
        metrics[10 + i] = itae[i]
        metrics[12 + i] = jj[i]
        metrics[14 + i] = jdev[i]
        metrics[16 + i] = tv[i]
    metrics[18] = min(min(lo[2], lo[3]), min(lo[4], lo[5]))
    metrics[19] = max(max(hi[2], hi[3]), max(hi[4], hi[5]))
    metrics[20] = min(lo[6], lo[7])
    metrics[21] = max(hi[6], hi[7])


# Switching: a pump is free (0) or saturated at its upper (+1) or lower (-1) limit; a tank is
# free (0) or held at its rim (+1) or its floor (-1). Event codes: 0, 1 the pumps, 2..5 the tanks.
N_EVENTS = 6
# Rows of the plant coefficients that a held tank's equation uses (outflow, inflow from above,
# pump gain), masked while it is held.
_TANK_COEFS = ((0, 4, 6), (1, 5, 7), (2, 8, -1), (3, 9, -1))
# Conditional integration can slide: a released pump whose free controller drives it straight
# back into saturation while its held controller would drift back inside (Filippov's sliding
# mode: the exact solution stays on the limit, its controller states moving at a fraction of
# their free rate). A pump that re-enters saturation within SLIDING_WINDOW steps of its release
# is sliding: its voltage is pinned at the limit, the loop is stepped at h/16, and at each step
# end its controller states are held (output beyond the limit) or integrate (output inside), so
# that their mean rate approximates Filippov's, to first order in the step. Its switches are
# not located (a located switch starts the next step on the limit, where every later decision
# would hang on rounding). It stops sliding when a held step moves its output further out (plain
# saturation) or a free step moves it further in (the pump leaves the limit).
SLIDING_WINDOW = 0.125
# Beyond this many located switches in one run, switches are taken at step ends without location.
MAX_LOCATED_EVENTS = 500
# Bisection steps of an event's location: 2^-52 of a step, below the rounding of t, so that
# runs whose states differ by rounding locate their switches within rounding of each other.
_LOCATE_ITERATIONS = 52


@_kernel
def _mode_arrays(sat, pin, asat, held, lam, bm, Aq, Bq, channel, c, Dc, u_op, uin, u_min, u_max,
                 lam_e, bm_e, Aq_e, Bq_e, c_e, Dn, v, pm):
    """The effective loop of a switching mode: the saturated pumps' controller states frozen
    (conditional integration: their eigenvalues and input gains 0); the saturated and the pinned
    (sliding) pumps' voltage the limit and their feedback and push 0; the held tanks' equations
    masked. Writes ``asat``, the limit each pump's voltage is at (0: none)."""
    nd = lam.size
    for i in range(nd):
        frozen = sat[channel[i]] != 0
        lam_e[i] = 0.0 if frozen else lam[i]
        bm_e[i] = 0.0 if frozen else bm[i]
    for i in range(Aq.shape[0]):
        # a reference state (channel REF_CHANNEL + j) has no dynamics to freeze
        frozen = channel[nd + i] < REF_CHANNEL and sat[channel[nd + i]] != 0
        for j in range(Aq.shape[1]):
            Aq_e[i, j] = 0.0 if frozen else Aq[i, j]
        for j in range(4):
            Bq_e[i, j] = 0.0 if frozen else Bq[i, j]
    for i in range(10):
        c_e[i] = c[i]
    for i in range(4):
        if held[i] != 0:
            for k in _TANK_COEFS[i]:
                if k >= 0:
                    c_e[k] = 0.0
    for j in range(2):
        asat[j] = sat[j] if sat[j] != 0 else pin[j]
        free = asat[j] == 0
        for k in range(4):
            Dn[j, k] = Dc[j, k] if free else 0.0
        pm[j] = 1.0 if free else 0.0
        lim = u_max if asat[j] > 0 else u_min
        v[j] = (u_op[j] if free else lim) + uin[j]


@_kernel(inline="always")
def _tank_slope(i, x, u1, u2, c):
    """dx_i/dt of tank i with the applied voltages (unmasked coefficients)."""
    s1 = math.sqrt(max(x[0], 0.0))
    s2 = math.sqrt(max(x[1], 0.0))
    s3 = math.sqrt(max(x[2], 0.0))
    s4 = math.sqrt(max(x[3], 0.0))
    if i == 0:
        return c[4] * s3 - c[0] * s1 + c[6] * u1
    if i == 1:
        return c[5] * s4 - c[1] * s2 + c[7] * u2
    if i == 2:
        return c[8] * u2 - c[2] * s3
    return c[9] * u1 - c[3] * s4


@_kernel
def _event_values(x, du, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g, ua):
    """Switching functions at a point (plant state ``x``, controller output ``du``): ``g[k] > 0``
    when event k has happened (a free pump outside its range, a saturated one back inside, a
    free tank past a limit, a held tank whose slope points back in; the voltages at the limits
    ``asat``). ``ua`` (2,) is scratch."""
    for j in range(N_EVENTS):
        g[j] = -1.0
    uc1 = u_op[0] + du[0]
    uc2 = u_op[1] + du[1]
    if saturate:
        for j in range(2):
            uc = uc1 if j == 0 else uc2
            if sat[j] == 0:
                g[j] = max(uc - u_max, u_min - uc)
            elif sat[j] > 0:
                g[j] = u_max - uc
            else:
                g[j] = uc - u_min
    if clip:
        _applied(du, u_op, asat, saturate, u_min, u_max, ua)
        u1 = u_op[0] + ua[0]
        u2 = u_op[1] + ua[1]
        for i in range(4):
            if held[i] == 0:
                g[2 + i] = max(x[i] - h_max[i], -x[i])
            elif held[i] > 0:
                g[2 + i] = -_tank_slope(i, x, u1, u2, c)
            else:
                g[2 + i] = _tank_slope(i, x, u1, u2, c)


# Columns of the segment table ``seg`` (S, N_SEG) of a step plan (continuous.StepPlan.table), one
# row per segment: start time, step, number of steps, whether the first step is graded (1.0 or
# 0.0), the output and input disturbances in force (2 each; the output one less the set-point
# step), whether the segment lies after the first level or set-point step (1.0 or 0.0), the
# adaptive pairs' settings and the set-point deviations in force (2).
SEG_T0, SEG_H, SEG_STEPS, SEG_GRADED, SEG_DIST, SEG_UIN, SEG_POST = 0, 1, 2, 3, 4, 6, 8
SEG_LOCAL_TOL, SEG_TOP, SEG_LOCAL_REL, SEG_LOCAL_PER, SEG_REF = 9, 10, 11, 12, 13
N_SEG = 15
# A dense controller state whose channel is REF_CHANNEL + j holds set-point deviation j: it has
# no dynamics (its row of Aq and Bq is zero), never freezes, and takes the segment's SEG_REF + j
# at each segment start (continuous.ContinuousController of a structure that reads the reference).
REF_CHANNEL = 2


@_kernel
def continuous_lane(P, level_per_state, x_init, h_op, lam, bm, mi, Cm, Aq, Bq, Cq, Dc, channel, seg, n_seg,
                    band_pct, metrics, out_dt, y_rec, u_rec, h_rec, n_rec, work):
    """The continuous-time closed loop of one lane (one controller under one scenario), by
    ETDRK4 on a planned grid, with its metrics: the step that every driver runs. Where the plan
    has a local tolerance (``SEG_LOCAL_TOL``), pairs of longer steps are taken where step
    doubling finds them within it (docs/model.md, "Adaptive steps").

    :func:`simulate_continuous` (one candidate), :func:`simulate_continuous_lanes` (many, on the
    CPU) and the CUDA kernel of :mod:`heurtune.objectives.qtp.gpu` (one thread a lane, this
    function compiled from its Python source as a device function) call it. It allocates
    nothing and calls only functions of this module and ``math``: its working arrays come in
    (shapes from :func:`workspace_shapes`) and are initialised here, so one set serves lane
    after lane.

    Parameters
    ----------
    As :func:`simulate_continuous`, and ``n_seg`` (rows used of ``seg``),
    ``n_rec`` (rows of the records to write) and ``work``, the tuple of working arrays in the
    order of :func:`workspace_shapes`.

    Returns
    -------
    status : int, STATUS_OK or STATUS_DIVERGED (metrics NaN, records NaN from there)
    n_steps : int, steps taken
    """
    c, u_op, h_max = P[P_COEF:P_COEF + 10], P[P_UOP:P_UOP + 2], P[P_HMAX:P_HMAX + 4]
    u_min, u_max = P[P_UMIN], P[P_UMAX]
    saturate, clip = P[P_SAT] > 0.0, P[P_CLIP] > 0.0
    t_dist, horizon = P[P_T_DIST], P[P_HORIZON]
    nd = lam.size
    nq = Aq.shape[0]
    nz = nd + nq
    s = level_per_state
    state_limit = LEVEL_LIMIT / s
    # the working arrays by name (rows of w4, w2, w10; see workspace_shapes)
    rows, coup, prop_m, prop_q, prop_qb, wz, wm, wq, wqb, w4, w2, w10, wi, wb, phw, sqw, rw, bw, vq = work
    x, x_new, x_mid, w, xr = w4[0], w4[1], w4[2], w4[3], w4[4]
    scr, wst, Dn = w4[5:8], w4[8:11], w4[11:13]
    # adaptive pairs: the second step's results, the double step's, and the stages of both steps
    x2, xm2, xb, xmb = w4[13], w4[14], w4[15], w4[16]
    scr1, wst1, scr2, wst2 = w4[17:20], w4[20:23], w4[23:26], w4[26:29]
    u_mid, u_end, du0, dur, v, pm = w2[0], w2[1], w2[2], w2[3], w2[4], w2[5]
    ue, ua, u_prev, t_release, band = w2[6], w2[7], w2[8], w2[9], w2[10]
    iae, ise, itae, jj, jdev, tv, mp = w2[11], w2[12], w2[13], w2[14], w2[15], w2[16], w2[17]
    ex_prev, ex_out, ex_in = w2[18:20], w2[20:22], w2[22:24]
    excess = w2[24]  # a sliding pump's output beyond its limit at the last step end
    um2, ue2, umb, ueb = w2[25], w2[26], w2[27], w2[28]
    f0, fm, f1, lo, hi, win_v = w10[0], w10[1], w10[2], w10[3], w10[4], w10[5:8]
    c_e, gm, g1, ga = w10[8], w10[9], w10[10], w10[11]
    win_t, pmc, pmh = w10[12], w10[13], w10[14]
    z, z_new, z2, zb = wz[0], wz[1], wz[2], wz[3]
    lam_e, bm_e = wm[0], wm[1]
    Aq_e, Bq_e = wq, wqb
    sat, held, pin, asat, ready = wi[0:2], wi[2:6], wi[6:8], wi[8:10], wi[10:]
    sliding, ex_has_prev, pending = wb[0], wb[1], wb[2]
    for i in range(4):
        x[i] = x_init[i]
    for i in range(nz):
        z[i] = 0.0
    for i in range(nd):
        lam_e[i] = lam[i]
        bm_e[i] = bm[i]
    for i in range(nq):
        for j in range(nq):
            Aq_e[i, j] = Aq[i, j]
        for j in range(4):
            Bq_e[i, j] = Bq[i, j]
    for i in range(10):
        c_e[i] = c[i]
    for r in range(2):
        for j in range(4):
            Dn[r, j] = Dc[r, j]
    for j in range(2):
        pm[j] = 1.0
        sat[j] = 0
        pin[j] = 0
        asat[j] = 0
        t_release[j] = -math.inf
        band[j] = band_pct / 100.0 * h_op[j]
        iae[j] = 0.0
        ise[j] = 0.0
        itae[j] = 0.0
        jj[j] = 0.0
        jdev[j] = 0.0
        tv[j] = 0.0
        mp[j] = 0.0
        for r in range(2):
            ex_prev[j, r] = 0.0
            ex_out[j, r] = -1.0
            ex_in[j, r] = 0.0
        sliding[j] = False
        ex_has_prev[j] = False
        pending[j] = False
    for i in range(4):
        held[i] = 0
    for i in range(_N_SIG):
        lo[i] = math.inf
        hi[i] = -math.inf
        for r in range(3):
            win_v[r, i] = 0.0
    for r in range(3):
        win_t[r] = 0.0
    switching = saturate or clip
    n_events = 0
    rec = n_rec
    k_rec = 0
    n_taken = 0
    diverged = False
    first_node = True
    for sg in range(n_seg):
        d1 = seg[sg, SEG_DIST]
        d2 = seg[sg, SEG_DIST + 1]
        post = seg[sg, SEG_POST] > 0.0
        uin = seg[sg, SEG_UIN:SEG_UIN + 2]
        t = seg[sg, SEG_T0]
        t_end = seg[sg, SEG_T0] + seg[sg, SEG_H] * int(seg[sg, SEG_STEPS])
        if sg == n_seg - 1:
            t_end = horizon
        h_target = seg[sg, SEG_H]
        graded = seg[sg, SEG_GRADED] > 0.0
        for i in range(nq):  # the set-points in force, for a structure that reads them
            if channel[nd + i] >= REF_CHANNEL:
                z[nd + i] = seg[sg, SEG_REF + channel[nd + i] - REF_CHANNEL]
        # the mode at the segment start: a jump of the measurement may push a pump across a limit
        _pump_voltages(x, z, Cm, Cq, s, d1, d2, h_op, Dc, w, du0)
        if saturate:
            for j in range(2):
                uc = u_op[j] + du0[j]
                sat[j] = 1 if uc > u_max else (-1 if uc < u_min else 0)
                sliding[j] = False  # a discontinuity ends a slide
                pin[j] = 0
        _mode_arrays(sat, pin, asat, held, lam, bm, Aq, Bq, channel, c, Dc, u_op, uin, u_min, u_max,
                     lam_e, bm_e, Aq_e, Bq_e, c_e, Dn, v, pm)
        _applied(du0, u_op, asat, saturate, u_min, u_max, ua)
        _signals(w, x, s, u_op, ua, f0)
        n_win = _visit(t, f0, post, band, 0, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in,
                       ex_has_prev, pending, tv, u_prev, first_node)
        first_node = False
        # Positions within a span count in units of its finest step (h/16 for fixed steps): the
        # graded steps (h/16, h/16, h/8, h/4, h/2 of the rule's step), a sliding pump's steps
        # (h/16), the plain steps (the rule's step, or the largest that keeps the position
        # aligned) and adaptive pairs all land on the span's grid and end on its end exactly.
        local_tol = seg[sg, SEG_LOCAL_TOL]
        local_rel = seg[sg, SEG_LOCAL_REL]
        local_per = seg[sg, SEG_LOCAL_PER]
        # cm per V s: the largest push of a pump voltage on a level
        u_gain = s * max(max(c[6], c[7]), max(c[8], c[9]))
        adaptive = local_tol > 0.0
        top = int(seg[sg, SEG_TOP]) if adaptive else 0
        n_levels = top + N_STEP_LEVELS
        fine = n_levels - 1
        lazy = adaptive and nq == 0  # modal tables are written level by level, when first used
        pos = 0
        units = 0
        gi = 0
        h = h_target
        lv_want = top - 1
        lv_pair = top
        wait = 0
        h_second = h_target
        stashed = False  # the second step of an accepted pair waits in x2, z2, ...
        replan = True
        # a span shorter than this (after a switch just before the segment's end) is not
        # stepped: its graded steps would fall below the resolution of t
        while t < t_end - 1e-9 * max(1.0, t_end):
            if replan:
                n_span = max(1, int(math.ceil((t_end - t) / (h_target * 2.0 ** top) - 1e-9)))
                h = (t_end - t) / n_span
                units = (1 << fine) * n_span
                pos = 0
                gi = 0
                lv_want = top - 1
                wait = 0
                stashed = False
                if lazy:
                    for lv in range(n_levels):
                        ready[lv] = 0
                else:
                    step_tables(lam_e, bm_e, mi, Cm, Aq_e, Bq_e, Cq, h, n_levels, -1, rows, coup, prop_m, prop_q,
                                prop_qb, pmc, pmh, phw, sqw, rw, bw)
                replan = False
            if stashed:
                # the second step of the pair accepted before
                level = lv_pair
                pos += 1 << (fine - level)
                hs = t_end - t if pos >= units else h_second
                for i in range(4):
                    x_new[i] = x2[i]
                    x_mid[i] = xm2[i]
                for i in range(nz):
                    z_new[i] = z2[i]
                for i in range(2):
                    u_mid[i] = um2[i]
                    u_end[i] = ue2[i]
                _copy_rows(scr2, scr)
                _copy_rows(wst2, wst)
                stashed = False
            else:
                paired = False
                if adaptive and not (graded and gi < 5) and not (sliding[0] or sliding[1]) and wait <= 0:
                    # Above the rule's step, a pair of steps at level lv < top is taken against
                    # one step of twice the length (step doubling): their difference over 15
                    # estimates the pair's local level error (fourth order). The pair is kept
                    # if that is within the pair's tolerance, else tried at half the step; at
                    # the rule's step the validated plain steps take over for a while.
                    lv = max(lv_want, 1)
                    while lv < top and (pos % (2 << (fine - lv)) != 0 or pos + (2 << (fine - lv)) > units):
                        lv += 1
                    lv0 = lv
                    # the pair's tolerance: local_tol, or local_rel times the largest measured
                    # deviation where that is smaller (an error then settles with the loop), not
                    # below LOCAL_FLOOR local_tol; the estimate counts per local_per seconds of step
                    _measure(x, s, d1, d2, h_op, w)
                    amp = max(max(abs(w[0]), abs(w[1])), max(abs(w[2]), abs(w[3])))
                    eps = max(min(local_tol, local_rel * amp), LOCAL_FLOOR * local_tol)
                    while lv < top:
                        if lazy:
                            for lv_t in range(lv - 1, lv + 1):
                                if ready[lv_t] == 0:
                                    step_tables(lam_e, bm_e, mi, Cm, Aq_e, Bq_e, Cq, h, n_levels, lv_t, rows, coup,
                                                prop_m, prop_q, prop_qb, pmc, pmh, phw, sqw, rw, bw)
                                    ready[lv_t] = 1
                        h1 = h / 2.0 ** lv
                        if pos + (2 << (fine - lv)) >= units:
                            h2 = t_end - t
                            h1b = h2 - h1
                        else:
                            h2 = 2.0 * h1
                            h1b = h1
                        _etdrk4_step(x, z, h1, rows[lv], coup[lv], prop_m[lv], prop_q[lv], prop_qb[lv], mi, c_e, s,
                                     d1, d2, v[0], v[1], h_op, Dc, Dn, pm[0], pm[1], scr, wst, x_new,
                                     z_new, x_mid, u_mid, u_end, True)
                        _copy_rows(scr, scr1)
                        _copy_rows(wst, wst1)
                        _etdrk4_step(x_new, z_new, h1b, rows[lv], coup[lv], prop_m[lv], prop_q[lv], prop_qb[lv], mi,
                                     c_e, s, d1, d2, v[0], v[1], h_op, Dc, Dn, pm[0], pm[1], scr, wst, x2,
                                     z2, xm2, um2, ue2, True)
                        _copy_rows(scr, scr2)
                        _copy_rows(wst, wst2)
                        lb = lv - 1
                        _etdrk4_step(x, z, h2, rows[lb], coup[lb], prop_m[lb], prop_q[lb], prop_qb[lb], mi, c_e, s,
                                     d1, d2, v[0], v[1], h_op, Dc, Dn, pm[0], pm[1], scr, wst, xb, zb,
                                     xmb, umb, ueb, switching)
                        if min(min(x2[0], x2[1]), min(x2[2], x2[3])) * s < ADAPTIVE_LOW_LEVEL or min(
                                min(xb[0], xb[1]), min(xb[2], xb[3])) * s < ADAPTIVE_LOW_LEVEL:
                            break  # near an empty tank the outflow sqrt(h) is not smooth
                        if post and _pair_crosses_band(x, x_mid, x_new, xm2, x2, xb, s, d1, d2, h_op, band, w):
                            break  # an error crossing its settling band: plain steps locate ts there
                        if switching and _pair_switches(x_new, u_end, x_mid, u_mid, x2, ue2, xm2, um2, xb, ueb, u_op,
                                                        sat, asat, held, saturate, clip, u_min, u_max, h_max, c, ga,
                                                        ue):
                            break  # a switch inside the pair: the plain steps locate it
                        est = _pair_error(x2, xb, z2, zb, lam_e, Cm, Cq, nd, nq, s, u_gain, local_per, h2)
                        if est <= eps:
                            paired = True
                            break
                        lv += 1
                    if lv0 >= top:
                        pass  # no pair aligned with the position: a plain step first
                    elif paired:
                        lv_want = lv - 1 if est * ADAPTIVE_GROWTH <= eps else lv
                        _copy_rows(scr1, scr)
                        _copy_rows(wst1, wst)
                        level = lv
                        lv_pair = lv
                        hs = h1
                        h_second = h1b
                        pos += 1 << (fine - lv)
                        stashed = True
                    else:
                        # no pair above the rule's step: plain steps for a while, then try again
                        wait = ADAPTIVE_WAIT
                        lv_want = top - 1
                if not paired:
                    if graded and gi < 5:
                        level = GRADED_LEVELS[gi] + top
                        gi += 1
                    elif sliding[0] or sliding[1]:
                        level = top + 4
                    else:
                        level = top
                        while pos % (1 << (fine - level)) != 0:
                            level += 1
                        wait -= 1
                    if lazy and ready[level] == 0:
                        step_tables(lam_e, bm_e, mi, Cm, Aq_e, Bq_e, Cq, h, n_levels, level, rows, coup, prop_m,
                                    prop_q, prop_qb, pmc, pmh, phw, sqw, rw, bw)
                        ready[level] = 1
                    hs = h / 2.0 ** level
                    pos += 1 << (fine - level)
                    if pos >= units:
                        hs = t_end - t  # the last step ends on the segment's end exactly
                    _etdrk4_step(x, z, hs, rows[level], coup[level], prop_m[level], prop_q[level], prop_qb[level], mi,
                                 c_e, s, d1, d2, v[0], v[1], h_op, Dc, Dn, pm[0], pm[1], scr, wst, x_new,
                                 z_new, x_mid, u_mid, u_end, True)
            n_taken += 1
            if not (abs(x_new[0]) + abs(x_new[1]) + abs(x_new[2]) + abs(x_new[3]) < state_limit):
                diverged = True
                break
            fired = -1
            if switching:
                _event_values(x_mid, u_mid, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, gm, ue)
                _event_values(x_new, u_end, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, g1, ue)
                th_lo = 1.0
                for k in range(N_EVENTS):
                    if k < 2 and sliding[k]:
                        continue  # a sliding pump switches at step ends (below)
                    if gm[k] > 0.0 or g1[k] > 0.0:
                        # bisection on the dense output, in the half where the sign changes
                        a_, b_ = (0.0, 0.5) if gm[k] > 0.0 else (0.5, 1.0)
                        if n_events < MAX_LOCATED_EVENTS:
                            for _ in range(_LOCATE_ITERATIONS):
                                mid = 0.5 * (a_ + b_)
                                _dense_at(mid, hs, x, z, lam_e, bm_e, mi, Cm, Aq_e, Bq_e, Cq, c_e, s, d1, d2, h_op,
                                          Dc, pm[0], pm[1], scr, wst, w, xr, dur, pmc, phw, sqw, vq)
                                _event_values(
                                    xr, dur, u_op, sat, asat, held, saturate, clip, u_min, u_max, h_max, c, ga, ue
                                )
                                if ga[k] > 0.0:
                                    b_ = mid
                                else:
                                    a_ = mid
                        if b_ < th_lo:
                            th_lo = b_
                            fired = k
                if fired >= 0 and th_lo < 1.0 and n_events < MAX_LOCATED_EVENTS:
                    # cut the step at the switch and take it again
                    hs = th_lo * hs
                    step_tables(lam_e, bm_e, mi, Cm, Aq_e, Bq_e, Cq, hs, n_levels, 0 if lazy else -1, rows, coup,
                                prop_m, prop_q, prop_qb, pmc, pmh, phw, sqw, rw, bw)
                    _etdrk4_step(x, z, hs, rows[0], coup[0], prop_m[0], prop_q[0], prop_qb[0], mi, c_e, s, d1, d2,
                                 v[0], v[1], h_op, Dc, Dn, pm[0], pm[1], scr, wst, x_new, z_new, x_mid,
                                 u_mid, u_end, True)
                    n_events += 1
                elif fired >= 0:
                    n_events += 1
            # recorded grid points in [t, t + hs)
            while k_rec < rec and k_rec * out_dt < t + hs - 1e-9 * hs:
                theta = (k_rec * out_dt - t) / hs
                _dense_at(max(theta, 0.0), hs, x, z, lam_e, bm_e, mi, Cm, Aq_e, Bq_e, Cq, c_e, s, d1, d2, h_op, Dc,
                          pm[0], pm[1], scr, wst, w, xr, dur, pmc, phw, sqw, vq)
                _measure(xr, s, d1, d2, h_op, w)
                _applied(dur, u_op, asat, saturate, u_min, u_max, ua)
                # the measured levels: w is taken from the set-points
                y_rec[k_rec, 0] = w[0] + h_op[0] + seg[sg, SEG_REF]
                y_rec[k_rec, 1] = w[1] + h_op[1] + seg[sg, SEG_REF + 1]
                u_rec[k_rec, 0] = u_op[0] + ua[0]
                u_rec[k_rec, 1] = u_op[1] + ua[1]
                for i in range(4):
                    h_rec[k_rec, i] = xr[i]
                k_rec += 1
            # midpoint and end nodes
            _measure(x_mid, s, d1, d2, h_op, w)
            _applied(u_mid, u_op, asat, saturate, u_min, u_max, ua)
            _signals(w, x_mid, s, u_op, ua, fm)
            n_win = _visit(t + 0.5 * hs, fm, post, band, n_win, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in,
                           ex_has_prev, pending, tv, u_prev, False)
            _measure(x_new, s, d1, d2, h_op, w)
            _applied(u_end, u_op, asat, saturate, u_min, u_max, ua)
            _signals(w, x_new, s, u_op, ua, f1)
            n_win = _visit(t + hs, f1, post, band, n_win, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in,
                           ex_has_prev, pending, tv, u_prev, False)
            te = t + hs
            _simpson_step(t, hs, u_op, f0, fm, f1, iae, ise, itae, jj, jdev)
            t = te
            x, x_new = x_new, x
            z, z_new = z_new, z
            du0[0] = u_end[0]
            du0[1] = u_end[1]
            changed = fired >= 0
            if fired >= 0:
                # the new mode: the switching element changes state, a new graded span starts
                if fired < 2:
                    uc = u_op[fired] + u_end[fired]
                    if sat[fired] == 0:  # the limit it crossed
                        sat[fired] = 1 if abs(uc - u_max) <= abs(uc - u_min) else -1
                        if t - t_release[fired] < SLIDING_WINDOW * h_target:
                            sliding[fired] = True
                            pin[fired] = sat[fired]
                            excess[fired] = 0.0  # located on the limit
                    else:
                        sat[fired] = 0
                        t_release[fired] = t
                else:
                    i = fired - 2
                    if held[i] == 0:  # held exactly on the limit it reached
                        held[i] = 1 if abs(x[i] - h_max[i]) <= abs(x[i]) else -1
                        x[i] = h_max[i] if held[i] > 0 else 0.0
                    else:
                        held[i] = 0
            for k in range(2):
                if fired >= 0 or not sliding[k]:
                    continue
                # a sliding pump at the end of a whole step (not one cut at another switch, whose
                # length may be down to rounding): its output beyond the pinned limit decides
                uc = u_op[k] + u_end[k]
                ex = uc - u_max if pin[k] > 0 else u_min - uc
                if sat[k] != 0:  # held over this step
                    if ex <= 0.0:
                        sat[k] = 0  # back inside: its states integrate, its voltage stays pinned
                        changed = True
                    elif ex > excess[k]:
                        sliding[k] = False  # pushed further out while held: plain saturation
                        pin[k] = 0
                        changed = True
                elif ex > 0.0:
                    sat[k] = pin[k]  # driven out again: held
                    changed = True
                elif ex < excess[k]:
                    sliding[k] = False  # drawn further in while free: it leaves the limit
                    pin[k] = 0
                    t_release[k] = t
                    changed = True
                excess[k] = ex
            if changed:
                _mode_arrays(sat, pin, asat, held, lam, bm, Aq, Bq, channel, c, Dc, u_op, uin, u_min, u_max,
                             lam_e, bm_e, Aq_e, Bq_e, c_e, Dn, v, pm)
                n_win = 0
                graded = True
                replan = True
        if diverged:
            break
    if diverged:
        _nan_records(k_rec, rec, y_rec, u_rec, h_rec)
        for i in range(N_METRICS):
            metrics[i] = math.nan
        return STATUS_DIVERGED, n_taken
    # the end point T
    while k_rec < rec:
        y_rec[k_rec, 0] = s * x[0] + seg[n_seg - 1, SEG_DIST] + seg[n_seg - 1, SEG_REF]
        y_rec[k_rec, 1] = s * x[1] + seg[n_seg - 1, SEG_DIST + 1] + seg[n_seg - 1, SEG_REF + 1]
        u_rec[k_rec, 0] = f1[6]
        u_rec[k_rec, 1] = f1[7]
        for i in range(4):
            h_rec[k_rec, i] = x[i]
        k_rec += 1
    _final_metrics(h_op, horizon, t_dist, band, mp, f1, lo, hi, iae, ise, itae, jj, jdev, tv, ex_prev, ex_out,
                   ex_in, ex_has_prev, pending, metrics)
    # a parabola through a kink at a limit must not refine past it
    if saturate:
        metrics[20] = max(metrics[20], u_min)
        metrics[21] = min(metrics[21], u_max)
    if clip:
        metrics[18] = max(metrics[18], 0.0)
        metrics[19] = min(metrics[19], s * max(max(h_max[0], h_max[1]), max(h_max[2], h_max[3])))
    return STATUS_OK, n_taken




@njit(cache=True)
def feedback_radius(A, B, D, lam, bm, mi, Cm, h):
    """Spectral radius of ``A + B D_h``, the linearised plant under the static feedback that the
    explicit part of a step ``h`` sees: ``D`` plus ``-Cm_i bm_i / lam_i`` on signal ``mi_i`` of
    every modal state with ``|lam_i| h > 1`` (``continuous.folded_feedback``, jitted for the
    per-candidate step rule ``continuous.feedback_step``).

    A : (4, 4); B : (4, 2); D : (2, 4); lam, bm : (nd,); mi : (nd,) int64; Cm : (2, nd).
    Returns inf when any entry is not finite (or LAPACK fails).
    """
    M = np.empty((4, 4))
    if not _feedback_matrix(A, B, D, lam, bm, mi, Cm, h, M):
        return math.inf
    return spectral_radius(M)


@njit(cache=True)
def _feedback_matrix(A, B, D, lam, bm, mi, Cm, h, M):
    """Write ``A + B D_h`` (:func:`feedback_radius`) into ``M`` (4, 4); False when an entry of
    the controller or of ``M`` is not finite."""
    Dh = D.copy()
    for i in range(lam.size):
        if not (math.isfinite(lam[i]) and math.isfinite(bm[i]) and math.isfinite(Cm[0, i])
                and math.isfinite(Cm[1, i])):
            return False
        if abs(lam[i]) * h > 1.0:
            g = bm[i] / lam[i]
            Dh[0, mi[i]] -= Cm[0, i] * g
            Dh[1, mi[i]] -= Cm[1, i] * g
    for r in range(4):
        for c in range(4):
            M[r, c] = A[r, c] + B[r, 0] * Dh[0, c] + B[r, 1] * Dh[1, c]
            if not math.isfinite(M[r, c]):
                return False
    return True


# A norm of A + B D_h decides a test of the step rule without the eigenvalues when it lies
# below the limit by this fraction: every eigenvalue is at most the matrix's infinity- and
# 1-norms, and the margin covers the rounding of LAPACK's (those of a nearby matrix, scaled by
# its balancing), so that the decision is the one the radius gives.
NORM_BOUND_MARGIN = 1e-4


@njit(cache=True)
def step_rule(A, B, D, lam, bm, mi, Cm, h_max, radius, min_step, stability_radius, top_max):
    """The per-candidate step rule in one call: the step ``h`` (``h_max`` halved while
    ``h rho(A + B D_h) > radius``, at least ``min_step``; ``min_step`` when an entry is not
    finite) and the adaptive range ``top`` above it (the largest ``j`` in 1 .. top_max - 1 with
    ``h 2^j rho(A + B D_(h 2^j)) <= stability_radius``, plus one; 0 if none). See
    ``continuous.feedback_step`` and ``continuous.adaptive_top``.

    ``D_h`` depends on ``h`` only through the modes it folds (``|lam_i| h > 1``), a set that
    grows with ``h``: its size names it, so each radius is computed once per set, and only
    where a norm of the matrix does not decide the test (:data:`NORM_BOUND_MARGIN`).

    Returns
    -------
    h : float
    top : int
    """
    known = np.full(lam.size + 1, -1.0)  # radius by number of folded modes (-1: not yet)
    M = np.empty((4, 4))
    h = h_max
    while h > min_step:
        within = _within_radius(A, B, D, lam, bm, mi, Cm, h, radius, known, M)
        if within < 0:
            return min_step, 0
        if within:
            break
        h *= 0.5
    if h <= min_step:
        return min_step, 0
    for j in range(top_max - 1, 0, -1):
        hj = h * 2.0 ** j
        if _within_radius(A, B, D, lam, bm, mi, Cm, hj, stability_radius, known, M) == 1:
            return h, j + 1
    return h, 0


@njit(cache=True)
def _within_radius(A, B, D, lam, bm, mi, Cm, h, limit, known, M):
    """Whether ``h rho(A + B D_h) <= limit``: 1 if so, 0 if not, -1 when the radius is not
    finite. The radius is :func:`feedback_radius`, kept in ``known`` by the number of modes
    folded; it is not computed when ``h`` times the smaller of the matrix's infinity- and
    1-norms lies below ``limit (1 - NORM_BOUND_MARGIN)``."""
    folded = 0
    for i in range(lam.size):
        if abs(lam[i]) * h > 1.0:
            folded += 1
    rho = known[folded]
    if rho < 0.0:
        if not _feedback_matrix(A, B, D, lam, bm, mi, Cm, h, M):
            rho = known[folded] = math.inf
        else:
            row, col = 0.0, 0.0
            for r in range(4):
                row = max(row, abs(M[r, 0]) + abs(M[r, 1]) + abs(M[r, 2]) + abs(M[r, 3]))
                col = max(col, abs(M[0, r]) + abs(M[1, r]) + abs(M[2, r]) + abs(M[3, r]))
            if h * min(row, col) <= limit * (1.0 - NORM_BOUND_MARGIN):
                return 1
            rho = known[folded] = spectral_radius(M)
    if not math.isfinite(rho):
        return -1
    return 1 if h * rho <= limit else 0


# Rows of the working arrays of continuous_lane (float64 unless stated): see its first lines.
_W4_ROWS = 29
_W2_ROWS = 29
_W10_ROWS = 15


def workspace_shapes(nd: int, nq: int) -> list:
    """Shapes and dtypes of the working arrays of :func:`continuous_lane`, in its order, for
    ``nd`` modal and ``nq`` dense controller states (exact: the lane reads its sizes from them).

    Parameters
    ----------
    nd : int
    nq : int

    Returns
    -------
    list of (tuple, dtype)
    """
    nz, d, q = nd + nq, nd, nq
    f, i8, b1 = np.float64, np.int64, np.bool_
    L = MAX_STEP_LEVELS
    return [((L, nz, N_ROWS), f), ((L, N_COUPLINGS, 2, 4), f), ((L, 4, d), f), ((L, q, q), f), ((L, 3, q, 4), f),
            ((4, nz), f), ((2, d), f), ((q, q), f), ((q, 4), f),
            ((_W4_ROWS, 4), f), ((_W2_ROWS, 2), f), ((_W10_ROWS, 10), f), ((10 + L,), i8), ((3, 2), b1),
            ((2, N_PHI, q, q), f), ((2, q, q), f), ((3, 2, q), f), ((q, 4), f), ((3, q), f)]


def _workspace(nd, nq, lanes=None):
    """The working arrays of :func:`continuous_lane` (with a leading lane axis when ``lanes``)."""
    lead = () if lanes is None else (lanes,)
    return tuple(np.empty(lead + shape, dtype=dt) for shape, dt in workspace_shapes(nd, nq))


_LOCAL = threading.local()


def _thread_workspace(nd, nq):
    """:func:`_workspace` for one lane, kept per thread and size (the lane initialises what it
    reads, so a set serves run after run; threads never share one)."""
    cache = getattr(_LOCAL, "work", None)
    if cache is None:
        cache = _LOCAL.work = {}
    work = cache.get((nd, nq))
    if work is None:
        if len(cache) >= 16:
            cache.clear()
        work = cache[(nd, nq)] = _workspace(nd, nq)
    return work


def simulate_continuous(P, level_per_state, x_init, h_op, lam, bm, mi, Cm, Aq, Bq, Cq, Dc, channel, seg, band_pct,
                        metrics, out_dt, y_rec, u_rec, h_rec):
    """Continuous-time closed loop by ETDRK4 on a planned grid, with its metrics.

    Parameters
    ----------
    P : (NP,) the scenario's parameter table (``kernels.scenario_table``): of its rows the
        loop reads the plant coefficients ``c`` (``kernels.plant_coefficients`` or the
        bond-graph ones), the operating voltages ``u_op``, the pump limits ``u_min``, ``u_max``
        and ``saturate`` (conditional-integration anti-windup: the states of a pump's channel
        are held while its controller output lies outside them), ``clip`` with the tank heights
        ``h_max`` in state units (each level stays in [0, h_max_i]), the output disturbance
        time ``t_dist`` and the horizon T; the disturbances themselves come from ``seg``
    level_per_state : float, level per unit of plant state (1 for the level model)
    x_init : (4,) initial plant state; h_op : (4,) operating levels
    lam, bm : (nd,) modal eigenvalues and input gains; mi : (nd,) int64 input of each mode;
    Cm : (2, nd) their output weights
    Aq : (nq, nq), Bq : (nq, 4), Cq : (2, nq): the dense controller blocks
    Dc : (2, 4) static feedback; channel : (nd + nq,) int64, the pump of each controller state
    seg : (S, N_SEG) the segment table (``StepPlan.table``; segments start at 0 and at every
        discontinuity), columns ``SEG_*`` of this module: start time and step, number of
        steps, whether the first step is graded (h/16, h/16, h/8, h/4, h/2), the output and
        input disturbances in force (2 each), and whether the segment lies after ``t_dist``
    band_pct : float, settling band in percent
    metrics : (N_METRICS,) output in the order of ``kernels.METRIC_NAMES``
    out_dt : float; y_rec, u_rec : (M + 1, 2), h_rec : (M + 1, 4) the dense output at
        ``t = k out_dt`` (measured levels, applied voltages, plant states), or 0 rows

    A switch (a pump reaching or leaving a limit, a level reaching a rim or the floor, a held
    level's slope turning back) is located inside the step on the dense output by bisection;
    the step is cut there, the loop changes mode, and a new graded span starts at the switch.

    Returns
    -------
    status : int, STATUS_OK or STATUS_DIVERGED (metrics NaN, records NaN from there)
    n_steps : int, steps taken

    The step is :func:`continuous_lane`'s, with working arrays allocated here.
    """
    work = _thread_workspace(lam.size, Aq.shape[0])
    status, n_taken = continuous_lane(
        P, level_per_state, x_init, h_op, lam, bm, mi, Cm, Aq, Bq, Cq, Dc, channel, seg, seg.shape[0], band_pct,
        metrics, out_dt, y_rec, u_rec, h_rec, y_rec.shape[0], work)
    return int(status), int(n_taken)


# The per-lane inputs of continuous_lane, in its order, as simulate_continuous_lanes takes them.
LANE_FIELDS = ("P", "lam", "bm", "mi", "Cm", "Aq", "Bq", "Cq", "Dc", "channel", "seg", "n_seg")


@njit(cache=True)
def _lanes_loop(level_per_state, x_init, h_op, band_pct, P, lam, bm, mi, Cm, Aq, Bq, Cq, Dc, channel, seg, n_seg,
                metrics, status, n_taken, rec2, rec4, work):
    """The lanes one after another through :func:`continuous_lane`, on one set of working arrays."""
    for k in range(P.shape[0]):
        st, n = continuous_lane(
            P[k], level_per_state, x_init, h_op, lam[k], bm[k], mi[k], Cm[k], Aq[k], Bq[k], Cq[k], Dc[k],
            channel[k], seg[k], n_seg[k], band_pct, metrics[k], 1.0, rec2, rec2, rec4, 0, work)
        status[k] = st
        n_taken[k] = n


def simulate_continuous_lanes(lanes, level_per_state, x_init, h_op, band_pct):
    """:func:`simulate_continuous` of many lanes (metrics only), one after another in one call.

    Parameters
    ----------
    lanes : dict
        The lanes' inputs by the names of :data:`LANE_FIELDS`, each with a leading lane axis
        (:func:`heurtune.objectives.qtp.continuous.pack_lanes`); all lanes have the same numbers
        of modal and dense controller states.
    level_per_state, x_init, h_op, band_pct : as :func:`simulate_continuous`, shared.

    Returns
    -------
    status : (L,) int64; metrics : (L, N_METRICS); n_taken : (L,) int64
    """
    L = lanes["P"].shape[0]
    metrics = np.empty((L, N_METRICS))
    status = np.empty(L, dtype=np.int64)
    n_taken = np.empty(L, dtype=np.int64)
    work = _workspace(lanes["lam"].shape[1], lanes["Aq"].shape[1])
    _lanes_loop(float(level_per_state), x_init, h_op, float(band_pct), *[lanes[k] for k in LANE_FIELDS],
                metrics, status, n_taken, np.empty((1, 2)), np.empty((1, 4)), work)
    return status, metrics, n_taken


@_kernel(inline="always")
def _applied(du, u_op, sat, saturate, u_min, u_max, out):
    """Applied voltage deviations: the controller's, or the limit's for a saturated pump."""
    for j in range(2):
        out[j] = du[j]
        if saturate:
            if sat[j] > 0:
                out[j] = u_max - u_op[j]
            elif sat[j] < 0:
                out[j] = u_min - u_op[j]
            else:
                out[j] = min(max(du[j], u_min - u_op[j]), u_max - u_op[j])


@_kernel(inline="always")
def _signals(w, x, s, u_op, du, f):
    """The followed signals at a node: |e1|, |e2| (``w`` measured there), levels, voltages."""
    f[0] = abs(w[0])
    f[1] = abs(w[1])
    f[2] = s * x[0]
    f[3] = s * x[1]
    f[4] = s * x[2]
    f[5] = s * x[3]
    f[6] = u_op[0] + du[0]
    f[7] = u_op[1] + du[1]
    f[8] = w[0]
    f[9] = w[1]


@_kernel(inline="always")
def _visit(t, f, post, band, n_win, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in, ex_has_prev, pending,
           tv, u_prev, first):
    """Fold one node (time ``t``, signals ``f``) into the extremes, the overshoot, the band
    exits and the total variation; returns the new window count."""
    # total variation over consecutive nodes, jumps at discontinuities included
    if not first:
        tv[0] += abs(f[6] - u_prev[0])
        tv[1] += abs(f[7] - u_prev[1])
    u_prev[0] = f[6]
    u_prev[1] = f[7]
    # window of the segment's last three nodes
    if n_win < 3:
        win_t[n_win] = t
        for i in range(_N_SIG):
            win_v[n_win, i] = f[i]
        n_win += 1
    else:
        win_t[0] = win_t[1]
        win_t[1] = win_t[2]
        win_t[2] = t
        for i in range(_N_SIG):
            win_v[0, i] = win_v[1, i]
            win_v[1, i] = win_v[2, i]
            win_v[2, i] = f[i]
    for i in range(2, _N_EXT):
        lo[i] = min(lo[i], f[i])
        hi[i] = max(hi[i], f[i])
    if post:
        for i in range(2):
            mp[i] = max(mp[i], f[i])
    if n_win == 3:
        t0, t1, t2 = win_t[0], win_t[1], win_t[2]
        for i in range(_N_EXT):
            a, b, cc = win_v[0, i], win_v[1, i], win_v[2, i]
            if b >= a and b >= cc:
                v = _vertex(t0, a, t1, b, t2, cc)
                if i < 2:
                    if post:
                        mp[i] = max(mp[i], v)
                else:
                    hi[i] = max(hi[i], v)
            if b <= a and b <= cc and i >= 2:
                lo[i] = min(lo[i], _vertex(t0, a, t1, b, t2, cc))
    if post:
        for i in range(2):
            if f[i] > band[i]:
                ex_out[i, 0] = t
                ex_out[i, 1] = f[i]
                ex_has_prev[i] = n_win >= 2
                if n_win >= 2:
                    ex_prev[i, 0] = win_t[n_win - 2]
                    ex_prev[i, 1] = win_v[n_win - 2, i]
                pending[i] = True
            elif pending[i]:
                ex_in[i, 0] = t
                ex_in[i, 1] = f[i]
                pending[i] = False
    return n_win
