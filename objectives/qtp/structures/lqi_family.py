"""FOLQI, IOLQI and LQI: state feedback from a Riccati design plus integral action.

- ``folqi`` (thesis eq. 3.9): ``du = -K dx + diag(Ki1 / s^alpha1, Ki2 / s^alpha2) e``, the
  fractional integrators by Oustaloup (``oustaloup_order``, ``band``, ``realisation``);
- ``iolqi``: the same with ``alpha = 1`` (exact integrators);
- ``lqi``: the textbook LQI, the integrated errors in the Riccati design with weights Qi.

Bounds are the thesis' (sec. 4.3 and 5.3): Q in [0.01, 2.5], R in [0.1, 5], Ki in [0.1, 10],
alpha in [0.1, 2]; the LQI's Qi in [1e-4, 10] (docs/model.md, "Integral action"). The design
arithmetic is in :mod:`heurtune.objectives.qtp.controllers` (shared with the batched design).
"""

from __future__ import annotations

from heurtune.core.schema import PAIR, within
from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.batch_design import folqi_controllers
from heurtune.objectives.qtp.controllers import folqi_design, lqi_design
from heurtune.objectives.qtp.oustaloup import MAX_OUSTALOUP_ORDER, REALISATIONS

# FOLQI's fractional-integrator options. LQI reads none of them, but carries them (at their
# defaults) as every controller type did before the registry, so that its problem ids stay.
FRACTIONAL_OPTIONS = {
    "oustaloup_order": (within(int, 1, MAX_OUSTALOUP_ORDER), 5),
    "band": (PAIR, (1e-3, 1e3)),
    "realisation": (REALISATIONS, "direct"),
}
Q_BOUNDS, R_BOUNDS, KI_BOUNDS, ALPHA_BOUNDS = (0.01, 2.5), (0.1, 5.0), (0.1, 10.0), (0.1, 2.0)
# Bounds of the LQI's weights on the integrated errors (docs/model.md, "Integral action").
LQI_INTEGRAL_WEIGHT_BOUNDS = (1e-4, 10.0)
_Q = ("Q11", "Q22", "Q33", "Q44")
_R = ("R11", "R22")
_KI = ("Ki1", "Ki2")
POSITIVE, NOT_NEGATIVE = (0.0, True), (0.0, False)


def _bounds(names):
    table = {"Q": Q_BOUNDS, "R": R_BOUNDS, "K": KI_BOUNDS, "a": ALPHA_BOUNDS}
    return {n: LQI_INTEGRAL_WEIGHT_BOUNDS if n.startswith("Qi") else table[n[0]] for n in names}


def _domains(names):
    return {n: NOT_NEGATIVE if n.startswith("Q") else POSITIVE for n in names}


def _folqi(values, plant, options):
    return folqi_design(values, plant.A, plant.B, (values["alpha1"], values["alpha2"]), options["oustaloup_order"],
                        options["band"], options["realisation"], options["pairing"])


def _iolqi(values, plant, options):
    return folqi_design(values, plant.A, plant.B, (1.0, 1.0), options["oustaloup_order"], options["band"],
                        options["realisation"], options["pairing"])


def _batch(kind):
    def design(values, names, plant, options):
        return folqi_controllers(kind, values, names, plant.A, plant.B, **options)
    return design


def _lqi(values, plant, options):
    return lqi_design(values, plant.A, plant.B)


_FOLQI_NAMES = _Q + _R + _KI + ("alpha1", "alpha2")
_IOLQI_NAMES = _Q + _R + _KI
_LQI_NAMES = _Q + ("Qi1", "Qi2") + _R

FOLQI = register_structure(ControllerStructure(
    name="folqi", family="qtp", variables=_FOLQI_NAMES, bounds=_bounds(_FOLQI_NAMES), design=_folqi,
    description="fractional-order LQI (thesis eq. 3.9): Riccati state feedback + Ki / s^alpha per loop",
    options=FRACTIONAL_OPTIONS, integral_action="paired", domains=_domains(_FOLQI_NAMES),
    batch_design=_batch("folqi"), label="FOLQI",
    extras={"step_at_reference": 0.125, "feedback_step": True, "integral_check": "signs"}))
IOLQI = register_structure(ControllerStructure(
    name="iolqi", family="qtp", variables=_IOLQI_NAMES, bounds=_bounds(_IOLQI_NAMES), design=_iolqi,
    description="integer-order LQI: Riccati state feedback + Ki / s per loop",
    options=FRACTIONAL_OPTIONS, integral_action="paired", domains=_domains(_IOLQI_NAMES),
    batch_design=_batch("iolqi"), label="IOLQI",
    extras={"step_at_reference": 0.125, "feedback_step": True, "integral_check": "signs"}))
LQI = register_structure(ControllerStructure(
    name="lqi", family="qtp", variables=_LQI_NAMES, bounds=_bounds(_LQI_NAMES), design=_lqi,
    description="textbook LQI: the integrated errors weighted (Qi) in the Riccati design",
    options=FRACTIONAL_OPTIONS, integral_action="full", domains=_domains(_LQI_NAMES), label="LQI",
    extras={"step_at_reference": 0.125, "feedback_step": True, "integral_check": "det"}))
