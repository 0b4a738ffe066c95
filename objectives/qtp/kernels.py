"""Numba kernels of the QTP closed loop and its metrics.

Arrays and scalars in, preallocated arrays out; no globals, no allocation inside the time loop,
random numbers drawn by the caller. Shapes and dtypes are float64 unless stated.
"""

import math

import numpy as np
from numba import njit

# Status codes returned by sampled_lane (simulate_loop).
STATUS_OK = 0
STATUS_DIVERGED = 1

# A simulation whose levels reach this sum of magnitudes (cm) counts as diverged.
LEVEL_LIMIT = 1.0e6

# Index of each metric in the vectors written by simulate_loop and loop_metrics. The last four
# are the physical range of the run: lowest and highest true level (any tank) and applied
# voltage (either pump).
METRIC_NAMES = (
    "Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2",
    "IAE1", "IAE2", "ISE1", "ISE2", "ITAE1", "ITAE2",
    "J1", "J2", "Jdev1", "Jdev2", "TV1", "TV2",
    "hmin", "hmax", "umin", "umax",
)
N_METRICS = len(METRIC_NAMES)

# Floating-point licence for the simulation kernel: reassociation lets LLVM vectorise the
# controller's matrix-vector products; NaN and inf keep their IEEE meaning (divergence checks).
# Every jitted function that sampled_lane calls is inlined into it (inline="always"): a callee
# compiled on its own and its copy in the caller's cached machine code would round differently
# under this licence (docs/model.md, "Compiled once, the same numbers").
_FAST = {"reassoc", "contract", "nsz", "arcp"}

# Rows of a scenario's parameter table ``P`` (NP,), read by simulate_loop (one column of it by
# simulate_scenarios and by the batched and GPU kernels, whose tables hold one per lane): plant
# coefficients, operating voltages, pump limits, flags (1.0 or 0.0), the measured-level and
# pump-voltage disturbances and their first samples (as floats: exact for any horizon that
# fits in memory), the tank heights, and (read by the continuous-time kernels, which take the
# disturbances from their step plan) the output disturbance time and the horizon. Built by
# scenario_table.
P_COEF, P_UOP, P_UMIN, P_UMAX, P_SAT, P_CLIP = 0, 10, 12, 13, 14, 15
P_OUT, P_IN, P_I_OUT, P_I_IN, P_HMAX = 16, 18, 20, 21, 22
P_T_DIST, P_HORIZON = 26, 27
NP = 28


def scenario_table(c, u_op, saturate, u_min, u_max, clip_levels, h_max, out_dist, i_out_dist, in_dist, i_in_dist,
                   t_dist, horizon):
    """A scenario's parameter table ``P`` as the QTP loop kernels take it.

    Parameters
    ----------
    c : (10,) array_like
        Plant coefficients (:func:`plant_coefficients`, or the bond-graph ones).
    u_op : (2,) array_like
        Operating voltages.
    saturate : bool
        Whether the applied voltages are clipped to [u_min, u_max] (with anti-windup).
    u_min, u_max : float
        Pump voltage limits (read only when ``saturate``).
    clip_levels : bool
        Whether each level stays within [0, h_max_i].
    h_max : (4,) array_like
        Tank heights in state units (read only when ``clip_levels``).
    out_dist : (2,) array_like
        Measured-level disturbance, in force from sample ``i_out_dist`` on.
    i_out_dist : int
    in_dist : (2,) array_like
        Pump-voltage disturbance, in force from sample ``i_in_dist`` on.
    i_in_dist : int
        The sample indices are read by the sampled loop only (-1 for a continuous scenario).
    t_dist : float
        Output disturbance time, s.
    horizon : float
        End time of the simulation, s.

    Returns
    -------
    (NP,) ndarray
        Rows ``P_*`` of this module.
    """
    P = np.empty(NP)
    P[P_COEF:P_COEF + 10] = c
    P[P_UOP:P_UOP + 2] = u_op
    P[P_UMIN], P[P_UMAX] = u_min, u_max
    P[P_SAT], P[P_CLIP] = float(bool(saturate)), float(bool(clip_levels))
    P[P_OUT:P_OUT + 2] = out_dist
    P[P_IN:P_IN + 2] = in_dist
    P[P_I_OUT], P[P_I_IN] = i_out_dist, i_in_dist
    P[P_HMAX:P_HMAX + 4] = h_max
    P[P_T_DIST], P[P_HORIZON] = t_dist, horizon
    return P


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


@njit(cache=True, fastmath=_FAST, inline="always")
def _qtp_rhs(h1, h2, h3, h4, f1, f2, f3, f4, c):
    """dh/dt of the QTP (levels clipped at 0 under the roots), with the input flows
    ``f = (b11 u1, b22 u2, b32 u2, b41 u1)`` given; ``c`` from plant_coefficients."""
    s1 = math.sqrt(max(h1, 0.0))
    s2 = math.sqrt(max(h2, 0.0))
    s3 = math.sqrt(max(h3, 0.0))
    s4 = math.sqrt(max(h4, 0.0))
    return (c[4] * s3 - c[0] * s1 + f1, c[5] * s4 - c[1] * s2 + f2, f3 - c[2] * s3, f4 - c[3] * s4)


