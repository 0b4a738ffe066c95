"""Two-input two-output coupled conical tanks (CCTS) with decentralised PI/PID level control.

A heurtune plant family in one file, loaded as a plugin.

Plant
-----
Two conical tanks stand side by side, apex down, joined at the bottom by a coupling pipe. Each
has its own pump (inflow) and its own bottom outlet (free outflow). Levels ``h_i`` in cm, time
in s, pump voltages ``u_i`` in V, flows in cm^3/s::

    A_i(h_i) dh_i/dt = k_i u_i - a_i sqrt(2 g h_i) -/+ q_12          (i = 1: -, i = 2: +)
    A_i(h)           = A0_i + pi (R_i h / H_i)^2                     (cross section at level h)
    q_12             = a_12 sign(h_1 - h_2) sqrt(2 g |h_1 - h_2|)    (from the higher tank)
    u_i              = sat(v_i) in [u_min, u_max]                    (pump range)

``R_i`` is the top radius, ``H_i`` the height, ``A0_i`` a small bottom area (so that the
cross section of an empty tank is not zero), ``a_i`` the outlet area, ``a_12`` the opening of
the coupling pipe, ``k_i`` the pump constant and ``g = 981 cm/s^2``.

Two details keep the model well posed everywhere:

* every square root is replaced below ``EPS_LEVEL = 0.01 cm`` by the straight line through 0
  and its value at ``EPS_LEVEL`` (a laminar zone), so the right-hand side is Lipschitz and an
  empty tank is an ordinary stationary point; at the operating levels (tens of cm, level gaps
  of several cm) this changes nothing;
* the levels stay in ``[0, H_i]``: an empty tank cannot go negative, a full one spills over
  its rim (the integrator projects the state back after each step).

Control
-------
A decentralised sampled PI (or PID) per loop: ``u_1`` from ``e_1 = r_1 - h_1``, ``u_2`` from
``e_2 = r_2 - h_2``, period ``Ts`` (a whole number of integration steps), output held between
samples. The derivative acts on the measured level through a first-order filter of time
constant ``Tf`` (no set-point kick). The integrator is clamped (not updated) while the pump is
saturated and the error drives further into saturation. Each scenario starts at rest at the
operating levels with the integrators holding that scenario's steady pump voltages. An input
disturbance ``d_i`` (in pump volts) adds the flow ``k_i d_i`` to tank ``i``.

Numbers
-------
Paper 000 (IEEE Access, decentralised PID of coupled tank systems, section V.B, eq. 49) gives
the CCTS only as an identified transfer matrix: first-order-plus-dead-time elements with
diagonal time constants of 340-365 s, cross time constants of about 410 s and cross/diagonal
static gain ratios of about 0.4. It gives no dimensions, so the values here are plausible
lab-scale ones, chosen so that the linearisation has the same character: tanks 70 cm high with
a 20 cm top radius and a 1 cm bottom radius (A0 = pi cm^2), outlets of 0.2 cm^2 (about 5 mm
bore), a coupling pipe of 0.07 cm^2, pumps of 12 cm^3/(V s) over 0-10 V. At the ``high``
operating point (40 cm, 32 cm) the linearised plant has a slow mode of about 480 s and a
cross/diagonal static gain ratio of 0.41; at ``low`` (20 cm, 15 cm) the slow mode is about
85 s: the conical shape makes the dynamics strongly level dependent, which is the point of the
rig. Steady pump voltages at the built-in operating points lie between 2.3 and 5.4 V.

Loading
-------
On the command line::

    python -m heurtune.experiment my_config --plugin experiments/plugins/conical_tanks.py

or in the experiment config (a relative path resolves against the config's folder)::

    plugins = ["plugins/conical_tanks.py"]

    [plant]
    model = "conical_tanks"

See ``experiments/example_plugin_plant.toml`` and ``docs/plants.md``.

Layout: physics and jitted kernels (functions) first, orchestration (classes) below.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
from numba import njit
from scipy.linalg import expm

from heurtune import ConfigError
from heurtune.core.families import register_family
from heurtune.core.problem import FAILED_OBJECTIVE, FAILED_VIOLATION, Evaluation, ExperimentBase, TuningProblem
from heurtune.core.schema import COMMON_SCHEMA, NUMBER, PAIR

# --------------------------------------------------------------------------------------------
# 1. Parameters, right-hand side, operating point
# --------------------------------------------------------------------------------------------

G_ACCEL = 981.0          # cm/s^2
EPS_LEVEL = 0.01         # cm: below this a square root becomes linear (laminar zone)
STATUS_OK = 0
STATUS_DIVERGED = 1      # a level or pump voltage became non-finite
# Kernel coefficient vector layout (see ConicalTanksParams.coefficients).
N_COEF = 11
# Metrics per loop, in this order; the metric vector is (name1, name2) for each name.
METRIC_BASE = ("IAE", "ISE", "ITAE", "Mp", "ts", "umax", "hmax")
METRIC_NAMES = tuple(f"{m}{i}" for m in METRIC_BASE for i in (1, 2))
N_METRICS = len(METRIC_NAMES)

# Built-in operating points (h1, h2) in cm: the plant "cases".
OPERATING_POINTS = {"low": (20.0, 15.0), "mid": (30.0, 24.0), "high": (40.0, 32.0)}


@dataclasses.dataclass(frozen=True)
class ConicalTanksParams:
    """Physical parameters of the two coupled conical tanks (cm, s, V).

    Parameters
    ----------
    R : pair of float
        Top radius of tank 1 and tank 2, cm.
    H : pair of float
        Height of each tank, cm (the level cannot exceed it).
    A0 : pair of float
        Bottom cross section, cm^2 (> 0, so that an empty tank has an area).
    a : pair of float
        Outlet areas, cm^2.
    a12 : float
        Opening of the coupling pipe, cm^2 (0 decouples the tanks).
    k : pair of float
        Pump constants, cm^3/(V s).
    u_range : pair of float
        Pump voltage range ``(u_min, u_max)``, V.
    g : float
        Gravity, cm/s^2.
    """

    R: tuple = (20.0, 20.0)
    H: tuple = (70.0, 70.0)
    A0: tuple = (math.pi, math.pi)
    a: tuple = (0.2, 0.2)
    a12: float = 0.07
    k: tuple = (12.0, 12.0)
    u_range: tuple = (0.0, 10.0)
    g: float = G_ACCEL

    def area(self, h) -> np.ndarray:
        """Cross sections ``A_i(h_i)`` (cm^2) at levels ``h`` (2,), levels clipped to ``[0, H]``."""
        h = np.clip(np.asarray(h, dtype=float), 0.0, self.H)
        return np.asarray(self.A0) + np.pi * (np.asarray(self.R) * h / np.asarray(self.H)) ** 2

    def coefficients(self, a_factor: float = 1.0) -> np.ndarray:
        """Kernel coefficients with the outlet areas scaled by ``a_factor`` (uncertainty).

        Layout: ``[cone1, cone2, A01, A02, c1, c2, c12, k1, k2, H1, H2]`` with
        ``cone_i = pi (R_i / H_i)^2``, ``c_i = a_i sqrt(2 g)``, ``c12 = a12 sqrt(2 g)``.
        """
        s2g = math.sqrt(2.0 * self.g)
        R, H = self.R, self.H
        return np.array([math.pi * (R[0] / H[0]) ** 2, math.pi * (R[1] / H[1]) ** 2,
                         self.A0[0], self.A0[1],
                         a_factor * self.a[0] * s2g, a_factor * self.a[1] * s2g, self.a12 * s2g,
                         self.k[0], self.k[1], H[0], H[1]])


def sroot(x: float) -> float:
    """Signed square root with a linear zone ``|x| < EPS_LEVEL`` (the kernels' ``_sroot``)."""
    ax = abs(x)
    r = math.sqrt(ax) if ax >= EPS_LEVEL else ax / math.sqrt(EPS_LEVEL)
    return r if x >= 0.0 else -r


def sroot_slope(x: float) -> float:
    """Derivative of :func:`sroot` (for the linearisation)."""
    ax = abs(x)
    return 0.5 / math.sqrt(ax) if ax >= EPS_LEVEL else 1.0 / math.sqrt(EPS_LEVEL)


def operating_point(params: ConicalTanksParams, levels, a_factor: float = 1.0) -> np.ndarray:
    """Steady pump voltages that hold the levels ``levels`` (cm), from the flow balance.

    ``k_1 u_1 = c_1 sqrt(h_1) + q_12`` and ``k_2 u_2 = c_2 sqrt(h_2) - q_12`` (exact, no
    iteration). The caller checks the result against the pump range.

    Parameters
    ----------
    params : ConicalTanksParams
    levels : pair of float
        Set-point levels ``(h1, h2)``, cm.
    a_factor : float
        Outlet-area factor of the scenario.

    Returns
    -------
    (2,) ndarray
        Pump voltages, V.
    """
    c = params.coefficients(a_factor)
    h1, h2 = float(levels[0]), float(levels[1])
    q12 = c[6] * sroot(h1 - h2)
    return np.array([(c[4] * sroot(h1) + q12) / c[7], (c[5] * sroot(h2) - q12) / c[8]])


def linearise(params: ConicalTanksParams, levels, a_factor: float = 1.0):
    """Jacobians ``(J, B)`` of ``dh/dt`` in ``h`` and ``u`` at a steady state.

    At a steady state the net inflow is zero, so the level dependence of ``A(h)`` drops out:
    ``J = diag(1/A) d(net flow)/dh`` and ``B = diag(k/A)``.

    Returns
    -------
    J, B : (2, 2) ndarray
    """
    c = params.coefficients(a_factor)
    h1, h2 = float(levels[0]), float(levels[1])
    A = params.area((h1, h2))
    s12 = c[6] * sroot_slope(h1 - h2)
    s1 = c[4] * sroot_slope(h1)
    s2 = c[5] * sroot_slope(h2)
    J = np.array([[-(s1 + s12) / A[0], s12 / A[0]],
                  [s12 / A[1], -(s2 + s12) / A[1]]])
    B = np.diag([c[7] / A[0], c[8] / A[1]])
    return J, B


def zoh(J, B, Ts):
    """Zero-order-hold discretisation ``(Phi, Gamma)`` of ``dx/dt = J x + B u`` over ``Ts``."""
    aug = np.zeros((4, 4))
    aug[:2, :2] = J * Ts
    aug[:2, 2:] = B * Ts
    E = expm(aug)
    return E[:2, :2], E[:2, 2:]


def closed_loop_matrices(Phi, Gamma, G, Tf, Ts):
    """Transition matrices of the sampled loop linearised at the operating point.

    State ``z = [x1, x2, I1, I2, Dp1, Dp2, yp1, yp2]``: level deviations, integrators, the
    previous derivative terms and the previous measured levels, in the same order of updates
    as :func:`simulate_loop` (saturation and anti-windup left out: this is the local loop).

    Parameters
    ----------
    Phi, Gamma : (2, 2) ndarray
        Zero-order-hold discretisation of ``(J, B)`` over the control period ``Ts``.
    G : (n, 6) ndarray
        Gains ``[Kp1, Ki1, Kd1, Kp2, Ki2, Kd2]`` per candidate.
    Tf : (2,) derivative filter time constants, s.
    Ts : float
        Control period, s.

    Returns
    -------
    (n, 8, 8) ndarray
    """
    n = G.shape[0]
    kp = G[:, [0, 3]]
    ki = G[:, [1, 4]]
    kd = G[:, [2, 5]]
    alpha = Tf / (Tf + Ts)  # (2,)
    beta = kd / (Tf + Ts)  # (n, 2)
    V = np.zeros((n, 2, 8))  # pump command deviation v = V z
    M = np.zeros((n, 8, 8))
    for i in range(2):
        V[:, i, i] = -kp[:, i] - beta[:, i]
        V[:, i, 2 + i] = 1.0
        V[:, i, 4 + i] = alpha[i]
        V[:, i, 6 + i] = beta[:, i]
        M[:, 2 + i, 2 + i] = 1.0
        M[:, 2 + i, i] = -ki[:, i] * Ts
        M[:, 4 + i, :] = V[:, i, :]
        M[:, 4 + i, i] += kp[:, i]  # the derivative term alone: v_i without -Kp x_i and I_i
        M[:, 4 + i, 2 + i] = 0.0
        M[:, 6 + i, i] = 1.0
    M[:, 0:2, 0:2] = Phi
    M[:, 0:2, :] += np.einsum("ij,njk->nik", Gamma, V)
    return M


# --------------------------------------------------------------------------------------------
# 2. Jitted closed-loop kernel: RK4 plant + sampled PI/PID, metrics, batch
# --------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _sroot(x):
    ax = abs(x)
    r = math.sqrt(ax) if ax >= EPS_LEVEL else ax / math.sqrt(EPS_LEVEL)
    return r if x >= 0.0 else -r


@njit(cache=True, inline="always")
def _rhs(h1, h2, q1, q2, c):
    """``(dh1/dt, dh2/dt)`` for pump inflows ``q1, q2`` (cm^3/s); levels clipped to [0, H]."""
    p1 = min(max(h1, 0.0), c[9])
    p2 = min(max(h2, 0.0), c[10])
    q12 = c[6] * _sroot(p1 - p2)
    A1 = c[2] + c[0] * p1 * p1
    A2 = c[3] + c[1] * p2 * p2
    return (q1 - c[4] * _sroot(p1) - q12) / A1, (q2 - c[5] * _sroot(p2) + q12) / A2


@njit(cache=True, inline="always")
def _rk4(h1, h2, q1, q2, c, dt):
    """One classic RK4 step with the inflows held, then the levels projected onto [0, H]."""
    half = 0.5 * dt
    a1, a2 = _rhs(h1, h2, q1, q2, c)
    b1, b2 = _rhs(h1 + half * a1, h2 + half * a2, q1, q2, c)
    e1, e2 = _rhs(h1 + half * b1, h2 + half * b2, q1, q2, c)
    g1, g2 = _rhs(h1 + dt * e1, h2 + dt * e2, q1, q2, c)
    sixth = dt / 6.0
    n1 = h1 + sixth * (a1 + 2.0 * b1 + 2.0 * e1 + g1)
    n2 = h2 + sixth * (a2 + 2.0 * b2 + 2.0 * e2 + g2)
    return min(max(n1, 0.0), c[9]), min(max(n2, 0.0), c[10])


@njit(cache=True)
def plant_rhs(h, u, c):
    """``dh/dt`` (2,) for levels ``h`` (2,) and pump voltages ``u`` (2,); ``c`` from
    :meth:`ConicalTanksParams.coefficients`. Callable from Python (tests, operating point)."""
    d1, d2 = _rhs(h[0], h[1], c[7] * u[0], c[8] * u[1], c)
    return np.array([d1, d2])


@njit(cache=True)
def rk4_step(h, u, c, dt):
    """One RK4 step of length ``dt`` with ``u`` (2,) held; returns the new levels (2,)."""
    n1, n2 = _rk4(h[0], h[1], c[7] * u[0], c[8] * u[1], c, dt)
    return np.array([n1, n2])


@njit(cache=True)
def simulate_loop(c, h0, gains, Tf, u_lo, u_hi, i0, dt, nsub, r, d, y, u):
    """Closed loop: plant by fixed-step RK4, decentralised PI/PID sampled every ``nsub`` steps.

    Parameters
    ----------
    c : (N_COEF,) plant coefficients (:meth:`ConicalTanksParams.coefficients`)
    h0 : (2,) initial levels, cm
    gains : (6,) ``[Kp1, Ki1, Kd1, Kp2, Ki2, Kd2]`` (Kd = 0 is a PI)
    Tf : (2,) derivative filter time constants, s (> 0)
    u_lo, u_hi : pump range, V
    i0 : (2,) initial integrator states (the steady pump voltages: bumpless start)
    dt : integration step, s; nsub : int, control period ``Ts = nsub dt``
    r : (n + 1, 2) set-points at ``t_k = k dt`` (cm); d : (n + 1, 2) input disturbances (V)
    y, u : (n + 1, 2) outputs: levels at ``t_k`` and the pump voltage held over
        ``[t_k, t_k + dt)`` (the last row repeats the last command)

    Returns
    -------
    int
        STATUS_OK, or STATUS_DIVERGED (rows from the first non-finite one are NaN).
    """
    n1 = r.shape[0]
    Ts = nsub * dt
    h1 = h0[0]
    h2 = h0[1]
    I1 = i0[0]
    I2 = i0[1]
    D1 = 0.0
    D2 = 0.0
    yp1 = h1
    yp2 = h2
    al1 = Tf[0] / (Tf[0] + Ts)
    al2 = Tf[1] / (Tf[1] + Ts)
    be1 = gains[2] / (Tf[0] + Ts)
    be2 = gains[5] / (Tf[1] + Ts)
    us1 = 0.0
    us2 = 0.0
    for k in range(n1):
        y[k, 0] = h1
        y[k, 1] = h2
        if k % nsub == 0:
            e1 = r[k, 0] - h1
            e2 = r[k, 1] - h2
            D1 = al1 * D1 - be1 * (h1 - yp1)
            D2 = al2 * D2 - be2 * (h2 - yp2)
            yp1 = h1
            yp2 = h2
            v1 = gains[0] * e1 + I1 + D1
            v2 = gains[3] * e2 + I2 + D2
            us1 = min(max(v1, u_lo), u_hi)
            us2 = min(max(v2, u_lo), u_hi)
            # clamping anti-windup: freeze the integral while it pushes into saturation
            w1 = gains[1] * Ts * e1
            w2 = gains[4] * Ts * e2
            if not ((v1 >= u_hi and w1 > 0.0) or (v1 <= u_lo and w1 < 0.0)):
                I1 += w1
            if not ((v2 >= u_hi and w2 > 0.0) or (v2 <= u_lo and w2 < 0.0)):
                I2 += w2
        u[k, 0] = us1
        u[k, 1] = us2
        if not (math.isfinite(h1) and math.isfinite(h2) and math.isfinite(us1) and math.isfinite(us2)
                and math.isfinite(I1) and math.isfinite(I2)):
            for j in range(k, n1):
                y[j, 0] = np.nan
                y[j, 1] = np.nan
                u[j, 0] = np.nan
                u[j, 1] = np.nan
            return STATUS_DIVERGED
        if k == n1 - 1:
            break
        h1, h2 = _rk4(h1, h2, c[7] * (us1 + d[k, 0]), c[8] * (us2 + d[k, 1]), c, dt)
    return STATUS_OK


@njit(cache=True)
def loop_metrics(r, y, u, dt, steps, band, out):
    """Per-loop performance metrics of one sampled response.

    Parameters
    ----------
    r, y, u : (n + 1, 2) set-points, levels and pump voltages from :func:`simulate_loop`
    dt : sample spacing, s
    steps : (m, 4) set-point steps ``[loop (0/1), k_start, k_end, size]``: the step of ``size``
        cm at sample ``k_start``, judged on samples ``k_start .. k_end - 1`` (up to the next
        event: another step or the disturbance)
    band : settling band, fraction of the step size (0.02 for 2 %)
    out : (N_METRICS,) written in the order of ``METRIC_NAMES``:

        IAE_i, ISE_i, ITAE_i  integrals of ``|e|``, ``e^2``, ``t |e|`` over the horizon,
            ``e = r - y``, the set-point held over each step (trapezoid in y)
        Mp_i   largest overshoot over the loop's steps, percent of the step size (>= 0)
        ts_i   longest settling time over the loop's steps: time from the step to the first
               sample after the last one outside ``band |size|`` around the new set-point; 0 if
               it never leaves; the window's length ``(k_end - k_start) dt`` if its last sample
               is outside (not settled)
        umax_i largest pump voltage; hmax_i highest level
    """
    n1 = r.shape[0]
    for i in range(2):
        iae = 0.0
        ise = 0.0
        itae = 0.0
        umax = abs(u[0, i])
        hmax = y[0, i]
        for k in range(n1 - 1):
            ea = r[k, i] - y[k, i]
            eb = r[k, i] - y[k + 1, i]
            iae += 0.5 * dt * (abs(ea) + abs(eb))
            ise += 0.5 * dt * (ea * ea + eb * eb)
            itae += 0.5 * dt * (k * dt * abs(ea) + (k + 1) * dt * abs(eb))
            umax = max(umax, abs(u[k + 1, i]))
            hmax = max(hmax, y[k + 1, i])
        mp = 0.0
        ts = 0.0
        for s in range(steps.shape[0]):
            if int(steps[s, 0]) != i:
                continue
            k0 = int(steps[s, 1])
            k1 = int(steps[s, 2])
            size = steps[s, 3]
            target = r[k0, i]
            sgn = 1.0 if size > 0.0 else -1.0
            tol = band * abs(size)
            last = -1
            for k in range(k0, k1):
                over = (y[k, i] - target) * sgn / abs(size) * 100.0
                if over > mp:
                    mp = over
                if abs(y[k, i] - target) > tol:
                    last = k
            if last == k1 - 1:
                tsk = (k1 - k0) * dt  # not settled: the whole window
            elif last >= 0:
                tsk = (last + 1 - k0) * dt
            else:
                tsk = 0.0
            if tsk > ts:
                ts = tsk
        out[i] = iae
        out[2 + i] = ise
        out[4 + i] = itae
        out[6 + i] = mp
        out[8 + i] = ts
        out[10 + i] = umax
        out[12 + i] = hmax


@njit(cache=True)
def run_batch(G, c, h0, Tf, u_lo, u_hi, i0, dt, nsub, r, d, steps, band, metrics, status):
    """Simulate and measure every row of ``G`` ((n, 6) gains, see :func:`simulate_loop`).

    Writes ``metrics`` (n, N_METRICS) (NaN rows for diverged candidates) and ``status`` (n,).
    """
    y = np.empty_like(r)
    u = np.empty_like(r)
    for j in range(G.shape[0]):
        st = simulate_loop(c, h0, G[j], Tf, u_lo, u_hi, i0, dt, nsub, r, d, y, u)
        status[j] = st
        if st == STATUS_OK:
            loop_metrics(r, y, u, dt, steps, band, metrics[j])
        else:
            metrics[j, :] = np.nan


# --------------------------------------------------------------------------------------------
# 3. Scenario
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TankScenario:
    """What a candidate is simulated under: set-point steps, a disturbance, uncertainty.

    Parameters
    ----------
    name : str
        The scenario's name (``"nominal"``, ``"-20%"``, ...).
    horizon, dt : float
        Simulated time and integration step, s (``horizon / dt`` a whole number).
    steps1, steps2 : tuple of (time, size)
        Set-point steps of loop 1 and loop 2: at ``time`` (s, on the ``dt`` grid) the set-point
        moves by ``size`` cm (relative to the operating level, cumulative).
    disturbance : (time, (d1, d2)) or None
        Input disturbance: from ``time`` on, tank ``i`` receives the extra flow of ``d_i`` pump
        volts (negative: a leak).
    a_factor : float
        Factor on both outlet areas (1.0 nominal; 0.8 and 1.2 for -20 % and +20 %).
    """

    name: str = "nominal"
    horizon: float = 1800.0
    dt: float = 1.0
    steps1: tuple = ((0.0, 5.0),)
    steps2: tuple = ((600.0, 5.0),)
    disturbance: tuple | None = (1200.0, (1.0, 0.0))
    a_factor: float = 1.0

    @property
    def n(self) -> int:
        """Number of integration steps (``n + 1`` samples)."""
        return int(round(self.horizon / self.dt))

    def sample(self, time: float) -> int:
        """Sample index of ``time`` (on the grid)."""
        return int(round(time / self.dt))

    def check(self, where: str, levels, H) -> None:
        """One-line ConfigError (prefixed ``where``) for an ill-formed scenario."""
        if not (self.dt > 0 and self.horizon > 0):
            raise ConfigError(f"{where}: scenario.horizon and scenario.dt must be > 0, got "
                              f"{self.horizon:g} and {self.dt:g}")
        if abs(self.horizon / self.dt - self.n) > 1e-9 * self.n or self.n < 2:
            raise ConfigError(f"{where}: scenario.horizon ({self.horizon:g}) must be a whole number "
                              f"(>= 2) of scenario.dt ({self.dt:g})")
        if not self.a_factor > 0:
            raise ConfigError(f"{where}: scenario.uncertainty.{self.name} must be > 0, got {self.a_factor:g}")
        events = [(f"steps{i + 1}", t) for i, steps in enumerate((self.steps1, self.steps2)) for t, _ in steps]
        if self.disturbance is not None:
            events.append(("input_disturbance.time", self.disturbance[0]))
        for key, t in events:
            k = t / self.dt
            if not (0 <= t < self.horizon) or abs(k - round(k)) > 1e-9 * max(1.0, k):
                raise ConfigError(f"{where}: scenario.{key}: time {t:g} must lie in [0, horizon) on the "
                                  f"dt grid (dt = {self.dt:g})")
        for i, steps in enumerate((self.steps1, self.steps2)):
            level = levels[i]
            for t, size in sorted(steps):
                level += size
                if size == 0 or not 0.0 < level < H[i]:
                    raise ConfigError(f"{where}: scenario.steps{i + 1}: the step of {size:g} cm at "
                                      f"{t:g} s must be nonzero and keep the set-point in (0, H{i + 1} "
                                      f"= {H[i]:g}) cm, got {level:g} cm")

    def signals(self, levels):
        """Set-points ``r`` and input disturbances ``d``, both (n + 1, 2), at the samples."""
        r = np.empty((self.n + 1, 2))
        r[:] = np.asarray(levels, dtype=np.float64)
        for i, steps in enumerate((self.steps1, self.steps2)):
            for t, size in steps:
                r[self.sample(t):, i] += size
        d = np.zeros((self.n + 1, 2))
        if self.disturbance is not None:
            d[self.sample(self.disturbance[0]):, :] = self.disturbance[1]
        return r, d

    def windows(self) -> np.ndarray:
        """Set-point steps ``[loop, k_start, k_end, size]`` (m, 4) for :func:`loop_metrics`:
        each judged up to the next event (a step of either loop or the disturbance)."""
        starts = sorted({self.sample(t) for steps in (self.steps1, self.steps2) for t, _ in steps}
                        | ({self.sample(self.disturbance[0])} if self.disturbance is not None else set()))
        rows = []
        for i, steps in enumerate((self.steps1, self.steps2)):
            for t, size in steps:
                k0 = self.sample(t)
                k1 = min([k for k in starts if k > k0], default=self.n + 1)
                rows.append((float(i), float(k0), float(k1), float(size)))
        return np.array(rows, dtype=np.float64).reshape(-1, 4)


# --------------------------------------------------------------------------------------------
# 4. Tuning problem and experiment (heurtune's plant-family contract)
# --------------------------------------------------------------------------------------------

CONTROLLERS = ("pi", "pid")
OBJECTIVES = {"iae": "IAE", "ise": "ISE", "itae": "ITAE"}
CONSTRAINT_KEYS = ("Mp", "ts", "umax", "hmax")  # upper limits per loop: %, s, V, cm
DEFAULT_BOUNDS = {"Kp": (0.0, 10.0), "Ki": (0.0, 0.2), "Kd": (0.0, 50.0)}
DEFAULT_UNCERTAINTY = {"nominal": 1.0, "-20%": 0.8, "+20%": 1.2}
BASELINES = ("simc",)
# Candidates whose linearised loop has a spectral radius above this are "unstable".
UNSTABLE_RADIUS = 1.0 + 1e-9


def gain_names(kind: str) -> tuple:
    """Decision variables of a controller type: ``Kp1, Ki1[, Kd1], Kp2, Ki2[, Kd2]``."""
    per = ("Kp", "Ki") if kind == "pi" else ("Kp", "Ki", "Kd")
    return tuple(f"{g}{i}" for i in (1, 2) for g in per)


class ConicalTanksProblem(TuningProblem):
    """Tune the decentralised PI/PID of the coupled conical tanks at one operating point.

    Minimise the summed IAE (or ISE, ITAE) of both loops under the tuning scenario subject to
    per-loop upper limits on overshoot ``Mp`` (%), settling time ``ts`` (s), the largest pump
    voltage ``umax`` (V) and the highest level ``hmax`` (cm), as configured. Without limits a
    single ``stability`` constraint is kept (0 when simulated, the failure's violation else).

    Failed candidates (never an exception): ``invalid_parameter`` (a gain that is not finite or
    is negative), ``unstable`` (the sampled loop linearised at the operating point has a
    spectral radius above 1: the nonlinear loop cannot settle there; the violation grows with
    the radius), ``diverged`` (the simulation produced a non-finite value) or ``non_finite``.

    Attributes
    ----------
    case, controller : str
        Case name and controller type (``"pi"`` or ``"pid"``).
    levels : (2,) ndarray
        Operating levels, cm; the set-point steps are relative to them.
    params : ConicalTanksParams
    names, lower, upper : decision variables and bounds
    scenarios : dict of str to TankScenario
    tuning_scenario, objective : str
    constraint_names, metric_names : tuple of str
    """

    scenario_type = TankScenario
    # What [problem] objectives may name (several objectives, NSGA-II): each the sum over both
    # loops. Robust tuning ([problem] tuning_scenarios) needs nothing here: the core applies both.
    objective_metrics = {name: (f"{key}1", f"{key}2") for name, key in OBJECTIVES.items()}
    report_columns = ("f", "IAE1", "IAE2", "Mp1", "Mp2", "ts1", "ts2", "umax1", "umax2", "hmax1", "hmax2",
                      "feasible", "reason")
    signal_labels = {"output": "tank", "input": "pump", "y_label": "level h{i} (cm)",
                     "u_label": "pump voltage u{i} (V)", "y_unit": "cm", "u_unit": "V"}

    def __init__(self, case: str, kind: str, params: ConicalTanksParams, levels, bounds: dict, *,
                 scenarios: dict, tuning_scenario: str, objective: str, constraints: dict, Ts: float,
                 Tf: float, settling_band: float, simc_lambda: float = 0.5):
        self.case = case
        self.controller = kind
        self.params = params
        self.levels = np.asarray(levels, dtype=np.float64)
        self.names = gain_names(kind)
        self.lower = np.array([bounds[n[:-1]][0] for n in self.names], dtype=np.float64)
        self.upper = np.array([bounds[n[:-1]][1] for n in self.names], dtype=np.float64)
        # columns of the kernel's 6-gain vector that the decision variables fill
        self._cols = np.array([("Kp", "Ki", "Kd").index(n[:-1]) + 3 * (int(n[-1]) - 1) for n in self.names])
        self.scenarios = dict(scenarios)
        self.tuning_scenario = tuning_scenario
        self.objective = objective
        self.constraints = dict(constraints)
        self.Ts = float(Ts)
        self.Tf = float(Tf)
        self.settling_band = float(settling_band)
        self.simc_lambda = float(simc_lambda)
        self.metric_names = METRIC_NAMES
        self._midx = {m: i for i, m in enumerate(METRIC_NAMES)}
        self.constraint_names = (tuple(f"{k}{i}" for k in self.constraints for i in (1, 2))
                                 or ("stability",))
        self._ccols = np.array([self._midx[c] for c in self.constraint_names if c != "stability"], dtype=np.int64)
        self._limits = np.array([self.constraints[c[:-1]] for c in self.constraint_names if c != "stability"])
        self._prepared = {}
        for sc in self.scenarios.values():
            self._prepare(sc)  # a scenario whose operating point is out of reach fails here

    def __repr__(self):
        return f"ConicalTanksProblem({self.case!r}, {self.controller!r}, levels={self.levels.tolist()})"

    # -- per-scenario arrays, built once ------------------------------------------------------
    def _prepare(self, sc: TankScenario) -> dict:
        if sc in self._prepared:
            return self._prepared[sc]
        nsub = int(round(self.Ts / sc.dt))
        if nsub < 1 or abs(self.Ts / sc.dt - nsub) > 1e-9 * nsub:
            raise ConfigError(f"case {self.case!r}: controller.Ts ({self.Ts:g} s) must be a whole number "
                              f"of scenario.dt ({sc.dt:g} s)")
        u0 = operating_point(self.params, self.levels, sc.a_factor)
        lo, hi = self.params.u_range
        if not np.all((u0 > lo) & (u0 < hi)):
            raise ConfigError(f"case {self.case!r}: levels {self.levels.tolist()} cm need pump voltages "
                              f"{np.round(u0, 3).tolist()} V under scenario {sc.name!r}, outside "
                              f"plant.u_range [{lo:g}, {hi:g}] V")
        r, d = sc.signals(self.levels)
        J, B = linearise(self.params, self.levels, sc.a_factor)
        Phi, Gamma = zoh(J, B, nsub * sc.dt)
        prep = dict(c=self.params.coefficients(sc.a_factor), u0=u0, r=r, d=d, steps=sc.windows(), nsub=nsub,
                    Phi=Phi, Gamma=Gamma, Tf=np.full(2, self.Tf))
        self._prepared[sc] = prep
        return prep

    def gains(self, X) -> np.ndarray:
        """The kernel's ``[Kp1, Ki1, Kd1, Kp2, Ki2, Kd2]`` rows of a batch (Kd = 0 for a PI)."""
        X = self.batch(X)
        G = np.zeros((X.shape[0], 6))
        G[:, self._cols] = X
        return G

    def spectral_radius(self, X, scenario=None) -> np.ndarray:
        """Spectral radius of the sampled loop linearised at the operating point, per row."""
        prep = self._prepare(self.scenario(self.tuning_scenario if scenario is None else scenario))
        G = self.gains(X)
        M = closed_loop_matrices(prep["Phi"], prep["Gamma"], G, prep["Tf"], self.Ts)
        return np.abs(np.linalg.eigvals(M)).max(axis=1)

    # -- the protocol ---------------------------------------------------------------------------
    def evaluate(self, X, scenario=None) -> Evaluation:
        """Evaluate a batch ``X`` (n, d) under a scenario (default: the tuning scenario).

        Returns
        -------
        Evaluation
            ``f`` the summed objective metric of both loops, ``g`` the normalised limits
            (``metric / limit - 1``), the 14 metrics of :func:`loop_metrics`; failed candidates
            get ``FAILED_OBJECTIVE``, ``FAILED_VIOLATION`` (graded for ``unstable``) and NaN
            metrics, with their reason.
        """
        X = self.batch(X)
        sc = self.scenario(self.tuning_scenario if scenario is None else scenario)
        prep = self._prepare(sc)
        n, m = X.shape[0], len(self.constraint_names)
        f = np.full(n, FAILED_OBJECTIVE)
        g = np.full((n, m), FAILED_VIOLATION)
        metrics = np.full((n, N_METRICS), np.nan)
        reason = np.full(n, "", dtype=object)
        valid = np.isfinite(X).all(axis=1) & (X >= 0.0).all(axis=1)
        reason[~valid] = "invalid_parameter"
        idx = np.flatnonzero(valid)
        if idx.size:
            with np.errstate(all="ignore"):
                rho = self.spectral_radius(X[idx], sc)
            bad = ~(rho <= UNSTABLE_RADIUS)  # NaN radius counts as unstable
            for j, rj in zip(idx[bad], rho[bad]):
                reason[j] = "unstable"
                g[j] = FAILED_VIOLATION * (1.0 + min(rj - 1.0, 1e3)) if np.isfinite(rj) else FAILED_VIOLATION * 1e3
            idx = idx[~bad]
        if idx.size:
            G = self.gains(X[idx])
            out = np.empty((idx.size, N_METRICS))
            status = np.empty(idx.size, dtype=np.int64)
            lo, hi = self.params.u_range
            run_batch(G, prep["c"], self.levels, prep["Tf"], float(lo), float(hi), prep["u0"], float(sc.dt),
                      prep["nsub"], prep["r"], prep["d"], prep["steps"], self.settling_band / 100.0, out, status)
            key = OBJECTIVES[self.objective]
            for row, j in enumerate(idx):
                if status[row] != STATUS_OK:
                    reason[j] = "diverged"
                    continue
                mj = out[row]
                fj = mj[self._midx[f"{key}1"]] + mj[self._midx[f"{key}2"]]
                gj = mj[self._ccols] / self._limits - 1.0 if self._ccols.size else np.zeros(1)
                if not (np.isfinite(fj) and np.all(np.isfinite(gj)) and np.all(np.isfinite(mj))):
                    reason[j] = "non_finite"
                    continue
                metrics[j], f[j], g[j] = mj, fj, gj
        feasible = (reason == "") & np.all(g <= 0.0, axis=1)
        return Evaluation(f, g, feasible, metrics, self.metric_names, self.constraint_names, reason)

    def simulate(self, x, scenario="nominal") -> pd.DataFrame:
        """Trajectories of one candidate: columns ``t, r1, r2, y1, y2, u1, u2`` (cm, V).

        ``y`` are the levels, ``u`` the pump voltages held from each sample. Any gains are
        simulated as given (a diverged run ends in NaN rows, ``attrs["status"]`` says so).
        """
        sc = self.scenario(scenario)
        prep = self._prepare(sc)
        G = np.zeros(6)
        G[self._cols] = [self.values(x)[k] for k in self.names]
        r, d = prep["r"], prep["d"]
        y = np.empty_like(r)
        u = np.empty_like(r)
        lo, hi = self.params.u_range
        st = simulate_loop(prep["c"], self.levels, G, prep["Tf"], float(lo), float(hi), prep["u0"], float(sc.dt),
                           prep["nsub"], r, d, y, u)
        df = pd.DataFrame({"t": np.arange(sc.n + 1) * sc.dt, "r1": r[:, 0], "r2": r[:, 1], "y1": y[:, 0],
                           "y2": y[:, 1], "u1": u[:, 0], "u2": u[:, 1]})
        df.attrs["status"] = "ok" if st == STATUS_OK else "diverged"
        return df

    def report(self, x, scenarios=None) -> pd.DataFrame:
        """One row per scenario (index ``scenario``): f, feasible, reason, g_*, the metrics."""
        x = np.array([self.values(x)[k] for k in self.names])
        frames = []
        for name in (scenarios or list(self.scenarios)):
            frames.append(self.evaluate(x[None, :], name).to_frame().assign(scenario=name))
        return pd.concat(frames).set_index("scenario")

    def identity(self) -> dict:
        """Everything that defines the problem (hashed into the runner's problem_id)."""
        return dict(family="conical_tanks", case=self.case, controller=self.controller,
                    params=dataclasses.asdict(self.params), levels=self.levels.tolist(),
                    bounds=dict(zip(self.names, zip(self.lower.tolist(), self.upper.tolist()))),
                    Ts=self.Ts, Tf=self.Tf, objective=self.objective, constraints=self.constraints,
                    settling_band=self.settling_band, tuning_scenario=self.tuning_scenario,
                    scenarios={k: dataclasses.asdict(v) for k, v in self.scenarios.items()})

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels on a four-sample case."""
        r = np.full((4, 2), 10.0)
        out = np.empty((1, N_METRICS))
        status = np.empty(1, dtype=np.int64)
        run_batch(np.zeros((1, 6)), self.params.coefficients(), np.full(2, 10.0), np.ones(2), 0.0, 10.0,
                  np.ones(2), 1.0, 1, r, np.zeros((4, 2)), np.zeros((0, 4)), 0.02, out, status)
        simulate_loop(self.params.coefficients(), np.full(2, 10.0), np.zeros(6), np.ones(2), 0.0, 10.0,
                      np.ones(2), 1.0, 1, r, np.zeros((4, 2)), np.empty((4, 2)), np.empty((4, 2)))

    # -- optional hooks -------------------------------------------------------------------------
    def baseline(self, name: str) -> np.ndarray:
        """A fixed design: ``"simc"``, SIMC-style PI per loop on the tank's own linearisation.

        Each loop sees its tank as first order, ``K_i / (tau_i s + 1)`` with ``tau_i = -1 /
        J_ii`` and ``K_i = B_ii tau_i`` (the other level held), and gets ``Kp = tau / (K tc)``,
        ``Ki = Kp / min(tau, 4 tc)`` for the closed-loop time constant ``tc = simc_lambda tau``
        (Kd = 0 for a PID).
        """
        if name not in BASELINES:
            raise ConfigError(f"case {self.case!r}: unknown baseline {name!r}; allowed: {', '.join(BASELINES)}")
        J, B = linearise(self.params, self.levels)
        x = dict.fromkeys(self.names, 0.0)
        for i in range(2):
            tau = -1.0 / J[i, i]
            K = B[i, i] * tau
            tc = self.simc_lambda * tau
            kp = tau / (K * tc)
            x[f"Kp{i + 1}"] = kp
            x[f"Ki{i + 1}"] = kp / min(tau, 4.0 * tc)
        return np.array([x[k] for k in self.names])

    def physical_limits(self) -> dict:
        """Levels in ``[0, H_i]`` cm, pump voltages in ``u_range`` V."""
        return {"y": [(0.0, self.params.H[0]), (0.0, self.params.H[1])], "u": tuple(self.params.u_range)}


SCHEMA = dict(COMMON_SCHEMA, **{
    "plant": {
        "model": ("conical_tanks",),
        "cases": ("list", str),  # operating points: built-in names or plant.levels keys
        "levels": ("map", PAIR),  # extra operating points: name = [h1, h2] (cm)
        "R": PAIR, "H": PAIR, "A0": PAIR, "a": PAIR, "a12": NUMBER, "k": PAIR, "u_range": PAIR,
    },
    "controller": {
        "type": ("choices", CONTROLLERS),
        "Ts": NUMBER,  # control period, s (a whole number of scenario.dt)
        "Tf": NUMBER,  # derivative filter time constant, s
        "bounds": {"Kp": PAIR, "Ki": PAIR, "Kd": PAIR},
        "baselines": ("list", BASELINES),
        "simc_lambda": NUMBER,
    },
    "scenario": {
        "horizon": NUMBER, "dt": NUMBER,
        "steps1": ("list", PAIR), "steps2": ("list", PAIR),  # [[time s, size cm], ...]
        "input_disturbance": {"time": NUMBER, "size": PAIR},  # size in pump volts
        "uncertainty": ("map", NUMBER),  # scenario name = factor on the outlet areas
    },
    "problem": {
        "objective": tuple(OBJECTIVES),
        "constraints": {k: NUMBER for k in CONSTRAINT_KEYS},
        "settling_band": NUMBER,  # percent of the step size
        "tuning_scenario": str,
    },
})


@register_family("conical_tanks", schema=SCHEMA,
                 description="two coupled conical tanks (CCTS of paper 000), nonlinear, decentralised PI/PID "
                             "(plugin experiments/plugins/conical_tanks.py)")
class ConicalTanksExperiment(ExperimentBase):
    """An experiment config with ``[plant] model = "conical_tanks"``: one case per operating
    point (and controller type), each a :class:`ConicalTanksProblem`."""

    def __init__(self, config: dict):
        self.config = config
        self.name = config["name"]
        where = self.name
        plant = config.get("plant", {})
        self.params = self._params(plant)
        self.levels = dict(OPERATING_POINTS)
        self.levels.update({k: tuple(float(v) for v in pair) for k, pair in plant.get("levels", {}).items()})
        cases = tuple(plant.get("cases", ()))
        if not cases:
            raise ConfigError(f"{where}: plant.cases must name at least one operating point; allowed: "
                              f"{', '.join(self.levels)} (or define plant.levels.<name> = [h1, h2])")
        for case in cases:
            if case not in self.levels:
                raise ConfigError(f"{where}: plant.cases: unknown operating point {case!r}; allowed: "
                                  f"{', '.join(self.levels)} (or define plant.levels.{case} = [h1, h2])")
            h = self.levels[case]
            if not all(0.0 < h[i] < self.params.H[i] for i in (0, 1)):
                raise ConfigError(f"{where}: plant.levels.{case}: levels {list(h)} must lie in (0, H) = "
                                  f"(0, {list(self.params.H)}) cm")
        ctrl = config.get("controller", {})
        self._set_cases(cases, ctrl.get("type", "pi"))
        self.Ts = float(ctrl.get("Ts", 1.0))
        self.Tf = float(ctrl.get("Tf", 5.0))
        for key, val in (("Ts", self.Ts), ("Tf", self.Tf)):
            if not val > 0:
                raise ConfigError(f"{where}: controller.{key} must be > 0 s, got {val:g}")
        self.bounds = dict(DEFAULT_BOUNDS)
        for key, (lo, hi) in ctrl.get("bounds", {}).items():
            if not 0.0 <= lo < hi:
                raise ConfigError(f"{where}: controller.bounds.{key} must satisfy 0 <= lower < upper, got "
                                  f"[{lo:g}, {hi:g}]")
            self.bounds[key] = (float(lo), float(hi))
        self.baselines = tuple(ctrl.get("baselines", ()))
        self.simc_lambda = float(ctrl.get("simc_lambda", 0.5))
        if not self.simc_lambda > 0:
            raise ConfigError(f"{where}: controller.simc_lambda must be > 0, got {self.simc_lambda:g}")
        self.scenarios = self._scenarios(config.get("scenario", {}))
        prob = config.get("problem", {})
        self.objective = prob.get("objective", "iae")
        self.constraints = {k: float(v) for k, v in self._positive_limits(prob.get("constraints", {})).items()}
        shortest = min((k1 - k0) * sc.dt for sc in self.scenarios.values() for _, k0, k1, _ in sc.windows())
        if "ts" in self.constraints and not self.constraints["ts"] < shortest:
            raise ConfigError(f"{where}: problem.constraints.ts ({self.constraints['ts']:g} s) must be shorter "
                              f"than the shortest set-point step window ({shortest:g} s), or an unsettled "
                              "step would pass")
        self.settling_band = float(self._settling_band(prob, 2.0))
        self.tuning_scenario = self._tuning_scenario(prob)
        self._load_optimisers(config)  # (the runner asks for optimisers or baselines)
        for case in self.cases:
            self.problem(case)  # operating points reachable under every scenario, Ts on the grid

    def __repr__(self):
        return f"ConicalTanksExperiment({self.name!r}, cases={self.cases})"

    def _params(self, plant: dict) -> ConicalTanksParams:
        kw = {}
        for key in ("R", "H", "A0", "a", "k", "u_range"):
            if key in plant:
                kw[key] = tuple(float(v) for v in plant[key])
        if "a12" in plant:
            kw["a12"] = float(plant["a12"])
        p = ConicalTanksParams(**kw)
        for key in ("R", "H", "A0", "a", "k"):
            if not all(v > 0 for v in getattr(p, key)):
                raise ConfigError(f"{self.name}: plant.{key} must be two numbers > 0, got {list(getattr(p, key))}")
        if not p.a12 >= 0:
            raise ConfigError(f"{self.name}: plant.a12 must be >= 0 cm^2, got {p.a12:g}")
        if not p.u_range[0] < p.u_range[1]:
            raise ConfigError(f"{self.name}: plant.u_range must be [u_min, u_max] with u_min < u_max, "
                              f"got {list(p.u_range)}")
        return p

    def _scenarios(self, sc: dict) -> dict:
        kw = {}
        for key in ("horizon", "dt"):
            if key in sc:
                kw[key] = float(sc[key])
        for key in ("steps1", "steps2"):
            if key in sc:
                kw[key] = tuple((float(t), float(s)) for t, s in sc[key])
        if "input_disturbance" in sc:
            dist = sc["input_disturbance"]
            kw["disturbance"] = (float(dist.get("time", 0.0)), tuple(float(v) for v in dist.get("size", (0.0, 0.0))))
        factors = dict(sc.get("uncertainty", DEFAULT_UNCERTAINTY))
        if "nominal" not in factors:
            factors = {"nominal": 1.0, **factors}
        scenarios = {name: TankScenario(name=name, a_factor=float(v), **kw) for name, v in factors.items()}
        for s in scenarios.values():
            for case in dict.fromkeys(pc for pc, _ in self._variants.values()):
                s.check(self.name, self.levels[case], self.params.H)
        return scenarios

    def problem(self, case: str) -> ConicalTanksProblem:
        """The tuning problem of one case (an operating point, with its controller type)."""
        plant_case, kind = self._variant(case)
        try:
            return ConicalTanksProblem(
                case, kind, self.params, self.levels[plant_case], self.bounds, scenarios=self.scenarios,
                tuning_scenario=self.tuning_scenario, objective=self.objective, constraints=self.constraints,
                Ts=self.Ts, Tf=self.Tf, settling_band=self.settling_band, simc_lambda=self.simc_lambda)
        except ConfigError as exc:
            raise ConfigError(f"{self.name}: {exc}") from None

    def baseline_names(self, case: str) -> tuple:
        """The fixed designs of ``controller.baselines`` (``"simc"``), run once per case."""
        return self.baselines
