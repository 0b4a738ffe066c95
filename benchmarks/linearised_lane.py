"""A prototype of the next QTP kernel: the loop's whole linearisation integrated exactly, in numba.

The loop in deviations from the operating point, ``Y = (xi, z)`` (plant state minus its
operating value, in state units, and the controller's state), is

    Y' = L Y + g + [r(xi); 0],

``L`` the loop linearised at the operating point (plant Jacobian, the static feedback ``Dc``,
the controller's input ``Bc`` and dynamics ``Ac``, its drive ``Cc`` of the pumps), ``g`` the
constant drive of a segment (disturbances, operating voltages) and ``r`` what the square-root
outflows leave beyond their linearisation, second order in ``xi`` (written without
cancellation). ETDRK4 (Cox and Matthews) integrates ``L`` and ``g`` exactly and only ``r``
explicitly, in the modal coordinates of ``L = V diag(lam) V^-1`` (complex): every stage is a
product by diagonal coefficients and two thin products (the plant rows of ``V`` out, the plant
columns of ``V^-1`` in). heurtune's kernel (``continuous_kernels``) integrates the plant and the
feedback explicitly instead; ``benchmarks/splitting.py`` measures the two error constants in
numpy, this file what the split costs and gives when compiled, with heurtune's own metric
helpers folding each step's end and midpoint (the midpoint from the method's dense output at
theta = 1/2). No saturation, no level limits, metrics only.

Run with ``python benchmarks/linearised_lane.py``: per case (the thesis' FOLQI min gains, the
weakly damped FOLQI candidate, the IOLQI nmp loop) and step, the relative errors of IAE, J and
TV and the settling time against heurtune's loop at 0.125/16 s (itself within 1e-8 of Radau in
IAE for these loops), beside heurtune's default loop; then, one core, the median time of the
prototype's lane per step and of its set-up (the loop matrix, its eigendecomposition and
inverse), beside heurtune's whole simulation. The findings are in docs/model.md ("Where the
error comes from"). Not part of ``make bench``: a measurement for the kernel's next design.
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import functools  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402
from numba.core.cpu import CPUTargetOptions  # noqa: E402

from heurtune.objectives.qtp import continuous  # noqa: E402
from heurtune.objectives.qtp.continuous_kernels import (  # noqa: E402
    _N_SIG,
    SEG_DIST,
    SEG_GRADED,
    SEG_H,
    SEG_POST,
    SEG_STEPS,
    SEG_T0,
    SEG_UIN,
    _abs_moments,
    _crossing,
    _measure,
    _signals,
    _visit,
)
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

# Step levels h / 2^l, l = 0 .. N_LEVELS - 1: the plain step and the graded first steps after a
# discontinuity (h/16, h/16, h/8, h/4, h/2, as the switching kernel grades them).
N_LEVELS = 5
GRADED_LEVELS = (4, 4, 3, 2, 1)
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
def step_coefficients(lam, h, Tr, Ti):
    """The diagonal coefficients of a step ``h / 2^l`` for each level l, real and imaginary
    parts (``Tr``, ``Ti`` (N_LEVELS, N_COEF, n), names ``C_*``)."""
    for lv in range(N_LEVELS):
        hl = h / 2.0 ** lv
        for i in range(lam.size):
            z = lam[i] * hl
            p0, p1, p2, p3 = _phi3(z)
            q0, q1, q2, q3 = _phi3(0.5 * z)
            for k, v in ((C_E, p0), (C_E2, q0), (C_Q, 0.5 * hl * q1), (C_F1, hl * (p1 - 3.0 * p2 + 4.0 * p3)),
                         (C_F2, 2.0 * hl * (p2 - 2.0 * p3)), (C_F3, hl * (4.0 * p3 - p2)),
                         (C_G1, hl * (0.5 * q1 - 0.75 * q2 + 0.5 * q3)), (C_G2, hl * (0.5 * q2 - 0.5 * q3)),
                         (C_G3, hl * (0.5 * q3 - 0.25 * q2))):
                Tr[lv, k, i] = v.real
                Ti[lv, k, i] = v.imag


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
def _plant_rows(V4r, V4i, yr, yi):
    """``Re(V_x y)``: the plant deviation of modal state ``y`` (``V4r``, ``V4i`` (n, 4), the plant
    rows of V transposed). Two partial sums per row (even and odd modes), so that the
    additions of one row form two short chains instead of one long one (IEEE order, no
    reassociation licence)."""
    a0 = a1 = a2 = a3 = 0.0
    b0 = b1 = b2 = b3 = 0.0
    n = yr.size
    j = 0
    while j + 1 < n:
        p, q = yr[j], yi[j]
        a0 += V4r[j, 0] * p - V4i[j, 0] * q
        a1 += V4r[j, 1] * p - V4i[j, 1] * q
        a2 += V4r[j, 2] * p - V4i[j, 2] * q
        a3 += V4r[j, 3] * p - V4i[j, 3] * q
        p, q = yr[j + 1], yi[j + 1]
        b0 += V4r[j + 1, 0] * p - V4i[j + 1, 0] * q
        b1 += V4r[j + 1, 1] * p - V4i[j + 1, 1] * q
        b2 += V4r[j + 1, 2] * p - V4i[j + 1, 2] * q
        b3 += V4r[j + 1, 3] * p - V4i[j + 1, 3] * q
        j += 2
    if j < n:
        p, q = yr[j], yi[j]
        a0 += V4r[j, 0] * p - V4i[j, 0] * q
        a1 += V4r[j, 1] * p - V4i[j, 1] * q
        a2 += V4r[j, 2] * p - V4i[j, 2] * q
        a3 += V4r[j, 3] * p - V4i[j, 3] * q
    return a0 + b0, a1 + b1, a2 + b2, a3 + b3


@_kernel(inline="always")
def _remainder(V4r, V4i, yr, yi, x_op, rt, c, Wr, Wi, kr, ki, Nr, Ni):
    """The modal drive ``N = k + W r(xi)`` of modal state ``y`` (``xi`` its plant deviation)."""
    x0, x1, x2, x3 = _plant_rows(V4r, V4i, yr, yi)
    e0 = _root_excess(x_op[0], rt[0], x0)
    e1 = _root_excess(x_op[1], rt[1], x1)
    e2 = _root_excess(x_op[2], rt[2], x2)
    e3 = _root_excess(x_op[3], rt[3], x3)
    r0 = c[4] * e2 - c[0] * e0
    r1 = c[5] * e3 - c[1] * e1
    r2 = -c[2] * e2
    r3 = -c[3] * e3
    for j in range(yr.size):
        Nr[j] = kr[j] + Wr[j, 0] * r0 + Wr[j, 1] * r1 + Wr[j, 2] * r2 + Wr[j, 3] * r3
        Ni[j] = ki[j] + Wi[j, 0] * r0 + Wi[j, 1] * r1 + Wi[j, 2] * r2 + Wi[j, 3] * r3


@_kernel(inline="always")
def _readout(V4r, V4i, Vur, Vui, yr, yi, x_op, du_const, x, du):
    """Plant state ``x`` and controller voltage deviations ``du`` of modal state ``y``
    (``Vur``, ``Vui`` (n, 2): the voltage rows transposed)."""
    x0, x1, x2, x3 = _plant_rows(V4r, V4i, yr, yi)
    x[0] = x_op[0] + x0
    x[1] = x_op[1] + x1
    x[2] = x_op[2] + x2
    x[3] = x_op[3] + x3
    a0 = a1 = b0 = b1 = 0.0
    n = yr.size
    j = 0
    while j + 1 < n:
        a0 += Vur[j, 0] * yr[j] - Vui[j, 0] * yi[j]
        a1 += Vur[j, 1] * yr[j] - Vui[j, 1] * yi[j]
        b0 += Vur[j + 1, 0] * yr[j + 1] - Vui[j + 1, 0] * yi[j + 1]
        b1 += Vur[j + 1, 1] * yr[j + 1] - Vui[j + 1, 1] * yi[j + 1]
        j += 2
    if j < n:
        a0 += Vur[j, 0] * yr[j] - Vui[j, 0] * yi[j]
        a1 += Vur[j, 1] * yr[j] - Vui[j, 1] * yi[j]
    du[0] = du_const[0] + a0 + b0
    du[1] = du_const[1] + a1 + b1


@njit(cache=True)
def modal_form(L, s, Cc, Dc):
    """Eigendecomposition of ``L`` and the thin products the stages take.

    Returns
    -------
    ok : bool (False: LAPACK failed or the eigenvectors are conditioned worse than COND_LIMIT)
    lam : (n,) complex eigenvalues
    V4r, V4i : (n, 4) the plant rows of V, transposed; Vur, Vui : (n, 2) the voltage rows
    ``s Dc V_x + Cc V_z``, transposed;
    Wr, Wi : (n, 4) the plant columns of V^-1; Vinv : (n, n) complex
    """
    n = L.shape[0]
    nc = n - 4
    lam, V = np.linalg.eig(L.astype(np.complex128))
    Vinv = np.linalg.inv(V)
    cond = np.abs(V).sum(axis=0).max() * np.abs(Vinv).sum(axis=0).max()
    ok = np.isfinite(cond) and cond <= COND_LIMIT
    Vu = np.zeros((2, n), dtype=np.complex128)
    for r in range(2):
        for j in range(n):
            acc = 0.0 + 0.0j
            for k in range(4):
                acc += s * Dc[r, k] * V[k, j]
            for k in range(nc):
                acc += Cc[r, k] * V[4 + k, j]
            Vu[r, j] = acc
    V4 = np.ascontiguousarray(V[:4, :].T)
    W = np.ascontiguousarray(Vinv[:, :4])
    VuT = Vu.T
    return (ok, lam, np.ascontiguousarray(V4.real), np.ascontiguousarray(V4.imag), np.ascontiguousarray(VuT.real),
            np.ascontiguousarray(VuT.imag), np.ascontiguousarray(W.real), np.ascontiguousarray(W.imag), Vinv)


@_kernel
def linearised_lane(P, level_per_state, x_op, h_op, lam, V4r, V4i, Vur, Vui, Wr, Wi, Vinv, Bc, Dc, seg, n_seg,
                    band_pct, metrics, work):
    """The loop of one controller under one scenario, metrics only (no saturation, no limits).

    Parameters
    ----------
    P : (NP,) the scenario table (``kernels.scenario_table``: plant coefficients, operating
        voltages, disturbance time, horizon); level_per_state : float; x_op : (4,) operating
        state; h_op : (4,) operating levels; lam, V4r .. Vinv: :func:`modal_form`; Bc (nc, 4),
        Dc (2, 4): the controller's input matrices; seg : (S, N_SEG) the step plan
        (``continuous.StepPlan.table``; ``SEG_H`` the step, graded first steps after a
        discontinuity); n_seg : rows used; band_pct : settling band in percent
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
    n = lam.size
    nc = n - 4
    state_limit = LEVEL_LIMIT / s
    Tr, Ti, vec, w4, w2, ex, wb, sig = work
    yr, yi, ar, ai, br, bi, cr, ci = vec[0], vec[1], vec[2], vec[3], vec[4], vec[5], vec[6], vec[7]
    Nur, Nui, Nar, Nai, Nbr, Nbi, Ncr, Nci = vec[8], vec[9], vec[10], vec[11], vec[12], vec[13], vec[14], vec[15]
    mr, mi_, kr, ki = vec[16], vec[17], vec[18], vec[19]
    x, x_mid, w, rt, f_op = w4[0], w4[1], w4[2], w4[3], w4[4]
    du0, du_mid, du_end, du_const, band, u_prev = w2[0], w2[1], w2[2], w2[3], w2[4], w2[5]
    iae, ise, itae, jj, jdev, tv, mp = w2[6], w2[7], w2[8], w2[9], w2[10], w2[11], w2[12]
    ex_prev, ex_out, ex_in = ex[0], ex[1], ex[2]
    ex_has_prev, pending = wb[0], wb[1]
    f0, fm, f1, lo, hi = sig[0], sig[1], sig[2], sig[3], sig[4]
    win_v, win_t = sig[5:8], sig[8, :3]
    for j in range(n):
        yr[j] = 0.0
        yi[j] = 0.0
    for i in range(4):
        rt[i] = math.sqrt(max(x_op[i], 0.0))
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
    for i in range(_N_SIG):
        lo[i] = math.inf
        hi[i] = -math.inf
        for r in range(3):
            win_v[r, i] = 0.0
    for r in range(3):
        win_t[r] = 0.0
    for j in range(2):
        band[j] = band_pct / 100.0 * h_op[j]
    # the operating point's own drive (zero up to rounding for an exact operating point)
    f_op[0] = c[4] * rt[2] - c[0] * rt[0]
    f_op[1] = c[5] * rt[3] - c[1] * rt[1]
    f_op[2] = -c[2] * rt[2]
    f_op[3] = -c[3] * rt[3]
    n_taken = 0
    diverged = False
    first_node = True
    h_tab = -1.0
    for sg in range(n_seg):
        d1 = seg[sg, SEG_DIST]
        d2 = seg[sg, SEG_DIST + 1]
        post = seg[sg, SEG_POST] > 0.0
        t = seg[sg, SEG_T0]
        h = seg[sg, SEG_H]
        n_plain = int(seg[sg, SEG_STEPS])
        graded = seg[sg, SEG_GRADED] > 0.0
        t_end = horizon if sg == n_seg - 1 else t + h * n_plain
        if h != h_tab:
            step_coefficients(lam, h, Tr, Ti)
            h_tab = h
        # the segment's constant drive g = [f_op + Bp (u_op + uin + Dc d); Bc d], in modal form
        for j in range(2):
            du_const[j] = Dc[j, 0] * d1 + Dc[j, 1] * d2
        for j in range(n):
            kr[j] = 0.0
            ki[j] = 0.0
        for i in range(4):
            p = _PUMP[i]
            gx = f_op[i] + c[_PUMP_COEF[i]] * (u_op[p] + seg[sg, SEG_UIN + p] + du_const[p])
            for j in range(n):
                v = Vinv[j, i] * gx
                kr[j] += v.real
                ki[j] += v.imag
        for r in range(nc):
            gz = Bc[r, 0] * d1 + Bc[r, 1] * d2
            if gz != 0.0:
                for j in range(n):
                    v = Vinv[j, 4 + r] * gz
                    kr[j] += v.real
                    ki[j] += v.imag
        # the segment's first node (a jump of the measurement is in it)
        _readout(V4r, V4i, Vur, Vui, yr, yi, x_op, du_const, x, du0)
        _measure(x, s, d1, d2, h_op, w)
        _signals(w, x, s, u_op, du0, f0)
        n_win = _visit(t, f0, post, band, 0, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in, ex_has_prev,
                       pending, tv, u_prev, first_node)
        first_node = False
        n_steps = n_plain + (4 if graded else 0)
        for k in range(n_steps):
            if graded and k < 5:
                lv = GRADED_LEVELS[k]
            else:
                lv = 0
            hs = h / 2.0 ** lv
            if k == n_steps - 1:
                hs = t_end - t
            _remainder(V4r, V4i, yr, yi, x_op, rt, c, Wr, Wi, kr, ki, Nur, Nui)
            for j in range(n):  # a = E2 y + Q N(y)
                e2r, e2i, qr, qi = Tr[lv, C_E2, j], Ti[lv, C_E2, j], Tr[lv, C_Q, j], Ti[lv, C_Q, j]
                ar[j] = e2r * yr[j] - e2i * yi[j] + qr * Nur[j] - qi * Nui[j]
                ai[j] = e2r * yi[j] + e2i * yr[j] + qr * Nui[j] + qi * Nur[j]
            _remainder(V4r, V4i, ar, ai, x_op, rt, c, Wr, Wi, kr, ki, Nar, Nai)
            for j in range(n):  # b = E2 y + Q N(a)
                e2r, e2i, qr, qi = Tr[lv, C_E2, j], Ti[lv, C_E2, j], Tr[lv, C_Q, j], Ti[lv, C_Q, j]
                br[j] = e2r * yr[j] - e2i * yi[j] + qr * Nar[j] - qi * Nai[j]
                bi[j] = e2r * yi[j] + e2i * yr[j] + qr * Nai[j] + qi * Nar[j]
            _remainder(V4r, V4i, br, bi, x_op, rt, c, Wr, Wi, kr, ki, Nbr, Nbi)
            for j in range(n):  # c = E2 a + Q (2 N(b) - N(y))
                e2r, e2i, qr, qi = Tr[lv, C_E2, j], Ti[lv, C_E2, j], Tr[lv, C_Q, j], Ti[lv, C_Q, j]
                sr = 2.0 * Nbr[j] - Nur[j]
                si = 2.0 * Nbi[j] - Nui[j]
                cr[j] = e2r * ar[j] - e2i * ai[j] + qr * sr - qi * si
                ci[j] = e2r * ai[j] + e2i * ar[j] + qr * si + qi * sr
            _remainder(V4r, V4i, cr, ci, x_op, rt, c, Wr, Wi, kr, ki, Ncr, Nci)
            for j in range(n):  # the midpoint (dense output at 1/2) and the step's end
                sr = Nar[j] + Nbr[j]
                si = Nai[j] + Nbi[j]
                e2r, e2i = Tr[lv, C_E2, j], Ti[lv, C_E2, j]
                g1r, g1i, g2r, g2i = Tr[lv, C_G1, j], Ti[lv, C_G1, j], Tr[lv, C_G2, j], Ti[lv, C_G2, j]
                g3r, g3i = Tr[lv, C_G3, j], Ti[lv, C_G3, j]
                mr[j] = (e2r * yr[j] - e2i * yi[j] + g1r * Nur[j] - g1i * Nui[j] + g2r * sr - g2i * si
                         + g3r * Ncr[j] - g3i * Nci[j])
                mi_[j] = (e2r * yi[j] + e2i * yr[j] + g1r * Nui[j] + g1i * Nur[j] + g2r * si + g2i * sr
                          + g3r * Nci[j] + g3i * Ncr[j])
                er, ei = Tr[lv, C_E, j], Ti[lv, C_E, j]
                f1r, f1i, f2r, f2i = Tr[lv, C_F1, j], Ti[lv, C_F1, j], Tr[lv, C_F2, j], Ti[lv, C_F2, j]
                f3r, f3i = Tr[lv, C_F3, j], Ti[lv, C_F3, j]
                nr = (er * yr[j] - ei * yi[j] + f1r * Nur[j] - f1i * Nui[j] + f2r * sr - f2i * si
                      + f3r * Ncr[j] - f3i * Nci[j])
                ni = (er * yi[j] + ei * yr[j] + f1r * Nui[j] + f1i * Nur[j] + f2r * si + f2i * sr
                      + f3r * Nci[j] + f3i * Ncr[j])
                yr[j] = nr
                yi[j] = ni
            n_taken += 1
            _readout(V4r, V4i, Vur, Vui, mr, mi_, x_op, du_const, x_mid, du_mid)
            _readout(V4r, V4i, Vur, Vui, yr, yi, x_op, du_const, x, du_end)
            if not (abs(x[0]) + abs(x[1]) + abs(x[2]) + abs(x[3]) < state_limit):
                diverged = True
                break
            _measure(x_mid, s, d1, d2, h_op, w)
            _signals(w, x_mid, s, u_op, du_mid, fm)
            n_win = _visit(t + 0.5 * hs, fm, post, band, n_win, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in,
                           ex_has_prev, pending, tv, u_prev, False)
            _measure(x, s, d1, d2, h_op, w)
            _signals(w, x, s, u_op, du_end, f1)
            n_win = _visit(t + hs, f1, post, band, n_win, win_t, win_v, lo, hi, mp, ex_prev, ex_out, ex_in,
                           ex_has_prev, pending, tv, u_prev, False)
            # Simpson's rule over the step (IAE and ITAE split at the error's zero crossings)
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
            t = t_end if k == n_steps - 1 else t + hs
        if diverged:
            break
    if diverged:
        for i in range(N_METRICS):
            metrics[i] = math.nan
        return STATUS_DIVERGED, n_taken
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
    return STATUS_OK, n_taken


