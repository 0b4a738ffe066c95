"""Two-input two-output (TITO) coupled-tank plants, decouplers, FOPDT reduction and GPM tuning.

Plants are 2x2 matrices of elements ``K prod(1 + s Tz) / prod(1 + s Tp) e^{-L s}``; every
frequency response is evaluated exactly (delays as ``e^{-j w L}``, no Pade approximation).

Pipeline (papers 000-002 of the seeds)::

    plant -> decoupler D(s) -> diagonal z11, z22 -> FOPDT fit -> GPM PI/PID -> exact margins

The FOPDT models printed in the papers do not follow from their printed plants (see the seeds'
README); fit them here and check the fit by its defining equations, never by the printed numbers.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from scipy.optimize import brentq

from heurtune.core.errors import ConfigError

__all__ = [
    "FOPDT",
    "PRESETS",
    "Decoupler",
    "Margins",
    "PIController",
    "PIDController",
    "ParallelPID",
    "TFElement",
    "TITOPlant",
    "exact_margins",
    "fit_fopdt",
    "gpm_pi",
    "gpm_pid",
    "inverted_decoupler",
    "preset",
]

_ELEMENT_KEYS = ("K", "leads", "lags", "L")
_PLANT_KEYS = ("g11", "g12", "g21", "g22", "name")


def _as_w(w) -> np.ndarray:
    return np.atleast_1d(np.asarray(w, dtype=np.float64))


# --------------------------------------------------------------------------------------------
# Elements and plants
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TFElement:
    """One transfer-function element ``G(s) = K prod(1 + s Tz) / prod(1 + s Tp) e^{-L s}``.

    Parameters
    ----------
    K : float
        Static gain (any finite sign).
    leads : tuple of float
        Numerator time constants ``Tz`` (finite; a negative ``Tz`` is a right-half-plane zero).
    lags : tuple of float
        Denominator time constants ``Tp`` (finite and positive: stable poles only).
    L : float
        Dead time, ``L >= 0``.
    """

    K: float
    leads: tuple = ()
    lags: tuple = ()
    L: float = 0.0

    def __post_init__(self):
        try:
            K = float(self.K)
            L = float(self.L)
            leads = tuple(float(v) for v in self.leads)
            lags = tuple(float(v) for v in self.lags)
        except (TypeError, ValueError):
            raise ConfigError(
                f"element: K, L must be numbers and leads, lags lists of numbers, got "
                f"K={self.K!r}, leads={self.leads!r}, lags={self.lags!r}, L={self.L!r}"
            ) from None
        if not math.isfinite(K):
            raise ConfigError(f"element: K must be finite, got {K!r}")
        if not (math.isfinite(L) and L >= 0):
            raise ConfigError(f"element: L must be finite and >= 0, got {L!r}")
        if not all(math.isfinite(v) for v in leads):
            raise ConfigError(f"element: leads must be finite, got {leads}")
        if not all(math.isfinite(v) and v > 0 for v in lags):
            raise ConfigError(f"element: lags must be finite and > 0, got {lags}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "L", L)
        object.__setattr__(self, "leads", leads)
        object.__setattr__(self, "lags", lags)

    @property
    def relative_degree(self) -> int:
        """Number of poles minus number of (non-trivial) zeros."""
        return len(self.lags) - sum(1 for t in self.leads if t != 0.0)

    @property
    def has_rhp_zero(self) -> bool:
        """True when a lead time constant is negative (zero at ``s = -1/Tz > 0``)."""
        return any(t < 0 for t in self.leads)

    def rational(self, w) -> np.ndarray:
        """Frequency response of the delay-free part at ``s = j w``."""
        s = 1j * _as_w(w)
        out = np.full(s.shape, self.K, dtype=np.complex128)
        for t in self.leads:
            out *= 1.0 + s * t
        for t in self.lags:
            out /= 1.0 + s * t
        return out

    def freqresp(self, w) -> np.ndarray:
        """Exact frequency response ``G(j w)``, shape ``(n,)`` complex."""
        w = _as_w(w)
        return self.rational(w) * np.exp(-1j * w * self.L)

    def dc_gain(self) -> float:
        """Static gain ``G(0) = K``."""
        return self.K

    @classmethod
    def from_config(cls, cfg, key: str = "element") -> TFElement:
        """Build an element from ``{"K": .., "leads": [..], "lags": [..], "L": ..}``."""
        if not isinstance(cfg, dict):
            raise ConfigError(f"{key}: must be a mapping with keys {', '.join(_ELEMENT_KEYS)}, got {cfg!r}")
        unknown = sorted(set(cfg) - set(_ELEMENT_KEYS))
        if unknown:
            raise ConfigError(f"{key}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(_ELEMENT_KEYS)}")
        if "K" not in cfg:
            raise ConfigError(f"{key}.K is required; allowed keys: {', '.join(_ELEMENT_KEYS)}")
        for name in ("leads", "lags"):
            val = cfg.get(name, ())
            if isinstance(val, (str, bytes)) or not hasattr(val, "__iter__"):
                raise ConfigError(f"{key}.{name} must be a list of numbers, got {val!r}")
        try:
            return cls(K=cfg["K"], leads=tuple(cfg.get("leads", ())), lags=tuple(cfg.get("lags", ())),
                       L=cfg.get("L", 0.0))
        except ConfigError as exc:
            raise ConfigError(f"{key}: {str(exc).removeprefix('element: ')}") from None


@dataclasses.dataclass(frozen=True)
class TITOPlant:
    """A 2x2 plant ``[[g11, g12], [g21, g22]]`` of :class:`TFElement` (inputs u1, u2 -> y1, y2)."""

    g11: TFElement
    g12: TFElement
    g21: TFElement
    g22: TFElement
    name: str = "custom"

    def __post_init__(self):
        for key in ("g11", "g12", "g21", "g22"):
            if not isinstance(getattr(self, key), TFElement):
                raise ConfigError(f"plant '{self.name}': {key} must be a TFElement")

    def element(self, i: int, j: int) -> TFElement:
        """Element ``g_ij`` with 1-based indices."""
        return getattr(self, f"g{i}{j}")

    def freqresp(self, w) -> np.ndarray:
        """Exact frequency response, shape ``(n, 2, 2)`` complex."""
        w = _as_w(w)
        out = np.empty((w.size, 2, 2), dtype=np.complex128)
        for i in (1, 2):
            for j in (1, 2):
                out[:, i - 1, j - 1] = self.element(i, j).freqresp(w)
        return out

    def dc_gain(self) -> np.ndarray:
        """Static gain matrix, shape ``(2, 2)``."""
        return np.array([[self.g11.K, self.g12.K], [self.g21.K, self.g22.K]])

    @classmethod
    def from_config(cls, cfg) -> TITOPlant:
        """Build a plant from ``{"g11": {...}, "g12": {...}, "g21": {...}, "g22": {...}, "name": ..}``.

        Raises
        ------
        ConfigError
            One line naming the offending key and the allowed keys / values.
        """
        if not isinstance(cfg, dict):
            raise ConfigError(f"tito plant: must be a mapping with keys {', '.join(_PLANT_KEYS)}")
        unknown = sorted(set(cfg) - set(_PLANT_KEYS))
        if unknown:
            raise ConfigError(f"tito plant: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(_PLANT_KEYS)}")
        missing = [k for k in _PLANT_KEYS[:4] if k not in cfg]
        if missing:
            raise ConfigError(f"tito plant: missing key(s) {', '.join(missing)}; required: g11, g12, g21, g22")
        name = cfg.get("name", "custom")
        if not isinstance(name, str):
            raise ConfigError(f"tito plant: name must be a string, got {name!r}")
        elems = {k: TFElement.from_config(cfg[k], key=k) for k in _PLANT_KEYS[:4]}
        return cls(name=name, **elems)


def _e(K, lags=(), L=0.0, leads=()):
    return TFElement(K=K, leads=tuple(leads), lags=tuple(lags), L=L)


PRESETS = {
    # Paper 000 eq. (44), quadruple tank system (QTS), taken from its ref. [44].
    # Checked against the printed decoupler eq. (45): 1.39/0.834 = 1.667, 7 - 5 = 2 s;
    # 1.271/0.757 = 1.679, 9 - 6 = 3 s -> consistent.
    "qts": TITOPlant(
        g11=_e(0.834, [6.57], 5.0),
        g12=_e(1.39, [10.231, 6.57], 7.0),
        g21=_e(1.271, [14.05, 11.29], 9.0),
        g22=_e(0.757, [11.29], 6.0),
        name="qts",
    ),
    # Paper 000 eq. (49), coupled conical tank system (CCTS), from its ref. [43].
    # Ambiguity: the printed decoupler eq. (50) shows e^{-s} for -g12/g11 although the plant gives
    # 19.2 - 11.5 = 7.7 s (its e^{-6.7 s} for -g21/g22 matches 19.1 - 12.4); its 770.91 is
    # 1.89 * 407.3 = 769.8 rounded differently. The plant (49) is taken as printed.
    "ccts": TITOPlant(
        g11=_e(1.8361, [340.7], 11.5),
        g12=_e(0.723, [415.4], 19.2),
        g21=_e(0.74, [407.3], 19.1),
        g22=_e(1.89, [365.6], 12.4),
        name="ccts",
    ),
    # Paper 000 eq. (54), coupled spherical tank system (CSTS), from its ref. [31].
    # g12 = g21 as printed. Ambiguity: the printed decoupler eq. (55) has a + sign on the
    # (2,1) entry; D = -g21/g22 per eq. (2) gives a - sign (magnitudes 40.88/115.73 match).
    "csts": TITOPlant(
        g11=_e(0.143, [236.25], 0.996),
        g12=_e(0.13, [723.305], 82.305),
        g21=_e(0.13, [723.305], 82.305),
        g22=_e(0.16, [314.47], 0.996),
        name="csts",
    ),
    # Paper 002 eq. (28), identified model of the real coupled two-tank rig.
    # Ambiguities: g21 has the same gain (2.197) as g11 as printed; the decoupler eq. (29) uses
    # -0.7846 = -2.197/2.8 and eq. (30) uses 2.8 for g22, whereas eq. (28) prints 2.82 (kept here);
    # eq. (29) prints the delay of -g12/g11 as 0.384 s, the plant gives 9.34 - 5.5 = 3.84 s.
    "two_tank": TITOPlant(
        g11=_e(2.197, [615.0], 5.5),
        g12=_e(2.3, [614.0], 9.34),
        g21=_e(2.197, [601.84], 30.0),
        g22=_e(2.82, [602.0], 30.0),
        name="two_tank",
    ),
    # Wood & Berry (1973) distillation column, public TITO peer (docs/REFERENCE.md section 6).
    "wood_berry": TITOPlant(
        g11=_e(12.8, [16.7], 1.0),
        g12=_e(-18.9, [21.0], 3.0),
        g21=_e(6.6, [10.9], 7.0),
        g22=_e(-19.4, [14.4], 3.0),
        name="wood_berry",
    ),
}


def preset(name: str) -> TITOPlant:
    """Return a TITO preset by name (``qts``, ``ccts``, ``csts``, ``two_tank``, ``wood_berry``).

    Parameters
    ----------
    name : str

    Returns
    -------
    TITOPlant
    """
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown TITO preset {name!r}; allowed: {', '.join(PRESETS)}") from None


# --------------------------------------------------------------------------------------------
# Decoupler
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Decoupler:
    """A realised decoupler for a :class:`TITOPlant` (build it with :func:`inverted_decoupler`).

    ``case=1`` (unit diagonal)::

        D = [[p1, d12 p2], [d21 p1, p2]],  d12 = -g12/g11,  d21 = -g21/g22
        h11 = z11 p1 = (g11 - g12 g21 / g22) p1,  h22 = z22 p2 = (g22 - g12 g21 / g11) p2

    ``case=2`` (unit off-diagonal, for diagonal elements with RHP zeros)::

        D = [[d11 p3, p4], [p3, d22 p4]],  d11 = -g22/g21,  d22 = -g11/g12
        h11 = (g12 - g11 g22 / g21) p3,  h22 = (g21 - g22 g11 / g12) p4

    ``p*`` are pure delays ``e^{-c s}`` with ``c = column_delays[k]`` (zero unless delay
    compensation was needed). All responses are exact products/ratios of element responses.

    Attributes
    ----------
    plant : TITOPlant
    case : int
        1 or 2 (paper 002, Section III).
    ratio_delays : tuple of 2 float
        Net delay of the two ratio elements before compensation (negative = non-causal).
    column_delays : tuple of 2 float
        Delay added to decoupler column 1 and column 2 to make every entry causal.
    """

    plant: TITOPlant
    case: int = 1
    ratio_delays: tuple = (0.0, 0.0)
    column_delays: tuple = (0.0, 0.0)

    def _ratio(self, num: TFElement, den: TFElement, w: np.ndarray) -> np.ndarray:
        return -num.freqresp(w) / den.freqresp(w)

    def freqresp(self, w) -> np.ndarray:
        """Decoupler ``D(j w)``, shape ``(n, 2, 2)`` complex."""
        w = _as_w(w)
        p = self.plant
        c1 = np.exp(-1j * w * self.column_delays[0])
        c2 = np.exp(-1j * w * self.column_delays[1])
        out = np.empty((w.size, 2, 2), dtype=np.complex128)
        if self.case == 1:
            out[:, 0, 0] = c1
            out[:, 1, 0] = self._ratio(p.g21, p.g22, w) * c1
            out[:, 0, 1] = self._ratio(p.g12, p.g11, w) * c2
            out[:, 1, 1] = c2
        else:
            out[:, 0, 0] = self._ratio(p.g22, p.g21, w) * c1
            out[:, 1, 0] = c1
            out[:, 0, 1] = c2
            out[:, 1, 1] = self._ratio(p.g11, p.g12, w) * c2
        return out

    def z11(self, w) -> np.ndarray:
        """Decoupled loop-1 element ``h11(j w)`` (including any compensation delay)."""
        w = _as_w(w)
        g11, g12, g21, g22 = (e.freqresp(w) for e in (self.plant.g11, self.plant.g12,
                                                        self.plant.g21, self.plant.g22))
        core = g11 - g12 * g21 / g22 if self.case == 1 else g12 - g11 * g22 / g21
        return core * np.exp(-1j * w * self.column_delays[0])

    def z22(self, w) -> np.ndarray:
        """Decoupled loop-2 element ``h22(j w)`` (including any compensation delay)."""
        w = _as_w(w)
        g11, g12, g21, g22 = (e.freqresp(w) for e in (self.plant.g11, self.plant.g12,
                                                        self.plant.g21, self.plant.g22))
        core = g22 - g12 * g21 / g11 if self.case == 1 else g21 - g22 * g11 / g12
        return core * np.exp(-1j * w * self.column_delays[1])

    def diagonal(self, w) -> np.ndarray:
        """``[h11(j w), h22(j w)]``, shape ``(n, 2)`` complex."""
        return np.stack([self.z11(w), self.z22(w)], axis=1)


def _check_ratio(label: str, num: TFElement, den: TFElement, plant: str) -> float:
    """Properness and stability of ``-num/den``; returns its net delay ``num.L - den.L``."""
    if num.relative_degree < den.relative_degree:
        raise ConfigError(
            f"plant '{plant}': decoupler element {label} is improper (relative degree "
            f"{num.relative_degree} - {den.relative_degree} < 0); not realisable"
        )
    if den.has_rhp_zero:
        raise ConfigError(
            f"plant '{plant}': decoupler element {label} is unstable (denominator has a RHP zero); "
            f"not realisable with this case"
        )
    return num.L - den.L


def inverted_decoupler(plant: TITOPlant, *, delay_compensation: bool = False, case: int = 1) -> Decoupler:
    """Build the simplified ("inverted") decoupler of papers 000/002 and check it is realisable.

    Parameters
    ----------
    plant : TITOPlant
    delay_compensation : bool
        If False, each ratio element must be causal (``L12 - L11 >= 0`` and ``L21 - L22 >= 0``
        for ``case=1``) or a ConfigError names the element. If True, a negative net delay of a
        ratio is compensated by delaying the whole decoupler column that carries it by the
        missing amount (paper 002's ``p1``/``p2`` factors); the added delays are reported in
        :attr:`Decoupler.column_delays` and appear in the decoupled elements.
    case : {1, 2}
        Paper 002 Section III. Case 1: unit diagonal, ratios ``-g12/g11`` and ``-g21/g22`` (needs
        no RHP zeros in g11, g22). Case 2: unit off-diagonal, ratios ``-g22/g21`` and
        ``-g11/g12`` (needs no RHP zeros in g21, g12).

    Notes
    -----
    Reading of paper 002 (its text is garbled by extraction): in case 1 it writes
    ``D = [[p1, d12 p2], [d21 p1, p2]]`` with ``d12 = -(g12/g11) e^{-(θ12-θ11)s}`` on the delay-free
    parts, ``p2 = 1`` if ``θ12 >= θ11`` else ``e^{(θ12-θ11)s}`` (a delay of ``θ11 - θ12``), and
    ``p1`` likewise from ``θ21, θ22``. So case 1 is this decoupler with column-wise delay
    compensation; without compensation it is exactly the brief's ``[[1, -g12/g11], [-g21/g22, 1]]``.
    Its case 2 is printed as ``[[d11 p3, p3], [p4, d22 p4]]`` with ``d11 = -g22/g21``,
    ``d22 = -g11/g12``; that matrix does not diagonalise ``G D`` unless the delays are applied per
    column, so it is implemented here as ``[[d11 p3, p4], [p3, d22 p4]]`` (p3 from ``θ22 - θ21``,
    p4 from ``θ11 - θ12``). Properness (relative degree of the ratio >= 0) is required in both cases;
    paper 002 does not discuss it, paper 000's plants all satisfy it.

    Returns
    -------
    Decoupler
    """
    if case not in (1, 2):
        raise ConfigError(f"decoupler case must be 1 or 2, got {case!r}")
    if case == 1:
        pairs = (("-g21/g22", plant.g21, plant.g22), ("-g12/g11", plant.g12, plant.g11))
    else:
        pairs = (("-g22/g21", plant.g22, plant.g21), ("-g11/g12", plant.g11, plant.g12))
    delays = tuple(_check_ratio(lbl, num, den, plant.name) for lbl, num, den in pairs)
    if not delay_compensation:
        for (lbl, _num, _den), d in zip(pairs, delays):
            if d < 0:
                raise ConfigError(
                    f"plant '{plant.name}': decoupler element {lbl} is non-causal (net delay {d:g} s "
                    f"< 0); use delay_compensation=True"
                )
    comp = tuple(max(0.0, -d) for d in delays)
    return Decoupler(plant=plant, case=case, ratio_delays=delays, column_delays=comp)


# --------------------------------------------------------------------------------------------
# FOPDT reduction
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FOPDT:
    """First-order plus dead time model ``K e^{-L s} / (T s + 1)`` fitted at ``w = 0`` and ``wp``."""

    K: float
    T: float
    L: float
    wp: float = math.nan

    def __post_init__(self):
        for key in ("K", "T", "L"):
            if not math.isfinite(getattr(self, key)):
                raise ConfigError(f"fopdt: {key} must be finite, got {getattr(self, key)!r}")
        if self.K == 0 or self.T < 0 or self.L < 0:
            raise ConfigError(f"fopdt: need K != 0, T >= 0, L >= 0, got K={self.K}, T={self.T}, L={self.L}")

    def freqresp(self, w) -> np.ndarray:
        """Exact frequency response, shape ``(n,)`` complex."""
        w = _as_w(w)
        return self.K * np.exp(-1j * w * self.L) / (1.0 + 1j * w * self.T)


def _phase_crossover(z: Callable, sign: float, w_min: float, w_max: float, n: int, level: float):
    """First ``w`` where the unwrapped phase of ``sign * z(jw)`` reaches ``level`` (rad), or None."""
    w = np.geomspace(w_min, w_max, n)
    zz = sign * np.asarray(z(w), dtype=np.complex128)
    phase = np.unwrap(np.angle(zz))
    below = phase <= level
    if not below.any():
        return None
    k = int(np.argmax(below))
    if k == 0:
        return None
    wl, wr = w[k - 1], w[k]
    zl, phl = zz[k - 1], phase[k - 1]

    def f(x):
        return phl + np.angle(sign * complex(np.asarray(z(np.array([x])))[0]) / zl) - level

    return brentq(f, wl, wr, xtol=1e-14, rtol=1e-14, maxiter=200)


def fit_fopdt(z: Callable, *, w_min: float = 1e-6, w_max: float = 1e3, n: int = 20000) -> FOPDT:
    """Fit ``K e^{-L s}/(T s + 1)`` to ``z`` at ``w = 0`` and the phase crossover ``wp``.

    ``K = z(0)``, ``T = sqrt((K^2 - |z(wp)|^2) / (|z(wp)|^2 wp^2))``,
    ``L = (pi - atan(wp T)) / wp``, with ``wp`` the first frequency where the unwrapped phase of
    ``sign(K) z(j w)`` reaches ``-pi`` (log grid, then :func:`scipy.optimize.brentq`). For a negative
    DC gain the phase is measured relative to ``pi``, so the fit matches ``z(j wp)`` as a complex number.

    Parameters
    ----------
    z : callable
        Vectorised frequency response ``z(w) -> complex array`` (``w`` in rad/s).
    w_min, w_max, n : float, float, int
        Log search grid; the grid must resolve the phase (step well below pi) up to the crossover.

    Returns
    -------
    FOPDT

    Raises
    ------
    ConfigError
        No phase crossover in ``[w_min, w_max]``; ``|z(wp)| >= |K|``; non-real or zero DC gain.
    """
    z0 = complex(np.asarray(z(np.array([0.0])))[0])
    if not np.isfinite(z0) or abs(z0.imag) > 1e-9 * max(1.0, abs(z0.real)) or z0.real == 0:
        raise ConfigError(f"fopdt fit: z(0) must be real and non-zero, got {z0!r}")
    K = z0.real
    sign = 1.0 if K > 0 else -1.0
    wp = _phase_crossover(z, sign, w_min, w_max, n, -math.pi)
    if wp is None:
        raise ConfigError(f"fopdt fit: no phase crossover (arg z = -pi) in [{w_min:g}, {w_max:g}] rad/s")
    m = abs(complex(np.asarray(z(np.array([wp])))[0]))
    if m >= abs(K):
        raise ConfigError(f"fopdt fit: |z(wp)| = {m:.6g} >= |K| = {abs(K):.6g} at wp = {wp:.6g}; no FOPDT fits")
    T = math.sqrt((K * K - m * m) / (m * m * wp * wp))
    L = (math.pi - math.atan(wp * T)) / wp
    return FOPDT(K=K, T=T, L=L, wp=wp)


# --------------------------------------------------------------------------------------------
# GPM PI / PID (Ho, Hang & Cao 1995; paper 001 eq. 17-27)
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PIController:
    """``C(s) = Kc (1 + 1/(Ti s))``; ``wp`` is the design phase-crossover estimate (eq. 20)."""

    Kc: float
    Ti: float
    wp: float = math.nan

    def freqresp(self, w) -> np.ndarray:
        w = _as_w(w)
        return self.Kc * (1.0 + 1.0 / (1j * w * self.Ti))

    def parallel(self) -> tuple:
        """``(Kp, Ki, Kd)`` of ``Kp + Ki/s + Kd s``."""
        return (self.Kc, self.Kc / self.Ti, 0.0)


@dataclasses.dataclass(frozen=True)
class PIDController:
    """Series PID ``C(s) = Kc (1 + Ti s)(1 + Td s) / (Ti s (1 + Tf s))`` (paper 001 eq. 21).

    ``Tf = Td / N`` is the derivative filter. ``parallel()`` gives the equivalent ideal/parallel
    gains of the unfiltered series form: ``Kp = Kc (Ti + Td)/Ti``, ``Ki = Kc/Ti``, ``Kd = Kc Td``.
    """

    Kc: float
    Ti: float
    Td: float
    Tf: float
    wp: float = math.nan

    def freqresp(self, w) -> np.ndarray:
        s = 1j * _as_w(w)
        return self.Kc * (1.0 + s * self.Ti) * (1.0 + s * self.Td) / (s * self.Ti * (1.0 + s * self.Tf))

    def parallel(self) -> tuple:
        return (self.Kc * (self.Ti + self.Td) / self.Ti, self.Kc / self.Ti, self.Kc * self.Td)


@dataclasses.dataclass(frozen=True)
class ParallelPID:
    """``C(s) = (Kp + Ki/s + Kd s) / (1 + Tf s)``: the controller a tuning run searches over.

    The parallel gains are the decision variables (any signs and ratios, also complex series
    zeros); the filter acts on the whole controller as in :class:`PIDController`. With
    ``Kd = 0`` and ``Tf = 0`` it is the PI ``Kp + Ki/s``. Build it with
    :func:`heurtune.objectives.tito.design.parallel_controller`, which sets ``Tf = Td / N``.
    """

    Kp: float
    Ki: float
    Kd: float = 0.0
    Tf: float = 0.0

    def freqresp(self, w) -> np.ndarray:
        """Exact frequency response ``C(jw)``."""
        s = 1j * _as_w(w)
        return (self.Kp + self.Ki / s + self.Kd * s) / (1.0 + self.Tf * s)

    def parallel(self) -> tuple:
        """``(Kp, Ki, Kd)``."""
        return (self.Kp, self.Ki, self.Kd)

    def rational(self) -> tuple:
        """``(num, den)`` coefficients, highest power first: ``(Kd s^2 + Kp s + Ki) / (Tf s^2 + s)``."""
        return [self.Kd, self.Kp, self.Ki], [self.Tf, 1.0, 0.0]


def _gpm_core(fopdt: FOPDT, Am: float, phim_deg: float):
    for key, val in (("Am", Am), ("phim_deg", phim_deg)):
        if not math.isfinite(val):
            raise ConfigError(f"gpm: {key} must be finite, got {val!r}")
    if Am <= 1:
        raise ConfigError(f"gpm: Am must be > 1, got {Am!r}")
    if not 0 < phim_deg < 90:
        raise ConfigError(f"gpm: phim_deg must lie in (0, 90), got {phim_deg!r}")
    if fopdt.L <= 0 or fopdt.T <= 0:
        raise ConfigError(f"gpm: the FOPDT needs L > 0 and T > 0, got T={fopdt.T}, L={fopdt.L}")
    phim = math.radians(phim_deg)
    wp = (Am * phim + 0.5 * math.pi * Am * (Am - 1.0)) / ((Am * Am - 1.0) * fopdt.L)
    Kc = wp * fopdt.T / (Am * fopdt.K)
    inv = 2.0 * wp - 4.0 * wp * wp * fopdt.L / math.pi + 1.0 / fopdt.T
    if inv <= 0:
        raise ConfigError(
            f"gpm: (Am, phim_deg) = ({Am:g}, {phim_deg:g}) gives a non-positive 1/Ti = {inv:.4g} for "
            f"L/T = {fopdt.L / fopdt.T:.4g}; choose smaller margins"
        )
    return Kc, 1.0 / inv, wp


def gpm_pi(fopdt: FOPDT, Am: float, phim_deg: float) -> tuple:
    """GPM PI by the arctan approximation (paper 001 eq. 18-20; Ho, Hang & Cao 1995).

    ``wp = (Am phim + (pi/2) Am (Am - 1)) / ((Am^2 - 1) L)``, ``Kc = wp T / (Am K)``,
    ``Ti = 1 / (2 wp - 4 wp^2 L / pi + 1/T)`` for ``C(s) = Kc (1 + 1/(Ti s))``.

    Parameters
    ----------
    fopdt : FOPDT
    Am : float
        Gain margin.
    phim_deg : float
        Phase margin in degrees.

    Returns
    -------
    (Kc, Ti) : tuple of float
        Use :class:`PIController` ``(Kc, Ti)`` for its frequency response.
    """
    Kc, Ti, _ = _gpm_core(fopdt, Am, phim_deg)
    return Kc, Ti


def gpm_pid(fopdt: FOPDT, Am: float, phim_deg: float, *, Td: float | None = None,
            N: float = 100.0) -> PIDController:
    """GPM PID of paper 001 (eq. 21-27): series form ``Kc (1 + Ti s)(1 + Td s) / (Ti s (1 + Tf s))``.

    ``Kc`` (eq. 25) and ``Ti`` (eq. 26) are the PI values of :func:`gpm_pi`. Paper 001 sets
    ``Td = Ti`` (eq. 22) and ``Tf = Ti`` (eq. 27), so the extra lead-lag cancels and the loop is
    the PI loop (eq. 24); its PI and PID table rows are indeed identical. With the default
    ``Td=None`` this literal reading is returned (``Td = Tf = Ti``; achieved margins equal the PI
    design). With an explicit ``Td`` the derivative filter is ``Tf = Td / N`` (``N = 100`` by
    default); that loop no longer meets the specification exactly, so report its
    :func:`exact_margins`. (``Td = Ti`` with ``N = 100`` destabilises the K=1, T=10, L=2 example.)

    ``PIDController.parallel()`` converts to the parallel form ``Kp + Ki/s + Kd s`` (ignoring the
    filter) used in the papers' printed controllers.

    Parameters
    ----------
    fopdt : FOPDT
    Am : float
        Gain margin.
    phim_deg : float
        Phase margin in degrees.
    Td : float, optional
        Derivative time; None: paper 001's ``Td = Tf = Ti``.
    N : float
        Derivative filter ratio when ``Td`` is given.

    Returns
    -------
    PIDController
    """
    if not (math.isfinite(N) and N >= 1):
        raise ConfigError(f"gpm_pid: N must be >= 1, got {N!r}")
    Kc, Ti, wp = _gpm_core(fopdt, Am, phim_deg)
    if Td is None:
        return PIDController(Kc=Kc, Ti=Ti, Td=Ti, Tf=Ti, wp=wp)
    Td = float(Td)
    if not (math.isfinite(Td) and Td >= 0):
        raise ConfigError(f"gpm_pid: Td must be finite and >= 0, got {Td!r}")
    return PIDController(Kc=Kc, Ti=Ti, Td=Td, Tf=Td / N, wp=wp)


@dataclasses.dataclass(frozen=True)
class Margins:
    """Exact loop margins: gain margin (ratio), phase margin (deg), and their crossover frequencies.

    ``gain_margin`` is ``inf`` (and ``w_pc`` nan) when no phase crossover is found; likewise
    ``phase_margin_deg`` is ``inf`` when ``|L|`` never crosses 1; it is wrapped to [-180, 180].
    """

    gain_margin: float
    phase_margin_deg: float
    w_pc: float
    w_gc: float


def exact_margins(plant: Callable, controller: Callable, *, w_min: float = 1e-6, w_max: float = 1e3,
                  n: int = 20000) -> Margins:
    """True gain and phase margins of the loop ``plant(w) * controller(w)``.

    Both arguments are vectorised frequency-response callables (e.g. ``TFElement.freqresp``,
    ``FOPDT.freqresp``, ``Decoupler.z11``, ``PIController.freqresp``). The first phase crossover
    (unwrapped ``arg L = -pi``) and the first gain crossover (``|L| = 1``) are bracketed on a
    log grid and refined with brentq.

    Parameters
    ----------
    plant, controller : callable
        Frequency responses of w (rad/s).
    w_min, w_max : float
        The search range in rad/s.
    n : int
        Points of the log grid.

    Returns
    -------
    Margins
    """
    def loop(w):
        w = _as_w(w)
        return np.asarray(plant(w), dtype=np.complex128) * np.asarray(controller(w), dtype=np.complex128)

    w = np.geomspace(w_min, w_max, n)
    lw = loop(w)

    w_pc = _phase_crossover(loop, 1.0, w_min, w_max, n, -math.pi)
    gm = math.inf if w_pc is None else 1.0 / abs(complex(loop(w_pc)[0]))

    mag = np.log(np.abs(lw))
    idx = np.nonzero((mag[:-1] > 0) & (mag[1:] <= 0))[0]
    if idx.size == 0:
        return Margins(gm, math.inf, math.nan if w_pc is None else w_pc, math.nan)
    k = int(idx[0])
    w_gc = brentq(lambda x: math.log(abs(complex(loop(x)[0]))), w[k], w[k + 1], xtol=1e-14, rtol=1e-14)
    pm = math.degrees(math.remainder(float(np.angle(complex(loop(w_gc)[0]))) + math.pi, 2 * math.pi))
    return Margins(gm, pm, math.nan if w_pc is None else w_pc, w_gc)
