"""Numba kernel of the nonlinear coupled two-tank closed loop (decoupler + decentralised PI/PID).

Arrays and scalars in, preallocated arrays out; no allocation inside the time loop; random
numbers drawn by the caller. The controllers and decoupler entries are SISO state spaces already
discretised exactly (zero-order hold) by the caller (the same realisation as the linear TITO
simulator); the plant is integrated by classic RK4 with the pump inputs held over each step.

Linear block layout (fixed, ``N_BLOCKS = 6``)::

    0..1  controllers c1, c2                    (input e_i, output v_i)
    2..5  decoupler entries D11, D12, D21, D22  (block 2 + 2 i + j: input v_j, output adds to u_i)

Plant coefficients ``c = [c1, c2, c12, eta1, eta2]`` (see ``TwoTankParams.coefficients``)::

    dh1/dt = eta1 u1 - c1 sqrt(h1) - c12 ssqrt(h1 - h2)
    dh2/dt = eta2 u2 - c2 sqrt(h2) + c12 ssqrt(h1 - h2)

with ``ssqrt(x) = sign(x) sqrt(|x|)`` and the levels clipped at 0 under every root.
"""

import math

import numpy as np
from numba import njit

from heurtune.objectives.tito.kernels import (  # noqa: F401  (status codes re-exported)
    SIGNAL_LIMIT,
    STATUS_DIVERGED,
    STATUS_OK,
    _block_update,
    controllers_and_decoupler,
    fill_nan,
)

N_BLOCKS = 6
CTRL0 = 0
DEC0 = 2

# A level (cm) whose magnitude sum exceeds this counts as diverged (the rig is a few tens of cm).
LEVEL_LIMIT = 1.0e6


@njit(cache=True, inline="always")
def _rhs(h1, h2, f1, f2, c1, c2, c12):
    """``(dh1/dt, dh2/dt)`` for the pump inflow rates ``f = (eta1 u1, eta2 u2)`` in cm/s."""
    p1 = max(h1, 0.0)
    p2 = max(h2, 0.0)
    d = p1 - p2
    q12 = c12 * math.sqrt(d) if d >= 0.0 else -c12 * math.sqrt(-d)
    return f1 - c1 * math.sqrt(p1) - q12, f2 - c2 * math.sqrt(p2) + q12


@njit(cache=True)
def two_tank_rhs(h, u, c):
    """Kernel right-hand side callable from Python (for tests): ``dh/dt`` for levels ``h`` and
    absolute pump inputs ``u`` (both shape (2,)); ``c`` from ``TwoTankParams.coefficients``."""
    d1, d2 = _rhs(h[0], h[1], c[3] * u[0], c[4] * u[1], c[0], c[1], c[2])
    return np.array([d1, d2])


@njit(cache=True)
def rk4_step(h, u, c, dt):
    """One classic RK4 step of length ``dt`` with ``u`` held (callable from Python, for tests)."""
    h1, h2 = _rk4(h[0], h[1], c[3] * u[0], c[4] * u[1], c[0], c[1], c[2], dt)
    return np.array([h1, h2])


@njit(cache=True, inline="always")
def _rk4(h1, h2, f1, f2, c1, c2, c12, dt):
    half = 0.5 * dt
    a1, a2 = _rhs(h1, h2, f1, f2, c1, c2, c12)
    b1, b2 = _rhs(h1 + half * a1, h2 + half * a2, f1, f2, c1, c2, c12)
    e1, e2 = _rhs(h1 + half * b1, h2 + half * b2, f1, f2, c1, c2, c12)
    g1, g2 = _rhs(h1 + dt * e1, h2 + dt * e2, f1, f2, c1, c2, c12)
    sixth = dt / 6.0
    return (h1 + sixth * (a1 + 2.0 * b1 + 2.0 * e1 + g1),
            h2 + sixth * (a2 + 2.0 * b2 + 2.0 * e2 + g2))


