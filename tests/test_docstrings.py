"""numpydoc sections on the public API, in the manner of python-control's docstring test.

For every public function of the modules below (their ``__all__``, or the names without a
leading underscore), the docstring has a ``Parameters`` section naming each parameter of the
signature (``*args``, ``**kwargs`` and keyword-only ones too; private ones, ``_name``, aside),
and a ``Returns`` (or ``Yields``) section when the signature declares a return value other
than None. The list holds every public module of heurtune, its optimisers and its two plant
families; ``heurtune.algorithms._gradient`` (private) and the plant-family plugins in
``experiments/plugins`` are not on it.
"""

import importlib
import inspect
import re

import pytest

MODULES = [
    "heurtune",
    "heurtune.analysis.agreement",
    "heurtune.analysis.runs",
    "heurtune.analysis.stats",
    "heurtune.analysis.render",
    "heurtune.analysis.side_by_side",
    "heurtune.analysis.compare",
    "heurtune.analysis.results",
    "heurtune.analysis.export",
    "heurtune.analysis.anytime",
    "heurtune.analysis.figures",
    "heurtune.core.engine",
    "heurtune.core.problem",
    "heurtune.core.structures",
    "heurtune.core.families",
    "heurtune.core.plugins",
    "heurtune.core.registry",
    "heurtune.core.robust",
    "heurtune.core.pareto",
    "heurtune.core.io",
    "heurtune.core.schema",
    "heurtune.core.evaluator",
    "heurtune.core.testfunctions",
    "heurtune.core.contract",
    "heurtune.core.family_contract",
    "heurtune.core.cli",
    "heurtune.runner.config",
    "heurtune.runner.resultdir",
    "heurtune.runner.experiment",
    "heurtune.runner.workplan",
    "heurtune.runner.progress",
    "heurtune.runner.evaluate",
    "heurtune.runner.check_plugin",
    "heurtune.runner.precompile",
    "heurtune.objectives.qtp",
    "heurtune.objectives.qtp.batch_design",
    "heurtune.objectives.qtp.bond_graph",
    "heurtune.objectives.qtp.continuous",
    "heurtune.objectives.qtp.continuous_kernels",
    "heurtune.objectives.qtp.controllers",
    "heurtune.objectives.qtp.gpu",
    "heurtune.objectives.qtp.loop",
    "heurtune.objectives.qtp.margins",
    "heurtune.objectives.qtp.model",
    "heurtune.objectives.qtp.oustaloup",
    "heurtune.objectives.qtp.problem",
    "heurtune.objectives.qtp.structure_checks",
    "heurtune.objectives.qtp.structures",
    "heurtune.objectives.qtp.structures.fopid",
    "heurtune.objectives.qtp.structures.pid",
    "heurtune.objectives.qtp.thesis.printed",
    "heurtune.objectives.qtp.thesis.tables",
    "heurtune.objectives.tito.design",
    "heurtune.objectives.tito.model",
    "heurtune.objectives.tito.problem",
    "heurtune.objectives.tito.report",
    "heurtune.objectives.tito.sim",
    "heurtune.objectives.tito.sweep",
    "heurtune.objectives.tito.kharitonov",
    "heurtune.objectives.tito.papers.printed",
    "heurtune.objectives.tito.papers.simulated",
    "heurtune.objectives.tito.papers.tables",
    "heurtune.objectives.tito.papers.figures",
    "heurtune.objectives.tito.two_tank",
    "heurtune.objectives.tito.family",
    "heurtune.analysis.report",
    "heurtune.core.errors",
    "heurtune.core.execution",
    "heurtune.core.lockstep",
    "heurtune.objectives.qtp.family",
    "heurtune.objectives.qtp.kernels",
    "heurtune.objectives.qtp.structures.ladr",
    "heurtune.objectives.qtp.structures.lqi_family",
    "heurtune.objectives.qtp.thesis.figures",
    "heurtune.objectives.robustness",
    "heurtune.objectives.tito.kernels",
    "heurtune.objectives.tito.two_tank_kernels",
    "heurtune.runner.machine",
    "heurtune.algorithms.apso",
    "heurtune.algorithms.bfgs",
    "heurtune.algorithms.dfp",
    "heurtune.algorithms.newton_raphson",
    "heurtune.algorithms.steepest_descent",
    "heurtune.algorithms.cmaes",
    "heurtune.algorithms.cmaes_sqp",
    "heurtune.algorithms.cs",
    "heurtune.algorithms.firefly",
    "heurtune.algorithms.ga",
    "heurtune.algorithms.jso",
    "heurtune.algorithms.lshade",
    "heurtune.algorithms.nevergrad_bridge",
    "heurtune.algorithms.nsga2",
    "heurtune.algorithms.pso",
    "heurtune.algorithms.pymoo_bridge",
    "heurtune.algorithms.sms_emoa",
    "heurtune.algorithms.sqp_multistart",
]


def _public_functions(module_name):
    module = importlib.import_module(module_name)
    names = getattr(module, "__all__", None) or [n for n in dir(module) if not n.startswith("_")]
    for name in names:
        obj = getattr(module, name, None)
        if inspect.isfunction(obj) and (obj.__module__ == module.__name__ or module_name == "heurtune"):
            yield f"{obj.__module__}.{name}", obj


def _section(doc: str, title: str) -> str | None:
    """The body of a numpydoc section, or None when the docstring has none."""
    match = re.search(rf"^{title}\n-{{{len(title)}}}\n(.*?)(?=^\w[\w ]*\n-{{3,}}\n|\Z)", doc, re.S | re.M)
    return match.group(1) if match else None


CASES = sorted({qual: fn for m in MODULES for qual, fn in _public_functions(m)}.items())


@pytest.mark.parametrize("qualname, fn", CASES, ids=[q for q, _ in CASES])
def test_public_function_documents_its_parameters_and_returns(qualname, fn):
    doc = inspect.getdoc(fn)
    assert doc, f"{qualname}: no docstring"
    sig = inspect.signature(fn)
    params = [p for p in sig.parameters.values() if p.name not in ("self", "cls") and not p.name.startswith("_")]
    if params:
        body = _section(doc, "Parameters")
        assert body is not None, f"{qualname}: no Parameters section"
        documented = set()
        for line in body.splitlines():
            if line and not line.startswith(" "):
                # "name : type", "a, b : type", "**extra", or the compact "a : (4,) ...; b : (2,) ..."
                documented.update(re.findall(r"\**([A-Za-z_]\w*)\s*(?=[:,]|$)", line))
        missing = [p.name for p in params if p.name not in documented]
        assert not missing, f"{qualname}: parameters not in its Parameters section: {missing}"
    returns = sig.return_annotation
    if returns is not inspect.Signature.empty and returns not in (None, "None"):
        assert _section(doc, "Returns") is not None or _section(doc, "Yields") is not None, \
            f"{qualname}: returns {returns} but has no Returns section"
