"""CMA-ES (Hansen & Ostermeier 2001; Hansen 2016, "The CMA Evolution Strategy: A Tutorial")
through pycma, the reference implementation (``cma``, maintained by N. Hansen).

heurtune does not re-implement the strategy: pycma's ``CMAEvolutionStrategy`` asks and is told,
one generation per batch of the evaluator. This module adds what the engine needs:

* **Normalised coordinates.** pycma searches the unit box ``[0, 1]^d`` (the variables' bounds
  mapped linearly) with its default boundary handling (``BoundTransform``: a smooth, piecewise
  quadratic map of the genotype into the box), so one ``sigma0`` fits every variable whatever
  its unit.
* **The engine's ranking.** CMA-ES uses only the order of a generation's values. pycma is told
  values whose order is the engine's (:func:`ranking_values`): the objective of the feasible
  candidates (Deb's rules) or the penalised objective (``"penalty"``), and after them the
  infeasible and non-finite ones in the engine's order.
* **Randomness from heurtune's generator.** pycma draws through its ``randn`` option, here the
  run's ``numpy.random.Generator``; its ``seed`` option is off, so pycma never touches NumPy's
  global random state and a seed gives the same run whatever else the process does.
* **Restarts.** When pycma's termination criteria fire (``tolx``, ``tolfun``, stagnation, ...)
  and the engine's budget is not spent, the strategy restarts from a uniform random point:
  ``restarts = "ipop"`` (default; Auger & Hansen 2005) multiplies the population by
  ``incpopsize`` at each restart, ``"none"`` keeps it (a plain restart), ``"stop"`` ends the run.

Settings: ``popsize`` (0: pycma's default ``4 + floor(3 ln d)``), ``sigma0`` (initial step in
the unit box, default 0.3, the value pycma's documentation suggests for a box of width 1),
``restarts`` and ``incpopsize`` (default 2). Needs at least two variables (pycma).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from heurtune.core.engine import Optimizer
from heurtune.core.errors import ConfigError
from heurtune.core.registry import register

RESTARTS = ("ipop", "none", "stop")
CONSTRAINTS = ("engine", "al")


@dataclasses.dataclass(frozen=True)
class CMAESSettings:
    popsize: int = dataclasses.field(default=0, metadata={"help": "population lambda; 0 = pycma's 4 + floor(3 ln d)"})
    sigma0: float = dataclasses.field(default=0.3, metadata={"help": "initial step size in the unit box"})
    restarts: str = dataclasses.field(default="ipop", metadata={
        "help": "after pycma's termination: ipop (population x incpopsize), none (same population) or stop"})
    incpopsize: float = dataclasses.field(default=2.0, metadata={"help": "population factor of an IPOP restart"})
    constraints: str = dataclasses.field(default="engine", metadata={
        "help": "engine (rank as the engine does: Deb's rules or the penalty) or al (pycma's "
                "augmented Lagrangian on the constraint values)"})

    def __post_init__(self):
        if self.popsize != 0 and self.popsize < 2:
            raise ValueError(f"popsize must be 0 (pycma's default) or >= 2, got {self.popsize}")
        if not 0 < self.sigma0 <= 1:
            raise ValueError(f"sigma0 must lie in (0, 1] (a step in the unit box), got {self.sigma0}")
        if self.restarts not in RESTARTS:
            raise ValueError(f"restarts must be one of {', '.join(RESTARTS)}, got {self.restarts!r}")
        if not self.incpopsize >= 1:
            raise ValueError(f"incpopsize must be >= 1, got {self.incpopsize}")
        if self.constraints not in CONSTRAINTS:
            raise ValueError(f"constraints must be one of {', '.join(CONSTRAINTS)}, got {self.constraints!r}")


def ranking_values(f, v, compare) -> np.ndarray:
    """Finite values whose order is ``compare``'s order of a generation, for pycma's ``tell``.

    In the engine's order (:meth:`Comparator.order`), the leading candidates with a finite
    score keep it (the objective of the feasible ones under Deb's rules, the penalised objective
    under ``"penalty"``); the others (feasible with an objective that is not finite, infeasible
    ones under Deb's rules) follow as ``top + 1 + k + max(violation so far)``, k their place
    after the leading ones. The values are non-decreasing along the engine's order, so pycma
    ranks as the engine does; where they are the objective, pycma's tolerances read them.

    Parameters
    ----------
    f, v : ndarray (n,)
        Objectives and total violations.
    compare : Comparator
        The engine's ranking.

    Returns
    -------
    ndarray (n,)
    """
    f = np.asarray(f, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    order = compare.order(f, v)
    score = compare.merit(f, v) if compare.mode == "penalty" else np.where(v <= 0, f, np.inf)
    ranked = score[order]
    head = len(ranked) if np.all(np.isfinite(ranked)) else int(np.argmin(np.isfinite(ranked)))
    out = np.empty(len(f))
    out[order[:head]] = ranked[:head]
    tail = order[head:]
    if tail.size:
        top = ranked[head - 1] if head else 0.0
        worse = np.maximum.accumulate(np.where(np.isfinite(v[tail]), v[tail], 0.0))
        out[tail] = top + 1.0 + np.arange(tail.size) + worse
    return out


def _cma():
    try:
        import cma
    except ImportError:  # a dependency of heurtune; this guards broken installs
        raise ConfigError("optimiser 'cmaes' needs pycma: pip install cma") from None
    return cma


def _quiet_augmented_lagrangian(cma):
    """pycma's ``AugmentedLagrangian`` without its file loggers: built with logging on, it creates
    ``./outcmaes/`` in the working directory and writes ``outauglag*.dat`` files there."""

    class QuietAugmentedLagrangian(cma.constraints_handler.AugmentedLagrangian):
        def _init_(self):
            self.logging = 0
            super()._init_()

    return QuietAugmentedLagrangian


@register("cmaes", settings=CMAESSettings, description="CMA-ES (pycma) with IPOP restarts, in the unit box",
          source="Hansen & Ostermeier 2001; Auger & Hansen 2005 (IPOP); pycma")
class CMAES(Optimizer):
    """CMA-ES through pycma (see the module docstring)."""

    uses_constraint_values = True  # read only with constraints = "al"

    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        if space.dim < 2:
            raise ConfigError("cmaes needs at least 2 variables (pycma's CMA-ES), got 1")
        self._cma = _cma()
        self._popsize = settings.popsize
        self.restarts = 0
        self._start(0.5 * np.ones(space.dim))

    def _start(self, x0) -> None:
        opts = {"bounds": [[0.0] * self.space.dim, [1.0] * self.space.dim], "seed": float("nan"),
                "randn": lambda *shape: self.rng.standard_normal(shape), "verbose": -9, "verb_log": 0,
                "verb_disp": 0}
        if self._popsize:
            opts["popsize"] = int(self._popsize)
        self.es = self._cma.CMAEvolutionStrategy(list(x0), self.settings.sigma0, opts)
        self._popsize = self.es.popsize
        self._al = None  # the augmented Lagrangian starts afresh with each strategy

    def ask(self) -> np.ndarray:
        self._genotypes = self.es.ask()
        return self.space.lower + np.array(self._genotypes) * self.space.width

    def _al_values(self, f, v) -> np.ndarray:
        """The values pycma's ``ConstrainedFitnessAL`` gives the generation (objective plus the
        augmented Lagrangian of the constraint values), its coefficients updated after. Where
        there are no constraints, or none of the candidates has finite values, the engine's
        ranking; candidates with a value that is not finite rank after the others, in the
        engine's order."""
        g = getattr(self, "constraint_values", None)
        f = np.asarray(f, dtype=np.float64)
        finite = np.isfinite(f) & (np.all(np.isfinite(g), axis=1) if g is not None and g.size else True)
        if g is None or g.shape[1] == 0 or not finite.any():
            return ranking_values(f, v, self.compare)
        if self._al is None:
            self._al = self._cma.ConstrainedFitnessAL(lambda x: self._fk, lambda x: self._gk,
                                                      dimension=self.space.dim, archives=False, logging=0)
            self._al._al = _quiet_augmented_lagrangian(self._cma)(self.space.dim)
        out = np.empty(len(f))
        with warnings.catch_warnings():
            # pycma warns (several lines) when a generation's values give its coefficients
            # nothing to scale by, as a first generation of equally failed candidates does; it
            # then keeps its defaults, which is all a user could do about it
            warnings.simplefilter("ignore", UserWarning)
            for k in np.flatnonzero(finite):
                self._fk, self._gk = float(f[k]), list(g[k])
                out[k] = self._al(self._genotypes[k])
            self._al.update(self.es)
        tail = np.flatnonzero(~finite)
        if tail.size:
            tail = tail[self.compare.order(f[tail], v[tail])]
            out[tail] = out[finite].max() + 1.0 + np.arange(tail.size)
        return out

    def tell(self, X, f, v) -> bool:
        values = (self._al_values(f, v) if self.settings.constraints == "al"
                  else ranking_values(f, v, self.compare))
        self.es.tell(self._genotypes, values.tolist())
        self.X, self.f, self.v = X, f, v
        if self.es.stop():
            if self.settings.restarts == "stop":
                self.finished = True
            else:
                if self.settings.restarts == "ipop":
                    self._popsize = int(round(self._popsize * self.settings.incpopsize))
                self.restarts += 1
                self._start(self.rng.random(self.space.dim))
        return True
