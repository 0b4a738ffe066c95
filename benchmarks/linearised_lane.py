"""A prototype of the next QTP kernel: the loop's whole linearisation integrated exactly, in numba.

The loop in deviations from the operating point, ``Y = (xi, z)`` (plant state minus its
operating value, in state units, and the controller's state), is

    Y' = L Y + g + [r(xi); 0],

``L`` the loop linearised at the operating point (plant Jacobian, the static feedback ``Dc``,
the controller's input ``Bc`` and dynamics ``Ac``, its drive ``Cc`` of the pumps), ``g`` the
constant drive of a segment (disturbances, operating voltages) and ``r`` what the square-root
outflows leave beyond their linearisation, second order in ``xi`` (written without
cancellation). ETDRK4 (Cox and Matthews) integrates ``L`` and ``g`` exactly and only ``r``
explicitly, in the real modal coordinates of ``L`` (LAPACK ``dgeev`` with right eigenvectors,
the routine the stability check calls without them): one real coordinate per real mode, two
per complex-conjugate pair, so that every stage is a product by diagonal coefficients (real, or
complex on a pair) and two thin real products (the plant rows of the basis out, the plant
columns of its inverse in).

Steps are adaptive, ``h_top 2^-l``: each step resolves (``|lam| h <= kappa``) every mode whose
transient ``|y_j'| / |lam_j|`` weighs more than ``amp_floor`` (cm or V) in the level errors and
voltages; lighter modes are integrated exactly and only the quadrature sees them. The metrics
are heurtune's own helpers (``continuous_kernels``) folding each step's end and midpoint (the
method's dense output at theta = 1/2). No saturation, no level limits, metrics only.

Run with ``python benchmarks/linearised_lane.py [--rule H_TOP KAPPA FLOOR]``: per case (the
thesis' FOLQI min gains, the weakly damped FOLQI candidate, the IOLQI nmp loop) and rule, the
relative errors of IAE, J and TV and the settling time against heurtune's loop at 0.125/16 s
(itself within 1e-8 of Radau in IAE for these loops), beside heurtune's default loop; then
``cs_folqi_qtp`` min's candidate sets of ``bench_study_candidates.py`` (thesis, uniform, at the
bounds, visited by cuckoo search) under one rule: IAE errors against the same reference, steps,
and the milliseconds per candidate of heurtune's evaluation, of heurtune's loop within it and of
the prototype's set-up and lane (one core, BLAS one thread). The findings are in docs/model.md
("Where the error comes from"). Not part of ``make bench``: a measurement for the kernel's next
design.
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import dataclasses  # noqa: E402
import functools  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402
from numba.core.cpu import CPUTargetOptions  # noqa: E402

from heurtune.objectives.qtp.continuous_kernels import (  # noqa: E402
    _N_SIG,
    SEG_DIST,
    SEG_POST,
    SEG_T0,
    SEG_UIN,
    _abs_moments,
    _crossing,
    _measure,
    _signals,
    _visit,
)
from heurtune.objectives.qtp.design_kernels import _N, _V, _data, _dgeev, _kept  # noqa: E402
from heurtune.objectives.qtp.kernels import (  # noqa: E402
    LEVEL_LIMIT,
    N_METRICS,
    P_COEF,
    P_HORIZON,
    P_T_DIST,
    P_UOP,
    STATUS_DIVERGED,
    STATUS_OK,
)

# The lane allocates nothing and is compiled without reference counting, as heurtune's lane is
# (continuous_kernels): with it, every array an inlined helper binds costs two atomic updates.
_kernel = functools.partial(njit, cache=True, **({"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}))

# Step levels h_top 2^-l, l = 0 .. N_LEVELS - 1, each step's level chosen by the modes it must
# resolve (_step_level); one more slot of coefficients for a segment's shortened last step.
N_LEVELS = 8
# Per level and mode, the step's diagonal coefficients: E = e^z, E2 = e^(z/2), Q = h/2 phi_1(z/2),
# the weights F1, F2, F3 of N(u), N(a) + N(b), N(c) at the step's end and G1, G2, G3 at its
# midpoint (z = lam h; the dense output replaces phi_k(z) by theta^k phi_k(theta z)).
N_COEF = 9
C_E, C_E2, C_Q, C_F1, C_F2, C_F3, C_G1, C_G2, C_G3 = range(N_COEF)
# Which pump drives each tank's equation, and its coefficient's row in c: tank 1 pump 1 (c[6]),
# tank 2 pump 2 (c[7]), tank 3 pump 2 (c[8]), tank 4 pump 1 (c[9]).
_PUMP = (0, 1, 1, 0)
_PUMP_COEF = (6, 7, 8, 9)
# Below this |z| the phi functions are summed as Taylor series (20 terms: truncation < 1e-19).
_TAYLOR_BELOW = 1.0
_TAYLOR_TERMS = 20
_INV_FACT_3 = tuple(1.0 / math.factorial(j + 3) for j in range(_TAYLOR_TERMS))
# A modal form whose eigenvector matrix is conditioned worse than this (1-norm estimate) is not
# used: the caller runs the switching kernel instead.
COND_LIMIT = 1e8
STATUS_NOT_MODAL = 2


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


@_kernel
def _coefficients(lam_r, lam_i, n_real, hl, T, lv):
    """The diagonal coefficients ``C_*`` of a step ``hl`` into ``T[lv]`` (N_COEF, n): a real
    mode's value at its coordinate, a pair's real and imaginary parts at its two."""
    n = lam_r.size
    j = 0
    while j < n:
        z = complex(lam_r[j], lam_i[j]) * hl
        p0, p1, p2, p3 = _phi3(z)
        q0, q1, q2, q3 = _phi3(0.5 * z)
        k = 0
        for v in (p0, q0, 0.5 * hl * q1, hl * (p1 - 3.0 * p2 + 4.0 * p3), 2.0 * hl * (p2 - 2.0 * p3),
                  hl * (4.0 * p3 - p2), hl * (0.5 * q1 - 0.75 * q2 + 0.5 * q3), hl * (0.5 * q2 - 0.5 * q3),
                  hl * (0.5 * q3 - 0.25 * q2)):
            T[lv, k, j] = v.real
            if j >= n_real:
                T[lv, k, j + 1] = v.imag
            k += 1
        j += 1 if j < n_real else 2


@_kernel(inline="always")
def _diag2(T, lv, k1, v1, k2, v2, out, n_real):
    """``out = T[k1] o v1 + T[k2] o v2``, ``o`` the product by the diagonal: real on the real
    modes, complex on the pairs (coordinates ``j, j + 1`` the real and imaginary parts)."""
    for j in range(n_real):
        out[j] = T[lv, k1, j] * v1[j] + T[lv, k2, j] * v2[j]
    for j in range(n_real, v1.size, 2):
        ar, ai, br, bi = T[lv, k1, j], T[lv, k1, j + 1], T[lv, k2, j], T[lv, k2, j + 1]
        out[j] = ar * v1[j] - ai * v1[j + 1] + br * v2[j] - bi * v2[j + 1]
        out[j + 1] = ar * v1[j + 1] + ai * v1[j] + br * v2[j + 1] + bi * v2[j]


@_kernel(inline="always")
def _diag4(T, lv, k1, v1, k2, v2, k3, v3, k4, v4, out, n_real):
    """``out = T[k1] o v1 + T[k2] o v2 + T[k3] o v3 + T[k4] o v4`` (see :func:`_diag2`)."""
    for j in range(n_real):
        out[j] = T[lv, k1, j] * v1[j] + T[lv, k2, j] * v2[j] + T[lv, k3, j] * v3[j] + T[lv, k4, j] * v4[j]
    for j in range(n_real, v1.size, 2):
        ar, ai, br, bi = T[lv, k1, j], T[lv, k1, j + 1], T[lv, k2, j], T[lv, k2, j + 1]
        cr, ci, dr, di = T[lv, k3, j], T[lv, k3, j + 1], T[lv, k4, j], T[lv, k4, j + 1]
        out[j] = (ar * v1[j] - ai * v1[j + 1] + br * v2[j] - bi * v2[j + 1] + cr * v3[j] - ci * v3[j + 1]
                  + dr * v4[j] - di * v4[j + 1])
        out[j + 1] = (ar * v1[j + 1] + ai * v1[j] + br * v2[j + 1] + bi * v2[j] + cr * v3[j + 1] + ci * v3[j]
                      + dr * v4[j + 1] + di * v4[j])


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


@_kernel(inline="always")
def _drive(x, x_op, rt, c, W, k, out):
    """The modal drive ``out = k + W r`` at plant state ``x`` (``r``: the outflows beyond their
    linearisation)."""
    e0 = _root_excess(x_op[0], rt[0], x[0] - x_op[0])
    e1 = _root_excess(x_op[1], rt[1], x[1] - x_op[1])
    e2 = _root_excess(x_op[2], rt[2], x[2] - x_op[2])
    e3 = _root_excess(x_op[3], rt[3], x[3] - x_op[3])
    r0 = c[4] * e2 - c[0] * e0
    r1 = c[5] * e3 - c[1] * e1
    r2 = -c[2] * e2
    r3 = -c[3] * e3
    for j in range(k.size):
        out[j] = k[j] + W[j, 0] * r0 + W[j, 1] * r1 + W[j, 2] * r2 + W[j, 3] * r3


@njit(cache=True)
def modal_form(L, s, Cc, Dc):
    """The real modal form of ``L``: LAPACK ``dgeev`` with right eigenvectors, the real modes
    first, then one coordinate pair per complex-conjugate pair of eigenvalues.

    With ``T`` the real basis (a real mode's eigenvector; a pair's real and imaginary parts
    ``P``, ``Q`` of the eigenvector of ``a + ib``, b > 0) and ``y = T^-1 Y``, a real mode obeys
    ``y_j' = lam_j y_j`` and a pair's ``zeta = y_j - i y_(j+1)``... stored as ``(Re, -Im)``:
    with ``(y_j, y_(j+1)) = (Re zeta, Im zeta)`` where ``zeta = p - i q``, ``zeta' = (a + ib)
    zeta`` and the state is ``P Re zeta - Q Im zeta``.

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


