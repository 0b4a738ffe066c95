"""Numba kernel of the sampled TITO closed loop (plant + decoupler + decentralised controllers).

Arrays and scalars in, preallocated arrays out; no allocation inside the time loop; random
numbers drawn by the caller. Every linear block is a SISO state space already discretised
exactly (zero-order hold) by the caller, preceded by an integer-sample delay line.

Block layout (fixed, ``N_BLOCKS = 10``)::

    0..3  plant elements g11, g12, g21, g22   (block 2 i + j: input up_j, output adds to y_i)
    4..5  controllers c1, c2                  (input e_i, output v_i)
    6..9  decoupler entries D11, D12, D21, D22 (block 6 + 2 i + j: input v_j, output adds to u_i)
"""

import numpy as np
from numba import njit

N_BLOCKS = 10
PLANT0 = 0
CTRL0 = 4
DEC0 = 6

STATUS_OK = 0
STATUS_DIVERGED = 1

# An output or input whose magnitude exceeds this counts as diverged.
SIGNAL_LIMIT = 1.0e12


@njit(cache=True, inline="always")
def _block_out(b, w, C, D, ns, x):
    """Output ``C x + D w`` of block ``b`` for its (already delayed) input ``w``."""
    s = D[b] * w
    for p in range(ns[b]):
        s += C[b, p] * x[b, p]
    return s


@njit(cache=True, inline="always")
def _block_update(b, w, A, B, ns, x, xt):
    """``x <- A x + B w`` for block ``b`` (``xt`` is scratch of length >= ns[b])."""
    m = ns[b]
    for p in range(m):
        s = B[b, p] * w
        for q in range(m):
            s += A[b, p, q] * x[b, q]
        xt[p] = s
    for p in range(m):
        x[b, p] = xt[p]


@njit(cache=True, inline="always")
def controllers_and_decoupler(k, e0, e1, ctrl0, dec0, buf, nd, C, D, ns, x):
    """Sample ``k`` of the two controllers (blocks ``ctrl0``, ``ctrl0 + 1``, inputs ``e0``, ``e1``)
    and the decoupler (blocks ``dec0 .. dec0 + 3``, entry ``2 i + j`` from ``v_j`` to ``u_i``),
    through their delay lines; returns ``(v0, v1, u0, u1)``. Shared by the TITO kernels."""
    v0 = 0.0
    v1 = 0.0
    for i in range(2):
        b = ctrl0 + i
        L = nd[b] + 1
        buf[b, k % L] = e0 if i == 0 else e1
        o = _block_out(b, buf[b, (k + 1) % L], C, D, ns, x)
        if i == 0:
            v0 = o
        else:
            v1 = o
    u0 = 0.0
    u1 = 0.0
    for q in range(4):
        b = dec0 + q
        L = nd[b] + 1
        buf[b, k % L] = v0 if q % 2 == 0 else v1
        o = _block_out(b, buf[b, (k + 1) % L], C, D, ns, x)
        if q < 2:
            u0 += o
        else:
            u1 += o
    return v0, v1, u0, u1


@njit(cache=True)
def fill_nan(k0, y_rec, ym_rec, u_rec, v_rec):
    """Mark the records from row ``k0`` on as NaN (after a divergence)."""
    for kk in range(k0, y_rec.shape[0]):
        for c in range(2):
            y_rec[kk, c] = np.nan
            ym_rec[kk, c] = np.nan
            u_rec[kk, c] = np.nan
            v_rec[kk, c] = np.nan


@njit(cache=True)
def simulate_tito(A, B, C, D, ns, nd, r, d_in, d_out, noise, x, buf, xt,
                  y_rec, ym_rec, u_rec, v_rec):
    """Run the loop for samples ``k = 0 .. n`` (``n + 1`` rows in every record).

    Parameters
    ----------
    A : (N_BLOCKS, m, m) discrete state matrices (zero padded), B, C : (N_BLOCKS, m), D : (N_BLOCKS,)
    ns : (N_BLOCKS,) int64 state counts; nd : (N_BLOCKS,) int64 input delays in samples
    r, d_in, d_out, noise : (n + 1, 2) set-points, input and output disturbances, measurement noise
        (``d_in`` is all that is added to the plant inputs: the caller folds the scenario's input
        noise into it, so a scenario without input noise runs exactly as before it existed)
    x : (N_BLOCKS, m) initial states (zeros: the loop starts at rest); updated in place
    buf : (N_BLOCKS, max(nd) + 1) delay lines, zero on entry (all inputs are zero for t < 0)
    xt : (m,) scratch

    Writes ``y_rec`` (plant output + output disturbance), ``ym_rec`` (y_rec + noise, what the
    controllers see), ``u_rec`` (decoupler output), ``v_rec`` (controller outputs).

    Within sample ``k``: plant outputs from the state and the inputs delayed by ``nd`` samples
    (a plant block with ``nd = 0`` must have ``D = 0``, checked by the caller); errors
    ``e = r - ym``; controllers; decoupler; plant inputs ``u + d_in``; then every state advances
    with its delayed input held over ``[k dt, (k + 1) dt)``.

    Returns STATUS_OK, or STATUS_DIVERGED after filling the remaining rows with NaN.
    """
    n1 = r.shape[0]
    for k in range(n1):
        # plant outputs
        yp0 = 0.0
        yp1 = 0.0
        for b in range(PLANT0, PLANT0 + 4):
            w = buf[b, (k + 1) % (nd[b] + 1)]
            o = _block_out(b, w, C, D, ns, x)
            if b < PLANT0 + 2:
                yp0 += o
            else:
                yp1 += o
        y0 = yp0 + d_out[k, 0]
        y1 = yp1 + d_out[k, 1]
        ym0 = y0 + noise[k, 0]
        ym1 = y1 + noise[k, 1]
        # controllers and decoupler
        e0 = r[k, 0] - ym0
        e1 = r[k, 1] - ym1
        v0, v1, u0, u1 = controllers_and_decoupler(k, e0, e1, CTRL0, DEC0, buf, nd, C, D, ns, x)
        up0 = u0 + d_in[k, 0]
        up1 = u1 + d_in[k, 1]
        for b in range(PLANT0, PLANT0 + 4):
            buf[b, k % (nd[b] + 1)] = up0 if b % 2 == 0 else up1
        # state updates
        for b in range(N_BLOCKS):
            _block_update(b, buf[b, (k + 1) % (nd[b] + 1)], A, B, ns, x, xt)
        y_rec[k, 0] = y0
        y_rec[k, 1] = y1
        ym_rec[k, 0] = ym0
        ym_rec[k, 1] = ym1
        u_rec[k, 0] = u0
        u_rec[k, 1] = u1
        v_rec[k, 0] = v0
        v_rec[k, 1] = v1
        big = abs(y0) + abs(y1) + abs(u0) + abs(u1)
        if not big < SIGNAL_LIMIT:
            fill_nan(k + 1, y_rec, ym_rec, u_rec, v_rec)
            return STATUS_DIVERGED
    return STATUS_OK
