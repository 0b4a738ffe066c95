"""The tuning suite's measures and leaderboard (``python -m heurtune.suite``; docs/suite.md).

Each (problem, instance) is a *case* ``problem/i<k>`` of the anytime measures of
:mod:`heurtune.analysis.anytime`: the runs' best feasible values over the evaluations, the
evaluations each run needed to reach each of the case's targets (:func:`fixed_target`), their
ERT and ECDF. Evaluations are counted per dimension (``evals / dim``, as COCO does), so that the
ECDF aggregates problems of different dimensions on one budget axis, from 1 to the budget
multiplier. The leaderboard ranks the algorithms by the area under that aggregated ECDF (log
budget axis, normalised to [0, 1]) and gives, beside it, the fraction of (case, target, run)
triples reached within the budget, the failed runs (no feasible candidate), and the mean rank of
the Friedman test across cases on the median final value (a failed run counts as infinite, the
worst), with Nemenyi's post-hoc and its critical difference.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from heurtune.analysis import anytime
from heurtune.analysis.stats import FriedmanResult, critical_difference
from heurtune.core.io import atomic_path

__all__ = ["N_TARGETS", "targets_of", "suite_value", "collect", "targets_table", "suite_measures", "friedman_final",
           "nemenyi_groups", "write_leaderboard"]


# Targets per problem and instance, log-spaced from the random-search median to the best known
# value (both included), as COCO's 51 targets.
N_TARGETS = 51


def targets_of(f_best: float, f_random: float, n: int = N_TARGETS) -> np.ndarray:
    """``n`` targets from ``f_random`` down to ``f_best``, equally spaced in log (both included).

    Parameters
    ----------
    f_best, f_random : float
        Positive; ``f_random >= f_best`` (a random-search median below the best known value
        leaves one target, the best).
    n : int

    Returns
    -------
    ndarray
    """
    if not (f_best > 0 and f_random > 0 and math.isfinite(f_best)):
        raise ValueError(f"targets need positive finite values, got best {f_best!r}, random {f_random!r}")
    if not math.isfinite(f_random) or f_random <= f_best:
        return np.array([f_best])
    out = np.geomspace(f_random, f_best, n)
    out[0], out[-1] = f_random, f_best
    return out


def suite_value(best_f, volume=None):
    """The suite's value of a run's ``best_f``: itself for one objective; for several, the
    hypervolume deficit ``1 - HV / volume`` (``best_f`` is minus the front's hypervolume, 0
    while nothing dominates the reference point; ``volume`` the box's between the origin and
    the reference point), in [0, 1] and lower is better like a single objective.

    Parameters
    ----------
    best_f : float, ndarray or pandas.Series
    volume : float, optional
        ``None`` for one objective.

    Returns
    -------
    The same type as ``best_f``.
    """
    return best_f if volume is None else 1.0 + best_f / volume


def collect(folders, volumes=None) -> tuple:
    """The runs and histories of the suite's results folders, cases renamed ``problem/case``.

    Parameters
    ----------
    folders : sequence of (str, str, Path)
        ``(problem, algorithm, folder)`` per results folder.
    volumes : dict, optional
        Problem name to its reference box's volume, for the problems with several objectives:
        their ``best_f`` becomes the hypervolume deficit (:func:`suite_value`).

    Returns
    -------
    (runs, history) : pandas.DataFrame
        With a ``problem`` column; ``experiment`` dropped and ``optimiser_index`` 0 (one
        optimiser per folder).
    """
    runs, hist = [], []
    for problem, _, folder in folders:
        r = pd.read_parquet(folder / "runs.parquet")
        h = pd.read_parquet(folder / "history.parquet")
        for df in (r, h):
            df["best_f"] = suite_value(df["best_f"].astype(float), (volumes or {}).get(problem))
            df["problem"] = problem
            df["instance"] = df["case"].str.lstrip("i").astype(int)
            df["case"] = problem + "/" + df["case"].astype(str)
        runs.append(r)
        hist.append(h)
    runs = pd.concat(runs, ignore_index=True).drop(columns=["experiment"], errors="ignore")
    hist = pd.concat(hist, ignore_index=True).drop(columns=["experiment"], errors="ignore")
    runs["optimiser_index"] = 0
    hist["optimiser_index"] = 0
    # one block per dtype: the TITO folders' hundreds of per-scenario columns left the frames in
    # pieces, and every later assign warned (PerformanceWarning) on the user's terminal
    return runs.copy(), hist.copy()


def _final(runs: pd.DataFrame) -> pd.Series:
    """Each run's final value: its best feasible objective, infinite for a failed run."""
    return runs["best_f"].astype(float).where(runs["feasible"].astype(bool), np.inf)


