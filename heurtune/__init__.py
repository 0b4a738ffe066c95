"""heurtune: tune controllers of tank processes with metaheuristics.

Public entry points::

    heurtune.load_experiment(name) -> experiment of its plant family (QTP: Experiment)
    experiment.problem(case) -> TuningProblem   # .names .lower .upper .evaluate(X) .simulate(x)
    heurtune.minimize(fun, lower, upper, algorithm="cs", ...) -> Result

The package is split by role: ``heurtune.core`` (registries, engine, evaluator, execution,
problem contract), ``heurtune.runner`` (configs, experiments, the evaluate command),
``heurtune.analysis`` (statistics, reports, exports, figures); plant families live in
``heurtune.objectives.<family>`` and optimisers in ``heurtune.algorithms`` (docs/architecture.md).
"""

from heurtune.core.engine import Result, minimize
from heurtune.core.errors import ConfigError
from heurtune.core.families import register_family
from heurtune.core.problem import Evaluation, ExperimentBase, TuningProblem
from heurtune.core.registry import register
from heurtune.objectives.qtp.family import Experiment
from heurtune.objectives.qtp.problem import Problem
from heurtune.runner.config import load_experiment

__version__ = "0.1.0"
__all__ = ["ConfigError", "Evaluation", "Experiment", "ExperimentBase", "Problem", "Result", "TuningProblem",
           "load_experiment", "minimize", "register", "register_family", "__version__"]