def workspace(n):
    """The working arrays of :func:`linearised_lane` for a loop of ``n`` states."""
    return (np.empty((N_LEVELS, N_COEF, n)), np.empty((N_LEVELS, N_COEF, n)), np.empty((20, n)), np.empty((5, 4)),
            np.empty((13, 2)), np.empty((3, 2, 2)), np.empty((2, 2), dtype=np.bool_), np.empty((9, _N_SIG)))


sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def prototype_inputs(loop, ctrl, scenario):
    """The lane's inputs for a heurtune loop, controller and scenario: the scenario table, the
    operating state and levels, :func:`modal_form` of the loop matrix, the controller's input
    matrices."""
    P = loop._scenario_table(scenario)
    s = loop._level_per_state
    x_op, h_op = loop._state_op(), loop.op.h
    Ac, Bc, Cc, Dc = (np.ascontiguousarray(a, dtype=np.float64) for a in ctrl.minimal_realisation())
    L = loop_matrix(P[P_COEF:P_COEF + 10].copy(), P[P_UOP:P_UOP + 2].copy(), x_op, s, Ac, Bc, Cc, Dc)
    return P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L


def run_prototype(loop, ctrl, scenario, step):
    """Metrics of the prototype at a fixed ``step`` (graded after the disturbance): (ok, status,
    steps, metrics)."""
    P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L = prototype_inputs(loop, ctrl, scenario)
    ok, lam, V4r, V4i, Vur, Vui, Wr, Wi, Vinv = modal_form(L, s, Cc, Dc)
    plan = continuous.plan_steps(scenario.horizon, step, scenario.output_disturbance, scenario.disturbance_time,
                                 scenario.input_disturbance, scenario.input_disturbance_time)
    metrics = np.empty(N_METRICS)
    status, steps = linearised_lane(P, s, x_op, h_op, lam, V4r, V4i, Vur, Vui, Wr, Wi, Vinv, Bc, Dc, plan.table,
                                    plan.t0.size, 3.0, metrics, workspace(lam.size))
    return ok, status, steps, metrics


