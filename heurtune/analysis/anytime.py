"""Anytime performance of tuning runs: fixed-target times, ECDF, ERT and the ECDF's area.

All measures work on a ``history.parquet`` table (one row per run and epoch, with the run's
best-so-far objective ``best_f``, its constraint violation ``best_violation`` and the
evaluations spent so far ``n_evals``). The objective is minimised.

Feasibility
    Before a run has found a feasible candidate its ``best_f`` is the objective of its least
    violating candidate (often the failure sentinel), not a value the run has achieved. An
    epoch counts as *feasible so far* when ``best_violation == 0`` (a table without that column
    is taken as unconstrained); until then the run's best feasible value is ``inf``, so no
    target is reached before the first feasible candidate.

Running time to a target
    A run reaches target ``v`` at the ``n_evals`` of its first epoch whose best feasible value
    is ``<= v``: epochs are the resolution of the logs, so this is an upper bound on the true
    number of evaluations. A run that never reaches ``v`` gets ``inf``; its budget is its last
    ``n_evals``.

Usage::

    python -m heurtune.anytime DIR [--targets N] [--reference VALUE] [--budgets N] [--out OUT]

writes ``anytime_ert.csv``, ``anytime_auc.csv``, ``anytime_ecdf.csv`` and per case
``ecdf_<case>.png`` and ``fixed_target_<case>.png`` to OUT (default DIR). See docs/anytime.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune import _startup
from heurtune.core.cli import exit_codes
from heurtune.core.io import atomic_path

__all__ = ["feasible_best", "default_targets", "fixed_target", "ert", "budget_grid", "ecdf", "ecdf_auc",
           "plot_ecdf", "plot_fixed_target", "write_report", "main"]

# What identifies an optimiser within a case (an algorithm may appear twice with other settings).
_OPT_KEYS = ("experiment", "case", "algorithm", "optimiser_index")


def _keys(df: pd.DataFrame, extra=()) -> list:
    return [k for k in _OPT_KEYS if k in df.columns] + list(extra)


def _check(history: pd.DataFrame, needed=("case", "algorithm", "run", "n_evals", "best_f")):
    missing = [c for c in needed if c not in history.columns]
    if missing:
        raise ValueError(f"history table lacks column(s) {', '.join(missing)}")


def feasible_best(history: pd.DataFrame) -> pd.DataFrame:
    """The history with ``f_feasible``: each run's best feasible objective so far.

    Parameters
    ----------
    history : pandas.DataFrame
        Rows of ``history.parquet``: ``case, algorithm, run, n_evals, best_f`` and, when the
        problem is constrained, ``best_violation`` (optional: ``experiment``,
        ``optimiser_index``).

    Returns
    -------
    pandas.DataFrame
        A copy, sorted by run and ``n_evals``, with column ``f_feasible``: ``best_f`` once
        ``best_violation == 0``, ``inf`` before, made non-increasing within each run.
    """
    _check(history)
    run_keys = _keys(history, ["run"])
    h = history.sort_values(run_keys + ["n_evals"], kind="mergesort").reset_index(drop=True)
    f = h["best_f"].astype(float)
    if "best_violation" in h.columns:
        f = f.where(h["best_violation"].astype(float) == 0.0, np.inf)
    h["f_feasible"] = f.fillna(np.inf).groupby([h[k] for k in run_keys], sort=False).cummin()
    return h


def default_targets(history: pd.DataFrame, n_targets: int = 20, reference=None) -> pd.DataFrame:
    """Targets per case, log-spaced between the best feasible value and a reference value.

    Parameters
    ----------
    history : pandas.DataFrame
        Rows of ``history.parquet``.
    n_targets : int
        Targets per case (>= 1; one target is the best value).
    reference : float or dict of str to float, optional
        The easiest target per case (one value for all cases, or ``{case: value}``). Default:
        the worst of the runs' *first* feasible values in the case, so that every run that
        becomes feasible reaches the easiest target when it does.

    Returns
    -------
    pandas.DataFrame
        Columns ``case, target``: ``n_targets`` values per case from ``reference`` down to the
        best feasible value of any run of the case (both included), equally spaced in
        ``log(target)``. Cases without a feasible value get no targets.

    Raises
    ------
    ValueError
        For ``n_targets < 1``, or for a case whose best value or reference is not positive
        (logarithmic spacing needs positive objectives).
    """
    if n_targets < 1:
        raise ValueError(f"n_targets must be >= 1, got {n_targets}")
    h = feasible_best(history)
    h = h[np.isfinite(h["f_feasible"])]
    rows = []
    for case, g in h.groupby("case", sort=False):
        best = float(g["f_feasible"].min())
        if reference is None:
            ref = float(g.groupby(_keys(g, ["run"]), sort=False)["f_feasible"].first().max())
        elif isinstance(reference, dict):
            if case not in reference:
                raise ValueError(f"no reference value for case {case!r}")
            ref = float(reference[case])
        else:
            ref = float(reference)
        if not (best > 0 and ref > 0):
            raise ValueError(f"case {case!r}: log-spaced targets need positive values, got best {best:g}, "
                             f"reference {ref:g}")
        hi = max(ref, best)
        values = np.geomspace(hi, best, n_targets) if n_targets > 1 else np.array([best])
        values[-1] = best  # exactly the best value, not a rounded one
        rows.append(pd.DataFrame({"case": case, "target": values}))
    if not rows:
        return pd.DataFrame({"case": pd.Series(dtype=object), "target": pd.Series(dtype=float)})
    return pd.concat(rows, ignore_index=True)


def _target_table(targets, cases) -> pd.DataFrame:
    if isinstance(targets, pd.DataFrame):
        if not {"case", "target"} <= set(targets.columns):
            raise ValueError("a targets table needs columns case and target")
        return targets[["case", "target"]].astype({"target": float})
    if isinstance(targets, dict):
        return pd.DataFrame([(c, float(t)) for c, ts in targets.items() for t in np.atleast_1d(ts)],
                            columns=["case", "target"])
    values = np.atleast_1d(np.asarray(targets, dtype=float))
    return pd.DataFrame([(c, t) for c in cases for t in values], columns=["case", "target"])


def fixed_target(history: pd.DataFrame, targets=None, **target_options) -> pd.DataFrame:
    """Evaluations each run needed to reach each target (fixed-target running times).

    Parameters
    ----------
    history : pandas.DataFrame
        Rows of ``history.parquet``.
    targets : sequence of float, dict of str to sequence, or pandas.DataFrame, optional
        The same targets for every case, ``{case: targets}``, or a table with columns
        ``case, target``. Default: :func:`default_targets`.
    **target_options
        Passed to :func:`default_targets` when ``targets`` is None.

    Returns
    -------
    pandas.DataFrame
        One row per run and target: the optimiser's keys (``experiment``, ``case``,
        ``algorithm``, ``optimiser_index`` where present), ``run``, ``target``, ``evals`` (the
        ``n_evals`` of the first epoch whose best feasible value is ``<= target``; ``inf`` when
        never), ``budget`` (the run's last ``n_evals``) and ``reached``.
    """
    h = feasible_best(history)
    run_keys = _keys(h, ["run"])
    tt = _target_table(default_targets(history, **target_options) if targets is None else targets,
                       h["case"].unique())
    out = []
    for keys, g in h.groupby(run_keys, sort=False):
        case = g["case"].iloc[0]
        tv = tt.loc[tt["case"] == case, "target"].to_numpy(dtype=float)
        if tv.size == 0:
            continue
        f = g["f_feasible"].to_numpy(dtype=float)
        n = g["n_evals"].to_numpy(dtype=float)
        # f is non-increasing: the first epoch with f <= t, by a search on -f (non-decreasing)
        first = np.searchsorted(-f, -tv, side="left")
        hit = first < f.size
        evals = np.where(hit, n[np.minimum(first, f.size - 1)], np.inf)
        row = dict(zip(run_keys, keys))
        out.append(pd.DataFrame({**{k: [v] * tv.size for k, v in row.items()}, "target": tv, "evals": evals,
                                 "budget": float(n.max()), "reached": hit}))
    if not out:
        return pd.DataFrame(columns=run_keys + ["target", "evals", "budget", "reached"])
    return pd.concat(out, ignore_index=True)


def ert(ft: pd.DataFrame) -> pd.DataFrame:
    """Expected running time per optimiser and target (Hansen et al., COCO).

    ``ERT(t) = (sum over runs of min(evals, budget)) / (number of runs that reached t)``:
    each successful run adds the evaluations it needed, each unsuccessful run its whole
    budget. ``inf`` when no run reached ``t``.

    Parameters
    ----------
    ft : pandas.DataFrame
        The table of :func:`fixed_target`.

    Returns
    -------
    pandas.DataFrame
        The optimiser's keys, ``target``, ``runs``, ``successes``, ``success_rate``, ``ert``
        and ``evals_spent`` (the numerator).
    """
    keys = _keys(ft, ["target"])
    spent = np.where(ft["reached"].to_numpy(bool), ft["evals"].to_numpy(float), ft["budget"].to_numpy(float))
    d = ft.assign(_spent=spent, _ok=ft["reached"].astype(int))
    g = d.groupby(keys, sort=False).agg(runs=("_ok", "size"), successes=("_ok", "sum"),
                                        evals_spent=("_spent", "sum")).reset_index()
    g["success_rate"] = g["successes"] / g["runs"]
    with np.errstate(divide="ignore", invalid="ignore"):
        g["ert"] = np.where(g["successes"] > 0, g["evals_spent"] / g["successes"].clip(lower=1), np.inf)
    return g[keys + ["runs", "successes", "success_rate", "ert", "evals_spent"]]


def budget_grid(ft: pd.DataFrame, n_budgets: int = 50) -> pd.DataFrame:
    """A log-spaced budget grid per case, shared by all its optimisers.

    From the smallest evaluation count at which any run of the case reached any target (at
    least 1) to the largest run budget of the case.

    Parameters
    ----------
    ft : pandas.DataFrame
        The table of :func:`fixed_target`.
    n_budgets : int
        Budgets per case.

    Returns
    -------
    pandas.DataFrame
        Columns ``case, budget``.
    """
    rows = []
    for case, g in ft.groupby("case", sort=False):
        lo, hi = _budget_range(g)
        values = np.unique(np.geomspace(lo, hi, n_budgets)) if hi > lo else np.array([hi])
        rows.append(pd.DataFrame({"case": case, "budget": values}))
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=["case", "budget"])


def _budget_range(g: pd.DataFrame) -> tuple:
    hi = float(g["budget"].max())
    e = g["evals"].to_numpy(float)
    e = e[np.isfinite(e)]
    lo = max(1.0, float(e.min())) if e.size else 1.0
    return min(lo, hi), hi


def ecdf(ft: pd.DataFrame, budgets=None, n_budgets: int = 50) -> pd.DataFrame:
    """ECDF of running times aggregated over targets (as in IOHanalyzer).

    At budget ``b``, the fraction of (run, target) pairs of an optimiser whose target was
    reached within ``b`` evaluations.

    Parameters
    ----------
    ft : pandas.DataFrame
        The table of :func:`fixed_target`.
    budgets : sequence of float or pandas.DataFrame, optional
        Budgets for every case, or a table ``case, budget``. Default: :func:`budget_grid`.
    n_budgets : int
        Grid size of the default grid.

    Returns
    -------
    pandas.DataFrame
        The optimiser's keys, ``budget`` and ``fraction``.
    """
    grid = budget_grid(ft, n_budgets) if budgets is None else (
        budgets if isinstance(budgets, pd.DataFrame)
        else pd.DataFrame([(c, float(b)) for c in ft["case"].unique() for b in np.atleast_1d(budgets)],
                          columns=["case", "budget"]))
    keys = _keys(ft)
    out = []
    for k, g in ft.groupby(keys, sort=False):
        row = dict(zip(keys, k if isinstance(k, tuple) else (k,)))
        b = grid.loc[grid["case"] == row["case"], "budget"].to_numpy(float)
        e = np.sort(g["evals"].to_numpy(float))
        frac = np.searchsorted(e, b, side="right") / max(e.size, 1)
        out.append(pd.DataFrame({**{c: [v] * b.size for c, v in row.items()}, "budget": b, "fraction": frac}))
    return pd.concat(out, ignore_index=True) if out else pd.DataFrame(columns=keys + ["budget", "fraction"])


def ecdf_auc(ft: pd.DataFrame, budget_range=None) -> pd.DataFrame:
    """Area under the aggregated ECDF over a log budget axis, normalised to [0, 1].

    ``AUC = (1 / log(b_max / b_min)) * integral of ECDF(b) d(log b)`` over
    ``[b_min, b_max]``, computed exactly from the step function: a (run, target) pair reached
    after ``e`` evaluations contributes ``log(b_max / max(e, b_min)) / log(b_max / b_min)``
    when ``e <= b_max`` and 0 otherwise; the AUC is the mean over pairs. 1 means every target
    was reached at ``b_min``; 0, none within ``b_max``. With ``b_min == b_max`` it is the
    ECDF's value there.

    Parameters
    ----------
    ft : pandas.DataFrame
        The table of :func:`fixed_target`.
    budget_range : (float, float) or dict of str to (float, float), optional
        ``(b_min, b_max)`` for every case or per case. Default: the range of
        :func:`budget_grid`, shared by the optimisers of a case.

    Returns
    -------
    pandas.DataFrame
        The optimiser's keys, ``b_min``, ``b_max`` and ``auc``.
    """
    keys = _keys(ft)
    ranges = {c: _budget_range(g) for c, g in ft.groupby("case", sort=False)}
    if isinstance(budget_range, dict):
        ranges.update({c: tuple(map(float, r)) for c, r in budget_range.items()})
    elif budget_range is not None:
        ranges = {c: tuple(map(float, budget_range)) for c in ranges}
    rows = []
    for k, g in ft.groupby(keys, sort=False):
        row = dict(zip(keys, k if isinstance(k, tuple) else (k,)))
        lo, hi = ranges[row["case"]]
        if not 0 < lo <= hi:
            raise ValueError(f"budget range must satisfy 0 < b_min <= b_max, got ({lo:g}, {hi:g})")
        e = g["evals"].to_numpy(float)
        if hi > lo:
            inside = e <= hi
            part = np.zeros(e.size)
            part[inside] = np.log(hi / np.maximum(e[inside], lo)) / np.log(hi / lo)
        else:
            part = (e <= hi).astype(float)
        rows.append({**row, "b_min": lo, "b_max": hi, "auc": float(part.mean()) if part.size else np.nan})
    return pd.DataFrame(rows, columns=keys + ["b_min", "b_max", "auc"])


# -- figures --------------------------------------------------------------------------------
def _labels(df: pd.DataFrame) -> pd.Series:
    """Legend labels: the algorithm, with ``#optimiser_index`` where a name repeats in a case."""
    if "optimiser_index" not in df.columns:
        return df["algorithm"].astype(str)
    pairs = df[["case", "algorithm", "optimiser_index"]].drop_duplicates()
    dup = pairs.groupby(["case", "algorithm"])["optimiser_index"].transform("nunique") > 1
    repeated = set(map(tuple, pairs.loc[dup, ["case", "algorithm"]].to_numpy()))
    return pd.Series([f"{a}#{i}" if (c, a) in repeated else str(a)
                      for c, a, i in zip(df["case"], df["algorithm"], df["optimiser_index"])], index=df.index)


def _axes():
    from heurtune.analysis.figures import new_figure

    return new_figure(figsize=(6.4, 4.2), layout="constrained")


def _say_why_empty(ax, why: str) -> None:
    """An empty panel says why it is empty, in its middle."""
    ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center", fontsize=9, wrap=True)


def _colors(labels) -> dict:
    """The colour of each algorithm, as in the experiment's other figures."""
    from heurtune.analysis.figures import algorithm_colors

    return algorithm_colors(labels)


def plot_ecdf(ecdf_table: pd.DataFrame, path, *, case: str, title: str | None = None):
    """Plot the aggregated ECDF of one case (fraction of (run, target) pairs vs budget).

    Parameters
    ----------
    ecdf_table : pandas.DataFrame
        The table of :func:`ecdf`.
    path : path
        PNG file to write.
    case : str
        The case to plot.
    title : str, optional
        The figure's title (default: the case).
    """
    d = ecdf_table[ecdf_table["case"] == case]
    d = d.assign(_label=_labels(d))
    fig, ax = _axes()
    colors = _colors(d["_label"])
    for label, g in d.groupby("_label", sort=False):
        ax.step(g["budget"], g["fraction"], where="post", label=label, color=colors[str(label)])
    if d.empty or not (d["fraction"] > 0).any():
        _say_why_empty(ax, "no run reached any target (no feasible value at or below the targets)"
                       if len(d) else f"no run of case {case} has a feasible value: no target to reach")
    if len(d):
        ax.set_xscale("log")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("function evaluations")
    ax.set_ylabel("fraction of (run, target) pairs")
    ax.set_title(title or f"{case}: ECDF aggregated over targets")
    ax.grid(True, which="both", alpha=0.3)
    if len(d):
        ax.legend(fontsize="small")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")


def plot_fixed_target(ert_table: pd.DataFrame, path, *, case: str, title: str | None = None):
    """Plot ERT against the target for one case (fixed-target view; log-log).

    Targets no run of an optimiser reached (``ERT = inf``) are left out of its line.

    Parameters
    ----------
    ert_table : pandas.DataFrame
        The table of :func:`ert`.
    path : str or Path
        PNG file to write (atomically).
    case : str
        The case to plot.
    title : str, optional
        The figure's title (default: the case).
    """
    d = ert_table[ert_table["case"] == case]
    d = d.assign(_label=_labels(d))
    fig, ax = _axes()
    colors = _colors(d["_label"])
    for label, g in d.groupby("_label", sort=False):
        g = g[np.isfinite(g["ert"])].sort_values("target")
        ax.plot(g["target"], g["ert"], marker="o", markersize=3, label=label, color=colors[str(label)])
    if not np.isfinite(d["ert"]).any():
        _say_why_empty(ax, "no run reached any target: every ERT is infinite" if len(d) else
                       f"no run of case {case} has a feasible value: no target to reach")
    if np.isfinite(d["ert"]).any():  # a log axis needs values
        ax.set_xscale("log")
        ax.set_yscale("log")
    ax.invert_xaxis()  # harder targets to the right
    ax.set_xlabel("target (best feasible objective)")
    ax.set_ylabel("ERT (function evaluations)")
    ax.set_title(title or f"{case}: expected running time per target")
    ax.grid(True, which="both", alpha=0.3)
    if np.isfinite(d["ert"]).any():
        ax.legend(fontsize="small")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in str(text))


