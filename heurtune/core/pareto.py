"""Pareto fronts of constrained multi-objective problems (all objectives minimised).

Constrained domination (Deb et al. 2002, section VI): a feasible candidate dominates an
infeasible one; two infeasible candidates compare by total violation; two feasible ones by
Pareto dominance. Non-dominated sorting and the hypervolume come from moocore (a maintained C
implementation); the crowding distance, the archive and the decision step are written here.
"""

from __future__ import annotations

import moocore
import numpy as np

from heurtune.core.errors import ConfigError

__all__ = ["constrained_ranks", "crowding_distance", "hypervolume", "update_front", "asf_choice"]


def constrained_ranks(F, v) -> np.ndarray:
    """Front index of every candidate under constrained domination (0 = the first front).

    Parameters
    ----------
    F : (n, k) array
        Objective values (minimised).
    v : (n,) array
        Total constraint violation (0 when feasible).

    Returns
    -------
    (n,) int array
        Feasible candidates get their Pareto front among the feasible ones; infeasible ones
        come after all of them, one front per distinct violation, smaller violations first.
    """
    F = np.asarray(F, dtype=np.float64)
    F = F.reshape(len(F), -1)
    v = np.asarray(v, dtype=np.float64)
    ranks = np.zeros(len(F), dtype=np.int64)
    feasible = v <= 0
    if feasible.any():
        ranks[feasible] = moocore.pareto_rank(np.nan_to_num(F[feasible], nan=np.inf))
    base = ranks[feasible].max() + 1 if feasible.any() else 0
    if (~feasible).any():
        ranks[~feasible] = base + np.unique(v[~feasible], return_inverse=True)[1]
    return ranks


def crowding_distance(F) -> np.ndarray:
    """Crowding distance of the points of one front (Deb et al. 2002, Fig. 6).

    Per objective the points are sorted, the two extremes get an infinite distance and every
    other point adds the gap between its two neighbours divided by the objective's range. An
    objective whose values are all equal adds nothing.

    Parameters
    ----------
    F : array_like (n, k)
        The front's objective values.

    Returns
    -------
    ndarray (n,)
    """
    F = np.asarray(F, dtype=np.float64)
    F = F.reshape(len(F), -1)
    n, k = F.shape
    d = np.zeros(n)
    if n <= 2:
        return np.full(n, np.inf)
    for j in range(k):
        order = np.argsort(F[:, j], kind="stable")
        fj = F[order, j]
        d[order[0]] = d[order[-1]] = np.inf
        with np.errstate(invalid="ignore"):
            span = fj[-1] - fj[0]
        if span > 0 and np.isfinite(span):
            d[order[1:-1]] += (fj[2:] - fj[:-2]) / span
    return d


def hypervolume(F, reference) -> float:
    """Volume dominated by ``F`` and bounded by ``reference``.

    Parameters
    ----------
    F : array_like (n, k)
        Objective values (minimised).
    reference : array_like (k,)
        The reference point.

    Returns
    -------
    float
        0 when no point is strictly better than the reference in every objective.
    """
    F = np.asarray(F, dtype=np.float64)
    F = F.reshape(len(F), -1)
    ref = np.asarray(reference, dtype=np.float64).ravel()
    if ref.size != F.shape[1]:
        raise ConfigError(f"the reference point has {ref.size} values for {F.shape[1]} objectives")
    inside = np.all(F < ref, axis=1)
    if not inside.any():
        return 0.0
    return float(moocore.hypervolume(F[inside], ref=ref))


def update_front(front, X, F, v, g):
    """The archive of the best candidates seen, updated with new ones.

    Parameters
    ----------
    front : tuple (X, F, v, g) or None
        The archive so far.
    X, F, v, g : arrays
        New candidates: decision vectors (n, d), objectives (n, k), violations (n,) and
        constraint values (n, m).

    Returns
    -------
    tuple (X, F, v, g)
        With feasible candidates among them, the feasible ones no other feasible one dominates
        (duplicates of the objective vector kept once, the earliest); otherwise those of the
        smallest violation.
    """
    if front is not None:
        X, F, v, g = (np.concatenate([a, b]) for a, b in zip(front, (X, F, v, g)))
    F = F.reshape(len(F), -1)
    feasible = v <= 0
    if feasible.any():
        idx = np.flatnonzero(feasible)
        _, first = np.unique(F[idx], axis=0, return_index=True)
        idx = idx[np.sort(first)]
        keep = idx[moocore.is_nondominated(F[idx])]
    else:
        keep = np.flatnonzero(v == v.min())[:1]
    return X[keep], F[keep], v[keep], g[keep]


def asf_choice(F, weights=None) -> int:
    """The decision step: the index of the point of a front that minimises the achievement
    scalarising function ``max_j w_j (F_j - ideal_j) / (nadir_j - ideal_j)`` (ideal and nadir of
    the front itself; equal weights by default). With normalised objectives and equal weights
    this picks the balanced compromise; a larger weight on an objective favours it.

    Parameters
    ----------
    F : array_like (n, k)
        The front's objective values.
    weights : array_like (k,), optional
        The weights ``w``; equal by default.

    Returns
    -------
    int
        The chosen point's row.
    """
    F = np.asarray(F, dtype=np.float64)
    F = F.reshape(len(F), -1)
    w = np.ones(F.shape[1]) if weights is None else np.asarray(weights, dtype=np.float64)
    ideal, nadir = F.min(axis=0), F.max(axis=0)
    span = np.where(nadir > ideal, nadir - ideal, 1.0)
    return int(np.argmin(np.max(w * (F - ideal) / span, axis=1)))
