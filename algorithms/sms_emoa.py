"""SMS-EMOA (Beume, Naujoks & Emmerich 2007): steady-state selection by hypervolume contribution.

The paper's (mu + 1) scheme (``offspring = 1``, the default): every step makes one offspring and
evaluates it, then drops one member of the mu + 1. With ``offspring = lambda > 1`` a generation
makes lambda offspring, evaluated as one batch (pymoo's default, lambda = mu), and the mu +
lambda are reduced to mu: whole fronts while they fit, then the splitting front loses its
least contributor one at a time, the contributions recomputed after each removal (an
infeasible splitting front keeps its smallest violations).

* Variation: two parents drawn uniformly at random (without replacement), Deb's bounded SBX
  (``eta_c = 20``, ``p_c = 0.9``), one child kept, polynomial mutation (``eta_m = 20``,
  ``p_m = 1/d``): the operators of ``algorithms/ga.py``.
* Reduction: constrained non-dominated sorting (as NSGA-II: feasible before infeasible,
  infeasible by violation) gives the worst front. In an infeasible worst front the member of
  largest violation goes; in a feasible one, the member whose exclusive hypervolume
  contribution is smallest. The contributions are computed with moocore against a reference
  point beyond the front's own nadir (``nadir + range``), and a front's extreme point in any
  objective is never dropped (the paper's infinite contribution of the boundary points in 2-D).

An epoch of the history is ``mu`` steps (``mu`` evaluations) of the steady state, or one
generation with ``offspring > 1``, so that budgets in epochs compare with NSGA-II's; the
initial population is the first epoch. The objectives (mu, k) are
``self.f``.
"""

from __future__ import annotations

import dataclasses

import moocore
import numpy as np

from heurtune.algorithms.ga import check_variation, polynomial_mutation, sbx
from heurtune.core.engine import Optimizer
from heurtune.core.pareto import constrained_ranks
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class SMSEMOASettings:
    n: int = dataclasses.field(default=100, metadata={"help": "population size mu"})
    eta_c: float = dataclasses.field(default=20.0, metadata={"help": "SBX distribution index"})
    p_c: float = dataclasses.field(default=0.9, metadata={"help": "crossover probability"})
    eta_m: float = dataclasses.field(default=20.0, metadata={"help": "polynomial mutation distribution index"})
    p_m: float = dataclasses.field(default=0.0, metadata={"help": "mutation probability per variable; 0 = 1/d"})
    offspring: int = dataclasses.field(default=1, metadata={
        "help": "children per generation: 1 = the paper's steady state (mu + 1); lambda > 1 = one batch of "
                "lambda, reduced one least contributor at a time (pymoo's default: lambda = n)"})

    def __post_init__(self):
        if self.n < 3:
            raise ValueError(f"n must be >= 3, got {self.n}")
        if self.offspring < 1:
            raise ValueError(f"offspring must be >= 1, got {self.offspring}")
        check_variation(self)


def contributions(F) -> np.ndarray:
    """Exclusive hypervolume contribution of each point of a non-dominated front, against
    ``nadir + range`` (a point extreme in any objective gets ``inf``).

    Parameters
    ----------
    F : ndarray (k, m)

    Returns
    -------
    ndarray (k,)
    """
    F = np.asarray(F, dtype=np.float64)
    if len(F) <= 2:
        return np.full(len(F), np.inf)
    lo, hi = F.min(axis=0), F.max(axis=0)
    ref = hi + np.where(hi > lo, hi - lo, 1.0)
    out = np.asarray(moocore.hv_contributions(F, ref=ref), dtype=np.float64)
    extreme = np.any((F == lo) | (F == hi), axis=1)
    return np.where(extreme, np.inf, out)


def least_contributor(F) -> int:
    """Index of the member a feasible front (k, m) loses: a member with non-finite objectives
    (a failed candidate) first, else the least hypervolume contributor; with one member or one
    objective (a tie), the newest.

    Parameters
    ----------
    F : ndarray (k, m)

    Returns
    -------
    int
    """
    if len(F) == 1 or F.shape[1] == 1:
        return len(F) - 1
    finite = np.all(np.isfinite(F), axis=1)
    if not finite.all():
        return int(np.flatnonzero(~finite)[0])
    return int(np.argmin(contributions(F)))


def reduce_one(F, v) -> int:
    """Index of the candidate SMS-EMOA drops from a pool of mu + 1.

    Parameters
    ----------
    F : ndarray (mu + 1, m)
    v : ndarray (mu + 1,)

    Returns
    -------
    int
    """
    F = np.asarray(F, dtype=np.float64).reshape(len(v), -1)
    v = np.asarray(v, dtype=np.float64)
    ranks = constrained_ranks(F, v)
    worst = np.flatnonzero(ranks == ranks.max())
    if v[worst[0]] > 0:  # an infeasible front: the largest violation goes
        return int(worst[np.argmax(v[worst])])
    return int(worst[least_contributor(F[worst])])


