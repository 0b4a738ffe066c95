"""Check an optimiser plugin against the optimiser contract.

Usage::

    python -m heurtune.check_plugin FILE_OR_MODULE [--settings '{"n": 10}']

Loads the plugin (a ``.py`` file or a module name), finds the optimisers it registers and runs
the contract checks of :mod:`heurtune.core.contract` on each (bounds, NaN/inf, seeds, exact
budgets, constraints, one and two workers), printing one line per check. Exit status 0 when all
pass, 1 when one fails, 2 for a mistake in the command (no such file, nothing registered, bad
settings).
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from heurtune import _startup
from heurtune.core import registry
from heurtune.core.cli import exit_codes
from heurtune.core.contract import CHECKS, run_checks
from heurtune.core.errors import ConfigError
from heurtune.core.plugins import load_plugin

__all__ = ["run", "main"]


def _parser():
    ap = argparse.ArgumentParser(prog="python -m heurtune.check_plugin", description=__doc__.split("\n")[0],
                                 epilog=exit_codes(c1="a check of the contract failed"))
    ap.add_argument("plugin", help="a .py file or an importable module that registers optimisers")
    ap.add_argument("--settings", default="{}", help="settings for the checks, as JSON (default: the optimiser's)")
    return ap


def _shipped_module(spec: str) -> str | None:
    """The module name of a shipped optimiser given as its file (``algorithms/cmaes.py``), whose
    import as a plugin would register it a second time; None for any other plugin."""
    if not spec.endswith(".py"):
        return None
    import heurtune.algorithms as shipped

    path = Path(spec).resolve()
    return f"{shipped.__name__}.{path.stem}" if path.parent in {Path(p).resolve() for p in shipped.__path__} else None


def run(argv=None, stream=None) -> int:
    """Entry point; returns the exit status (the lines go to ``stream``, default the
    ``sys.stdout`` of the call)."""
    stream = sys.stdout if stream is None else stream
    args = _parser().parse_args(argv)
    try:
        before = set(registry.available())
        shipped = _shipped_module(args.plugin)
        module = importlib.import_module(shipped) if shipped else load_plugin(args.plugin)
        names = sorted(set(registry.available()) - before)
        if not names:  # a module imported before (a shipped optimiser): the ones it registered
            names = sorted(n for n in registry.available() if registry.get(n).cls.__module__ == module.__name__)
        if not names:
            raise ConfigError(f"{args.plugin} registers no optimiser (use heurtune.core.registry.register)")
        try:
            settings = json.loads(args.settings)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"--settings is not JSON: {exc}") from None
        for name in names:
            registry.make_settings(name, settings)  # a bad setting is a one-line error here
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    failed = 0
    for name in names:
        for check, ok, reason in run_checks(name, settings):
            failed += not ok
            print(f"{'PASS' if ok else 'FAIL'}  {name}: {check}" + ("" if ok else f": {reason}"), file=stream)
    total = len(names) * len(CHECKS)
    print(f"{total - failed} of {total} checks passed", file=stream)
    return 0 if failed == 0 else 1


def main() -> None:
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
