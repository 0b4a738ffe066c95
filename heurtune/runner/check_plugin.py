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
import json
import sys

from heurtune import _startup
from heurtune.core import registry
from heurtune.core.contract import CHECKS, run_checks
from heurtune.core.errors import ConfigError
from heurtune.core.plugins import load_plugin

__all__ = ["run", "main"]


def _parser():
    ap = argparse.ArgumentParser(prog="python -m heurtune.check_plugin", description=__doc__.split("\n")[0])
    ap.add_argument("plugin", help="a .py file or an importable module that registers optimisers")
    ap.add_argument("--settings", default="{}", help="settings for the checks, as JSON (default: the optimiser's)")
    return ap


def run(argv=None, stream=None) -> int:
    """Entry point; returns the exit status (the lines go to ``stream``, default the
    ``sys.stdout`` of the call)."""
    stream = sys.stdout if stream is None else stream
    args = _parser().parse_args(argv)
    try:
        before = set(registry.available())
        load_plugin(args.plugin)
        names = sorted(set(registry.available()) - before)
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
    sys.exit(run())
