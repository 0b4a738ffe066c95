"""Statistical comparison of optimisers across experiment results.

Usage::

    python -m heurtune.compare DIR [DIR ...] [--format md|csv|latex] [--metric best_f]
                               [--alpha 0.05] [--out FILE]

Each ``DIR`` is an experiment output folder holding ``runs.parquet`` (one row per case,
algorithm and run; a path to a ``.parquet`` file is accepted too). The folders are merged and,
per plant case, the report gives

* a summary of the metric per algorithm: number of runs, mean, standard deviation (ddof=1),
  median, best (minimum), worst (maximum), mean convergence epoch, feasible rate and, with at
  least three algorithms, the mean Friedman rank;
* the Friedman test over runs paired by run index (at least three algorithms);
* two-sided Wilcoxon rank-sum (Mann-Whitney U) tests between every pair of algorithms, with
  p-values Holm-corrected within the case;
* the winner, marked with an asterisk, only when it is significantly better (Holm-adjusted
  p < alpha) than every other algorithm of the case;
* the best run of every algorithm re-evaluated per scenario (``Mp1 ... J`` columns read from
  the ``<metric>@<scenario>`` columns of ``runs.parquet``);
* the loop margins of that best run per interaction loop (input i, output j): gain-crossover
  frequency and phase margin (thesis Tables 4.11, 5.8-5.10), read from each folder's
  ``margins.parquet`` as the experiment runner wrote it; a folder without that file (or with
  margins not per input and output, as TITO experiments write) adds none.

Lower metric values are better. Runs are comparable only if their ``problem_id`` (plant case,
controller, scenarios, objective, constraints, bounds) matches: a case mixing problem ids is
refused, and so is a run (experiment, case, algorithm, run) found twice. When the same algorithm
name comes from several experiments in one case, its rows are labelled ``"name [experiment]"``
so that the variants are compared rather than pooled.

Mistakes (no folders, a missing ``runs.parquet``, an unknown format or metric column) give a
one-line ``error: ...`` on stderr and exit code 2. All steps are reusable from Python::

    from heurtune.compare import load_runs, summary_table, pairwise_tests, report
    runs = load_runs(["results/cs_folqi_qtp", "results/pso_folqi_qtp"])
    print(report(runs, metric="best_f", fmt="md"))
"""

from __future__ import annotations

import argparse
import io
import itertools
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from heurtune.errors import ConfigError

__all__ = [
    "FORMATS",
    "REEVALUATION_COLUMNS",
    "load_runs",
    "summary_table",
    "failed_runs",
    "pairwise_tests",
    "holm",
    "friedman_test",
    "find_winners",
    "best_run_index",
    "reevaluation_table",
    "load_margins",
    "margins_table",
    "report",
    "run",
    "main",
]

FORMATS = ("md", "csv", "latex")
REEVALUATION_COLUMNS = ("Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2", "J1", "J2", "J")
REQUIRED_COLUMNS = ("experiment", "case", "algorithm", "problem_id", "run")
MARGIN_KEY_COLUMNS = ("experiment", "case", "algorithm", "input", "output", "gain_crossover_rad_s",
                      "phase_margin_deg")
_KEY = ["experiment", "case", "algorithm", "run"]


# ----------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------

def _read_one(d) -> pd.DataFrame:
    path = Path(d)
    file = path if path.suffix == ".parquet" and not path.is_dir() else path / "runs.parquet"
    if not file.is_file():
        raise ConfigError(f"{d}: no runs.parquet found")
    try:
        df = pd.read_parquet(file)
    except Exception as exc:  # corrupt or foreign file: report it on one line
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"{file}: cannot be read as parquet ({first})") from exc
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise ConfigError(f"{file}: missing column(s) {', '.join(missing)}")
    return df


