"""Real-coded genetic algorithm: tournament, SBX, polynomial mutation, (mu + lambda) survival.

One generation = ``n_offspring`` evaluations (the initial population: ``n``):

* Parent selection: binary tournaments decided by the run's comparator (Deb's feasibility
  rules by default: feasible beats infeasible, two feasible by f, two infeasible by total
  violation; or the static penalty). Contestants are paired from random permutations of the
  population, so every individual enters two tournaments per ``n`` parents (tournament
  without replacement, as in Deb's NSGA-II code); a tie is broken by a fair coin.
* Simulated binary crossover (Deb & Agrawal 1995), ``eta_c = 15``, applied to a pair with
  probability ``p_c = 0.9``; within a crossed pair each variable is recombined with
  probability 0.5 and the two children's values are swapped with probability 0.5. The
  *bounded* form is used (Deb's NSGA-II reference C code, ``realcross``): the spread factor
  of each child is drawn from the polynomial distribution truncated at the box face on its
  side, so children land in the box (a final clip only removes rounding).
* Polynomial mutation (Deb & Goyal 1996), ``eta_m = 20``, each variable with probability
  ``p_m = 1/d``; bounded form (same code, ``real_mutate_ind``): the perturbation is scaled
  by the box width and shrinks near a face.
* Survival: parents and offspring together, ranked by the comparator (stable: a parent ties
  ahead of a child), keep the best ``n``. The best candidate is therefore never lost.
  Duplicates are not removed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.core.engine import Optimizer
from heurtune.core.registry import register

EPS = 1e-14  # parents closer than this in a variable are not recombined (Deb's code)


@dataclasses.dataclass(frozen=True)
class GASettings:
    n: int = dataclasses.field(default=100, metadata={"help": "population size (pymoo's default 100)"})
    n_offspring: int = dataclasses.field(default=0, metadata={"help": "children per generation; 0 = n"})
    eta_c: float = dataclasses.field(default=15.0, metadata={"help": "SBX distribution index"})
    p_c: float = dataclasses.field(default=0.9, metadata={"help": "crossover probability per pair"})
    eta_m: float = dataclasses.field(default=20.0, metadata={"help": "polynomial mutation distribution index"})
    p_m: float = dataclasses.field(default=0.0, metadata={"help": "mutation probability per variable; 0 = 1/d"})

    def __post_init__(self):
        if self.n < 2:
            raise ValueError(f"n must be >= 2, got {self.n}")
        if self.n_offspring < 0:
            raise ValueError(f"n_offspring must be >= 0 (0 = n), got {self.n_offspring}")
        check_variation(self)


def check_variation(settings) -> None:
    """The checks of the SBX and mutation settings (``eta_c``, ``p_c``, ``eta_m``, ``p_m``)
    shared by the optimisers built on these operators (ValueError naming the setting).

    Parameters
    ----------
    settings : dataclass
        With ``eta_c``, ``p_c``, ``eta_m`` and ``p_m``.
    """
    if not settings.eta_c >= 0:
        raise ValueError(f"eta_c must be >= 0, got {settings.eta_c}")
    if not 0 <= settings.p_c <= 1:
        raise ValueError(f"p_c must lie in [0, 1], got {settings.p_c}")
    if not settings.eta_m >= 0:
        raise ValueError(f"eta_m must be >= 0, got {settings.eta_m}")
    if not 0 <= settings.p_m <= 1:
        raise ValueError(f"p_m must lie in [0, 1] (0 = 1/d), got {settings.p_m}")


def tournament(f, v, a, b, coin, compare):
    """Winners of binary tournaments ``a[k]`` vs ``b[k]`` (index arrays).

    ``coin`` (k,) ~ U(0, 1) breaks ties: ``a`` wins a tie when ``coin < 0.5``.

    Parameters
    ----------
    f, v : ndarray
        Objectives and total violations.
    a, b : ndarray of int
    coin : ndarray (k,)
    compare : Comparator

    Returns
    -------
    ndarray of int
    """
    f, v = np.asarray(f), np.asarray(v)
    a, b = np.asarray(a), np.asarray(b)
    a_better = compare.better(f[a], v[a], f[b], v[b])
    b_better = compare.better(f[b], v[b], f[a], v[a])
    take_a = a_better | (~b_better & (np.asarray(coin) < 0.5))
    return np.where(take_a, a, b)


def _sbx_betaq(u, alpha, eta):
    """Inverse CDF of SBX's (truncated) spread-factor distribution."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        low = (u * alpha) ** (1.0 / (eta + 1.0))
        high = (1.0 / (2.0 - u * alpha)) ** (1.0 / (eta + 1.0))
    return np.where(u <= 1.0 / alpha, low, high)


