"""heurtune: tune controllers of tank processes with metaheuristics.

Public entry points::

    heurtune.load_experiment(name) -> experiment of its plant family (QTP: Experiment)
    experiment.problem(case) -> TuningProblem   # .names .lower .upper .evaluate(X) .simulate(x)
    heurtune.minimize(fun, lower, upper, algorithm="cs", ...) -> Result
    heurtune.load_results("results/NAME") -> Results   # .runs .history .summary .margins .best()

The package is split by role: ``heurtune.core`` (registries, engine, evaluator, execution,
problem contract), ``heurtune.runner`` (configs, experiments, the evaluate command),
``heurtune.analysis`` (statistics, reports, exports, figures); plant families live in
``heurtune.objectives.<family>`` and optimisers in ``heurtune.algorithms`` (docs/architecture.md).
"""

from heurtune import _startup

_startup.guard()  # python -m heurtune.<command>: Ctrl-C during the imports is one line, exit 130

from heurtune.core.engine import Result, minimize  # noqa: E402
from heurtune.core.errors import ConfigError  # noqa: E402
from heurtune.core.families import register_family  # noqa: E402
from heurtune.core.problem import Evaluation, ExperimentBase, TuningProblem  # noqa: E402
from heurtune.core.registry import register  # noqa: E402
from heurtune.runner.config import load_experiment  # noqa: E402

# The QTP family's classes, imported when first asked for: ``import heurtune`` loads no plant
# family (each is imported when a config names its model, heurtune.core.families).
_LAZY = {"Experiment": "heurtune.objectives.qtp.family", "Problem": "heurtune.objectives.qtp.problem",
         # the results of a folder as DataFrames (imports the analysis, statistics included)
         "load_results": "heurtune.analysis.results", "Results": "heurtune.analysis.results"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'heurtune' has no attribute {name!r}")

__version__ = "0.1.0"
__all__ = ["ConfigError", "Evaluation", "Experiment", "ExperimentBase", "Problem", "Result", "Results", "TuningProblem",
           "load_experiment", "load_results", "minimize", "register", "register_family", "__version__"]
