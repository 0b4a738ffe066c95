"""Result figures: convergence curves, final-objective box plots, closed-loop responses.

Every figure is a :class:`matplotlib.figure.Figure` of its own with an Agg canvas
(:func:`new_figure`: no display needed, and pyplot's backend, a notebook's say, is never switched
or touched), written through :func:`heurtune.core.io.atomic_path`, so a figure file is either
complete or absent.

Examples
--------
>>> from heurtune.analysis.figures import convergence_figure, boxplot_figure    # doctest: +SKIP
>>> convergence_figure(history, "results/convergence.png")             # doctest: +SKIP
>>> boxplot_figure(runs, "results/final_objective.png")                # doctest: +SKIP
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from heurtune.analysis.colours import colours_of
from heurtune.core.errors import ConfigError
from heurtune.core.io import atomic_path
from heurtune.core.problem import DEFAULT_SIGNAL_LABELS, RANGE_RTOL

if TYPE_CHECKING:
    from heurtune.analysis.stats import FriedmanResult

__all__ = ["convergence_figure", "boxplot_figure", "response_figure", "plot_responses", "pareto_figure",
           "new_figure", "algorithm_colors", "FAILED_THRESHOLD", "cd_diagram", "best_f_axis", "shown_best_f",
           "HYPERVOLUME_LABEL"]

# Objective values at or above this are the problem's failure sentinel (FAILED_OBJECTIVE = 1e10,
# see heurtune.objectives.qtp.problem): they are left out of medians and boxes, which they would otherwise swamp.
FAILED_THRESHOLD = 1.0e10
DPI = 110
# Line style of each scenario of a response figure, in turn (solid, dashed, dotted, dash-dot).
SCENARIO_STYLES = ("-", "--", ":", "-.")


def _needs_log(values) -> bool:
    """Log axis when every value is positive and they span more than two decades."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return bool(v.size and v.min() > 0 and v.max() / v.min() > 100.0)


def new_figure(nrows: int = 1, ncols: int = 1, *, figsize=None, layout=None, **subplots):
    """A figure and its axes, as pyplot's ``subplots`` gives them, without pyplot.

    Parameters
    ----------
    nrows, ncols : int
        The grid of axes.
    figsize : (float, float), optional
        Width and height in inches.
    layout : str, optional
        Matplotlib's layout engine (``"constrained"``, ``"tight"``).
    **subplots
        Passed to :meth:`matplotlib.figure.Figure.subplots` (``sharex``, ``squeeze``, ...).

    Returns
    -------
    fig : matplotlib.figure.Figure
        With an Agg canvas of its own: it draws and saves without a display and leaves the
        backend of pyplot (a notebook's, say) as it was; nothing needs closing.
    axes : Axes or array of Axes
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout=layout)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **subplots)


def _panel_grid(n: int, width: float = 5.2, height: float = 3.8, max_cols: int = 3):
    cols = min(n, max_cols)
    rows = math.ceil(n / cols)
    fig, axes = new_figure(rows, cols, figsize=(width * cols, height * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:n])


def _save(fig, path) -> None:
    """Write ``fig`` atomically in the format its name says (PNG for any other name)."""
    fig.tight_layout()
    fmt = Path(path).suffix.lower().lstrip(".")
    if fmt not in fig.canvas.get_supported_filetypes():
        fmt = "png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, format=fmt)


def _require(df: pd.DataFrame, cols, what: str) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise ValueError(f"{what} needs column(s) {', '.join(missing)}; got {', '.join(map(str, df.columns))}")


def algorithm_colors(algorithms) -> dict:
    """One colour per algorithm label, the same in every figure and report: a name's colour
    does not depend on the others present (:mod:`heurtune.analysis.colours`).

    Parameters
    ----------
    algorithms : iterable of str
        The labels (repeats are fine).

    Returns
    -------
    dict
        Label to an RGBA colour.
    """
    return colours_of(map(str, algorithms))


def _empty_reason(failures) -> str:
    """Why a convergence panel has nothing to draw, from the failed runs' reasons."""
    reasons = [r for r in (failures if failures is not None else []) if r]
    if not reasons:
        return "median not finite: most runs found\nno stable, simulable candidate"
    counts = pd.Series(reasons).value_counts()
    if len(counts) == 1:
        return f"no line: {counts.iloc[0]} runs failed,\nevery best candidate {counts.index[0]}"
    return "no line: runs failed, best candidates\n" + ", ".join(f"{n} {r}" for r, n in counts.items())


