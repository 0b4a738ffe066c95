"""Nonlinear coupled two-tank plant (paper 002, section II): parameters, equilibria, linearisation,
small-signal TITO model and a closed-loop simulator that is a drop-in for ``simulate_tito``.

Model (mass balance with Torricelli/Bernoulli outflows; levels ``h`` in cm, pump inputs ``u`` in V,
time in s)::

    dh1/dt = eta1 u1 - (a1/A) sqrt(2 g h1) - (a12/A) ssqrt(2 g (h1 - h2))
    dh2/dt = eta2 u2 - (a2/A) sqrt(2 g h2) + (a12/A) ssqrt(2 g (h1 - h2))

``ssqrt(x) = sign(x) sqrt(|x|)``: the coupling flow runs from the higher to the lower tank and
reverses when the levels cross. Levels are clipped at 0 under every root. The paper writes one
pump constant ``eta``; a pair ``(eta1, eta2)`` is allowed (a scalar means both pumps are equal).

Dead times: pump ``j`` applies its command ``Lu_j`` seconds late and level sensor ``i`` reports
the level ``Ly_i`` seconds late, so the small-signal element ``g_ij`` carries the dead time
``Ly_i + Lu_j``. (A free delay per input/output pair cannot be realised on this plant: pump ``j``
feeds tank ``j`` only and reaches the other tank through it.)

The default parameters are calibrated to the identified model of paper 002 eq. 28 (preset
``two_tank`` of :mod:`tito`); see :func:`calibrate` and ``docs/two_tank.md`` for what matches
(all four DC gains, the slow time constant) and what cannot (the fast mode, the zeros of the
diagonal elements, the decoupled-loop time constants).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
from scipy.optimize import brentq

from heurtune.core.errors import ConfigError

from . import two_tank_kernels as _k
from .model import TFElement, TITOPlant
from .sim import (
    TITOScenario,
    _decoupler_entries,
    _delay_samples,
    _step_signal,
    controller_tf,
    discretise_rational,
)

__all__ = [
    "CONFIG_KEYS",
    "DEFAULT_VARY",
    "MODEL_NAME",
    "VARY_KEYS",
    "OperatingPoint",
    "TwoTankParams",
    "calibrate",
    "equilibrium_levels",
    "from_config",
    "linear_tito_plant",
    "linearise",
    "operating_point",
    "simulate_two_tank",
    "two_tank_rhs",
]

MODEL_NAME = "two_tank_nonlinear"
CONFIG_KEYS = ("model", "name", "A", "a1", "a2", "a12", "eta", "g", "levels", "inputs",
               "pump_delays", "sensor_delays")
VARY_KEYS = ("A", "a1", "a2", "a12", "eta", "pump_delays", "sensor_delays")
DEFAULT_VARY = ("A", "a1", "a2", "a12")
# Smallest |h1 - h2| (cm) at which the coupling flow is linearised (its slope is infinite at 0).
MIN_LEVEL_GAP = 1e-6


def _prefix(name) -> str:
    return f"two_tank plant '{name}'"


def _number(owner: str, key: str, val, unit: str, *, low: float = 0.0, strict: bool = True) -> float:
    rng = f"{'>' if strict else '>='} {low:g}"
    try:
        x = float(val)
    except (TypeError, ValueError):
        raise ConfigError(f"{owner}: {key} must be a finite number {rng} ({unit}), got {val!r}") from None
    if isinstance(val, bool) or not math.isfinite(x) or (x <= low if strict else x < low):
        raise ConfigError(f"{owner}: {key} must be a finite number {rng} ({unit}), got {val!r}")
    return x


def _pair(owner: str, key: str, val, unit: str, *, strict: bool = True, scalar_ok: bool = False) -> tuple:
    rng = f"{'>' if strict else '>='} 0"
    if scalar_ok and np.ndim(val) == 0 and not isinstance(val, (str, bytes)):
        x = _number(owner, key, val, unit, strict=strict)
        return (x, x)
    if isinstance(val, (str, bytes)) or not hasattr(val, "__len__") or len(val) != 2:
        what = "a number or a pair" if scalar_ok else "a pair"
        raise ConfigError(f"{owner}: {key} must be {what} of finite numbers {rng} ({unit}), got {val!r}")
    return tuple(_number(owner, f"{key}[{i}]", v, unit, strict=strict) for i, v in enumerate(val))


def _ssqrt(x: float) -> float:
    return math.copysign(math.sqrt(abs(x)), x)


# --------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TwoTankParams:
    """Physical parameters of the coupled two-tank rig and its operating levels.

    Parameters
    ----------
    A : float
        Cross section of each tank, cm^2 (> 0).
    a1, a2 : float
        Outlet areas of tank 1 and tank 2, cm^2 (>= 0; 0 is a closed outlet).
    a12 : float
        Opening of the coupling pipe between the tanks, cm^2 (>= 0; 0 decouples the tanks).
    eta : float or pair
        Pump constants ``(eta1, eta2)``: level rate per pump volt, cm/(V s) (> 0). The pump's
        volume flow is ``A eta_j u_j`` cm^3/s.
    levels : pair
        Operating levels ``(h1, h2)``, cm (> 0); the loop is simulated about this equilibrium.
    pump_delays : pair
        Pump actuation dead times ``(Lu1, Lu2)``, s (>= 0).
    sensor_delays : pair
        Level measurement dead times ``(Ly1, Ly2)``, s (>= 0).
    g : float
        Gravitational acceleration, cm/s^2 (> 0).
    name : str

    The defaults are the calibration of ``docs/two_tank.md`` (tank-2 outlet closed, so tank 2
    drains through tank 1 and ``h2 > h1`` at the operating point).
    """

    A: float = 150.0
    a1: float = 0.062443
    a2: float = 0.0
    a12: float = 0.093369
    eta: tuple = (0.0076558, 0.0080147)
    levels: tuple = (7.0, 7.8)
    pump_delays: tuple = (5.5, 5.5)
    sensor_delays: tuple = (1.9, 24.5)
    g: float = 981.0
    name: str = "two_tank_rig"

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ConfigError(f"two_tank plant: name must be a string, got {self.name!r}")
        own = _prefix(self.name)
        vals = {
            "A": _number(own, "A", self.A, "cm^2"),
            "a1": _number(own, "a1", self.a1, "cm^2", strict=False),
            "a2": _number(own, "a2", self.a2, "cm^2", strict=False),
            "a12": _number(own, "a12", self.a12, "cm^2", strict=False),
            "eta": _pair(own, "eta", self.eta, "cm/(V s)", scalar_ok=True),
            "levels": _pair(own, "levels", self.levels, "cm"),
            "pump_delays": _pair(own, "pump_delays", self.pump_delays, "s", strict=False),
            "sensor_delays": _pair(own, "sensor_delays", self.sensor_delays, "s", strict=False),
            "g": _number(own, "g", self.g, "cm/s^2"),
        }
        for key, val in vals.items():
            object.__setattr__(self, key, val)

    def coefficients(self) -> np.ndarray:
        """``[c1, c2, c12, eta1, eta2]`` with ``c = a sqrt(2 g) / A`` (cm^0.5/s), for the kernel."""
        r = math.sqrt(2.0 * self.g)
        return np.array([self.a1 * r / self.A, self.a2 * r / self.A, self.a12 * r / self.A, *self.eta])

    def delays(self) -> np.ndarray:
        """Dead time of each small-signal element, ``L[i, j] = Ly_i + Lu_j`` (s), shape (2, 2)."""
        return np.add.outer(np.array(self.sensor_delays), np.array(self.pump_delays))

    def varied(self, delta: float, vary=DEFAULT_VARY) -> TwoTankParams:
        """The plant with the fields named in ``vary`` multiplied by ``1 + delta``.

        ``vary`` is any of ``A, a1, a2, a12, eta, pump_delays, sensor_delays``. Scaling ``A``
        keeps the pumps' volume flow ``A eta u``, so ``eta`` is divided by ``1 + delta`` too
        (and multiplied by it if ``eta`` is also named). The default (``A, a1, a2, a12``, the
        thesis convention of ``QTPParams.scaled``) keeps every time constant and the operating
        levels and divides all small-signal gains by ``1 + delta``.
        """
        try:
            d = float(delta)
        except (TypeError, ValueError):
            raise ConfigError(f"variation must be a number in (-1, 1), got {delta!r}") from None
        if not (math.isfinite(d) and -1 < d < 1):
            raise ConfigError(f"variation must be a number in (-1, 1), got {delta!r}")
        vary = (vary,) if isinstance(vary, str) else tuple(vary)
        bad = [v for v in vary if v not in VARY_KEYS]
        if bad:
            raise ConfigError(
                f"two_tank vary: unknown key(s) {', '.join(map(str, bad))}; allowed: {', '.join(VARY_KEYS)}"
            )
        f = 1.0 + d
        new = {}
        for key in ("A", "a1", "a2", "a12"):
            if key in vary:
                new[key] = getattr(self, key) * f
        ef = (f if "eta" in vary else 1.0) / (f if "A" in vary else 1.0)
        new["eta"] = tuple(e * ef for e in self.eta)
        for key in ("pump_delays", "sensor_delays"):
            if key in vary:
                new[key] = tuple(v * f for v in getattr(self, key))
        if d:
            new["name"] = f"{self.name}*{f:g}"
        return dataclasses.replace(self, **new)


@dataclasses.dataclass(frozen=True)
class OperatingPoint:
    """Equilibrium of the two-tank plant: levels ``h`` (2,) in cm and pump inputs ``u`` (2,) in V."""

    h: np.ndarray
    u: np.ndarray


def two_tank_rhs(h, u, params: TwoTankParams) -> np.ndarray:
    """Nonlinear right-hand side ``dh/dt`` (cm/s) for levels ``h`` (cm) and pump inputs ``u`` (V).

    Levels are clipped at 0 under the roots; the coupling flow uses the signed square root.

    Parameters
    ----------
    h : array_like (2,)
    u : array_like (2,)
    params : TwoTankParams

    Returns
    -------
    ndarray (2,)
    """
    c1, c2, c12, e1, e2 = params.coefficients()
    p1, p2 = max(float(h[0]), 0.0), max(float(h[1]), 0.0)
    q12 = c12 * _ssqrt(p1 - p2)
    return np.array([e1 * u[0] - c1 * math.sqrt(p1) - q12, e2 * u[1] - c2 * math.sqrt(p2) + q12])


def _levels(params: TwoTankParams, levels) -> tuple:
    if levels is None:
        return params.levels
    return _pair(_prefix(params.name), "levels", levels, "cm")


def operating_point(params: TwoTankParams, levels=None) -> OperatingPoint:
    """Pump inputs that hold ``levels`` (default ``params.levels``) in equilibrium.

    Each tank balance is linear in its own pump input::

        eta1 u1 = c1 sqrt(h1) + c12 ssqrt(h1 - h2),   eta2 u2 = c2 sqrt(h2) - c12 ssqrt(h1 - h2)

    Parameters
    ----------
    params : TwoTankParams
    levels : array_like (2,), optional
        Default ``params.levels``.

    Returns
    -------
    OperatingPoint

    Raises
    ------
    ConfigError
        Levels not positive; ``h1 = h2`` with an open coupling (the coupling flow has an infinite
        slope there, so the point cannot be linearised); a pump input below 0 (the coupling flow
        into that tank exceeds what its outlet drains, e.g. ``h1 > h2`` with tank 2's outlet
        closed).
    """
    h1, h2 = _levels(params, levels)
    own = _prefix(params.name)
    c1, c2, c12, e1, e2 = params.coefficients()
    if c12 > 0 and abs(h1 - h2) < MIN_LEVEL_GAP:
        raise ConfigError(f"{own}: levels h1 = h2 = {h1:g} cm put the coupling flow at its non-differentiable "
                          f"point; choose |h1 - h2| >= {MIN_LEVEL_GAP:g} cm")
    q12 = c12 * _ssqrt(h1 - h2)
    u1 = (c1 * math.sqrt(h1) + q12) / e1
    u2 = (c2 * math.sqrt(h2) - q12) / e2
    for j, uj in ((1, u1), (2, u2)):
        if uj < 0:
            raise ConfigError(
                f"{own}: levels ({h1:g}, {h2:g}) cm need pump input u{j} = {uj:.4g} V < 0 (the coupling flow into "
                f"tank {j} exceeds its outlet flow); allowed: levels whose pump inputs are >= 0"
            )
    return OperatingPoint(h=np.array([h1, h2]), u=np.array([u1, u2]))


def equilibrium_levels(params: TwoTankParams, inputs) -> np.ndarray:
    """Levels (cm) at which the constant pump ``inputs`` (V, both >= 0) are in equilibrium.

    Solved by bracketing on ``h1``: tank 1's balance gives ``h2(h1)``, and the total outflow
    ``c1 sqrt(h1) + c2 sqrt(h2)`` increases with ``h1`` until it equals the total inflow.

    Parameters
    ----------
    params : TwoTankParams
    inputs : array_like (2,)

    Returns
    -------
    ndarray (2,)
    """
    own = _prefix(params.name)
    u1, u2 = _pair(own, "inputs", inputs, "V", strict=False)
    c1, c2, c12, e1, e2 = params.coefficients()
    f1, f2 = e1 * u1, e2 * u2
    if c12 == 0.0:
        for j, (f, c) in enumerate(((f1, c1), (f2, c2)), start=1):
            if f > 0 and c == 0:
                raise ConfigError(f"{own}: tank {j} has no outlet and no coupling; no equilibrium for u{j} > 0")
        return np.array([(f1 / c1) ** 2 if f1 else 0.0, (f2 / c2) ** 2 if f2 else 0.0])
    if c1 == 0.0 and c2 == 0.0:
        raise ConfigError(f"{own}: a1 and a2 are both 0 (no outlet); no equilibrium for inputs > 0")
    if f1 + f2 == 0.0:
        return np.zeros(2)

    def h2_of(h1):
        s = (f1 - c1 * math.sqrt(h1)) / c12
        return h1 - s * abs(s)

    def total(h1):
        return c1 * math.sqrt(h1) + c2 * math.sqrt(max(h2_of(h1), 0.0)) - (f1 + f2)

    hi = 1.0
    while total(hi) <= 0:
        hi *= 2.0
        if hi > 1e12:
            raise ConfigError(f"{own}: no equilibrium found for inputs ({u1:g}, {u2:g}) V")
    h1 = brentq(total, 0.0, hi, xtol=1e-14, rtol=4 * np.finfo(float).eps, maxiter=500)
    return np.array([h1, max(h2_of(h1), 0.0)])


# --------------------------------------------------------------------------------------------
# Linearisation and the small-signal TITO model
# --------------------------------------------------------------------------------------------


def _conductances(params: TwoTankParams, h) -> tuple:
    """``(k1, k2, k12)``: slopes (1/s) of the outlet and coupling flows (per A) at the levels ``h``."""
    c1, c2, c12, _, _ = params.coefficients()
    h1, h2 = h
    k12 = 0.0 if c12 == 0.0 else 0.5 * c12 / math.sqrt(abs(h1 - h2))
    return 0.5 * c1 / math.sqrt(h1), 0.5 * c2 / math.sqrt(h2), k12


def linearise(params: TwoTankParams, levels=None):
    """Small-signal model about the equilibrium at ``levels`` (default ``params.levels``).

    Parameters
    ----------
    params : TwoTankParams
    levels : array_like (2,), optional
        Default ``params.levels``.

    Returns
    -------
    A : (2, 2) ndarray
        ``[[-(k1 + k12), k12], [k12, -(k2 + k12)]]`` (1/s) with ``k1 = c1 / (2 sqrt(h1))``,
        ``k2 = c2 / (2 sqrt(h2))``, ``k12 = c12 / (2 sqrt|h1 - h2|)``. It is symmetric, so its
        eigenvalues (the poles) are real.
    B : (2, 2) ndarray
        ``diag(eta1, eta2)`` (cm/(V s)).
    C : (2, 2) ndarray
        Identity (both levels measured). Dead times are not part of ``(A, B, C)``.

    Deviation model ``dx/dt = A x + B du``, ``dy = C x`` (x, y in cm, du in V).
    """
    op = operating_point(params, levels)
    k1, k2, k12 = _conductances(params, op.h)
    A = np.array([[-(k1 + k12), k12], [k12, -(k2 + k12)]])
    return A, np.diag(np.array(params.eta, dtype=float)), np.eye(2)


def linear_tito_plant(params: TwoTankParams, levels=None, name: str | None = None) -> TITOPlant:
    """The linearisation as a :class:`TITOPlant` (second-order elements plus dead times).

    ``G(s) = (sI - A)^-1 B`` with ``det(sI - A) = (s + p1)(s + p2)``, ``p1, p2 > 0`` real (``A`` is
    symmetric and negative definite whenever an equilibrium exists)::

        g11 = eta1 (s + k2 + k12) / det,  g12 = eta2 k12 / det,
        g21 = eta1 k12 / det,             g22 = eta2 (s + k1 + k12) / det

    as ``TFElement(K, leads, lags, L)`` with lags ``1/p1, 1/p2``, the diagonal leads
    ``1/(k2 + k12)`` and ``1/(k1 + k12)``, and ``L = Ly_i + Lu_j``. With the coupling closed
    (``a12 = 0``) the off-diagonal elements are zero. Complex poles cannot occur; a
    non-positive pole (no outlet reachable) is reported as a ConfigError.

    Parameters
    ----------
    params : TwoTankParams
    levels : array_like (2,), optional
        Default ``params.levels``.
    name : str, optional

    Returns
    -------
    TITOPlant
    """
    A, B, _ = linearise(params, levels)
    own = _prefix(params.name)
    k12 = A[0, 1]
    tr = -(A[0, 0] + A[1, 1])
    det = A[0, 0] * A[1, 1] - k12 * k12
    disc = (A[0, 0] - A[1, 1]) ** 2 + 4.0 * k12 * k12  # tr^2 - 4 det, >= 0 for symmetric A
    if not det > 0:
        raise ConfigError(f"{own}: the linearisation has a pole at s >= 0 (no outlet is reachable); "
                          f"allowed: a1 > 0, or a2 > 0")
    sq = math.sqrt(disc)
    p_fast = 0.5 * (tr + sq)
    p_slow = det / p_fast  # stable form of 0.5 (tr - sq)
    lags = (1.0 / p_slow, 1.0 / p_fast)
    e1, e2 = B[0, 0], B[1, 1]
    z11, z22 = -A[1, 1], -A[0, 0]  # zeros of g11, g22: s = -(k2 + k12), s = -(k1 + k12)
    L = params.delays()
    zero = TFElement(K=0.0)
    g11 = TFElement(K=e1 * z11 / det, leads=(1.0 / z11,), lags=lags, L=L[0, 0])
    g22 = TFElement(K=e2 * z22 / det, leads=(1.0 / z22,), lags=lags, L=L[1, 1])
    if k12 > 0:
        g12 = TFElement(K=e2 * k12 / det, lags=lags, L=L[0, 1])
        g21 = TFElement(K=e1 * k12 / det, lags=lags, L=L[1, 0])
    else:
        g12 = g21 = zero
    return TITOPlant(g11=g11, g12=g12, g21=g21, g22=g22, name=name or f"{params.name}_linear")


# --------------------------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------------------------


def calibrate(target, T_slow: float, *, A: float, levels, pump_delays=(0.0, 0.0), sensor_delays=(0.0, 0.0),
              g: float = 981.0, name: str = "calibrated") -> TwoTankParams:
    """Physical parameters whose linearisation at ``levels`` has the DC gains of ``target`` exactly
    and the slow time constant ``T_slow``.

    With ``G(0) = M^-1 diag(eta1, eta2)`` and ``M = [[k1 + k12, -k12], [-k12, k2 + k12]]`` the
    gains ``K`` fix (with ``D = det K``)::

        eta2 / eta1 = K12 / K21,  k12 = eta1 K12 / D,  k1 = eta1 (K22 - K12) / D,
        k2 = eta2 (K11 - K21) / D

    so an exact match needs ``K > 0`` elementwise, ``D > 0``, ``K22 >= K12`` and ``K11 >= K21``
    (``K11 = K21`` means ``a2 = 0``). ``T_slow`` (the slower pole's time constant) then fixes the
    common scale ``eta1``, and the areas follow from ``a = 2 k A sqrt(h) / sqrt(2 g)`` (with
    ``|h1 - h2|`` for ``a12``).

    Parameters
    ----------
    target : TITOPlant or (2, 2) array_like
        Model (its ``dc_gain()``) or gain matrix to reproduce.
    T_slow : float
        Slow time constant, s.
    A, levels, pump_delays, sensor_delays, g, name
        As in :class:`TwoTankParams`; ``A`` only sets the scale of the areas and pump flows.

    Returns
    -------
    TwoTankParams
    """
    K = target.dc_gain() if isinstance(target, TITOPlant) else np.asarray(target, dtype=float)
    if K.shape != (2, 2) or not np.all(np.isfinite(K)):
        raise ConfigError(f"calibrate: target must be a TITOPlant or a 2x2 gain matrix, got {target!r}")
    D = K[0, 0] * K[1, 1] - K[0, 1] * K[1, 0]
    if not (np.all(K > 0) and D > 0 and K[1, 1] >= K[0, 1] and K[0, 0] >= K[1, 0]):
        raise ConfigError(
            f"calibrate: gains {K.tolist()} are not those of a two-tank plant; allowed: all > 0, det > 0, "
            f"K22 >= K12 and K11 >= K21"
        )
    T_slow = _number("calibrate", "T_slow", T_slow, "s")
    r = K[0, 1] / K[1, 0]  # eta2 / eta1
    k12, k1, k2 = K[0, 1] / D, (K[1, 1] - K[0, 1]) / D, r * (K[0, 0] - K[1, 0]) / D  # for eta1 = 1
    tr, det = k1 + k2 + 2 * k12, k1 * k2 + k12 * (k1 + k2)
    p_slow = det / (0.5 * (tr + math.sqrt(max(tr * tr - 4 * det, 0.0))))
    eta1 = 1.0 / (p_slow * T_slow)
    h1, h2 = _pair(f"calibrate '{name}'", "levels", levels, "cm")
    s = 2.0 * _number("calibrate", "A", A, "cm^2") / math.sqrt(2.0 * _number("calibrate", "g", g, "cm/s^2"))
    return TwoTankParams(
        A=A, a1=s * eta1 * k1 * math.sqrt(h1), a2=s * eta1 * k2 * math.sqrt(h2),
        a12=s * eta1 * k12 * math.sqrt(abs(h1 - h2)), eta=(eta1, r * eta1), levels=(h1, h2),
        pump_delays=pump_delays, sensor_delays=sensor_delays, g=g, name=name,
    )


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------


def from_config(cfg) -> TwoTankParams:
    """Build the plant from a ``[plant]`` table (a dict); absent keys keep the calibrated defaults.

    Keys: ``model`` (``"two_tank_nonlinear"``, optional), ``name``, ``A``, ``a1``, ``a2``, ``a12``,
    ``eta`` (number or ``[eta1, eta2]``), ``g``, ``levels = [h1, h2]`` or ``inputs = [u1, u2]``
    (the equilibrium levels of those pump inputs; not both), ``pump_delays``, ``sensor_delays``.
    The operating point is checked (a ConfigError names the infeasible levels).

    Parameters
    ----------
    cfg : dict

    Returns
    -------
    TwoTankParams
    """
    if not isinstance(cfg, dict):
        raise ConfigError(f"[plant]: must be a table with keys {', '.join(CONFIG_KEYS)}, got {cfg!r}")
    unknown = sorted(set(cfg) - set(CONFIG_KEYS))
    if unknown:
        raise ConfigError(f"[plant]: unknown key(s) {', '.join(map(str, unknown))}; allowed: {', '.join(CONFIG_KEYS)}")
    model = cfg.get("model", MODEL_NAME)
    if model != MODEL_NAME:
        raise ConfigError(f"[plant]: model = {model!r} is not handled here; allowed: {MODEL_NAME!r}")
    if "levels" in cfg and "inputs" in cfg:
        raise ConfigError("[plant]: give either levels or inputs, not both")
    kw = {k: v for k, v in cfg.items() if k not in ("model", "inputs")}
    p = TwoTankParams(**kw)
    if "inputs" in cfg:
        h = equilibrium_levels(p, cfg["inputs"])
        p = dataclasses.replace(p, levels=(float(h[0]), float(h[1])))
    operating_point(p)
    return p


# --------------------------------------------------------------------------------------------
# Closed-loop simulation
# --------------------------------------------------------------------------------------------


def simulate_two_tank(params: TwoTankParams, controllers, decoupler=None, scenario: TITOScenario | None = None,
                      *, vary=DEFAULT_VARY) -> pd.DataFrame:
    """Closed loop of the nonlinear plant with the decoupler and controllers of ``simulate_tito``.

    Same loop, scenario and record as :func:`tito_sim.simulate_tito`, with the plant replaced by
    the nonlinear tanks (RK4, pump inputs held over each step ``scenario.dt``) about the
    equilibrium at ``params.levels``. All signals are deviations from that operating point:
    ``y`` is the level deviation (cm) reported by the sensors (after their dead time) plus the
    output disturbance, ``u`` the pump input deviation (V) from the decoupler, before the input
    disturbance, ``v`` the controller outputs. The loop starts at rest.

    Parameters
    ----------
    params : TwoTankParams
    controllers : pair of PIController / PIDController
    decoupler : Decoupler or None
        Realised from ``decoupler.plant`` (e.g. designed on :func:`linear_tito_plant` or on the
        identified preset); ``None`` is ``D = I``.
    scenario : TITOScenario, default ``TITOScenario()``
        ``variation = delta`` multiplies the physical parameters named in ``vary`` by
        ``1 + delta`` (``scenario.vary`` names transfer-function parameters and is not used).
        The varied plant starts at rest at the same levels (its own equilibrium inputs); a
        variation that makes those levels unreachable (a pump input < 0) is a ConfigError.
    vary : tuple of str
        Any of ``A, a1, a2, a12, eta, pump_delays, sensor_delays`` (see
        :meth:`TwoTankParams.varied`).

    Returns
    -------
    DataFrame with columns ``t, r1, r2, y1, y2, ym1, ym2, u1, u2, v1, v2``. ``attrs``: ``status``
    ("ok" / "diverged": signals or levels left the kernel's limits or became NaN; the rows from
    there on are NaN), ``delay_rounding`` (largest ``|round(L/dt) dt - L|``, s), ``plant`` (the
    small-signal :class:`TITOPlant` of the simulated plant), ``params`` (the simulated
    :class:`TwoTankParams`), ``operating_point``.

    A bad candidate controller never raises: it ends with status "diverged".
    """
    sc = TITOScenario() if scenario is None else scenario
    if not isinstance(sc, TITOScenario):
        raise ConfigError(f"scenario: must be a TITOScenario, got {type(sc).__name__}")
    if not isinstance(params, TwoTankParams):
        raise ConfigError(f"plant: must be a TwoTankParams, got {type(params).__name__}")
    if isinstance(controllers, (str, bytes)) or not hasattr(controllers, "__len__") or len(controllers) != 2:
        raise ConfigError("controllers: must be a pair (c1, c2) of PIController / PIDController")
    dt = sc.dt
    p = params.varied(sc.variation, vary) if sc.variation else params
    if not sc.variation:
        params.varied(0.0, vary)  # validates vary
    op = operating_point(p)
    small_signal = linear_tito_plant(p)  # also rejects plants without a reachable outlet, before simulating

    blocks = []
    rounding = 0.0
    for i, c in enumerate(controllers, start=1):
        Ad, Bd, C, D = discretise_rational(*controller_tf(c, i), dt)
        blocks.append((Ad, Bd, C, D, 0))
    for q, (num, den, L) in enumerate(_decoupler_entries(decoupler)):
        Ad, Bd, C, D = discretise_rational(num, den, dt)
        nd, err = _delay_samples(f"decoupler D{q // 2 + 1}{q % 2 + 1}", L, dt)
        rounding = max(rounding, err)
        blocks.append((Ad, Bd, C, D, nd))
    ndu = np.zeros(2, dtype=np.int64)
    ndy = np.zeros(2, dtype=np.int64)
    for j in range(2):
        ndu[j], err = _delay_samples(f"pump {j + 1} dead time", p.pump_delays[j], dt)
        rounding = max(rounding, err)
        ndy[j], err = _delay_samples(f"sensor {j + 1} dead time", p.sensor_delays[j], dt)
        rounding = max(rounding, err)

    nb = _k.N_BLOCKS
    m = max(1, max(b[0].shape[0] for b in blocks))
    A = np.zeros((nb, m, m))
    B = np.zeros((nb, m))
    C = np.zeros((nb, m))
    D = np.zeros(nb)
    ns = np.zeros(nb, dtype=np.int64)
    nd = np.zeros(nb, dtype=np.int64)
    for b, (Ad, Bd, Cb, Db, d) in enumerate(blocks):
        k = Ad.shape[0]
        A[b, :k, :k] = Ad
        B[b, :k] = Bd
        C[b, :k] = Cb
        D[b] = Db
        ns[b] = k
        nd[b] = d

    t = sc.time()
    n1 = t.size
    r = np.column_stack([_step_signal(t, sc.setpoints[0]), _step_signal(t, sc.setpoints[1])])
    ti, mi = sc.input_disturbance
    to, mo = sc.output_disturbance
    on_i = (t >= ti - 1e-9).astype(np.float64)
    on_o = (t >= to - 1e-9).astype(np.float64)
    d_in = np.column_stack([on_i * mi[0], on_i * mi[1]])
    d_out = np.column_stack([on_o * mo[0], on_o * mo[1]])
    rng = np.random.default_rng(sc.noise_seed)
    noise = rng.standard_normal((n1, 2)) * np.sqrt(np.array(sc.noise_power) / dt)

    x = np.zeros((nb, m))
    buf = np.zeros((nb, int(nd.max()) + 1))
    ubuf = np.zeros((2, int(ndu.max()) + 1))
    ybuf = np.zeros((2, int(ndy.max()) + 1))
    xt = np.zeros(m)
    y = np.empty((n1, 2))
    ym = np.empty((n1, 2))
    u = np.empty((n1, 2))
    v = np.empty((n1, 2))
    status = _k.simulate_two_tank(A, B, C, D, ns, nd, p.coefficients(), op.h, op.u, ndu, ndy, dt,
                                  np.ascontiguousarray(r), d_in, d_out, np.ascontiguousarray(noise),
                                  x, buf, xt, ubuf, ybuf, y, ym, u, v)
    df = pd.DataFrame({"t": t, "r1": r[:, 0], "r2": r[:, 1], "y1": y[:, 0], "y2": y[:, 1],
                       "ym1": ym[:, 0], "ym2": ym[:, 1], "u1": u[:, 0], "u2": u[:, 1],
                       "v1": v[:, 0], "v2": v[:, 1]})
    df.attrs["status"] = "ok" if status == _k.STATUS_OK else "diverged"
    df.attrs["delay_rounding"] = rounding
    df.attrs["plant"] = small_signal
    df.attrs["params"] = p
    df.attrs["operating_point"] = op
    return df
