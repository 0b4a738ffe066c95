"""Statistical comparison of optimisers across experiment results.

Usage::

    python -m heurtune.compare DIR [DIR ...] [--format md|csv|latex] [--metric best_f]
                               [--alpha 0.05] [--out FILE] [--cd-diagram PNG]

Each ``DIR`` is an experiment output folder holding ``runs.parquet`` (one row per case,
algorithm and run; a path to a ``.parquet`` file is accepted too). The folders are merged. Only
successful runs (not failed, best candidate feasible: :func:`successful_runs`) enter the
statistics; the others are counted. Per plant case the report gives

* a summary of the metric per algorithm: successful runs, mean, standard deviation (ddof=1),
  median with its bootstrap confidence interval, best (minimum), worst (maximum), mean
  convergence epoch, feasible rate, runs, failed and infeasible runs, success rate and the mean
  rank in the pooled ranking of the case;
* the Kruskal-Wallis test (the runs of different algorithms are independent samples: each run
  has its own seed);
* for every pair of algorithms: Dunn's post-hoc test and the two-sided Wilcoxon rank-sum
  (Mann-Whitney U) test, each Holm-corrected within the case, and the Vargha-Delaney A12 effect
  size with its bootstrap confidence interval and magnitude;
* the winner, marked with an asterisk, only when it wins against every other algorithm of the
  case: Holm-adjusted Dunn and rank-sum p < alpha and an effect at least small
  (``|A12 - 0.5| >= 0.06``);
* the best run of every algorithm re-evaluated per scenario (``Mp1 ... J`` columns read from
  the ``<metric>@<scenario>`` columns of ``runs.parquet``);
* the loop margins of that best run per interaction loop (input i, output j): gain-crossover
  frequency and phase margin (thesis Tables 4.11, 5.8-5.10), read from each folder's
  ``margins.parquet`` as the experiment runner wrote it; a folder without that file (or with
  margins not per input and output, as TITO experiments write) adds none.

Across cases, the Friedman test on the per-case medians (cases are the blocks) with Nemenyi's
post-hoc test and critical difference, when at least 2 cases and 3 algorithms share them; the
critical-difference diagram is written with ``--cd-diagram``. docs/statistics.md describes
every statistic.

Lower metric values are better. Runs are comparable only if their ``problem_id`` (plant case,
controller, scenarios, objective, constraints, bounds) matches: a case mixing problem ids is
refused, and so is a run (experiment, case, algorithm, run) found twice in one folder, or one
folder given twice. Each folder is a *variant*: when the same algorithm name comes from several
folders in one case, its rows are labelled ``"name [experiment]"`` if the experiment names tell
the folders apart, otherwise ``"name [label]"`` with the folder name as label, or the one given
by ``--label NAME=DIR`` (``load_runs(dirs, labels={NAME: DIR})``); the variants are compared,
never pooled.

Mistakes (no folders, a missing ``runs.parquet``, an unknown format or metric column) give a
one-line ``error: ...`` on stderr and exit code 2. All steps are reusable from Python::

    from heurtune.analysis.compare import load_runs, summary_table, pairwise_tests, report
    runs = load_runs(["results/cs_folqi_qtp", "results/pso_folqi_qtp"])
    print(report(runs, metric="best_f", fmt="md"))
"""

from __future__ import annotations

import argparse
import inspect
import io
import itertools
import re
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from heurtune import _startup
from heurtune.core.cli import exit_codes
from heurtune.core.errors import ConfigError
from heurtune.core.io import atomic_path, check_output_file
from heurtune.core.problem import FAILED_OBJECTIVE

