"""Cuckoo search (Yang & Deb 2009; Yang's reference code ``cuckoo_search_new.m``).

One generation = a Levy-flight phase (n evaluations) and a discovery phase (n evaluations):

* Levy flights by Mantegna's algorithm, ``beta = 1.5``: ``step = u / |v|^(1/beta)`` with
  ``u ~ N(0, sigma_u^2)``, ``v ~ N(0, 1)`` per component; ``x' = x + 0.01 step (x - best) z``,
  ``z ~ N(0, 1)``; each nest keeps the better of old and new (ties go to the new one, as in the
  reference code).
* Discovery: each component is abandoned with probability ``pa``: ``K = U(0,1) > pa``,
  ``x'' = x + r (x[perm1] - x[perm2]) K`` with one scalar ``r ~ U(0, 1)`` and two random
  permutations of the nests; greedy replacement again.

Candidates are clipped to the bounds by the engine (``simplebounds`` in the reference code).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heurtune.core.engine import Optimizer
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class CSSettings:
    n: int = dataclasses.field(default=25, metadata={"help": "nests (thesis Table 5.1: 25)"})
    pa: float = dataclasses.field(default=0.25, metadata={"help": "discovery probability per component"})
    beta: float = dataclasses.field(default=1.5, metadata={"help": "Levy exponent (Mantegna)"})
    step_scale: float = dataclasses.field(default=0.01, metadata={"help": "Levy step factor"})

    def __post_init__(self):
        if self.n < 3:
            raise ValueError(f"n must be >= 3, got {self.n}")
        if not 0 <= self.pa <= 1:
            raise ValueError(f"pa must lie in [0, 1], got {self.pa}")
        if not 0 < self.beta <= 2:
            raise ValueError(f"beta must lie in (0, 2], got {self.beta}")
        if not self.step_scale > 0:
            raise ValueError(f"step_scale must be positive, got {self.step_scale}")


def mantegna_sigma(beta: float) -> float:
    """sigma_u of Mantegna's algorithm for a Levy-stable step of index ``beta``.

    Parameters
    ----------
    beta : float

    Returns
    -------
    float
    """
    num = math.gamma(1 + beta) * math.sin(math.pi * beta / 2)
    den = math.gamma((1 + beta) / 2) * beta * 2 ** ((beta - 1) / 2)
    return (num / den) ** (1 / beta)


def levy_flight(nests, best, u, v, z, beta: float, step_scale: float):
    """New nests by Levy flights; ``u`` (n, d) ~ N(0, sigma_u^2), ``v``, ``z`` (n, d) ~ N(0, 1).

    Parameters
    ----------
    nests : ndarray (n, d)
    best : ndarray (d,)
    u, v, z : ndarray (n, d)
        The draws.
    beta : float
        Levy index.
    step_scale : float

    Returns
    -------
    ndarray (n, d)
    """
    step = u / np.abs(v) ** (1.0 / beta)
    return nests + step_scale * step * (nests - best) * z


def discovery(nests, k_uniform, perm1, perm2, r: float, pa: float):
    """Abandon-and-rebuild step; ``k_uniform`` (n, d) ~ U(0, 1), ``r`` ~ U(0, 1).

    Parameters
    ----------
    nests : ndarray (n, d)
    k_uniform : ndarray (n, d)
        Draws ~ U(0, 1): a coordinate moves where ``> pa``.
    perm1, perm2 : ndarray (n,)
        Permutations of the nests.
    r : float
        Draw ~ U(0, 1), the step size.
    pa : float
        Discovery probability.

    Returns
    -------
    ndarray (n, d)
    """
    keep_moving = k_uniform > pa
    return nests + r * (nests[perm1] - nests[perm2]) * keep_moving


@register("cs", settings=CSSettings, source="Yang & Deb (2009); Yang, cuckoo_search_new.m",
          description="Cuckoo search: Mantegna Levy flights + discovery (2n evaluations per generation)")
class CuckooSearch(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.phase = "init"
        self.sigma_u = mantegna_sigma(settings.beta)

    def _best(self):
        return self.X[self.compare.best(self.f, self.v)]

    def ask(self):
        s, n, d = self.settings, self.settings.n, self.space.dim
        if self.phase == "init":
            return self.space.uniform(self.rng, n)
        if self.phase == "levy":
            u = self.rng.normal(0.0, self.sigma_u, (n, d))
            v = self.rng.normal(size=(n, d))
            z = self.rng.normal(size=(n, d))
            return levy_flight(self.X, self._best(), u, v, z, s.beta, s.step_scale)
        k = self.rng.random((n, d))
        r = self.rng.random()
        perm1, perm2 = self.rng.permutation(n), self.rng.permutation(n)
        return discovery(self.X, k, perm1, perm2, r, s.pa)

    def tell(self, X, f, v):
        if self.phase == "init":
            self.X, self.f, self.v = X.copy(), f.copy(), v.copy()
            self.phase = "levy"
            return True
        take = ~self.compare.better(self.f, self.v, f, v)  # new unless strictly worse
        self.X[take], self.f[take], self.v[take] = X[take], f[take], v[take]
        if self.phase == "levy":
            self.phase = "discovery"
            return False
        self.phase = "levy"
        return True