# The axis of a multi-objective problem's best_f, shown as the hypervolume it is minus of.
HYPERVOLUME_LABEL = "hypervolume of the front (higher is better)"


def best_f_axis(prob) -> tuple:
    """How a figure shows ``best_f`` of ``prob``: ``(label, sign)``, the axis label and the
    factor that turns ``best_f`` into what the label names. One objective: its label with its
    unit (None where the family gives none) and 1; several: :data:`HYPERVOLUME_LABEL` and -1
    (``best_f`` is minus the front's hypervolume).

    Parameters
    ----------
    prob : TuningProblem

    Returns
    -------
    tuple of (str or None, float)
    """
    if getattr(prob, "objective_names", None):
        return HYPERVOLUME_LABEL, -1.0
    return getattr(prob, "objective_label", None), 1.0


def shown_best_f(frame: pd.DataFrame, sign: float) -> pd.DataFrame:
    """``frame`` with its ``best_f`` as :func:`best_f_axis`'s label names it (times ``sign``);
    failure placeholders (at or above :data:`FAILED_THRESHOLD`) kept, so the figures still tell
    them apart.

    Parameters
    ----------
    frame : pandas.DataFrame
        With a ``best_f`` column (runs or history).
    sign : float

    Returns
    -------
    pandas.DataFrame
    """
    if sign > 0:
        return frame
    f = frame["best_f"].astype(float)
    return frame.assign(best_f=f.where(f >= FAILED_THRESHOLD, sign * f))


def convergence_figure(history: pd.DataFrame, path, case=None, *, failures=None, ylabel=None) -> None:
    """Median best objective per epoch with its inter-quartile band (thesis Figs 5.4-5.5).

    One PNG with one panel per case (side by side, at most three per row), one line per
    algorithm: the median over runs of ``best_f`` against ``epoch``, shaded between the 25th and
    75th percentiles. When the algorithms of a case spend different numbers of evaluations per
    epoch (e.g. CS 50, FF 100), the x axis is the number of evaluations instead, so that equal
    abscissas mean equal work, and each algorithm's line ends where its budget ends.

    Runs of different lengths are aligned on the union of the case's epochs: each run's
    ``best_f`` is carried forward from its last recorded epoch (a stopped run keeps its final
    best), and a run contributes nothing before its first recorded epoch. Values at or above
    ``FAILED_THRESHOLD`` (the failure sentinel of a run with no simulable candidate yet) rank as
    +inf; epochs whose median is not finite are not drawn. The y-axis of a panel is logarithmic when
    all its plotted values are positive
    and span more than two decades.

    Parameters
    ----------
    history : pandas.DataFrame
        Columns ``case, algorithm, run, epoch, best_f`` (others, e.g. ``n_evals``, ignored).
    path : str or Path
        PNG written atomically.
    case : str or sequence of str, optional
        Only these cases (default: every case, in order of appearance).
    failures : dict, optional
        Per case, the failure reasons of its failed runs (``runs.parquet``'s ``failure``), so
        that a panel with nothing to draw says why (e.g. "every best candidate unstable").
    ylabel : str, optional
        The objective with its unit (default "best objective").

    Raises
    ------
    ValueError
        A required column is missing, or no rows are left for the selected cases.
    """
    _require(history, ("case", "algorithm", "run", "epoch", "best_f"), "convergence_figure")
    cases = list(pd.unique(history["case"])) if case is None else (
        [case] if isinstance(case, str) else list(case))
    data = history[history["case"].isin(cases)]
    if data.empty:
        raise ValueError(f"convergence_figure: no history rows for case(s) {', '.join(map(str, cases))}")
    colors = algorithm_colors(data["algorithm"])
    fig, axes = _panel_grid(len(cases))
    for ax, name in zip(axes, cases):
        d = data[data["case"] == name]
        x = _x_axis(d)
        epochs = np.sort(pd.unique(d[x]))
        plotted = []
        for alg, g in d.groupby("algorithm", sort=False):
            # A failed best (the sentinel) ranks worst, as +inf: the median stays an order
            # statistic over all runs, so it never rises when a run finds its first candidate.
            f = g["best_f"].astype(float).where(lambda s: s < FAILED_THRESHOLD, np.inf)
            # On evaluations each algorithm spans its own budget (no flat tail past its end).
            grid = epochs if x == "epoch" else np.sort(pd.unique(g[x]))
            wide = (g.assign(best_f=f).pivot_table(index=x, columns="run", values="best_f",
                                                   aggfunc="last", dropna=False)
                    .reindex(grid).ffill())
            vals = wide.to_numpy()
            with np.errstate(all="ignore"):
                q25, q50, q75 = np.nanpercentile(vals, [25, 50, 75], axis=1)
            ok = np.isfinite(q50)
            if not ok.any():
                continue
            q25, q50, q75 = q25[ok], q50[ok], np.where(np.isfinite(q75[ok]), q75[ok], np.nan)
            n_runs = wide.shape[1]
            ax.plot(grid[ok], q50, color=colors[alg], lw=1.6, label=f"{alg} (n={n_runs})")
            ax.fill_between(grid[ok], q25, q75, color=colors[alg], alpha=0.2, lw=0)
            plotted.append(np.concatenate([q25, q75[np.isfinite(q75)]]))
        ax.grid(alpha=0.3)
        if not plotted:
            ax.text(0.5, 0.5, _empty_reason((failures or {}).get(name)),
                    ha="center", va="center", transform=ax.transAxes, fontsize=9)
        if plotted and _needs_log(np.concatenate(plotted)):
            ax.set_yscale("log")
            ax.grid(alpha=0.1, which="minor")
        ax.set_title(f"case {name}")
        ax.set_xlabel("epoch" if x == "epoch" else "evaluations")
        ax.set_ylabel(f"{ylabel or 'best objective'} (median, IQR band)")
        if plotted:
            ax.legend(fontsize=8)
    _save(fig, path)


