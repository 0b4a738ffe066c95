"""python -m heurtune.check_plugin: the optimiser contract on an out-of-tree plugin."""

import io
import os
from pathlib import Path

import pytest

from heurtune.runner.check_plugin import run
from heurtune.runner.check_plugin import run as run_check

ROOT = Path(__file__).resolve().parents[2]


def _guide_plugin(tmp_path) -> Path:
    text = (ROOT / "docs" / "optimisers.md").read_text()
    start = text.index('```python\n"""Greedy random walk') + len("```python\n")
    path = tmp_path / "guide_walk.py"
    path.write_text(text[start:text.index("```", start)].replace('"random_walk"', '"guide_walk"'))
    return path


def test_the_guides_plugin_passes_every_check(tmp_path):
    out = io.StringIO()
    assert run([str(_guide_plugin(tmp_path))], stream=out) == 0
    lines = out.getvalue().splitlines()
    assert [ln.split()[0] for ln in lines[:-1]] == ["PASS"] * 6
    assert lines[-1] == "6 of 6 checks passed"


def test_a_plugin_breaking_the_contract_fails_with_the_reason(tmp_path):
    path = tmp_path / "unseeded.py"
    path.write_text(
        _guide_plugin(tmp_path)
        .read_text()
        .replace('"guide_walk"', '"unseeded_walk"')
        .replace("self.rng.normal(size=self.X.shape)", "__import__('numpy').random.normal(size=self.X.shape)")
    )
    out = io.StringIO()
    assert run([str(path)], stream=out) == 1
    text = out.getvalue()
    assert "FAIL  unseeded_walk: seeds: the same seed gave another history" in text
    assert "PASS  unseeded_walk: bounds" in text


