"""SMS-EMOA (Beume, Naujoks & Emmerich 2007): steady-state selection by hypervolume contribution.

A (mu + 1) scheme: every step makes one offspring and evaluates it, then drops one member of
the mu + 1:

* Variation: two parents drawn uniformly at random (without replacement), Deb's bounded SBX
  (``eta_c = 20``, ``p_c = 0.9``), one child kept, polynomial mutation (``eta_m = 20``,
  ``p_m = 1/d``): the operators of ``algorithms/ga.py``.
* Reduction: constrained non-dominated sorting (as NSGA-II: feasible before infeasible,
  infeasible by violation) gives the worst front. In an infeasible worst front the member of
  largest violation goes; in a feasible one, the member whose exclusive hypervolume
  contribution is smallest. The contributions are computed with moocore against a reference
  point beyond the front's own nadir (``nadir + range``), and a front's extreme point in any
  objective is never dropped (the paper's infinite contribution of the boundary points in 2-D).

An epoch of the history is ``mu`` steps (``mu`` evaluations), so that budgets in epochs
compare with NSGA-II's; the initial population is the first epoch. The objectives (mu, k) are
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

    def __post_init__(self):
        if self.n < 3:
            raise ValueError(f"n must be >= 3, got {self.n}")
        check_variation(self)


def contributions(F) -> np.ndarray:
    """Exclusive hypervolume contribution of each point of a non-dominated front, against
    ``nadir + range`` (a point extreme in any objective gets ``inf``)."""
    F = np.asarray(F, dtype=np.float64)
    if len(F) <= 2:
        return np.full(len(F), np.inf)
    lo, hi = F.min(axis=0), F.max(axis=0)
    ref = hi + np.where(hi > lo, hi - lo, 1.0)
    out = np.asarray(moocore.hv_contributions(F, ref=ref), dtype=np.float64)
    extreme = np.any((F == lo) | (F == hi), axis=1)
    return np.where(extreme, np.inf, out)


def reduce_one(F, v) -> int:
    """Index of the candidate SMS-EMOA drops from a pool of mu + 1."""
    F = np.asarray(F, dtype=np.float64).reshape(len(v), -1)
    v = np.asarray(v, dtype=np.float64)
    ranks = constrained_ranks(F, v)
    worst = np.flatnonzero(ranks == ranks.max())
    if v[worst[0]] > 0:  # an infeasible front: the largest violation goes
        return int(worst[np.argmax(v[worst])])
    if len(worst) == 1 or F.shape[1] == 1:  # one objective: a tie, the newest goes
        return int(worst[-1])
    finite = np.all(np.isfinite(F[worst]), axis=1)
    if not finite.all():  # non-finite objectives (failed candidates) go first
        return int(worst[np.flatnonzero(~finite)[0]])
    return int(worst[np.argmin(contributions(F[worst]))])


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

    def ask(self):
        s, d = self.settings, self.space.dim
        if not self.started:
            return self.space.uniform(self.rng, s.n)
        i, j = self.rng.choice(len(self.v), size=2, replace=False)
        lo, hi = self.space.lower, self.space.upper
        child, _ = sbx(self.X[i][None, :], self.X[j][None, :], lo, hi, s.eta_c, s.p_c, self.rng.random(1),
                       self.rng.random((1, d)), self.rng.random((1, d)), self.rng.random((1, d)))
        return polynomial_mutation(child, lo, hi, s.eta_m, self.p_m, self.rng.random((1, d)), self.rng.random((1, d)))

    def tell(self, X, f, v):
        F = np.asarray(f, dtype=np.float64).reshape(len(v), -1)
        if not self.started:
            self.X, self.f, self.v = X.copy(), F.copy(), np.asarray(v, dtype=np.float64).copy()
            self.started = True
            return True
        X_all, F_all = np.vstack([self.X, X]), np.vstack([self.f, F])
        v_all = np.concatenate([self.v, v])
        keep = np.delete(np.arange(len(v_all)), reduce_one(F_all, v_all))
        self.X, self.f, self.v = X_all[keep], F_all[keep], v_all[keep]
        self.steps += 1
        return self.steps % self.settings.n == 0
