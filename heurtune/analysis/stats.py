"""The statistics of a comparison: effect sizes, bootstrap intervals, the within-case tests
(Kruskal-Wallis, Dunn, rank-sum with Holm's correction), winners, and Friedman with Nemenyi's
critical difference across cases. docs/statistics.md states each one.
"""

from __future__ import annotations

import inspect
import itertools
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import stats

from heurtune.analysis.runs import _samples, check_metric, failed_runs, successful_runs

__all__ = [
    "BOOTSTRAP_SEED", "BOOTSTRAP_RESAMPLES", "CI_LEVEL", "A12_THRESHOLDS", "vargha_delaney_a12",
    "effect_magnitude", "bootstrap_ci", "median_ci", "a12_ci", "summary_table", "holm",
    "kruskal_test", "dunn_test", "pairwise_tests", "find_winners", "FriedmanResult",
    "critical_difference", "friedman_across_cases",
]


#: Seed of every bootstrap interval (a fresh ``numpy.random.default_rng(BOOTSTRAP_SEED)`` each).
BOOTSTRAP_SEED = 20240611


#: Bootstrap resamples per interval.
BOOTSTRAP_RESAMPLES = 2000


#: Confidence level of the percentile bootstrap intervals.
CI_LEVEL = 0.95


#: Vargha & Delaney (2000) magnitudes: ``|A12 - 0.5|`` at or above the threshold.
A12_THRESHOLDS = (("small", 0.06), ("medium", 0.14), ("large", 0.21))


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
    check_metric(runs, metric)
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
    check_metric(runs, metric)
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

    check_metric(runs, metric)
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
    check_metric(runs, metric)
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

    check_metric(runs, metric)
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