@njit(cache=True)
def simulate_two_tank(A, B, C, D, ns, nd, c, h_op, u_op, ndu, ndy, dt, r, d_in, d_out, noise,
                      x, buf, xt, ubuf, ybuf, y_rec, ym_rec, u_rec, v_rec):
    """Run the loop for samples ``k = 0 .. n`` (``n + 1`` rows in every record).

    Parameters
    ----------
    A : (N_BLOCKS, m, m), B, C : (N_BLOCKS, m), D : (N_BLOCKS,) discrete linear blocks (zero padded)
    ns : (N_BLOCKS,) int64 state counts; nd : (N_BLOCKS,) int64 input delays in samples
    c : (5,) plant coefficients ``[c1, c2, c12, eta1, eta2]``
    h_op, u_op : (2,) operating levels (cm) and pump inputs (V); the plant starts at rest there
    ndu, ndy : (2,) int64 pump and level-sensor dead times in samples
    dt : float step (s)
    r, d_in, d_out, noise : (n + 1, 2) set-points, input and output disturbances, measurement noise
    x : (N_BLOCKS, m) initial block states (zeros); buf : (N_BLOCKS, max(nd) + 1) zeros
    xt : (m,) scratch; ubuf : (2, max(ndu) + 1) zeros; ybuf : (2, max(ndy) + 1) zeros

    Within sample ``k``: the sensors read the level deviations ``h(k - ndy_i) - h_op_i`` (zero
    before t = 0); ``y = sensor + d_out``, ``ym = y + noise``; errors ``e = r - ym``; controllers;
    decoupler (output ``u``, a deviation from ``u_op``); the pump command ``u + d_in`` enters the
    pump delay lines, and pump ``j`` applies ``u_op_j`` plus the command of sample ``k - ndu_j``,
    held over ``[k dt, (k + 1) dt)`` while RK4 advances the levels; the linear blocks advance.

    Writes ``y_rec`` (level deviation seen by the sensor + output disturbance), ``ym_rec``
    (y_rec + noise), ``u_rec`` (decoupler output, deviation), ``v_rec`` (controller outputs).

    Returns STATUS_OK, or STATUS_DIVERGED after filling the rows from the first bad one with NaN
    (a row is bad when its signals or the levels it leads to exceed the limits or are NaN).
    """
    n1 = r.shape[0]
    c1 = c[0]
    c2 = c[1]
    c12 = c[2]
    eta1 = c[3]
    eta2 = c[4]
    h1 = h_op[0]
    h2 = h_op[1]
    Ly0 = ndy[0] + 1
    Ly1 = ndy[1] + 1
    Lu0 = ndu[0] + 1
    Lu1 = ndu[1] + 1
    for k in range(n1):
        # level sensors (dead time ndy samples)
        ybuf[0, k % Ly0] = h1 - h_op[0]
        ybuf[1, k % Ly1] = h2 - h_op[1]
        y0 = ybuf[0, (k + 1) % Ly0] + d_out[k, 0]
        y1 = ybuf[1, (k + 1) % Ly1] + d_out[k, 1]
        ym0 = y0 + noise[k, 0]
        ym1 = y1 + noise[k, 1]
        # controllers and decoupler
        e0 = r[k, 0] - ym0
        e1 = r[k, 1] - ym1
        v0, v1, u0, u1 = controllers_and_decoupler(k, e0, e1, CTRL0, DEC0, buf, nd, C, D, ns, x)
        y_rec[k, 0] = y0
        y_rec[k, 1] = y1
        ym_rec[k, 0] = ym0
        ym_rec[k, 1] = ym1
        u_rec[k, 0] = u0
        u_rec[k, 1] = u1
        v_rec[k, 0] = v0
        v_rec[k, 1] = v1
        big = abs(y0) + abs(y1) + abs(u0) + abs(u1) + abs(v0) + abs(v1)
        if not big < SIGNAL_LIMIT:
            fill_nan(k, y_rec, ym_rec, u_rec, v_rec)
            return STATUS_DIVERGED
        # pump dead times
        ubuf[0, k % Lu0] = u0 + d_in[k, 0]
        ubuf[1, k % Lu1] = u1 + d_in[k, 1]
        up0 = u_op[0] + ubuf[0, (k + 1) % Lu0]
        up1 = u_op[1] + ubuf[1, (k + 1) % Lu1]
        if k == n1 - 1:
            break
        # linear block states
        for b in range(N_BLOCKS):
            _block_update(b, buf[b, (k + 1) % (nd[b] + 1)], A, B, ns, x, xt)
        # plant: RK4 with the pump inputs held over the step
        h1, h2 = _rk4(h1, h2, eta1 * up0, eta2 * up1, c1, c2, c12, dt)
        if not abs(h1) + abs(h2) < LEVEL_LIMIT:
            fill_nan(k + 1, y_rec, ym_rec, u_rec, v_rec)
            return STATUS_DIVERGED
    return STATUS_OK