@njit(cache=True)
def qtp_rhs(h, u, c):
    """Kernel right-hand side callable from Python (for tests); ``c`` from plant_coefficients."""
    d = _qtp_rhs(h[0], h[1], h[2], h[3], c[6] * u[0], c[7] * u[1], c[8] * u[1], c[9] * u[0], c)
    return np.array([d[0], d[1], d[2], d[3]])


@njit(cache=True, fastmath=_FAST, inline="always")
def _rk4_clipped(h1, h2, h3, h4, f1, f2, f3, f4, c, dt):
    """Classic RK4 step of the QTP with the levels clipped at 0 under the roots."""
    half = 0.5 * dt
    sixth = dt / 6.0
    a1, a2, a3, a4 = _qtp_rhs(h1, h2, h3, h4, f1, f2, f3, f4, c)
    b1, b2, b3, b4 = _qtp_rhs(h1 + half * a1, h2 + half * a2, h3 + half * a3, h4 + half * a4, f1, f2, f3, f4, c)
    e1, e2, e3, e4 = _qtp_rhs(h1 + half * b1, h2 + half * b2, h3 + half * b3, h4 + half * b4, f1, f2, f3, f4, c)
    g1, g2, g3, g4 = _qtp_rhs(h1 + dt * e1, h2 + dt * e2, h3 + dt * e3, h4 + dt * e4, f1, f2, f3, f4, c)
    return (h1 + sixth * (a1 + 2.0 * b1 + 2.0 * e1 + g1), h2 + sixth * (a2 + 2.0 * b2 + 2.0 * e2 + g2),
            h3 + sixth * (a3 + 2.0 * b3 + 2.0 * e3 + g3), h4 + sixth * (a4 + 2.0 * b4 + 2.0 * e4 + g4))


@njit(cache=True, fastmath=_FAST, inline="always")
def _rk4_step(h1, h2, h3, h4, f1, f2, f3, f4, c, dt):
    """The same classic RK4 step as :func:`_rk4_clipped`, arranged for a short critical path.

    The inflows ``f`` are constant over the step, so every stage argument is a base
    ``h + tau f`` (ready early) plus outflow terms ``tau c sqrt(.)``: two fused multiply-adds
    separate one square root from the next, instead of a clip, a product, a sum and an update.
    The clip at 0 moves off that path: when any stage argument is negative (or NaN) the
    step is redone by :func:`_rk4_clipped`. Both give the same step up to rounding.
    """
    half = 0.5 * dt
    sixth = dt / 6.0
    p1, p2, p3, p4 = h1 + half * f1, h2 + half * f2, h3 + half * f3, h4 + half * f4
    q1, q2, q3, q4 = h1 + dt * f1, h2 + dt * f2, h3 + dt * f3, h4 + dt * f4
    hc0, hc1, hc2, hc3, hc4, hc5 = half * c[0], half * c[1], half * c[2], half * c[3], half * c[4], half * c[5]
    dc0, dc1, dc2, dc3, dc4, dc5 = dt * c[0], dt * c[1], dt * c[2], dt * c[3], dt * c[4], dt * c[5]
    # stage 1 at h, stages 2 and 3 at h + dt/2 (slope), stage 4 at h + dt (slope)
    s1, s2, s3, s4 = math.sqrt(h1), math.sqrt(h2), math.sqrt(h3), math.sqrt(h4)
    x1, x2, x3, x4 = p1 - hc0 * s1 + hc4 * s3, p2 - hc1 * s2 + hc5 * s4, p3 - hc2 * s3, p4 - hc3 * s4
    t1, t2, t3, t4 = math.sqrt(x1), math.sqrt(x2), math.sqrt(x3), math.sqrt(x4)
    y1, y2, y3, y4 = p1 - hc0 * t1 + hc4 * t3, p2 - hc1 * t2 + hc5 * t4, p3 - hc2 * t3, p4 - hc3 * t4
    v1, v2, v3, v4 = math.sqrt(y1), math.sqrt(y2), math.sqrt(y3), math.sqrt(y4)
    z1, z2, z3, z4 = q1 - dc0 * v1 + dc4 * v3, q2 - dc1 * v2 + dc5 * v4, q3 - dc2 * v3, q4 - dc3 * v4
    r1, r2, r3, r4 = math.sqrt(z1), math.sqrt(z2), math.sqrt(z3), math.sqrt(z4)
    if not (min(min(h1, h2), min(h3, h4)) >= 0.0 and min(min(x1, x2), min(x3, x4)) >= 0.0
            and min(min(y1, y2), min(y3, y4)) >= 0.0 and min(min(z1, z2), min(z3, z4)) >= 0.0):
        return _rk4_clipped(h1, h2, h3, h4, f1, f2, f3, f4, c, dt)
    o3 = s3 + 2.0 * t3 + 2.0 * v3 + r3
    o4 = s4 + 2.0 * t4 + 2.0 * v4 + r4
    return (q1 + sixth * (c[4] * o3 - c[0] * (s1 + 2.0 * t1 + 2.0 * v1 + r1)),
            q2 + sixth * (c[5] * o4 - c[1] * (s2 + 2.0 * t2 + 2.0 * v2 + r2)),
            q3 - sixth * c[2] * o3,
            q4 - sixth * c[3] * o4)


