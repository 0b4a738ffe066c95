"""Evaluate one controller of an experiment under its scenarios.

Usage::

    X="Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,Ki2=7.1716,alpha1=0.9814,alpha2=0.8437"
    python -m heurtune.evaluate cs_folqi_qtp --case min --x "$X" \\
        [--scenario nominal --scenario +30%] [--out traj.parquet] [--plot resp.png] [--plugin FILE]

Prints one row per scenario: overshoot Mp (%), settling time ts (s) and steady-state error
ess (%) per output, effort J per input and in total, the lowest and highest level (cm) and
voltage (V), and feasibility, then a line per scenario whose trajectory leaves the plant's
physical range, and one line when the controller structure cannot hold integral action. For a TITO experiment
(e.g. ``ga_pi_ccts --case ccts --x "Kp1=..,Ki1=..,Kp2=..,Ki2=.."``): the objective, IAE, ISE,
ITAE and settling time per loop, the loop margins and sensitivity peaks. Mistakes in the command
(unknown experiment, case, scenario or variable, a missing variable, a value out of bounds) give
a one-line error and exit code 2. ``--outside-bounds`` evaluates a controller whose values lie
outside the experiment's bounds anyway (e.g. gains published for other bounds), exactly as given
(never clipped), with one warning line per such variable on stderr.
"""

from __future__ import annotations

import argparse
import sys
import warnings

import pandas as pd

from heurtune import _startup
from heurtune.analysis.figures import plot_responses
from heurtune.core.cli import exit_codes
from heurtune.core.errors import ConfigError, DesignError
from heurtune.core.families import load_registering_plugin
from heurtune.core.io import FIGURE_SUFFIXES, check_output_file, write_parquet
from heurtune.core.problem import StructureWarning
from heurtune.runner.config import load_experiment


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m heurtune.evaluate", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=exit_codes(('python -m heurtune.evaluate cs_pid_qtp --case min '
                                                    '--x "Kp1=2,Ki1=0.05,Kd1=0.5,Kp2=2,Ki2=0.05,Kd2=0.5" '
                                                    '--plot pid.png',)))
    ap.add_argument("experiment", help="experiment name (experiments/<name>.toml) or a .toml path")
    ap.add_argument("--case", required=True, help="plant case, e.g. min or nmp")
    ap.add_argument("--x", required=True, help='decision variables as "NAME=VALUE,NAME=VALUE,..."')
    ap.add_argument("--scenario", action="append", default=None,
                    help="scenario to evaluate (repeatable; default: all of the experiment's)")
    ap.add_argument(
        "--out", help="write trajectories (scenario, t, h1..h4 or r1, r2, y1, y2, u1, u2) to this parquet file"
    )
    ap.add_argument("--plot", help="draw levels and pump voltages to this PNG file")
    ap.add_argument("--plugin", action="append", default=[],
                    help="plugin (a plant family, controller structures or optimisers): a .py file or module; "
                         "repeatable")
    ap.add_argument("--outside-bounds", action="store_true",
                    help="evaluate values outside the experiment's bounds as given (one warning per variable)")
    return ap


def bound_violations(prob, x) -> list:
    """Variables of ``x`` outside the bounds of ``prob``.

    Parameters
    ----------
    prob : heurtune.core.problem.TuningProblem
        Any problem with ``names``, ``lower`` and ``upper``.
    x : (d,) array_like
        Decision vector in the order of ``prob.names``.

    Returns
    -------
    list of (str, float, float, float)
        ``(name, value, lower, upper)`` per offending variable, in the order of ``prob.names``.
    """
    return [(name, float(v), float(lo), float(hi))
            for name, v, lo, hi in zip(prob.names, x, prob.lower, prob.upper) if not lo <= v <= hi]


def run(argv=None) -> int:
    """Entry point; returns the process exit code.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit code (``--help`` lists them).
    """
    args = _parser().parse_args(argv)
    try:
        for spec in args.plugin:
            load_registering_plugin(spec)
        if args.out:
            check_output_file(args.out, "--out")
        if args.plot:
            check_output_file(args.plot, "--plot", FIGURE_SUFFIXES)
        exp = load_experiment(args.experiment)
        prob = exp.problem(args.case)
        x = prob.parse(args.x, check_bounds=False)
        outside = bound_violations(prob, x)
        if outside and not args.outside_bounds:
            name, v, lo, hi = outside[0]
            raise ConfigError(f"{name}={v:g} is outside its bounds [{lo:g}, {hi:g}]"
                              + (f" (and {len(outside) - 1} more)" if len(outside) > 1 else "")
                              + "; pass --outside-bounds to evaluate it anyway")
        scenarios = args.scenario or list(prob.scenarios)
        for name in scenarios:
            prob.scenario(name)
        with warnings.catch_warnings():  # said once below, as one line
            warnings.simplefilter("ignore", StructureWarning)
            table = prob.report(x, scenarios)
        trajectories = None
        if args.out or args.plot:
            trajectories = pd.concat(
                [prob.simulate(x, name).assign(scenario=name) for name in scenarios], ignore_index=True
            )
            trajectories = trajectories[["scenario"] + [c for c in trajectories.columns if c != "scenario"]]
    except (ConfigError, DesignError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for name, v, lo, hi in outside:
        print(f"warning: {name} = {v:g} lies outside its bounds [{lo:g}, {hi:g}]; "
              "evaluated anyway (--outside-bounds)", file=sys.stderr)
    if prob.structure_warning:
        print(f"warning: {args.case}: {prob.structure_warning}", file=sys.stderr)
    print(f"{exp.name} / case {args.case} / {prob.controller}")
    columns = list(prob.report_columns or table.columns)
    with pd.option_context("display.width", 250, "display.max_columns", 24,
                           "display.float_format", "{:.4f}".format):
        print(table[columns].to_string())
    for name, flags in table.get("range", pd.Series(dtype=object)).items():
        if flags:
            print(f"{name}: outside the physical range: {flags}")
    if args.out:
        write_parquet(trajectories, args.out)
        print(f"trajectories written to {args.out}")
    if args.plot:
        plot_responses(trajectories, args.plot, title=f"{exp.name} / {args.case}",
                       limits=prob.physical_limits(), labels=prob.signal_labels)
        print(f"figure written to {args.plot}")
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
