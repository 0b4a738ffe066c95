"""Sweeps of a TITO design parameter: one design per value, the family of its responses.

Usage::

    python -m heurtune.objectives.tito.sweep CONFIG --param Am --values 2,3,4 \\
        [--cases ccts] [--out DIR] [--optimiser sqp_multistart] [--max-evals 2000] [--seed 0] [--no-figures]

``CONFIG`` is a TITO experiment (a name under ``experiments/`` or a ``.toml`` path). For every
case of the experiment (or those of ``--cases``) and every value, the controller is designed,
simulated under the experiment's ``nominal`` scenario and measured. Written to ``--out``
(default ``results/<experiment>``):

- ``sweep_<param>.parquet``: one row per (case, value, loop): the design (``Kp, Ki, Kd``), the
  specification, the exact gain and phase margins with their crossovers, ``Mt``, ``Ms`` and the
  bandwidth ``w_b`` (frequency grid of the problem), IAE / ISE / ITAE of the nominal response
  (whole record and per window of the experiment);
- ``sweep_<param>_<case>.png``: ``y1`` and ``y2`` with their set-points, one line per value.

Parameters (``--param``):

``Am``, ``phim``
    The GPM design of the experiment (paper 001; :func:`heurtune.objectives.tito.model.gpm_pi`
    on each decoupled loop's FOPDT fit), the other margin held at ``controller.gpm`` (default
    3 and 60 deg). A PID case gets paper 001's GPM PID, which is this PI (``Kd = 0``).
``Mt`` (alias ``gamma_m``)
    The bandwidth design (papers 000 and 002): maximise ``w_b1 + w_b2`` subject to ``Am``,
    ``phim`` and ``max|T| <= Mt`` on each loop, the experiment's ``bandwidth`` problem solved by
    a registered optimiser (:func:`heurtune.minimize`) for each value. Paper 000's ``gamma_m^*``
    (Theorem 1) is the upper bound of the maximum closed-loop amplitude ratio
    ``A_r = max_w |W_O / (1 + W_O)|``, that is of ``max|T(jw)|``: exactly ``Mt``. The margin
    bounds are the experiment's ``problem.constraints`` when its objective is ``bandwidth``;
    otherwise those ``Mt`` itself implies (paper 000 eq. 25-26: ``Am >= 1 + 1/Mt``,
    ``phim >= 2 asin(1 / (2 Mt))``), so that ``Mt`` is the only active specification. Each
    value keeps the best design, under its own constraints, of those found at every value of
    the sweep (a design feasible for a tighter ``Mt`` is feasible for a looser one), so the
    achieved bandwidth never falls as ``Mt`` grows because of one poor search.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.core.errors import ConfigError

__all__ = ["PARAMETERS", "check_sweep", "sweep_designs", "sweep_figure", "run_sweep", "run"]

PARAMETERS = {
    "Am": "gain margin of the GPM design (> 1)",
    "phim": "phase margin of the GPM design, degrees (in (0, 90))",
    "Mt": "upper bound of max|T| of the bandwidth design (> 1)",
    "gamma_m": "paper 000's gamma_m^*, the same bound as Mt (> 1)",
}
ALIASES = {"gamma_m": "Mt"}
# A short label of each parameter (legends, axis titles).
LABELS = {"Am": "Am", "phim": "phim (deg)", "Mt": "Mt", "gamma_m": "gamma_m* (= Mt)"}
DEFAULT_OPTIMISER = "sqp_multistart"
DEFAULT_MAX_EVALS = 2000
# The budget of a --smoke run's sweep (``[report] sweep`` of a config): two starts, 60 evaluations.
SMOKE_BUDGET = {"max_evals": 60, "settings": {"starts": 2}}


def _allowed() -> str:
    return ", ".join(f"{k} ({v})" for k, v in PARAMETERS.items())


def check_sweep(param: str, values) -> tuple:
    """The design parameter a sweep varies and its values, checked (one-line ConfigError).

    Parameters
    ----------
    param : str
        One of :data:`PARAMETERS` (``Am``, ``phim``, ``Mt``, ``gamma_m``).
    values : sequence of float, or str
        The values; a string is read as comma-separated numbers (``"2,3,4"``).

    Returns
    -------
    design_param : str
        ``param``, with the alias ``gamma_m`` resolved to ``Mt``.
    values : tuple of float
        In the order given; distinct, finite and in the parameter's range.
    """
    if param not in PARAMETERS:
        raise ConfigError(f"sweep: unknown parameter {param!r}; allowed: {_allowed()}")
    if isinstance(values, str):
        items = [v.strip() for v in values.split(",")]
        try:
            values = [float(v) for v in items]
        except ValueError:
            raise ConfigError(f"sweep: values {values!r} must be comma-separated numbers, e.g. 2,3,4") from None
    try:
        vals = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ConfigError(f"sweep: values must be numbers, got {values!r}") from None
    if not vals:
        raise ConfigError(f"sweep: give at least one value of {param}")
    design = ALIASES.get(param, param)
    for v in vals:
        ok = math.isfinite(v) and (0.0 < v < 90.0 if design == "phim" else v > 1.0)
        if not ok:
            raise ConfigError(f"sweep: {param} = {v!r} is out of range; allowed: {param}: {PARAMETERS[param]}")
    if len(set(vals)) != len(vals):
        dup = next(v for v in vals if vals.count(v) > 1)
        raise ConfigError(f"sweep: {param} = {dup:g} is given twice; give distinct values")
    return design, vals


def _slug(case: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in case)


def _gpm_x(prob, case: str, Am: float, phim: float, label: str) -> np.ndarray:
    """Decision vector of the GPM PI (``Kd = 0`` for a PID case) at ``(Am, phim)``."""
    from heurtune.objectives.tito import model as tito

    per = 2 if prob.kind == "pi" else 3
    x = np.zeros(prob.dim)
    for i, fo in enumerate(prob.chain.fopdt):
        if fo is None:
            why = prob.chain.fopdt_error[i] or f"loop {i + 1}: no FOPDT fit"
            raise ConfigError(f"sweep: case {case!r} has no GPM design ({why}); sweep Mt there, or choose --cases")
        try:
            Kc, Ti = tito.gpm_pi(fo, Am, phim)
        except ConfigError as exc:
            raise ConfigError(f"sweep: case {case!r}, {label}, loop {i + 1}: {exc}") from None
        kp, ki, _ = tito.PIController(Kc, Ti).parallel()
        x[i * per], x[i * per + 1] = kp, ki
    return x


def _bandwidth_problem(base, constraints: dict):
    """The experiment's case as the bandwidth design with ``constraints`` (same chain, bounds,
    scenarios and filter ratio), designed on the nominal plant."""
    from heurtune.objectives.tito.problem import TITOProblem

    bounds = dict(zip(base.names, zip(base.lower.tolist(), base.upper.tolist())))
    return TITOProblem(base.case, base.kind, base.chain, bounds, objective="bandwidth", constraints=constraints,
                       scenarios=base.scenarios, tuning_scenario="nominal", N=base.N, windows=base.windows,
                       settling_band=base.settling_band, nonlinear=base.nonlinear,
                       robustness=base.robustness_options, gpm_spec=base.gpm_spec)


def _mt_constraints(exp, Mt: float, implied: bool = False) -> dict:
    """The bandwidth design's constraints at ``Mt``: the experiment's margins when its objective is
    ``bandwidth`` (and not ``implied``), else those ``Mt`` implies (paper 000 eq. 25-26)."""
    if exp.objective == "bandwidth" and not implied:
        return {**exp.constraints, "Mt": Mt}
    return {"Am": 1.0 + 1.0 / Mt, "phim": math.degrees(2.0 * math.asin(1.0 / (2.0 * Mt))), "Mt": Mt}


def _rank(ev) -> list:
    """Deb's order of an evaluation's rows: feasible by objective, then the rest by violation."""
    viol = np.sum(np.maximum(ev.g, 0.0), axis=1)
    return sorted(range(len(ev.f)), key=lambda k: (0, ev.f[k]) if ev.feasible[k] else (1, viol[k]))


def sweep_designs(exp, param: str, values, *, cases=None, optimiser: str = DEFAULT_OPTIMISER,
                  max_evals: int = DEFAULT_MAX_EVALS, settings: dict | None = None, seed: int | None = None,
                  implied_margins: bool = False):
    """Design, simulate and measure one controller per value of a design parameter.

    Parameters
    ----------
    exp : TITOExperiment
        From :func:`heurtune.load_experiment`.
    param : str
        ``Am``, ``phim`` (GPM design), ``Mt`` or ``gamma_m`` (bandwidth design); see the module
        docstring.
    values : sequence of float or str
        The values (``"2,3,4"`` is read as three).
    cases : sequence of str, optional
        Cases of the experiment (default: all).
    optimiser : str
        Registered optimiser of the bandwidth design (``Mt`` sweeps only).
    max_evals : int
        Its evaluation budget per value.
    settings : dict, optional
        Its settings (default: ``starts = 20`` for ``sqp_multistart``).
    seed : int, optional
        Root seed of the searches (default: the experiment's ``seed``); value ``k`` gets
        ``SeedSequence([seed, k])``.
    implied_margins : bool
        ``Mt`` sweeps: hold the margins ``Mt`` implies (paper 000 eq. 25-26: ``Am >= 1 + 1/Mt``,
        ``phim >= 2 asin(1 / (2 Mt))``) even when the experiment's own objective is ``bandwidth``
        with margins of its own (which can bind before ``Mt`` does).

    Returns
    -------
    table : pandas.DataFrame
        One row per (case, value, loop); the columns of ``sweep_<param>.parquet``.
    responses : dict
        ``{case: {value: DataFrame}}``: the nominal responses (``t, r1, r2, y1, y2, u1, u2``).
    """
    design, vals = check_sweep(param, values)
    if getattr(exp, "model", None) not in ("tito", "two_tank_nonlinear") or not hasattr(exp, "gpm"):
        raise ConfigError(f"sweep: {getattr(exp, 'name', exp)!r} is not a TITO experiment "
                          f"([plant] model = 'tito' or 'two_tank_nonlinear')")
    cases = tuple(exp.cases if cases is None else cases)
    for case in cases:
        if case not in exp.cases:
            raise ConfigError(f"sweep: unknown case {case!r} for {exp.name}; allowed: {', '.join(exp.cases)}")
    if not (isinstance(max_evals, int) and max_evals >= 1):
        raise ConfigError(f"sweep: max_evals must be an integer >= 1, got {max_evals!r}")
    root = int(exp.config.get("seed", 0) if seed is None else seed)
    if settings is None:
        settings = {"starts": 20} if optimiser == DEFAULT_OPTIMISER else {}
    rows, responses = [], {}
    for case in cases:
        base = exp.problem(case)
        designs = []  # (value, problem that measures it, x, spec, extra)
        if design in ("Am", "phim"):
            for v in vals:
                Am, phim = (v, exp.gpm["phim"]) if design == "Am" else (exp.gpm["Am"], v)
                x = _gpm_x(base, case, Am, phim, f"{param} = {v:g}")
                designs.append((v, base, x, {"Am": Am, "phim": phim, "Mt": math.nan}, {"design": "gpm"}))
        else:
            import heurtune

            probs, found = [], []
            for k, v in enumerate(vals):
                prob = _bandwidth_problem(base, _mt_constraints(exp, v, implied_margins))
                try:
                    res = heurtune.minimize(prob, prob.lower, prob.upper, optimiser, max_evals=max_evals,
                                            seed=np.random.SeedSequence([root, k]), settings=settings)
                except ConfigError as exc:
                    raise ConfigError(f"sweep: case {case!r}, {param} = {v:g}: {exc}") from None
                probs.append(prob)
                found.append((np.asarray(res.x, dtype=np.float64), int(res.n_evals)))
            pool = np.array([x for x, _ in found])
            for k, (v, prob) in enumerate(zip(vals, probs)):
                best = _rank(prob.evaluate(pool))[0]
                c = prob.constraints
                designs.append((v, prob, pool[best], {"Am": c.get("Am", math.nan), "phim": c.get("phim", math.nan),
                                                      "Mt": v},
                                {"design": "bandwidth", "optimiser": optimiser, "n_evals": found[k][1],
                                 "found_at": vals[best]}))
        responses[case] = {}
        for v, prob, x, spec, extra in designs:
            ev = prob.evaluate(x[None, :], "nominal", with_time=True)
            met = dict(zip(ev.metric_names, ev.metrics[0]))
            margins = prob.margins(x)
            df = prob.simulate(x, "nominal")
            responses[case][v] = df
            per = 2 if prob.kind == "pi" else 3
            for i in (1, 2):
                g = x[(i - 1) * per:i * per]
                mg = margins.iloc[i - 1]
                row = dict(experiment=exp.name, case=case, param=param, design_param=design, value=v, loop=i,
                           controller=prob.kind, Kp=float(g[0]), Ki=float(g[1]), Kd=float(g[2]) if per == 3 else 0.0,
                           Am_spec=spec["Am"], phim_spec=spec["phim"], Mt_spec=spec["Mt"],
                           gain_margin=float(mg["gain_margin"]), phase_margin_deg=float(mg["phase_margin_deg"]),
                           w_pc=float(mg["w_pc"]), w_gc=float(mg["w_gc"]))
                for key in ("Mt", "Ms", "w_b", "IAE", "ISE", "ITAE"):
                    row[key] = float(met[f"{key}{i}"])
                for wname in prob.windows:
                    for key in ("IAE", "ISE", "ITAE"):
                        row[f"{key}_{wname}"] = float(met[f"{key}_{wname}{i}"])
                row.update(status=df.attrs.get("status", "ok"), stable=ev.reason[0] != "unstable",
                           feasible=bool(ev.feasible[0]) if extra["design"] == "bandwidth" else None,
                           reason=ev.reason[0])
                row.update(extra)
                rows.append(row)
    table = pd.DataFrame(rows)
    if "feasible" in table:
        table["feasible"] = table["feasible"].astype("boolean")
    return table, responses


def sweep_figure(responses: dict, path, *, param: str, title: str = "") -> None:
    """Outputs ``y1`` and ``y2`` with their set-points, one line per value of the swept parameter.

    Parameters
    ----------
    responses : dict
        ``{value: DataFrame}`` with columns ``t, r1, r2, y1, y2`` (one case of
        :func:`sweep_designs`).
    path : str or Path
        The PNG file (written atomically).
    param : str
        The parameter's name, for the legend.
    title : str
        The figure's title.
    """
    import matplotlib

    from heurtune.analysis.figures import new_figure
    from heurtune.core.io import atomic_path

    fig, axes = new_figure(2, 1, figsize=(9, 6.5), sharex=True)
    cmap = matplotlib.colormaps["viridis"]
    n = len(responses)
    label = LABELS.get(param, param)
    for k, (v, df) in enumerate(responses.items()):
        color = cmap(0.9 * k / max(1, n - 1))
        for i, ax in enumerate(axes, start=1):
            ax.plot(df["t"], df[f"y{i}"], color=color, lw=1.3, label=f"{label} = {v:g}")
    first = next(iter(responses.values()))
    for i, ax in enumerate(axes, start=1):
        ax.plot(first["t"], first[f"r{i}"], color="k", ls="--", lw=0.9, label=f"set-point r{i}")
        ax.set_ylabel(f"output y{i} (plant units)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    axes[1].set_xlabel("time t (s)")
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, format="png")


def run_sweep(exp, param: str, values, out_dir, *, cases=None, figures: bool = True, **options) -> list:
    """:func:`sweep_designs`, then write ``sweep_<param>.parquet`` and one
    ``sweep_<param>_<case>.png`` per case to ``out_dir``.

    Parameters
    ----------
    exp : TITOExperiment
    param : str
        See :func:`sweep_designs`.
    values : sequence of float or str
    out_dir : str or Path
        The folder (created if missing).
    cases : sequence of str, optional
    figures : bool
        Also draw the figures.
    **options
        ``optimiser``, ``max_evals``, ``settings``, ``seed``, ``implied_margins`` of
        :func:`sweep_designs`.

    Returns
    -------
    list of Path
        The files written.
    """
    from heurtune.core.io import check_output_folder, write_parquet

    out_dir = check_output_folder(out_dir, "out")
    table, responses = sweep_designs(exp, param, values, cases=cases, **options)
    written = [out_dir / f"sweep_{param}.parquet"]
    write_parquet(table, written[0])
    if figures:
        for case, resp in responses.items():
            path = out_dir / f"sweep_{param}_{_slug(case)}.png"
            spec = "GPM design" if ALIASES.get(param, param) in ("Am", "phim") else "bandwidth design"
            sweep_figure(resp, path, param=param, title=f"{exp.name} / {case}: {spec}, nominal response")
            written.append(path)
    return written


def _parser() -> argparse.ArgumentParser:
    from heurtune.core.cli import exit_codes

    ap = argparse.ArgumentParser(prog="python -m heurtune.objectives.tito.sweep",
                                 description="Sweep a TITO design parameter and draw the family of responses.",
                                 epilog=exit_codes())
    ap.add_argument("experiment", help="TITO experiment name (experiments/<name>.toml) or a .toml path")
    ap.add_argument("--param", required=True, help=f"the design parameter: {_allowed()}")
    ap.add_argument("--values", required=True, help="comma-separated values, e.g. 2,3,4")
    ap.add_argument("--cases", help="comma-separated cases (default: all of the experiment's)")
    ap.add_argument("--out", help="output folder (default results/<experiment>)")
    ap.add_argument("--optimiser", default=DEFAULT_OPTIMISER,
                    help=f"optimiser of the bandwidth design, Mt / gamma_m only (default {DEFAULT_OPTIMISER})")
    ap.add_argument("--max-evals", type=int, default=DEFAULT_MAX_EVALS,
                    help=f"its evaluations per value (default {DEFAULT_MAX_EVALS})")
    ap.add_argument("--seed", type=int, help="root seed of the searches (default: the experiment's)")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    ap.add_argument("--implied-margins", action="store_true",
                    help="Mt sweeps: the margins Mt implies (paper 000 eq. 25-26), not the experiment's")
    return ap


def run(argv=None) -> int:
    """Entry point of ``python -m heurtune.objectives.tito.sweep``; returns the exit code.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        0 when done, 2 after a one-line error on stderr.
    """
    args = _parser().parse_args(argv)
    try:
        from heurtune.core.errors import DesignError
        from heurtune.runner.config import load_experiment

        check_sweep(args.param, args.values)
        exp = load_experiment(args.experiment)
        cases = None if args.cases is None else [c.strip() for c in args.cases.split(",") if c.strip()]
        out = Path(args.out) if args.out else Path("results") / exp.name
        written = run_sweep(exp, args.param, args.values, out, cases=cases, figures=not args.no_figures,
                            optimiser=args.optimiser, max_evals=args.max_evals, seed=args.seed,
                            implied_margins=args.implied_margins)
    except (ConfigError, DesignError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    table = pd.read_parquet(written[0])
    cols = ["case", "value", "loop", "Kp", "Ki", "Kd", "gain_margin", "phase_margin_deg", "Mt", "IAE"]
    with pd.option_context("display.width", 200, "display.float_format", "{:.4g}".format):
        print(table[cols].to_string(index=False))
    for path in written:
        print(f"written: {path}")
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    from heurtune import _startup

    _startup.release()
    sys.exit(_startup.run_command(run))


if __name__ == "__main__":
    main()