@njit(cache=True, fastmath=_FAST, inline="always")
def _limited(x, d, hi):
    """Slope ``d`` of a level ``x`` held in [0, hi]: none past a limit (NaN passes through)."""
    if (x >= hi and d > 0.0) or (x <= 0.0 and d < 0.0):
        return 0.0
    return d


@njit(cache=True, fastmath=_FAST, inline="always")
def _rhs_limited(h1, h2, h3, h4, f1, f2, f3, f4, c, m1, m2, m3, m4):
    """dh/dt of the QTP with tanks of heights ``m``: levels clamped to [0, m_i] and each slope
    projected (water above a rim overflows, an empty tank stays empty)."""
    x1 = min(max(h1, 0.0), m1)
    x2 = min(max(h2, 0.0), m2)
    x3 = min(max(h3, 0.0), m3)
    x4 = min(max(h4, 0.0), m4)
    d1, d2, d3, d4 = _qtp_rhs(x1, x2, x3, x4, f1, f2, f3, f4, c)
    return _limited(x1, d1, m1), _limited(x2, d2, m2), _limited(x3, d3, m3), _limited(x4, d4, m4)


@njit(cache=True, fastmath=_FAST, inline="always")
def _rk4_limited(h1, h2, h3, h4, f1, f2, f3, f4, c, dt, m1, m2, m3, m4):
    """Classic RK4 step of the QTP with tank heights ``m`` (see :func:`_rhs_limited`), the
    result clipped to [0, m_i]. Where no level touches a limit during the step it is the step
    of :func:`_rk4_clipped`; where one does, it is first-order accurate at that instant."""
    half = 0.5 * dt
    sixth = dt / 6.0
    a1, a2, a3, a4 = _rhs_limited(h1, h2, h3, h4, f1, f2, f3, f4, c, m1, m2, m3, m4)
    b1, b2, b3, b4 = _rhs_limited(h1 + half * a1, h2 + half * a2, h3 + half * a3, h4 + half * a4,
                                  f1, f2, f3, f4, c, m1, m2, m3, m4)
    e1, e2, e3, e4 = _rhs_limited(h1 + half * b1, h2 + half * b2, h3 + half * b3, h4 + half * b4,
                                  f1, f2, f3, f4, c, m1, m2, m3, m4)
    g1, g2, g3, g4 = _rhs_limited(h1 + dt * e1, h2 + dt * e2, h3 + dt * e3, h4 + dt * e4,
                                  f1, f2, f3, f4, c, m1, m2, m3, m4)
    # Written so that NaN passes through (max and min keep their first argument when the
    # comparison fails) and still counts as divergence.
    return (min(max(h1 + sixth * (a1 + 2.0 * b1 + 2.0 * e1 + g1), 0.0), m1),
            min(max(h2 + sixth * (a2 + 2.0 * b2 + 2.0 * e2 + g2), 0.0), m2),
            min(max(h3 + sixth * (a3 + 2.0 * b3 + 2.0 * e3 + g3), 0.0), m3),
            min(max(h4 + sixth * (a4 + 2.0 * b4 + 2.0 * e4 + g4), 0.0), m4))


# Metrics are folded block by block: the simulation loop only stores the deviations
# a = |y - y_op| and voltages u of up to METRIC_BLOCK samples, and a separate tight (vectorised)
# loop folds them into a small state. Per output (OUT_STATE slots): plain sums of a, a^2 and
# k a, from which the trapezoid integrals follow at the end; the maximum after t_d; the last
# sample outside the band after t_d, its deviation and that of the sample after it (with a flag
# when that sample falls in the next block); the deviations at samples 0, i_dist - 1, i_dist
# and the latest. Per input (IN_STATE slots): sums of u^2 and (u - u_op)^2, the total variation,
# the latest voltage, and the lowest and highest voltage.
METRIC_BLOCK = 256
OUT_STATE = 12
IN_STATE = 6


@njit(cache=True, fastmath=_FAST, inline="always")
def _output_state_init(st):
    for i in range(OUT_STATE):
        st[i] = 0.0
    st[4] = -1.0  # no sample outside the band yet


@njit(cache=True, fastmath=_FAST, inline="always")
def _fold_output(a, k0, cnt, i_dist, band, st):
    """Fold deviations ``a[:cnt]`` of samples ``k0 .. k0 + cnt - 1`` into the state ``st``."""
    s = 0.0
    s2 = 0.0
    sk = 0.0
    for j in range(cnt):
        x = a[j]
        s += x
        s2 += x * x
        sk += (k0 + j) * x
    st[0] += s
    st[1] += s2
    st[2] += sk
    if cnt == 0:
        return
    if st[7] > 0.0:  # the sample after the last exit is this block's first
        st[6] = a[0]
        st[7] = 0.0
    jd = min(max(i_dist - k0, 0), cnt)
    mx = st[3]
    for j in range(jd, cnt):
        mx = max(mx, a[j])
    st[3] = mx
    for j in range(cnt - 1, jd - 1, -1):
        if a[j] > band:
            st[4] = k0 + j
            st[5] = a[j]
            if j + 1 < cnt:
                st[6] = a[j + 1]
            else:
                st[7] = 1.0
            break
    if k0 == 0:
        st[8] = a[0]
    if k0 <= i_dist - 1 < k0 + cnt:
        st[9] = a[i_dist - 1 - k0]
    if k0 <= i_dist < k0 + cnt:
        st[10] = a[i_dist - k0]
    st[11] = a[cnt - 1]


