"""PI2DOF: decentralised two-degree-of-freedom PI loops with set-point weights.

Each pump ``r`` is driven by the level ``[controller] pairing`` gives it (diagonal: pump 1 on
y1), with the proportional action on a weighted set-point and the integral on the error::

    v_r = Kp_r (b_r r - y) + Ki_r \u222b (r - y) dt

``b_r = 1`` is the PI of ``pid`` without a derivative (the same loop, the same numbers);
``b_r < 1`` softens the kick of a set-point step without changing the response to a
disturbance, nor the stability or the margins, which do not depend on ``b``. The structure reads
the reference (``reads_reference``): its
:class:`~heurtune.objectives.qtp.controllers.LinearController` carries ``Br`` and ``Dr``, and
a set-point step (``[scenario] setpoint_step``) reaches ``b`` there. Without a set-point step
``b1``, ``b2`` change nothing, and the experiment's start says so.

The realisation: per loop an integrator ``z_r' = (r - h_o) - w`` of the paired error (``w``
the measured deviation, ``r - h_o`` the set-point deviation) and
``du_r = Ki_r z_r + Kp_r (b_r (r - h_o) - w)``.

Default bounds: Kp in [0, 10], Ki in [1e-4, 1] (those of ``pid``), b in [0, 1].
"""

from __future__ import annotations

import numpy as np

from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import N_INPUTS, N_MEASURED, LinearController, _error_of_pump
from heurtune.objectives.qtp.structures.pid import PID_BOUNDS

PI2DOF_NAMES = ("Kp1", "Ki1", "b1", "Kp2", "Ki2", "b2")
PI2DOF_BOUNDS = {"Kp": PID_BOUNDS["Kp"], "Ki": PID_BOUNDS["Ki"], "b": (0.0, 1.0)}


def pi2dof_design(values: dict, plant, options: dict) -> LinearController:
    """The 2-DOF PI of ``values`` (Kp1, Ki1, b1, Kp2, Ki2, b2) as a LinearController with a
    reference path.

    Parameters
    ----------
    values : dict
    plant : PlantLinearisation
        Not read: the design is the gains themselves.
    options : dict
        ``pairing``.

    Returns
    -------
    LinearController
    """
    pairing = options["pairing"]
    A = np.zeros((N_INPUTS, N_INPUTS))
    B = np.zeros((N_INPUTS, N_MEASURED))
    C = np.zeros((N_INPUTS, N_INPUTS))
    D = np.zeros((N_INPUTS, N_MEASURED))
    Br = np.zeros((N_INPUTS, 2))
    Dr = np.zeros((N_INPUTS, 2))
    for r in range(N_INPUTS):
        kp, ki, b = (float(values[f"{g}{r + 1}"]) for g in ("Kp", "Ki", "b"))
        err = _error_of_pump(pairing, r)
        B[r, err], Br[r, err] = -1.0, 1.0     # z_r' = (r - h_o) - w
        C[r, r] = ki
        D[r, err], Dr[r, err] = -kp, b * kp   # Kp (b (r - h_o) - w)
    return LinearController(A, B, C, D, ((0, 1), (1, 2)), (0, 1), Br=Br, Dr=Dr)


PI2DOF = register_structure(ControllerStructure(
    name="pi2dof", family="qtp", variables=PI2DOF_NAMES, bounds={n: PI2DOF_BOUNDS[n[:-1]] for n in PI2DOF_NAMES},
    design=pi2dof_design,
    description="decentralised 2-DOF PI, Kp (b r - y) + Ki/s (r - y) per loop (set-point weights b)",
    integral_action="paired",
    domains={n: (0.0, n.startswith("Ki")) for n in PI2DOF_NAMES}, label="2-DOF PI",
    extras={"step_at_reference": 0.125, "explicit_step": True, "integral_check": "signs",
            "reads_reference": True}))
