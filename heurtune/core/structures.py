"""The controller-structure registry: what a family's controllers are, declared once.

A controller structure (FOLQI, PID, a user's two-degree-of-freedom PI) is the part of a tuning
problem that turns a decision vector into a controller. It declares, in one
:class:`ControllerStructure`:

- its decision variables, in order, with default bounds and the domain each must stay in;
- the ``[controller]`` options it reads, with their schema and defaults;
- whether it has integral action, and whether ``[controller] pairing`` applies to it;
- a design function from the values (and the plant's linearisation) to the family's linear
  controller, and optionally a batched design.

Structures register per plant family (``family = "qtp"``): the family builds its config
schema, its bounds, its design and its checks from the registry, so a structure added by a
plugin file (``--plugin my_pi.py`` or a config's ``plugins``) is as much a part of it as a
shipped one. docs/controllers.md is the guide; ``objectives/qtp/structures/`` holds the QTP's.
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing

from heurtune.core.errors import ConfigError

__all__ = ["ControllerStructure", "register_structure", "get_structure", "structure_names",
           "structures_of", "all_structures", "on_register", "register_checks", "check_structure", "INTEGRAL_ACTIONS"]

# "paired": integrators on the errors, one per input, which error each input integrates set by
# [controller] pairing; "full": an integral gain that couples every error to every input (the
# pairing does not apply); "none": no integral action on the errors.
INTEGRAL_ACTIONS = ("paired", "full", "none")

_REGISTRY: dict = {}  # family -> {name: ControllerStructure}
_LISTENERS: dict = {}  # family -> [callback(structure)]
_CHECKERS: dict = {}  # family -> checks(structure) -> [(check, ok, reason)]
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclasses.dataclass(frozen=True)
class ControllerStructure:
    """A controller structure of a plant family.

    Attributes
    ----------
    name : str
        Its ``[controller] type``, lowercase (``[a-z][a-z0-9_]*``).
    family : str
        The plant family it designs for (its registry key, e.g. ``"qtp"``).
    variables : tuple of str
        Decision variables in decision-vector order.
    bounds : dict
        Default ``(low, high)`` per variable (a config's ``problem.bounds`` overrides them).
    design : callable
        ``design(values, plant, options) -> controller``: ``values`` maps every variable to a
        float, ``plant`` is the family's linearisation, ``options`` the structure's options
        with ``pairing``. It raises the family's design error for a candidate that has no
        controller (a Riccati failure, an invalid parameter), and returns the family's linear
        controller (for the QTP a :class:`~heurtune.objectives.qtp.controllers.LinearController`).
    description : str
        One line for listings.
    options : dict
        ``[controller]`` keys it reads: ``{key: (schema spec, default)}``.
    integral_action : {"paired", "full", "none"}
        See :data:`INTEGRAL_ACTIONS`.
    domains : dict
        ``{variable: (low, strict)}``: the variable must be at least ``low`` (above it when
        ``strict``); a variable left out may take any value.
    batch_design : callable, optional
        ``batch_design(values (k, d), names, plant, options) -> list`` of controllers or
        design errors, the same as ``design`` row by row.
    label : str
        Its name in tables and figures (default: the name in capitals).
    extras : dict
        Family-specific declarations (the QTP reads ``step_at_reference``, the continuous loop's
        step at the reference tolerance, ``explicit_step``, and ``unread``, the variables the
        design keeps but does not read).
    source : str
        Where the structure is defined (module), filled in by :func:`register_structure`.
    """

    name: str
    family: str
    variables: tuple
    bounds: dict
    design: typing.Callable
    description: str
    options: dict = dataclasses.field(default_factory=dict)
    integral_action: str = "paired"
    domains: dict = dataclasses.field(default_factory=dict)
    batch_design: typing.Callable | None = None
    label: str = ""
    extras: dict = dataclasses.field(default_factory=dict)
    source: str = ""

    def __post_init__(self):
        where = f"controller structure {self.name!r}"
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise ConfigError(f"{where}: the name must match [a-z][a-z0-9_]*")
        variables = tuple(self.variables)
        object.__setattr__(self, "variables", variables)
        if not variables or len(set(variables)) != len(variables):
            raise ConfigError(f"{where}: variables must be distinct names, at least one")
        missing = [v for v in variables if v not in self.bounds]
        if missing:
            raise ConfigError(f"{where}: no default bounds for {', '.join(missing)}")
        extra = [v for v in self.bounds if v not in variables]
        if extra:
            raise ConfigError(f"{where}: bounds of unknown variables {', '.join(extra)}")
        for v in variables:
            lo, hi = self.bounds[v]
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ConfigError(f"{where}: bounds.{v} must be finite with low < high, got {[lo, hi]}")
            if v in self.domains:
                low, strict = self.domains[v]
                if lo < low or (strict and lo == low):
                    raise ConfigError(f"{where}: bounds.{v} start at {lo}, outside its domain "
                                      f"({'>' if strict else '>='} {low:g})")
        if self.integral_action not in INTEGRAL_ACTIONS:
            raise ConfigError(f"{where}: integral_action: got {self.integral_action!r}; "
                              f"allowed: {', '.join(INTEGRAL_ACTIONS)}")
        if not callable(self.design):
            raise ConfigError(f"{where}: design must be callable")
        for key, value in self.options.items():
            if not (isinstance(value, tuple) and len(value) == 2):
                raise ConfigError(f"{where}: options.{key} must be (schema spec, default)")
        if not self.label:
            object.__setattr__(self, "label", self.name.upper())

    @property
    def paired(self) -> bool:
        """Whether ``[controller] pairing`` applies (integral action on paired errors)."""
        return self.integral_action == "paired"

    def default_options(self) -> dict:
        """The options with their defaults."""
        return {key: default for key, (_, default) in self.options.items()}

    def domain(self, variable: str) -> tuple:
        """``(low, strict)`` of a variable (``(-inf, False)`` when it has none)."""
        return self.domains.get(variable, (-math.inf, False))


def register_structure(structure: ControllerStructure) -> ControllerStructure:
    """Add a structure to its family's registry and tell the family (:func:`on_register`).

    Parameters
    ----------
    structure : ControllerStructure

    Returns
    -------
    ControllerStructure
        ``structure``, so that a module can keep it.

    Raises
    ------
    ConfigError
        For a name already taken in the family.
    """
    known = _REGISTRY.setdefault(structure.family, {})
    if structure.name in known:
        raise ConfigError(f"controller structure {structure.name!r} of family {structure.family!r} is "
                          f"registered already (by {known[structure.name].source or 'another module'})")
    source = getattr(structure.design, "__module__", "") or ""
    structure = dataclasses.replace(structure, source=structure.source or source)
    known[structure.name] = structure
    for callback in _LISTENERS.get(structure.family, []):
        callback(structure)
    return structure


def on_register(family: str, callback) -> None:
    """Call ``callback(structure)`` for every structure of a family, those registered already
    and those to come (a family keeps its schema's choices up to date this way).

    Parameters
    ----------
    family : str
    callback : callable
        Takes a :class:`ControllerStructure`.
    """
    _LISTENERS.setdefault(family, []).append(callback)
    for structure in list(_REGISTRY.get(family, {}).values()):
        callback(structure)


def get_structure(family: str, name: str) -> ControllerStructure:
    """A registered structure.

    Parameters
    ----------
    family : str
        The plant family (``"qtp"``).
    name : str
        The structure's name (``[controller] type``).

    Returns
    -------
    ControllerStructure

    Raises
    ------
    ConfigError
        One line naming the allowed ones.
    """
    try:
        return _REGISTRY[family][name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown controller type {name!r}; allowed: "
                          f"{', '.join(structure_names(family)) or 'none'}") from None


def structure_names(family: str) -> tuple:
    """The structure names of a family.

    Parameters
    ----------
    family : str

    Returns
    -------
    tuple of str
        Sorted.
    """
    return tuple(sorted(_REGISTRY.get(family, {})))


def all_structures() -> tuple:
    """Every registered structure of every family.

    Returns
    -------
    tuple of ControllerStructure
    """
    return tuple(s for family in sorted(_REGISTRY) for s in _REGISTRY[family].values())


def structures_of(family: str) -> tuple:
    """The structures of a family.

    Parameters
    ----------
    family : str

    Returns
    -------
    tuple of ControllerStructure
        In registration order.
    """
    return tuple(_REGISTRY.get(family, {}).values())


def register_checks(family: str, checks) -> None:
    """Give a family's contract for controller structures (``python -m heurtune.check_plugin``
    runs it on a plugin's structures).

    Parameters
    ----------
    family : str
    checks : callable
        ``checks(structure)`` returns ``[(check name, passed, one-line reason), ...]``.
    """
    _CHECKERS[family] = checks


def check_structure(structure: ControllerStructure) -> list:
    """The contract checks of a structure's family on it.

    Parameters
    ----------
    structure : ControllerStructure

    Returns
    -------
    list of (str, bool, str)
        ``(check name, passed, one-line reason)``; a single failed check when the family gives
        no contract.
    """
    checks = _CHECKERS.get(structure.family)
    if checks is None:
        return [("family", False, f"family {structure.family!r} gives no structure contract (register_checks)")]
    return checks(structure)