def load_runs(dirs) -> pd.DataFrame:
    """Read and merge the ``runs.parquet`` files of experiment output folders.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders, each containing ``runs.parquet`` (a path to a ``.parquet``
        file is accepted as well).

    Returns
    -------
    pandas.DataFrame
        All rows, in folder order, with a fresh index. ``experiment``, ``case``,
        ``algorithm`` and ``problem_id`` are strings and ``run`` is an integer. If one
        algorithm name occurs in several experiments of the same case, those rows get the
        algorithm label ``"name [experiment]"``.

    Raises
    ------
    ConfigError
        No folder given; a folder without ``runs.parquet``; a file missing the columns
        ``experiment, case, algorithm, problem_id, run``; a case whose rows have different
        ``problem_id`` (not comparable); a run (experiment, case, algorithm, run) present
        more than once.
    """
    dirs = list(dirs)
    if not dirs:
        raise ConfigError("no experiment directories given")
    frames, sources = [], []
    for d in dirs:
        df = _read_one(d)
        frames.append(df)
        sources.extend([str(d)] * len(df))
    runs = pd.concat(frames, ignore_index=True, sort=False)
    for col in ("experiment", "case", "algorithm", "problem_id"):
        runs[col] = runs[col].astype(str)
    try:
        runs["run"] = runs["run"].astype(int)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"column 'run' must hold integers ({exc})") from exc
    source = pd.Series(sources, index=runs.index)

    for case, rows in runs.groupby("case", sort=False):
        ids = pd.unique(rows["problem_id"])
        if len(ids) > 1:
            parts = []
            for pid in ids:
                exps = ", ".join(pd.unique(rows.loc[rows["problem_id"] == pid, "experiment"]))
                parts.append(f"{pid} ({exps})")
            raise ConfigError(f"case '{case}': runs are not comparable, problem_id differs: "
                              + "; ".join(parts))

    dup = runs.duplicated(_KEY, keep=False)
    if dup.any():
        first = runs.loc[dup].iloc[0]
        same = (runs[_KEY] == first[_KEY]).all(axis=1)
        where = " and ".join(pd.unique(source[same]))
        n_dup = int(runs.duplicated(_KEY, keep="first").sum())
        more = f" ({n_dup - 1} more duplicate(s))" if n_dup > 1 else ""
        raise ConfigError(f"duplicate run: experiment '{first['experiment']}', case '{first['case']}', "
                          f"algorithm '{first['algorithm']}', run {first['run']} in {where}{more}")

    n_exp = runs.groupby(["case", "algorithm"])["experiment"].transform("nunique")
    ambiguous = n_exp > 1
    if ambiguous.any():
        runs.loc[ambiguous, "algorithm"] = (runs.loc[ambiguous, "algorithm"] + " ["
                                            + runs.loc[ambiguous, "experiment"] + "]")
    return runs