__all__ = [
    "FORMATS",
    "REEVALUATION_COLUMNS",
    "load_runs",
    "summary_table",
    "BOOTSTRAP_SEED",
    "BOOTSTRAP_RESAMPLES",
    "CI_LEVEL",
    "A12_THRESHOLDS",
    "failed_runs",
    "successful_runs",
    "vargha_delaney_a12",
    "effect_magnitude",
    "bootstrap_ci",
    "median_ci",
    "a12_ci",
    "pairwise_tests",
    "holm",
    "kruskal_test",
    "dunn_test",
    "find_winners",
    "FriedmanResult",
    "critical_difference",
    "friedman_across_cases",
    "cd_diagram",
    "best_run_index",
    "best_runs",
    "reevaluation_table",
    "load_margins",
    "load_histories",
    "parse_labels",
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
#: Seed of every bootstrap interval (a fresh ``numpy.random.default_rng(BOOTSTRAP_SEED)`` each).
BOOTSTRAP_SEED = 20240611
#: Bootstrap resamples per interval.
BOOTSTRAP_RESAMPLES = 2000
#: Confidence level of the percentile bootstrap intervals.
CI_LEVEL = 0.95
#: Vargha & Delaney (2000) magnitudes: ``|A12 - 0.5|`` at or above the threshold.
A12_THRESHOLDS = (("small", 0.06), ("medium", 0.14), ("large", 0.21))


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


def experiment_folder(d) -> Path:
    """The experiment folder that ``d`` stands for (a ``.parquet`` path stands for its folder)."""
    path = Path(d)
    return path.parent if path.suffix == ".parquet" and not path.is_dir() else path


def _source_key(d) -> str:
    """Resolved folder path of ``d``: the identity of a variant across load_runs/load_margins."""
    return str(experiment_folder(d).resolve())


def _variant_labels(dirs, labels) -> tuple[list[str], set[str]]:
    """Label of each folder in ``dirs`` and the set of labels the caller gave explicitly.

    Explicit labels (``labels``: label -> folder) are validated; the other folders are
    labelled by their name, extended by parent folders (``seed1/exp``) where names clash.
    """
    keys = [_source_key(d) for d in dirs]
    seen = {}
    for d, key in zip(dirs, keys):
        if key in seen:
            raise ConfigError(f"the same folder is given twice: {seen[key]} and {d}")
        seen[key] = d
    given = {}
    for name, d in (labels or {}).items():
        name = str(name)
        if not name.strip() or "[" in name or "]" in name:
            raise ConfigError(f"label '{name}' for {d} must be non-empty and free of '[' and ']'")
        key = _source_key(d)
        if key not in seen:
            raise ConfigError(f"label '{name}': {d} is not among the folders compared")
        if key in given:
            raise ConfigError(f"folder {d} has two labels: '{given[key]}' and '{name}'")
        given[key] = name
    if len(set(given.values())) < len(given):  # only reachable with str()-equal keys
        raise ConfigError("two labels are the same after conversion to text")
    out = [given.get(key) for key in keys]
    depth = {i: 1 for i, lab in enumerate(out) if lab is None}
    while depth:
        for i, k in depth.items():
            parts = Path(keys[i]).parts
            out[i] = "/".join(parts[-k:]) if len(parts) > 1 else keys[i]
        clash = {i for i in depth if out[i] in given.values()
                 or sum(out[j] == out[i] for j in range(len(out))) > 1}
        grow = {i for i in clash if depth[i] < len(Path(keys[i]).parts) - 1}
        if clash and not grow:
            i = min(clash)
            raise ConfigError(f"cannot label {dirs[i]} by its folder name ('{out[i]}' is taken); "
                              f"name it with --label NAME=DIR")
        depth = {i: depth[i] + 1 for i in grow}
    return out, set(given.values())


def load_runs(dirs, *, labels: dict | None = None) -> pd.DataFrame:
    """Read and merge the ``runs.parquet`` files of experiment output folders.

    Every folder is a *variant*: folders of the same experiment run with other settings or
    seeds are compared side by side instead of being refused.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders, each containing ``runs.parquet`` (a path to a ``.parquet``
        file is accepted as well and stands for its folder).
    labels : dict, optional
        Variant label -> folder (one of ``dirs``). A folder without a label here is labelled by
        its name, or by its name with as many parent folders as needed to tell it apart from
        the others (``seed1/exp``).

    Returns
    -------
    pandas.DataFrame
        All rows, in folder order, with a fresh index. ``experiment``, ``case``,
        ``algorithm`` and ``problem_id`` are strings and ``run`` is an integer. If one
        algorithm name of a case comes from several folders, its rows are relabelled: by
        experiment, ``"name [experiment]"``, when the experiment names tell the folders apart
        and none of them has an explicit label; otherwise by variant, ``"name [label]"``.
        ``attrs["algorithm_labels"]`` maps (resolved folder, experiment, case, algorithm) to
        the label used, so that :func:`load_margins` can follow it.

    Raises
    ------
    ConfigError
        No folder given; the same folder given twice (after resolving the paths); a label
        that is empty, names a folder not in ``dirs`` or gives a folder a second label; a
        folder without ``runs.parquet``; a file missing the columns ``experiment, case,
        algorithm, problem_id, run``; a case whose rows have different ``problem_id`` (not
        comparable); a run (experiment, case, algorithm, run) present more than once in one
        folder.
    """
    dirs = list(dirs)
    if not dirs:
        raise ConfigError("no experiment directories given")
    names, explicit = _variant_labels(dirs, labels)
    frames, sources, keys, variants = [], [], [], []
    for d, name in zip(dirs, names):
        df = _read_one(d)
        frames.append(df)
        sources.extend([str(d)] * len(df))
        keys.extend([_source_key(d)] * len(df))
        variants.extend([name] * len(df))
    runs = pd.concat(frames, ignore_index=True, sort=False)
    for col in ("experiment", "case", "algorithm", "problem_id"):
        runs[col] = runs[col].astype(str)
    try:
        runs["run"] = runs["run"].astype(int)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"column 'run' must hold integers ({exc})") from exc
    source = pd.Series(sources, index=runs.index)
    key = pd.Series(keys, index=runs.index)
    variant = pd.Series(variants, index=runs.index)

    for case, rows in runs.groupby("case", sort=False):
        ids = pd.unique(rows["problem_id"])
        if len(ids) > 1:
            parts = []
            for pid in ids:
                same = rows["problem_id"] == pid
                exps = ", ".join(pd.unique(rows.loc[same, "experiment"]))
                where = ", ".join(pd.unique(source[same.index[same]]))
                parts.append(f"{pid} ({exps}) in {where}")
            raise ConfigError(f"case '{case}': runs are not comparable, problem_id differs: "
                              + "; ".join(parts))

    dup = runs.assign(_key=key).duplicated(_KEY + ["_key"], keep=False)
    if dup.any():
        first = runs.loc[dup].iloc[0]
        n_dup = int(runs.assign(_key=key).duplicated(_KEY + ["_key"], keep="first").sum())
        more = f" ({n_dup - 1} more duplicate(s))" if n_dup > 1 else ""
        raise ConfigError(f"duplicate run: experiment '{first['experiment']}', case '{first['case']}', "
                          f"algorithm '{first['algorithm']}', run {first['run']} in "
                          f"{source[dup.index[dup][0]]}{more}")

    original = runs["algorithm"].copy()
    for _, idx in runs.groupby(["case", "algorithm"], sort=False).groups.items():
        n_src, n_exp = key[idx].nunique(), runs.loc[idx, "experiment"].nunique()
        if n_src == 1 and n_exp == 1:
            continue
        pairs = runs.loc[idx, "experiment"] + "\0" + key[idx]
        by_experiment = pairs.nunique() == n_exp and not set(variant[idx]) & explicit
        if by_experiment:
            tag = runs.loc[idx, "experiment"]
        elif pairs.nunique() == n_src:  # one experiment per folder
            tag = variant[idx]
        else:  # a folder holding several experiments of this algorithm
            tag = variant[idx] + ": " + runs.loc[idx, "experiment"]
        runs.loc[idx, "algorithm"] = original[idx] + " [" + tag + "]"
    mapping = pd.DataFrame({"k": key, "e": runs["experiment"], "c": runs["case"], "a": original,
                            "l": runs["algorithm"]}).drop_duplicates(["k", "e", "c", "a"])
    runs.attrs["algorithm_labels"] = {(k, e, c, a): lab for k, e, c, a, lab in mapping.itertuples(index=False)}
    return runs


