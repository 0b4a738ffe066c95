"""Quadruple tank process (QTP): parameters, presets, operating point, linearisation.

Model (Johansson 2000; thesis eq. 2.6-2.9), levels ``h`` in cm, pump voltages ``u`` in V::

    dh1/dt = (-a1 sqrt(2 g h1) + a3 sqrt(2 g h3) + g1 k1 u1) / A1
    dh2/dt = (-a2 sqrt(2 g h2) + a4 sqrt(2 g h4) + g2 k2 u2) / A2
    dh3/dt = (-a3 sqrt(2 g h3) + (1 - g2) k2 u2) / A3
    dh4/dt = (-a4 sqrt(2 g h4) + (1 - g1) k1 u1) / A4

Tanks 1 and 2 are the lower (controlled) tanks; 3 feeds 1 and 4 feeds 2.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heurtune.core.errors import ConfigError

__all__ = [
    "QTPParams",
    "OperatingPoint",
    "PRESETS",
    "preset",
    "operating_point",
    "linearise",
    "transmission_zeros",
    "is_minimum_phase",
    "qtp_rhs",
]


@dataclasses.dataclass(frozen=True)
class QTPParams:
    """Physical parameters of a quadruple tank process and its target levels.

    Parameters
    ----------
    A : tuple of 4 float
        Tank cross sections A1..A4 in cm^2.
    a : tuple of 4 float
        Outlet hole areas a1..a4 in cm^2.
    k : tuple of 2 float
        Pump gains k1, k2 in cm^3/(V s).
    gamma : tuple of 2 float
        Valve splits gamma1, gamma2 in (0, 1): fraction of pump j's flow sent to lower tank j.
    levels : tuple of 2 float
        Target (operating) levels of the lower tanks h1, h2 in cm.
    height : tuple of 4 float, optional
        Tank heights H1..H4 in cm (water above the rim is lost). None: no height given.
    u_range : (float, float), optional
        Pump voltage range (lo, hi) in V, lo < hi. None: no range given.
        Both ``height`` and ``u_range`` are needed for ``scenario.limits = "physical"``
        (see :attr:`has_limits`); neither enters the model equations otherwise.
    g : float
        Gravitational acceleration in cm/s^2.
    name : str
        A label used in tables and errors.
    """

    A: tuple
    a: tuple
    k: tuple
    gamma: tuple
    levels: tuple
    height: tuple | None = None
    u_range: tuple | None = None
    g: float = 981.0
    name: str = "custom"

    def __post_init__(self):
        def check(key, values, n, low=0.0, high=math.inf, open_high=False):
            try:
                vals = tuple(float(v) for v in values)
            except (TypeError, ValueError):
                raise ConfigError(f"plant '{self.name}': {key} must be {n} numbers, got {values!r}") from None
            if len(vals) != n:
                raise ConfigError(f"plant '{self.name}': {key} must have {n} values, got {len(vals)}")
            for v in vals:
                bad_high = v >= high if open_high else v > high
                if not math.isfinite(v) or v <= low or bad_high:
                    raise ConfigError(
                        f"plant '{self.name}': {key} values must lie in ({low:g}, {high:g}"
                        f"{')' if open_high else ']'}, got {vals}"
                    )
            object.__setattr__(self, key, vals)

        check("A", self.A, 4)
        check("a", self.a, 4)
        check("k", self.k, 2)
        check("gamma", self.gamma, 2, 0.0, 1.0, open_high=True)
        check("levels", self.levels, 2)
        if self.height is not None:
            check("height", self.height, 4)
        if self.u_range is not None:
            try:
                lo, hi = (float(v) for v in self.u_range)
            except (TypeError, ValueError):
                raise ConfigError(
                    f"plant '{self.name}': u_range must be two numbers (lo, hi) in V, got {self.u_range!r}"
                ) from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ConfigError(
                    f"plant '{self.name}': u_range must be finite with lo < hi, got {self.u_range!r}"
                )
            object.__setattr__(self, "u_range", (lo, hi))
        if not (math.isfinite(self.g) and self.g > 0):
            raise ConfigError(f"plant '{self.name}': g must be positive, got {self.g!r}")

    @property
    def has_limits(self) -> bool:
        """True when both the tank heights and the pump voltage range are given."""
        return self.height is not None and self.u_range is not None

    def physical_limits(self) -> tuple[np.ndarray, tuple]:
        """Tank heights and pump voltage range, for ``scenario.limits = "physical"``.

        Returns
        -------
        height : numpy.ndarray, shape (4,)
            Tank heights in cm.
        u_range : (float, float)
            Pump voltage range (lo, hi) in V.

        Raises
        ------
        ConfigError
            When the plant lacks ``height`` or ``u_range``.
        """
        if not self.has_limits:
            raise ConfigError(
                f"plant '{self.name}': scenario.limits = 'physical' needs plant height and u_range "
                f"(give plant.custom.{self.name}.height and u_range)"
            )
        return np.array(self.height, dtype=np.float64), self.u_range

    def scaled(self, factor: float) -> QTPParams:
        """Return the plant with every A_i and a_i multiplied by ``factor``.

        This is the thesis' parameter uncertainty: time constants and operating levels stay,
        the equilibrium input scales with ``factor``. Tank heights and the voltage range are
        kept.
        """
        if not (math.isfinite(factor) and factor > 0):
            raise ConfigError(f"uncertainty factor must be positive, got {factor!r}")
        return dataclasses.replace(
            self,
            A=tuple(x * factor for x in self.A),
            a=tuple(x * factor for x in self.a),
            name=f"{self.name}x{factor:g}",
        )

    def as_array(self) -> np.ndarray:
        """Pack the parameters for the jitted kernels.

        Returns
        -------
        numpy.ndarray, shape (13,)
            ``[A1..A4, a1..a4, k1, k2, gamma1, gamma2, g]``.
        """
        return np.array([*self.A, *self.a, *self.k, *self.gamma, self.g], dtype=np.float64)


# Thesis Table 4.1 (A_i = 176.71, a1 = a2 = 2.54, a3 = a4 = 1.43) and Johansson (2000) P-/P+.
#
# Physical limits (used only with scenario.limits = "physical"):
# - P-, P+: Johansson's lab rig, tanks 20 cm tall. Pump range 0..10 V: assumed (the usual
#   analogue output range of such a rig; Johansson's operating points use about 3 V).
# - min, nmp: the thesis gives neither a height nor a voltage range. The pumps get the same
#   0..10 V. The thesis' A_i = 176.71 cm^2 is a 15 cm diameter tank, whereas
#   Johansson's 28-32 cm^2 tanks are about 6 cm wide and 20 cm tall; the same aspect ratio at
#   15 cm diameter gives 50 cm. (Johansson's own 20 cm would not do: the nmp operating point
#   has h3 = 22.9 cm, above such a rim.)
_RIG_HEIGHT = (20.0,) * 4
_THESIS_HEIGHT = (50.0,) * 4
_PUMP_RANGE = (0.0, 10.0)
PRESETS = {
    "min": QTPParams(
        A=(176.71,) * 4, a=(2.54, 2.54, 1.43, 1.43), k=(180.29, 180.29), gamma=(0.60, 0.60),
        levels=(16.47, 16.71), height=_THESIS_HEIGHT, u_range=_PUMP_RANGE, name="min",
    ),
    "nmp": QTPParams(
        A=(176.71,) * 4, a=(2.54, 2.54, 1.43, 1.43), k=(186.86, 186.86), gamma=(0.45, 0.35),
        levels=(20.20, 13.33), height=_THESIS_HEIGHT, u_range=_PUMP_RANGE, name="nmp",
    ),
    "P-": QTPParams(
        A=(28.0, 32.0, 28.0, 32.0), a=(0.071, 0.057, 0.071, 0.057), k=(3.33, 3.35),
        gamma=(0.70, 0.60), levels=(12.4, 12.7), height=_RIG_HEIGHT, u_range=_PUMP_RANGE, name="P-",
    ),
    "P+": QTPParams(
        A=(28.0, 32.0, 28.0, 32.0), a=(0.071, 0.057, 0.071, 0.057), k=(3.14, 3.29),
        gamma=(0.43, 0.34), levels=(12.6, 13.0), height=_RIG_HEIGHT, u_range=_PUMP_RANGE, name="P+",
    ),
}


def preset(name: str) -> QTPParams:
    """Return a QTP preset by name (``min``, ``nmp``, ``P-``, ``P+``).

    Parameters
    ----------
    name : str

    Returns
    -------
    QTPParams
    """
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(
            f"unknown QTP preset {name!r}; allowed: {', '.join(PRESETS)}"
        ) from None


@dataclasses.dataclass(frozen=True)
class OperatingPoint:
    """Equilibrium of the QTP: levels ``h`` (4,) in cm and pump voltages ``u`` (2,) in V."""

    h: np.ndarray
    u: np.ndarray


def operating_point(p: QTPParams) -> OperatingPoint:
    """Equilibrium that holds the lower tanks at ``p.levels``.

    The two lower-tank balances are linear in the pump voltages::

        a1 sqrt(2 g h1) = g1 k1 u1 + (1 - g2) k2 u2
        a2 sqrt(2 g h2) = (1 - g1) k1 u1 + g2 k2 u2

    and the upper levels follow from their own balances.

    Parameters
    ----------
    p : QTPParams

    Returns
    -------
    OperatingPoint

    Raises
    ------
    ConfigError
        When gamma1 + gamma2 = 1 (the balance is singular) or the solution needs a
        non-positive pump voltage (the target levels cannot be held).
    """
    g1, g2 = p.gamma
    k1, k2 = p.k
    h1, h2 = p.levels
    det = k1 * k2 * (g1 + g2 - 1.0)
    if abs(g1 + g2 - 1.0) < 1e-9:
        raise ConfigError(
            f"plant '{p.name}': gamma1 + gamma2 = 1 makes the operating point singular; "
            "choose valve splits whose sum differs from 1"
        )
    q1 = p.a[0] * math.sqrt(2.0 * p.g * h1)
    q2 = p.a[1] * math.sqrt(2.0 * p.g * h2)
    # Cramer's rule on [[g1 k1, (1-g2) k2], [(1-g1) k1, g2 k2]] u = [q1, q2].
    u1 = (q1 * g2 * k2 - (1.0 - g2) * k2 * q2) / det
    u2 = (g1 * k1 * q2 - (1.0 - g1) * k1 * q1) / det
    if u1 <= 0 or u2 <= 0:
        raise ConfigError(
            f"plant '{p.name}': levels {p.levels} need pump voltages ({u1:.4g}, {u2:.4g}); "
            "both must be positive"
        )
    h3 = ((1.0 - g2) * k2 * u2 / p.a[2]) ** 2 / (2.0 * p.g)
    h4 = ((1.0 - g1) * k1 * u1 / p.a[3]) ** 2 / (2.0 * p.g)
    if h3 <= 0 or h4 <= 0:
        raise ConfigError(f"plant '{p.name}': upper levels ({h3:.4g}, {h4:.4g}) must be positive")
    return OperatingPoint(h=np.array([h1, h2, h3, h4]), u=np.array([u1, u2]))


def qtp_rhs(h: np.ndarray, u: np.ndarray, p: QTPParams) -> np.ndarray:
    """Nonlinear QTP right-hand side dh/dt (levels clipped at 0 under the square roots).

    Parameters
    ----------
    h : ndarray (4,)
        Levels in cm.
    u : ndarray (2,)
        Pump voltages in V.
    p : QTPParams

    Returns
    -------
    ndarray (4,)
    """
    A, a, (k1, k2), (g1, g2), g = p.A, p.a, p.k, p.gamma, p.g
    q = [a[i] * math.sqrt(2.0 * g * max(h[i], 0.0)) for i in range(4)]
    return np.array([
        (-q[0] + q[2] + g1 * k1 * u[0]) / A[0],
        (-q[1] + q[3] + g2 * k2 * u[1]) / A[1],
        (-q[2] + (1.0 - g2) * k2 * u[1]) / A[2],
        (-q[3] + (1.0 - g1) * k1 * u[0]) / A[3],
    ])


def linearise(p: QTPParams, op: OperatingPoint | None = None):
    """Linearise the QTP about its operating point.

    Parameters
    ----------
    p : QTPParams
    op : OperatingPoint, optional
        Default: the operating point of ``p``.

    Returns
    -------
    A : numpy.ndarray, shape (4, 4)
    B : numpy.ndarray, shape (4, 2)
    C : numpy.ndarray, shape (2, 4)
        Deviation model ``dx' = A dx + B du``, ``dy = C dx`` with ``T_i = (A_i/a_i) sqrt(2 h_i/g)``.
    """
    op = operating_point(p) if op is None else op
    T = np.array([p.A[i] / p.a[i] * math.sqrt(2.0 * op.h[i] / p.g) for i in range(4)])
    Ar = np.array(p.A)
    (k1, k2), (g1, g2) = p.k, p.gamma
    A = np.diag(-1.0 / T)
    A[0, 2] = Ar[2] / (Ar[0] * T[2])
    A[1, 3] = Ar[3] / (Ar[1] * T[3])
    B = np.array([
        [g1 * k1 / Ar[0], 0.0],
        [0.0, g2 * k2 / Ar[1]],
        [0.0, (1.0 - g2) * k2 / Ar[2]],
        [(1.0 - g1) * k1 / Ar[3], 0.0],
    ])
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    return A, B, C


def transmission_zeros(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Finite transmission zeros of a square system (D = 0) from the Rosenbrock pencil.

    The zeros are the finite generalised eigenvalues of ``([[A, B], [C, 0]], diag(I, 0))``.

    Parameters
    ----------
    A, B, C : ndarray

    Returns
    -------
    ndarray
        Sorted.
    """
    import scipy.linalg

    n, m = B.shape
    M = np.block([[A, B], [C, np.zeros((C.shape[0], m))]])
    N = np.zeros_like(M)
    N[:n, :n] = np.eye(n)
    w = scipy.linalg.eigvals(M, N)
    return np.sort_complex(w[np.isfinite(w)])


def is_minimum_phase(p: QTPParams) -> bool:
    """True when every transmission zero of the linearised QTP lies in the open left half plane.

    Parameters
    ----------
    p : QTPParams

    Returns
    -------
    bool
    """
    z = transmission_zeros(*linearise(p))
    return bool(np.all(z.real < 0))