@_kernel(inline="always")
def _step_level(y, N, lam_r, lam_i, gain, n_real, amp_floor, kappa, h_top, n_levels):
    """The step level ``l`` (step ``h_top 2^-l``) for the coming step: every mode whose transient
    ``|y_j'| / |lam_j| = |lam_j y_j + N_j| / |lam_j|`` (its distance from where the present
    drive ``N`` holds it) weighs more than ``amp_floor`` in the level errors and voltages is
    resolved (``|lam| h <= kappa``); lighter modes are integrated exactly and left to the
    quadrature."""
    fast = 0.0
    for j in range(n_real):
        lam = abs(lam_r[j])
        if abs(lam_r[j] * y[j] + N[j]) * gain[j] > amp_floor * lam:
            fast = max(fast, lam)
    for j in range(n_real, y.size, 2):
        lam = math.hypot(lam_r[j], lam_i[j])
        dr = lam_r[j] * y[j] - lam_i[j] * y[j + 1] + N[j]
        di = lam_r[j] * y[j + 1] + lam_i[j] * y[j] + N[j + 1]
        if math.hypot(dr, di) * gain[j] > amp_floor * lam:
            fast = max(fast, lam)
    lv = 0
    while lv < n_levels - 1 and h_top * fast > kappa * 2.0 ** lv:
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
    """Simpson's rule over a step from its start, midpoint and end signals (``sig[0..2]``), IAE
    and ITAE split at the error's zero crossings; the end becomes the next step's start."""
    f0, fm, f1 = sig[0], sig[1], sig[2]
    iae, ise, itae, jj, jdev = w2[6], w2[7], w2[8], w2[9], w2[10]
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
        bm = am - u_op[i]
        b1 = a1 - u_op[i]
        jdev[i] += wq * (b0 * b0 + 4.0 * bm * bm + b1 * b1)
    for i in range(_N_SIG):
        f0[i] = f1[i]


