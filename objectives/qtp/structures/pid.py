"""PID: decentralised PID loops with a filtered derivative, and an optional static decoupler.

Each pump ``r`` is driven by a PID on the error ``e = r - y`` of the level ``[controller]
pairing`` gives it (diagonal: pump 1 on y1; anti-diagonal: pump 1 on y2)::

    v_r = C_r(s) e,    C_r(s) = Kp_r + Ki_r / s + Kd_r s / (1 + s / N),    u = u0 + Dd v

with ``N = [controller] derivative_filter`` (rad/s, default 10) and ``Dd`` the decoupler:
``"none"`` (the identity) or ``"inverse_dc"``, ``Dd = G(0)^-1 M`` with ``M`` the paired
elements of the plant's DC gain ``G(0)`` (so that the decoupled plant's DC gain is diagonal in
the pairing and keeps each loop's own gain: the PID gains mean the same with or without it).
``y`` is the measured level, the output disturbance included, as for every QTP controller.

The realisation: per loop an exact integrator ``z_I' = e`` and the filter state
``z_F' = -N z_F + e``; ``Kd s / (1 + s / N) = Kd N - Kd N^2 / (s + N)``, so
``v = Ki z_I - Kd N^2 z_F + (Kp + Kd N) e``. Both states are modal (diagonal, one input).

Default bounds (:data:`PID_BOUNDS`, from ``benchmarks/sweep_pid_gains.py``; docs/model.md, "PID and
FOPID"): Kp in [0, 10], Ki in [1e-4, 1], Kd in [0, 2] (V/cm, V/(cm s), V s/cm).
"""

from __future__ import annotations

import numpy as np

from heurtune.core.schema import positive
from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import (
    N_INPUTS,
    N_MEASURED,
    LinearController,
    _error_of_pump,
    dc_gain,
)

DECOUPLERS = ("none", "inverse_dc")
DEFAULT_DERIVATIVE_FILTER = 10.0
PID_NAMES = ("Kp1", "Ki1", "Kd1", "Kp2", "Ki2", "Kd2")
PID_BOUNDS = {"Kp": (0.0, 10.0), "Ki": (1e-4, 1.0), "Kd": (0.0, 2.0)}


def decoupler_gain(plant, pairing: str, decoupler: str):
    """The static decoupler ``Dd`` (2, 2) between the loops' outputs and the pumps, or None
    for ``"none"``: ``G(0)^-1 M``, ``M[e_r, r] = G(0)[e_r, r]`` for pump r's error e_r.

    Parameters
    ----------
    plant : PlantLinearisation
    pairing : str
    decoupler : {"none", "inverse_dc"}

    Returns
    -------
    ndarray (2, 2) or None
    """
    if decoupler == "none":
        return None
    G0 = dc_gain(plant.A, plant.B, plant.C)
    M = np.zeros((N_INPUTS, N_INPUTS))
    for r in range(N_INPUTS):
        e = _error_of_pump(pairing, r)
        M[e, r] = G0[e, r]
    return np.linalg.solve(G0, M)


def decoupled(C, D, plant, pairing, decoupler):
    """``(Dd C, Dd D)`` for the decoupler (the loops' output matrices unchanged for none).

    Parameters
    ----------
    C, D : ndarray
        The loops' output matrices (2 rows).
    plant : PlantLinearisation
    pairing : str
    decoupler : {"none", "inverse_dc"}

    Returns
    -------
    tuple
    """
    Dd = decoupler_gain(plant, pairing, decoupler)
    return (C, D) if Dd is None else (Dd @ C, Dd @ D)


def pid_design(values: dict, plant, options: dict) -> LinearController:
    """The PID controller of ``values`` (Kp1, Ki1, Kd1, Kp2, Ki2, Kd2) as a LinearController.

    Parameters
    ----------
    values : dict
    plant : PlantLinearisation
    options : dict

    Returns
    -------
    LinearController
    """
    N = float(options["derivative_filter"])
    pairing = options["pairing"]
    A = np.zeros((4, 4))
    B = np.zeros((4, N_MEASURED))
    C = np.zeros((N_INPUTS, 4))
    D = np.zeros((N_INPUTS, N_MEASURED))
    blocks = []
    for r in range(N_INPUTS):
        kp, ki, kd = (float(values[f"{g}{r + 1}"]) for g in ("Kp", "Ki", "Kd"))
        err = _error_of_pump(pairing, r)
        s = 2 * r
        A[s + 1, s + 1] = -N
        B[s, err] = B[s + 1, err] = -1.0  # e = -w_err
        C[r, s] = ki
        C[r, s + 1] = -kd * N * N
        D[r, err] = -(kp + kd * N)
        blocks.append((s, s + 2))
    C, D = decoupled(C, D, plant, pairing, options["decoupler"])
    return LinearController(A, B, np.ascontiguousarray(C), np.ascontiguousarray(D), tuple(blocks), (0, 1))


def decoupler_sign(plant, options: dict) -> int:
    """Sign of ``det Dd`` (1 without a decoupler), for the integral-action check.

    Parameters
    ----------
    plant : PlantLinearisation
    options : dict

    Returns
    -------
    int
    """
    Dd = decoupler_gain(plant, options["pairing"], options.get("decoupler", "none"))
    return 1 if Dd is None or np.linalg.det(Dd) > 0 else -1


PID = register_structure(ControllerStructure(
    name="pid", family="qtp", variables=PID_NAMES, bounds={n: PID_BOUNDS[n[:2]] for n in PID_NAMES},
    design=pid_design,
    description="decentralised PID, Kp + Ki/s + Kd s/(1 + s/N) per loop, optional static decoupler",
    options={"derivative_filter": (positive(), DEFAULT_DERIVATIVE_FILTER), "decoupler": (DECOUPLERS, "none")},
    integral_action="paired",
    domains={n: (0.0, n.startswith("Ki")) for n in PID_NAMES}, label="PID",
    extras={"step_at_reference": 0.125, "explicit_step": True, "integral_check": "signs",
            "gain_sign": decoupler_sign}))