def _x_axis(history: pd.DataFrame) -> str:
    """``"epoch"``, or ``"n_evals"`` when the algorithms of a case spend different numbers of
    evaluations per epoch (CS 2n, FF n^2 ...): then epochs would compare unequal work."""
    if "n_evals" not in history or history["algorithm"].nunique() < 2:
        return "epoch"
    per_epoch = history.groupby(["algorithm", "epoch"])["n_evals"].median().unstack("algorithm")
    common = per_epoch.dropna()
    return "epoch" if len(common) and (common.nunique(axis=1) == 1).all() else "n_evals"


def boxplot_figure(runs: pd.DataFrame, path, metric: str = "best_f", *, ylabel: str | None = None) -> None:
    """Box plots of the final objective per algorithm, one panel per case.

    Each box summarises the runs whose ``metric`` is finite and below ``FAILED_THRESHOLD``
    (whiskers at 1.5 IQR); the individual runs are overlaid as points, feasible ones as dots
    and infeasible ones as red crosses, and every tick label gives the number of runs and of
    infeasible runs. The y-axis of a panel is logarithmic when all its values are positive and
    span more than two decades.

    Parameters
    ----------
    runs : pandas.DataFrame
        Columns ``case, algorithm, run, feasible`` and ``metric``.
    path : str or Path
        PNG written atomically.
    metric : str
        Column to plot (default ``best_f``); lower is better.
    ylabel : str, optional
        What ``metric`` is, with its unit (the problem's ``objective_label``); default
        ``"final <metric>"``.

    Raises
    ------
    ValueError
        A required column is missing or ``runs`` is empty.
    """
    _require(runs, ("case", "algorithm", "run", "feasible", metric), "boxplot_figure")
    if runs.empty:
        raise ValueError("boxplot_figure: no runs")
    cases = list(pd.unique(runs["case"]))
    colors = algorithm_colors(runs["algorithm"])
    rng = np.random.default_rng(0)  # jitter of the overlaid points: deterministic figures
    fig, axes = _panel_grid(len(cases), width=max(4.5, 1.1 * runs["algorithm"].nunique() + 2))
    for ax, name in zip(axes, cases):
        d = runs[runs["case"] == name]
        algs = list(pd.unique(d["algorithm"]))
        boxes, labels, shown = [], [], []
        for k, alg in enumerate(algs, start=1):
            g = d[d["algorithm"] == alg]
            v = g[metric].astype(float).to_numpy()
            feas = g["feasible"].astype(bool).to_numpy()
            ok = np.isfinite(v) & (v < FAILED_THRESHOLD)
            # the counts of compare's table: a failed run (no stable, simulable candidate) is
            # not an infeasible one
            failed = (g["status"] == "failed").to_numpy() if "status" in g else ~ok
            boxes.append(v[ok])
            shown.append(v[ok])
            labels.append(f"{alg}\nn={len(g)}, failed={int(failed.sum())}, infeas.={int((~feas & ~failed).sum())}")
            xj = k + rng.uniform(-0.15, 0.15, size=len(v))
            ax.scatter(xj[ok & feas], v[ok & feas], s=12, color=colors[alg], alpha=0.7, zorder=3)
            ax.scatter(xj[ok & ~feas], v[ok & ~feas], s=22, marker="x", color="red", zorder=4)
        ax.boxplot(boxes, positions=range(1, len(algs) + 1), widths=0.55, showfliers=False,
                   medianprops=dict(color="black", lw=1.5))
        # beyond four algorithms the three-line labels would run into each other: upright
        slant = dict(rotation=90, ha="center") if len(algs) > 4 else {}
        ax.set_xticks(range(1, len(algs) + 1), labels, fontsize=8, **slant)
        ax.grid(alpha=0.3, axis="y")
        if not any(len(v) for v in shown):  # every run failed: say so rather than draw empty axes
            ax.text(0.5, 0.5, "no run has a finite value below the failure placeholder:\nevery run failed",
                    ha="center", va="center", transform=ax.transAxes, fontsize=9)
        elif _needs_log(np.concatenate(shown)):
            ax.set_yscale("log")
            ax.grid(alpha=0.1, axis="y", which="minor")
        ax.set_title(f"case {name}")
        ax.set_ylabel(f"final {ylabel}" if ylabel else f"final {metric}")
    _save(fig, path)


