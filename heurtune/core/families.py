"""The plant-family registry: strict names, a config schema per family, plugins found by import.

A plant family is an experiment class (:class:`heurtune.core.problem.ExperimentBase`) that
builds the tuning problems of a config, registered for one or more ``[plant] model`` names::

    @register_family("conical_tanks", schema=SCHEMA, description="coupled conical tanks, PI")
    class ConicalTanksExperiment(ExperimentBase):
        ...

The shipped families live in ``objectives/<family>/family.py`` (imported as
``heurtune.objectives.<family>.family``); a user's family is a ``.py`` file or module loaded
with ``--plugin`` or a config's ``plugins`` key (:func:`heurtune.core.plugins.load_plugin`).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import pkgutil
from pathlib import Path

import heurtune.objectives as families_package
from heurtune.core import registry, structures
from heurtune.core.errors import ConfigError
from heurtune.core.plugins import load_plugin, load_plugins, loaded
from heurtune.core.problem import ExperimentBase
from heurtune.core.robust import ROBUST_SCHEMA, apply_tuning
from heurtune.core.schema import MULTI_OBJECTIVE_SCHEMA

__all__ = ["FamilyInfo", "register_family", "get_family", "available", "load_families", "make_experiment",
           "families", "load_registering_plugin", "DEFAULT_MODEL"]

DEFAULT_MODEL = "qtp"  # the plant model of a config that names none
_FAMILIES: dict = {}  # model name -> FamilyInfo
_BUILTINS_LOADED = False


@dataclasses.dataclass(frozen=True)
class FamilyInfo:
    """What the registry knows of a plant family."""

    name: str
    models: tuple  # the [plant] model names it builds
    cls: type  # its ExperimentBase subclass
    schema: dict  # its config schema (heurtune.core.schema)
    description: str


def register_family(name: str, *, schema: dict, description: str, models: tuple | None = None):
    """Class decorator adding a plant family to the registry.

    Parameters
    ----------
    name : str
        Lowercase key (``[a-z0-9_]+``).
    schema : dict
        The config schema of the family's experiments (see :mod:`heurtune.core.schema`); its
        ``plant.model`` entry should allow the ``models`` names. The keys of robust and
        multi-objective tuning (``tuning_scenarios``, ``aggregate``, ``cvar_level``,
        ``objectives``, ``reference_point``, ``decision_weights``) are added to its
        ``[problem]`` table here: the core applies them to every family's problems
        (:meth:`~heurtune.core.problem.ExperimentBase._apply_tuning`).
    description : str
        One line for listings.
    models : tuple of str, optional
        The ``[plant] model`` values this family builds (default: ``(name,)``). A model name
        already taken is an error.
    """
    if not name or name != name.lower() or not name.replace("_", "").isalnum():
        raise ValueError(f"plant family name {name!r} must be lowercase letters, digits and '_'")
    models = tuple(models or (name,))

    def decorate(cls):
        if not (isinstance(cls, type) and issubclass(cls, ExperimentBase)):
            raise TypeError(f"plant family {name!r} must be a subclass of heurtune.core.problem.ExperimentBase")
        taken = [m for m in models if m in _FAMILIES and _FAMILIES[m].cls is not cls]
        if taken:
            raise ValueError(
                f"plant model {taken[0]!r} is already registered (by {_FAMILIES[taken[0]].cls.__module__})"
            )
        table = schema.setdefault("problem", {})
        if isinstance(table, dict):
            for key, spec in {**ROBUST_SCHEMA, **MULTI_OBJECTIVE_SCHEMA}.items():
                table.setdefault(key, spec)
        cls._tuning_hook = staticmethod(apply_tuning)
        info = FamilyInfo(name, models, cls, schema, description)
        for m in models:
            _FAMILIES[m] = info
        cls.family = name
        return cls

    return decorate


def load_families(model: str | None = None) -> None:
    """Import the shipped families: every ``heurtune.objectives.<package>.family``.

    Parameters
    ----------
    model : str, optional
        Stop at the first family that registers this ``[plant] model`` (in package order), so
        that a QTP run does not import the TITO family (and scipy.signal with it: 1.7 s of
        every command's start on a 2-core EPYC). Without it, or when no family has it, all
        of them are imported.
    """
    global _BUILTINS_LOADED
    if _BUILTINS_LOADED or (model is not None and model in _FAMILIES):
        return
    for mod in pkgutil.iter_modules(families_package.__path__):
        if mod.ispkg and importlib.util.find_spec(f"heurtune.objectives.{mod.name}.family") is not None:
            importlib.import_module(f"heurtune.objectives.{mod.name}.family")
            if model is not None and model in _FAMILIES:
                return
    _BUILTINS_LOADED = True


def available() -> list:
    """The registered ``[plant] model`` names.

    Returns
    -------
    list of str
        Sorted.
    """
    load_families()
    return sorted(_FAMILIES)


def families() -> list:
    """The registered families.

    Returns
    -------
    list of FamilyInfo
        One per family, by name.
    """
    load_families()
    return sorted({info.name: info for info in _FAMILIES.values()}.values(), key=lambda i: i.name)


def get_family(model: str) -> FamilyInfo:
    """The family that builds ``[plant] model = model``.

    Parameters
    ----------
    model : str
        A ``[plant] model`` name.

    Returns
    -------
    FamilyInfo

    Raises
    ------
    ConfigError
        One line naming the registered models.
    """
    load_families(model)
    try:
        return _FAMILIES[model]
    except KeyError:
        raise ConfigError(f"plant.model: got {model!r}; allowed: {', '.join(sorted(_FAMILIES))} "
                          "(or load a plant-family plugin)") from None


def make_experiment(config: dict) -> ExperimentBase:
    """The experiment object of a loaded config.

    Parameters
    ----------
    config : dict
        A checked config (e.g. ``meta.json``'s ``config``).

    Returns
    -------
    ExperimentBase
        Built by the family of its ``plant.model`` once the config's plugins are loaded.
    """
    load_plugins(config.get("plugins", []))
    return get_family(config.get("plant", {}).get("model", DEFAULT_MODEL)).cls(config)


def load_registering_plugin(spec: str):
    """:func:`heurtune.core.plugins.load_plugin`, refusing a plugin that registers nothing.

    Parameters
    ----------
    spec : str
        A ``.py`` file or a module name.

    Returns
    -------
    module
        The plugin's module.

    Raises
    ------
    ConfigError
        One line when the plugin, loaded for the first time, registers no optimiser, plant
        family or controller structure (a module name mistyped for another one, e.g.
        ``plugins = ["json"]``).
    """
    spec = str(spec)
    key = str(Path(spec).resolve()) if spec.endswith(".py") else spec
    if key in loaded():
        return load_plugin(spec)
    before = (tuple(registry.available()), tuple(sorted(_FAMILIES)), _structure_keys())
    module = load_plugin(spec)
    now = (tuple(registry.available()), tuple(sorted(_FAMILIES)), _structure_keys())
    if now == before and not _registered_from(module.__name__):
        raise ConfigError(f"plugin {spec!r} registers no optimiser, no plant family and no controller structure "
                          "(heurtune.core.registry.register, heurtune.core.families.register_family, "
                          "heurtune.core.structures.register_structure)")
    return module


def _structure_keys() -> tuple:
    """Every registered controller structure as (family, name)."""
    return tuple((s.family, s.name) for s in structures.all_structures())


def _registered_from(module_name: str) -> bool:
    """Whether an optimiser or plant family comes from ``module_name`` or its submodules (a
    plugin imported before, whose import now adds nothing new)."""
    classes = [registry.get(n).cls for n in registry.available()] + [f.cls for f in _FAMILIES.values()]
    modules = [c.__module__ for c in classes] + [s.source for s in structures.all_structures()]
    return any(m == module_name or m.startswith(module_name + ".") for m in modules)