def reduce_to(F, v, mu: int) -> np.ndarray:
    """Indices (sorted) of the ``mu`` candidates a generation keeps from a pool of mu + lambda:
    whole fronts in rank order while they fit; the splitting front, if infeasible, keeps its
    smallest violations (ties: the older), else loses its least contributor one at a time.

    Parameters
    ----------
    F : ndarray (mu + lambda, m)
    v : ndarray (mu + lambda,)
    mu : int

    Returns
    -------
    ndarray of int
    """
    F = np.asarray(F, dtype=np.float64).reshape(len(v), -1)
    v = np.asarray(v, dtype=np.float64)
    ranks = constrained_ranks(F, v)
    keep = []
    for rank in np.unique(ranks):
        members = np.flatnonzero(ranks == rank)
        if len(keep) + len(members) <= mu:
            keep.extend(members)
            continue
        need = mu - len(keep)
        if v[members[0]] > 0:
            keep.extend(members[np.argsort(v[members], kind="stable")[:need]])
        else:
            members = list(members)
            while len(members) > need:
                del members[least_contributor(F[members])]
            keep.extend(members)
        break
    return np.sort(np.asarray(keep, dtype=np.int64))


@register("sms_emoa", settings=SMSEMOASettings, multi_objective=True,
          source="Beume, Naujoks & Emmerich (2007), EJOR 181(3); bounded SBX and polynomial mutation "
                 "of Deb's NSGA-II code; hypervolume contributions by moocore",
          description="SMS-EMOA: steady-state (mu + 1), drops the least hypervolume contributor")
class SMSEMOA(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.started = False
        self.steps = 0

    @property
    def p_m(self) -> float:
        return self.settings.p_m or 1.0 / self.space.dim

    def _parents(self, k: int):
        """``k`` pairs of distinct parents, uniformly at random."""
        if k == 1:  # the steady state's draw (its results are pinned)
            i, j = self.rng.choice(len(self.v), size=2, replace=False)
            return np.array([i]), np.array([j])
        return self._tournament(k), self._tournament(k)

    def _tournament(self, k: int) -> np.ndarray:
        """``k`` winners of binary tournaments (pymoo's SMS-EMOA selection): the smaller
        violation if either is infeasible, else the dominating one, else a coin flip."""
        n = len(self.v)
        a = self.rng.integers(n, size=k)
        b = self.rng.integers(n - 1, size=k)
        b = b + (b >= a)
        coin = self.rng.random(k) < 0.5
        va, vb, Fa, Fb = self.v[a], self.v[b], self.f[a], self.f[b]
        a_dominates = np.all(Fa <= Fb, axis=1) & np.any(Fa < Fb, axis=1)
        b_dominates = np.all(Fb <= Fa, axis=1) & np.any(Fb < Fa, axis=1)
        infeasible = (va > 0) | (vb > 0)
        pick_a = np.where(infeasible, (va < vb) | ((va == vb) & coin),
                          a_dominates | (~b_dominates & coin))
        return np.where(pick_a, a, b)

    def ask(self):
        s, d, k = self.settings, self.space.dim, self.settings.offspring
        if not self.started:
            return self.space.uniform(self.rng, s.n)
        i, j = self._parents(k)
        lo, hi = self.space.lower, self.space.upper
        child, _ = sbx(self.X[i], self.X[j], lo, hi, s.eta_c, s.p_c, self.rng.random(k),
                       self.rng.random((k, d)), self.rng.random((k, d)), self.rng.random((k, d)))
        return polynomial_mutation(child, lo, hi, s.eta_m, self.p_m, self.rng.random((k, d)), self.rng.random((k, d)))

    def tell(self, X, f, v):
        F = np.asarray(f, dtype=np.float64).reshape(len(v), -1)
        if not self.started:
            self.X, self.f, self.v = X.copy(), F.copy(), np.asarray(v, dtype=np.float64).copy()
            self.started = True
            return True
        X_all, F_all = np.vstack([self.X, X]), np.vstack([self.f, F])
        v_all = np.concatenate([self.v, v])
        if len(X) == 1:
            keep = np.delete(np.arange(len(v_all)), reduce_one(F_all, v_all))
        else:
            keep = reduce_to(F_all, v_all, self.settings.n)
        self.X, self.f, self.v = X_all[keep], F_all[keep], v_all[keep]
        self.steps += 1
        return self.settings.offspring > 1 or self.steps % self.settings.n == 0
