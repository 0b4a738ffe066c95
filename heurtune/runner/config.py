"""Experiment configs: TOML files in ``experiments/``, validated with one-line errors.

A config may ``extends = "other_name"`` (a shipped experiment) or ``extends = "other.toml"`` (a
file, a relative path read from the folder of the config that names it): the other config is
loaded first and this file's tables are merged over it key by key (lists and scalars replace,
tables merge).
"""

from __future__ import annotations

import copy
import tomllib
from importlib import resources
from pathlib import Path

from heurtune.core.errors import ConfigError
from heurtune.core.families import DEFAULT_MODEL, get_family, load_registering_plugin, make_experiment
from heurtune.core.schema import COMMON_SCHEMA, NUMBER, PAIR, check  # noqa: F401  (NUMBER, PAIR: for plugin schemas)

__all__ = ["experiments_dir", "list_experiments", "find_experiment", "load_config", "load_experiment"]


def experiments_dir() -> Path:
    """Folder of the shipped experiment configs.

    Returns
    -------
    Path
    """
    return Path(str(resources.files("heurtune.experiments")))


def list_experiments() -> list[str]:
    """Names of the shipped experiments, sorted.

    Returns
    -------
    list of str
    """
    return sorted(p.stem for p in experiments_dir().glob("*.toml"))


def find_experiment(name: str) -> Path:
    """Path of an experiment given its name or a path to a ``.toml`` file.

    Parameters
    ----------
    name : str
        A shipped experiment's name, or a path to a ``.toml`` file.

    Returns
    -------
    Path

    Raises
    ------
    ConfigError
        One line: a ``.toml`` file that does not exist, or an unknown name (the shipped ones
        listed).
    """
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
        raw = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{src}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{src}: cannot read it: {exc.strerror or exc}") from None
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
    # Plugins first (a plugin may register the family of this config's plant model); a
    # relative .py path names a file beside the config.
    plugins = raw.get("plugins", [])
    check(plugins, COMMON_SCHEMA["plugins"], "plugins", src)
    raw["plugins"] = [str((path.parent / p).resolve()) if p.endswith(".py") and not Path(p).is_absolute() else p
                      for p in plugins]
    for spec in raw["plugins"]:
        try:
            load_registering_plugin(spec)
        except ConfigError as exc:
            raise ConfigError(f"{src}: plugins: {exc}") from None
    if base is not None and "plugins" in raw:
        raw["plugins"] = list(dict.fromkeys(base.get("plugins", []) + raw["plugins"]))
    if not raw["plugins"]:
        del raw["plugins"]
    # The plant model (this file's, else the parent's) selects the family and its schema.
    plant = raw.get("plant", {})
    model = plant.get("model") if isinstance(plant, dict) else None
    if model is None and base is not None:
        model = base.get("plant", {}).get("model")
    try:
        family = get_family(model or DEFAULT_MODEL)
    except ConfigError as exc:
        raise ConfigError(f"{src}: {exc}") from None
    check(raw, family.schema, "", src)
    if base is not None:
        raw = _merge(base, raw)
    raw["name"] = path.stem
    raw["source"] = str(path)
    return raw


def load_experiment(name: str):
    """Load an experiment by name (``experiments/<name>.toml``) or path: the experiment object
    of its plant family (:func:`heurtune.core.families.make_experiment`).

    Parameters
    ----------
    name : str
        A shipped experiment's name (``cs_folqi_qtp``) or the path of a ``.toml`` file.

    Returns
    -------
    ExperimentBase
        The experiment: its ``cases``, ``problem(case)``, ``optimisers`` and config.

    Raises
    ------
    ConfigError
        With a one-line message naming the file, the key and the allowed values.
    """
    return make_experiment(load_config(name))