@_kernel(inline="always")
def _finish_metrics(diverged, n_taken, w2, ex, wb, sig, h_op, horizon, t_dist, metrics):
    """The metrics from the accumulators (NaN when the run diverged); returns (status, steps)."""
    if diverged:
        for i in range(N_METRICS):
            metrics[i] = math.nan
        return STATUS_DIVERGED, n_taken
    ex_prev, ex_out, ex_in = ex[0], ex[1], ex[2]
    ex_has_prev, pending = wb[0], wb[1]
    f1, lo, hi = sig[2], sig[3], sig[4]
    band, mp = w2[4], w2[12]
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
        for r in range(6):  # IAE, ISE, ITAE, J, Jdev, TV
            metrics[6 + 2 * r + i] = w2[6 + r, i]
    metrics[18] = min(min(lo[2], lo[3]), min(lo[4], lo[5]))
    metrics[19] = max(max(hi[2], hi[3]), max(hi[4], hi[5]))
    metrics[20] = min(lo[6], lo[7])
    metrics[21] = max(hi[6], hi[7])
    return STATUS_OK, n_taken


@_kernel(inline="always")
def _segment_drive(row, d1, d2, c, f_op, u_op, Dc, Bc, Tinv, du_const, k):
    """A segment's constant drive ``g = [f_op + Bp (u_op + uin + Dc d); Bc d]`` in modal form
    (``k = T^-1 g``), and the voltage deviations ``du_const = Dc d`` its output disturbance
    ``d`` adds (``row``: the segment's row of the step plan)."""
    n = k.size
    for j in range(2):
        du_const[j] = Dc[j, 0] * d1 + Dc[j, 1] * d2
    for j in range(n):
        k[j] = 0.0
    for i in range(4):
        p = _PUMP[i]
        gx = f_op[i] + c[_PUMP_COEF[i]] * (u_op[p] + row[SEG_UIN + p] + du_const[p])
        for j in range(n):
            k[j] += Tinv[j, i] * gx
    for r in range(n - 4):
        gz = Bc[r, 0] * d1 + Bc[r, 1] * d2
        if gz != 0.0:
            for j in range(n):
                k[j] += Tinv[j, 4 + r] * gz


