"""The QTP's controller structures: one module each, registered in :mod:`heurtune.core.structures`.

A structure turns named tuning values into a
:class:`~heurtune.objectives.qtp.controllers.LinearController` (``z' = A z + B w``,
``du = C z + D w`` on the measured deviations ``w = [y1 - h1o, y2 - h2o, h3 - h3o, h4 - h4o]``),
which every simulation path, the margins and the exports take as it is. The shipped ones:

- :mod:`.lqi_family`: ``folqi`` and ``iolqi`` (thesis eq. 3.9), ``lqi`` (integral weights in the
  Riccati design);
- :mod:`.ladr`: ``ladr`` (thesis Appendix A);
- :mod:`.pid`: ``pid``, decentralised PID with a filtered derivative and an optional static
  decoupler;
- :mod:`.fopid`: ``fopid``, decentralised fractional-order PID (Oustaloup);
- :mod:`.pi2dof`: ``pi2dof``, decentralised 2-DOF PI with set-point weights (reads the reference).

A new structure is one module that calls :func:`heurtune.core.structures.register_structure`
with ``family = "qtp"``: dropped here (and imported below) or loaded as a plugin file
(docs/controllers.md). The functions here are the family's view of the registry.
"""

from __future__ import annotations

import math

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.core.structures import get_structure, structure_names, structures_of
from heurtune.objectives.qtp.controllers import PAIRINGS, LinearController, PlantLinearisation
from heurtune.objectives.qtp.structures import fopid, ladr, lqi_family, pi2dof, pid  # noqa: F401  (they register)

__all__ = ["FAMILY", "structure", "names", "controller_label", "paired_types", "decision_names", "default_bounds",
           "variable_domain", "build_controller", "loop_options"]

FAMILY = "qtp"


def structure(kind: str):
    """The registered structure ``kind`` (one-line ConfigError naming the allowed ones).

    Parameters
    ----------
    kind : str

    Returns
    -------
    ControllerStructure
    """
    return get_structure(FAMILY, kind)


def names() -> tuple:
    """Every registered QTP controller type, sorted.

    Returns
    -------
    tuple of str
    """
    return structure_names(FAMILY)


def controller_label(kind: str) -> str:
    """A type's label in tables and figures (``"FOLQI"``); an unknown type as it is.

    Parameters
    ----------
    kind : str

    Returns
    -------
    str
    """
    try:
        return structure(kind).label
    except ConfigError:
        return kind


def paired_types() -> tuple:
    """The types whose integral action follows ``[controller] pairing``.

    Returns
    -------
    tuple of str
    """
    return tuple(sorted(s.name for s in structures_of(FAMILY) if s.paired))


def decision_names(kind: str) -> tuple:
    """Names of the tuning variables of a controller type, in decision-vector order.

    Parameters
    ----------
    kind : str

    Returns
    -------
    tuple of str
    """
    return structure(kind).variables


def default_bounds(kind: str) -> dict:
    """Default ``(low, high)`` of each variable of a controller type (see each structure).

    Parameters
    ----------
    kind : str

    Returns
    -------
    dict of str to (float, float)
    """
    return dict(structure(kind).bounds)


def variable_domain(name: str) -> tuple:
    """Where a tuning variable is meaningful, ``(low, strict)``, as the first structure that
    has it declares (``(-inf, False)`` for a name none declares).

    Parameters
    ----------
    name : str

    Returns
    -------
    tuple
        ``(low, strict)``.
    """
    for s in structures_of(FAMILY):
        if name in s.variables:
            return s.domain(name)
    return -math.inf, False


def loop_options(kind: str, options: dict) -> dict:
    """The options of a loop of type ``kind``: the structure's defaults updated by ``options``
    and ``pairing`` last (a one-line ConfigError for a key the structure does not read).

    Parameters
    ----------
    kind : str
    options : dict
        The config's ``[controller]`` options (``pairing`` among them).

    Returns
    -------
    dict
    """
    s = structure(kind)
    out = s.default_options()
    pairing = options.get("pairing", "diagonal")
    for key, value in options.items():
        if key == "pairing":
            continue
        if key not in out:
            allowed = ", ".join(sorted(out) + ["pairing"])
            raise ConfigError(f"controller type {kind!r} has no option {key!r}; allowed: {allowed}")
        out[key] = tuple(value) if isinstance(value, list) else value
    if pairing not in PAIRINGS:
        raise ConfigError(f"unknown pairing {pairing!r}; allowed: {', '.join(PAIRINGS)}")
    out["pairing"] = pairing
    return out


def build_controller(kind: str, values: dict, A, B, C=None, **options) -> LinearController:
    """Build a controller from its named tuning variables and the linearised plant.

    Parameters
    ----------
    kind : str
        A registered controller type (:func:`names`).
    values : dict
        Tuning variables by name (:func:`decision_names`).
    A, B : ndarray
        Linearised plant (nominal model) the design uses.
    C : ndarray, optional
        Its measured outputs (default: the two lower levels), for structures that need the DC
        gain (a PID's decoupler).
    **options
        The structure's options (:func:`loop_options`), and ``pairing``.

    Returns
    -------
    LinearController

    Raises
    ------
    ControllerDesignError
        The design fails for this candidate (reason in ``.reason``).
    ConfigError
        An unknown type, option or pairing.
    """
    if C is None:
        C = np.eye(2, A.shape[0])
    return structure(kind).design(values, PlantLinearisation(A, B, C), loop_options(kind, options))
