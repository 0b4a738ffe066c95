"""Experiment configs: TOML files in ``experiments/``, validated with one-line errors.

A config may ``extends = "other_name"`` (a shipped experiment) or ``extends = "other.toml"`` (a
file, a relative path read from the folder of the config that names it): the other config is
loaded first and this file's tables are merged over it key by key (lists and scalars replace,
tables merge).
"""

from __future__ import annotations

import copy
import math
import tomllib
from importlib import resources
from pathlib import Path

from heurtune.errors import ConfigError

__all__ = ["experiments_dir", "list_experiments", "find_experiment", "load_config", "SCHEMA", "TITO_SCHEMA"]

# Schema: key -> type spec. A dict is a table with fixed keys; ("map", spec) is a table with
# free keys whose values follow spec; ("list", spec) a list. Leaf specs are python types or a
# tuple of allowed strings.
NUMBER = (int, float)
PAIR = ("pair", NUMBER)

# Each optimiser's settings are validated by the registry (they differ per optimiser); `cases`
# restricts an optimiser to some of the experiment's cases (default: all).
OPTIMISERS = ("list", {
    "name": str, "settings": ("map", None), "max_epochs": int, "max_evals": int,
    "max_time": NUMBER, "tol": NUMBER, "tol_window": int,
    "constraint_handling": ("deb", "penalty"), "penalty": NUMBER, "bound_handling": ("clip", "reflect"),
    "cases": ("list", str),
})

SCHEMA = {
    "description": str,
    "extends": str,
    "runs": int,
    "seed": int,
    "plant": {
        # "qtp_bond_graph": the thesis' chapter-6 bond-graph form (pressure states) of the QTP
        "model": ("qtp", "qtp_bond_graph", "tito", "two_tank_nonlinear"),
        "cases": ("list", str),
        "custom": ("map", {
            "A": ("list", NUMBER), "a": ("list", NUMBER), "k": ("list", NUMBER),
            "gamma": ("list", NUMBER), "levels": ("list", NUMBER), "g": NUMBER,
            "height": ("list", NUMBER), "u_range": PAIR,
        }),
    },
    "controller": {
        "type": ("choices", ("folqi", "iolqi", "ladr", "lqi")),  # one, or a list (one case per type)
        "oustaloup_order": int,
        "band": PAIR,
        "realisation": ("direct", "integer_split"),
        # One pairing for every case, "auto" (the one the sign of det G(0) allows), or a table
        # naming it per plant case.
        "pairing": ("oneof", (("diagonal", "anti-diagonal", "auto"),
                              ("map", ("diagonal", "anti-diagonal", "auto")))),
    },
    "scenario": {
        "horizon": NUMBER, "dt": NUMBER,
        "output_disturbance": PAIR, "disturbance_time": NUMBER,
        "input_disturbance": PAIR, "input_disturbance_time": NUMBER,
        "noise_sd": NUMBER, "noise_seed": int,
        "saturation": PAIR,
        "limits": ("none", "physical"),
        "uncertainty": ("map", NUMBER),
    },
    "problem": {
        "objective": ("effort", "effort_deviation", "iae", "ise", "itae", "weighted"),
        # objective = "weighted": sum over the named metrics of weight * (metric1 + metric2)
        "weights": {"J": NUMBER, "Jdev": NUMBER, "IAE": NUMBER, "ISE": NUMBER, "ITAE": NUMBER,
                    "TV": NUMBER},
        "settling_band": NUMBER,
        "tuning_scenario": str,
        # "none": no performance constraints (stability is always required)
        "constraints": ("oneof", ({"Mp": NUMBER, "ts": NUMBER, "ess": NUMBER}, ("none",))),
        "bounds": ("map", PAIR),
    },
    # Optimiser plugins outside algorithms/: .py paths or importable module names.
    "plugins": ("list", str),
    "optimisers": OPTIMISERS,
    # Fixed controllers evaluated as runs of their own (one evaluation, no search), e.g. the
    # thesis' printed gains: x = {name = value, ...} or printed = {table = "4.7", row = "min"}.
    "baselines": ("list", {"name": str, "case": str, "x": ("map", NUMBER),
                           "printed": {"table": str, "row": str}}),
    # thesis_chapter = 4, 5 or 6: write that chapter's tables next to the printed values.
    "report": {"thesis_chapter": int},
}


# Keys shared by every plant model.
_COMMON = {key: SCHEMA[key] for key in ("description", "extends", "runs", "seed", "plugins", "optimisers")}
STEPS = ("list", ("list", PAIR))  # per loop, [[time, value], ...]

# Two-input two-output coupled tanks with dead time (heurtune.tito_problem).
TITO_SCHEMA = dict(_COMMON, **{
    "plant": {
        "model": ("tito", "two_tank_nonlinear"),
        "cases": ("list", str),
        # TITO: {g11 = {K, lags, leads, L}, ...}; two_tank_nonlinear: TwoTankParams fields.
        # Validated by the plant constructors, which name the key.
        "custom": ("map", ("map", None)),
    },
    "decoupler": {"type": ("inverted", "none"), "case": int, "delay_compensation": bool},
    "controller": {
        "type": ("choices", ("pi", "pid")),
        "N": NUMBER,
        "baselines": ("list", ("gpm",)),
        "gpm": {"Am": NUMBER, "phim": NUMBER},
    },
    "scenario": {
        "horizon": NUMBER, "dt": NUMBER,
        "setpoints": STEPS,
        "input_disturbance": {"time": NUMBER, "size": PAIR},
        "output_disturbance": {"time": NUMBER, "size": PAIR},
        "noise_power": NUMBER, "noise_seed": int,
        "variation": ("map", NUMBER),
        "vary": ("list", ("K", "lags", "leads", "L")),
    },
    "problem": {
        "objective": ("iae", "ise", "itae", "bandwidth"),
        "tuning_scenario": str,
        "settling_band": NUMBER,
        "windows": ("map", PAIR),
        "constraints": {"Am": NUMBER, "phim": NUMBER, "Mt": NUMBER, "Ms": NUMBER},
        "bounds": ("map", PAIR),
    },
    "robustness": {"uncertainty": NUMBER, "variation": NUMBER, "pade_order": int, "w": PAIR},
})

