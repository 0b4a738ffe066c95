"""Accelerated particle swarm optimisation (Yang, *Nature-Inspired Metaheuristic Algorithms*,
2nd ed. 2010, sec. 8.3).

APSO keeps neither velocities nor personal bests. Every generation moves every particle:

* ``alpha <- gamma * alpha`` (the decay comes first, so generation k uses
  ``alpha0 * gamma**k``);
* ``x <- x + beta (g* - x) + alpha z (Ub - Lb)`` with ``z ~ N(0, 1)`` per component,

where ``g*`` is the best candidate evaluated so far (kept by the optimiser and updated from every
evaluated batch through the comparator, so Deb's rules and the penalty mode both apply). There is
no greedy selection: the swarm is always the moved one. The engine clips (or reflects) the moved
particles into the box, as ``simplebounds`` does in Yang's code. One batch of ``n`` evaluations
per generation.

Defaults: ``n = 25`` (thesis Table 5.1), ``alpha0 = 0.2``, ``gamma = 0.95``, ``beta = 0.5``
(Yang's recommended values).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.core.engine import Optimizer
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class APSOSettings:
    n: int = dataclasses.field(default=25, metadata={"help": "particles (thesis Table 5.1: 25)"})
    alpha0: float = dataclasses.field(default=0.2, metadata={"help": "initial randomness, times the box width"})
    gamma: float = dataclasses.field(default=0.95, metadata={"help": "alpha decay factor per generation"})
    beta: float = dataclasses.field(default=0.5, metadata={"help": "attraction towards the best so far"})

    def __post_init__(self):
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        if not self.alpha0 >= 0:
            raise ValueError(f"alpha0 must be >= 0, got {self.alpha0}")
        if not 0 < self.gamma <= 1:
            raise ValueError(f"gamma must lie in (0, 1], got {self.gamma}")
        if not 0 <= self.beta <= 1:
            raise ValueError(f"beta must lie in [0, 1], got {self.beta}")


def apso_move(X, gbest, z, alpha: float, beta: float, width):
    """One APSO move; ``z`` (n, d) ~ N(0, 1), ``width`` = Ub - Lb.

    Parameters
    ----------
    X : ndarray (n, d)
        Positions.
    gbest : ndarray (d,)
        The best so far.
    z : ndarray (n, d)
        Draws ~ N(0, 1).
    alpha, beta : float
        Noise and attraction.
    width : ndarray (d,)
        ``Ub - Lb``.

    Returns
    -------
    ndarray (n, d)
    """
    return X + beta * (gbest - X) + alpha * z * width


@register(
    "apso",
    settings=APSOSettings,
    source="Yang (2010), Nature-Inspired Metaheuristic Algorithms, sec. 8.3",
    description="Accelerated PSO: move towards the best so far plus decaying Gaussian noise "
    "(n evaluations per generation)",
)
class AcceleratedPSO(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.alpha = settings.alpha0
        self.generation = 0
        self.g_x = None
        self.g_f = np.inf
        self.g_v = np.inf

    def ask(self):
        s = self.settings
        if self.g_x is None:
            return self.space.uniform(self.rng, s.n)
        self.alpha *= s.gamma
        self.generation += 1
        z = self.rng.normal(size=(s.n, self.space.dim))
        return apso_move(self.X, self.g_x, z, self.alpha, s.beta, self.space.width)

    def tell(self, X, f, v):
        self.X, self.f, self.v = X.copy(), f.copy(), v.copy()
        i = self.compare.best(f, v)
        if self.g_x is None or self.compare.better(f[i], v[i], self.g_f, self.g_v):
            self.g_x = np.array(X[i], dtype=np.float64)
            self.g_f, self.g_v = float(f[i]), float(v[i])
        return True