def test_mistakes_are_one_line_errors(tmp_path, capsys):
    empty = tmp_path / "empty.py"
    empty.write_text("x = 1\n")
    plugin = _guide_plugin(tmp_path)
    for argv, message in (([str(tmp_path / "nope.py")], "does not exist"),
                          ([str(empty)], "registers no optimiser"),
                          ([str(plugin).replace("guide_walk", "guide_walk2"), "--settings", "{"], None)):
        if message is None:  # a second copy under another name, with bad settings JSON
            Path(argv[0]).write_text(plugin.read_text().replace('"guide_walk"', '"guide_walk2"'))
            message = "--settings is not JSON"
        assert run(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and message in err and "\n" not in err


def test_load_plugin_returns_the_module_it_loaded_for_unit_tests_of_its_update(tmp_path):
    import numpy as np
    from numerics import assert_exact

    from heurtune.core import registry
    from heurtune.core.engine import Comparator, SearchSpace
    from heurtune.core.plugins import load_plugin

    path = tmp_path / "guide_walk_unit.py"
    path.write_text(_guide_plugin(tmp_path).read_text().replace('"guide_walk"', '"guide_walk_unit"'))
    module = load_plugin(str(path))
    assert load_plugin(str(path)) is module  # loaded once
    X, z, width = np.zeros((3, 2)), np.ones((3, 2)), np.array([2.0, 4.0])
    # the update step, pinned: 0 + 0.5 * 1 * [2, 4], dyadic numbers with no rounding
    assert_exact(module.walk(X, z, 0.5, width), np.tile([1.0, 2.0], (3, 1)))
    opt = module.RandomWalk(SearchSpace(np.zeros(2), np.ones(2)), registry.make_settings("guide_walk_unit", None),
                            np.random.default_rng(0), Comparator())
    assert opt.X.shape == (0, 2) and opt.ask().shape == (20, 2)  # empty population, then the initial one


@pytest.mark.long  # 7 s on the EPYC: `make test` checks the guide's plugin and a bridge below
def test_a_shipped_optimiser_passes_by_file_or_module(capsys):
    """A shipped module is checked as imported (loading its file as a plugin would register
    its optimiser twice)."""
    import heurtune.algorithms as shipped

    path = os.path.join(os.path.dirname(shipped.__file__), "cmaes.py")
    for spec in (path, "heurtune.algorithms.cmaes"):
        assert run([spec]) == 0
        assert capsys.readouterr().out.strip().endswith("6 of 6 checks passed")


def test_a_bridge_is_checked_on_the_names_it_declares(tmp_path):
    """A module that registers a bridge to another library runs the contract on its ``checked``
    names (here a toy library of one algorithm, the guide's walk under another name)."""
    guide = _guide_plugin(tmp_path).read_text()
    start = guide.index('@register("guide_walk"')
    walk = guide[:start] + guide[guide.index("class RandomWalk(", start):]  # the class, not registered
    path = tmp_path / "toy_bridge.py"
    path.write_text(walk + '''

from heurtune.core.registry import AlgorithmInfo, register_bridge


def resolve(name):
    return AlgorithmInfo(f"toylib:{name}", RandomWalk, RandomWalkSettings, "a toy library's walk", "", "population")


register_bridge("toylib", resolve, "a toy library", checked=("Walk",))
''')
    assert "@register(" not in path.read_text()
    out = io.StringIO()
    assert run([str(path)], stream=out) == 0
    lines = out.getvalue().splitlines()
    assert lines[0] == "PASS  toylib:Walk: bounds" and lines[-1] == "6 of 6 checks passed"


BROKEN = {
    "syntax.py": ("def f(:\n    pass\n", "syntax.py:1: syntax error: invalid syntax"),
    "pi2dof.py": ("from heurtune.core.structures import ControllerStructure\n\n"
                  "PI2DOF = ControllerStructure(name='pi2dof', family='qtp', variables=(), bounds={},\n"
                  "                             description='')\n",
                  "pi2dof.py:3: TypeError: ControllerStructure.__init__() missing 1 required positional argument: "
                  "'design'"),
    "walk.py": ("import dataclasses\nfrom heurtune.core.engine import Optimizer\n"
                "from heurtune.core.registry import register\n\n\n@dataclasses.dataclass(frozen=True)\n"
                "class Settings:\n    n: int = 4\n\n\n@register('walk_notell', settings=Settings, description='x')\n"
                "class Walk(Optimizer):\n    def ask(self):\n        return self.space.uniform(self.rng, 4)\n",
                "walk.py:11: walk_notell: the optimiser has no tell()"),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_broken_plugin_code_is_one_line_with_file_and_line_and_leaves_no_folder(tmp_path, capsys, name):
    """A syntax error, a structure built without design=, an optimiser without tell(): one line
    naming the file, the line and what is missing; exit 2; no results folder (issue 52)."""
    from heurtune.runner.experiment import run

    text, message = BROKEN[name]
    plugin = tmp_path / name
    plugin.write_text(text)
    out = tmp_path / "out"
    assert run(["cs_pid_qtp", "--smoke", "--plugin", str(plugin), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {message}") and err.count("\n") == 1, err
    assert not out.exists()
    # check_plugin says the same in one line
    stream = io.StringIO()
    assert run_check([str(plugin)], stream=stream) == 2
    assert message in stream.getvalue() + capsys.readouterr().err


PI_B = '''
import numpy as np
from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import LinearController


def design(values, plant, options):
    """A diagonal PI that keeps set-point weights b1, b2 and never reads them."""
    A = np.zeros((2, 2))
    B = np.zeros((2, 4))
    B[0, 0] = B[1, 1] = -1.0
    D = np.zeros((2, 4))
    D[0, 0], D[1, 1] = -values["Kp1"], -values["Kp2"]
    C = np.diag([values["Ki1"], values["Ki2"]])
    return LinearController(A, B, C, D, ((0, 1), (1, 2)), (0, 1))


register_structure(ControllerStructure(
    name="pi_b_test", family="qtp", variables=("Kp1", "Ki1", "Kp2", "Ki2", "b1", "b2"), design=design,
    bounds={"Kp1": (0.0, 5.0), "Ki1": (0.001, 0.3), "Kp2": (0.0, 5.0), "Ki2": (0.001, 0.3), "b1": (0.0, 1.0),
            "b2": (0.0, 1.0)},
    description="PI with unread set-point weights (a test plugin)", integral_action="full",
    extras={"step_at_reference": 0.125, "explicit_step": True}))
'''


def test_variables_the_design_does_not_read_fail_their_check_and_warn_before_the_runs(tmp_path, capsys):
    """check_plugin names the set-point weights that change nothing; an experiment tuning them warns
    once, naming them (issue 52)."""
    from heurtune.runner.experiment import run as run_experiment_cli

    plugin = tmp_path / "pi_b.py"
    plugin.write_text(PI_B)
    stream = io.StringIO()
    assert run_check([str(plugin)], stream=stream) == 1
    fails = [line for line in stream.getvalue().splitlines() if line.startswith("FAIL")]
    assert len(fails) == 1 and fails[0].startswith("FAIL  qtp structure pi_b_test: variables: b1, b2 change no metric")
    config = tmp_path / "pi_b.toml"
    config.write_text(f'plugins = ["{plugin}"]\n[plant]\nmodel = "qtp"\ncases = ["min"]\n'
                      '[controller]\ntype = "pi_b_test"\n[problem]\nobjective = "iae"\n'
                      '[[optimisers]]\nname = "cs"\nmax_evals = 50\n')
    capsys.readouterr()
    assert run_experiment_cli([str(config), "--runs", "1", "--out", str(tmp_path / "out"), "--no-figures"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "change nothing" in line]
    assert len(warnings) == 1 and "case 'min': b1, b2 change nothing the problem reports" in warnings[0]


PI_2DOF = '''
import numpy as np
from heurtune.core.structures import ControllerStructure, register_structure
from heurtune.objectives.qtp.controllers import LinearController


def design(values, plant, options):
    """A diagonal 2-DOF PI written from docs/controllers_reference.md, "The reference path"."""
    A = np.zeros((2, 2))
    B, Br = np.zeros((2, 4)), np.zeros((2, 2))
    D, Dr = np.zeros((2, 4)), np.zeros((2, 2))
    for j in range(2):
        kp, ki, b = values[f"Kp{j + 1}"], values[f"Ki{j + 1}"], values[f"b{j + 1}"]
        B[j, j], Br[j, j] = -1.0, 1.0
        D[j, j], Dr[j, j] = -kp, b * kp
    C = np.diag([values["Ki1"], values["Ki2"]])
    return LinearController(A, B, C, D, ((0, 1), (1, 2)), (0, 1), Br=Br, Dr=Dr)


register_structure(ControllerStructure(
    name="pi_2dof_test", family="qtp", variables=("Kp1", "Ki1", "Kp2", "Ki2", "b1", "b2"), design=design,
    bounds={"Kp1": (0.0, 5.0), "Ki1": (0.001, 0.3), "Kp2": (0.0, 5.0), "Ki2": (0.001, 0.3), "b1": (0.0, 1.0),
            "b2": (0.0, 1.0)},
    description="2-DOF PI (a test plugin)", integral_action="full",
    extras={"step_at_reference": 0.125, "explicit_step": True, "reads_reference": True}))
'''


def test_a_2dof_plugin_passes_its_checks_and_its_weights_move_the_set_point_iae(tmp_path):
    """Issue 52's done-when: a 2-DOF PI plugin written from the docs changes its set-point IAE
    with b; the same design without the declaration fails its design check, naming it."""
    from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
    from heurtune.objectives.qtp.model import preset

    plugin = tmp_path / "pi_2dof.py"
    plugin.write_text(PI_2DOF)
    stream = io.StringIO()
    assert run_check([str(plugin)], stream=stream) == 0, stream.getvalue()
    loop = ClosedLoop(preset("min"), "pi_2dof_test")
    scenario = Scenario(horizon=150.0, output_disturbance=(0.0, 0.0), setpoint_step=(1.0, 1.0), setpoint_time=10.0)
    iae = [loop.run(loop.controller(dict(Kp1=2.0, Ki1=0.05, Kp2=2.0, Ki2=0.05, b1=b, b2=b)), scenario,
                    record=False).metrics[6] for b in (0.0, 0.5, 1.0)]
    assert iae[0] > iae[1] > iae[2]  # the set-point weight acts on the servo response
    undeclared = tmp_path / "pi_2dof_undeclared.py"
    undeclared.write_text(PI_2DOF.replace(', "reads_reference": True', "").replace("pi_2dof_test", "pi_2dof_u"))
    stream = io.StringIO()
    assert run_check([str(undeclared)], stream=stream) == 1
    assert ("FAIL  qtp structure pi_2dof_u: design: the design returns Br and Dr but the structure does not "
            "declare extras['reads_reference']") in stream.getvalue()
