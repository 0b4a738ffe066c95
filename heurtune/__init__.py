"""heurtune: tune controllers of tank processes with metaheuristics.

Public entry points::

    heurtune.load_experiment(name) -> Experiment
    Experiment.problem(case) -> Problem   # .names .lower .upper .evaluate(X) .simulate(x)
    heurtune.minimize(fun, lower, upper, algorithm="cs", ...) -> Result
"""

from heurtune.engine import Result, minimize
from heurtune.errors import ConfigError
from heurtune.problem import Evaluation, Experiment, Problem, load_experiment

__version__ = "0.1.0"
__all__ = ["ConfigError", "Evaluation", "Experiment", "Problem", "Result", "load_experiment", "minimize",
           "__version__"]
