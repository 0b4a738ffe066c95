"""nevergrad's optimisers in the registry, by name: ``ng:NGOpt``, ``ng:TwoPointsDE``, ``ng:CMA``, ...

An optional extra (``pip install 'heurtune[nevergrad]'``). Any name of nevergrad's registry
(``nevergrad.optimizers.registry``, 500-odd) becomes an ask/tell optimiser of the engine the first
time a config or ``heurtune.minimize`` names it with the prefix ``ng:``. The bridge adds:

* **The unit box.** nevergrad searches ``[0, 1]^d`` (``ng.p.Array`` with those bounds, the
  variables' bounds mapped linearly), so its step sizes fit every variable whatever its unit.
* **Generations as batches.** Each generation asks ``batch`` candidates (nevergrad's
  ``num_workers``; default 10) and evaluates them as one batch of the evaluator.
* **The budget.** The optimiser is built when the engine gives the run's ``max_evals``
  (nevergrad's ``budget``, which NGOpt reads to choose its algorithm); the engine stops asking
  when the budget is spent, so no run evaluates more.
* **The engine's ranking.** nevergrad is told values whose order is the engine's
  (:func:`heurtune.algorithms.cmaes.ranking_values`): feasible candidates keep their objective
  (Deb's rules) or the penalised one, the others follow in the engine's order.
* **Seeds.** The parametrisation's ``random_state`` is seeded from the run's generator, so a
  seed gives the same run, whatever else the process does with NumPy's global state.

Settings: ``batch``.

An exception inside nevergrad ends the run with a one-line error naming the optimiser and
nevergrad's version. Known: with nevergrad 1.0.12 and NumPy 2, ``MetaModel`` (which NGOpt
picks for some small problems, e.g. 4 variables and 2,000 evaluations) fails in nevergrad's
``metamodel.py`` (``float`` of a one-element array); for 10 variables and 1,000-5,000
evaluations NGOpt picks CMA and runs.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.algorithms._bridge import inside_library
from heurtune.algorithms.cmaes import ranking_values
from heurtune.core.engine import Optimizer
from heurtune.core.errors import ConfigError
from heurtune.core.registry import AlgorithmInfo, register_bridge

INSTALL = "pip install 'heurtune[nevergrad]'"


@dataclasses.dataclass(frozen=True)
class NevergradSettings:
    """Settings of a bridged nevergrad optimiser."""

    batch: int = dataclasses.field(default=10, metadata={
        "help": "candidates per generation, evaluated as one batch (nevergrad's num_workers)"})

    def __post_init__(self):
        if self.batch < 1:
            raise ValueError(f"batch must be >= 1, got {self.batch}")


def _nevergrad():
    try:
        import nevergrad
    except ImportError:
        raise ConfigError(f"the ng: optimisers need nevergrad: {INSTALL}") from None
    return nevergrad


class NevergradOptimizer(Optimizer):
    """One of nevergrad's optimisers, ``ng_name``, asked and told through the engine (see the
    module docstring); a subclass per name is made by :func:`resolve`."""

    ng_name = ""

    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self._ng = _nevergrad()
        self._budget = None
        self._opt = None
        self._asked = []

    def set_budget(self, max_evals) -> None:
        """The run's evaluation budget (None: unbounded), nevergrad's ``budget``."""
        self._budget = max_evals

    def _optimizer(self):
        if self._opt is None:
            param = self._ng.p.Array(shape=(self.space.dim,), lower=0.0, upper=1.0)
            param.random_state = np.random.RandomState(int(self.rng.integers(2**31 - 1)))
            self._opt = self._ng.optimizers.registry[self.ng_name](
                parametrization=param, budget=self._budget, num_workers=self.settings.batch)
        return self._opt

    def _inside(self, step, *args):
        return inside_library(f"ng:{self.ng_name}", f"nevergrad {getattr(self._ng, '__version__', '')}", step, *args)

    def _ask(self):
        opt = self._optimizer()
        return [opt.ask() for _ in range(self.settings.batch)]

    def ask(self) -> np.ndarray:
        self._asked = self._inside(self._ask)
        U = np.array([c.value for c in self._asked], dtype=np.float64)
        return self.space.lower + np.clip(U, 0.0, 1.0) * self.space.width

    def _tell(self, values):
        for candidate, value in zip(self._asked, values):
            self._opt.tell(candidate, float(value))

    def tell(self, X, f, v) -> bool:
        self._inside(self._tell, ranking_values(f, v, self.compare))
        self.X, self.f, self.v = X, f, v
        return True


def resolve(name: str) -> AlgorithmInfo:
    """The registry entry of nevergrad's optimiser ``name`` (a one-line ConfigError for a name
    nevergrad does not have, naming some it has).

    Parameters
    ----------
    name : str
        Without the ``ng:`` prefix.

    Returns
    -------
    AlgorithmInfo
    """
    ng = _nevergrad()
    if name not in ng.optimizers.registry:
        known = ", ".join(n for n in ("NGOpt", "TwoPointsDE", "CMA", "PSO", "DE", "OnePlusOne")
                          if n in ng.optimizers.registry)
        raise ConfigError(f"nevergrad has no optimiser {name!r} (e.g. {known}; all: "
                          "nevergrad.optimizers.registry)")
    cls = type(f"Nevergrad_{name}", (NevergradOptimizer,), {"ng_name": name, "__module__": __name__})
    globals()[cls.__name__] = cls  # so that runs pickle by reference
    return AlgorithmInfo(f"ng:{name}", cls, NevergradSettings, f"nevergrad's {name} (bridged, in the unit box)",
                         f"nevergrad {getattr(ng, '__version__', '')}: {name}", "population")


# NGOpt is not in the checked names: on the contract's 4-variable problems it picks MetaModel,
# which fails under NumPy 2 in nevergrad 1.0.12 (see the module docstring).
register_bridge("ng", resolve, "nevergrad's optimisers, e.g. ng:NGOpt, ng:TwoPointsDE",
                checked=("CMA", "TwoPointsDE", "PSO"))


def __getattr__(attr: str):
    """``Nevergrad_<Name>`` made on demand (an unpickled run in a fresh process)."""
    if attr.startswith("Nevergrad_"):
        resolve(attr[len("Nevergrad_"):])
        return globals()[attr]
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")