@njit(cache=True, fastmath=_FAST, inline="always")
def _fold_input(u, k0, cnt, u_op, st):
    """Fold voltages ``u[:cnt]`` of samples ``k0 ..`` into the state ``st``."""
    if cnt == 0:
        return
    s2 = 0.0
    sd2 = 0.0
    tv = abs(u[0] - st[3]) if k0 > 0 else 0.0
    for j in range(cnt):
        x = u[j]
        d = x - u_op
        s2 += x * x
        sd2 += d * d
    for j in range(1, cnt):
        tv += abs(u[j] - u[j - 1])
    # Range in a loop of its own, so that the sums above keep their vectorised grouping.
    lo = st[4] if k0 > 0 else u[0]
    hi = st[5] if k0 > 0 else u[0]
    for j in range(cnt):
        lo = min(lo, u[j])
        hi = max(hi, u[j])
    st[0] += s2
    st[1] += sd2
    st[2] += tv
    st[3] = u[cnt - 1]
    st[4] = lo
    st[5] = hi


@njit(cache=True, fastmath=_FAST, inline="always")
def _finish_output(n, dt, i_dist, band, y0, st, out, i):
    """Write Mp, ts, ess, IAE, ISE, ITAE of output ``i`` (0 or 1) from its state into ``out``."""
    s, s2, sk, mx, last, a_out, a_back = st[0], st[1], st[2], st[3], st[4], st[5], st[6]
    a_first, a_pre, a_at, a_last = st[8], st[9], st[10], st[11]
    if last < 0.0:
        ts = 0.0
    elif last >= n:
        ts = (n - i_dist) * dt
    else:
        frac = (a_out - band) / (a_out - a_back) if a_out > a_back else 1.0
        ts = (last - i_dist + frac) * dt
    # Trapezoid sums over k = 1..n of (a_k + a_{k-1}) and the like; on the step ending at
    # i_dist the measured level jumps, and the left value a_{i_dist-1} holds over it.
    iae = 2.0 * s - a_first - a_last
    ise = 2.0 * s2 - a_first * a_first - a_last * a_last
    itae = 2.0 * sk - n * a_last
    if 1 <= i_dist <= n:
        iae += a_pre - a_at
        ise += a_pre * a_pre - a_at * a_at
        itae += i_dist * (a_pre - a_at)
    out[i] = mx / y0 * 100.0
    out[2 + i] = ts
    out[4 + i] = a_last / y0 * 100.0
    out[6 + i] = 0.5 * dt * iae
    out[8 + i] = 0.5 * dt * ise
    out[10 + i] = 0.5 * dt * dt * itae


@njit(cache=True, fastmath=_FAST, inline="always")
def _finish_input(dt, u_op, st, out, j):
    """Write J, Jdev and TV of input ``j`` (the sums run over k < n: drop sample n)."""
    u_last = st[3]
    du = u_last - u_op
    out[12 + j] = dt * (st[0] - u_last * u_last)
    out[14 + j] = dt * (st[1] - du * du)
    out[16 + j] = st[2]


@njit(cache=True, fastmath=_FAST, inline="always")
def _finish_range(h_lo, h_hi, si, out):
    """Write hmin, hmax (levels, over all tanks) and umin, umax (voltages, both pumps)."""
    out[18] = h_lo
    out[19] = h_hi
    out[20] = min(si[0, 4], si[1, 4])
    out[21] = max(si[0, 5], si[1, 5])


def loop_metrics(y, u, y_op, u_op, dt, i_dist, band_pct, out, h=None):
    """Performance metrics of a sampled closed-loop response.

    The same block folds that :func:`simulate_loop` runs on its buffered samples.

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
        hmin, hmax  lowest and highest true level over all four tanks and samples k = 0..n
               (NaN when ``h`` is not given)
        umin, umax  lowest and highest applied voltage over both pumps and samples k = 0..n

    h : (n + 1, 4) true levels at the same instants, optional (None or shape (0, 4): none)
    """
    h = np.empty((0, 4)) if h is None else np.asarray(h, dtype=np.float64)
    if h.ndim != 2 or h.shape[1] != 4 or h.shape[0] not in (0, y.shape[0]):
        raise ValueError(f"loop_metrics: h must have shape ({y.shape[0]}, 4) or (0, 4), got {h.shape}")
    _loop_metrics(y, u, h, y_op, u_op, dt, i_dist, band_pct, out)