def _median_ms(fn, repeats=30):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main() -> int:
    from qtp_cases import IOLQI_NMP, THESIS_MIN, WEAK

    from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario
    from heurtune.objectives.qtp.model import preset
    from heurtune.runner.machine import cpu_name

    idx = {name: i for i, name in enumerate(METRIC_NAMES)}
    print(f"CPU: {cpu_name()}, one core")
    print("| case | loop | step (s) | steps | IAE1, IAE2 rel. | J1 rel. | TV1 rel. | ts1 (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    cases = {"FOLQI min, thesis": ("min", "folqi", THESIS_MIN), "FOLQI min, weakly damped": ("min", "folqi", WEAK),
             "IOLQI nmp": ("nmp", "iolqi", IOLQI_NMP)}
    scenario = Scenario()

    def row(label, kind, step, steps, m, ref):
        rel = [m[idx[k]] / ref[idx[k]] - 1.0 for k in ("IAE1", "IAE2", "J1", "TV1")]
        print(f"| {label} | {kind} | {step} | {steps} | {rel[0]:+.1e}, {rel[1]:+.1e} | {rel[2]:+.1e} | "
              f"{rel[3]:+.1e} | {m[idx['ts1']]:.4f} (ref. {ref[idx['ts1']]:.4f}) |")

    timings = []
    for label, (case, kind, gains) in cases.items():
        loop = ClosedLoop(preset(case), kind)
        ctrl = loop.controller(gains)
        ref = loop.run(ctrl, Scenario(step=0.125 / 16), record=False).metrics
        sim = loop.run(ctrl, scenario, record=False)
        row(label, "heurtune, default tolerance", "rule", sim.steps, sim.metrics, ref)
        for step in (0.125, 0.25, 0.5, 1.0):
            ok, status, steps, m = run_prototype(loop, ctrl, scenario, step)
            row(label, "prototype" + ("" if ok else " (ill-conditioned V)"), step, steps, m, ref)
        P, s, x_op, h_op, (Ac, Bc, Cc, Dc), L = prototype_inputs(loop, ctrl, scenario)
        form = modal_form(L, s, Cc, Dc)
        plan = continuous.plan_steps(scenario.horizon, 0.25, scenario.output_disturbance, scenario.disturbance_time,
                                     scenario.input_disturbance, scenario.input_disturbance_time)
        metrics = np.empty(N_METRICS)
        work = workspace(L.shape[0])
        coef, u_op = P[P_COEF:P_COEF + 10].copy(), P[P_UOP:P_UOP + 2].copy()

        def lane(P=P, s=s, x_op=x_op, h_op=h_op, form=form, Bc=Bc, Dc=Dc, plan=plan, metrics=metrics, work=work):
            linearised_lane(P, s, x_op, h_op, *form[1:], Bc, Dc, plan.table, plan.t0.size, 3.0, metrics, work)

        def setup(coef=coef, u_op=u_op, x_op=x_op, s=s, Ac=Ac, Bc=Bc, Cc=Cc, Dc=Dc):
            modal_form(loop_matrix(coef, u_op, x_op, s, Ac, Bc, Cc, Dc), s, Cc, Dc)

        def heurtune_run(loop=loop, ctrl=ctrl):
            loop.run(ctrl, scenario, record=False)

        lane_ms, setup_ms, heurtune_ms = _median_ms(lane), _median_ms(setup), _median_ms(heurtune_run)
        timings.append((label, L.shape[0], 1e3 * lane_ms / plan.n_steps, setup_ms, heurtune_ms, sim.steps))
    print()
    print("| case | loop states | prototype: us per step | prototype: set-up ms | heurtune: ms per simulation "
          "(steps) |")
    print("| --- | --- | --- | --- | --- |")
    for label, n, per_step, setup_ms, heurtune_ms, steps in timings:
        print(f"| {label} | {n} | {per_step:.2f} | {setup_ms:.3f} | {heurtune_ms:.3f} ({steps}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