def targets_table(targets: pd.DataFrame, runs: pd.DataFrame, n_targets: int, *, multiplier: float) -> tuple:
    """The targets of every case: from the suite's table where it has the case for this budget
    and this definition of the problem, else from the runs.

    A table row is made for one budget (its ``budget_multiplier``): its ``f_random`` is random
    search's median at that budget and its targets are spaced up to it. Runs at another budget
    (``--smoke``, ``--budget-multiplier``) take their targets from their own results, as a
    table made for 100 x dim evaluations would leave every target out of reach of 5 x dim. So do
    runs whose ``problem_id`` is not the row's (the problem was redefined after the row was
    made: its best known value answers another problem), with the source ``stale``.

    Parameters
    ----------
    targets : pandas.DataFrame
        ``experiments/suite/targets.csv`` (:func:`heurtune.runner.suite.load_targets`).
    runs : pandas.DataFrame
        The runs of :func:`collect`.
    n_targets : int
    multiplier : float
        The runs' budget in evaluations per dimension; only table rows made for it are used.

    Returns
    -------
    (table, sources) : pandas.DataFrame
        ``case, target`` rows, and per case ``case, f_best, f_random, source`` (``table``:
        ``targets.csv``; ``results``: the best final value of these runs, and the median of
        ``random_search``'s where it ran, else the largest final value of a successful run;
        ``stale``: the same, where the table's row is of another ``problem_id``).
    """
    rows, sources = [], []
    known = {(str(p), int(i)): (str(pid), float(b), float(r)) for p, i, pid, b, r, m in
             targets[["problem", "instance", "problem_id", "f_best", "f_random", "budget_multiplier"]]
             .itertuples(index=False)
             if np.isclose(float(m), float(multiplier), rtol=1e-12, atol=0.0)} if len(targets) else {}
    finals = runs.assign(_f=_final(runs))
    for case, g in finals.groupby("case", sort=False):
        key = (str(g["problem"].iloc[0]), int(g["instance"].iloc[0]))
        ok = g["_f"][np.isfinite(g["_f"])]
        ids = set(g["problem_id"].astype(str)) if "problem_id" in g else set()
        stale = key in known and ids and ids != {known[key][0]}
        if key in known and not stale and np.isfinite(known[key][1]):
            _, f_best, f_random = known[key]
            f_best = min(f_best, float(ok.min())) if ok.size else f_best
            source = "table"
        else:
            if ok.empty:
                continue
            f_best = float(ok.min())
            rand = g.loc[g["algorithm"] == "random_search", "_f"]
            f_random = float(np.median(rand)) if rand.size else np.inf
            source = "stale" if stale else "results"
        if not np.isfinite(f_random):
            f_random = float(ok.max()) if ok.size else f_best
        values = targets_of(f_best, max(f_random, f_best), n_targets)
        rows.append(pd.DataFrame({"case": case, "target": values}))
        sources.append(dict(case=case, f_best=f_best, f_random=f_random, source=source))
    table = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=["case", "target"])
    return table, pd.DataFrame(sources, columns=["case", "f_best", "f_random", "source"])