def sbx(p1, p2, lower, upper, eta, p_c, u_pair, u_var, u_beta, u_swap):
    """Bounded simulated binary crossover of parent rows ``p1``, ``p2`` (k, d).

    Injected draws, all ~ U(0, 1): ``u_pair`` (k,) crosses a pair when ``<= p_c``; ``u_var``
    (k, d) recombines a variable when ``<= 0.5``; ``u_beta`` (k, d) is the spread draw (one
    per variable, shared by both children); ``u_swap`` (k, d) swaps the children's values
    when ``<= 0.5``. Per recombined variable with ``y1 = min``, ``y2 = max`` of the parents::

        beta  = 1 + 2 (y1 - lower) / (y2 - y1)       (child 1; child 2: (upper - y2))
        alpha = 2 - beta^-(eta + 1)
        betaq = (u alpha)^(1/(eta+1))                 if u <= 1/alpha
              = (1 / (2 - u alpha))^(1/(eta+1))       otherwise
        c1 = (y1 + y2 - betaq1 (y2 - y1)) / 2,  c2 = (y1 + y2 + betaq2 (y2 - y1)) / 2

    Returns the two children (k, d), clipped to the box.

    Parameters
    ----------
    p1, p2 : ndarray (k, d)
        Parents.
    lower, upper : ndarray (d,)
    eta : float
        Distribution index.
    p_c : float
        Crossover probability per pair.
    u_pair, u_var, u_beta, u_swap : ndarray
        The draws.
    """
    p1, p2 = np.atleast_2d(np.asarray(p1, dtype=np.float64)), np.atleast_2d(np.asarray(p2, dtype=np.float64))
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    y1, y2 = np.minimum(p1, p2), np.maximum(p1, p2)
    gap = y2 - y1
    active = (np.asarray(u_pair)[:, None] <= p_c) & (np.asarray(u_var) <= 0.5) & (gap > EPS)
    safe_gap = np.where(active, gap, 1.0)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        beta1 = 1.0 + 2.0 * (y1 - lower) / safe_gap
        beta2 = 1.0 + 2.0 * (upper - y2) / safe_gap
        alpha1 = 2.0 - beta1 ** -(eta + 1.0)
        alpha2 = 2.0 - beta2 ** -(eta + 1.0)
    c1 = 0.5 * (y1 + y2 - _sbx_betaq(u_beta, alpha1, eta) * gap)
    c2 = 0.5 * (y1 + y2 + _sbx_betaq(u_beta, alpha2, eta) * gap)
    c1, c2 = np.clip(c1, lower, upper), np.clip(c2, lower, upper)
    swap = np.asarray(u_swap) <= 0.5
    child1 = np.where(active, np.where(swap, c2, c1), p1)
    child2 = np.where(active, np.where(swap, c1, c2), p2)
    return child1, child2


