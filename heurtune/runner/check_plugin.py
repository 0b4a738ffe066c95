"""Check a plugin against the contracts of what it registers: optimisers, structures, families.

Usage::

    python -m heurtune.check_plugin FILE_OR_MODULE [--settings '{"n": 10}'] [--config EXPERIMENT.toml]

Loads the plugin (a ``.py`` file or a module name) and finds what it registers:

- each optimiser runs the contract checks of :mod:`heurtune.core.contract` (bounds, NaN/inf,
  seeds, exact budgets, constraints, one and two workers), with ``--settings``; a bridge to
  another library (:func:`heurtune.core.registry.register_bridge`) runs them on the names it
  declares ``checked``;
- each controller structure runs its plant family's contract
  (:func:`heurtune.core.structures.check_structure`; the QTP's in
  ``heurtune.objectives.qtp.structure_checks``: design, determinism, corners, simulation,
  batch design, pickling);
- each plant family runs the family contract of :mod:`heurtune.core.family_contract`
  (protocol, bad candidates, identity, report, robust and multi-objective tuning by config,
  workers) on the experiment ``--config`` names, which it needs.

One line per check. Exit status 0 when all pass, 1 when one fails, 2 for a mistake in the
command (no such file, nothing registered, bad settings).
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from heurtune import _startup
from heurtune.core import family_contract, registry, structures
from heurtune.core.cli import exit_codes
from heurtune.core.contract import run_checks
from heurtune.core.errors import ConfigError
from heurtune.core.families import DEFAULT_MODEL, families, get_family, load_families
from heurtune.core.plugins import load_plugin
from heurtune.runner.config import load_config

__all__ = ["run", "main"]


def _parser():
    ap = argparse.ArgumentParser(prog="python -m heurtune.check_plugin", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=exit_codes(("python -m heurtune.check_plugin my_optimiser.py",
                                                    "python -m heurtune.check_plugin experiments/plugins/mimo_pi.py",
                                                    "python -m heurtune.check_plugin my_family.py --config my.toml"),
                                                   c1="a check of the contract failed"))
    ap.add_argument("plugin", help="a .py file or an importable module that registers optimisers or controller "
                                   "structures")
    ap.add_argument("--settings", default="{}", help="settings for the checks, as JSON (default: the optimiser's)")
    ap.add_argument("--config", help="an experiment of the plant family the plugin registers (its checks need one)")
    return ap


def _shipped_module(spec: str) -> str | None:
    """The module name of a shipped optimiser given as its file (``algorithms/cmaes.py``), whose
    import as a plugin would register it a second time; None for any other plugin."""
    if not spec.endswith(".py"):
        return None
    import heurtune.algorithms as shipped

    path = Path(spec).resolve()
    return f"{shipped.__name__}.{path.stem}" if path.parent in {Path(p).resolve() for p in shipped.__path__} else None


def _structures() -> dict:
    """Every registered controller structure by (family, name)."""
    return {(s.family, s.name): s for s in structures.all_structures()}


def run(argv=None, stream=None) -> int:
    """Entry point; returns the exit status (the lines go to ``stream``, default the
    ``sys.stdout`` of the call).

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    stream : file-like, optional
        Where the lines go; default ``sys.stdout``.

    Returns
    -------
    int
        0 when every check passed, 1 when one failed, 2 for a mistake in the command.
    """
    stream = sys.stdout if stream is None else stream
    args = _parser().parse_args(argv)
    try:
        load_families()  # their structure contracts, and the structures shipped with them
        before = set(registry.available())
        before_structures = _structures()
        before_families = {f.name for f in families()}
        shipped = _shipped_module(args.plugin)
        module = importlib.import_module(shipped) if shipped else load_plugin(args.plugin)
        names = sorted(set(registry.available()) - before)
        if not names:  # a module imported before (a shipped optimiser): the ones it registered
            names = sorted(n for n in registry.available() if registry.get(n).cls.__module__ == module.__name__)
        names += registry.bridge_checked(module.__name__)  # a bridge: the names it declares checked
        new_structures = [s for key, s in _structures().items() if key not in before_structures
                          or s.source == module.__name__]
        new_families = sorted({f.name for f in families()} - before_families
                              | {f.name for f in families() if f.cls.__module__ == module.__name__})
        if not names and not new_structures and not new_families:
            raise ConfigError(f"{args.plugin} registers no optimiser (heurtune.core.registry.register or "
                              "register_bridge with checked names), no "
                              "controller structure (heurtune.core.structures.register_structure) and no plant "
                              "family (heurtune.core.families.register_family)")
        config = None
        if new_families:
            if args.config is None:
                raise ConfigError(f"{args.plugin} registers the plant family {', '.join(new_families)}: give "
                                  "--config EXPERIMENT.toml, an experiment of it, to check it")
            config = load_config(args.config)
            model = get_family(config.get("plant", {}).get("model", DEFAULT_MODEL)).name
            if model not in new_families:
                raise ConfigError(f"--config {args.config} is an experiment of family {model!r}, not of "
                                  f"{', '.join(new_families)}")
        try:
            settings = json.loads(args.settings)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"--settings is not JSON: {exc}") from None
        for name in names:
            registry.make_settings(name, settings)  # a bad setting is a one-line error here
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    failed = total = 0
    for name in names:
        for check, ok, reason in run_checks(name, settings):
            failed += not ok
            total += 1
            print(f"{'PASS' if ok else 'FAIL'}  {name}: {check}" + ("" if ok else f": {reason}"), file=stream)
    if config is not None:
        for check, ok, reason in family_contract.run_checks(config):
            failed += not ok
            total += 1
            print(f"{'PASS' if ok else 'FAIL'}  family {new_families[0]}: {check}" + ("" if ok else f": {reason}"),
                  file=stream)
    for s in new_structures:
        for check, ok, reason in structures.check_structure(s):
            failed += not ok
            total += 1
            print(f"{'PASS' if ok else 'FAIL'}  {s.family} structure {s.name}: {check}" + ("" if ok else f": {reason}"),
                  file=stream)
    print(f"{total - failed} of {total} checks passed", file=stream)
    return 0 if failed == 0 else 1


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