def suite_measures(runs: pd.DataFrame, history: pd.DataFrame, targets: pd.DataFrame, dims: dict,
                   multiplier: float, groups: dict, n_budgets: int = 50) -> dict:
    """The anytime measures of the suite.

    Parameters
    ----------
    runs, history : pandas.DataFrame
        From :func:`collect`.
    targets : pandas.DataFrame
        ``case, target`` (:func:`targets_table`).
    dims : dict
        Problem name to dimension.
    multiplier : float
        The budget in evaluations per dimension (the ECDF's axis ends there).
    groups : dict
        Problem name to its group.
    n_budgets : int
        Points of the ECDF curves.

    Returns
    -------
    dict
        ``fixed_target`` (per run and target, with ``evals_per_dim``), ``ert`` (per case,
        algorithm and target), ``ecdf`` (per group, ``all`` included, algorithm and budget per
        dimension), ``auc`` (per group and algorithm) and ``auc_problem`` (per problem and
        algorithm).
    """
    ft = anytime.fixed_target(history, targets=targets)
    problem = ft["case"].str.split("/").str[0]
    dim = problem.map(dims).astype(float)
    ft = ft.assign(problem=problem, group=problem.map(groups), evals_per_dim=ft["evals"] / dim,
                   budget_per_dim=ft["budget"] / dim)
    grid = np.geomspace(1.0, multiplier, n_budgets)
    ecdf_rows, auc_rows, auc_problem = [], [], []
    for group, sel in [("all", ft)] + list(ft.groupby("group", sort=True)):
        for alg, g in sel.groupby("algorithm", sort=True):
            e = np.sort(g["evals_per_dim"].to_numpy(float))
            frac = np.searchsorted(e, grid, side="right") / max(e.size, 1)
            ecdf_rows.append(pd.DataFrame({"group": group, "algorithm": alg, "budget_per_dim": grid,
                                           "fraction": frac}))
            auc_rows.append(dict(group=group, algorithm=alg, auc=_auc(e, 1.0, multiplier), pairs=int(e.size),
                                 reached=float(np.mean(e <= multiplier)) if e.size else np.nan))
    for (prob, alg), g in ft.groupby(["problem", "algorithm"], sort=True):
        auc_problem.append(dict(problem=prob, algorithm=alg, auc=_auc(g["evals_per_dim"].to_numpy(float), 1.0,
                                                                      multiplier)))
    return dict(fixed_target=ft, ert=anytime.ert(ft.drop(columns=["problem", "group", "evals_per_dim",
                                                                  "budget_per_dim"])),
                ecdf=pd.concat(ecdf_rows, ignore_index=True), auc=pd.DataFrame(auc_rows),
                auc_problem=pd.DataFrame(auc_problem))


def _auc(evals, lo: float, hi: float) -> float:
    """Area under the ECDF of ``evals`` over ``[lo, hi]`` on a log axis, normalised to [0, 1]
    (as :func:`heurtune.analysis.anytime.ecdf_auc`)."""
    e = np.asarray(evals, float)
    if e.size == 0:
        return float("nan")
    inside = e <= hi
    part = np.zeros(e.size)
    part[inside] = np.log(hi / np.maximum(e[inside], lo)) / np.log(hi / lo)
    return float(part.mean())


def friedman_final(runs: pd.DataFrame, alpha: float = 0.05) -> FriedmanResult:
    """Friedman's test across cases on each algorithm's median final value, failures worst.

    Unlike :func:`heurtune.analysis.stats.friedman_across_cases`, which compares only the
    algorithms with a successful run in every case, a failed run counts here as an infinite
    value (a median is infinite when half the runs failed; ties share their rank), so that an
    algorithm that fails where others succeed ranks last there instead of leaving the test.
    Nemenyi's post-hoc by ``scikit_posthocs.posthoc_nemenyi_friedman``.

    Parameters
    ----------
    runs : pandas.DataFrame
        From :func:`collect`.
    alpha : float

    Returns
    -------
    FriedmanResult
    """
    import scikit_posthocs as sp
    from scipy import stats

    med = runs.assign(_f=_final(runs)).groupby(["case", "algorithm"], sort=True)["_f"].median().unstack()
    med = med.dropna(axis=0, how="any")
    n, k = med.shape
    if n < 2 or k < 3:
        return FriedmanResult(med, pd.Series(dtype=float), alpha=alpha,
                              skipped=f"needs at least 2 cases and 3 algorithms; have {n} and {k}")
    values = np.where(np.isfinite(med.to_numpy(float)), med.to_numpy(float), np.finfo(float).max)
    ranks = pd.Series(stats.rankdata(values, axis=1).mean(axis=0), index=med.columns)
    stat = p = np.nan
    if np.ptp(values, axis=1).any():
        res = stats.friedmanchisquare(*values.T)
        stat, p = float(res.statistic), float(res.pvalue)
    nem = sp.posthoc_nemenyi_friedman(values)
    nem.index = nem.columns = list(med.columns)
    return FriedmanResult(med, ranks, stat, p, nem, critical_difference(k, n, alpha), alpha, "")


