"""Numba kernels of the QTP closed loop and its metrics.

Arrays and scalars in, preallocated arrays out; no globals, no allocation inside the time loop,
random numbers drawn by the caller. Shapes and dtypes are float64 unless stated.
"""

import math

import numpy as np
from numba import njit

# Status codes returned by simulate_loop.
STATUS_OK = 0
STATUS_DIVERGED = 1

# Levels beyond this (cm, in magnitude) count as a diverged simulation.
LEVEL_LIMIT = 1.0e6

# Index of each metric in the vector written by loop_metrics.
METRIC_NAMES = (
    "Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2",
    "IAE1", "IAE2", "ISE1", "ISE2", "ITAE1", "ITAE2",
    "J1", "J2", "Jdev1", "Jdev2", "TV1", "TV2",
)
N_METRICS = len(METRIC_NAMES)

# Floating-point licence for the simulation kernel: reassociation lets LLVM vectorise the
# controller's matrix-vector products; NaN and inf keep their IEEE meaning (divergence checks).
_FAST = {"reassoc", "contract", "nsz", "arcp"}


def plant_coefficients(p):
    """Coefficients of the QTP right-hand side, so that the kernels need no division.

    Parameters
    ----------
    p : (13,) ``[A1..A4, a1..a4, k1, k2, gamma1, gamma2, g]`` (see ``QTPParams.as_array``)

    Returns
    -------
    (10,) ndarray ``[c1, c2, c3, c4, c31, c42, b11, b22, b32, b41]`` with::

        dh1 = -c1 sqrt(h1) + c31 sqrt(h3) + b11 u1      dh3 = -c3 sqrt(h3) + b32 u2
        dh2 = -c2 sqrt(h2) + c42 sqrt(h4) + b22 u2      dh4 = -c4 sqrt(h4) + b41 u1
    """
    A, a, k1, k2, g1, g2, g = p[0:4], p[4:8], p[8], p[9], p[10], p[11], p[12]
    r = math.sqrt(2.0 * g)
    return np.array([
        a[0] * r / A[0], a[1] * r / A[1], a[2] * r / A[2], a[3] * r / A[3],
        a[2] * r / A[0], a[3] * r / A[1],
        g1 * k1 / A[0], g2 * k2 / A[1], (1.0 - g2) * k2 / A[2], (1.0 - g1) * k1 / A[3],
    ])


@njit(cache=True, inline="always")
def _qtp_rhs(h, u1, u2, c, dh):
    """dh/dt of the QTP (levels clipped at 0 under the roots); ``c`` from plant_coefficients."""
    s1 = math.sqrt(max(h[0], 0.0))
    s2 = math.sqrt(max(h[1], 0.0))
    s3 = math.sqrt(max(h[2], 0.0))
    s4 = math.sqrt(max(h[3], 0.0))
    dh[0] = c[4] * s3 - c[0] * s1 + c[6] * u1
    dh[1] = c[5] * s4 - c[1] * s2 + c[7] * u2
    dh[2] = c[8] * u2 - c[2] * s3
    dh[3] = c[9] * u1 - c[3] * s4


@njit(cache=True)
def qtp_rhs(h, u, c):
    """Kernel right-hand side callable from Python (for tests); ``c`` from plant_coefficients."""
    dh = np.empty(4)
    _qtp_rhs(h, u[0], u[1], c, dh)
    return dh


