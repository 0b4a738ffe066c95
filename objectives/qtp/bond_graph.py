"""Bond-graph (pressure) formulation of the quadruple tank process (thesis chapter 6).

The hydraulic bond graph uses pressure as effort and volumetric flow as flow. Units are cgs
throughout: pressure in dyn/cm^2 (= 0.1 Pa), flow in cm^3/s, density in g/cm^3 (water: 1.0),
g in cm/s^2. With those units the pressure state is ``P = rho g h`` (981 x the level for water),
a genuine change of variables of the level model in :mod:`heurtune.objectives.qtp.model`.

Elements (see ``docs/bond_graph.md`` for the graph, its causality and the derivation):

* ``C_i = A_i / (rho g)``: tank i as a capacitance, ``dP_i/dt = (net inflow) / C_i``;
* ``Q_i = kappa_i sqrt(P_i)`` with ``kappa_i = a_i sqrt(2 / rho)``: the outlet orifice, a
  nonlinear resistance (Torricelli);
* ``Sf_j = k_j u_j``: the pumps, flow sources;
* ``TF1..TF4 = (gamma1, gamma2, 1 - gamma2, 1 - gamma1)``: the valve splits, transformers that
  send pump 1 to tanks 1 and 4 and pump 2 to tanks 2 and 3.

The resulting state equations::

    dP1/dt = (-kappa1 sqrt(P1) + kappa3 sqrt(P3) + TF1 k1 u1) / C1
    dP2/dt = (-kappa2 sqrt(P2) + kappa4 sqrt(P4) + TF2 k2 u2) / C2
    dP3/dt = (-kappa3 sqrt(P3) + TF3 k2 u2) / C3
    dP4/dt = (-kappa4 sqrt(P4) + TF4 k1 u1) / C4
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.model import OperatingPoint, QTPParams, linearise, operating_point

__all__ = [
    "RHO_WATER",
    "BondGraphElements",
    "pressure_of_level",
    "level_of_pressure",
    "pressure_rhs",
    "pressure_coefficients",
    "linearise_pressure",
]

# Density of water in g/cm^3 (the default of BondGraphElements.from_plant).
RHO_WATER = 1.0


@dataclasses.dataclass(frozen=True)
class BondGraphElements:
    """Element values of the QTP bond graph (cgs units).

    Parameters
    ----------
    C : tuple of 4 float
        Tank capacitances ``C_i = A_i / (rho g)`` in cm^3 per dyn/cm^2.
    kappa : tuple of 4 float
        Orifice coefficients ``kappa_i = a_i sqrt(2 / rho)``: outflow ``Q_i = kappa_i sqrt(P_i)``
        in cm^3/s for ``P_i`` in dyn/cm^2.
    k : tuple of 2 float
        Pump constants: flow source ``Sf_j = k_j u_j`` in cm^3/s for ``u_j`` in V.
    tf : tuple of 4 float
        Transformer ratios TF1..TF4 = ``(gamma1, gamma2, 1 - gamma2, 1 - gamma1)``: TF1, TF4
        carry pump 1 to tanks 1 and 4; TF2, TF3 carry pump 2 to tanks 2 and 3.
    rho : float
        Density in g/cm^3.
    g : float
        Gravitational acceleration in cm/s^2.
    """

    C: tuple
    kappa: tuple
    k: tuple
    tf: tuple
    rho: float
    g: float

    @classmethod
    def from_plant(cls, p: QTPParams, rho: float = RHO_WATER) -> BondGraphElements:
        """Element values of the plant ``p`` for a liquid of density ``rho`` (g/cm^3).

        Raises
        ------
        ConfigError
            When ``rho`` is not a positive finite number.
        """
        if isinstance(rho, bool) or not isinstance(rho, (int, float)) or not (math.isfinite(rho) and rho > 0):
            raise ConfigError(f"plant.rho must be a positive finite number (g/cm^3), got {rho!r}")
        rho = float(rho)
        rg = rho * p.g
        g1, g2 = p.gamma
        return cls(
            C=tuple(A / rg for A in p.A),
            kappa=tuple(a * math.sqrt(2.0 / rho) for a in p.a),
            k=tuple(p.k),
            tf=(g1, g2, 1.0 - g2, 1.0 - g1),
            rho=rho,
            g=float(p.g),
        )

    @property
    def rho_g(self) -> float:
        """Hydrostatic pressure per cm of level, ``rho g`` in dyn/cm^2 per cm."""
        return self.rho * self.g


def pressure_of_level(h, elements: BondGraphElements) -> np.ndarray:
    """Hydrostatic pressure ``P = rho g h`` (dyn/cm^2) at the bottom of a level ``h`` (cm).

    Parameters
    ----------
    h : array_like
        Levels in cm.
    elements : BondGraphElements

    Returns
    -------
    ndarray
    """
    return np.asarray(h, dtype=np.float64) * elements.rho_g


def level_of_pressure(P, elements: BondGraphElements) -> np.ndarray:
    """Level ``h = P / (rho g)`` (cm) of a hydrostatic pressure ``P`` (dyn/cm^2).

    Parameters
    ----------
    P : array_like
        Pressures in dyn/cm^2.
    elements : BondGraphElements

    Returns
    -------
    ndarray
    """
    return np.asarray(P, dtype=np.float64) / elements.rho_g


def pressure_rhs(P, u, elements: BondGraphElements) -> np.ndarray:
    """dP/dt of the QTP bond graph, assembled element by element (numpy, not jitted).

    Parameters
    ----------
    P : array_like, shape (4,)
        Tank pressures in dyn/cm^2 (clipped at 0 under the square roots, as the level model
        clips its levels).
    u : array_like, shape (2,)
        Pump voltages in V.
    elements : BondGraphElements

    Returns
    -------
    numpy.ndarray, shape (4,)
        dP/dt in dyn/(cm^2 s).
    """
    P = np.asarray(P, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    if P.shape != (4,) or u.shape != (2,):
        raise ValueError(f"pressure_rhs: P must have shape (4,) and u shape (2,), got {P.shape} and {u.shape}")
    # Flow sources (pumps), then the transformers that split them: TF1, TF4 on pump 1,
    # TF2, TF3 on pump 2. Each transformer passes its ratio times the pump flow.
    sf = np.array(elements.k) * u
    tf = elements.tf
    inflow = np.array([tf[0] * sf[0], tf[1] * sf[1], tf[2] * sf[1], tf[3] * sf[0]])
    # R elements: each orifice receives its tank's pressure (from the 0-junction the C element
    # fixes) and returns the outflow.
    Q = np.array(elements.kappa) * np.sqrt(np.maximum(P, 0.0))
    # 0-junction of each tank: the flow into C_i is the sum of the flows on the junction.
    # Tanks 3 and 4 drain (as free jets) into tanks 1 and 2.
    net = inflow - Q
    net[0] += Q[2]
    net[1] += Q[3]
    return net / np.array(elements.C)


def pressure_coefficients(elements: BondGraphElements) -> np.ndarray:
    """Kernel coefficients of the pressure equations (layout of ``_kernels.plant_coefficients``).

    Parameters
    ----------
    elements : BondGraphElements

    Returns
    -------
    numpy.ndarray, shape (10,)
        ``[c1, c2, c3, c4, c31, c42, b11, b22, b32, b41]`` with::

            dP1 = -c1 sqrt(P1) + c31 sqrt(P3) + b11 u1      dP3 = -c3 sqrt(P3) + b32 u2
            dP2 = -c2 sqrt(P2) + c42 sqrt(P4) + b22 u2      dP4 = -c4 sqrt(P4) + b41 u1

        i.e. ``c_i = kappa_i / C_i``, ``c31 = kappa3 / C1``, ``c42 = kappa4 / C2`` and
        ``b = (TF1 k1 / C1, TF2 k2 / C2, TF3 k2 / C3, TF4 k1 / C4)``.
    """
    C, kap, (k1, k2), tf = elements.C, elements.kappa, elements.k, elements.tf
    return np.array([
        kap[0] / C[0], kap[1] / C[1], kap[2] / C[2], kap[3] / C[3],
        kap[2] / C[0], kap[3] / C[1],
        tf[0] * k1 / C[0], tf[1] * k2 / C[1], tf[2] * k2 / C[2], tf[3] * k1 / C[3],
    ])


def linearise_pressure(p: QTPParams, rho: float = RHO_WATER, op: OperatingPoint | None = None):
    """Linearisation of the pressure model about the operating point of ``p``.

    With ``dP = rho g dh`` the level linearisation ``(A, B, C)`` of :func:`linearise` becomes
    ``(A, rho g B, C / (rho g))``: the state matrix is unchanged (the change of variables is a
    scalar multiple of the identity), the inputs act ``rho g`` times more strongly and the
    measured levels are ``h1, h2 = P1, P2 / (rho g)``.

    Parameters
    ----------
    p : QTPParams
    rho : float
        Water's density (g/cm^3).
    op : OperatingPoint, optional
        Default: the operating point of ``p``.

    Returns
    -------
    A : (4, 4), B : (4, 2), C : (2, 4) numpy.ndarray
        ``dP' = A dP + B du``, ``dy = C dP`` (y in cm).
    """
    el = BondGraphElements.from_plant(p, rho)
    A, B, C = linearise(p, operating_point(p) if op is None else op)
    return A.copy(), B * el.rho_g, C / el.rho_g