@_kernel
def linearised_lane(P, level_per_state, x_op, h_op, lam_r, lam_i, n_real, V6, W, Tinv, gain, Bc, Dc, seg, n_seg,
                    band_pct, h_top, kappa, amp_floor, metrics, work):
    """The loop of one controller under one scenario, metrics only (no saturation, no limits),
    in adaptive steps ``h_top 2^-l`` chosen by :func:`_step_level`.

    Parameters
    ----------
    P : (NP,) the scenario table (``kernels.scenario_table``); level_per_state : float; x_op :
        (4,) operating state; h_op : (4,) operating levels; lam_r .. gain: :func:`modal_form`;
        Bc (nc, 4), Dc (2, 4): the controller's input matrices; seg : (S, N_SEG) the segments
        (``continuous.StepPlan.table``: their starts and disturbances; the steps are this lane's);
        n_seg : rows used; band_pct : settling band in percent; h_top, kappa, amp_floor: the
        step rule (:func:`_step_level`)
    metrics : (N_METRICS,) output, in the order of ``kernels.METRIC_NAMES``
    work : the working arrays of :func:`workspace` (initialised here)

    Returns
    -------
    status : int, STATUS_OK or STATUS_DIVERGED (metrics NaN)
    n_steps : int
    """
    c = P[P_COEF:P_COEF + 10]
    u_op = P[P_UOP:P_UOP + 2]
    t_dist, horizon = P[P_T_DIST], P[P_HORIZON]
    s = level_per_state
    n = lam_r.size
    state_limit = LEVEL_LIMIT / s
    T, vec, w4, w2, ex, wb, sig = work
    y, a, b, cs, Ny, Na, Nb, Nc, ym, k, sab = (vec[0], vec[1], vec[2], vec[3], vec[4], vec[5], vec[6], vec[7],
                                                   vec[8], vec[9], vec[10])
    x, x_mid, w, rt, f_op, xs = w4[0], w4[1], w4[2], w4[3], w4[4], w4[5]
    du0, du_mid, du_end, du_const = w2[0], w2[1], w2[2], w2[3]
    du_stage = w2[13]  # a stage's voltages, not read
    f0, fm, f1 = sig[0], sig[1], sig[2]
    n_levels = T.shape[0] - 1  # the last slot: a segment's shortened last step
    for lv in range(n_levels):
        _coefficients(lam_r, lam_i, n_real, h_top / 2.0 ** lv, T, lv)
    for j in range(n):
        y[j] = 0.0
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
        _segment_drive(seg[sg], d1, d2, c, f_op, u_op, Dc, Bc, Tinv, du_const, k)
        # the segment's first node (a jump of the measurement is in it)
        _readout(V6, y, x_op, du_const, x, du0)
        n_win = _visit_node(t, x, du0, s, d1, d2, h_op, u_op, post, 0, w, f0, w2, ex, wb, sig, first_node)
        first_node = False
        while t < t_end:
            _drive(x, x_op, rt, c, W, k, Ny)
            lv = _step_level(y, Ny, lam_r, lam_i, gain, n_real, amp_floor, kappa, h_top, n_levels)
            hs = h_top / 2.0 ** lv
            last = t + hs >= t_end * (1.0 - 1e-14)
            if last:
                hs = t_end - t
                lv = n_levels
                _coefficients(lam_r, lam_i, n_real, hs, T, lv)
            _diag2(T, lv, C_E2, y, C_Q, Ny, a, n_real)  # a = E2 y + Q N(y)
            _readout(V6, a, x_op, du_const, xs, du_stage)
            _drive(xs, x_op, rt, c, W, k, Na)
            _diag2(T, lv, C_E2, y, C_Q, Na, b, n_real)  # b = E2 y + Q N(a)
            _readout(V6, b, x_op, du_const, xs, du_stage)
            _drive(xs, x_op, rt, c, W, k, Nb)
            for j in range(n):
                sab[j] = 2.0 * Nb[j] - Ny[j]
            _diag2(T, lv, C_E2, a, C_Q, sab, cs, n_real)  # c = E2 a + Q (2 N(b) - N(y))
            _readout(V6, cs, x_op, du_const, xs, du_stage)
            _drive(xs, x_op, rt, c, W, k, Nc)
            for j in range(n):
                sab[j] = Na[j] + Nb[j]
            _diag4(T, lv, C_E2, y, C_G1, Ny, C_G2, sab, C_G3, Nc, ym, n_real)  # the midpoint
            _diag4(T, lv, C_E, y, C_F1, Ny, C_F2, sab, C_F3, Nc, a, n_real)  # the step's end
            for j in range(n):
                y[j] = a[j]
            n_taken += 1
            _readout(V6, ym, x_op, du_const, x_mid, du_mid)
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
    return _finish_metrics(diverged, n_taken, w2, ex, wb, sig, h_op, horizon, t_dist, metrics)