@njit(cache=True, fastmath=_FAST)
def _loop_metrics(y, u, h, y_op, u_op, dt, i_dist, band_pct, out):
    """Kernel of :func:`loop_metrics` (``h`` of shape (n + 1, 4) or (0, 4))."""
    n = y.shape[0] - 1
    so = np.empty((2, OUT_STATE))
    si = np.zeros((2, IN_STATE))
    for i in range(2):
        _output_state_init(so[i])
        band = band_pct / 100.0 * y_op[i]
        _fold_output(np.abs(y[:, i] - y_op[i]), 0, n + 1, i_dist, band, so[i])
        _fold_input(np.ascontiguousarray(u[:, i]), 0, n + 1, u_op[i], si[i])
        _finish_output(n, dt, i_dist, band, y_op[i], so[i], out, i)
        _finish_input(dt, u_op[i], si[i], out, i)
    h_lo = np.nan
    h_hi = np.nan
    if h.shape[0] > 0:
        # one running minimum and maximum per tank: independent chains, combined at the end
        lo1, lo2, lo3, lo4 = h[0, 0], h[0, 1], h[0, 2], h[0, 3]
        hi1, hi2, hi3, hi4 = lo1, lo2, lo3, lo4
        for k in range(1, h.shape[0]):
            lo1 = min(lo1, h[k, 0])
            lo2 = min(lo2, h[k, 1])
            lo3 = min(lo3, h[k, 2])
            lo4 = min(lo4, h[k, 3])
            hi1 = max(hi1, h[k, 0])
            hi2 = max(hi2, h[k, 1])
            hi3 = max(hi3, h[k, 2])
            hi4 = max(hi4, h[k, 3])
        h_lo = min(min(lo1, lo2), min(lo3, lo4))
        h_hi = max(max(hi1, hi2), max(hi3, hi4))
    _finish_range(h_lo, h_hi, si, out)


@njit(cache=True, fastmath=_FAST, inline="always")
def _modal_sum(z, ad, bd, lo, hi, w):
    """Advance the modal states ``z[lo:hi]`` driven by the signal ``w``; return their sum."""
    total = 0.0
    for i in range(lo, hi):
        zi = ad[i] * z[i] + bd[i] * w
        z[i] = zi
        total += zi
    return total


def loop_workspace(nd: int, nq: int) -> tuple:
    """The working arrays of :func:`sampled_lane` for ``nd`` modal and ``nq`` dense controller
    states: controller state (nd + nq), next dense state (nq), measured deviations (4), the
    metric block (4, METRIC_BLOCK), the output and input fold states (2, OUT_STATE) and
    (2, IN_STATE), and whether each pump's states are held (2, bool). The lane sets them up
    itself; one workspace serves any number of lanes one after another.

    Parameters
    ----------
    nd, nq : int

    Returns
    -------
    tuple of ndarray
    """
    return (np.zeros(nd + nq), np.zeros(nq), np.zeros(4), np.empty((4, METRIC_BLOCK)), np.empty((2, OUT_STATE)),
            np.zeros((2, IN_STATE)), np.zeros(2, dtype=np.bool_))


def simulate_loop(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
                  dt, n_steps, noise, band_pct, metrics, y_rec, u_rec, h_rec, substeps=1):
    """:func:`sampled_lane` of one candidate under one scenario, with working arrays of its own.

    Parameters
    ----------
    P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments, dt, n_steps, \
noise, band_pct, metrics, y_rec, u_rec, h_rec, substeps
        As :func:`sampled_lane` takes them.

    Returns
    -------
    status, last : int
        As :func:`sampled_lane` returns them.
    """
    return sampled_lane(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel,
                        segments, dt, n_steps, noise, band_pct, metrics, y_rec, u_rec, h_rec, substeps,
                        loop_workspace(ad.shape[0], Ad.shape[0]))


