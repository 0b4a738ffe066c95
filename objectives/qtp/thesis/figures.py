"""The thesis' figures (Chapters 4-6) redrawn from heurtune's results.

* Response overlays as the thesis draws them: h1, h2, u1, u2 of several designs on one set of
  axes per operating condition (Figs 4.3/4.4: FOLQI, IOLQI and LADR; Chapter 5: CS, APSO, FF per
  controller; Chapter 6: NR, DFP, SD, BFGS per controller), each design being heurtune's best
  tuned run of that case and algorithm.
* Convergence curves: the median best objective per epoch of each algorithm, one panel per case
  (:func:`heurtune.analysis.figures.convergence_figure`, from ``history.parquet``).
* Bode plots (Figs 4.9/4.10): magnitude and phase of the four interaction loops "input i,
  output j" of the best FOLQI design on min and nmp (the loops whose margins
  :func:`heurtune.objectives.qtp.margins.loop_margins` reports), gain crossovers marked.

Every figure is drawn on an Agg canvas of its own (:func:`heurtune.analysis.figures.new_figure`,
pyplot's backend untouched) and written atomically as a PNG.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.analysis.colours import colours_of
from heurtune.analysis.figures import _save, convergence_figure, new_figure
from heurtune.analysis.runs import best_run_index
from heurtune.objectives.qtp.margins import element_loop, frequency_grid, loop_margins
from heurtune.objectives.qtp.structures import controller_label

__all__ = ["response_overlay_figure", "bode_figure", "chapter_figures"]

_CH_ALGS = {5: ("cs", "apso", "firefly"), 6: ("newton_raphson", "dfp", "steepest_descent", "bfgs")}
_LABEL = {"cs": "CS", "apso": "APSO", "firefly": "FF", "newton_raphson": "NR", "dfp": "DFP",
          "steepest_descent": "SD", "bfgs": "BFGS"}
_COND = {"min": "minimum phase", "nmp": "non-minimum phase"}
# The measured levels (the thesis' h1(t), h2(t) under the output disturbance d(t)) and the pumps.
_SIGNALS = ("y1", "y2", "u1", "u2")


def response_overlay_figure(designs: dict, path, scenario: str = "nominal", title: str = "") -> None:
    """h1, h2, u1 and u2 of several designs overlaid, one panel per signal (thesis Figs 4.3/4.4).

    The levels drawn are the measured ones (``y1``, ``y2``: level plus the output disturbance
    d(t)), as the thesis' responses to d(t) show them.

    Parameters
    ----------
    designs : dict of str to (Problem, array_like)
        Legend label to (problem, tuning values). A design that cannot be simulated is left out
        and named in the figure.
    path : str or Path
        PNG written atomically.
    scenario : str
        Scenario simulated (default nominal).
    title : str

    Raises
    ------
    ValueError
        When ``designs`` is empty.
    """
    if not designs:
        raise ValueError("response_overlay_figure: no designs")
    fig, axes = new_figure(2, 2, figsize=(11, 7), sharex=True)
    failed = []
    colours = colours_of(designs)  # CS, FOLQI, ... in their colours of every other figure
    for label, (prob, x) in designs.items():
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                df = prob.simulate(x, scenario, record_levels=True)
        except Exception as exc:  # noqa: BLE001 - an undesignable candidate is named, not drawn
            failed.append(f"{label} ({exc.__class__.__name__})")
            continue
        for ax, col in zip(axes.flat, _SIGNALS):
            src = col if col in df else {"y1": "h1", "y2": "h2"}.get(col, col)
            if src in df:
                ax.plot(df["t"], df[src], lw=1.2, label=label, color=colours[label])
    units = {"y1": "h1, measured (cm)", "y2": "h2, measured (cm)", "u1": "u1 (V)", "u2": "u2 (V)"}
    for ax, col in zip(axes.flat, _SIGNALS):
        ax.set_ylabel(units[col])
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=8)
    if failed:
        axes[0, 1].text(0.02, 0.02, "not simulable: " + ", ".join(failed), transform=axes[0, 1].transAxes,
                        fontsize=7, color="red")
    fig.suptitle(title or f"responses under {scenario}")
    _save(fig, path)


def _loops(problem, x):
    """The four SISO loops whose margins :func:`heurtune.objectives.qtp.margins.loop_margins` reports, keyed
    (input, output): :func:`heurtune.objectives.qtp.margins.element_loop`."""
    return {(i, j): element_loop(problem, x, i, j) for i, j in ((1, 1), (1, 2), (2, 1), (2, 2))}


def bode_figure(problem, x, path, title: str = "", omega=None) -> None:
    """Bode plots of the four interaction loops "input i, output j" (thesis Figs 4.9/4.10).

    Two rows (magnitude in dB, phase in degrees) and four columns, one per loop, each loop being
    the one whose margins :func:`heurtune.objectives.qtp.margins.loop_margins` reports for that pair. Every
    gain crossover found by ``loop_margins`` is marked with a vertical line and its phase margin.

    Parameters
    ----------
    problem : heurtune.Problem
    x : array_like
        Tuning values.
    path : str or Path
        PNG written atomically.
    title : str
    omega : array_like, optional
        Frequencies (rad/s); default :func:`heurtune.objectives.qtp.margins.frequency_grid` of all four loops'
        poles.

    Raises
    ------
    ControllerDesignError
        When the controller cannot be designed for ``x``.
    """
    import control

    loops = _loops(problem, x)
    if omega is None:
        omega = frequency_grid(np.concatenate([control.poles(sys) for sys in loops.values()]))
    omega = np.asarray(omega, dtype=np.float64)
    margins = loop_margins(problem, x)
    fig, axes = new_figure(2, 4, figsize=(16, 6), sharex=True)
    for k, ((i, j), sys) in enumerate(loops.items()):
        resp = control.frequency_response(sys, omega)
        mag = np.asarray(resp.magnitude).ravel()
        phase = np.degrees(np.unwrap(np.asarray(resp.phase).ravel()))
        axes[0, k].semilogx(omega, 20 * np.log10(np.maximum(mag, 1e-300)), lw=1.2)
        axes[1, k].semilogx(omega, phase, lw=1.2)
        axes[0, k].axhline(0.0, color="grey", lw=0.8, ls=":")
        axes[0, k].set_title(f"input {i}, output {j}")
        row = margins[(margins["input"] == i) & (margins["output"] == j)]
        if len(row) and np.isfinite(row["gain_crossover_rad_s"].iloc[0]):
            wgc, pm = row["gain_crossover_rad_s"].iloc[0], row["phase_margin_deg"].iloc[0]
            for ax in axes[:, k]:
                ax.axvline(wgc, color="red", lw=0.9, ls="--")
            axes[0, k].annotate(f"wgc = {wgc:.3g} rad/s\nPM = {pm:.3g} deg", xy=(0.03, 0.05),
                                xycoords="axes fraction", fontsize=8, color="red")
        elif len(row):
            axes[0, k].annotate("no gain crossover", xy=(0.03, 0.05), xycoords="axes fraction", fontsize=8)
        for ax in axes[:, k]:
            ax.grid(alpha=0.3, which="both")
        axes[1, k].set_xlabel("frequency (rad/s)")
    axes[0, 0].set_ylabel("magnitude (dB)")
    axes[1, 0].set_ylabel("phase (deg)")
    fig.suptitle(title or "Bode plots of the interaction loops")
    _save(fig, path)


def _best(runs: pd.DataFrame, case: str, algorithm=None):

    if runs is None or runs.empty or "case" not in runs:
        return None
    g = runs[runs["case"] == case]
    if algorithm is not None:
        g = g[g["algorithm"] == algorithm]
    if g.empty:
        return None
    return g.loc[best_run_index(g)]


def _case(exp, plant, ctrl):
    name = f"{plant}-{ctrl}"
    cases = tuple(getattr(exp, "cases", ()))
    if name in cases:
        return name
    if plant in cases and tuple(getattr(exp, "controllers", ())) == (ctrl,):
        return plant
    return None


def _design(exp, runs, case, algorithm=None):
    b = _best(runs, case, algorithm)
    if b is None or b.get("status") == "failed":  # no stable candidate: nothing to draw
        return None
    prob = exp.problem(case)
    if not all(n in b for n in prob.names):
        return None
    return prob, np.array([float(b[n]) for n in prob.names])


def chapter_figures(chapter: int, exp, out_dir, *, runs=None, history=None) -> list[Path]:
    """Draw a chapter's figures into ``out_dir``; returns the PNGs written.

    Chapter 4: ``figure_4_3_min.png`` / ``figure_4_4_nmp.png`` (FOLQI, IOLQI and LADR best runs
    overlaid, nominal), ``figure_4_9_bode_min.png`` / ``figure_4_10_bode_nmp.png`` (best FOLQI);
    Chapters 5 and 6: ``figure_<ch>_responses_<case>.png`` (the chapter's algorithms overlaid
    per case). Every chapter: ``figure_<ch>_convergence.png`` (one panel per case). Designs or
    data that are missing are skipped.

    Parameters
    ----------
    chapter : {4, 5, 6}
    exp : heurtune.Experiment
    out_dir : str or Path
    runs, history : pandas.DataFrame, optional

    Returns
    -------
    list of pathlib.Path
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if chapter == 4:
        for plant, fig_no in (("min", "4_3"), ("nmp", "4_4")):
            designs = {}
            for ctrl in ("folqi", "iolqi", "ladr"):
                case = _case(exp, plant, ctrl)
                d = _design(exp, runs, case) if case else None
                if d is not None:
                    designs[controller_label(ctrl)] = d
            if designs:
                p = out_dir / f"figure_{fig_no}_{plant}.png"
                response_overlay_figure(
                    designs, p, title=f"Responses under d(t), {_COND[plant]} (heurtune's best runs)"
                )
                written.append(p)
        for plant, fig_no in (("min", "4_9"), ("nmp", "4_10")):
            case = _case(exp, plant, "folqi")
            d = _design(exp, runs, case) if case else None
            if d is not None:
                p = out_dir / f"figure_{fig_no}_bode_{plant}.png"
                try:
                    bode_figure(*d, p, title=f"Bode plots of the best FOLQI loop, {_COND[plant]}")
                    written.append(p)
                except Exception:  # noqa: BLE001 - an undesignable best run has no Bode plot
                    pass
    else:
        for plant in ("min", "nmp"):
            for ctrl in ("iolqi", "folqi"):
                case = _case(exp, plant, ctrl)
                if case is None:
                    continue
                designs = {}
                for alg in _CH_ALGS.get(chapter, ()):
                    d = _design(exp, runs, case, alg)
                    if d is not None:
                        designs[_LABEL[alg]] = d
                if designs:
                    p = out_dir / f"figure_{chapter}_responses_{plant}-{ctrl}.png"
                    response_overlay_figure(
                        designs, p, title=f"{controller_label(ctrl)}, {_COND[plant]}: best run per algorithm"
                    )
                    written.append(p)
    if history is not None and not history.empty and {"case", "algorithm", "run", "epoch", "best_f"} <= set(history):
        p = out_dir / f"figure_{chapter}_convergence.png"
        convergence_figure(history, p)
        written.append(p)
    return written
