"""Firefly algorithm as in Yang's reference codes ``fa_ndim.m`` / ``ffa_mincon.m``.

One generation (``n`` evaluations):

1. ``alpha <- (1 - delta) alpha`` with ``delta = 1 - (1e-4 / 0.9)^(1 / max_generations)``
   (Yang's ``alpha_new``; the decay comes first, as in his main loop).
2. Sort the evaluated fireflies best-first with the comparator (Deb's rules or penalty) and keep
   a snapshot ``xs`` of the sorted positions and their fitness.
3. For each firefly ``i`` (sorted order) and each ``j`` of the snapshot, if ``j`` is strictly
   better than ``i``'s evaluated fitness (Yang: ``Lightn(i) > Lighto(j)``)::

       r    = ||x_i - xs_j||                  (x_i: i's current, possibly already moved position)
       beta = (beta0 - beta_min) exp(-gamma r^2) + beta_min
       x_i <- x_i (1 - beta) + xs_j beta + alpha (U(0,1)^d - 0.5) |Ub - Lb|

4. The moved fireflies are the new population (no greedy selection); the engine clips them into
   the box (Yang's ``findlimits``) and evaluates them.

Consequences of the reference rules kept here: the best firefly (and any firefly tied with it)
has no brighter neighbour, so it does not move at all - it is re-evaluated unchanged, which makes
the scheme implicitly elitist; every other firefly moves once per brighter neighbour.

Choices where the sources leave room (documented defaults):

* ``alpha = 0.3``: the thesis's randomness ``mu = 0.3`` (Yang suggests 0.25-0.5).
* ``beta0 = 0.3``: the thesis's ``beta = 0.3``, read as the attractiveness at ``r = 0``
  (Yang's code uses ``beta0 = 1``).
* ``beta_min = 0.2``: Yang's code (the thesis does not name it). With ``beta0 = 0.3`` the
  attractiveness therefore lies in [0.2, 0.3].
* ``gamma = 1``: thesis and Yang's code.
* ``max_generations = 100``: the thesis's ``T = 100``; it only sets the decay rate ``delta``
  (the run length is the engine's business), so alpha falls to ``0.3 * 1e-4 / 0.9`` after 100
  generations and keeps decaying geometrically afterwards.
* Distance: ``r`` is measured to the snapshot position ``xs_j``, the point ``i`` is attracted to.
  (``fa_ndim.m`` measures it to ``ns(j,:)``, which for ``j < i`` may already have moved; we take
  the self-consistent reading.)
* The comparator decides "brighter", so constrained problems use Deb's rules instead of the
  penalty-in-the-objective of ``ffa_mincon.m``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.core.engine import Optimizer
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class FireflySettings:
    n: int = dataclasses.field(default=100, metadata={"help": "fireflies"})
    alpha: float = dataclasses.field(
        default=0.3, metadata={"help": "initial randomness (thesis mu = 0.3), times |Ub - Lb|"}
    )
    beta0: float = dataclasses.field(default=0.3, metadata={"help": "attractiveness at r = 0 (thesis beta = 0.3)"})
    beta_min: float = dataclasses.field(default=0.2, metadata={"help": "attractiveness floor (Yang's code: 0.2)"})
    gamma: float = dataclasses.field(default=1.0, metadata={"help": "light absorption coefficient"})
    max_generations: int = dataclasses.field(
        default=100, metadata={"help": "sets only the alpha decay: delta = 1 - (1e-4/0.9)^(1/max_generations)"})

    def __post_init__(self):
        if self.n < 2:
            raise ValueError(f"n must be >= 2, got {self.n}")
        if not self.alpha >= 0:
            raise ValueError(f"alpha must be >= 0, got {self.alpha}")
        if not 0 <= self.beta0 <= 1:
            raise ValueError(f"beta0 must lie in [0, 1], got {self.beta0}")
        if not 0 <= self.beta_min <= 1:
            raise ValueError(f"beta_min must lie in [0, 1], got {self.beta_min}")
        if not self.gamma >= 0:
            raise ValueError(f"gamma must be >= 0, got {self.gamma}")
        if self.max_generations < 1:
            raise ValueError(f"max_generations must be >= 1, got {self.max_generations}")


def alpha_decay_delta(max_generations: int) -> float:
    """Yang's ``delta = 1 - (1e-4 / 0.9)^(1 / MaxGeneration)``.

    Parameters
    ----------
    max_generations : int

    Returns
    -------
    float
    """
    return 1.0 - (1e-4 / 0.9) ** (1.0 / max_generations)


def brighter_matrix(compare, f, v) -> np.ndarray:
    """``B[i, j]``: is firefly ``j`` strictly better than firefly ``i``?

    Parameters
    ----------
    compare : Comparator
    f, v : ndarray (n,)
        Objectives and total violations.

    Returns
    -------
    ndarray (n, n) of bool
    """
    f, v = np.asarray(f), np.asarray(v)
    return np.asarray(compare.better(f[None, :], v[None, :], f[:, None], v[:, None]), dtype=bool)


def move_fireflies(X_sorted, brighter, uniform_draws, alpha: float, beta0: float, beta_min: float,
                   gamma: float, scale):
    """Move every firefly towards every brighter one of the snapshot ``X_sorted``.

    ``brighter`` (n, n): ``brighter[i, j]`` = snapshot firefly ``j`` is strictly better than
    firefly ``i``; ``uniform_draws`` (n, n, d) ~ U(0, 1), the draw of pair (i, j) is used only
    when ``brighter[i, j]``; ``scale`` = |Ub - Lb|. Firefly ``i`` visits ``j = 0, 1, ...`` in
    order, each move starting from where the previous one left it. Fireflies do not interact
    within a generation, so the loop runs over ``j`` and moves all attracted ``i`` at once.

    Parameters
    ----------
    X_sorted : ndarray (n, d)
    brighter : ndarray (n, n) of bool
    uniform_draws : ndarray (n, n, d)
    alpha, beta0, beta_min, gamma : float
        Yang's randomisation, attractiveness at distance 0, its floor, and absorption.
    scale : ndarray (d,)

    Returns
    -------
    ndarray (n, d)
    """
    Xs = np.asarray(X_sorted, dtype=np.float64)
    X = Xs.copy()
    brighter = np.asarray(brighter, dtype=bool)
    for j in range(Xs.shape[0]):
        idx = np.flatnonzero(brighter[:, j])
        if idx.size == 0:
            continue
        r2 = ((X[idx] - Xs[j]) ** 2).sum(axis=1)
        beta = ((beta0 - beta_min) * np.exp(-gamma * r2) + beta_min)[:, None]
        X[idx] = X[idx] * (1.0 - beta) + Xs[j] * beta + alpha * (uniform_draws[idx, j] - 0.5) * scale
    return X


@register(
    "firefly",
    settings=FireflySettings,
    source="Yang (2009/2010); Yang, fa_ndim.m / ffa_mincon.m",
    description="Firefly algorithm: move towards every brighter firefly, decaying randomness "
    "(n evaluations per generation)",
)
class Firefly(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.alpha = settings.alpha
        self.delta = alpha_decay_delta(settings.max_generations)
        self.started = False

    def ask(self):
        s, n, d = self.settings, self.settings.n, self.space.dim
        if not self.started:
            return self.space.uniform(self.rng, n)
        self.alpha *= 1.0 - self.delta
        order = self.compare.order(self.f, self.v)
        Xs, fs, vs = self.X[order], self.f[order], self.v[order]
        u = self.rng.random((n, n, d))
        return move_fireflies(Xs, brighter_matrix(self.compare, fs, vs), u, self.alpha, s.beta0,
                              s.beta_min, s.gamma, np.abs(self.space.width))

    def tell(self, X, f, v):
        self.X, self.f, self.v = X.copy(), f.copy(), v.copy()
        self.started = True
        return True
