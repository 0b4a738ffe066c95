"""The optimiser registry: strict names, typed settings, plugins found by import.

Every module in ``algorithms/`` (imported as ``heurtune.algorithms.<name>``) registers its
optimiser on import with :func:`register`. A user adds one by dropping a module there, or by
naming a ``.py`` file or an importable module (:func:`heurtune.core.plugins.load_plugin`) - no
reinstall needed.

``python -m heurtune.algorithms`` lists what is registered, with settings and defaults.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import typing

import heurtune.algorithms as algorithms_package
from heurtune.core.errors import ConfigError

__all__ = [
    "AlgorithmInfo",
    "register",
    "register_bridge",
    "bridges",
    "bridge_checked",
    "get",
    "available",
    "load_algorithms",
    "make_settings",
    "describe",
    "reference_markdown",
]

_REGISTRY: dict = {}
_PLUGINS_LOADED = False
# Bridged libraries: prefix -> (resolve(name) -> AlgorithmInfo or None, what the prefix names).
_BRIDGES: dict = {}


@dataclasses.dataclass(frozen=True)
class AlgorithmInfo:
    """What the registry knows of an optimiser."""

    name: str
    cls: type
    settings: type
    description: str
    source: str
    kind: str  # "population" (ask/tell) or "driver" (owns its loop)
    multi_objective: bool = False  # takes objectives (n, k) in tell


def register(name: str, *, settings: type, description: str, source: str = "",
             kind: str = "population", multi_objective: bool = False):
    """Class decorator adding an optimiser to the registry.

    Parameters
    ----------
    name : str
        Lowercase key (``[a-z0-9_]+``); a name already taken is an error.
    settings : type
        Frozen dataclass of the hyperparameters, with defaults.
    description : str
        One line for listings.
    source : str
        The reference the implementation follows.
    kind : {"population", "driver"}
        A population optimiser implements ``ask``/``tell``; a driver implements ``run(ctx)``.
    multi_objective : bool
        The optimiser's ``tell`` takes an (n, k) array of objectives (a problem with several
        objectives can only be run by such an optimiser).
    """
    if not name or name != name.lower() or not name.replace("_", "").isalnum():
        raise ValueError(f"optimiser name {name!r} must be lowercase letters, digits and '_'")
    if not dataclasses.is_dataclass(settings):
        raise TypeError(f"settings of {name!r} must be a dataclass")
    if kind not in ("population", "driver"):
        raise ValueError(f"kind of {name!r} must be 'population' or 'driver'")

    def decorate(cls):
        # the methods the engine calls, written by the class or a base of its own (not the
        # engine's Optimizer/Driver stubs, which raise NotImplementedError)
        needed = ("ask", "tell") if kind == "population" else ("run",)
        missing = [m for m in needed if getattr(getattr(cls, m, None), "__qualname__", "").split(".")[0]
                   in ("", "Optimizer", "Driver")]
        if missing:
            raise ValueError(f"{name}: the optimiser has no {'() and '.join(missing)}() (a {kind} optimiser implements "
                             f"{' and '.join(m + '()' for m in needed)}; docs/optimisers.md)")
        if name in _REGISTRY:
            raise ValueError(f"optimiser {name!r} is already registered (by {_REGISTRY[name].cls.__module__})")
        _REGISTRY[name] = AlgorithmInfo(name, cls, settings, description, source, kind, multi_objective)
        cls.registry_name = name
        return cls

    return decorate


def load_algorithms() -> None:
    """Import every module of ``heurtune.algorithms`` once (each registers itself)."""
    global _PLUGINS_LOADED
    if _PLUGINS_LOADED:
        return
    for mod in pkgutil.iter_modules(algorithms_package.__path__):
        if not mod.name.startswith("_"):
            importlib.import_module(f"heurtune.algorithms.{mod.name}")
    _PLUGINS_LOADED = True


def available() -> list:
    """The registered optimisers.

    Returns
    -------
    list of str
        Sorted names; bridged ones (``ng:NGOpt``) are not listed: see :func:`bridges`.
    """
    load_algorithms()
    return sorted(n for n in _REGISTRY if ":" not in n)


def register_bridge(prefix: str, resolve, description: str, checked: tuple = ()) -> None:
    """Names ``"<prefix>:<Name>"`` stand for the optimisers of another library (``ng:NGOpt``):
    the first :func:`get` of such a name calls ``resolve(Name)``, which returns the
    :class:`AlgorithmInfo` of a class bridging that optimiser (or raises a one-line
    ConfigError for a name the library does not have, or when the library is not installed).

    Parameters
    ----------
    prefix : str
        Lowercase, e.g. ``"ng"`` (nevergrad) or ``"pymoo"``.
    resolve : callable
        ``resolve(name) -> AlgorithmInfo``.
    description : str
        What the prefix names, for listings and error messages.
    checked : tuple of str
        Names (without the prefix) that the engine contract runs on, in the tests and in
        ``python -m heurtune.check_plugin`` on the bridge's module; names left out of it say why
        in the bridge's docstring.
    """
    if not prefix or prefix != prefix.lower() or not prefix.isalnum():
        raise ValueError(f"bridge prefix {prefix!r} must be lowercase letters and digits")
    if prefix in _BRIDGES:
        raise ValueError(f"bridge prefix {prefix!r} is already registered")
    _BRIDGES[prefix] = (resolve, description, tuple(checked))


def bridges() -> dict:
    """The bridged libraries.

    Returns
    -------
    dict
        ``{prefix: description}``.
    """
    load_algorithms()
    return {k: v[1] for k, v in sorted(_BRIDGES.items())}


def bridge_checked(module: str | None = None) -> list:
    """The bridged names the contract checks.

    Parameters
    ----------
    module : str, optional
        Only the bridges this module registered; every bridge by default.

    Returns
    -------
    list of str
        ``["ng:CMA", ...]``.
    """
    load_algorithms()
    return [f"{prefix}:{name}" for prefix, (resolve, _, checked) in sorted(_BRIDGES.items())
            if module is None or resolve.__module__ == module for name in checked]


def get(name: str) -> AlgorithmInfo:
    """The registry entry of an optimiser.

    Parameters
    ----------
    name : str
        A registered name, or a bridged one (``ng:NGOpt``), resolved and registered on first use.

    Returns
    -------
    AlgorithmInfo

    Raises
    ------
    ConfigError
        One line listing the allowed names.
    """
    load_algorithms()
    if name in _REGISTRY:
        return _REGISTRY[name]
    prefix, sep, rest = str(name).partition(":")
    if sep and prefix in _BRIDGES and rest:
        info = _BRIDGES[prefix][0](rest)
        _REGISTRY[name] = dataclasses.replace(info, name=name)
        return _REGISTRY[name]
    extra = "".join(f", {p}:<name> ({d})" for p, (_, d, _) in sorted(_BRIDGES.items()))
    raise ConfigError(f"unknown optimiser {name!r}; allowed: {', '.join(available())}{extra}")


def _check_type(name: str, key: str, hint, value):
    """Check one setting against its annotation (int, float, bool or str); ints pass as floats.
    Returns the value, or raises a ConfigError saying what it must be."""
    if hint is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif hint is bool:
        ok = isinstance(value, bool)
    elif hint is str:
        ok = isinstance(value, str)
    else:
        ok = True
    if not ok:
        raise ConfigError(f"{name}: setting {key} must be {getattr(hint, '__name__', hint)}, got {value!r}")
    return value


def make_settings(name: str, values: dict | None = None):
    """Typed, validated settings of an optimiser.

    Parameters
    ----------
    name : str
        A registered name.
    values : dict, optional
        Setting values; the others keep their defaults.

    Returns
    -------
    dataclass
        The optimiser's settings.

    Raises
    ------
    ConfigError
        One line naming every unknown setting and wrong type at once (with the allowed names),
        or the settings' own range check.
    """
    info = get(name)
    values = dict(values or {})
    fields = [f.name for f in dataclasses.fields(info.settings)]
    problems = [f"unknown setting {k!r}" for k in values if k not in fields]
    hints = typing.get_type_hints(info.settings)
    for key, value in list(values.items()):
        if key in fields:
            try:
                values[key] = _check_type(name, key, hints.get(key), value)
            except ConfigError as exc:
                problems.append(str(exc).split(": ", 1)[1])
    if problems:  # every bad key at once, in one line
        allowed = f"; allowed: {', '.join(fields)}" if any(p.startswith("unknown") for p in problems) else ""
        raise ConfigError(f"{name}: {'; '.join(problems)}{allowed}")
    try:
        return info.settings(**values)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{name}: {exc}") from None


def describe(name: str) -> str:
    """An optimiser as ``python -m heurtune.algorithms NAME`` prints it.

    Parameters
    ----------
    name : str
        A registered name.

    Returns
    -------
    str
        Its name, description, source, and settings with defaults and help, one per line.
    """
    info = get(name)
    lines = [f"{info.name}: {info.description}"]
    if info.source:
        lines.append(f"    source: {info.source}")
    for f in dataclasses.fields(info.settings):
        help_text = f.metadata.get("help", "")
        lines.append(f"    {f.name} = {f.default!r}" + (f"  ({help_text})" if help_text else ""))
    return "\n".join(lines)


def reference_markdown() -> str:
    """The optimiser reference page.

    Returns
    -------
    str
        Markdown: every registered optimiser with its settings (docs/optimisers_reference.md).
    """
    out = ["# Optimiser reference", "",
           "Generated by `python -m heurtune.algorithms --markdown`; every setting can be given in",
           "`settings={...}` or an experiment's `[[optimisers]]` table.", ""]
    for name in available():
        info = get(name)
        module = info.cls.__module__.replace("heurtune.algorithms.", "algorithms/") + ".py"
        out += [f"## `{name}`", "", info.description + ".", "",
                f"- kind: {info.kind}; module: `{module}`",
                f"- source: {info.source or '-'}", "",
                "| setting | default | meaning |", "| --- | --- | --- |"]
        for f in dataclasses.fields(info.settings):
            meaning = f.metadata.get("help", "").replace("|", "\\|")
            out.append(f"| `{f.name}` | `{f.default!r}` | {meaning} |")
        out.append("")
    return "\n".join(out)