@njit(cache=True, fastmath=_FAST)
def sampled_lane(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
                 dt, n_steps, noise, band_pct, metrics, y_rec, u_rec, h_rec, substeps, work):
    """Fixed-step closed loop: sampled linear controller, RK4 nonlinear plant, metrics.

    The per-lane loop of every driver of the sampled loop: the one-candidate path
    (:func:`simulate_loop`), the scenarios of one controller (:func:`simulate_scenarios`), the
    lanes of ``--device cpu-batch`` (:func:`simulate_lanes`) and, compiled from the same source
    as a CUDA device function, the GPU kernel (``heurtune.objectives.qtp.gpu``). It allocates
    nothing: its working arrays come in ``work``.

    The plant state ``x`` follows the square-root law of :func:`plant_coefficients` (levels
    for the level model, pressures for the bond-graph model with the coefficients of
    ``qtp_bond_graph.pressure_coefficients``); its levels are ``h = s x`` with
    ``s = level_per_state`` (1 for levels, 1/(rho g) for pressures). Everything the loop
    measures or reports (w, y, hmin, hmax, the divergence test) is in levels; the state, its
    initial value, the record ``h_rec`` and the tank heights ``h_max`` are in state units.

    At each sample ``k`` (``t = k dt``) the controller reads the measured deviations
    ``w = [h1 + d1 - h1o, h2 + d2 - h2o, h3 - h3o, h4 - h4o] (+ noise)`` and outputs
    ``u = u_op + Cc z + Dc w`` (optionally clipped to [u_min, u_max]); ``u`` is held over the
    step while classic RK4 integrates the plant, and the controller advances by its exact
    zero-order-hold discretisation. The first ``nd = ad.size`` controller states are modal and
    single-input (``z_i <- ad_i z_i + bd_i w[state_input[i]]``, in the order of ``segments``),
    the remaining ones evolve with the dense ``Ad`` and ``Bd``. With saturation on, the states
    of a saturated pump's channel are held (conditional-integration anti-windup). With
    ``clip_levels`` on, every level stays in [0, h_max_i]: a tank cannot hold more than its
    height (the water above the rim is lost) nor less than nothing. RK4 then works on the
    projected slopes (:func:`_rk4_limited`: no rise at a rim, no fall at the floor) and clips
    each level after the step, which is first-order accurate over the step in which a level
    reaches a limit and as accurate as without limits elsewhere. The input disturbance is
    added to the plant input after saturation. The metrics
    of :func:`loop_metrics` are folded in the same pass from a small buffer of samples, so an
    evaluation needs no trajectory in memory. The plant state lives in scalars: the RK4 chain of square roots is
    the loop's critical path, and everything else overlaps with it.

    Parameters
    ----------
    P : (NP,) the scenario's parameter table (:func:`scenario_table`, rows ``P_*`` of this
        module): plant coefficients ``c`` (10, see plant_coefficients), operating voltages
        ``u_op`` (2), pump limits ``u_min``, ``u_max``, the flags ``saturate`` and
        ``clip_levels`` (1.0 or 0.0), the measured-level disturbance ``out_dist`` (2) from
        sample ``i_out_dist`` on, the pump-voltage disturbance ``in_dist`` (2) from sample
        ``i_in_dist`` on, and the tank heights ``h_max`` (4, state units, read only when
        ``clip_levels``)
    level_per_state : float, level per unit of state, ``s`` above (1.0 for the level model)
    h_init : (4,) initial state; h_op : (4,) operating levels
    ad, bd : (nd,) modal factors and input gains; state_input : (nd,) int64 in 0..3
    Ad : (nq, nq), Bd : (nq, 4) dense part; Cc : (2, nd + nq); Dc : (2, 4)
    state_channel : (nd + nq,) int64, pump each state belongs to
    segments : (4,) int64, the modal states' order (see ``DiscreteController``): states
        ``[0, segments[1])`` and ``[segments[1], segments[2])`` read w0 and w1 and add up, with
        weight 1, into u1 and u2
    dt : float; n_steps : int, the horizon is ``n_steps * dt``
    noise : (n_steps + 1, 4) measurement noise, or shape (0, 4) for none
    band_pct : float, settling band of the metrics, percent of the operating level
    metrics : (N_METRICS,) output, in the order of METRIC_NAMES; hmin, hmax cover the true
        levels and umin, umax the applied voltages (what ``u_rec`` records: after saturation,
        before the input disturbance) at samples 0..n_steps
    y_rec, u_rec : (n_steps + 1, 2) measured levels and applied voltages, or shape (0, 2)
    h_rec : (n_steps + 1, 4) true plant states (levels times ``1 / level_per_state``), or
        shape (0, 4)
    substeps : int
        RK4 steps of the plant per sample (1: one step of ``dt``; more for a long sample period,
        the voltages still held over the whole sample)
    work : tuple of ndarray
        The working arrays of :func:`loop_workspace` (or larger ones), set up here.

    Returns
    -------
    status : int
        STATUS_OK, or STATUS_DIVERGED (|h1| + ... + |h4| in levels reached LEVEL_LIMIT or became NaN;
        records after that are NaN and the metrics NaN).
    last : int
        Index of the last finite sample.
    """
    c = P[P_COEF:P_COEF + 10]
    u_op = P[P_UOP:P_UOP + 2]
    u_min, u_max = P[P_UMIN], P[P_UMAX]
    saturate = P[P_SAT] > 0.0
    clip_levels = P[P_CLIP] > 0.0
    out_dist, in_dist, h_max = P[P_OUT:P_OUT + 2], P[P_IN:P_IN + 2], P[P_HMAX:P_HMAX + 4]
    i_out_dist, i_in_dist = int(P[P_I_OUT]), int(P[P_I_IN])
    nd = ad.shape[0]
    nq = Ad.shape[0]
    # unit states of pumps 1 and 2: [0, g1) and [g1, nu); other modal: [nu, nd); dense: [nd, nd + nq)
    g1, nu = segments[1], segments[2]
    # controller state, next dense state, measured deviations; metric buffer and fold states
    # (see _fold_output / _fold_input); whether each pump's states are held
    z, z_dense, wv, buf, so, si, frozen = work
    for i in range(nd + nq):
        z[i] = 0.0
    cz1 = 0.0  # Cc z of the current sample (z starts at zero)
    cz2 = 0.0
    for j in range(2):
        for i in range(IN_STATE):
            si[j, i] = 0.0
        frozen[j] = False
    _output_state_init(so[0])
    _output_state_init(so[1])
    nb = 0
    k0 = 0
    h1, h2, h3, h4 = h_init[0], h_init[1], h_init[2], h_init[3]
    has_noise = noise.shape[0] > 0
    rec = y_rec.shape[0] > 0
    rec_h = h_rec.shape[0] > 0
    band1 = band_pct / 100.0 * h_op[0]
    band2 = band_pct / 100.0 * h_op[1]
    hm1, hm2, hm3, hm4 = (h_max[0], h_max[1], h_max[2], h_max[3]) if clip_levels else (0.0, 0.0, 0.0, 0.0)
    # Divergence bound in state units (LEVEL_LIMIT itself for the level model).
    state_limit = LEVEL_LIMIT / level_per_state
    dt_plant = dt / substeps
    h_lo = math.inf
    h_hi = -math.inf
    diverged_at = -1
    for k in range(n_steps + 1):
        # Range of the true states, in levels at the end (not on the plant's critical path).
        h_lo = min(h_lo, min(min(h1, h2), min(h3, h4)))
        h_hi = max(h_hi, max(max(h1, h2), max(h3, h4)))
        d1 = out_dist[0] if k >= i_out_dist else 0.0
        d2 = out_dist[1] if k >= i_out_dist else 0.0
        w0 = level_per_state * h1 + (d1 - h_op[0])
        w1 = level_per_state * h2 + (d2 - h_op[1])
        w2 = level_per_state * h3 - h_op[2]
        w3 = level_per_state * h4 - h_op[3]
        if has_noise:
            w0 += noise[k, 0]
            w1 += noise[k, 1]
            w2 += noise[k, 2]
            w3 += noise[k, 3]
        u1 = u_op[0] + cz1 + Dc[0, 0] * w0 + Dc[0, 1] * w1 + Dc[0, 2] * w2 + Dc[0, 3] * w3
        u2 = u_op[1] + cz2 + Dc[1, 0] * w0 + Dc[1, 1] * w1 + Dc[1, 2] * w2 + Dc[1, 3] * w3
        if saturate:
            frozen[0] = u1 > u_max or u1 < u_min
            frozen[1] = u2 > u_max or u2 < u_min
            u1 = min(max(u1, u_min), u_max)
            u2 = min(max(u2, u_min), u_max)
        if rec:
            y_rec[k, 0] = w0 + h_op[0]
            y_rec[k, 1] = w1 + h_op[1]
            u_rec[k, 0] = u1
            u_rec[k, 1] = u2
        if rec_h:
            h_rec[k, 0] = h1
            h_rec[k, 1] = h2
            h_rec[k, 2] = h3
            h_rec[k, 3] = h4
        buf[0, nb] = abs(w0)
        buf[1, nb] = abs(w1)
        buf[2, nb] = u1
        buf[3, nb] = u2
        nb += 1
        if nb == METRIC_BLOCK or k == n_steps:
            _fold_output(buf[0], k0, nb, i_out_dist, band1, so[0])
            _fold_output(buf[1], k0, nb, i_out_dist, band2, so[1])
            _fold_input(buf[2], k0, nb, u_op[0], si[0])
            _fold_input(buf[3], k0, nb, u_op[1], si[1])
            k0 += nb
            nb = 0
        if k == n_steps:
            break
        # Controller: modal single-input states (in place), then the dense part, then the
        # output contribution Cc z of the next sample. Plain loops over contiguous arrays, so
        # that LLVM vectorises them and they run in the shadow of the plant's RK4 chain.
        wv[0] = w0
        wv[1] = w1
        wv[2] = w2
        wv[3] = w3
        if saturate:
            for i in range(nd):
                if not frozen[state_channel[i]]:
                    z[i] = ad[i] * z[i] + bd[i] * wv[state_input[i]]
            cz1 = 0.0
            cz2 = 0.0
            for i in range(nu):
                cz1 += Cc[0, i] * z[i]
                cz2 += Cc[1, i] * z[i]
        else:
            # The unit states of each pump in one loop with the measured signal a scalar (LLVM
            # vectorises it) and no output weights; the other modal states gather their input.
            cz1 = _modal_sum(z, ad, bd, 0, g1, w0)
            cz2 = _modal_sum(z, ad, bd, g1, nu, w1)
            for i in range(nu, nd):
                z[i] = ad[i] * z[i] + bd[i] * wv[state_input[i]]
        if nq > 0:
            for i in range(nq):
                acc_i = Bd[i, 0] * w0 + Bd[i, 1] * w1 + Bd[i, 2] * w2 + Bd[i, 3] * w3
                for j in range(nq):
                    acc_i += Ad[i, j] * z[nd + j]
                z_dense[i] = acc_i
            for i in range(nq):
                if not (saturate and frozen[state_channel[nd + i]]):
                    z[nd + i] = z_dense[i]
        for i in range(nu, nd + nq):
            cz1 += Cc[0, i] * z[i]
            cz2 += Cc[1, i] * z[i]
        # Plant: classic RK4 with the pump voltages held over the step.
        if k >= i_in_dist:
            u1 += in_dist[0]
            u2 += in_dist[1]
        if substeps > 1:  # a long sample period: the plant in several RK4 steps between samples
            for _ in range(substeps):
                if clip_levels:
                    h1, h2, h3, h4 = _rk4_limited(h1, h2, h3, h4, c[6] * u1, c[7] * u2, c[8] * u2, c[9] * u1, c,
                                                  dt_plant, hm1, hm2, hm3, hm4)
                else:
                    h1, h2, h3, h4 = _rk4_step(h1, h2, h3, h4, c[6] * u1, c[7] * u2, c[8] * u2, c[9] * u1, c,
                                               dt_plant)
        elif clip_levels:
            h1, h2, h3, h4 = _rk4_limited(h1, h2, h3, h4, c[6] * u1, c[7] * u2, c[8] * u2, c[9] * u1, c, dt,
                                          hm1, hm2, hm3, hm4)
        else:
            h1, h2, h3, h4 = _rk4_step(h1, h2, h3, h4, c[6] * u1, c[7] * u2, c[8] * u2, c[9] * u1, c, dt)
        # One comparison per step; NaN fails it, so it counts as divergence too.
        if not (abs(h1) + abs(h2) + abs(h3) + abs(h4) < state_limit):
            diverged_at = k
            break
    if diverged_at < 0:
        _finish_output(n_steps, dt, i_out_dist, band1, h_op[0], so[0], metrics, 0)
        _finish_output(n_steps, dt, i_out_dist, band2, h_op[1], so[1], metrics, 1)
        _finish_input(dt, u_op[0], si[0], metrics, 0)
        _finish_input(dt, u_op[1], si[1], metrics, 1)
        _finish_range(level_per_state * h_lo, level_per_state * h_hi, si, metrics)
        return STATUS_OK, n_steps
    # Kept out of the time loop so that it stays lean.
    for kk in range(diverged_at + 1, y_rec.shape[0]):
        y_rec[kk, 0] = np.nan
        y_rec[kk, 1] = np.nan
        u_rec[kk, 0] = np.nan
        u_rec[kk, 1] = np.nan
    for kk in range(diverged_at + 1, h_rec.shape[0]):
        for i in range(4):
            h_rec[kk, i] = np.nan
    for i in range(N_METRICS):
        metrics[i] = np.nan
    return STATUS_DIVERGED, diverged_at


