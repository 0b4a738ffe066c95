"""Particle swarm optimisation with Clerc & Kennedy's constriction coefficients, global best.

This is the "canonical" constriction PSO (Clerc & Kennedy 2002, IEEE TEC 6(1); Bratton &
Kennedy 2007, "Defining a standard for particle swarm optimization", gbest variant)::

    v <- w v + c1 r1 (p - x) + c2 r2 (g - x)
    x <- x + v

with ``w = chi = 0.7298`` and ``c1 = c2 = chi * 2.05 = 1.49618``, ``r1``, ``r2 ~ U(0, 1)`` drawn
per particle and per component, ``p`` the particle's personal best and ``g`` the best personal
best of the whole swarm (global-best topology). It is not SPSO-2011 (no random informant
topology, no hypersphere sampling); only its initialisation is borrowed from SPSO-2006:

* positions ``x0 ~ U(lo, hi)``; velocities ``v0 = (U(lo, hi) - x0) / 2``.

Choices where the standards leave room:

* Synchronous update: all particles move, the batch is evaluated, then the personal bests and
  ``g`` are updated (SPSO's C code updates ``g`` after each particle; a batch evaluator cannot).
* A personal best is replaced only when the new position is *strictly better* (comparator:
  Deb's rules or penalty), as in the SPSO reference code (``if f < p.f``); personal bests
  therefore never get worse and ties keep the old one.
* No velocity clamping (the constriction factor makes it unnecessary).
* Bounds: the engine clips (or reflects) each new position into the box; the particle's velocity
  is kept as it is (SPSO-2006 would zero the clamped components). A clipped particle therefore
  stays on the face until the attraction terms turn its outward velocity around; with
  ``bound_handling="reflect"`` its velocity still points the way it was going.
* ``n = 40``: the SPSO-2006 default swarm size for small dimensions.

One batch of ``n`` evaluations per generation.
"""

from __future__ import annotations

import dataclasses


from heurtune.core.engine import Optimizer
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class PSOSettings:
    n: int = dataclasses.field(default=40, metadata={"help": "particles (SPSO-2006 default)"})
    w: float = dataclasses.field(default=0.7298, metadata={"help": "inertia = constriction factor chi"})
    c1: float = dataclasses.field(default=1.49618, metadata={"help": "cognitive coefficient (chi * 2.05)"})
    c2: float = dataclasses.field(default=1.49618, metadata={"help": "social coefficient (chi * 2.05)"})

    def __post_init__(self):
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        if not 0 <= self.w < 1:
            raise ValueError(f"w must lie in [0, 1), got {self.w}")
        if not self.c1 >= 0:
            raise ValueError(f"c1 must be >= 0, got {self.c1}")
        if not self.c2 >= 0:
            raise ValueError(f"c2 must be >= 0, got {self.c2}")


def pso_step(X, V, P, g, r1, r2, w: float, c1: float, c2: float):
    """One constriction-PSO step; ``r1``, ``r2`` (n, d) ~ U(0, 1). Returns (new X, new V)."""
    V_new = w * V + c1 * r1 * (P - X) + c2 * r2 * (g - X)
    return X + V_new, V_new


@register("pso", settings=PSOSettings,
          source="Clerc & Kennedy (2002); Bratton & Kennedy (2007), gbest constriction PSO; SPSO-2006 initialisation",
          description="Constriction PSO, global best (chi = 0.7298, c1 = c2 = 1.49618; n evaluations per generation)")
class ParticleSwarm(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.V = None
        self.P = self.pf = self.pv = None

    def _gbest(self):
        return self.P[self.compare.best(self.pf, self.pv)]

    def ask(self):
        s, n, d = self.settings, self.settings.n, self.space.dim
        if self.P is None:
            X0 = self.space.uniform(self.rng, n)
            self.V = (self.space.uniform(self.rng, n) - X0) / 2.0
            return X0
        r1 = self.rng.random((n, d))
        r2 = self.rng.random((n, d))
        X_new, self.V = pso_step(self.X, self.V, self.P, self._gbest(), r1, r2, s.w, s.c1, s.c2)
        return X_new

    def tell(self, X, f, v):
        self.X, self.f, self.v = X.copy(), f.copy(), v.copy()
        if self.P is None:
            self.P, self.pf, self.pv = X.copy(), f.copy(), v.copy()
            return True
        improved = self.compare.better(f, v, self.pf, self.pv)
        self.P[improved], self.pf[improved], self.pv[improved] = X[improved], f[improved], v[improved]
        return True