def response_figure(problem, x, path, scenarios=("nominal", "-30%", "+30%"), title: str = "",
                    tlim=None) -> None:
    """Closed-loop response of one candidate under several scenarios (thesis Figs 5.14-5.25).

    Simulates ``x`` under each scenario (``problem.simulate``) and draws it with
    :func:`plot_responses`, with the problem's :meth:`~heurtune.core.problem.TuningProblem.physical_limits`
    and :attr:`~heurtune.core.problem.TuningProblem.signal_labels`.

    Parameters
    ----------
    problem : heurtune.core.problem.TuningProblem
    x : array_like or dict
        Tuning values (see ``problem.names``).
    path : str or Path
        PNG written atomically.
    scenarios : sequence of str or scenario objects
        Scenario names of ``problem.scenarios`` (or scenario objects, labelled by their
        uncertainty factor when they have one).
    title : str
        Figure title; default ``"<case> / <controller>"``.
    tlim : (float, float), optional
        Time window in s to draw (e.g. ``(40, 150)`` to zoom on the disturbance response);
        default the whole horizon.

    Raises
    ------
    ControllerDesignError
        The controller cannot be designed for ``x`` (QTP).
    ConfigError
        An unknown scenario name.
    """
    frames = []
    for sc in scenarios:
        label = sc if isinstance(sc, str) else f"x{problem.scenario(sc).uncertainty:g}"
        df = problem.simulate(x, sc)
        if tlim is not None:
            df = df[(df["t"] >= tlim[0]) & (df["t"] <= tlim[1])]
        frames.append(df.assign(scenario=label))
    traj = pd.concat(frames, ignore_index=True)
    plot_responses(traj, path, title=title or f"{problem.case} / {problem.controller}",
                   limits=problem.physical_limits(), labels=problem.signal_labels)


