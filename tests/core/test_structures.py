"""The controller-structure registry: declarations checked at registration, one-line errors, the
QTP contract on every shipped structure and on plugins (python -m heurtune.check_plugin), and a
plugin structure usable by config alone."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from heurtune.core.errors import ConfigError
from heurtune.core.structures import ControllerStructure, get_structure, register_structure, structures_of
from heurtune.objectives.qtp import structure_checks
from heurtune.runner.check_plugin import run as check_plugin

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "experiments" / "plugins" / "mimo_pi.py"


def _design(values, plant, options):
    raise NotImplementedError


def _declare(**changes):
    spec = dict(name="probe", family="probe_family", variables=("a", "b"), bounds={"a": (0.0, 1.0), "b": (1.0, 2.0)},
                design=_design, description="a probe")
    spec.update(changes)
    return ControllerStructure(**spec)


@pytest.mark.parametrize("changes, message", [
    (dict(name="Bad-Name"), "the name must match"),
    (dict(bounds={"a": (0.0, 1.0)}), "no default bounds for b"),
    (dict(bounds={"a": (0.0, 1.0), "b": (2.0, 1.0)}), "bounds.b must be finite with low < high"),
    (dict(bounds={"a": (0.0, 1.0), "b": (1.0, 2.0), "c": (0.0, 1.0)}), "bounds of unknown variables c"),
    (dict(domains={"a": (0.0, True)}), "bounds.a start at 0.0, outside its domain (> 0)"),
    (dict(integral_action="some"), "integral_action: got 'some'; allowed: paired, full, none"),
    (dict(options={"gain": 3.0}), "options.gain must be (schema spec, default)"),
    (dict(variables=("a", "a")), "variables must be distinct"),
])
def test_bad_declarations_are_one_line_errors(changes, message):
    with pytest.raises(ConfigError) as exc:
        _declare(**changes)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_registration_is_strict_and_lookups_name_the_allowed_types():
    s = register_structure(_declare(name="probe_once"))
    assert s.label == "PROBE_ONCE" and s.source == __name__
    assert get_structure("probe_family", "probe_once") is s
    with pytest.raises(ConfigError, match="'probe_once' of family 'probe_family' is registered already"):
        register_structure(_declare(name="probe_once"))
    with pytest.raises(ConfigError, match="unknown controller type 'nope'; allowed: probe_once"):
        get_structure("probe_family", "nope")


@pytest.mark.parametrize("name", [s.name for s in structures_of("qtp")])
def test_every_shipped_qtp_structure_meets_the_contract(name):
    results = structure_checks.run_checks(get_structure("qtp", name))
    assert [(check, ok, reason) for check, ok, reason in results if not ok] == []
    assert len(results) == len(structure_checks.CHECKS)


def test_the_example_plugin_passes_check_plugin():
    out = io.StringIO()
    assert check_plugin([str(PLUGIN)], stream=out) == 0
    lines = out.getvalue().splitlines()
    assert [ln.split()[0] for ln in lines[:-1]] == ["PASS"] * len(structure_checks.CHECKS)
    assert lines[-1] == f"{len(structure_checks.CHECKS)} of {len(structure_checks.CHECKS)} checks passed"


@pytest.mark.parametrize(
    "old, new, failing",
    [
        # C with one row: the kernels' shapes are broken
        ("return LinearController(A, B, Ki, D,", "return LinearController(A, B, Ki[:1], D[:1],", "design"),
        # a crash at a corner of the bounds instead of a ControllerDesignError
        (
            "    Kp = np.array(",
            "    if values['Kp11'] == 0.0:\n        raise ValueError('no')\n    Kp = np.array(",
            "corners",
        ),
        # a design that depends on hidden state
        (
            "    Kp = np.array(",
            "    values = dict(values, Kp11=values['Kp11'] + np.random.rand())\n    Kp = np.array(",
            "deterministic",
        ),
    ],
)
def test_a_broken_structure_plugin_fails_naming_the_check(tmp_path, old, new, failing):
    text = PLUGIN.read_text()
    assert old in text
    path = tmp_path / f"broken_{failing}.py"
    path.write_text(text.replace(old, new).replace('name="mimo_pi"', f'name="broken_{failing}"'))
    out = io.StringIO()
    assert check_plugin([str(path)], stream=out) == 1
    assert f"FAIL  qtp structure broken_{failing}: {failing}: " in out.getvalue()


def test_a_plugin_structure_runs_by_config_alone(tmp_path):
    """example_plugin_controller loads mimo_pi.py through ``plugins``; its type and its bounds
    come from the plugin, and a run writes its margins."""
    import pandas as pd

    from heurtune.runner.experiment import run_experiment

    with open("/dev/null", "w") as quiet:
        out = run_experiment("example_plugin_controller", smoke=True, seed=3, out=tmp_path / "ex", figures=False,
                             progress_stream=quiet)
    runs = pd.read_parquet(out / "runs.parquet")
    assert {"Kp12", "Ki21"} <= set(runs.columns) and set(runs.controller) == {"mimo_pi"}
    assert np.isfinite(runs.best_f[runs.case == "min"]).all()
    assert len(pd.read_parquet(out / "margins.parquet")) > 0


def test_the_guides_example_passes_check_plugin(tmp_path):
    """docs/controllers.md's code block, as a user would copy it, is a working plugin."""
    text = (ROOT / "docs" / "controllers.md").read_text()
    start = text.index("```python\nimport numpy as np") + len("```python\n")
    path = tmp_path / "guide_pi.py"
    path.write_text(text[start:text.index("```", start)].replace('name="mimo_pi"', 'name="guide_pi"'))
    out = io.StringIO()
    assert check_plugin([str(path)], stream=out) == 0, out.getvalue()