SCHEMAS = {"qtp": SCHEMA, "qtp_bond_graph": SCHEMA, "tito": TITO_SCHEMA, "two_tank_nonlinear": TITO_SCHEMA}


def experiments_dir() -> Path:
    """Folder of the shipped experiment configs."""
    return Path(str(resources.files("heurtune.experiments")))


def list_experiments() -> list[str]:
    """Names of the shipped experiments, sorted."""
    return sorted(p.stem for p in experiments_dir().glob("*.toml"))


def find_experiment(name: str) -> Path:
    """Path of an experiment given its name or a path to a ``.toml`` file."""
    p = Path(name)
    if p.suffix == ".toml":
        if not p.is_file():
            raise ConfigError(f"experiment file {name!r} does not exist")
        return p
    candidate = experiments_dir() / f"{name}.toml"
    if not candidate.is_file():
        raise ConfigError(
            f"unknown experiment {name!r}; allowed: {', '.join(list_experiments())}"
        )
    return candidate


def _describe(spec) -> str:
    if isinstance(spec, tuple) and spec and spec[0] in ("list", "map", "pair", "oneof"):
        return {"list": "a list", "map": "a table", "pair": "two numbers [a, b]", "oneof": "one of several forms"}[spec[0]]
    if isinstance(spec, tuple):
        if all(isinstance(s, str) for s in spec):
            return "one of " + ", ".join(repr(s) for s in spec)
        return "a number"
    if isinstance(spec, dict):
        return "a table"
    return {str: "a string", int: "an integer", dict: "a table"}.get(spec, str(spec))


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check(value, spec, where: str, src: str):
    """Validate ``value`` against ``spec``; raise ConfigError naming file and key."""

    def fail(msg):
        raise ConfigError(f"{src}: {where}: {msg}")

    if isinstance(spec, dict):
        if not isinstance(value, dict):
            fail(f"expected a table, got {value!r}")
        for key, sub in value.items():
            if key not in spec:
                fail(f"unknown key {key!r}; allowed: {', '.join(spec)}")
            _check(sub, spec[key], f"{where}.{key}" if where else key, src)
        return
    if isinstance(spec, tuple) and spec and spec[0] == "map":
        if not isinstance(value, dict):
            fail(f"expected a table, got {value!r}")
        for key, sub in value.items():
            _check(sub, spec[1], f"{where}.{key}", src)
        return
    if isinstance(spec, tuple) and spec and spec[0] == "list":
        if not isinstance(value, list):
            fail(f"expected a list, got {value!r}")
        for i, sub in enumerate(value):
            _check(sub, spec[1], f"{where}[{i}]", src)
        return
    if isinstance(spec, tuple) and spec and spec[0] == "oneof":
        errors = []
        for sub in spec[1]:
            try:
                _check(value, sub, where, src)
                return
            except ConfigError as exc:
                errors.append(str(exc).split(": ", 2)[-1])
        fail(" or ".join(dict.fromkeys(errors)))
    if isinstance(spec, tuple) and spec and spec[0] == "choices":
        values = value if isinstance(value, list) else [value]
        for v in values:
            if v not in spec[1]:
                fail(f"got {v!r}; allowed: {', '.join(spec[1])}")
        if not values or len(set(values)) != len(values):
            fail(f"give one or more distinct values, got {value!r}")
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


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def load_config(name: str, _seen: tuple = ()) -> dict:
    """Load, merge (``extends``) and validate an experiment config.

    Parameters
    ----------
    name : str
        Experiment name (a file ``experiments/<name>.toml``) or a path to a TOML file.

    Returns
    -------
    dict
        The resolved config with ``name`` and ``source`` added.
    """
    path = find_experiment(name)
    src = path.name
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{src}: not valid TOML: {exc}") from None
    if not isinstance(raw.get("extends", ""), str):
        raise ConfigError(f"{src}: extends: expected a string, got {raw['extends']!r}")
    parent = raw.pop("extends", None)
    base = None
    if parent is not None:
        if parent.endswith(".toml") and not Path(parent).is_absolute():
            # a relative path names a file beside the config that extends it
            parent = str(path.parent / parent)
        chain = _seen + (path.resolve(),)
        if find_experiment(parent).resolve() in chain:
            raise ConfigError(f"{src}: extends: circular chain through {parent!r}")
        base = load_config(parent, chain)
        base.pop("name", None)
        base.pop("source", None)
    # The plant model (this file's, else the parent's) selects the schema.
    plant = raw.get("plant", {})
    model = plant.get("model") if isinstance(plant, dict) else None
    if model is None and base is not None:
        model = base.get("plant", {}).get("model")
    model = model or "qtp"
    if model not in SCHEMAS:
        raise ConfigError(f"{src}: plant.model: got {model!r}; allowed: {', '.join(SCHEMAS)}")
    _check(raw, SCHEMAS[model], "", src)
    if base is not None:
        raw = _merge(base, raw)
    raw["name"] = path.stem
    raw["source"] = str(path)
    return raw