def simulate_scenarios(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel,
                       segments, dt, n_steps, noise, band_pct, metrics, status):
    """:func:`sampled_lane` of one controller under ``S`` scenarios, one after another on one
    workspace (metrics only).

    Parameters
    ----------
    P : (NP, S) the scenarios' parameter tables (:func:`scenario_table`), one column each
    level_per_state, h_init, h_op : as :func:`simulate_loop`, shared
    ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments : the discrete controller,
        as :func:`simulate_loop` takes it
    dt, n_steps, band_pct : as :func:`simulate_loop`, shared (one plant step per sample)
    noise : (S, n_steps + 1, 4) measurement noise, or (S, 0, 4) for none
    metrics : (S, N_METRICS) output; status : (S,) int64 output, each row exactly what
        :func:`simulate_loop` gives for that scenario
    """
    work = loop_workspace(ad.shape[0], Ad.shape[0])
    y_rec, u_rec, h_rec = np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 4))
    for s in range(P.shape[1]):
        status[s], _ = sampled_lane(np.ascontiguousarray(P[:, s]), level_per_state, h_init, h_op, ad, bd, state_input,
                                    Ad, Bd, Cc, Dc, state_channel, segments, dt, n_steps, noise[s], band_pct,
                                    metrics[s], y_rec, u_rec, h_rec, 1, work)


