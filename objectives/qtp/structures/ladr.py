"""LADR: the thesis' linear active disturbance rejection controller (Appendix A).

Two channels, each an extended-state observer of a pair of tanks with a static feedback law;
``[controller] pairing = "anti-diagonal"`` makes each channel regulate the other lower tank.
Bounds: beta in [0, 150], b and r in [0, 10] (thesis sec. 4.3). The realisation is in
:func:`heurtune.objectives.qtp.controllers.ladr_design`.
"""

from __future__ import annotations

from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import LADR_NAMES, ladr_design
from heurtune.objectives.qtp.structures.lqi_family import FRACTIONAL_OPTIONS


def _ladr(values, plant, options):
    return ladr_design(values, options["pairing"])


LADR = register_structure(ControllerStructure(
    name="ladr", family="qtp", variables=LADR_NAMES,
    bounds={n: (0.0, 150.0) if n.startswith("beta") else (0.0, 10.0) for n in LADR_NAMES}, design=_ladr,
    description="linear ADRC (thesis Appendix A): extended-state observers per channel",
    # carries FOLQI's options, unread, as every type did before the registry (problem ids stay)
    options=FRACTIONAL_OPTIONS, integral_action="paired", domains={n: (0.0, False) for n in LADR_NAMES},
    label="LADR",
    # Its observers couple fast modes through the plant, which the explicit part sees
    # (docs/model.md, "Step rule"); its extended states are not integrators of the errors; its
    # observer's structural zero eigenvalues make the realisation non-minimal: no margins.
    # beta42 is never used and r1..r4 act only through the tracking differentiator, which a zero
    # set-point leaves at rest (docs/model.md, "Controllers"): kept for the thesis' tables, declared
    # unread so that the structure check knows it (an experiment tuning them is warned)
    extras={"step_at_reference": 0.05, "integral_check": None, "margins": False,
            "unread": ("beta42", "r1", "r2", "r3", "r4")}))
