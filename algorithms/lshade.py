"""L-SHADE: success-history adaptive differential evolution with linear population size
reduction (Tanabe & Fukunaga 2014, CEC 2014; SHADE: Tanabe & Fukunaga 2013).

One generation evaluates one trial vector per member (a batch of N):

* **Parameters from the success history.** Memories ``M_CR``, ``M_F`` of ``H`` slots start at
  0.5. Member i draws a slot r_i; ``CR_i ~ N(M_CR[r_i], 0.1)`` clipped to [0, 1] (0 once the
  slot holds the terminal value), ``F_i ~ Cauchy(M_F[r_i], 0.1)``, drawn again while
  ``F_i <= 0`` and cut to 1 above it.
* **current-to-pbest/1 with an archive**: ``v = x_i + F_i (x_pbest - x_i) + F_i (x_r1 - x_r2)``,
  ``x_pbest`` one of the best ``max(2, round(p N))`` members, ``x_r1`` a member other than i,
  ``x_r2`` a member or archived vector other than i and r1.
* **Binomial crossover** with one component always from ``v``; a component outside the box is
  put halfway between the parent's component and the bound it crossed.
* **Selection**: a trial no worse than its parent (the engine's order: Deb's rules or penalty)
  replaces it; a strictly better one sends the parent to the archive and records ``CR_i``,
  ``F_i`` and the improvement ``|f(u) - f(x)|`` (violation under Deb's rules when either is
  infeasible).
* **Memory update** (slot k, cycling): weighted Lehmer means of the successful ``F`` and
  ``CR``, weights the improvements; ``M_CR[k]`` becomes terminal once it or ``max S_CR`` is 0.
* **Linear population size reduction**: after each generation the population shrinks to
  ``round(N_init + (N_min - N_init) nfe / max_nfe)``, the worst members leaving, and the
  archive to ``round(r_arc N)``. ``max_nfe`` is the run's ``max_evals`` (the engine tells the
  optimiser its budget); without one the population stays at ``N_init``.

Defaults are the paper's: ``N_init = 18 D``, ``N_min = 4``, ``H = 6``, ``p = 0.11``,
``r_arc = 2.6``. The update steps are the pure functions below, pinned in
``tests/algorithms/test_lshade.py``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.core.engine import Optimizer
from heurtune.core.registry import register

TERMINAL = -1.0  # the terminal value of an M_CR slot (the paper's bottom symbol)


@dataclasses.dataclass(frozen=True)
class LSHADESettings:
    n_init_per_dim: float = dataclasses.field(default=18.0, metadata={"help": "initial population N_init = this x D"})
    n_min: int = dataclasses.field(default=4, metadata={"help": "final population size"})
    memory: int = dataclasses.field(default=6, metadata={"help": "success-history slots H"})
    p: float = dataclasses.field(default=0.11, metadata={"help": "share of the best members for pbest"})
    archive_rate: float = dataclasses.field(default=2.6, metadata={"help": "archive size = this x N"})

    def __post_init__(self):
        if not self.n_init_per_dim > 0:
            raise ValueError(f"n_init_per_dim must be positive, got {self.n_init_per_dim}")
        if self.n_min < 4:
            raise ValueError(f"n_min must be >= 4 (current-to-pbest needs four distinct vectors), got {self.n_min}")
        if self.memory < 1:
            raise ValueError(f"memory must be >= 1, got {self.memory}")
        if not 0 < self.p <= 1:
            raise ValueError(f"p must lie in (0, 1], got {self.p}")
        if not self.archive_rate >= 0:
            raise ValueError(f"archive_rate must be >= 0, got {self.archive_rate}")


def sample_cr(m_cr, rng) -> np.ndarray:
    """``CR_i ~ N(M_CR, 0.1)`` clipped to [0, 1]; 0 where the slot is terminal.

    Parameters
    ----------
    m_cr : ndarray (n,)
        The memory slot of each individual (``TERMINAL``, -1: terminal).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray (n,)
    """
    m_cr = np.asarray(m_cr, dtype=np.float64)
    cr = np.clip(m_cr + 0.1 * rng.standard_normal(m_cr.shape), 0.0, 1.0)
    return np.where(m_cr == TERMINAL, 0.0, cr)


def sample_f(m_f, rng) -> np.ndarray:
    """``F_i ~ Cauchy(M_F, 0.1)``, drawn again while ``F_i <= 0``, cut to 1 above it.

    Parameters
    ----------
    m_f : ndarray (n,)
    rng : numpy.random.Generator

    Returns
    -------
    ndarray (n,)
    """
    m_f = np.asarray(m_f, dtype=np.float64)
    f = m_f + 0.1 * np.tan(np.pi * (rng.random(m_f.shape) - 0.5))
    bad = f <= 0
    while bad.any():
        f[bad] = m_f[bad] + 0.1 * np.tan(np.pi * (rng.random(int(bad.sum())) - 0.5))
        bad = f <= 0
    return np.minimum(f, 1.0)


def current_to_pbest(X, F, pbest, r1, r2_vectors):
    """``v_i = x_i + F_i (x_pbest_i - x_i) + F_i (x_r1_i - x_r2_i)`` (rows).

    Parameters
    ----------
    X : ndarray (n, d)
    F : ndarray (n,)
    pbest, r1 : ndarray of int (n,)
    r2_vectors : ndarray (n, d)

    Returns
    -------
    ndarray (n, d)
    """
    F = np.asarray(F, dtype=np.float64)[:, None]
    return X + F * (X[pbest] - X) + F * (X[r1] - r2_vectors)


def binomial_crossover(X, V, CR, j_rand, uniform):
    """``u_ij = v_ij`` where ``uniform_ij <= CR_i`` or ``j = j_rand_i``, else ``x_ij``.

    Parameters
    ----------
    X, V : ndarray (n, d)
        Parents and mutants.
    CR : ndarray (n,)
    j_rand : ndarray of int (n,)
    uniform : ndarray (n, d)

    Returns
    -------
    ndarray (n, d)
    """
    take = uniform <= np.asarray(CR, dtype=np.float64)[:, None]
    take[np.arange(len(X)), j_rand] = True
    return np.where(take, V, X)


def halfway_repair(U, X, lower, upper):
    """A component of trial ``U`` below ``lower`` becomes ``(lower + x) / 2``, above ``upper``
    ``(upper + x) / 2`` (x the parent's component).

    Parameters
    ----------
    U, X : ndarray (n, d)
        Trials and parents.
    lower, upper : ndarray (d,)

    Returns
    -------
    ndarray (n, d)
    """
    U = np.where(U < lower, 0.5 * (lower + X), U)
    return np.where(U > upper, 0.5 * (upper + X), U)


def lehmer_mean(values, weights) -> float:
    """Weighted Lehmer mean ``sum w s^2 / sum w s``, weights normalised to sum 1.

    Parameters
    ----------
    values, weights : ndarray

    Returns
    -------
    float
    """
    s = np.asarray(values, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    return float(np.sum(w * s * s) / np.sum(w * s))


def update_memory(m_cr: float, m_f: float, s_cr, s_f, delta) -> tuple:
    """The new ``(M_CR[k], M_F[k])`` from the successes of a generation (unchanged without any).

    Parameters
    ----------
    m_cr, m_f : float
        The memory slot's values.
    s_cr, s_f : ndarray
        The successful CR and F of the generation.
    delta : ndarray
        Their improvements (the weights).

    Returns
    -------
    tuple of float
    """
    if len(s_cr) == 0:
        return m_cr, m_f
    delta = np.asarray(delta, dtype=np.float64)
    if not np.sum(delta) > 0:
        delta = np.ones_like(delta)
    if m_cr == TERMINAL or max(s_cr) == 0:
        new_cr = TERMINAL
    else:
        new_cr = lehmer_mean(s_cr, delta)
    return new_cr, lehmer_mean(s_f, delta)


def population_size(nfe: int, max_nfe: int, n_init: int, n_min: int) -> int:
    """Linear population size reduction: ``round(n_init + (n_min - n_init) nfe / max_nfe)``,
    at least ``n_min``.

    Parameters
    ----------
    nfe : int
        Evaluations spent.
    max_nfe : int
        The budget.
    n_init, n_min : int

    Returns
    -------
    int
    """
    if not max_nfe:
        return n_init
    return max(n_min, int(round(n_init + (n_min - n_init) * min(nfe, max_nfe) / max_nfe)))


@register("lshade", settings=LSHADESettings, description="L-SHADE: success-history DE with linear population reduction",
          source="Tanabe & Fukunaga (2014), CEC 2014")
class LSHADE(Optimizer):
    """L-SHADE (see the module docstring)."""

    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.n_init = self._initial_size(space.dim)
        self.max_nfe = 0
        self.nfe = 0
        self.m_cr = np.full(settings.memory, 0.5)
        self.m_f = np.full(settings.memory, 0.5)
        self.k = 0
        self.archive = np.zeros((0, space.dim))
        self.pop = None  # (X, f, v) of the population once evaluated

    def set_budget(self, max_evals) -> None:
        """The run's evaluation budget (the engine calls this), which sets the reduction."""
        self.max_nfe = int(max_evals or 0)

    # -- the steps a successor (jSO) changes --------------------------------------------------
    def _initial_size(self, dim: int) -> int:
        return max(self.settings.n_min, int(round(self.settings.n_init_per_dim * dim)))

    def _parameters(self, slots) -> tuple:
        """``(CR, F)`` of the members drawing the memory slots ``slots``."""
        return sample_cr(self.m_cr[slots], self.rng), sample_f(self.m_f[slots], self.rng)

    def _p(self) -> float:
        """The share of the best members ``x_pbest`` is drawn from."""
        return self.settings.p

    def _mutant(self, X, F, pbest, r1, r2_vectors) -> np.ndarray:
        return current_to_pbest(X, F, pbest, r1, r2_vectors)

    def _remember(self, s_cr, s_f, delta) -> None:
        """Update slot ``k`` from a generation's successes and move on when there were any."""
        self.m_cr[self.k], self.m_f[self.k] = update_memory(self.m_cr[self.k], self.m_f[self.k], s_cr, s_f, delta)
        if len(s_cr):
            self.k = (self.k + 1) % self.settings.memory

    # -- one generation ------------------------------------------------------------------------
    def ask(self) -> np.ndarray:
        if self.pop is None:
            self._trial = None
            return self.space.uniform(self.rng, self.n_init)
        X, f, v = self.pop
        n, d = X.shape
        slots = self.rng.integers(0, self.settings.memory, n)
        CR, F = self._parameters(slots)
        order = self.compare.order(f, v)
        top = order[:max(2, int(round(self._p() * n)))]
        pbest = top[self.rng.integers(0, len(top), n)]
        r1 = _distinct(self.rng, n, n, [np.arange(n)])
        pool = np.vstack([X, self.archive])
        r2 = _distinct(self.rng, n, len(pool), [np.arange(n), r1])
        V = self._mutant(X, F, pbest, r1, pool[r2])
        U = binomial_crossover(X, V, CR, self.rng.integers(0, d, n), self.rng.random((n, d)))
        U = halfway_repair(U, X, self.space.lower, self.space.upper)
        self._trial = (CR, F)
        return U

    def tell(self, U, fu, vu) -> bool:
        self.nfe += len(U)
        if self.pop is None:
            self.pop = (np.array(U), np.array(fu, dtype=np.float64), np.array(vu, dtype=np.float64))
        else:
            X, f, v = (a.copy() for a in self.pop)
            CR, F = self._trial
            fu = np.asarray(fu, dtype=np.float64)
            vu = np.asarray(vu, dtype=np.float64)
            not_worse = ~self.compare.better(f, v, fu, vu)
            better = self.compare.better(fu, vu, f, v)
            both_feasible = (v <= 0) & (vu <= 0)
            with np.errstate(invalid="ignore"):  # inf - inf: no measurable improvement
                delta = np.where(both_feasible, np.abs(f - fu), np.abs(v - vu))
            delta = np.where(np.isfinite(delta), delta, 0.0)
            self.archive = np.vstack([self.archive, X[better]])
            X[not_worse], f[not_worse], v[not_worse] = U[not_worse], fu[not_worse], vu[not_worse]
            self._remember(CR[better], F[better], delta[better])
            self.pop = (X, f, v)
        self._reduce()
        self.X, self.f, self.v = self.pop
        return True

    def _archive_rate(self) -> float:
        return self.settings.archive_rate

    def _reduce(self) -> None:
        """Shrink the population (the worst leave) and the archive (random members leave)."""
        X, f, v = self.pop
        n = population_size(self.nfe, self.max_nfe, self.n_init, self.settings.n_min)
        if n < len(X):
            keep = np.sort(self.compare.order(f, v)[:n])
            self.pop = (X[keep], f[keep], v[keep])
        size = int(round(self._archive_rate() * len(self.pop[0])))
        if len(self.archive) > size:
            self.archive = self.archive[np.sort(self.rng.permutation(len(self.archive))[:size])]


def _distinct(rng, n: int, high: int, avoid) -> np.ndarray:
    """For each of n rows an index in [0, high) different from ``avoid[k][i]`` for every k."""
    out = rng.integers(0, high, n)
    clash = np.zeros(n, dtype=bool)
    for a in avoid:
        clash |= out == a
    while clash.any():
        out[clash] = rng.integers(0, high, int(clash.sum()))
        clash[:] = False
        for a in avoid:
            clash |= out == a
    return out