def nemenyi_groups(result: FriedmanResult) -> list:
    """The groups a critical-difference diagram joins: maximal runs of algorithms (in mean-rank
    order) whose mean ranks differ by less than the critical difference.

    Parameters
    ----------
    result : FriedmanResult

    Returns
    -------
    list of list of str
        Best group first; an algorithm may be in two overlapping groups.
    """
    if result.skipped:
        return []
    order = result.mean_ranks.sort_values()
    names, ranks = list(order.index), order.to_numpy(float)
    groups = []
    for i in range(len(names)):
        j = i
        while j + 1 < len(names) and ranks[j + 1] - ranks[i] < result.cd:
            j += 1
        if not groups or j > groups[-1][1]:
            groups.append((i, j))
    return [names[i:j + 1] for i, j in groups]


def _latex(df: pd.DataFrame, caption: str, label: str) -> str:
    def cell(v):
        if isinstance(v, float):
            return "--" if not np.isfinite(v) else f"{v:.3f}"
        return str(v).replace("_", r"\_").replace("%", r"\%")

    cols = "l" + "r" * (df.shape[1] - 1)
    lines = [r"% needs \usepackage{booktabs}", r"\begin{table}[htbp]", r"\centering", f"\\caption{{{caption}}}",
             f"\\label{{{label}}}", f"\\begin{{tabular}}{{{cols}}}", r"\toprule",
             " & ".join(cell(c) for c in df.columns) + r" \\", r"\midrule"]
    lines += [" & ".join(cell(v) for v in row) + r" \\" for row in df.itertuples(index=False)]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def _markdown(df: pd.DataFrame) -> str:
    def cell(v):
        if isinstance(v, float):
            return "-" if not np.isfinite(v) else f"{v:.3f}"
        return str(v)

    lines = ["| " + " | ".join(map(str, df.columns)) + " |", "| " + " | ".join("---" for _ in df.columns) + " |"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines) + "\n"


