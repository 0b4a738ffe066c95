"""pymoo's single-objective algorithms in the registry, by name: ``pymoo:DE``, ``pymoo:GA``, ...

An optional extra (``pip install 'heurtune[pymoo]'``). The names of :data:`ALGORITHMS` become
ask/tell optimisers of the engine the first time a config or ``heurtune.minimize`` names them
with the prefix ``pymoo:``. pymoo's own ask and tell (``Algorithm.infill`` / ``advance``) drive
them; the bridge adds:

* **The unit box.** pymoo searches ``[0, 1]^d`` (the variables' bounds mapped linearly), so its
  operators' scales (SBX, polynomial mutation, DE's steps) fit every variable whatever its unit.
* **Generations as batches.** What pymoo asks for at once (its population, or its offspring
  per generation) is one batch of the evaluator; ``pop_size`` sets it where the algorithm has
  one (0 keeps pymoo's default).
* **The budget.** pymoo's termination is ``("n_evals", max_evals)`` of the run, and the engine
  stops asking when the budget is spent; an algorithm that ends by its own rule (Nelder-Mead's
  tolerances, say) ends the run with ``stop_reason = "finished"``.
* **The engine's ranking.** pymoo is told values whose order is the engine's
  (:func:`heurtune.algorithms.cmaes.ranking_values`), as one objective and no constraints, so
  Deb's rules or the penalty decide as they do for every other optimiser.
* **Seeds.** pymoo 0.6 draws from a ``numpy.random.Generator`` of its own
  (``Algorithm.random_state``); the bridge seeds it from the run's generator, so a seed gives
  the same run whatever else the process does.

Settings: ``pop_size``.

An exception inside pymoo ends the run with a one-line error naming the algorithm and pymoo's
version.
"""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np

from heurtune.algorithms._bridge import inside_library
from heurtune.algorithms.cmaes import ranking_values
from heurtune.core.engine import Optimizer
from heurtune.core.errors import ConfigError
from heurtune.core.registry import AlgorithmInfo, register_bridge

INSTALL = "pip install 'heurtune[pymoo]'"

#: The bridged names and where pymoo 0.6 keeps them (module under ``pymoo.algorithms.soo.nonconvex``,
#: class). Each takes a continuous box; ``pop_size`` applies to those marked True.
ALGORITHMS = {
    "DE": ("de", "DE", True),
    "GA": ("ga", "GA", True),
    "PSO": ("pso", "PSO", True),
    "ES": ("es", "ES", True),
    "SRES": ("sres", "SRES", True),
    "ISRES": ("isres", "ISRES", True),
    "G3PCX": ("g3pcx", "G3PCX", True),
    "NRBO": ("nrbo", "NRBO", True),
    "CMAES": ("cmaes", "CMAES", False),
}
# Not bridged: NelderMead and PatternSearch (pymoo's local searches ask for one Individual and
# expect one back, which pymoo 0.6.2's own Population-based ask/tell does not give them).


@dataclasses.dataclass(frozen=True)
class PymooSettings:
    """Settings of a bridged pymoo algorithm."""

    pop_size: int = dataclasses.field(default=0, metadata={
        "help": "population size where the algorithm has one; 0 = pymoo's default"})

    def __post_init__(self):
        if self.pop_size != 0 and self.pop_size < 2:
            raise ValueError(f"pop_size must be 0 (pymoo's default) or >= 2, got {self.pop_size}")


def _pymoo():
    try:
        import pymoo
    except ImportError:
        raise ConfigError(f"the pymoo: optimisers need pymoo: {INSTALL}") from None
    return pymoo


def _version() -> str:
    return getattr(_pymoo(), "__version__", "")