# -- The same method with its stages folded into per-level tables ----------------------------
# Every stage's plant state is the plant rows of the basis applied to the stage's modal state,
# and each stage is linear in y, the constant drive k and the residuals r of earlier stages:
#
#   x_a = x_op + V4 E2 y + V4 (Q o k) + V4 (Q o W) r_y           (V4: the plant rows, n -> 4)
#   x_b = x_op + V4 E2 y + V4 (Q o k) + V4 (Q o W) r_a
#   x_c = x_op + V4 E y + V4 ((E2 Q + Q) o k) + V4 ((E2 Q - Q) o W) r_y + 2 V4 (Q o W) r_b
#   y+  = E y + ((F1 + 2 F2 + F3) o k) + (F1 o W) r_y + (F2 o W) (r_a + r_b) + (F3 o W) r_c
#
# (and the midpoint's levels and voltages alike with G1, G2, G3 and V6). Per level, the thin
# (rows x n) and small (rows x 4) products are tabulated once per candidate, the k terms once
# per segment: a step costs two thin products of y (V4 E2 y and V4 E y, plus the voltage rows
# for the midpoint), the update of y and one readout, instead of a readout and a drive per stage.
N_COEF_FOLDED = 13
C_EQM, C_EQP, C_FK, C_GK = 9, 10, 11, 12
# Rows of a level's thin tables LT: V6 E2 (6), V4 E (4), then (F1 o W), (F2 o W), (F3 o W)
# transposed (4 each).
LT_E2, LT_E, LT_F1, LT_F2, LT_F3 = 0, 6, 10, 14, 18
N_LT = 22
# Rows of a level's small matrices SM (., 4): V4 (Q o W), V4 ((E2 Q - Q) o W), V6 (G1 o W),
# V6 (G2 o W), V6 (G3 o W).
SM_Q, SM_C, SM_G1, SM_G2, SM_G3 = 0, 4, 8, 14, 20
N_SM = 26
# A segment's constants per level SC: V4 (Q o k), V4 ((E2 Q + Q) o k), V6 ((G1 + 2 G2 + G3) o k).
SC_Q, SC_C, SC_M = 0, 4, 8
N_SC = 14


@_kernel
def _coefficients_folded(lam_r, lam_i, n_real, hl, T, lv):
    """:func:`_coefficients` and the combinations the folded stages take (``C_EQM`` = E2 Q - Q,
    ``C_EQP`` = E2 Q + Q, ``C_FK`` = F1 + 2 F2 + F3, ``C_GK`` = G1 + 2 G2 + G3)."""
    n = lam_r.size
    j = 0
    while j < n:
        z = complex(lam_r[j], lam_i[j]) * hl
        p0, p1, p2, p3 = _phi3(z)
        q0, q1, q2, q3 = _phi3(0.5 * z)
        qq = 0.5 * hl * q1
        f1, f2, f3 = hl * (p1 - 3.0 * p2 + 4.0 * p3), 2.0 * hl * (p2 - 2.0 * p3), hl * (4.0 * p3 - p2)
        g1, g2 = hl * (0.5 * q1 - 0.75 * q2 + 0.5 * q3), hl * (0.5 * q2 - 0.5 * q3)
        g3 = hl * (0.5 * q3 - 0.25 * q2)
        k = 0
        for v in (p0, q0, qq, f1, f2, f3, g1, g2, g3, q0 * qq - qq, q0 * qq + qq, f1 + 2.0 * f2 + f3,
                  g1 + 2.0 * g2 + g3):
            T[lv, k, j] = v.real
            if j >= n_real:
                T[lv, k, j + 1] = v.imag
            k += 1
        j += 1 if j < n_real else 2


@_kernel(inline="always")
def _diag_vec(T, lv, kc, v, n_real, out):
    """``out = T[kc] o v`` (real on the real modes, complex on the pairs)."""
    for j in range(n_real):
        out[j] = T[lv, kc, j] * v[j]
    for j in range(n_real, v.size, 2):
        cr, ci = T[lv, kc, j], T[lv, kc, j + 1]
        out[j] = cr * v[j] - ci * v[j + 1]
        out[j + 1] = cr * v[j + 1] + ci * v[j]