@njit(cache=True, fastmath=_FAST)
def simulate_loop(c, h_init, h_op, u_op, ad, bd, col_start, Ad, Bd, Cc, Dc, state_channel,
                  dt, n_steps, i_out_dist, out_dist, i_in_dist, in_dist, noise,
                  saturate, u_min, u_max, y_rec, u_rec, h_rec):
    """Fixed-step closed loop: sampled linear controller, RK4 nonlinear plant.

    At each sample ``k`` (``t = k dt``) the controller reads the measured deviations
    ``w = [h1 + d1 - h1o, h2 + d2 - h2o, h3 - h3o, h4 - h4o] (+ noise)`` and outputs
    ``u = u_op + Cc z + Dc w`` (optionally clipped to [u_min, u_max]); ``u`` is held over the
    step while classic RK4 integrates the plant, and the controller advances by its exact
    zero-order-hold discretisation. The first ``nd = ad.size`` controller states are modal and
    single-input (``z_i <- ad_i z_i + bd_i w_c`` for ``i`` in ``[col_start[c], col_start[c+1])``),
    the remaining ones evolve with the dense ``Ad`` and ``Bd``.
    With saturation on, the states of a saturated pump's channel are held (conditional
    integration anti-windup).

    Parameters
    ----------
    c : (10,) plant coefficients (see plant_coefficients)
    h_init, h_op : (4,) initial and operating levels; u_op : (2,) operating voltages
    ad, bd : (nd,) modal factors and input gains; col_start : (5,) int64
    Ad : (nq, nq), Bd : (nq, 4) dense part; Cc : (2, nd + nq); Dc : (2, 4)
    state_channel : (nd + nq,) int64, pump each state belongs to
    dt : float; n_steps : int, the horizon is ``n_steps * dt``
    i_out_dist : int, first sample with the measured-level disturbance ``out_dist`` (2,)
    i_in_dist : int, first sample with the pump-voltage disturbance ``in_dist`` (2,)
    noise : (n_steps + 1, 4) measurement noise, or shape (0, 4) for none
    saturate : bool; u_min, u_max : float
    y_rec, u_rec : (n_steps + 1, 2) outputs: measured levels and applied voltages
    h_rec : (n_steps + 1, 4) or (0, 4): true levels, recorded when it has rows

    Returns
    -------
    status : int
        STATUS_OK, or STATUS_DIVERGED (records after the divergence are NaN).
    last : int
        Index of the last finite sample.
    """
    nd = ad.shape[0]
    nz = nd + Ad.shape[0]
    z = np.zeros(nz)
    z_new = np.zeros(nz)
    w = np.zeros(4)
    h = h_init.copy()
    k1 = np.empty(4)
    k2 = np.empty(4)
    k3 = np.empty(4)
    k4 = np.empty(4)
    tmp = np.empty(4)
    frozen = np.zeros(2, dtype=np.bool_)
    has_noise = noise.shape[0] > 0
    rec_h = h_rec.shape[0] > 0
    half = 0.5 * dt
    sixth = dt / 6.0
    for k in range(n_steps + 1):
        d1 = out_dist[0] if k >= i_out_dist else 0.0
        d2 = out_dist[1] if k >= i_out_dist else 0.0
        w[0] = h[0] + d1 - h_op[0]
        w[1] = h[1] + d2 - h_op[1]
        w[2] = h[2] - h_op[2]
        w[3] = h[3] - h_op[3]
        if has_noise:
            for i in range(4):
                w[i] += noise[k, i]
        u1 = u_op[0] + Dc[0, 0] * w[0] + Dc[0, 1] * w[1] + Dc[0, 2] * w[2] + Dc[0, 3] * w[3]
        u2 = u_op[1] + Dc[1, 0] * w[0] + Dc[1, 1] * w[1] + Dc[1, 2] * w[2] + Dc[1, 3] * w[3]
        for j in range(nz):
            u1 += Cc[0, j] * z[j]
            u2 += Cc[1, j] * z[j]
        if saturate:
            frozen[0] = u1 > u_max or u1 < u_min
            frozen[1] = u2 > u_max or u2 < u_min
            u1 = min(max(u1, u_min), u_max)
            u2 = min(max(u2, u_min), u_max)
        y_rec[k, 0] = w[0] + h_op[0]
        y_rec[k, 1] = w[1] + h_op[1]
        u_rec[k, 0] = u1
        u_rec[k, 1] = u2
        if rec_h:
            for i in range(4):
                h_rec[k, i] = h[i]
        if k == n_steps:
            break
        # Controller: modal states, then the dense part.
        for col in range(4):
            wc = w[col]
            for i in range(col_start[col], col_start[col + 1]):
                z_new[i] = ad[i] * z[i] + bd[i] * wc
        for i in range(nz - nd):
            acc = Bd[i, 0] * w[0] + Bd[i, 1] * w[1] + Bd[i, 2] * w[2] + Bd[i, 3] * w[3]
            for j in range(nz - nd):
                acc += Ad[i, j] * z[nd + j]
            z_new[nd + i] = acc
        if saturate:
            for i in range(nz):
                if not frozen[state_channel[i]]:
                    z[i] = z_new[i]
        else:
            for i in range(nz):
                z[i] = z_new[i]
        # Plant: classic RK4 with the pump voltages held over the step.
        if k >= i_in_dist:
            u1 += in_dist[0]
            u2 += in_dist[1]
        _qtp_rhs(h, u1, u2, c, k1)
        for i in range(4):
            tmp[i] = h[i] + half * k1[i]
        _qtp_rhs(tmp, u1, u2, c, k2)
        for i in range(4):
            tmp[i] = h[i] + half * k2[i]
        _qtp_rhs(tmp, u1, u2, c, k3)
        for i in range(4):
            tmp[i] = h[i] + dt * k3[i]
        _qtp_rhs(tmp, u1, u2, c, k4)
        ok = True
        for i in range(4):
            h[i] += sixth * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            if not (abs(h[i]) < LEVEL_LIMIT):  # also catches NaN
                ok = False
        if not ok:
            for kk in range(k + 1, n_steps + 1):
                y_rec[kk, 0] = np.nan
                y_rec[kk, 1] = np.nan
                u_rec[kk, 0] = np.nan
                u_rec[kk, 1] = np.nan
                if rec_h:
                    for i in range(4):
                        h_rec[kk, i] = np.nan
            return STATUS_DIVERGED, k
    return STATUS_OK, n_steps


