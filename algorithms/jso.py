"""jSO: L-SHADE with parameter schedules and a weighted mutation (Brest, Maucec & Boskovic 2017,
"Single objective real-parameter optimization: algorithm jSO", IEEE CEC 2017, an entry of
its competition on bound-constrained optimisation; the successor of iL-SHADE, Brest, Maucec &
Boskovic 2016).

A generation is L-SHADE's (:mod:`heurtune.algorithms.lshade`: success-history memories,
current-to-pbest with an archive, binomial crossover, halfway repair, one-to-one selection,
linear population size reduction), with these changes, all functions of the run's progress
``t = nfe / max_nfe`` (the engine tells the optimiser its ``max_evals``; without one ``t``
stays 0 and the population at ``N_init``):

* **Population:** ``N_init = round(25 ln(D) sqrt(D))`` (at least ``N_min = 4``), archive rate 1.
* **Memories:** ``H = 5`` slots, ``M_F = 0.3`` and ``M_CR = 0.8`` at the start; the last slot
  holds ``M_F = M_CR = 0.9`` for the whole run and is never updated.
* **CR floor:** ``CR_i = max(CR_i, 0.7)`` while ``t < 0.25``, ``max(CR_i, 0.6)`` while
  ``t < 0.5`` (:func:`cr_floor`).
* **F cap:** ``F_i = min(F_i, 0.7)`` while ``t < 0.6`` (:func:`f_cap`).
* **Weighted mutation, current-to-pbest-w/1:**
  ``v = x_i + Fw_i (x_pbest - x_i) + F_i (x_r1 - x_r2)`` with ``Fw = 0.7 F`` while
  ``t < 0.2``, ``0.8 F`` while ``t < 0.4``, ``1.2 F`` after (:func:`weighted_f`).
* **Greediness:** ``p`` grows linearly from ``p_max / 2`` to ``p_max = 0.25`` (:func:`jso_p`).
* **Memory update:** the mean of the old value and the weighted Lehmer mean of the successes,
  ``M_k = (mean_WL(S) + M_k) / 2`` for F and CR, with L-SHADE's terminal rule for CR
  (:func:`update_memory`); ``k`` cycles over the first ``H - 1`` slots.

Defaults are the paper's; the update steps are the pure functions below, pinned in
``tests/algorithms/test_jso.py``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heurtune.algorithms.lshade import LSHADE, TERMINAL
from heurtune.algorithms.lshade import update_memory as lshade_update_memory
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class JSOSettings:
    n_min: int = dataclasses.field(default=4, metadata={"help": "final population size"})
    memory: int = dataclasses.field(default=5, metadata={"help": "success-history slots H (the last one fixed at 0.9)"})
    p_max: float = dataclasses.field(default=0.25, metadata={"help": "share of the best members for pbest at the end "
                                                                      "(p_max / 2 at the start)"})
    archive_rate: float = dataclasses.field(default=1.0, metadata={"help": "archive size = this x N"})

    def __post_init__(self):
        if self.n_min < 4:
            raise ValueError(f"n_min must be >= 4 (current-to-pbest needs four distinct vectors), got {self.n_min}")
        if self.memory < 2:
            raise ValueError(f"memory must be >= 2 (one slot is the fixed 0.9), got {self.memory}")
        if not 0 < self.p_max <= 1:
            raise ValueError(f"p_max must lie in (0, 1], got {self.p_max}")
        if not self.archive_rate >= 0:
            raise ValueError(f"archive_rate must be >= 0, got {self.archive_rate}")


def initial_population(dim: int, n_min: int = 4) -> int:
    """``round(25 ln(D) sqrt(D))``, at least ``n_min`` (D = 10: 182).

    Parameters
    ----------
    dim : int
    n_min : int

    Returns
    -------
    int
    """
    return max(n_min, int(round(25.0 * math.log(dim) * math.sqrt(dim)))) if dim > 1 else n_min


def cr_floor(cr, t: float) -> np.ndarray:
    """``max(CR, 0.7)`` while ``t < 0.25``, ``max(CR, 0.6)`` while ``t < 0.5``, else ``CR``.

    Parameters
    ----------
    cr : ndarray
    t : float
        The fraction of the budget spent.

    Returns
    -------
    ndarray
    """
    cr = np.asarray(cr, dtype=np.float64)
    if t < 0.25:
        return np.maximum(cr, 0.7)
    if t < 0.5:
        return np.maximum(cr, 0.6)
    return cr


def f_cap(f, t: float) -> np.ndarray:
    """``min(F, 0.7)`` while ``t < 0.6``, else ``F``.

    Parameters
    ----------
    f : ndarray
    t : float
        The fraction of the budget spent.

    Returns
    -------
    ndarray
    """
    f = np.asarray(f, dtype=np.float64)
    return np.minimum(f, 0.7) if t < 0.6 else f


def weighted_f(f, t: float) -> np.ndarray:
    """The weight of the pbest term: ``0.7 F`` while ``t < 0.2``, ``0.8 F`` while ``t < 0.4``,
    ``1.2 F`` after.

    Parameters
    ----------
    f : ndarray
    t : float
        The fraction of the budget spent.

    Returns
    -------
    ndarray
    """
    f = np.asarray(f, dtype=np.float64)
    return (0.7 if t < 0.2 else 0.8 if t < 0.4 else 1.2) * f


def jso_p(t: float, p_max: float = 0.25) -> float:
    """``p`` from ``p_max / 2`` at ``t = 0`` to ``p_max`` at ``t = 1``, linearly.

    Parameters
    ----------
    t : float
        The fraction of the budget spent.
    p_max : float

    Returns
    -------
    float
    """
    p_min = p_max / 2
    return p_min + (p_max - p_min) * min(max(t, 0.0), 1.0)


def current_to_pbest_w(X, F, Fw, pbest, r1, r2_vectors):
    """``v_i = x_i + Fw_i (x_pbest_i - x_i) + F_i (x_r1_i - x_r2_i)`` (rows).

    Parameters
    ----------
    X : ndarray (n, d)
    F, Fw : ndarray (n,)
        Scale factors of the difference and of the pbest term.
    pbest, r1 : ndarray of int (n,)
    r2_vectors : ndarray (n, d)
        ``x_r2`` rows (from the population or the archive).

    Returns
    -------
    ndarray (n, d)
    """
    F = np.asarray(F, dtype=np.float64)[:, None]
    Fw = np.asarray(Fw, dtype=np.float64)[:, None]
    return X + Fw * (X[pbest] - X) + F * (X[r1] - r2_vectors)


def update_memory(m_cr: float, m_f: float, s_cr, s_f, delta) -> tuple:
    """The new ``(M_CR[k], M_F[k])``: each the mean of its old value and L-SHADE's update (the
    weighted Lehmer mean of the generation's successes, :func:`heurtune.algorithms.lshade.update_memory`,
    whose terminal rule for ``M_CR`` holds); unchanged without successes.

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
    cr, f = lshade_update_memory(m_cr, m_f, s_cr, s_f, delta)
    return (TERMINAL if cr == TERMINAL else 0.5 * (cr + m_cr)), 0.5 * (f + m_f)


