"""FOPID: decentralised fractional-order PID loops (Podlubny's PI^lambda D^mu).

Each pump ``r`` is driven, on the error of the level ``[controller] pairing`` gives it, by::

    C_r(s) = Kp_r + Ki_r / s^lambda_r + Kd_r s^mu_r

with both fractional parts realised by Oustaloup's filter over FOLQI's ``oustaloup_order`` and
``band``: ``1 / s^lambda`` as FOLQI's integrator (``realisation``), ``s^mu`` (0 < mu < 1) as
the filter of ``s^mu``, whose gain above the band is ``wh^mu``, so that ``Kd`` is a
high-frequency gain of ``Kd wh^mu`` (500 Kd at mu = 0.9 and the default band). The optional
decoupler is the PID's (``decoupler``).

Default bounds (:data:`FOPID_BOUNDS`, from ``benchmarks/sweep_pid_gains.py``; docs/model.md, "PID and
FOPID"): Kp in [0, 10], Ki in [1e-4, 1], Kd in [0, 0.5], lambda in [0.1, 2], mu in [0.1, 0.9].
"""

from __future__ import annotations

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import (
    N_INPUTS,
    N_MEASURED,
    ControllerDesignError,
    LinearController,
    _error_of_pump,
)
from heurtune.objectives.qtp.oustaloup import FractionalIntegrator, fractional_integrator, oustaloup_zpk
from heurtune.objectives.qtp.structures.lqi_family import FRACTIONAL_OPTIONS
from heurtune.objectives.qtp.structures.pid import DECOUPLERS, decoupled, decoupler_sign

FOPID_NAMES = ("Kp1", "Ki1", "Kd1", "lambda1", "mu1", "Kp2", "Ki2", "Kd2", "lambda2", "mu2")
FOPID_BOUNDS = {"Kp": (0.0, 10.0), "Ki": (1e-4, 1.0), "Kd": (0.0, 0.5), "la": (0.1, 2.0), "mu": (0.1, 0.9)}


def _realised(part):
    """``(A, b, c, d)`` of a single-input part: diagonal from its partial fractions where it
    has them, else its cascade realisation."""
    modal = part.modal()
    if modal is None:
        return part.state_space()
    poles, residues, d = modal
    return np.diag(poles), np.ones(poles.size), residues, d


def fopid_design(values: dict, plant, options: dict) -> LinearController:
    """The FOPID controller of ``values`` as a LinearController (blocks: per loop the
    integral part, then the derivative part).

    Parameters
    ----------
    values : dict
    plant : PlantLinearisation
    options : dict

    Returns
    -------
    LinearController
    """
    order, band, realisation = options["oustaloup_order"], options["band"], options["realisation"]
    pairing = options["pairing"]
    parts = []  # (pump, error, gain, (A, b, c, d))
    static = np.zeros(N_INPUTS)
    for r in range(N_INPUTS):
        kp, ki, kd, lam, mu = (float(values[f"{g}{r + 1}"]) for g in ("Kp", "Ki", "Kd", "lambda", "mu"))
        if not 0.0 < mu < 1.0:
            raise ControllerDesignError("invalid_parameter", f"mu{r + 1} must lie in (0, 1), got {mu}")
        try:
            integral = fractional_integrator(lam, order, band, realisation)
            z, p, k = oustaloup_zpk(mu, order, band)
        except ConfigError as exc:
            raise ControllerDesignError("invalid_parameter", str(exc)) from None
        derivative = FractionalIntegrator(-mu, 0, z, p, k)
        err = _error_of_pump(pairing, r)
        static[r] = kp
        parts.append((r, err, ki, _realised(integral)))
        parts.append((r, err, kd, _realised(derivative)))
    nz = sum(part[3][0].shape[0] for part in parts)
    A = np.zeros((nz, nz))
    B = np.zeros((nz, N_MEASURED))
    C = np.zeros((N_INPUTS, nz))
    D = np.zeros((N_INPUTS, N_MEASURED))
    blocks, channel = [], []
    start = 0
    for r, err, gain, (Af, bf, cf, df) in parts:
        stop = start + Af.shape[0]
        A[start:stop, start:stop] = Af
        B[start:stop, err] = -bf  # e = -w_err
        C[r, start:stop] = gain * cf
        D[r, err] -= gain * df
        blocks.append((start, stop))
        channel.append(r)
        start = stop
    for r in range(N_INPUTS):
        D[r, _error_of_pump(pairing, r)] -= static[r]
    C, D = decoupled(C, D, plant, pairing, options["decoupler"])
    return LinearController(A, B, np.ascontiguousarray(C), np.ascontiguousarray(D), tuple(blocks), tuple(channel))


FOPID = register_structure(ControllerStructure(
    name="fopid", family="qtp", variables=FOPID_NAMES, bounds={n: FOPID_BOUNDS[n[:2]] for n in FOPID_NAMES},
    design=fopid_design,
    description="decentralised fractional-order PID, Kp + Ki/s^lambda + Kd s^mu per loop (Oustaloup)",
    options=dict(FRACTIONAL_OPTIONS, decoupler=(DECOUPLERS, "none")), integral_action="paired",
    domains={n: (0.0, not n.startswith(("Kp", "Kd"))) for n in FOPID_NAMES}, label="FOPID",
    extras={"step_at_reference": 0.125, "explicit_step": True, "integral_check": "signs",
            "gain_sign": decoupler_sign}))
