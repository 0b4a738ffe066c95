"""Numba kernel of the QTP closed loop for many candidates side by side (CPU, SIMD lanes).

:func:`simulate_batch` advances ``L`` lanes (a lane is one candidate under one scenario) in the
same time loop. Every per-lane quantity is stored structure-of-arrays, lanes last, so that each
inner loop runs over the lanes with unit stride and LLVM turns it into vector instructions: the
square roots of the RK4 chain of eight candidates fill one AVX-512 register instead of waiting on
each other. The arithmetic of a lane is that of :func:`heurtune.objectives.qtp.kernels.simulate_loop`,
in the same order, and the metrics are folded by the same functions from the same buffered
samples; only the rounding of the controller's sums differs (the single-candidate kernel lets the
compiler regroup a sum over the states, here a lane sums its states in order), which moves the
metrics by a few units in the last place (the tests bound it).

Lanes whose controller has the same structure (number of modal and dense states, their inputs,
pumps and ``segments``) share one call: the structure is an argument shared by all lanes, the
numbers are per lane.
"""

import math

import numpy as np
from numba import njit

from heurtune.objectives.qtp.kernels import (
    _FAST,
    IN_STATE,
    LEVEL_LIMIT,
    METRIC_BLOCK,
    N_METRICS,
    NP,
    OUT_STATE,
    P_CLIP,
    P_HMAX,
    P_I_IN,
    P_I_OUT,
    P_IN,
    P_OUT,
    P_SAT,
    P_UMAX,
    P_UMIN,
    P_UOP,
    STATUS_DIVERGED,
    STATUS_OK,
    _finish_input,
    _finish_output,
    _finish_range,
    _fold_input,
    _fold_output,
    _output_state_init,
    _rk4_clipped,
    _rk4_limited,
)

__all__ = ["simulate_batch", "NP"]


@njit(cache=True, fastmath=_FAST, inline="always")
def _rk4_fast(h1, h2, h3, h4, f1, f2, f3, f4, c0, c1, c2, c3, c4, c5, dt):
    """The fast path of :func:`heurtune.objectives.qtp.kernels._rk4_step` without its branch, so
    that a loop over lanes vectorises: the four new levels and ``ok``, False when a stage argument
    is negative (or NaN), where the lane's step is redone by ``_rk4_clipped``.

    The formulas are those of ``_rk4_step``, whose code stays as it is: its arrangement fixes the
    rounding of the shipped experiments.
    """
    half = 0.5 * dt
    sixth = dt / 6.0
    p1, p2, p3, p4 = h1 + half * f1, h2 + half * f2, h3 + half * f3, h4 + half * f4
    q1, q2, q3, q4 = h1 + dt * f1, h2 + dt * f2, h3 + dt * f3, h4 + dt * f4
    hc0, hc1, hc2, hc3, hc4, hc5 = half * c0, half * c1, half * c2, half * c3, half * c4, half * c5
    dc0, dc1, dc2, dc3, dc4, dc5 = dt * c0, dt * c1, dt * c2, dt * c3, dt * c4, dt * c5
    s1, s2, s3, s4 = math.sqrt(h1), math.sqrt(h2), math.sqrt(h3), math.sqrt(h4)
    x1, x2, x3, x4 = p1 - hc0 * s1 + hc4 * s3, p2 - hc1 * s2 + hc5 * s4, p3 - hc2 * s3, p4 - hc3 * s4
    t1, t2, t3, t4 = math.sqrt(x1), math.sqrt(x2), math.sqrt(x3), math.sqrt(x4)
    y1, y2, y3, y4 = p1 - hc0 * t1 + hc4 * t3, p2 - hc1 * t2 + hc5 * t4, p3 - hc2 * t3, p4 - hc3 * t4
    v1, v2, v3, v4 = math.sqrt(y1), math.sqrt(y2), math.sqrt(y3), math.sqrt(y4)
    z1, z2, z3, z4 = q1 - dc0 * v1 + dc4 * v3, q2 - dc1 * v2 + dc5 * v4, q3 - dc2 * v3, q4 - dc3 * v4
    r1, r2, r3, r4 = math.sqrt(z1), math.sqrt(z2), math.sqrt(z3), math.sqrt(z4)
    lowest = min(min(min(h1, h2), min(h3, h4)), min(min(x1, x2), min(x3, x4)))
    lowest = min(lowest, min(min(min(y1, y2), min(y3, y4)), min(min(z1, z2), min(z3, z4))))
    o3 = s3 + 2.0 * t3 + 2.0 * v3 + r3
    o4 = s4 + 2.0 * t4 + 2.0 * v4 + r4
    return (q1 + sixth * (c4 * o3 - c0 * (s1 + 2.0 * t1 + 2.0 * v1 + r1)),
            q2 + sixth * (c5 * o4 - c1 * (s2 + 2.0 * t2 + 2.0 * v2 + r2)),
            q3 - sixth * c2 * o3,
            q4 - sixth * c3 * o4, lowest >= 0.0)