OUTSIDE = "outside physical range"


def _outside(values, lo, hi) -> bool:
    """True when a finite value lies below ``lo`` or above ``hi`` by more than the tolerance."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return False
    tol = RANGE_RTOL * max(abs(lo), abs(hi), 1.0)
    return bool(v.min() < lo - tol or v.max() > hi + tol)


def _draw_limits(ax, lo, hi, label):
    """Dashed lines at ``lo`` and ``hi`` that do not rescale the panel.

    The view stays on the response: a limit that the response approaches or crosses is drawn
    and named in the legend; limits both off the panel's scale are named in its title
    instead (a legend entry for a line one cannot see would mislead).
    """
    ylim = ax.get_ylim()
    visible = any(ylim[0] <= v <= ylim[1] for v in (lo, hi))
    ax.axhline(lo, color="0.35", lw=0.9, ls=(0, (5, 3)), label=label if visible else None)
    ax.axhline(hi, color="0.35", lw=0.9, ls=(0, (5, 3)))
    ax.set_ylim(ylim)
    if not visible:
        ax.set_title(f"{ax.get_title()} (limits off scale: {label.split(': ', 1)[-1]})", fontsize=10)


def _signal_numbers(df: pd.DataFrame, prefix: str) -> list:
    """The numbers ``i`` of the columns ``<prefix><i>`` of ``df`` (``y1, y2, y3`` -> 1, 2, 3), sorted."""
    found = (re.fullmatch(rf"{prefix}(\d+)", str(c)) for c in df.columns)
    return sorted(int(m.group(1)) for m in found if m)


def _input_ranges(limits: dict, inputs: list) -> dict:
    """``limits["u"]``, one (lo, hi) for every input or one per input, as ``{input: (lo, hi)}``."""
    u = limits["u"]
    if len(u) == 2 and all(np.isscalar(v) for v in u):
        return {j: (float(u[0]), float(u[1])) for j in inputs}
    return {j: (float(u[j - 1][0]), float(u[j - 1][1])) for j in inputs}


# A response drawn with more rows than this per scenario keeps, in each of DRAWN_BUCKETS equal
# runs of rows, the first and last row and those where a drawn signal is smallest or largest:
# every extreme and every step stays in the figure, and matplotlib lays out and rasterises a
# few thousand points instead of the 50,000 of a 1000 s horizon at 0.02 s (a paper's
# response figures took 25 s of its smoke run).
DRAWN_BUCKETS = 1000


def _drawn_rows(df, columns):
    """The rows of one scenario's trajectory that its figure draws (see DRAWN_BUCKETS)."""
    n = len(df)
    if n <= 4 * DRAWN_BUCKETS or not columns:
        return df
    values = df[columns].to_numpy(dtype=float)
    low = np.where(np.isnan(values), np.inf, values)
    high = np.where(np.isnan(values), -np.inf, values)
    edges = np.linspace(0, n, DRAWN_BUCKETS + 1).astype(int)
    keep = [edges[:-1], edges[1:] - 1]
    for lo, hi in zip(edges[:-1], edges[1:]):
        keep.append(lo + np.argmin(low[lo:hi], axis=0))
        keep.append(lo + np.argmax(high[lo:hi], axis=0))
    return df.iloc[np.unique(np.concatenate(keep))]