class PymooOptimizer(Optimizer):
    """One of pymoo's algorithms, ``pymoo_name``, asked and told through the engine (see the
    module docstring); a subclass per name is made by :func:`resolve`."""

    pymoo_name = ""

    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        _pymoo()
        self._budget = None
        self._alg = None
        self._problem = None
        self._pop = None
        self.finished = False

    def set_budget(self, max_evals) -> None:
        """The run's evaluation budget (None: unbounded), pymoo's ``("n_evals", budget)``."""
        self._budget = max_evals

    def _algorithm(self):
        if self._alg is None:
            from pymoo.core.problem import Problem

            module, cls_name, has_pop = ALGORITHMS[self.pymoo_name]
            cls = getattr(importlib.import_module(f"pymoo.algorithms.soo.nonconvex.{module}"), cls_name)
            kwargs = {"pop_size": self.settings.pop_size} if has_pop and self.settings.pop_size else {}
            if self.settings.pop_size and not has_pop:
                raise ConfigError(f"pymoo:{self.pymoo_name}: setting pop_size does not apply "
                                  "(the algorithm has no population); leave it 0")
            alg = cls(**kwargs)
            self._problem = Problem(n_var=self.space.dim, n_obj=1, xl=0.0, xu=1.0)
            budget = self._budget if self._budget is not None else 2**62
            alg.setup(self._problem, termination=("n_evals", budget), verbose=False,
                      seed=int(self.rng.integers(2**31 - 1)))
            self._alg = alg
        return self._alg

    def _inside(self, step, *args):
        return inside_library(f"pymoo:{self.pymoo_name}", f"pymoo {_version()}", step, *args)

    def _ask(self):
        """pymoo's next individuals still to evaluate (None when it is done). Individuals pymoo
        asks for again with their values known are not re-evaluated; a generation with none to
        evaluate goes straight back to pymoo."""
        alg = self._algorithm()
        while alg.has_next():
            pop = alg.infill()
            if pop is None:
                return None
            pending = [i for i, ind in enumerate(pop) if "F" not in ind.evaluated]
            if pending:
                return pop, pending
            alg.advance(infills=pop)
        return None

    def ask(self) -> np.ndarray:
        asked = self._inside(self._ask)
        if asked is None:
            # pymoo has nothing left to ask: the run ends after one repeat of the last
            # generation's best (the engine asks for at least one candidate)
            self.finished, self._pop = True, None
            if len(self.f):
                return self.X[[self.compare.best(self.f, self.v)]]
            return (self.space.lower + 0.5 * self.space.width)[None, :]
        self._pop, pending = asked
        U = np.asarray(self._pop.get("X"), dtype=np.float64).reshape(len(self._pop), self.space.dim)[pending]
        return self.space.lower + np.clip(U, 0.0, 1.0) * self.space.width

    def _tell(self, values):
        from pymoo.problems.static import StaticProblem

        self._alg.evaluator.eval(StaticProblem(self._problem, F=values[:, None]), self._pop)
        self._alg.advance(infills=self._pop)
        if not self._alg.has_next():
            self.finished = True

    def tell(self, X, f, v) -> bool:
        if self._pop is not None:
            self._inside(self._tell, ranking_values(f, v, self.compare))
        self.X, self.f, self.v = X, f, v
        return True


def resolve(name: str) -> AlgorithmInfo:
    """The registry entry of pymoo's algorithm ``name`` (a one-line ConfigError for a name the
    bridge does not know, listing those it does).

    Parameters
    ----------
    name : str
        Without the ``pymoo:`` prefix.

    Returns
    -------
    AlgorithmInfo
    """
    _pymoo()
    if name not in ALGORITHMS:
        raise ConfigError(f"the pymoo bridge has no algorithm {name!r}; allowed: {', '.join(ALGORITHMS)}")
    cls = type(f"Pymoo_{name}", (PymooOptimizer,), {"pymoo_name": name, "__module__": __name__})
    globals()[cls.__name__] = cls  # so that runs pickle by reference
    module, cls_name, _ = ALGORITHMS[name]
    return AlgorithmInfo(f"pymoo:{name}", cls, PymooSettings, f"pymoo's {name} (bridged, in the unit box)",
                         f"pymoo {_version()}: pymoo.algorithms.soo.nonconvex.{module}.{cls_name}", "population")


register_bridge("pymoo", resolve, "pymoo's single-objective algorithms, e.g. pymoo:DE, pymoo:GA",
                checked=("DE", "GA"))


def __getattr__(attr: str):
    """``Pymoo_<Name>`` made on demand (an unpickled run in a fresh process)."""
    if attr.startswith("Pymoo_"):
        resolve(attr[len("Pymoo_"):])
        return globals()[attr]
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")