@_kernel
def _level_tables(lam_r, lam_i, n_real, V6, W, hl, T, LT, SM, lv, scr):
    """The coefficients, thin tables and small matrices of a step ``hl`` into slot ``lv``
    (``scr`` (4, n) scratch)."""
    n = lam_r.size
    _coefficients_folded(lam_r, lam_i, n_real, hl, T, lv)
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
def _residual(x0, x1, x2, x3, x_op, rt, c):
    """The outflows beyond their linearisation at plant state ``x``, per tank equation."""
    e0 = _root_excess(x_op[0], rt[0], x0 - x_op[0])
    e1 = _root_excess(x_op[1], rt[1], x1 - x_op[1])
    e2 = _root_excess(x_op[2], rt[2], x2 - x_op[2])
    e3 = _root_excess(x_op[3], rt[3], x3 - x_op[3])
    return c[4] * e2 - c[0] * e0, c[5] * e3 - c[1] * e1, -c[2] * e2, -c[3] * e3


@_kernel(inline="always")
def _small(SM, lv, base, r, a0, a1, a2, a3):
    """``SM[lv, base + r] . a``."""
    return SM[lv, base + r, 0] * a0 + SM[lv, base + r, 1] * a1 + SM[lv, base + r, 2] * a2 + SM[lv, base + r, 3] * a3


@_kernel
def folded_lane(P, level_per_state, x_op, h_op, lam_r, lam_i, n_real, V6, W, Tinv, gain, Bc, Dc, seg, n_seg,
                band_pct, h_top, kappa, amp_floor, metrics, work):
    """:func:`linearised_lane` with its stages folded into per-level tables (the same method and
    steps; rounding apart, the same numbers). ``work``: :func:`folded_workspace`."""
    c = P[P_COEF:P_COEF + 10]
    u_op = P[P_UOP:P_UOP + 2]
    t_dist, horizon = P[P_T_DIST], P[P_HORIZON]
    s = level_per_state
    n = lam_r.size
    state_limit = LEVEL_LIMIT / s
    T, LT, SM, SC, KF, scr, vec, w4, w2, ex, wb, sig = work
    y, Ny, k, tmp = vec[0], vec[1], vec[2], vec[3]
    x, x_mid, w, rt, f_op = w4[0], w4[1], w4[2], w4[3], w4[4]
    du0, du_mid, du_end, du_const = w2[0], w2[1], w2[2], w2[3]
    f0, fm, f1 = sig[0], sig[1], sig[2]
    n_levels = T.shape[0] - 1  # the last slot: a segment's shortened last step
    for lv in range(n_levels):
        _level_tables(lam_r, lam_i, n_real, V6, W, h_top / 2.0 ** lv, T, LT, SM, lv, scr)
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
        _segment_drive(seg[sg], d1, d2, c, f_op, u_op, Dc, Bc, Tinv, du_const, k)
        for lv in range(n_levels):
            _segment_constants(T, V6, k, n_real, lv, SC, KF, tmp)
        _readout(V6, y, x_op, du_const, x, du0)
        n_win = _visit_node(t, x, du0, s, d1, d2, h_op, u_op, post, 0, w, f0, w2, ex, wb, sig, first_node)
        first_node = False
        while t < t_end:
            ry0, ry1, ry2, ry3 = _residual(x[0], x[1], x[2], x[3], x_op, rt, c)
            for j in range(n):
                Ny[j] = k[j] + W[j, 0] * ry0 + W[j, 1] * ry1 + W[j, 2] * ry2 + W[j, 3] * ry3
            lv = _step_level(y, Ny, lam_r, lam_i, gain, n_real, amp_floor, kappa, h_top, n_levels)
            hs = h_top / 2.0 ** lv
            last = t + hs >= t_end * (1.0 - 1e-14)
            if last:
                hs = t_end - t
                lv = n_levels
                _level_tables(lam_r, lam_i, n_real, V6, W, hs, T, LT, SM, lv, scr)
                _segment_constants(T, V6, k, n_real, lv, SC, KF, tmp)
            # V6 E2 y and V4 E y, two partial sums per row
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
    return _finish_metrics(diverged, n_taken, w2, ex, wb, sig, h_op, horizon, t_dist, metrics)


def folded_workspace(n, n_levels=N_LEVELS):
    """The working arrays of :func:`folded_lane` for a loop of ``n`` states."""
    L = n_levels + 1
    return (np.empty((L, N_COEF_FOLDED, n)), np.empty((L, N_LT, n)), np.empty((L, N_SM, 4)), np.empty((L, N_SC)),
            np.empty((L, n)), np.empty((4, n)), np.empty((4, n)), np.empty((5, 4)), np.empty((13, 2)),
            np.empty((3, 2, 2)), np.empty((2, 2), dtype=np.bool_), np.empty((9, _N_SIG)))