def plot_responses(traj, path, title: str = "", limits=None, labels=None) -> None:
    """Outputs (with set-points and internal levels when recorded) and inputs per scenario.

    The grid has the outputs in its first row and the inputs in its second, as many columns
    as the larger of the two counts (a family of two inputs and two outputs gets 2 x 2).

    Parameters
    ----------
    traj : pandas.DataFrame
        Columns ``scenario, t``, the outputs ``y1 .. ym`` and the inputs ``u1 .. un``; optional
        ``r1 .. rm`` (set-points, drawn black dashed for the first scenario) and ``h1 ..``
        (true levels: ``h_i`` thin and pale beside the measured ``y_i``). Each scenario has its
        own colour and line style (:data:`SCENARIO_STYLES`), so that scenarios whose responses
        overlap stay apart.
    path : str or Path
        PNG written atomically.
    title : str
        Figure title.
    limits : dict, optional
        :meth:`~heurtune.core.problem.TuningProblem.physical_limits`: ``"y"`` one (lo, hi) per
        output, ``"u"`` one (lo, hi) for every input or one per input, ``"h"`` one range per
        recorded level. Drawn as dashed lines; a panel whose trajectory leaves its range says
        so in its title, and the figure title names the scenarios that leave any range.
    labels : dict, optional
        :attr:`~heurtune.core.problem.TuningProblem.signal_labels` (panel names and units).
    """
    lab = {**DEFAULT_SIGNAL_LABELS, **(labels or {})}
    outputs, inputs = _signal_numbers(traj, "y"), _signal_numbers(traj, "u")
    ncol = max(len(outputs), len(inputs), 1)
    fig, axes = new_figure(2, ncol, figsize=(6.8 * ncol, 7), sharex=True, squeeze=False)
    out_ax = {i: axes[0, k] for k, i in enumerate(outputs)}
    in_ax = {j: axes[1, k] for k, j in enumerate(inputs)}
    for ax in list(axes[0, len(outputs):]) + list(axes[1, len(inputs):]):
        ax.set_visible(False)
    drawn = [c for c in traj.columns if c != "scenario" and c != "t" and c[:1] in "yhur" and c[1:].isdigit()]
    for k, (name, df) in enumerate(traj.groupby("scenario", sort=False)):
        df = _drawn_rows(df, drawn)
        style = SCENARIO_STYLES[k % len(SCENARIO_STYLES)]  # scenarios that overlap stay apart
        for i, ax in out_ax.items():
            line, = ax.plot(df["t"], df[f"y{i}"], lw=1.2, ls=style, label=f"{name}: y{i}")
            if f"h{i}" in df:
                ax.plot(
                    df["t"], df[f"h{i}"], lw=0.7, ls=style, alpha=0.5, color=line.get_color(), label=f"{name}: h{i}"
                )
            if k == 0 and f"r{i}" in df:
                ax.plot(df["t"], df[f"r{i}"], "k--", lw=0.8, label="set-point")
        for j, ax in in_ax.items():
            ax.plot(df["t"], df[f"u{j}"], lw=1.2, ls=style, label=name)
    for i, ax in out_ax.items():
        ax.set_title(f"{lab['output']} {i}", fontsize=10)
    for j, ax in in_ax.items():
        ax.set_title(f"{lab['input']} {j}", fontsize=10)
    if limits:
        u_range = _input_ranges(limits, inputs)
        for i, ax in out_ax.items():
            y_lo, y_hi = limits["y"][i - 1]
            # the true level when recorded (the measured one carries the output disturbance)
            level = traj[f"h{i}"] if f"h{i}" in traj else traj[f"y{i}"]
            _draw_limits(ax, y_lo, y_hi, f"{lab['output']} {i}: {y_lo:g} and {y_hi:g} {lab['y_unit']}".rstrip())
            if _outside(level, y_lo, y_hi):
                ax.set_title(f"{lab['output']} {i}: {OUTSIDE}", fontsize=10)
        for j, ax in in_ax.items():
            u_lo, u_hi = u_range[j]
            _draw_limits(ax, u_lo, u_hi, f"{lab['input']} range {u_lo:g} to {u_hi:g} {lab['u_unit']}".rstrip())
            if _outside(traj[f"u{j}"], u_lo, u_hi):
                ax.set_title(f"{lab['input']} {j}: {OUTSIDE}", fontsize=10)
        levels = limits.get("h", limits["y"])
        leaving = []
        for name, df in traj.groupby("scenario", sort=False):
            tanks = [j for j in range(1, len(levels) + 1) if f"h{j}" in df] or outputs
            out = any(_outside(df[f"h{j}"] if f"h{j}" in df else df[f"y{j}"], *levels[j - 1]) for j in tanks)
            out = out or any(_outside(df[f"u{j}"], *u_range[j]) for j in inputs)
            if out:
                leaving.append(str(name))
        if leaving:
            title = f"{title}\n{OUTSIDE}: {', '.join(leaving)}" if title else f"{OUTSIDE}: {', '.join(leaving)}"
    for i, ax in out_ax.items():
        ax.set_ylabel(lab["y_label"].format(i=i))
    for j, ax in in_ax.items():
        ax.set_ylabel(lab["u_label"].format(i=j))
        ax.set_xlabel("t (s)")
    for ax in list(out_ax.values()) + list(in_ax.values()):
        # beside the panel, never over its traces
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)


