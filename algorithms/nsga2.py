"""NSGA-II (Deb, Pratap, Agarwal & Meyarivan 2002): elitist non-dominated sorting GA.

One generation = ``n`` evaluations (the initial population too):

* Ranking: constrained non-dominated sorting (the paper's section VI: a feasible candidate
  dominates an infeasible one, two infeasible ones compare by total violation, two feasible
  ones by Pareto dominance), then the crowding distance within each front (Fig. 6).
* Parent selection: binary tournaments with the crowded-comparison operator (lower front
  wins; in the same front the larger crowding distance; a tie by a fair coin), contestants
  paired from random permutations of the population (tournament without replacement, as in
  Deb's code).
* Variation: the bounded SBX (``eta_c = 20`` as in the paper, ``p_c = 0.9``) and polynomial
  mutation (``eta_m = 20``, ``p_m = 1/d``) of Deb's reference code, shared with
  ``algorithms/ga.py``.
* Survival (Fig. 2): parents and offspring together; whole fronts are taken in order while they
  fit, and the front that does not fit is cut by descending crowding distance.

With one objective the fronts are the sorted objective values, so it is a (mu + lambda) GA
with a crowding tie-break. The population's objectives (n, k) are ``self.f``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.algorithms.ga import check_variation, polynomial_mutation, sbx
from heurtune.core.engine import Optimizer
from heurtune.core.pareto import constrained_ranks, crowding_distance
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class NSGA2Settings:
    n: int = dataclasses.field(default=100, metadata={"help": "population size (even; the paper uses 100)"})
    eta_c: float = dataclasses.field(default=20.0, metadata={"help": "SBX distribution index (paper: 20)"})
    p_c: float = dataclasses.field(default=0.9, metadata={"help": "crossover probability per pair"})
    eta_m: float = dataclasses.field(default=20.0, metadata={"help": "polynomial mutation distribution index"})
    p_m: float = dataclasses.field(default=0.0, metadata={"help": "mutation probability per variable; 0 = 1/d"})

    def __post_init__(self):
        if self.n < 4 or self.n % 2:
            raise ValueError(f"n must be an even number >= 4, got {self.n}")
        check_variation(self)


def rank_and_crowding(F, v):
    """Front index and crowding distance (within its front) of every candidate.

    Parameters
    ----------
    F : ndarray (n, m)
    v : ndarray (n,)
        Total violations (infeasible candidates rank after the feasible ones).

    Returns
    -------
    ranks : ndarray of int (n,)
    crowd : ndarray (n,)
    """
    F = np.asarray(F, dtype=np.float64).reshape(len(v), -1)
    ranks = constrained_ranks(F, v)
    crowd = np.zeros(len(v))
    for r in np.unique(ranks):
        members = np.flatnonzero(ranks == r)
        crowd[members] = crowding_distance(F[members])
    return ranks, crowd


def crowded_tournament(ranks, crowd, a, b, coin):
    """Winners of the tournaments ``a[k]`` vs ``b[k]``: lower front, then larger crowding
    distance, then ``a`` when ``coin[k] < 0.5``.

    Parameters
    ----------
    ranks : ndarray of int
    crowd : ndarray
    a, b : ndarray of int
    coin : ndarray (k,)

    Returns
    -------
    ndarray of int
    """
    a, b = np.asarray(a), np.asarray(b)
    a_better = (ranks[a] < ranks[b]) | ((ranks[a] == ranks[b]) & (crowd[a] > crowd[b]))
    b_better = (ranks[b] < ranks[a]) | ((ranks[a] == ranks[b]) & (crowd[b] > crowd[a]))
    return np.where(a_better | (~b_better & (np.asarray(coin) < 0.5)), a, b)


def survivors(F, v, n):
    """Indices of the ``n`` candidates NSGA-II keeps from a merged pool (Fig. 2).

    Parameters
    ----------
    F : ndarray (n, m)
    v : ndarray (n,)
    n : int

    Returns
    -------
    ndarray of int
    """
    ranks, crowd = rank_and_crowding(F, v)
    keep = []
    for r in np.unique(ranks):
        members = np.flatnonzero(ranks == r)
        if len(keep) + len(members) <= n:
            keep.extend(members.tolist())
            continue
        order = members[np.argsort(-crowd[members], kind="stable")]
        keep.extend(order[:n - len(keep)].tolist())
        break
    return np.array(keep, dtype=np.int64)


@register("nsga2", settings=NSGA2Settings, multi_objective=True,
          source="Deb, Pratap, Agarwal & Meyarivan (2002), IEEE TEC 6(2); bounded SBX and polynomial "
                 "mutation of Deb's NSGA-II code",
          description="NSGA-II: constrained non-dominated sorting, crowding distance, crowded tournaments")
class NSGA2(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.started = False

    @property
    def p_m(self) -> float:
        return self.settings.p_m or 1.0 / self.space.dim

    def ask(self):
        s, d = self.settings, self.space.dim
        if not self.started:
            return self.space.uniform(self.rng, s.n)
        ranks, crowd = rank_and_crowding(self.f, self.v)
        n = len(self.v)
        a = np.concatenate([self.rng.permutation(n), self.rng.permutation(n)])
        b = np.concatenate([self.rng.permutation(n), self.rng.permutation(n)])
        parents = crowded_tournament(ranks, crowd, a[:s.n], b[:s.n], self.rng.random(s.n))
        pairs = s.n // 2
        lo, hi = self.space.lower, self.space.upper
        c1, c2 = sbx(self.X[parents[0::2]], self.X[parents[1::2]], lo, hi, s.eta_c, s.p_c, self.rng.random(pairs),
                     self.rng.random((pairs, d)), self.rng.random((pairs, d)), self.rng.random((pairs, d)))
        children = np.empty((s.n, d))
        children[0::2], children[1::2] = c1, c2
        return polynomial_mutation(children, lo, hi, s.eta_m, self.p_m, self.rng.random((s.n, d)),
                                   self.rng.random((s.n, d)))

    def tell(self, X, f, v):
        F = np.asarray(f, dtype=np.float64).reshape(len(v), -1)
        if not self.started:
            self.X, self.f, self.v = X.copy(), F.copy(), np.asarray(v, dtype=np.float64).copy()
            self.started = True
            return True
        X_all = np.vstack([self.X, X])
        F_all = np.vstack([self.f, F])
        v_all = np.concatenate([self.v, v])
        keep = survivors(F_all, v_all, self.settings.n)
        self.X, self.f, self.v = X_all[keep], F_all[keep], v_all[keep]
        return True