def polynomial_mutation(X, lower, upper, eta, p_m, u_do, u_delta):
    """Bounded polynomial mutation of the rows of ``X`` (k, d).

    Injected draws ~ U(0, 1): ``u_do`` (k, d) mutates a variable when ``<= p_m``; ``u_delta``
    (k, d) is the perturbation draw ``u``. With ``d1 = (x - lower) / w``, ``d2 = (upper - x)
    / w``, ``w = upper - lower``::

        u <= 0.5:  dq = (2u + (1 - 2u) (1 - d1)^(eta+1))^(1/(eta+1)) - 1
        u >  0.5:  dq = 1 - (2(1 - u) + 2(u - 0.5) (1 - d2)^(eta+1))^(1/(eta+1))
        x' = x + dq w   (clipped to the box)

    Variables with zero width are left alone.

    Parameters
    ----------
    X : ndarray (k, d)
    lower, upper : ndarray (d,)
    eta : float
        Distribution index.
    p_m : float
        Mutation probability per variable.
    u_do, u_delta : ndarray (k, d)
        The draws.

    Returns
    -------
    ndarray (k, d)
    """
    X = np.atleast_2d(np.asarray(X, dtype=np.float64))
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    width = upper - lower
    mutate = (np.asarray(u_do) <= p_m) & (width > 0)
    w = np.where(width > 0, width, 1.0)
    d1, d2 = (X - lower) / w, (upper - X) / w
    u = np.asarray(u_delta, dtype=np.float64)
    power = 1.0 / (eta + 1.0)
    with np.errstate(invalid="ignore"):
        low = (2.0 * u + (1.0 - 2.0 * u) * (1.0 - d1) ** (eta + 1.0)) ** power - 1.0
        high = 1.0 - (2.0 * (1.0 - u) + 2.0 * (u - 0.5) * (1.0 - d2) ** (eta + 1.0)) ** power
    dq = np.where(u <= 0.5, low, high)
    return np.where(mutate, np.clip(X + dq * width, lower, upper), X)


def survive(f, v, n, compare):
    """Indices of the ``n`` best of a merged parent + offspring pool (best first).

    Parameters
    ----------
    f, v : ndarray
        Objectives and total violations of the pool.
    n : int
    compare : Comparator

    Returns
    -------
    ndarray of int
    """
    return compare.order(f, v)[:n]


@register("ga", settings=GASettings,
          source="Deb & Agrawal (1995) SBX; Deb & Goyal (1996) mutation; Deb (2000) tournament; "
                 "bounded operators of Deb's NSGA-II code; pymoo GA defaults",
          description="Real-coded GA: Deb-rule tournament, bounded SBX, polynomial mutation, (mu+lambda)")
class GeneticAlgorithm(Optimizer):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.started = False

    @property
    def n_offspring(self) -> int:
        return self.settings.n_offspring or self.settings.n

    @property
    def p_m(self) -> float:
        return self.settings.p_m or 1.0 / self.space.dim

    def _contestants(self, k):
        """2k population indices from concatenated random permutations, paired in order."""
        n = len(self.f)
        reps = -(-2 * k // n)
        idx = np.concatenate([self.rng.permutation(n) for _ in range(reps)])[:2 * k]
        return idx[0::2], idx[1::2]

    def ask(self):
        s, d = self.settings, self.space.dim
        if not self.started:
            return self.space.uniform(self.rng, s.n)
        pairs = -(-self.n_offspring // 2)
        a, b = self._contestants(2 * pairs)
        parents = tournament(self.f, self.v, a, b, self.rng.random(2 * pairs), self.compare)
        p1, p2 = self.X[parents[0::2]], self.X[parents[1::2]]
        lo, hi = self.space.lower, self.space.upper
        c1, c2 = sbx(p1, p2, lo, hi, s.eta_c, s.p_c, self.rng.random(pairs), self.rng.random((pairs, d)),
                     self.rng.random((pairs, d)), self.rng.random((pairs, d)))
        children = np.empty((2 * pairs, d))
        children[0::2], children[1::2] = c1, c2
        children = children[:self.n_offspring]
        k = len(children)
        return polynomial_mutation(children, lo, hi, s.eta_m, self.p_m, self.rng.random((k, d)),
                                   self.rng.random((k, d)))

    def tell(self, X, f, v):
        if not self.started:
            self.X, self.f, self.v = X.copy(), f.copy(), v.copy()
            self.started = True
            return True
        X_all = np.vstack([self.X, X])
        f_all, v_all = np.concatenate([self.f, f]), np.concatenate([self.v, v])
        keep = survive(f_all, v_all, self.settings.n, self.compare)
        self.X, self.f, self.v = X_all[keep], f_all[keep], v_all[keep]
        return True