def load_margins(dirs, runs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Read and merge the ``margins.parquet`` files of experiment output folders.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders (a path to a ``.parquet`` file stands for its folder).
    runs : pandas.DataFrame, optional
        Rows of :func:`load_runs` for the same folders: an algorithm that :func:`load_runs`
        relabelled (``"name [experiment]"`` or ``"name [variant]"``) gets the same label here,
        read from ``runs.attrs["algorithm_labels"]`` (without it, only ``"name [experiment]"``
        is followed).

    Returns
    -------
    pandas.DataFrame
        All rows of the files found, in folder order, with a fresh index (empty, with the
        columns ``MARGIN_KEY_COLUMNS``, when there are none). Folders without
        ``margins.parquet``, and files that cannot be read or lack the columns ``experiment,
        case, algorithm, input, output, gain_crossover_rad_s, phase_margin_deg`` (e.g. TITO
        margins, which are per loop), are skipped without error.
    """
    return _load_labelled(dirs, runs, "margins.parquet", MARGIN_KEY_COLUMNS)


def load_histories(dirs, runs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Read and merge the ``history.parquet`` files of experiment output folders, with the
    algorithms labelled as :func:`load_runs` labelled them (see :func:`load_margins`).

    Returns
    -------
    pandas.DataFrame
        All rows of the readable files (empty when there are none).
    """
    return _load_labelled(dirs, runs, "history.parquet", ("experiment", "case", "algorithm"))


def _load_labelled(dirs, runs, filename: str, required) -> pd.DataFrame:
    """``filename`` of each folder, merged, algorithms relabelled to match ``runs``."""
    frames = []
    for d in dirs:
        file = experiment_folder(d) / filename
        if not file.is_file():
            continue
        try:
            df = pd.read_parquet(file)
        except Exception:  # unreadable: these files are an optional extra
            continue
        if all(c in df.columns for c in required):
            frames.append(df.assign(_source=_source_key(d)))
    if not frames:
        return pd.DataFrame(columns=list(required))
    m = pd.concat(frames, ignore_index=True, sort=False)
    for col in ("experiment", "case", "algorithm"):
        m[col] = m[col].astype(str)
    known = runs.attrs.get("algorithm_labels") if runs is not None else None
    if known and len(m):
        m["algorithm"] = [known.get((k, e, c, a), a)
                          for k, e, c, a in zip(m["_source"], m["experiment"], m["case"], m["algorithm"])]
    elif runs is not None and len(m):  # rows without the labels of load_runs: follow "name [experiment]"
        labels = set(zip(runs["case"], runs["algorithm"]))
        relabel = [(c, f"{a} [{e}]") in labels for e, c, a in zip(m["experiment"], m["case"], m["algorithm"])]
        relabel = np.array(relabel, dtype=bool)
        if relabel.any():
            m.loc[relabel, "algorithm"] = m.loc[relabel, "algorithm"] + " [" + m.loc[relabel, "experiment"] + "]"
    return m.drop(columns="_source")


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
    """Metric values of the successful runs per algorithm, algorithms in order of appearance.

    Failed and infeasible runs (see :func:`successful_runs`) and missing values are left out.
    """
    ok = successful_runs(rows).to_numpy()
    out = {}
    for alg in pd.unique(rows["algorithm"]):
        sel = (rows["algorithm"] == alg).to_numpy() & ok
        v = rows.loc[sel, metric].to_numpy(dtype=float)
        out[alg] = v[~np.isnan(v)]
    return out


def failed_runs(runs: pd.DataFrame) -> pd.Series:
    """Which runs failed (no stable, simulable candidate; their objective is a sentinel).

    ``status == "failed"`` where the column exists; rows without a status (runs written before
    it existed) count as failed when ``best_f`` is at the failure sentinel.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.

    Returns
    -------
    pandas.Series of bool
        True for a failed run, aligned with ``runs``.
    """
    missing = runs["status"].isna() if "status" in runs else pd.Series(True, index=runs.index)
    failed = runs["status"].eq("failed") if "status" in runs else pd.Series(False, index=runs.index)
    if missing.any() and "best_f" in runs:
        failed |= missing & (runs["best_f"] >= FAILED_OBJECTIVE)
    return failed


def successful_runs(runs: pd.DataFrame) -> pd.Series:
    """Which runs succeeded: not failed (:func:`failed_runs`) and with a feasible best candidate.

    Feasibility is read from the ``feasible`` column of ``runs.parquet`` (the best candidate under
    the tuning scenario meets every constraint); without that column, a ``status`` of
    ``"infeasible"`` marks an infeasible run; without either, every run that did not fail counts.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.

    Returns
    -------
    pandas.Series of bool
        True for a successful run, aligned with ``runs``. Only these runs enter the means,
        medians and tests of this module.
    """
    ok = ~failed_runs(runs).astype(bool)
    if "feasible" in runs:
        ok &= runs["feasible"].astype("boolean").fillna(False).astype(bool)
    elif "status" in runs:
        ok &= ~runs["status"].eq("infeasible")
    return ok


# ---------------------------------------------------------------------------------- effect sizes

def vargha_delaney_a12(a, b) -> float:
    """Vargha-Delaney A12 for minimisation: P(a run of A is smaller than one of B), ties half.

    ``A12 = (#{a_i < b_j} + 0.5 #{a_i == b_j}) / (n_a n_b)``; 0.5 means no effect, 1.0 that every
    value of ``a`` is below every value of ``b`` (A better), 0.0 the opposite. It is computed from
    the rank sum of ``a`` in the pooled sample (the Mann-Whitney U of ``b``).

    Parameters
    ----------
    a, b : array_like
        Two independent samples (lower is better). Missing values are not allowed.

    Returns
    -------
    float
        A12, or NaN if a sample is empty.

    Examples
    --------
    >>> vargha_delaney_a12([1, 2, 3], [4, 5, 6])
    1.0
    >>> vargha_delaney_a12([1, 2], [2, 3])
    0.875
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.size == 0 or b.size == 0:
        return float("nan")
    return float(_a12(a, b))


def _a12(a, b, axis=-1):
    """A12 along ``axis`` (vectorised over leading axes, for :func:`scipy.stats.bootstrap`)."""
    a = np.moveaxis(np.asarray(a, dtype=float), axis, -1)
    b = np.moveaxis(np.asarray(b, dtype=float), axis, -1)
    na, nb = a.shape[-1], b.shape[-1]
    lead = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    pooled = np.concatenate([np.broadcast_to(a, lead + (na,)), np.broadcast_to(b, lead + (nb,))], axis=-1)
    rank_sum_a = stats.rankdata(pooled, axis=-1)[..., :na].sum(axis=-1)
    greater_a = rank_sum_a - na * (na + 1) / 2.0  # #{a > b} + 0.5 #{a == b}
    return 1.0 - greater_a / (na * nb)


def effect_magnitude(a12: float) -> str:
    """Vargha-Delaney magnitude of an A12 value.

    Parameters
    ----------
    a12 : float
        Vargha-Delaney A12.

    Returns
    -------
    str
        ``"negligible"`` (``|A12 - 0.5| < 0.06``), ``"small"`` (< 0.14), ``"medium"`` (< 0.21),
        ``"large"`` (>= 0.21); ``""`` for NaN.

    Examples
    --------
    >>> effect_magnitude(0.56), effect_magnitude(0.3), effect_magnitude(0.5)
    ('small', 'medium', 'negligible')
    """
    if a12 is None or np.isnan(a12):
        return ""
    d = abs(a12 - 0.5) + 1e-12  # A12 is a ratio of counts: 0.56 - 0.5 may round below 0.06
    label = "negligible"
    for name, threshold in A12_THRESHOLDS:
        if d >= threshold:
            label = name
    return label


def _rng_kw(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    params = inspect.signature(stats.bootstrap).parameters
    return {"rng": rng} if "rng" in params else {"random_state": rng}


def bootstrap_ci(samples, statistic, *, seed: int = BOOTSTRAP_SEED, n_resamples: int = BOOTSTRAP_RESAMPLES,
                 level: float = CI_LEVEL) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of a statistic of one or more independent samples.

    A thin wrapper of :func:`scipy.stats.bootstrap` (``method="percentile"``, each sample
    resampled with replacement on its own) with a fresh generator seeded with ``seed``, so
    that the interval depends only on the data and the seed.

    Parameters
    ----------
    samples : sequence of array_like
        The samples, e.g. ``(x,)`` for a median or ``(a, b)`` for A12.
    statistic : callable
        ``statistic(*samples, axis=-1)``, vectorised along ``axis``.
    seed : int
        Seed of :func:`numpy.random.default_rng`.
    n_resamples : int
        Number of bootstrap resamples.
    level : float
        Confidence level.

    Returns
    -------
    tuple of float
        ``(low, high)``; NaN when a sample has fewer than two values.
    """
    samples = [np.asarray(s, dtype=float) for s in samples]
    if any(s.size < 2 for s in samples):
        return float("nan"), float("nan")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # degenerate distribution (all equal): fine here
        res = stats.bootstrap(samples, statistic, n_resamples=n_resamples, confidence_level=level,
                              method="percentile", vectorized=True, **_rng_kw(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def _median(x, axis=-1):
    return np.median(x, axis=axis)


def median_ci(x, *, seed: int = BOOTSTRAP_SEED, n_resamples: int = BOOTSTRAP_RESAMPLES,
              level: float = CI_LEVEL) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the median (see :func:`bootstrap_ci`).

    Parameters
    ----------
    x : array_like
        One sample.
    seed, n_resamples, level
        As in :func:`bootstrap_ci`.

    Returns
    -------
    tuple of float
        ``(low, high)``, NaN for fewer than two values.
    """
    return bootstrap_ci((x,), _median, seed=seed, n_resamples=n_resamples, level=level)


def a12_ci(a, b, *, seed: int = BOOTSTRAP_SEED, n_resamples: int = BOOTSTRAP_RESAMPLES,
           level: float = CI_LEVEL) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of :func:`vargha_delaney_a12`.

    The two samples are resampled independently (they are independent runs).

    Parameters
    ----------
    a, b : array_like
        Two independent samples.
    seed, n_resamples, level
        As in :func:`bootstrap_ci`.

    Returns
    -------
    tuple of float
        ``(low, high)``, NaN when a sample has fewer than two values.
    """
    return bootstrap_ci((a, b), _a12, seed=seed, n_resamples=n_resamples, level=level)


# ---------------------------------------------------------------------------------- summary

def summary_table(runs: pd.DataFrame, metric: str = "best_f", *, seed: int = BOOTSTRAP_SEED) -> pd.DataFrame:
    """Descriptive statistics of a metric per case and algorithm (thesis Table 5.3 style).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs` (columns ``case``, ``algorithm`` and ``metric`` at least).
    metric : str
        Column to summarise; lower is better. Missing values are ignored.
    seed : int
        Seed of the bootstrap confidence interval of the median.

    Returns
    -------
    pandas.DataFrame
        One row per (case, algorithm) in order of appearance, columns ``case, algorithm, n,
        mean, sd, median, median_ci_low, median_ci_high, best, worst`` over the successful runs
        only (:func:`successful_runs`; ``n`` counts them where the metric is not missing,
        ``sd`` uses ddof=1, ``best``/``worst`` are the minimum/maximum, the median's interval
        is :func:`median_ci`), then ``mean_convergence_epoch`` and ``mean_convergence_evals`` if
        ``convergence_epoch`` and ``convergence_evals`` exist (the convergence point in epochs and
        in evaluations: optimisers may spend different evaluations per epoch) and
        ``feasible_rate`` if ``feasible`` exists (all over all runs), then ``runs`` (all
        runs), ``failed`` (:func:`failed_runs`: their objective is a sentinel), ``infeasible``
        (not failed, best candidate infeasible) and ``success_rate`` (successful / all runs).
    """
    _check_metric(runs, metric)
    ok_all = successful_runs(runs)
    failed_all = failed_runs(runs)
    rows = []
    for (case, alg), g in runs.groupby(["case", "algorithm"], sort=False):
        ok = ok_all.loc[g.index].to_numpy()
        failed = failed_all.loc[g.index].to_numpy()
        v = g[metric].to_numpy(dtype=float)[ok]
        v = v[~np.isnan(v)]
        lo, hi = median_ci(v, seed=seed)
        row = {"case": case, "algorithm": alg, "n": int(v.size),
               "mean": v.mean() if v.size else np.nan,
               "sd": v.std(ddof=1) if v.size > 1 else np.nan,
               "median": np.median(v) if v.size else np.nan,
               "median_ci_low": lo, "median_ci_high": hi,
               "best": v.min() if v.size else np.nan,
               "worst": v.max() if v.size else np.nan}
        if "convergence_epoch" in g:
            row["mean_convergence_epoch"] = float(g["convergence_epoch"].astype(float).mean())
        if "convergence_evals" in g:
            row["mean_convergence_evals"] = float(g["convergence_evals"].astype(float).mean())
        if "feasible" in g:
            row["feasible_rate"] = float(g["feasible"].astype(float).mean())
        row.update(runs=len(g), failed=int(failed.sum()), infeasible=int((~failed & ~ok).sum()),
                   success_rate=float(ok.mean()) if len(g) else np.nan)
        rows.append(row)
    return pd.DataFrame(rows)


def holm(pvalues) -> np.ndarray:
    """Holm's step-down adjustment of p-values (family-wise error rate).

    The i-th smallest of m p-values is multiplied by ``m - i + 1``; adjusted values are made
    monotone (running maximum in ascending order of p) and capped at 1. Missing values stay
    missing and do not count in ``m``. (Same values as ``statsmodels``' ``multipletests(...,
    method="holm")``, which does not accept missing values.)

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


# ---------------------------------------------------------------------------------- within a case

def kruskal_test(runs: pd.DataFrame, metric: str = "best_f") -> pd.DataFrame:
    """Kruskal-Wallis H test per case over the successful runs (independent samples).

    The runs of different algorithms in a case are independent (each run has its own seed), so
    the algorithms are compared as independent samples: ``scipy.stats.kruskal`` (chi-square
    approximation, tie-corrected) on the successful runs (:func:`successful_runs`) of every
    algorithm with at least one. Mean ranks are those of the pooled sample of the case
    (1 = lowest metric, ties averaged), the ranks Dunn's test compares.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better.

    Returns
    -------
    pandas.DataFrame
        One row per (case, algorithm) with columns ``case, algorithm, n`` (successful runs
        used), ``mean_rank, statistic`` (H), ``df`` (groups - 1) and ``p``; ``statistic``,
        ``df`` and ``p`` repeat on the rows of a case and are missing when fewer than two
        algorithms have a successful run or all values are equal. Algorithms without a
        successful run have ``n = 0`` and no mean rank.
    """
    _check_metric(runs, metric)
    out = []
    for case, rows in runs.groupby("case", sort=False):
        samples = _samples(rows, metric)
        used = {a: v for a, v in samples.items() if v.size}
        stat = p = np.nan
        df = len(used) - 1 if len(used) >= 2 else np.nan
        mean_rank = {}
        if used:
            pooled = np.concatenate(list(used.values()))
            ranks = stats.rankdata(pooled)
            start = 0
            for a, v in used.items():
                mean_rank[a] = float(ranks[start:start + v.size].mean())
                start += v.size
            if len(used) >= 2 and np.ptp(pooled) > 0:
                res = stats.kruskal(*used.values())
                stat, p = float(res.statistic), float(res.pvalue)
        for a, v in samples.items():
            out.append({"case": case, "algorithm": a, "n": int(v.size), "mean_rank": mean_rank.get(a, np.nan),
                        "statistic": stat, "df": df, "p": p})
    return pd.DataFrame(out, columns=["case", "algorithm", "n", "mean_rank", "statistic", "df", "p"])


def dunn_test(runs: pd.DataFrame, metric: str = "best_f") -> pd.DataFrame:
    """Dunn's post-hoc test between every pair of algorithms, per case, Holm-corrected.

    Dunn (1964) compares the mean ranks of two groups in the pooled ranking of the case with a
    normal approximation (tie-corrected); the p-values come from
    ``scikit_posthocs.posthoc_dunn`` and the ones of a case form one family, adjusted with
    :func:`holm`. Only successful runs are used.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better.

    Returns
    -------
    pandas.DataFrame
        One row per case and pair (algorithms in order of appearance), columns ``case,
        algorithm_a, algorithm_b, p, p_holm``; p is missing for a pair with an empty sample or
        when all values of the case are equal.
    """
    import scikit_posthocs as sp

    _check_metric(runs, metric)
    out = []
    for case, rows in runs.groupby("case", sort=False):
        samples = _samples(rows, metric)
        used = [a for a, v in samples.items() if v.size]
        pooled = np.concatenate([samples[a] for a in used]) if used else np.empty(0)
        matrix = None
        if len(used) >= 2 and np.ptp(pooled) > 0:
            long = pd.DataFrame({"value": pooled, "group": np.repeat(used, [samples[a].size for a in used])})
            matrix = sp.posthoc_dunn(long, val_col="value", group_col="group", p_adjust=None)
        recs = []
        for a, b in itertools.combinations(samples, 2):
            p = float(matrix.loc[a, b]) if matrix is not None and a in used and b in used else np.nan
            recs.append({"case": case, "algorithm_a": a, "algorithm_b": b, "p": p})
        for r, pa in zip(recs, holm([r["p"] for r in recs])):
            r["p_holm"] = float(pa)
        out.extend(recs)
    return pd.DataFrame(out, columns=["case", "algorithm_a", "algorithm_b", "p", "p_holm"])


def pairwise_tests(runs: pd.DataFrame, metric: str = "best_f", alpha: float = 0.05, *,
                   seed: int = BOOTSTRAP_SEED) -> pd.DataFrame:
    """Pairwise comparisons within each case: rank-sum and Dunn tests, A12 with its CI, win.

    For every pair of algorithms of a case, over their successful runs
    (:func:`successful_runs`):

    * the two-sided Wilcoxon rank-sum test, ``scipy.stats.mannwhitneyu(a, b,
      alternative="two-sided")`` (exact for small samples without ties, otherwise normal
      approximation with continuity and tie correction), Holm-corrected within the case;
    * Dunn's test (:func:`dunn_test`), the post-hoc of the Kruskal-Wallis test, Holm-corrected
      within the case;
    * Vargha-Delaney A12 (:func:`vargha_delaney_a12`, probability that a run of A is lower than
      one of B) with its percentile bootstrap interval (:func:`a12_ci`) and magnitude
      (:func:`effect_magnitude`).

    A pair has a winner only when both Holm-adjusted p-values (Dunn and rank-sum) are below
    ``alpha`` and the effect is at least small (``|A12 - 0.5| >= 0.06``). Requiring the rank-sum
    test too guards against Dunn's normal approximation, which is anti-conservative for very
    small groups (3 + 3 fully separated runs: Dunn p = 0.0495, exact rank-sum p = 0.1).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better. Missing values are ignored.
    alpha : float
        Significance level applied to the Holm-adjusted p-values.
    seed : int
        Seed of the bootstrap intervals.

    Returns
    -------
    pandas.DataFrame
        One row per case and pair (algorithms in order of appearance), columns ``case,
        algorithm_a, algorithm_b, n_a, n_b, median_a, median_b, U`` (Mann-Whitney statistic of
        a), ``p, p_holm, significant`` (rank-sum test, ``p_holm < alpha``), ``p_dunn,
        p_dunn_holm, a12, a12_low, a12_high, effect``, ``better`` (the algorithm favoured by
        A12, i.e. by the rank-sum direction; empty if A12 = 0.5) and ``win`` (the better
        algorithm if it wins by the rule above, else empty). A pair with an empty sample has
        missing p-values and no winner.
    """
    _check_metric(runs, metric)
    cols = ["case", "algorithm_a", "algorithm_b", "n_a", "n_b", "median_a", "median_b", "U", "p", "p_holm",
            "significant", "p_dunn", "p_dunn_holm", "a12", "a12_low", "a12_high", "effect", "better", "win"]
    dunn = dunn_test(runs, metric)
    dunn_p = {(r.case, r.algorithm_a, r.algorithm_b): (r.p, r.p_holm) for r in dunn.itertuples()}
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
            a12 = vargha_delaney_a12(x, y)
            lo, hi = a12_ci(x, y, seed=seed)
            better = "" if np.isnan(a12) or a12 == 0.5 else (a if a12 > 0.5 else b)
            pd_raw, pd_holm = dunn_p[(case, a, b)]
            recs.append({"case": case, "algorithm_a": a, "algorithm_b": b, "n_a": int(x.size),
                         "n_b": int(y.size), "median_a": float(np.median(x)) if x.size else np.nan,
                         "median_b": float(np.median(y)) if y.size else np.nan, "U": u, "p": p,
                         "p_dunn": pd_raw, "p_dunn_holm": pd_holm, "a12": a12, "a12_low": lo, "a12_high": hi,
                         "effect": effect_magnitude(a12), "better": better})
        for r, pa in zip(recs, holm([r["p"] for r in recs])):
            r["p_holm"] = float(pa)
            r["significant"] = bool(pa < alpha)  # NaN compares False
            wins = r["p_dunn_holm"] < alpha and r["p_holm"] < alpha and r["effect"] not in ("", "negligible")
            r["win"] = r["better"] if wins else ""
        out.extend(recs)
    return pd.DataFrame(out, columns=cols)


def find_winners(pairs: pd.DataFrame, alpha: float = 0.05) -> dict:
    """The winner of each case: winning against every other algorithm, or None.

    Parameters
    ----------
    pairs : pandas.DataFrame
        Output of :func:`pairwise_tests`.
    alpha : float
        Significance level; used only for tables without a ``win`` column, where a pair is won
        by its ``better`` algorithm when ``p_holm < alpha``.

    Returns
    -------
    dict
        ``{case: algorithm or None}`` for every case of ``pairs`` (cases with a single
        algorithm have no pairs and do not appear). An algorithm wins the case only if it
        wins (``win`` column: Holm-adjusted Dunn and rank-sum p < alpha and at least a small
        A12 effect) its pair with every other algorithm of the case.
    """
    winners = {}
    for case, g in pairs.groupby("case", sort=False):
        algs = list(pd.unique(pd.concat([g["algorithm_a"], g["algorithm_b"]])))
        if "win" in g:
            won = g[g["win"] != ""]
            who = won["win"]
        else:
            won = g[(g["p_holm"] < alpha) & (g["better"] != "")]
            who = won["better"]
        winners[case] = None
        for alg in algs:
            beaten = won.loc[who == alg]
            others = set(beaten["algorithm_a"]) | set(beaten["algorithm_b"])
            others.discard(alg)
            if others == set(algs) - {alg}:
                winners[case] = alg
                break
    return winners


# ---------------------------------------------------------------------------------- across cases

@dataclass
class FriedmanResult:
    """Friedman test on per-case medians with Nemenyi's post-hoc (see :func:`friedman_across_cases`).

    Attributes
    ----------
    medians : pandas.DataFrame
        Median of the successful runs, rows the cases used (blocks), columns the algorithms
        compared (treatments).
    mean_ranks : pandas.Series
        Mean rank of each algorithm over the cases (1 = lowest median).
    statistic, p : float
        Friedman chi-square and its p-value (NaN when every case is fully tied).
    nemenyi : pandas.DataFrame
        Nemenyi p-values between every pair of algorithms.
    cd : float
        Critical difference of the mean ranks at ``alpha`` (:func:`critical_difference`).
    alpha : float
        The significance level used for ``cd``.
    skipped : str
        Why the test was not run (empty when it was run; the other fields are then empty).
    left_out : list of str
        Algorithms left out because they lack a median in some case.
    cases_left_out : list of str
        Cases left out because no algorithm has a successful run there.
    """

    medians: pd.DataFrame
    mean_ranks: pd.Series
    statistic: float = float("nan")
    p: float = float("nan")
    nemenyi: pd.DataFrame = field(default_factory=pd.DataFrame)
    cd: float = float("nan")
    alpha: float = 0.05
    skipped: str = ""
    left_out: list = field(default_factory=list)
    cases_left_out: list = field(default_factory=list)


def critical_difference(k: int, n: int, alpha: float = 0.05) -> float:
    """Nemenyi critical difference of mean ranks (Demsar 2006, eq. for CD).

    ``CD = q_alpha sqrt(k (k + 1) / (6 n))`` with ``q_alpha`` the upper ``alpha`` quantile of
    the studentized range of ``k`` groups with infinite degrees of freedom divided by sqrt(2)
    (``scipy.stats.studentized_range``).

    Parameters
    ----------
    k : int
        Number of algorithms (at least 2).
    n : int
        Number of blocks (cases).
    alpha : float
        Significance level.

    Returns
    -------
    float
        Two algorithms whose mean ranks differ by at least CD differ significantly.
    """
    q = stats.studentized_range.ppf(1.0 - alpha, k, np.inf) / np.sqrt(2.0)
    return float(q * np.sqrt(k * (k + 1) / (6.0 * n)))


def friedman_across_cases(runs: pd.DataFrame, metric: str = "best_f", alpha: float = 0.05) -> FriedmanResult:
    """Friedman test across cases on the per-case medians, with Nemenyi's post-hoc.

    Cases are the blocks and algorithms the treatments: in every case the algorithms are
    ranked by the median of their successful runs (1 = lowest, ties averaged). The statistic
    and p-value come from ``scipy.stats.friedmanchisquare``, the pairwise p-values from
    ``scikit_posthocs.posthoc_nemenyi_friedman``. Only algorithms with a median in every case
    are compared (the others are listed in ``left_out``); the test needs at least 2 cases and
    3 such algorithms, otherwise ``skipped`` says why.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better.
    alpha : float
        Significance level for the critical difference.

    Returns
    -------
    FriedmanResult
    """
    import scikit_posthocs as sp

    _check_metric(runs, metric)
    med = {}
    for case, rows in runs.groupby("case", sort=False):
        med[case] = {a: (float(np.median(v)) if v.size else np.nan) for a, v in _samples(rows, metric).items()}
    table = pd.DataFrame.from_dict(med, orient="index")
    if table.empty:
        return FriedmanResult(table, pd.Series(dtype=float), alpha=alpha, skipped="no runs")
    # A case where no algorithm succeeded ranks nothing: it leaves the blocks, not the algorithms.
    cases_left_out = [c for c in table.index if table.loc[c].isna().all()]
    table = table.drop(index=cases_left_out)
    shared = [a for a in table.columns if table[a].notna().all()]
    left_out = [a for a in table.columns if a not in shared]
    table = table[shared]
    n_cases, k = table.shape
    if n_cases < 2 or k < 3:
        why = (f"needs at least 2 cases and 3 algorithms with a successful run in every case; "
               f"have {n_cases} case(s) and {k} such algorithm(s)")
        return FriedmanResult(table, pd.Series(dtype=float), alpha=alpha, skipped=why, left_out=left_out,
                              cases_left_out=cases_left_out)
    values = table.to_numpy(dtype=float)
    ranks = pd.Series(stats.rankdata(values, axis=1).mean(axis=0), index=shared)
    stat = p = np.nan
    if np.ptp(values, axis=1).any():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res = stats.friedmanchisquare(*values.T)
        stat, p = float(res.statistic), float(res.pvalue)
    nem = sp.posthoc_nemenyi_friedman(values)
    nem.index = nem.columns = shared
    return FriedmanResult(table, ranks, stat, p, nem, critical_difference(k, n_cases, alpha), alpha, "", left_out,
                          cases_left_out)


def cd_diagram(result: FriedmanResult, path) -> Path:
    """Draw the critical-difference diagram of a Friedman/Nemenyi result as a PNG.

    Uses ``scikit_posthocs.critical_difference_diagram`` (mean ranks on the axis, algorithms
    not significantly different by Nemenyi's test joined by a bar) on a matplotlib Agg figure,
    with the critical difference drawn above the axis; the file is written atomically.

    Parameters
    ----------
    result : FriedmanResult
        Output of :func:`friedman_across_cases` that was not skipped.
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
    sp.critical_difference_diagram(result.mean_ranks, result.nemenyi, alpha=result.alpha, ax=ax)
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


def _scenario_columns(runs: pd.DataFrame):
    """``{scenario: {metric: column}}`` from ``<metric>@<scenario>`` columns, in column order."""
    found: dict[str, dict[str, str]] = {}
    for col in runs.columns:
        if isinstance(col, str) and "@" in col:
            metric, scenario = col.split("@", 1)
            found.setdefault(scenario, {})[metric] = col
    return found


def best_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """Per case and optimiser (``optimiser_index``, else ``algorithm``), its best run as
    :func:`best_run_index` picks it, in order of appearance."""
    keys = ["case", "optimiser_index"] if "optimiser_index" in runs.columns else ["case", "algorithm"]
    return runs.loc[[best_run_index(g) for _, g in runs.groupby(keys, sort=False)]]


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
        "<": r"\textless{}", ">": r"\textgreater{}", "|": r"\textbar{}"}


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


# The widest LaTeX table: its leading text columns (algorithm, pair) and at most this many
# others. A wider one is split into parts that repeat the leading columns, so that every part
# fits an A4 or letter text width in \\small (measured with pdflatex on benchmark_qtp's report).
LATEX_MAX_COLUMNS = 7
# What the LaTeX output needs in the preamble (said in its first line).
LATEX_PACKAGES = ("booktabs",)


def _latex_label(title: str) -> str:
    """A \\label key from a table's title: ``tab:`` and its words, lowercase, joined by ``-``."""
    words, key = re.findall(r"[a-z0-9]+", title.lower()), ""
    for word in words:  # whole words, up to 60 characters
        if key and len(key) + 1 + len(word) > 60:
            break
        key = f"{key}-{word}" if key else word
    return "tab:" + key


def _latex_table(df: pd.DataFrame, formats: dict, title: str, use_pandas: bool | None = None) -> str:
    num = _numeric_columns(df)
    cols = list(df.columns)
    keys = []
    for c, n in zip(cols, num):  # the leading text columns, repeated in every part
        if n or len(keys) == 2:
            break
        keys.append(c)
    rest = [c for c in cols if c not in keys]
    width = max(1, LATEX_MAX_COLUMNS - len(keys))
    chunks = [rest[i:i + width] for i in range(0, len(rest), width)] or [[]]
    if use_pandas is None:
        use_pandas = _have_jinja2()
    out = []
    for k, chunk in enumerate(chunks):
        part = df[keys + chunk]
        flags = [num[cols.index(c)] for c in part.columns]
        colfmt = "".join("r" if n else "l" for n in flags)
        cells = pd.DataFrame({_tex(c): [_tex(_fmt(v, formats.get(c, 5))) for v in part[c]] for c in part.columns},
                             columns=[_tex(c) for c in part.columns])
        body = (cells.to_latex(index=False, escape=False, column_format=colfmt) if use_pandas
                else _tabular(cells, colfmt))
        caption = title if len(chunks) == 1 else f"{title} (part {k + 1} of {len(chunks)})"
        label = _latex_label(title) + ("" if len(chunks) == 1 else f"-{k + 1}")
        out.append("\\begin{table}[htbp]\n\\centering\n\\small\n" + f"\\caption{{{_tex(caption)}}}\n"
                   + f"\\label{{{label}}}\n" + body + "\\end{table}")
    return "\n\n".join(out)


def _methods_note(alpha: float) -> str:
    th = ", ".join(f"{name} >= {t:g}" for name, t in A12_THRESHOLDS)
    return (f"Only successful runs (not failed, best candidate feasible) enter the statistics; failed and "
            f"infeasible runs are counted in the success rate. Within a case the runs of different algorithms "
            f"are independent samples: Kruskal-Wallis test, Dunn's post-hoc test and two-sided Wilcoxon "
            f"rank-sum (Mann-Whitney U) tests, both Holm-corrected within the case, alpha = {alpha:g}. "
            f"Effect size: Vargha-Delaney A12 = P(a run of A is lower than one of B), ties count half, 0.5 = "
            f"no effect; magnitude of |A12 - 0.5|: negligible below 0.06, {th}. A pair is won only when "
            f"both Holm-adjusted p-values (Dunn, rank-sum) are < {alpha:g} and the effect is at least small. "
            f"Intervals: {CI_LEVEL:.0%} percentile bootstrap, {BOOTSTRAP_RESAMPLES} resamples, "
            f"seed {BOOTSTRAP_SEED}. Across cases: Friedman test on the per-case medians with Nemenyi's post-hoc test.")


def _blocks(runs: pd.DataFrame, metric: str, alpha: float, margins: pd.DataFrame | None = None,
            cd_path=None):
    """The report as a list of ('heading', level, text) / ('note', text) / ('table', title, df, formats)."""
    marg = margins_table(margins) if margins is not None and len(margins) else pd.DataFrame()
    summary = summary_table(runs, metric)
    pairs = pairwise_tests(runs, metric, alpha)
    kw = kruskal_test(runs, metric)
    winners = find_winners(pairs, alpha)
    reeval = reevaluation_table(runs) if "best_f" in runs.columns else pd.DataFrame()
    fried = friedman_across_cases(runs, metric, alpha)

    experiments = ", ".join(pd.unique(runs["experiment"])) if "experiment" in runs else ""
    blocks = [("heading", 1, f"Statistical comparison of {metric}"),
              ("note", f"Experiments: {experiments}. Metric {metric}, lower is better."),
              ("note", _methods_note(alpha))]
    p_fmt = {"p": 3, "p (Holm)": 3, "p Dunn": 3, "p Dunn (Holm)": 3, "A12": 3, "A12 low": 3, "A12 high": 3}
    for case in pd.unique(runs["case"]):
        rows = runs[runs["case"] == case]
        winner = winners.get(case)
        blocks.append(("heading", 2, f"Case {case}"))
        if "problem_id" in rows:
            blocks.append(("note", f"problem_id {', '.join(pd.unique(rows['problem_id']))}"))

        s = summary[summary["case"] == case].drop(columns="case").reset_index(drop=True)
        k = kw[kw["case"] == case]
        s["mean rank"] = s["algorithm"].map(dict(zip(k["algorithm"], k["mean_rank"])))
        s["algorithm"] = [a + "*" if a == winner else a for a in s["algorithm"]]
        s = s.rename(columns={"sd": "SD", "median_ci_low": "median CI low", "median_ci_high": "median CI high",
                              "mean_convergence_epoch": "conv. epoch",
                              "mean_convergence_evals": "conv. evals", "feasible_rate": "feasible rate",
                              "success_rate": "success rate"})
        blocks.append(("table", f"Case {case}: {metric} over successful runs", s,
                       {"mean rank": 3, "feasible rate": 3, "success rate": 3}))

        algs = pd.unique(rows["algorithm"])
        if winner is not None:
            blocks.append(("note", f"* {winner}: significantly better than every other algorithm of this "
                                   f"case (Holm-adjusted Dunn and rank-sum p < {alpha:g}, A12 effect at least small)."))
        elif len(algs) > 1:
            blocks.append(("note", f"No winner: no algorithm wins against every other (Holm-adjusted Dunn "
                                   f"and rank-sum p < {alpha:g}, A12 effect at least small)."))
        else:
            blocks.append(("note", "Only one algorithm: nothing to compare."))
        if len(algs) > 1 and len(k):
            r = k.iloc[0]
            n_ok, n_all = int(k["n"].sum()), int(len(rows))
            used = int((k["n"] > 0).sum())
            if np.isnan(r["statistic"]):
                why = ("fewer than two algorithms with a successful run" if used < 2 else "all values are equal")
                blocks.append(("note", f"Kruskal-Wallis test not computed: {why} ({n_ok} of {n_all} runs "
                                       f"successful)."))
            else:
                blocks.append(("note", f"Kruskal-Wallis test over {n_ok} successful runs of {used} algorithms "
                                       f"({n_all - n_ok} failed or infeasible runs left out): "
                                       f"H = {_fmt(r['statistic'], 4)}, df = {int(r['df'])}, "
                                       f"p = {_fmt(r['p'], 3)}."))

        pc = pairs[pairs["case"] == case]
        if len(pc):
            t = pd.DataFrame({"A": pc["algorithm_a"], "B": pc["algorithm_b"], "n A": pc["n_a"], "n B": pc["n_b"],
                              "median A": pc["median_a"], "median B": pc["median_b"], "U": pc["U"],
                              "p": pc["p"], "p (Holm)": pc["p_holm"], "p Dunn": pc["p_dunn"],
                              "p Dunn (Holm)": pc["p_dunn_holm"], "A12": pc["a12"], "A12 low": pc["a12_low"],
                              "A12 high": pc["a12_high"], "effect": pc["effect"], "better": pc["better"],
                              "win": pc["win"]}).reset_index(drop=True)
            blocks.append(("table", f"Case {case}: pairwise tests (Wilcoxon rank-sum, Dunn) and A12 effect sizes",
                           t, p_fmt))

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

    blocks.append(("heading", 2, "Across cases"))
    if fried.cases_left_out:
        blocks.append(("note", f"Cases left out (no algorithm has a successful run): {', '.join(fried.cases_left_out)}."))
    if fried.left_out:
        blocks.append(("note", f"Left out (no successful run in some case): {', '.join(fried.left_out)}."))
    if fried.skipped:
        blocks.append(("note", f"Friedman test across cases skipped: {fried.skipped}."))
        if cd_path is not None:
            blocks.append(("note", f"No critical-difference diagram written to {cd_path}."))
        return blocks
    n_cases, k = fried.medians.shape
    stat = _fmt(fried.statistic, 4) or "n/a"
    blocks.append(("note", f"Friedman test on the medians of the successful runs, {n_cases} cases (blocks) x "
                           f"{k} algorithms: chi2 = {stat}, df = {k - 1}, p = {_fmt(fried.p, 3) or 'n/a'}. "
                           f"Nemenyi critical difference of mean ranks at alpha = {alpha:g}: "
                           f"CD = {_fmt(fried.cd, 4)}."))
    t = fried.medians.T.reset_index().rename(columns={"index": "algorithm"})
    t.columns = [str(c) for c in t.columns]
    t["mean rank"] = fried.mean_ranks.to_numpy()
    blocks.append(("table", "Across cases: median per case and mean rank", t, {"mean rank": 3}))
    nem = fried.nemenyi.reset_index().rename(columns={"index": "algorithm"})
    nem.columns = [str(c) for c in nem.columns]
    blocks.append(("table", "Across cases: Nemenyi p-values", nem, {str(c): 3 for c in fried.nemenyi.columns}))
    if cd_path is not None:
        cd_diagram(fried, cd_path)
        blocks.append(("note", f"Critical-difference diagram written to {cd_path}."))
    return blocks


def report(runs: pd.DataFrame, metric: str = "best_f", alpha: float = 0.05, fmt: str = "md",
           margins: pd.DataFrame | None = None, cd_path=None) -> str:
    """Render the full comparison (summary, tests, winner, re-evaluation, margins) for every case.

    The report ends with the comparison across cases (:func:`friedman_across_cases`), or a note
    saying why it was skipped.

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
        ``\\usepackage{booktabs}``, said in a first comment line), each ``\\small`` with a
        ``\\label`` (``tab:`` and its caption's words); a table wider than
        :data:`LATEX_MAX_COLUMNS` is split into parts that repeat its leading text columns, and
        each case starts on a new page (``\\clearpage``) so that no table drifts past the next
        case's heading.
    margins : pandas.DataFrame, optional
        Rows of :func:`load_margins`; when given and not empty, each case ends with the table
        of :func:`margins_table`.
    cd_path : str or Path, optional
        Where to write the critical-difference diagram (:func:`cd_diagram`) when the Friedman
        test across cases is run; nothing is written otherwise (the report says so).

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
    for block in _blocks(runs, metric, alpha, margins, cd_path):
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
                if block[1] <= 2 and len(parts) > 1:
                    parts.append("\\clearpage")  # the tables of one case stay before the next one's heading
                parts.append(f"\\{cmd}*{{{_tex(block[2])}}}")
            elif kind == "note":
                parts.append(_tex(block[1]))
            else:
                parts.append(_latex_table(block[2], block[3], block[1]))
    if fmt == "latex":
        parts.insert(0, f"% heurtune.compare: needs \\usepackage{{{', '.join(LATEX_PACKAGES)}}}; tables are "
                        f"labelled tab:<their caption's words>")
    return "\n\n".join(parts) + "\n"


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------

class UsageError(Exception):
    """A command-line mistake, reported as one line (exit code 2)."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors raise :class:`UsageError` instead of printing usage."""

    def error(self, message):  # one line instead of usage + message
        raise UsageError(message)


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m heurtune.compare", description=__doc__.split("\n")[0], epilog=exit_codes())
    ap.add_argument("dirs", nargs="*", metavar="DIR", help="experiment output folder containing runs.parquet")
    ap.add_argument("--format", default="md", help="output format: md (default), csv or latex")
    ap.add_argument("--metric", default="best_f", help="column to compare, lower is better (default best_f)")
    ap.add_argument("--alpha", type=float, default=0.05, help="significance level (default 0.05)")
    ap.add_argument("--out", help="write the report to this file (atomically) instead of stdout")
    ap.add_argument("--cd-diagram", metavar="PNG",
                    help="write the critical-difference diagram across cases to this PNG file")
    ap.add_argument("--label", action="append", default=[], metavar="NAME=DIR",
                    help="name the variant in DIR (one of the folders) NAME instead of the folder name; "
                         "repeatable")
    return ap


def parse_labels(items) -> dict:
    """``["NAME=DIR", ...]`` -> ``{NAME: DIR}``; a missing ``=`` or a repeated NAME is an error."""
    out = {}
    for item in items:
        name, sep, d = item.partition("=")
        name = name.strip()
        if not sep or not name or not d:
            raise ConfigError(f"--label '{item}' must have the form NAME=DIR")
        if name in out:
            raise ConfigError(f"--label name '{name}' is given twice ({out[name]} and {d})")
        out[name] = d
    return out


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
        runs = load_runs(args.dirs, labels=parse_labels(args.label))
        margins = load_margins(args.dirs, runs)
        text = report(runs, metric=args.metric, alpha=args.alpha, fmt=args.format, margins=margins,
                      cd_path=args.cd_diagram)
    except (ConfigError, UsageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.out:
        try:
            check_output_file(args.out, "--out")
            with atomic_path(args.out) as tmp:
                tmp.write_text(text, encoding="utf-8")
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except OSError as exc:
            print(f"error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        print(f"report written to {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
