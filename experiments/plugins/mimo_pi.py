"""A controller structure as a plugin: a multivariable (centralised) PI on the QTP.

    du = Kp e + Ki integral(e),    e = r - y = -[dy1, dy2],    Kp, Ki full 2 x 2 matrices

Eight decision variables ``Kp11, Kp12, Kp21, Kp22, Ki11, Ki12, Ki21, Ki22`` (``Kp_ij`` from the
error of level j to pump i). The whole file is the example docs/controllers.md shows: a design
function from the values to a LinearController, and one register_structure call. Load it with
``--plugin experiments/plugins/mimo_pi.py`` or a config's ``plugins`` (example_plugin_controller)
and check it with ``python -m heurtune.check_plugin experiments/plugins/mimo_pi.py``.
"""

from __future__ import annotations

import numpy as np

from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import LinearController

NAMES = ("Kp11", "Kp12", "Kp21", "Kp22", "Ki11", "Ki12", "Ki21", "Ki22")


def design(values: dict, plant, options: dict) -> LinearController:
    """The controller of ``values``: two exact integrators of the errors, ``z' = e``, then
    ``du = Ki z + Kp e``. ``plant`` (A, B, C) and ``options`` are not needed here."""
    Kp = np.array([[values["Kp11"], values["Kp12"]], [values["Kp21"], values["Kp22"]]])
    Ki = np.array([[values["Ki11"], values["Ki12"]], [values["Ki21"], values["Ki22"]]])
    A = np.zeros((2, 2))
    B = np.zeros((2, 4))
    B[0, 0] = B[1, 1] = -1.0  # z_j' = e_j = -w_j (w: the measured deviations y - y_op, h3, h4)
    D = np.zeros((2, 4))
    D[:, :2] = -Kp
    # anti-windup: each integrator belongs to the pump it drives harder
    channel = tuple(int(np.argmax(np.abs(Ki[:, j]))) for j in range(2))
    return LinearController(A, B, Ki, D, ((0, 1), (1, 2)), channel)


MIMO_PI = register_structure(ControllerStructure(
    name="mimo_pi", family="qtp", variables=NAMES, design=design,
    description="multivariable PI: full 2 x 2 Kp and Ki on the errors of both lower tanks (a plugin)",
    # the cross terms may take either sign; the direct ones push the way the plant's gains need
    bounds={"Kp11": (0.0, 10.0), "Kp22": (0.0, 10.0), "Kp12": (-5.0, 5.0), "Kp21": (-5.0, 5.0),
            "Ki11": (-1.0, 1.0), "Ki22": (-1.0, 1.0), "Ki12": (-1.0, 1.0), "Ki21": (-1.0, 1.0)},
    # a full integral gain: the pairing does not apply, and det G(0) != 0 is all it needs
    integral_action="full",
    # the continuous loop's step: 0.125 s at the reference tolerance, shortened for a large
    # static feedback (Kp) as for the shipped PID
    extras={"step_at_reference": 0.125, "explicit_step": True, "integral_check": "det"}))