def workspace(n, n_levels=N_LEVELS):
    """The working arrays of :func:`linearised_lane` for a loop of ``n`` states."""
    return (np.empty((n_levels + 1, N_COEF, n)), np.empty((11, n)), np.empty((6, 4)), np.empty((14, 2)),
            np.empty((3, 2, 2)), np.empty((2, 2), dtype=np.bool_), np.empty((9, _N_SIG)))


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

# The step rules measured: (h_top, kappa, amp_floor in cm or V).
RULES = ((1.0, 0.5, 1e-6), (1.0, 0.5, 1e-4), (1.0, 0.5, 1e-3), (1.0, 0.75, 1e-4), (1.0, 1.0, 1e-4))


def prototype_inputs(loop, ctrl, scenario):
    """The lane's inputs for a heurtune loop, controller and scenario: the scenario table, the
    operating state and levels, the controller's minimal realisation and the loop matrix."""
    P = loop._scenario_table(scenario)
    s = loop._level_per_state
    x_op, h_op = loop._state_op(), loop.op.h
    Ac, Bc, Cc, Dc = (np.ascontiguousarray(a, dtype=np.float64) for a in ctrl.minimal_realisation())
    L = loop_matrix(P[P_COEF:P_COEF + 10].copy(), P[P_UOP:P_UOP + 2].copy(), x_op, s, Ac, Bc, Cc, Dc)
    return P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L


def run_prototype(loop, ctrl, scenario, rule, work=None):
    """Metrics of the prototype under ``rule`` = (h_top, kappa, amp_floor): (ok, status, steps,
    metrics)."""
    P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L = prototype_inputs(loop, ctrl, scenario)
    ok, lam_r, lam_i, n_real, V6, W, Tinv, gain = modal_form(L, s, Cc, Dc)
    plan = loop.step_plan(ctrl, scenario)
    metrics = np.empty(N_METRICS)
    work = workspace(lam_r.size) if work is None else work
    status, steps = linearised_lane(P, s, x_op, h_op, lam_r, lam_i, n_real, V6, W, Tinv, gain, Bc, Dc, plan.table,
                                    plan.t0.size, 3.0, *rule, metrics, work)
    return ok, status, steps, metrics


def _median_ms(fn, repeats=30):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _rel(m, ref, idx, name):
    return m[idx[name]] / ref[idx[name]] - 1.0


def named_cases(idx):
    """The three loops of docs/model.md at each rule, against heurtune's loop at 0.125/16 s."""
    from qtp_cases import IOLQI_NMP, THESIS_MIN, WEAK

    from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
    from heurtune.objectives.qtp.model import preset

    print("| case | loop | rule (h_top, kappa, floor) | steps | IAE1, IAE2 rel. | J1 rel. | TV1 rel. | ts1 (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    cases = {"FOLQI min, thesis": ("min", "folqi", THESIS_MIN), "FOLQI min, weakly damped": ("min", "folqi", WEAK),
             "IOLQI nmp": ("nmp", "iolqi", IOLQI_NMP)}
    scenario = Scenario()

    def row(label, kind, rule, steps, m, ref):
        rel = [_rel(m, ref, idx, k) for k in ("IAE1", "IAE2", "J1", "TV1")]
        print(f"| {label} | {kind} | {rule} | {steps} | {rel[0]:+.1e}, {rel[1]:+.1e} | {rel[2]:+.1e} | "
              f"{rel[3]:+.1e} | {m[idx['ts1']]:.4f} (ref. {ref[idx['ts1']]:.4f}) |")

    for label, (case, kind, gains) in cases.items():
        loop = ClosedLoop(preset(case), kind)
        ctrl = loop.controller(gains)
        ref = loop.run(ctrl, Scenario(step=0.125 / 16), record=False).metrics
        sim = loop.run(ctrl, scenario, record=False)
        row(label, "heurtune, default tolerance", "", sim.steps, sim.metrics, ref)
        for rule in RULES:
            ok, status, steps, m = run_prototype(loop, ctrl, scenario, rule)
            row(label, "prototype" + ("" if ok else " (ill-conditioned T)"), rule, steps, m, ref)


