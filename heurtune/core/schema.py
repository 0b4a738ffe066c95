"""The config schema language, checked with one-line errors naming the file and the key.

A schema maps keys to specs: a dict is a table with fixed keys; ``("map", spec)`` a table with
free keys whose values follow spec; ``("list", spec)`` a list; ``("pair", NUMBER)`` two numbers;
``("choices", values[, hint])`` one of the values or a list of distinct ones (the hint, when
given, ends the error of a value not among them); ``("oneof", specs)`` the
first spec that fits; ``("range", spec, lo, hi, strict)`` a number of ``spec`` within [lo, hi]
(``strict``: above lo), either end None for none (:func:`at_least`, :func:`positive`); a tuple
of strings the allowed values; ``None`` anything (checked
elsewhere); python types (``str``, ``int``, ``bool``) and ``NUMBER`` leaves.

Every family's schema starts from :data:`COMMON_SCHEMA`, the keys the runner reads.
"""

from __future__ import annotations

import math

from heurtune.core.errors import ConfigError

__all__ = ["NUMBER", "PAIR", "OPTIMISERS", "COMMON_SCHEMA", "MULTI_OBJECTIVE_SCHEMA", "check", "at_least",
           "positive", "within"]

NUMBER = (int, float)
PAIR = ("pair", NUMBER)


def at_least(spec, lo):
    """A value of ``spec`` (``int`` or ``NUMBER``) that is at least ``lo``.

    Parameters
    ----------
    spec : type or spec
        ``int`` or ``NUMBER``.
    lo : float

    Returns
    -------
    tuple
        A ``("range", ...)`` spec.
    """
    return ("range", spec, lo, None, False)


def positive(spec=NUMBER):
    """A value of ``spec`` above 0.

    Parameters
    ----------
    spec : type or spec
        ``int`` or ``NUMBER`` (default).

    Returns
    -------
    tuple
        A ``("range", ...)`` spec.
    """
    return ("range", spec, 0, None, True)


def within(spec, lo, hi):
    """A value of ``spec`` in [lo, hi].

    Parameters
    ----------
    spec : type or spec
        ``int`` or ``NUMBER``.
    lo, hi : float

    Returns
    -------
    tuple
        A ``("range", ...)`` spec.
    """
    return ("range", spec, lo, hi, False)


# Each optimiser's settings are validated by the registry (they differ per optimiser); `cases`
# restricts an optimiser to some of the experiment's cases (default: all).
OPTIMISERS = ("list", {
    "name": str, "settings": ("map", None), "max_epochs": at_least(int, 0), "max_evals": at_least(int, 1),
    "max_time": positive(), "tol": at_least(NUMBER, 0), "tol_window": at_least(int, 1),
    "constraint_handling": ("deb", "penalty"), "penalty": positive(), "bound_handling": ("clip", "reflect"),
    "cases": ("list", str),
})


# The keys the runner reads, shared by every plant family.
COMMON_SCHEMA = {
    "description": str,
    "extends": str,
    "runs": at_least(int, 1),
    "seed": at_least(int, 0),
    # Plugins (optimisers, plant families): .py paths (relative ones from the config's folder)
    # or importable module names.
    "plugins": ("list", str),
    "optimisers": OPTIMISERS,
}

# Keys of a family's [problem] table for several objectives (ExperimentBase._objectives).
MULTI_OBJECTIVE_SCHEMA = {"objectives": ("list", str), "reference_point": ("list", NUMBER),
                          "decision_weights": ("list", NUMBER)}


def _describe(spec) -> str:
    if isinstance(spec, tuple) and spec and spec[0] == "range":
        return _describe(spec[1])
    if isinstance(spec, tuple) and spec and spec[0] in ("list", "map", "pair", "oneof"):
        return {"list": "a list", "map": "a table", "pair": "two numbers [a, b]", "oneof": "one of several forms"}[
            spec[0]
        ]
    if isinstance(spec, tuple):
        if all(isinstance(s, str) for s in spec):
            return "one of " + ", ".join(repr(s) for s in spec)
        return "a number"
    if isinstance(spec, dict):
        return "a table"
    return {str: "a string", int: "an integer", dict: "a table", bool: "true or false"}.get(spec, str(spec))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check(value, spec, where: str, src: str):
    """Validate ``value`` against ``spec``; raise ConfigError naming file and key.

    Parameters
    ----------
    value
        The config value.
    spec
        Its spec (see the module docstring).
    where : str
        The key path (``scenario.horizon``).
    src : str
        The file, named in the error.
    """

    def fail(msg):
        raise ConfigError(f"{src}: {where}: {msg}" if where else f"{src}: {msg}")

    if isinstance(spec, dict):
        if not isinstance(value, dict):
            fail(f"expected a table, got {value!r}")
        for key, sub in value.items():
            if key not in spec:
                fail(f"unknown {'key' if where else 'top-level key or table'} {key!r}; allowed: {', '.join(spec)}")
            check(sub, spec[key], f"{where}.{key}" if where else key, src)
        return
    if isinstance(spec, tuple) and spec and spec[0] == "map":
        if not isinstance(value, dict):
            fail(f"expected a table, got {value!r}")
        for key, sub in value.items():
            check(sub, spec[1], f"{where}.{key}", src)
        return
    if isinstance(spec, tuple) and spec and spec[0] == "list":
        if not isinstance(value, list):
            fail(f"expected a list, got {value!r}")
        for i, sub in enumerate(value):
            check(sub, spec[1], f"{where}[{i}]", src)
        return
    if isinstance(spec, tuple) and spec and spec[0] == "oneof":
        errors = []
        for sub in spec[1]:
            try:
                check(value, sub, where, src)
                return
            except ConfigError as exc:
                errors.append(str(exc).split(": ", 2)[-1])
        fail(" or ".join(dict.fromkeys(errors)))
    if isinstance(spec, tuple) and spec and spec[0] == "choices":
        values = value if isinstance(value, list) else [value]
        for v in values:
            if v not in spec[1]:
                hint = f" ({spec[2]})" if len(spec) > 2 else ""
                fail(f"got {v!r}; allowed: {', '.join(spec[1])}{hint}")
        if not values or len(set(values)) != len(values):
            fail(f"give one or more distinct values, got {value!r}")
        return
    if isinstance(spec, tuple) and spec and spec[0] == "range":
        _, base, lo, hi, strict = spec
        check(value, base, where, src)
        if lo is not None and (value <= lo if strict else value < lo):
            fail(f"must be {'>' if strict else '>='} {lo}, got {value!r}")
        if hi is not None and value > hi:
            fail(f"must be <= {hi}, got {value!r}")
        return
    if isinstance(spec, tuple) and spec and spec[0] == "pair":
        if not (isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)):
            fail(f"expected two numbers [a, b], got {value!r}")
        return
    if spec is None:  # free value, validated elsewhere
        return
    if spec == NUMBER:
        if not _is_number(value) or not math.isfinite(value):
            fail(f"expected a number, got {value!r}")
        return
    if isinstance(spec, tuple):  # allowed strings
        if value not in spec:
            fail(f"got {value!r}; allowed: {', '.join(spec)}")
        return
    if spec is int:
        if not isinstance(value, int) or isinstance(value, bool):
            fail(f"expected an integer, got {value!r}")
        return
    if not isinstance(value, spec):
        fail(f"expected {_describe(spec)}, got {value!r}")
