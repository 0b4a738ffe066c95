"""heurtune: tune controllers of tank processes with metaheuristics.

Public entry points::

    heurtune.load_experiment(name) -> Experiment
    Experiment.problem(case) -> Problem   # .names .lower .upper .evaluate(X) .simulate(x)
"""

from heurtune.errors import ConfigError
from heurtune.problem import Evaluation, Experiment, Problem, load_experiment

__version__ = "0.1.0"
__all__ = ["ConfigError", "Evaluation", "Experiment", "Problem", "load_experiment", "__version__"]