def study_sets(idx, n, rule):
    """cs_folqi_qtp min: uniform, at-bounds and visited candidates (bench_study_candidates), each
    against heurtune's loop at 0.125/16 s: IAE errors, steps and time per candidate."""
    import warnings

    from bench_evaluate import forget_designs
    from bench_study_candidates import candidate_sets

    import heurtune

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
        sets = candidate_sets(prob, n, 1, True)
    loop = prob.loop
    scenario = prob.scenario(prob.tuning_scenario)
    tight = dataclasses.replace(scenario, step=0.125 / 16, tolerance=None)
    print(f"\ncs_folqi_qtp min, rule (h_top, kappa, floor) = {rule}; IAE relative errors against heurtune's loop "
          "at 0.125/16 s; ms per candidate, one core; the folded lane timed (the stage lane: its largest metric "
          "difference from the folded one, relative)")
    print("| set | n | ill-cond. | steps mean / max (heurtune) | max abs IAE rel. err. (heurtune) | > 1e-4 "
          "(heurtune) | max abs J rel. err. | stages vs folded | evaluate ms | heurtune loop ms | stability check "
          "ms | prototype set-up + lane ms | projected evaluate ms |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    works, folded_works = {}, {}

    def work_of(n, store=works, make=workspace):
        if n not in store:
            store[n] = make(n)
        return store[n]

    for label, X in sets.items():
        ctrls = [loop.controller(prob.values(x)) for x in X]
        errs, errs_h, jerr, steps, steps_h, bad, agree = [], [], [], [], [], 0, 0.0
        inputs = []
        plan = loop.step_plan(ctrls[0], scenario)
        for ctrl in ctrls:
            ref = loop.run(ctrl, tight, record=False).metrics
            sim = loop.run(ctrl, scenario, record=False)
            ok, status, st, m = run_prototype(loop, ctrl, scenario, rule, work_of(ctrl.A.shape[0] + 4))
            P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L = prototype_inputs(loop, ctrl, scenario)
            mf = np.empty(N_METRICS)
            folded_lane(P, s, x_op, h_op, *modal_form(L, s, Cc, Dc)[1:], Bc, Dc, plan.table, plan.t0.size, 3.0,
                        *rule, mf, work_of(L.shape[0], folded_works, folded_workspace))
            agree = max(agree, float(np.max(np.abs(mf[6:18] - m[6:18]) / np.abs(m[6:18]))))
            bad += not ok
            errs.append(max(abs(_rel(m, ref, idx, "IAE1")), abs(_rel(m, ref, idx, "IAE2"))))
            errs_h.append(max(abs(_rel(sim.metrics, ref, idx, "IAE1")), abs(_rel(sim.metrics, ref, idx, "IAE2"))))
            jerr.append(max(abs(_rel(m, ref, idx, "J1")), abs(_rel(m, ref, idx, "J2"))))
            steps.append(st)
            steps_h.append(sim.steps)
            inputs.append((P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L))

        def evaluate(X=X):
            forget_designs(filters=True)
            prob.evaluate(X)

        def heurtune_loops(ctrls=ctrls):
            for ctrl in ctrls:
                loop._continuous_metrics(ctrl, scenario, 3.0)

        def margins(ctrls=ctrls):
            for ctrl in ctrls:
                loop.stability_margin(ctrl)

        def prototype(inputs=inputs, plan=plan):
            metrics = np.empty(N_METRICS)
            for P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L in inputs:
                L = loop_matrix(P[P_COEF:P_COEF + 10], P[P_UOP:P_UOP + 2], x_op, s, Ac, Bc, Cc, Dc)
                form = modal_form(L, s, Cc, Dc)
                folded_lane(P, s, x_op, h_op, *form[1:], Bc, Dc, plan.table, plan.t0.size, 3.0, *rule, metrics,
                            work_of(L.shape[0], folded_works, folded_workspace))

        k = len(X)
        ev, hl, mg, pr = (_median_ms(f, 7) / k for f in (evaluate, heurtune_loops, margins, prototype))
        e = np.array(errs)
        print(f"| {label} | {k} | {bad} | {np.mean(steps):.0f} / {max(steps)} ({np.mean(steps_h):.0f} / "
              f"{max(steps_h)}) | {e.max():.1e} ({max(errs_h):.1e}) | {int((e > 1e-4).sum())} "
              f"({int((np.array(errs_h) > 1e-4).sum())}) | {max(jerr):.1e} | {agree:.0e} | {ev:.3f} | {hl:.3f} | "
              f"{mg:.3f} | {pr:.3f} | {ev - hl + pr:.3f} |")


def main(argv=None) -> int:
    import argparse

    from heurtune.objectives.qtp.loop import METRIC_NAMES
    from heurtune.runner.machine import cpu_name

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--candidates", type=int, default=40)
    ap.add_argument("--rule", type=float, nargs=3, default=(1.0, 0.5, 1e-3), help="h_top kappa amp_floor")
    args = ap.parse_args(argv)
    idx = {name: i for i, name in enumerate(METRIC_NAMES)}
    print(f"CPU: {cpu_name()}, one core, BLAS one thread")
    named_cases(idx)
    study_sets(idx, args.candidates, tuple(args.rule))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
