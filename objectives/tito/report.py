"""Outputs of TITO experiments: design, robustness and performance tables, figures.

Called by the experiment runner after the runs are gathered (:func:`write_outputs`); the
functions also work on their own, e.g. on a ``runs.parquet`` read back.

The performance table follows the layout of the papers' Tables 1-3: one row per design (each
optimiser's best run and the analytic baselines), per loop the IAE, ISE and ITAE of the
nominal response, and the same per window (servo, regulatory) when the experiment has them.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.core.errors import ConfigError
from heurtune.core.io import atomic_path, write_parquet

__all__ = ["performance_table", "spectral_radius_figure", "write_outputs"]


def performance_table(best: pd.DataFrame, scenario: str = "nominal", windows=()) -> pd.DataFrame:
    """IAE / ISE / ITAE per loop of each design (papers' table layout).

    Parameters
    ----------
    best : DataFrame
        Rows of ``runs.parquet`` (one per design), with the report columns ``IAE1@nominal``...
    scenario : str
        Which scenario's response.
    windows : sequence of str
        Window names (columns ``IAE_<window><loop>@<scenario>``) to add after the whole-horizon
        integrals.

    Returns
    -------
    DataFrame indexed by (case, design) with columns ``(loop, window, metric)``.
    """
    rows, index = [], []
    for _, r in best.iterrows():
        vals = {}
        for loop in (1, 2):
            for win in ("whole",) + tuple(windows):
                for m in ("IAE", "ISE", "ITAE"):
                    key = f"{m}{loop}@{scenario}" if win == "whole" else f"{m}_{win}{loop}@{scenario}"
                    vals[(f"loop {loop}", win, m)] = float(r[key]) if key in r and pd.notna(r[key]) else np.nan
        rows.append(vals)
        design = r["algorithm"] if r.get("stop_reason") == "analytic design" else f"{r['algorithm']} (best of runs)"
        index.append((r["case"], design))
    table = pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["case", "design"]))
    table.columns = pd.MultiIndex.from_tuples(table.columns, names=["loop", "window", "metric"])
    return table


def _markdown(table: pd.DataFrame, title: str) -> str:
    cols = list(table.columns)
    head = "| case | design | " + " | ".join(f"{c[0]} {c[1]} {c[2]}" for c in cols) + " |"
    sep = "| --- | --- | " + " | ".join("---:" for _ in cols) + " |"
    lines = [f"# {title}", "", head, sep]
    empty = False
    for (case, design), row in table.iterrows():
        cells = ["" if not np.isfinite(v) else f"{v:.4g}" for v in row.to_numpy()]
        empty = empty or "" in cells
        lines.append(f"| {case} | {design} | " + " | ".join(cells) + " |")
    if empty:
        lines += ["", "An empty cell: that design has no simulated response (its best run failed or is unstable; "
                  "see the status column of runs.parquet)."]
    return "\n".join(lines) + "\n"


def spectral_radius_figure(results: dict, path, title: str = "", *, failed=()) -> None:
    """``rho(W T(jw))`` for input and output uncertainty, one line per design, with the limit 1.

    ``results`` maps a label to a :class:`~heurtune.objectives.robustness.SpectralRadiusResult`.

    Parameters
    ----------
    results : dict
    path : str or Path
        The PNG file.
    title : str
    failed : collection of str
        Labels of designs whose run failed: drawn dashed (the test presumes a stable loop).
    """
    from heurtune.analysis.colours import colours_of
    from heurtune.analysis.figures import new_figure

    fig, axes = new_figure(1, 2, figsize=(11, 4), sharey=True)
    colours = colours_of(results)
    for label, sr in results.items():
        style = "--" if label in failed else "-"
        axes[0].semilogx(sr.w, sr.rho_input, ls=style, color=colours[label], label=label)
        axes[1].semilogx(sr.w, sr.rho_output, ls=style, color=colours[label], label=label)
    for ax, side in zip(axes, ("input", "output")):
        ax.axhline(1.0, color="k", ls="--", lw=0.8)
        ax.set_xlabel("w (rad/s)")
        ax.set_title(f"multiplicative {side} uncertainty")
    axes[0].set_ylabel("spectral radius rho(W T)")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)


def _accuracy_lines(exp, best: pd.DataFrame) -> str:
    """The performance table's note on how accurately each design was simulated (the
    continuous loop's step and error estimate under the nominal scenario), with a warning on
    stderr for a design whose run missed its tolerance at the finest step; empty on the
    sampled loop."""
    rows = []
    for _, r in best.iterrows():
        prob = exp.problem(r["case"])
        try:
            x = np.array([float(r[n]) for n in prob.names])
        except (KeyError, TypeError, ValueError):
            continue
        if not np.all(np.isfinite(x)):
            continue
        try:
            acc = prob.simulation_accuracy(x, "nominal")
        except ConfigError:
            continue
        if acc is None or acc["status"] != "ok":
            continue
        design = r["algorithm"] if r.get("stop_reason") == "analytic design" else f"{r['algorithm']} (best of runs)"
        rows.append((r["case"], design, acc))
        if not acc["within"]:
            print(f"warning: {exp.name}: {r['case']} {design}: the continuous loop's error estimate "
                  f"{acc['error_estimate']:.3g} exceeds its tolerance {acc['tolerance']:g} even at its finest "
                  f"step ({acc['step']:.3g} s); its metrics are less accurate than stated", file=sys.stderr)
    if not rows:
        return ""
    tolerance = rows[0][2]["tolerance"]
    lines = ["", f"Simulated on the continuous loop to tolerance {tolerance:g} on the outputs (docs/tito.md, "
                 "\"Which loop\"): the step each design's run kept and its error estimate.", "",
             "| case | design | step (s) | error estimate | within the tolerance |",
             "| --- | --- | ---: | ---: | --- |"]
    for case, design, acc in rows:
        lines.append(f"| {case} | {design} | {acc['step']:.4g} | {acc['error_estimate']:.2g} | "
                     f"{'yes' if acc['within'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def _failure_of(row) -> str:
    """The reason a best run failed (``"unstable"``, ...), "" for a run that did not."""
    if str(row.get("status", "")) != "failed":
        return ""
    reason = row.get("failure", "")
    return str(reason) if isinstance(reason, str) and reason else "failed"


def _failed_verdicts(summary: dict, failure: str) -> dict:
    """A failed design's robustness verdicts: not robustly stable. The spectral-radius and
    Kharitonov tests bound how far a *stable* nominal loop may be perturbed; a design whose own
    run failed (an unstable nominal loop, a diverged simulation) passes neither, whatever the
    numbers, and ``robustness_note`` says why."""
    out = dict(summary)
    out["spectral_radius_pass"] = False
    for key in list(out):
        if key.startswith("kharitonov_pass") and out[key] is not None:
            out[key] = False
    out["robustness_note"] = (f"the design's run failed ({failure}): the tests presume a stable nominal loop, so "
                              f"neither passes")
    return out


def _save(fig, path) -> None:
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, format="png")


def write_outputs(exp, runs: pd.DataFrame, best: pd.DataFrame, out_dir: Path, *, figures: bool = True) -> None:
    """``design.parquet``, ``robustness.parquet``, ``performance.{parquet,md}`` and the
    spectral-radius figures of a TITO experiment's best designs.

    Parameters
    ----------
    exp : ExperimentBase
    runs : pandas.DataFrame
        Rows of ``runs.parquet``.
    best : pandas.DataFrame
        The best run of every case and optimiser.
    out_dir : Path
    figures : bool
        Also draw the figures.
    """
    out_dir = Path(out_dir)
    designs, robust = [], []
    spectral, failed = {}, set()
    for case in exp.cases:
        prob = exp.problem(case)
        designs.append(prob.design_table().assign(experiment=exp.name, case=case))
        spectral[case] = {}
        for _, r in best[best["case"] == case].iterrows():
            x = np.array([r[n] for n in prob.names])
            summary, sr = prob.robustness(x)
            failure = _failure_of(r)
            if failure:
                summary = _failed_verdicts(summary, failure)
            robust.append(dict(experiment=exp.name, case=case, algorithm=r["algorithm"], run=int(r["run"]), **summary))
            label = f"{r['algorithm']} (run {int(r['run'])})" + (f", failed: {failure}" if failure else "")
            spectral[case][label] = sr
            if failure:
                failed.add(label)
    lead = ["experiment", "case"]
    d = pd.concat(designs, ignore_index=True)
    write_parquet(d[lead + [c for c in d.columns if c not in lead]], out_dir / "design.parquet")
    if robust:
        write_parquet(pd.DataFrame(robust), out_dir / "robustness.parquet")
    windows = tuple(exp.windows)
    table = performance_table(best, "nominal", windows)
    flat = table.copy()
    flat.columns = [" ".join(c) for c in flat.columns]
    write_parquet(flat.reset_index(), out_dir / "performance.parquet")
    accuracy = _accuracy_lines(exp, best)
    with atomic_path(out_dir / "performance.md") as tmp:
        tmp.write_text(_markdown(table, f"{exp.name}: IAE, ISE, ITAE per loop (nominal plant)") + accuracy)
    if figures:
        for case, results in spectral.items():
            if results:
                slug = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in case)
                spectral_radius_figure(results, out_dir / f"spectral_radius_{slug}.png", failed=failed,
                                       title=f"{exp.name} / {case}: robust stability (weight "
                                             f"{exp.problem(case).robustness_options.get('uncertainty', 0.2):g})")