@njit(cache=True, fastmath=_FAST)
def simulate_batch(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
                   dt, n_steps, noise, lane_noise, band_pct, metrics, status):
    """:func:`~heurtune.objectives.qtp.kernels.simulate_loop` of ``L`` lanes side by side
    (metrics only).

    The time loop is a sequence of short loops over the lanes, each reading a few lane-last
    arrays and writing one, so that LLVM vectorises them (the arrays may alias as far as it
    knows; few of them keep its run-time overlap checks few). What a lane cannot do in vector
    form (a step with a level at 0 or a tank limit, the metric folds of a block, divergence) is
    done lane by lane in separate loops.

    Parameters
    ----------
    P : (NP, L) per-lane parameters, one column of :func:`~heurtune.objectives.qtp.kernels.scenario_table`
        per lane (rows ``P_*`` of :mod:`~heurtune.objectives.qtp.kernels`): ``c`` (10 rows, see
        ``plant_coefficients``), ``u_op`` (2), ``u_min``, ``u_max``, ``saturate``,
        ``clip_levels`` (1.0 or 0.0), ``out_dist`` (2), ``in_dist`` (2), ``i_out_dist``,
        ``i_in_dist`` (sample indices) and ``h_max`` (4), as :func:`simulate_loop` takes them
    level_per_state : float; h_init, h_op : (4,) shared initial state and operating levels
    ad, bd : (nd, L) modal factors and gains; state_input : (nd,) int64, shared
    Ad : (nq, nq, L), Bd : (nq, 4, L), Cc : (2, nd + nq, L), Dc : (2, 4, L)
    state_channel : (nd + nq,) int64 and segments : (4,) int64, shared (see ``DiscreteController``)
    dt : float; n_steps : int, shared
    noise : (S, n_steps + 1, 4) measurement noise of S noise draws (S may be 0)
    lane_noise : (L,) int64, the draw each lane reads, or -1 for none
    band_pct : float
    metrics : (L, N_METRICS) output; status : (L,) int64 output, as ``simulate_loop`` returns
    """
    L = P.shape[1]
    nd = ad.shape[0]
    nq = Ad.shape[0]
    nz = nd + nq
    g1, nu = segments[1], segments[2]
    H = np.empty((4, L))
    for j in range(4):
        for lane in range(L):
            H[j, lane] = h_init[j]
    Hn = np.empty((5, L))  # the next states and, row 4, whether the vector step stands
    z = np.zeros((nz, L))
    zd = np.empty((max(nq, 1), L))
    W = np.empty((4, L))
    U = np.empty((4, L))  # applied voltages, then whether each pump's states are frozen (1.0)
    CZ = np.zeros((2, L))
    R = np.empty((2, L))  # lowest and highest true state
    for lane in range(L):
        R[0, lane] = math.inf
        R[1, lane] = -math.inf
    active = np.ones(L, dtype=np.bool_)
    n_active = L
    buf = np.empty((L, 4, METRIC_BLOCK))  # each lane's rows contiguous, as the folds read them
    so = np.empty((L, 2, OUT_STATE))
    si = np.zeros((L, 2, IN_STATE))
    for lane in range(L):
        _output_state_init(so[lane, 0])
        _output_state_init(so[lane, 1])
    band1 = band_pct / 100.0 * h_op[0]
    band2 = band_pct / 100.0 * h_op[1]
    h_op0, h_op1, h_op2, h_op3 = h_op[0], h_op[1], h_op[2], h_op[3]
    state_limit = LEVEL_LIMIT / level_per_state
    has_noise = False
    any_sat = False
    for lane in range(L):
        has_noise = has_noise or lane_noise[lane] >= 0
        any_sat = any_sat or P[P_SAT, lane] > 0.0
    nb = 0
    k0 = 0
    for k in range(n_steps + 1):
        kf = float(k)
        for lane in range(L):
            on = kf >= P[P_I_OUT, lane]
            W[0, lane] = level_per_state * H[0, lane] + ((P[P_OUT, lane] if on else 0.0) - h_op0)
            W[1, lane] = level_per_state * H[1, lane] + ((P[P_OUT + 1, lane] if on else 0.0) - h_op1)
            W[2, lane] = level_per_state * H[2, lane] - h_op2
            W[3, lane] = level_per_state * H[3, lane] - h_op3
        if has_noise:
            for lane in range(L):
                s = lane_noise[lane]
                if s >= 0:
                    for j in range(4):
                        W[j, lane] += noise[s, k, j]
        for lane in range(L):
            w0, w1, w2, w3 = W[0, lane], W[1, lane], W[2, lane], W[3, lane]
            u1 = (P[P_UOP, lane] + CZ[0, lane] + Dc[0, 0, lane] * w0 + Dc[0, 1, lane] * w1
                  + Dc[0, 2, lane] * w2 + Dc[0, 3, lane] * w3)
            u2 = (P[P_UOP + 1, lane] + CZ[1, lane] + Dc[1, 0, lane] * w0 + Dc[1, 1, lane] * w1
                  + Dc[1, 2, lane] * w2 + Dc[1, 3, lane] * w3)
            lo_u, hi_u = P[P_UMIN, lane], P[P_UMAX, lane]
            sat = P[P_SAT, lane] > 0.0
            U[2, lane] = 1.0 if sat & ((u1 > hi_u) | (u1 < lo_u)) else 0.0
            U[3, lane] = 1.0 if sat & ((u2 > hi_u) | (u2 < lo_u)) else 0.0
            U[0, lane] = min(max(u1, lo_u), hi_u) if sat else u1
            U[1, lane] = min(max(u2, lo_u), hi_u) if sat else u2
        for lane in range(L):
            buf[lane, 0, nb] = abs(W[0, lane])
            buf[lane, 1, nb] = abs(W[1, lane])
            buf[lane, 2, nb] = U[0, lane]
            buf[lane, 3, nb] = U[1, lane]
        for lane in range(L):
            R[0, lane] = min(R[0, lane], min(min(H[0, lane], H[1, lane]), min(H[2, lane], H[3, lane])))
            R[1, lane] = max(R[1, lane], max(max(H[0, lane], H[1, lane]), max(H[2, lane], H[3, lane])))
        nb += 1
        if nb == METRIC_BLOCK or k == n_steps:
            for lane in range(L):
                if not active[lane]:
                    continue
                i_dist = int(P[P_I_OUT, lane])
                _fold_output(buf[lane, 0], k0, nb, i_dist, band1, so[lane, 0])
                _fold_output(buf[lane, 1], k0, nb, i_dist, band2, so[lane, 1])
                _fold_input(buf[lane, 2], k0, nb, P[P_UOP, lane], si[lane, 0])
                _fold_input(buf[lane, 3], k0, nb, P[P_UOP + 1, lane], si[lane, 1])
            k0 += nb
            nb = 0
        if k == n_steps:
            break
        # Controller states: modal (single input, in place; held while their pump is frozen),
        # then dense, then Cc z of the next sample.
        for lane in range(L):
            CZ[0, lane] = 0.0
            CZ[1, lane] = 0.0
        if any_sat:
            for i in range(nd):
                src = state_input[i]
                fr = 2 + state_channel[i]
                for lane in range(L):
                    zi = ad[i, lane] * z[i, lane] + bd[i, lane] * W[src, lane]
                    z[i, lane] = z[i, lane] if U[fr, lane] > 0.0 else zi
            # A saturated lane sums Cc z over the unit states of both pumps, as the
            # single-candidate kernel does then; the others add their unit states with weight 1.
            for i in range(nu):
                pump = 0 if i < g1 else 1
                for lane in range(L):
                    zi = z[i, lane]
                    sat = P[P_SAT, lane] > 0.0
                    CZ[0, lane] += Cc[0, i, lane] * zi if sat else (zi if pump == 0 else 0.0)
                    CZ[1, lane] += Cc[1, i, lane] * zi if sat else (zi if pump == 1 else 0.0)
        else:
            # No saturation in this call: each unit state is updated and added to its pump's
            # output in one pass, the other modal states are updated.
            for i in range(g1):
                for lane in range(L):
                    zi = ad[i, lane] * z[i, lane] + bd[i, lane] * W[0, lane]
                    z[i, lane] = zi
                    CZ[0, lane] += zi
            for i in range(g1, nu):
                for lane in range(L):
                    zi = ad[i, lane] * z[i, lane] + bd[i, lane] * W[1, lane]
                    z[i, lane] = zi
                    CZ[1, lane] += zi
            for i in range(nu, nd):
                src = state_input[i]
                for lane in range(L):
                    z[i, lane] = ad[i, lane] * z[i, lane] + bd[i, lane] * W[src, lane]
        if nq > 0:
            for i in range(nq):
                for lane in range(L):
                    zd[i, lane] = (Bd[i, 0, lane] * W[0, lane] + Bd[i, 1, lane] * W[1, lane]
                                   + Bd[i, 2, lane] * W[2, lane] + Bd[i, 3, lane] * W[3, lane])
                for j in range(nq):
                    for lane in range(L):
                        zd[i, lane] += Ad[i, j, lane] * z[nd + j, lane]
            for i in range(nq):
                fr = 2 + state_channel[nd + i]
                for lane in range(L):
                    z[nd + i, lane] = z[nd + i, lane] if U[fr, lane] > 0.0 else zd[i, lane]
        for i in range(nu, nz):
            for lane in range(L):
                CZ[0, lane] += Cc[0, i, lane] * z[i, lane]
                CZ[1, lane] += Cc[1, i, lane] * z[i, lane]
        # Plant: every lane by the branch-free RK4 step, then the lanes that need the clipped
        # or level-limited step again, one by one.
        for lane in range(L):
            on = kf >= P[P_I_IN, lane]
            u1 = U[0, lane] + P[P_IN, lane] if on else U[0, lane]
            u2 = U[1, lane] + P[P_IN + 1, lane] if on else U[1, lane]
            n1, n2, n3, n4, fine = _rk4_fast(H[0, lane], H[1, lane], H[2, lane], H[3, lane],
                                             P[6, lane] * u1, P[7, lane] * u2, P[8, lane] * u2, P[9, lane] * u1,
                                             P[0, lane], P[1, lane], P[2, lane], P[3, lane], P[4, lane], P[5, lane],
                                             dt)
            Hn[0, lane] = n1
            Hn[1, lane] = n2
            Hn[2, lane] = n3
            Hn[3, lane] = n4
            Hn[4, lane] = 1.0 if fine & (P[P_CLIP, lane] <= 0.0) else 0.0
        for lane in range(L):
            if Hn[4, lane] > 0.0:
                continue
            on = kf >= P[P_I_IN, lane]
            u1 = U[0, lane] + P[P_IN, lane] if on else U[0, lane]
            u2 = U[1, lane] + P[P_IN + 1, lane] if on else U[1, lane]
            cl = P[:10, lane]
            if P[P_CLIP, lane] > 0.0:
                n1, n2, n3, n4 = _rk4_limited(H[0, lane], H[1, lane], H[2, lane], H[3, lane], cl[6] * u1,
                                              cl[7] * u2, cl[8] * u2, cl[9] * u1, cl, dt, P[P_HMAX, lane],
                                              P[P_HMAX + 1, lane], P[P_HMAX + 2, lane], P[P_HMAX + 3, lane])
            else:
                n1, n2, n3, n4 = _rk4_clipped(H[0, lane], H[1, lane], H[2, lane], H[3, lane], cl[6] * u1,
                                              cl[7] * u2, cl[8] * u2, cl[9] * u1, cl, dt)
            Hn[0, lane] = n1
            Hn[1, lane] = n2
            Hn[2, lane] = n3
            Hn[3, lane] = n4
        # Divergence (NaN fails the comparison too): the lane stops counting, and its state is
        # reset so that it stays cheap.
        n_bad = 0.0
        for lane in range(L):
            h1, h2, h3, h4 = Hn[0, lane], Hn[1, lane], Hn[2, lane], Hn[3, lane]
            H[0, lane] = h1
            H[1, lane] = h2
            H[2, lane] = h3
            H[3, lane] = h4
            n_bad += 0.0 if abs(h1) + abs(h2) + abs(h3) + abs(h4) < state_limit else 1.0
        if n_bad > 0.0:
            for lane in range(L):
                if abs(H[0, lane]) + abs(H[1, lane]) + abs(H[2, lane]) + abs(H[3, lane]) < state_limit:
                    continue
                if active[lane]:
                    active[lane] = False
                    n_active -= 1
                for j in range(4):
                    H[j, lane] = h_init[j]
                for i in range(nz):
                    z[i, lane] = 0.0
            if n_active == 0:
                break
    for lane in range(L):
        if active[lane]:
            out = metrics[lane]
            i_dist = int(P[P_I_OUT, lane])
            _finish_output(n_steps, dt, i_dist, band1, h_op[0], so[lane, 0], out, 0)
            _finish_output(n_steps, dt, i_dist, band2, h_op[1], so[lane, 1], out, 1)
            _finish_input(dt, P[P_UOP, lane], si[lane, 0], out, 0)
            _finish_input(dt, P[P_UOP + 1, lane], si[lane, 1], out, 1)
            _finish_range(level_per_state * R[0, lane], level_per_state * R[1, lane], si[lane], out)
            status[lane] = STATUS_OK
        else:
            for i in range(N_METRICS):
                metrics[lane, i] = np.nan
            status[lane] = STATUS_DIVERGED