@njit(cache=True, fastmath=_FAST)
def loop_metrics(y, u, y_op, u_op, dt, i_dist, band_pct, out):
    """Performance metrics of a sampled closed-loop response.

    Parameters
    ----------
    y : (n + 1, 2) measured levels at t = 0, dt, ..., n dt
    u : (n + 1, 2) applied voltages; ``u[k]`` is held over [k dt, (k + 1) dt)
    y_op : (2,) operating levels; u_op : (2,) operating voltages
    dt : float; i_dist : int, sample index of the disturbance time t_d
    band_pct : float, settling band in percent of the operating level
    out : (N_METRICS,) written in the order of METRIC_NAMES:

        Mp_i   max over t >= t_d of |y_i - y_op_i| / y_op_i * 100
        ts_i   time after t_d from which that deviation stays inside the band (linear
               interpolation of the last exit); 0 if it never leaves, T - t_d if it ends outside
        ess_i  |y_i(T) - y_op_i| / y_op_i * 100
        IAE_i, ISE_i, ITAE_i  integrals of |e|, e^2, t |e| over [0, T], e = y_i - y_op_i, by the
               trapezoid rule except on the step just before t_d, where the measured level
               jumps and the left value holds
        J_j    integral of u_j^2 over [0, T] (exact for the held input)
        Jdev_j integral of (u_j - u_op_j)^2 over [0, T]
        TV_j   sum of |u_j[k+1] - u_j[k]|
    """
    n = y.shape[0] - 1
    for i in range(2):
        y0 = y_op[i]
        band = band_pct / 100.0 * y0
        mp = 0.0
        last_out = -1
        iae = 0.0
        ise = 0.0
        itae = 0.0
        prev_a = abs(y[0, i] - y0)
        for k in range(n + 1):
            a = abs(y[k, i] - y0)
            if k >= i_dist:
                if a > mp:
                    mp = a
                if a > band:
                    last_out = k
            if k == i_dist and k > 0:
                # The step disturbance jumps at t_d: the interval before it holds the old value.
                iae += dt * prev_a
                ise += dt * prev_a * prev_a
                itae += dt * (k - 1) * dt * prev_a
            elif k > 0:
                iae += 0.5 * dt * (a + prev_a)
                ise += 0.5 * dt * (a * a + prev_a * prev_a)
                itae += 0.5 * dt * (k * dt * a + (k - 1) * dt * prev_a)
            prev_a = a
        if last_out < 0:
            ts = 0.0
        elif last_out == n:
            ts = (n - i_dist) * dt
        else:
            a0 = abs(y[last_out, i] - y0)
            a1 = abs(y[last_out + 1, i] - y0)
            frac = (a0 - band) / (a0 - a1) if a0 > a1 else 1.0
            ts = (last_out - i_dist + frac) * dt
        out[i] = mp / y0 * 100.0
        out[2 + i] = ts
        out[4 + i] = abs(y[n, i] - y0) / y0 * 100.0
        out[6 + i] = iae
        out[8 + i] = ise
        out[10 + i] = itae
        j_abs = 0.0
        j_dev = 0.0
        tv = 0.0
        for k in range(n):
            v = u[k, i]
            j_abs += v * v * dt
            j_dev += (v - u_op[i]) * (v - u_op[i]) * dt
            tv += abs(u[k + 1, i] - v)
        out[12 + i] = j_abs
        out[14 + i] = j_dev
        out[16 + i] = tv