def simulate_lanes(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
                   dt, n_steps, noise, lane_noise, band_pct, metrics, status):
    """:func:`sampled_lane` of ``L`` lanes (a lane: one candidate under one scenario), one after
    another on one workspace (metrics only): the sampled loop of ``--device cpu-batch``.

    A lane runs the same compiled function as the one-candidate path, so its metrics are those
    of :func:`simulate_loop` bit for bit, whatever the other lanes.

    Parameters
    ----------
    P : (L, NP) per-lane parameter tables (:func:`scenario_table`), one row per lane
    level_per_state : float; h_init, h_op : (4,) shared initial state and operating levels
    ad, bd : (L, nd) modal factors and gains; state_input : (nd,) int64, shared
    Ad : (L, nq, nq), Bd : (L, nq, 4), Cc : (L, 2, nd + nq), Dc : (L, 2, 4)
    state_channel : (nd + nq,) int64 and segments : (4,) int64, shared (see ``DiscreteController``)
    dt : float; n_steps : int, shared
    noise : (S, n_steps + 1, 4) measurement noise of S draws (S may be 0)
    lane_noise : (L,) int64, the draw each lane reads, or -1 for none
    band_pct : float
    metrics : (L, N_METRICS) output; status : (L,) int64 output, as ``simulate_loop`` returns
    """
    work = loop_workspace(ad.shape[1], Ad.shape[1])
    y_rec, u_rec, h_rec = np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 4))
    no_noise = np.empty((0, 4))
    for k in range(P.shape[0]):
        lane_draw = noise[lane_noise[k]] if lane_noise[k] >= 0 else no_noise
        status[k], _ = sampled_lane(P[k], level_per_state, h_init, h_op, ad[k], bd[k], state_input, Ad[k], Bd[k],
                                    Cc[k], Dc[k], state_channel, segments, dt, n_steps, lane_draw, band_pct, metrics[k],
                                    y_rec, u_rec, h_rec, 1, work)