def write_report(history: pd.DataFrame, out, *, n_targets: int = 20, reference=None, n_budgets: int = 50,
                 figures: bool = True) -> dict:
    """Compute every measure and write CSV tables (and figures) to ``out``.

    Parameters
    ----------
    history : pandas.DataFrame
        Rows of ``history.parquet``.
    out : str or Path
        The folder to write (created).
    n_targets : int
        Targets per case (:func:`default_targets`).
    reference : optional
        The reference values of the targets (:func:`default_targets`).
    n_budgets : int
        Budgets per case of the ECDF (:func:`budget_grid`).
    figures : bool
        Also draw the ECDF and ERT figures of every case.

    Returns
    -------
    dict
        ``targets``, ``fixed_target``, ``ert``, ``ecdf``, ``auc`` tables.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    targets = default_targets(history, n_targets, reference)
    ft = fixed_target(history, targets)
    tables = dict(targets=targets, fixed_target=ft, ert=ert(ft), ecdf=ecdf(ft, n_budgets=n_budgets),
                  auc=ecdf_auc(ft))
    for name in ("ert", "ecdf", "auc"):
        with atomic_path(out / f"anytime_{name}.csv") as tmp:
            tables[name].to_csv(tmp, index=False)
    if figures:
        for case in ft["case"].unique():
            plot_ecdf(tables["ecdf"], out / f"ecdf_{_slug(case)}.png", case=case)
            plot_fixed_target(tables["ert"], out / f"fixed_target_{_slug(case)}.png", case=case)
    return tables


def _parser():
    ap = argparse.ArgumentParser(prog="python -m heurtune.anytime",
                                 description="Anytime measures (ERT, ECDF, AUC) of an experiment's history.",
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=exit_codes(("python -m heurtune.anytime results/benchmark_qtp",
                                                    "python -m heurtune.anytime results/thesis_ch5 --targets 51 "
                                                    "--out anytime")))
    ap.add_argument("dir", help="results folder with history.parquet")
    ap.add_argument("--targets", type=int, default=20, help="targets per case (default 20)")
    ap.add_argument("--reference", type=float, help="easiest target for every case (default: per case, "
                                                      "the worst first feasible value of its runs)")
    ap.add_argument("--budgets", type=int, default=50, help="points of the log budget grid (default 50)")
    ap.add_argument("--out", help="output folder (default DIR)")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    return ap


def run(argv=None) -> int:
    """Command-line entry point; returns the exit code (2 for a usage error)."""
    args = _parser().parse_args(argv)
    path = Path(args.dir) / "history.parquet"
    try:
        if not path.is_file():
            raise ValueError(f"{path} not found (is {args.dir} a results folder?)")
        if args.targets < 1 or args.budgets < 1:
            raise ValueError("--targets and --budgets must be >= 1")
        tables = write_report(pd.read_parquet(path), args.out or args.dir, n_targets=args.targets,
                              reference=args.reference, n_budgets=args.budgets, figures=not args.no_figures)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(tables["auc"].to_string(index=False))
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