def _write_text(path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _plot_ecdf(ecdf: pd.DataFrame, group: str, multiplier: float, path) -> None:
    from heurtune.analysis.figures import algorithm_colors, new_figure

    d = ecdf[ecdf["group"] == group]
    fig, ax = new_figure()
    colors = algorithm_colors(ecdf["algorithm"])
    for alg, g in d.groupby("algorithm", sort=True):
        ax.step(g["budget_per_dim"], g["fraction"], where="post", label=alg, color=colors[alg])
    ax.set_xscale("log")
    ax.set_xlim(1.0, multiplier)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("evaluations / dimension")
    ax.set_ylabel("fraction of (problem, instance, target, run)")
    ax.set_title(f"suite ECDF, {group} problems" if group != "all" else "suite ECDF, all problems")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png", bbox_inches="tight")


def write_leaderboard(out, runs: pd.DataFrame, measures: dict, friedman: FriedmanResult, sources: pd.DataFrame,
                      *, multiplier: float, figures: bool = True, title: str = "Suite leaderboard",
                      note: str = "") -> list:
    """Write ``leaderboard.md``, ``.csv``, ``.tex``, the per-problem areas, the ERT table and the
    figures (ECDF of all problems and of each group, critical-difference diagram) into ``out``.

    Parameters
    ----------
    out : str or Path
    runs : pandas.DataFrame
    measures : dict
        From :func:`suite_measures`.
    friedman : FriedmanResult
        From :func:`friedman_final`.
    sources : pandas.DataFrame
        From :func:`targets_table`.
    multiplier : float
    figures : bool
    title : str
        The page's heading (and the LaTeX caption's).
    note : str
        A sentence after the heading (what the values are, where the figures are).

    Returns
    -------
    list of Path
        The files written.
    """
    from pathlib import Path

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    auc = measures["auc"]
    board = auc[auc["group"] == "all"].set_index("algorithm")[["auc", "reached"]]
    for group in sorted(set(auc["group"]) - {"all"}):
        board[f"auc {group}"] = auc[auc["group"] == group].set_index("algorithm")["auc"]
    final = runs.assign(_failed=~runs["feasible"].astype(bool))
    board["failed runs"] = final.groupby("algorithm")["_failed"].sum().astype(int)
    board["runs"] = final.groupby("algorithm").size()
    if not friedman.skipped:
        board["mean rank"] = friedman.mean_ranks
    board = board.sort_values("auc", ascending=False).reset_index()
    board.insert(0, "place", np.arange(1, len(board) + 1))
    per_problem = measures["auc_problem"].pivot(index="problem", columns="algorithm", values="auc").reset_index()
    written = []
    paths = {k: out / f"{k}" for k in ("leaderboard.csv", "leaderboard.md", "leaderboard.tex", "problems.csv",
                                        "ert.csv", "targets_used.csv")}
    with atomic_path(paths["leaderboard.csv"]) as tmp:
        board.to_csv(tmp, index=False)
    with atomic_path(paths["problems.csv"]) as tmp:
        per_problem.to_csv(tmp, index=False)
    with atomic_path(paths["ert.csv"]) as tmp:
        measures["ert"].to_csv(tmp, index=False)
    with atomic_path(paths["targets_used.csv"]) as tmp:
        sources.to_csv(tmp, index=False)
    from_table = int((sources["source"] == "table").sum())
    notes = [f"Budget: {multiplier:g} x dimension evaluations per run. Targets: {len(sources)} (problem, instance) "
             f"cases, {from_table} from experiments/suite/targets.csv (rows made for this budget), "
             f"{len(sources) - from_table} from these results (best final value; easiest target the median of "
             f"random_search, else the largest successful final value)."]
    stale = sources.loc[sources["source"] == "stale", "case"].tolist()
    if stale:
        notes.append(f"{len(stale)} of them have a row in targets.csv made for an earlier definition of the problem "
                     f"(another problem_id), not used: {', '.join(stale)}; run `python -m heurtune.suite "
                     f"--make-targets` for them.")
    if friedman.skipped:
        notes.append(f"Friedman test not run: {friedman.skipped}.")
    else:
        groups = nemenyi_groups(friedman)
        notes.append(f"Friedman across {len(friedman.medians)} cases: chi2 = {friedman.statistic:.1f}, "
                     f"p = {friedman.p:.2g}; Nemenyi critical difference {friedman.cd:.2f} (alpha "
                     f"{friedman.alpha:g}); groups: " + "; ".join("{" + ", ".join(g) + "}" for g in groups) + ".")
    if note:
        notes.insert(0, note)
    md = [f"# {title}", "", *notes, "", "Ranked by the area under the ECDF of all (problem, instance, "
          "target, run) over evaluations / dimension (log axis, 1 to the budget); `reached`: the fraction "
          "reached within the budget.", "", _markdown(board), "## Area under the ECDF per problem", "",
          _markdown(per_problem)]
    _write_text(paths["leaderboard.md"], "\n".join(md))
    _write_text(paths["leaderboard.tex"], _latex(board, f"heurtune {title[0].lower()}{title[1:]} (area under the ECDF)",
                                                 "tab:heurtune-suite-leaderboard"))
    written += list(paths.values())
    if figures:
        for group in sorted(set(measures["ecdf"]["group"])):
            path = out / f"ecdf_{group}.png"
            _plot_ecdf(measures["ecdf"], group, multiplier, path)
            written.append(path)
        if not friedman.skipped:
            from heurtune.analysis.figures import cd_diagram

            written.append(cd_diagram(friedman, out / "cd_diagram.png"))
    return written