@register("jso", settings=JSOSettings, description="jSO: L-SHADE with parameter schedules and a weighted mutation",
          source="Brest, Maucec & Boskovic (2017), CEC 2017")
class JSO(LSHADE):
    """jSO (see the module docstring)."""

    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.m_cr = np.full(settings.memory, 0.8)
        self.m_f = np.full(settings.memory, 0.3)
        self.m_cr[-1] = self.m_f[-1] = 0.9

    def _initial_size(self, dim: int) -> int:
        return initial_population(dim, self.settings.n_min)

    def _progress(self) -> float:
        return self.nfe / self.max_nfe if self.max_nfe else 0.0

    def _parameters(self, slots) -> tuple:
        t = self._progress()
        CR, F = super()._parameters(slots)
        return cr_floor(CR, t), f_cap(F, t)

    def _p(self) -> float:
        return jso_p(self._progress(), self.settings.p_max)

    def _mutant(self, X, F, pbest, r1, r2_vectors) -> np.ndarray:
        return current_to_pbest_w(X, F, weighted_f(F, self._progress()), pbest, r1, r2_vectors)

    def _remember(self, s_cr, s_f, delta) -> None:
        self.m_cr[self.k], self.m_f[self.k] = update_memory(self.m_cr[self.k], self.m_f[self.k], s_cr, s_f, delta)
        if len(s_cr):
            self.k = (self.k + 1) % (self.settings.memory - 1)  # the last slot stays 0.9