def load_margins(dirs, runs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Read and merge the ``margins.parquet`` files of experiment output folders.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders (a path to a ``.parquet`` file stands for its folder).
    runs : pandas.DataFrame, optional
        Rows of :func:`load_runs` for the same folders: an algorithm that :func:`load_runs`
        relabelled ``"name [experiment]"`` gets the same label here.

    Returns
    -------
    pandas.DataFrame
        All rows of the files found, in folder order, with a fresh index (empty, with the
        columns ``MARGIN_KEY_COLUMNS``, when there are none). Folders without
        ``margins.parquet``, and files that cannot be read or lack the columns ``experiment,
        case, algorithm, input, output, gain_crossover_rad_s, phase_margin_deg`` (e.g. TITO
        margins, which are per loop), are skipped without error.
    """
    frames = []
    for d in dirs:
        path = Path(d)
        folder = path.parent if path.suffix == ".parquet" and not path.is_dir() else path
        file = folder / "margins.parquet"
        if not file.is_file():
            continue
        try:
            df = pd.read_parquet(file)
        except Exception:  # unreadable: the margins are an optional extra
            continue
        if all(c in df.columns for c in MARGIN_KEY_COLUMNS):
            frames.append(df)
    if not frames:
        return pd.DataFrame(columns=list(MARGIN_KEY_COLUMNS))
    m = pd.concat(frames, ignore_index=True, sort=False)
    for col in ("experiment", "case", "algorithm"):
        m[col] = m[col].astype(str)
    if runs is not None and len(m):
        labels = set(zip(runs["case"], runs["algorithm"]))
        relabel = [(c, f"{a} [{e}]") in labels for e, c, a in zip(m["experiment"], m["case"], m["algorithm"])]
        relabel = np.array(relabel, dtype=bool)
        if relabel.any():
            m.loc[relabel, "algorithm"] = m.loc[relabel, "algorithm"] + " [" + m.loc[relabel, "experiment"] + "]"
    return m


def margins_table(margins: pd.DataFrame) -> pd.DataFrame:
    """Gain crossover and phase margin per (case, algorithm, input, output) (thesis Table 5.8 layout).

    Parameters
    ----------
    margins : pandas.DataFrame
        Rows of :func:`load_margins` (one per best run and interaction loop).

    Returns
    -------
    pandas.DataFrame
        Columns ``case, algorithm, run`` (when present), ``input, output``, ``gain crossover
        (rad/s)`` (NaN: |L| never reaches 1) and ``phase margin (deg)`` (``inf`` then), rows
        in file order, sorted by input and output within each (case, algorithm).
    """
    cols = ["case", "algorithm"] + (["run"] if "run" in margins.columns else []) + ["input", "output"]
    out = margins[cols + ["gain_crossover_rad_s", "phase_margin_deg"]].copy()
    out["input"] = out["input"].astype(int)
    out["output"] = out["output"].astype(int)
    if "run" in out:
        out["run"] = out["run"].astype(int)
    order = {}
    for key in zip(out["case"], out["algorithm"]):
        order.setdefault(key, len(order))
    out["_o"] = [order[key] for key in zip(out["case"], out["algorithm"])]
    out = out.sort_values(["_o", "input", "output"], kind="mergesort").drop(columns="_o")
    return out.rename(columns={"gain_crossover_rad_s": "gain crossover (rad/s)",
                               "phase_margin_deg": "phase margin (deg)"}).reset_index(drop=True)


# ----------------------------------------------------------------------------------------------
# Statistics
# ----------------------------------------------------------------------------------------------

def _check_metric(runs: pd.DataFrame, metric: str) -> None:
    if metric not in runs.columns:
        numeric = [c for c in runs.columns if pd.api.types.is_numeric_dtype(runs[c])
                   and not pd.api.types.is_bool_dtype(runs[c])]
        raise ConfigError(f"unknown metric column '{metric}' (numeric columns: {', '.join(map(str, numeric))})")
    col = runs[metric]
    if pd.api.types.is_bool_dtype(col) or not pd.api.types.is_numeric_dtype(col):
        raise ConfigError(f"metric column '{metric}' is not numeric ({col.dtype}); "
                          "choose a numeric metric where lower is better")


def _samples(rows: pd.DataFrame, metric: str) -> dict[str, np.ndarray]:
    """Finite metric values per algorithm, algorithms in order of appearance."""
    out = {}
    for alg, g in rows.groupby("algorithm", sort=False):
        v = g[metric].to_numpy(dtype=float)
        out[alg] = v[~np.isnan(v)]
    return out


def failed_runs(runs: pd.DataFrame) -> pd.Series:
    """Which runs failed (no stable, simulable candidate; their objective is a sentinel).

    ``status == "failed"`` where the column exists; rows without a status (runs written before
    it existed) count as failed when ``best_f`` is at the failure sentinel.
    """
    missing = runs["status"].isna() if "status" in runs else pd.Series(True, index=runs.index)
    failed = runs["status"].eq("failed") if "status" in runs else pd.Series(False, index=runs.index)
    if missing.any() and "best_f" in runs:
        from heurtune.problem import FAILED_OBJECTIVE

        failed |= missing & (runs["best_f"] >= FAILED_OBJECTIVE)
    return failed


def summary_table(runs: pd.DataFrame, metric: str = "best_f") -> pd.DataFrame:
    """Descriptive statistics of a metric per case and algorithm (thesis Table 5.3 style).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs` (columns ``case``, ``algorithm`` and ``metric`` at least).
    metric : str
        Column to summarise; lower is better. Missing values are ignored.

    Returns
    -------
    pandas.DataFrame
        One row per (case, algorithm) in order of appearance, columns ``case, algorithm, n,
        mean, sd, median, best, worst`` (``n`` counts non-missing values, ``sd`` uses
        ddof=1, ``best``/``worst`` are the minimum/maximum), then ``mean_convergence_epoch``
        if ``convergence_epoch`` exists and ``feasible_rate`` if ``feasible`` exists. Where
        ``status`` exists, failed runs (no stable, simulable candidate: their objective is a
        sentinel) are left out of the statistics and counted in a ``failed`` column.
    """
    _check_metric(runs, metric)
    rows = []
    for (case, alg), g in runs.groupby(["case", "algorithm"], sort=False):
        failed = failed_runs(g).to_numpy() if "status" in g else np.zeros(len(g), dtype=bool)
        v = g[metric].to_numpy(dtype=float)[~failed]
        v = v[~np.isnan(v)]
        row = {"case": case, "algorithm": alg, "n": int(v.size),
               "mean": v.mean() if v.size else np.nan,
               "sd": v.std(ddof=1) if v.size > 1 else np.nan,
               "median": np.median(v) if v.size else np.nan,
               "best": v.min() if v.size else np.nan,
               "worst": v.max() if v.size else np.nan}
        if "convergence_epoch" in g:
            row["mean_convergence_epoch"] = float(g["convergence_epoch"].astype(float).mean())
        if "feasible" in g:
            row["feasible_rate"] = float(g["feasible"].astype(float).mean())
        if "status" in g:
            row["failed"] = int(failed.sum())
        rows.append(row)
    return pd.DataFrame(rows)


def holm(pvalues) -> np.ndarray:
    """Holm's step-down adjustment of p-values (family-wise error rate).

    The i-th smallest of m p-values is multiplied by ``m - i + 1``; adjusted values are made
    monotone (running maximum in ascending order of p) and capped at 1. Missing values stay
    missing and do not count in ``m``.

    Parameters
    ----------
    pvalues : array_like
        Raw p-values of one family of tests.

    Returns
    -------
    numpy.ndarray
        Adjusted p-values in the input order.

    Examples
    --------
    >>> holm([0.01, 0.04, 0.03]).round(3).tolist()
    [0.03, 0.06, 0.06]
    """
    p = np.asarray(pvalues, dtype=float)
    out = np.full(p.shape, np.nan)
    ok = ~np.isnan(p)
    q = p[ok]
    m = q.size
    if m == 0:
        return out
    order = np.argsort(q, kind="mergesort")
    adj = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * q[order]))
    res = np.empty(m)
    res[order] = adj
    out[ok] = res
    return out


def pairwise_tests(runs: pd.DataFrame, metric: str = "best_f", alpha: float = 0.05) -> pd.DataFrame:
    """Two-sided Wilcoxon rank-sum tests between every pair of algorithms, per case.

    ``scipy.stats.mannwhitneyu(a, b, alternative="two-sided")`` (exact for small samples
    without ties, otherwise normal approximation with continuity and tie correction). The
    p-values of one case form one family and are Holm-corrected (:func:`holm`).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better. Missing values are ignored.
    alpha : float
        Significance level applied to the Holm-adjusted p-values.

    Returns
    -------
    pandas.DataFrame
        One row per case and pair (algorithms in order of appearance), columns ``case,
        algorithm_a, algorithm_b, n_a, n_b, median_a, median_b, U`` (statistic of a),
        ``p, p_holm, significant`` (``p_holm < alpha``) and ``better``: the algorithm with the
        lower median (ties broken by the rank-sum direction; empty if still tied). A pair with
        an empty sample has p missing and is not significant.
    """
    _check_metric(runs, metric)
    cols = ["case", "algorithm_a", "algorithm_b", "n_a", "n_b", "median_a", "median_b", "U", "p",
            "p_holm", "significant", "better"]
    out = []
    for case, rows in runs.groupby("case", sort=False):
        samples = _samples(rows, metric)
        recs = []
        for a, b in itertools.combinations(samples, 2):
            x, y = samples[a], samples[b]
            u = p = np.nan
            if x.size and y.size:
                res = stats.mannwhitneyu(x, y, alternative="two-sided")
                u, p = float(res.statistic), float(res.pvalue)
            med_a = float(np.median(x)) if x.size else np.nan
            med_b = float(np.median(y)) if y.size else np.nan
            if med_a < med_b:
                better = a
            elif med_b < med_a:
                better = b
            elif not np.isnan(u) and u != x.size * y.size / 2:
                better = a if u < x.size * y.size / 2 else b
            else:
                better = ""
            recs.append({"case": case, "algorithm_a": a, "algorithm_b": b, "n_a": int(x.size),
                         "n_b": int(y.size), "median_a": med_a, "median_b": med_b, "U": u, "p": p,
                         "better": better})
        adj = holm([r["p"] for r in recs])
        for r, pa in zip(recs, adj):
            r["p_holm"] = float(pa)
            r["significant"] = bool(pa < alpha)  # NaN compares False
        out.extend(recs)
    return pd.DataFrame(out, columns=cols)


def find_winners(pairs: pd.DataFrame, alpha: float = 0.05) -> dict:
    """The winner of each case: significantly better than every other algorithm, or None.

    Parameters
    ----------
    pairs : pandas.DataFrame
        Output of :func:`pairwise_tests`.
    alpha : float
        Significance level for the Holm-adjusted p-values.

    Returns
    -------
    dict
        ``{case: algorithm or None}`` for every case of ``pairs`` (cases with a single
        algorithm have no pairs and do not appear). An algorithm wins only if, against every
        other algorithm of the case, ``p_holm < alpha`` and it is the ``better`` one.
    """
    winners = {}
    for case, g in pairs.groupby("case", sort=False):
        algs = list(pd.unique(pd.concat([g["algorithm_a"], g["algorithm_b"]])))
        won = g[(g["p_holm"] < alpha) & (g["better"] != "")]
        winners[case] = None
        for alg in algs:
            beaten = won.loc[won["better"] == alg]
            others = set(beaten["algorithm_a"]) | set(beaten["algorithm_b"])
            others.discard(alg)
            if others == set(algs) - {alg}:
                winners[case] = alg
                break
    return winners


def friedman_test(runs: pd.DataFrame, metric: str = "best_f") -> pd.DataFrame:
    """Friedman test per case with at least three algorithms; runs paired by run index.

    Blocks are the run indices present (with a value) for every algorithm of the case. Within
    a block the algorithms are ranked (1 = lowest metric, ties averaged) and the ranks are
    averaged over blocks. The statistic and p-value come from
    ``scipy.stats.friedmanchisquare`` (tie-corrected).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better.

    Returns
    -------
    pandas.DataFrame
        One row per (case, algorithm) with columns ``case, algorithm, mean_rank, n_blocks,
        statistic, p`` (``statistic`` and ``p`` repeated on the rows of a case; missing when
        no block is complete or every block is fully tied). Cases with fewer than three
        algorithms are left out.

    Raises
    ------
    ConfigError
        An algorithm has several rows for the same run index in one case.
    """
    _check_metric(runs, metric)
    out = []
    for case, rows in runs.groupby("case", sort=False):
        algs = list(pd.unique(rows["algorithm"]))
        if len(algs) < 3:
            continue
        dup = rows.duplicated(["algorithm", "run"])
        if dup.any():
            r = rows.loc[dup].iloc[0]
            raise ConfigError(f"case '{case}': algorithm '{r['algorithm']}' has several rows for run {r['run']}")
        table = rows.pivot(index="run", columns="algorithm", values=metric)[algs].astype(float).dropna()
        values = table.to_numpy()
        n = values.shape[0]
        stat = p = np.nan
        ranks = np.full(len(algs), np.nan)
        if n:
            ranks = stats.rankdata(values, axis=1).mean(axis=0)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all blocks tied: 0/0
                res = stats.friedmanchisquare(*values.T)
            stat, p = float(res.statistic), float(res.pvalue)
        for alg, rk in zip(algs, ranks):
            out.append({"case": case, "algorithm": alg, "mean_rank": float(rk), "n_blocks": n,
                        "statistic": stat, "p": p})
    return pd.DataFrame(out, columns=["case", "algorithm", "mean_rank", "n_blocks", "statistic", "p"])


def _scenario_columns(runs: pd.DataFrame):
    """``{scenario: {metric: column}}`` from ``<metric>@<scenario>`` columns, in column order."""
    found: dict[str, dict[str, str]] = {}
    for col in runs.columns:
        if isinstance(col, str) and "@" in col:
            metric, scenario = col.split("@", 1)
            found.setdefault(scenario, {})[metric] = col
    return found


def best_run_index(g: pd.DataFrame):
    """Index of the best run: lowest best_f among feasible runs, else lowest violation."""
    feasible = g["feasible"].fillna(False).astype(bool) if "feasible" in g else pd.Series(True, index=g.index)
    best_f = g["best_f"].astype(float)
    if feasible.any():
        return best_f[feasible].fillna(np.inf).idxmin()
    if "violation" in g:
        key = g.assign(_v=g["violation"].astype(float).fillna(np.inf), _f=best_f.fillna(np.inf))
        return key.sort_values(["_v", "_f"], kind="mergesort").index[0]
    return best_f.fillna(np.inf).idxmin()


def reevaluation_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per-scenario metrics of each algorithm's best run (thesis Tables 5.5-5.7 layout).

    The best run of a (case, algorithm) is the one with the lowest ``best_f`` among feasible
    runs; if none is feasible, the one with the lowest ``violation`` (then lowest ``best_f``).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs` with ``best_f`` and columns ``<metric>@<scenario>``, e.g.
        ``Mp1@nominal``, ``J@+30%``, ``feasible@-30%``.

    Returns
    -------
    pandas.DataFrame
        Rows (case, algorithm, scenario), scenarios in column order; columns ``case,
        algorithm, scenario, run`` (the chosen run), then those of ``Mp1, Mp2, ts1, ts2, ess1,
        ess2, J1, J2, J`` that exist, any other numeric ``<metric>@<scenario>`` metrics, and
        ``feasible`` if ``feasible@<scenario>`` exists. Empty (with these key columns) when
        there are no scenario columns.
    """
    if "best_f" not in runs.columns:
        raise ConfigError("column 'best_f' is needed to pick the best run")
    scen = _scenario_columns(runs)
    present = {m for cols in scen.values() for m in cols}
    metrics = [m for m in REEVALUATION_COLUMNS if m in present]
    extra = []
    for cols in scen.values():
        for m in cols:
            if m not in metrics and m not in extra and m != "feasible":
                extra.append(m)
    metrics += extra
    with_feasible = "feasible" in present
    columns = ["case", "algorithm", "scenario", "run"] + metrics + (["feasible"] if with_feasible else [])
    rows = []
    if scen:
        for (case, alg), g in runs.groupby(["case", "algorithm"], sort=False):
            best = g.loc[best_run_index(g)]
            for scenario, cols in scen.items():
                row = {"case": case, "algorithm": alg, "scenario": scenario, "run": int(best["run"])}
                for m in metrics:
                    row[m] = best[cols[m]] if m in cols else np.nan
                if with_feasible:
                    row["feasible"] = best[cols["feasible"]] if "feasible" in cols else pd.NA
                rows.append(row)
    return pd.DataFrame(rows, columns=columns)


# ----------------------------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------------------------

def _fmt(x, digits: int = 5) -> str:
    if x is None or x is pd.NA:
        return ""
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        if np.isnan(x):
            return ""
        return f"{x:.{digits}g}"
    return str(x)


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
        "<": r"\textless{}", ">": r"\textgreater{}"}


def _tex(s: str) -> str:
    return "".join(_TEX.get(ch, ch) for ch in str(s))


def _numeric_columns(df: pd.DataFrame) -> list[bool]:
    return [pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c])
            for c in df.columns]


def _md_table(df: pd.DataFrame, formats: dict) -> str:
    num = _numeric_columns(df)
    head = [str(c).replace("|", r"\|") for c in df.columns]
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join("---:" if n else ":---" for n in num) + "|"]
    for _, r in df.iterrows():
        cells = [_fmt(v, formats.get(c, 5)).replace("|", r"\|") for c, v in r.items()]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _have_jinja2() -> bool:
    try:
        import jinja2  # noqa: F401
    except ImportError:
        return False
    return True


def _tabular(cells: pd.DataFrame, column_format: str) -> str:
    """A booktabs tabular of pre-formatted, pre-escaped string cells (pandas' to_latex layout)."""
    lines = [f"\\begin{{tabular}}{{{column_format}}}", r"\toprule",
             " & ".join(cells.columns) + r" \\", r"\midrule"]
    lines += [" & ".join(r) + r" \\" for r in cells.itertuples(index=False, name=None)]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


def _latex_table(df: pd.DataFrame, formats: dict, title: str, use_pandas: bool | None = None) -> str:
    num = _numeric_columns(df)
    colfmt = "".join("r" if n else "l" for n in num)
    cells = pd.DataFrame({_tex(c): [_tex(_fmt(v, formats.get(c, 5))) for v in df[c]] for c in df.columns},
                         columns=[_tex(c) for c in df.columns])
    if use_pandas is None:
        use_pandas = _have_jinja2()
    body = (cells.to_latex(index=False, escape=False, column_format=colfmt) if use_pandas
            else _tabular(cells, colfmt))
    return "\\begin{table}[htbp]\n\\centering\n" + f"\\caption{{{_tex(title)}}}\n" + body + "\\end{table}"


def _blocks(runs: pd.DataFrame, metric: str, alpha: float, margins: pd.DataFrame | None = None):
    """The report as a list of ('heading', level, text) / ('note', text) / ('table', title, df, formats)."""
    marg = margins_table(margins) if margins is not None and len(margins) else pd.DataFrame()
    summary = summary_table(runs, metric)
    pairs = pairwise_tests(runs, metric, alpha)
    fried = friedman_test(runs, metric)
    winners = find_winners(pairs, alpha)
    reeval = reevaluation_table(runs) if "best_f" in runs.columns else pd.DataFrame()

    experiments = ", ".join(pd.unique(runs["experiment"])) if "experiment" in runs else ""
    blocks = [("heading", 1, f"Statistical comparison of {metric}"),
              ("note", f"Experiments: {experiments}. Metric {metric}, lower is better. "
                       f"Two-sided Wilcoxon rank-sum (Mann-Whitney U) tests, Holm-corrected within "
                       f"each case, alpha = {alpha:g}; Friedman test over runs paired by run index.")]
    p_fmt = {"p": 3, "p (Holm)": 3, "p_holm": 3}
    for case in pd.unique(runs["case"]):
        rows = runs[runs["case"] == case]
        winner = winners.get(case)
        blocks.append(("heading", 2, f"Case {case}"))
        if "problem_id" in rows:
            blocks.append(("note", f"problem_id {', '.join(pd.unique(rows['problem_id']))}"))

        s = summary[summary["case"] == case].drop(columns="case").reset_index(drop=True)
        f = fried[fried["case"] == case]
        if len(f):
            s["mean rank"] = s["algorithm"].map(dict(zip(f["algorithm"], f["mean_rank"])))
        s["algorithm"] = [a + "*" if a == winner else a for a in s["algorithm"]]
        s = s.rename(columns={"sd": "SD", "mean_convergence_epoch": "conv. epoch",
                              "feasible_rate": "feasible rate"})
        blocks.append(("table", f"Case {case}: {metric} over runs", s, {"mean rank": 3, "feasible rate": 3}))

        algs = pd.unique(rows["algorithm"])
        if winner is not None:
            blocks.append(("note", f"* {winner}: significantly better than every other algorithm of this "
                                   f"case (Holm-adjusted Wilcoxon rank-sum p < {alpha:g})."))
        elif len(algs) > 1:
            blocks.append(("note", f"No winner: no algorithm is significantly better than every other "
                                   f"(Holm-adjusted Wilcoxon rank-sum p < {alpha:g})."))
        else:
            blocks.append(("note", "Only one algorithm: nothing to compare."))
        if len(f):
            r = f.iloc[0]
            blocks.append(("note", f"Friedman test over {int(r['n_blocks'])} paired runs: "
                                   f"chi2 = {_fmt(r['statistic'], 4) or 'n/a'}, p = {_fmt(r['p'], 3) or 'n/a'}."))

        pc = pairs[pairs["case"] == case]
        if len(pc):
            t = pd.DataFrame({"A": pc["algorithm_a"], "B": pc["algorithm_b"], "median A": pc["median_a"],
                              "median B": pc["median_b"], "U": pc["U"], "p": pc["p"], "p (Holm)": pc["p_holm"],
                              "significant": pc["significant"], "better": pc["better"]}).reset_index(drop=True)
            blocks.append(("table", f"Case {case}: pairwise Wilcoxon rank-sum tests", t, p_fmt))

        rc = reeval[reeval["case"] == case] if len(reeval) else reeval
        if len(rc):
            t = rc.drop(columns="case").reset_index(drop=True)
            t["algorithm"] = [a + "*" if a == winner else a for a in t["algorithm"]]
            blocks.append(("table", f"Case {case}: best run of each algorithm per scenario", t, {}))

        mc = marg[marg["case"] == case] if len(marg) else marg
        if len(mc):
            t = mc.drop(columns="case").reset_index(drop=True)
            t["algorithm"] = [a + "*" if a == winner else a for a in t["algorithm"]]
            blocks.append(("table", f"Case {case}: loop margins of each algorithm's best run (input i, output j)",
                           t, {"gain crossover (rad/s)": 4, "phase margin (deg)": 4}))
    return blocks


def report(runs: pd.DataFrame, metric: str = "best_f", alpha: float = 0.05, fmt: str = "md",
           margins: pd.DataFrame | None = None) -> str:
    """Render the full comparison (summary, tests, winner, re-evaluation, margins) for every case.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better.
    alpha : float
        Significance level for the Holm-adjusted p-values.
    fmt : {"md", "csv", "latex"}
        ``md``: headings and pipe tables. ``csv``: one CSV table per block, separated by blank
        lines, headings and notes as ``# ...`` lines, numbers unrounded. ``latex``: starred
        sectioning commands and ``table`` environments with booktabs tabulars (needs
        ``\\usepackage{booktabs}``).
    margins : pandas.DataFrame, optional
        Rows of :func:`load_margins`; when given and not empty, each case ends with the table
        of :func:`margins_table`.

    Returns
    -------
    str
        The report, ending with a newline. The winner of a case carries an asterisk and is
        explained in a note line.
    """
    if fmt not in FORMATS:
        raise ConfigError(f"unknown format '{fmt}' (choose from {', '.join(FORMATS)})")
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must lie in (0, 1), got {alpha:g}")
    _check_metric(runs, metric)
    parts = []
    for block in _blocks(runs, metric, alpha, margins):
        kind = block[0]
        if fmt == "md":
            if kind == "heading":
                parts.append("#" * block[1] + " " + block[2])
            elif kind == "note":
                text = block[1]
                parts.append("\\" + text if text.startswith("*") else text)
            else:
                parts.append(f"### {block[1]}\n\n" + _md_table(block[2], block[3]))
        elif fmt == "csv":
            if kind == "heading":
                parts.append("# " + block[2])
            elif kind == "note":
                parts.append("# " + block[1])
            else:
                buf = io.StringIO()
                block[2].to_csv(buf, index=False, lineterminator="\n")
                parts.append("# " + block[1] + "\n" + buf.getvalue().rstrip("\n"))
        else:
            if kind == "heading":
                cmd = {1: "section", 2: "subsection"}.get(block[1], "subsubsection")
                parts.append(f"\\{cmd}*{{{_tex(block[2])}}}")
            elif kind == "note":
                parts.append(_tex(block[1]))
            else:
                parts.append(_latex_table(block[2], block[3], block[1]))
    return "\n\n".join(parts) + "\n"


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------

class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line instead of usage + message
        raise _UsageError(message)


def _parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="python -m heurtune.compare", description=__doc__.split("\n")[0])
    ap.add_argument("dirs", nargs="*", metavar="DIR", help="experiment output folder containing runs.parquet")
    ap.add_argument("--format", default="md", help="output format: md (default), csv or latex")
    ap.add_argument("--metric", default="best_f", help="column to compare, lower is better (default best_f)")
    ap.add_argument("--alpha", type=float, default=0.05, help="significance level (default 0.05)")
    ap.add_argument("--out", help="write the report to this file (atomically) instead of stdout")
    return ap


def run(argv=None) -> int:
    """Command-line entry point; returns the process exit code (0 ok, 2 usage/input error).

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    """
    try:
        args = _parser().parse_args(argv)
        if not args.dirs:
            raise ConfigError("no experiment directories given")
        if args.format not in FORMATS:
            raise ConfigError(f"unknown format '{args.format}' (choose from {', '.join(FORMATS)})")
        if not 0 < args.alpha < 1:
            raise ConfigError(f"--alpha must lie in (0, 1), got {args.alpha:g}")
        runs = load_runs(args.dirs)
        margins = load_margins(args.dirs, runs)
        text = report(runs, metric=args.metric, alpha=args.alpha, fmt=args.format, margins=margins)
    except (ConfigError, _UsageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.out:
        from heurtune.io import atomic_path

        try:
            with atomic_path(args.out) as tmp:
                tmp.write_text(text, encoding="utf-8")
        except OSError as exc:
            print(f"error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
            return 1
        print(f"report written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    sys.exit(run())


if __name__ == "__main__":
    main()