def pareto_figure(fronts, path, objectives, title: str = "", *, axis_labels=None) -> None:
    """The final fronts of several runs in the plane of the first two objectives.

    Parameters
    ----------
    fronts : pandas.DataFrame
        Rows of ``pareto.parquet`` (one front per ``algorithm`` and ``run``) with columns
        ``f_<objective>``, ``feasible`` and ``chosen``.
    path : str or Path
        PNG written atomically.
    objectives : sequence of str
        The objective names; the first two are drawn.
    title : str
        Figure title.
    axis_labels : sequence of str, optional
        The objectives with their units (the problem's ``objective_axis_label``); default the
        names.
    """
    fig, ax = new_figure(figsize=(6.5, 5))
    a, b = (f"f_{name}" for name in objectives[:2])
    colors = algorithm_colors(fronts["algorithm"])
    for (alg, run), front in fronts.groupby(["algorithm", "run"], sort=False):
        front = front.sort_values(a)
        ok = front["feasible"].to_numpy(bool)
        line, = ax.plot(front[a][ok], front[b][ok], marker=".", lw=0.8, label=f"{alg} (run {run})",
                        color=colors[str(alg)])
        if (~ok).any():
            ax.plot(front[a][~ok], front[b][~ok], "x", color=line.get_color(), label=f"{alg}: infeasible")
        chosen = front[front["chosen"]]
        ax.plot(chosen[a], chosen[b], "*", ms=14, color=line.get_color(), markeredgecolor="k",
                label=f"{alg}: chosen")
    labels = list(axis_labels) if axis_labels is not None else list(objectives)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    _save(fig, path)


def cd_diagram(result: FriedmanResult, path) -> Path:
    """Draw the critical-difference diagram of a Friedman/Nemenyi result as a PNG.

    Uses ``scikit_posthocs.critical_difference_diagram`` (mean ranks on the axis, algorithms
    not significantly different by Nemenyi's test joined by a bar) on a matplotlib Agg figure,
    with the critical difference drawn above the axis; the file is written atomically.

    Parameters
    ----------
    result : FriedmanResult
        Output of :func:`heurtune.analysis.stats.friedman_across_cases` that was not skipped.
    path : str or Path
        The PNG file to write (folders are created).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ConfigError
        The Friedman test was skipped, so there is no diagram to draw.
    """
    import scikit_posthocs as sp
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if result.skipped:
        raise ConfigError(f"no critical-difference diagram: Friedman test skipped ({result.skipped})")
    fig = Figure(figsize=(6.4, 0.6 + 0.35 * len(result.mean_ranks)))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    # the algorithms' colours of every other figure (the library's own palette otherwise)
    sp.critical_difference_diagram(result.mean_ranks, result.nemenyi, alpha=result.alpha, ax=ax,
                                   color_palette={str(k): v for k, v in colours_of(result.mean_ranks.index).items()})
    if np.isfinite(result.cd):  # drawn here, above the tick labels (the library's bar overlaps them)
        from matplotlib.transforms import blended_transform_factory, offset_copy

        where = offset_copy(blended_transform_factory(ax.transData, ax.transAxes), fig=fig, y=26, units="points")
        x0 = float(result.mean_ranks.min())
        ax.plot([x0, x0 + result.cd], [1.0, 1.0], color="k", linewidth=2, transform=where, clip_on=False)
        ax.text(x0 + result.cd / 2, 1.0, f"CD = {result.cd:.3g}", ha="center", va="bottom", transform=where)
    ax.set_title(f"Mean ranks over {len(result.medians)} cases (Nemenyi, alpha = {result.alpha:g})",
                 fontsize="small", pad=44)
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=150, bbox_inches="tight")
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return path
