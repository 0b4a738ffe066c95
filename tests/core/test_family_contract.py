"""The plant-family contract (heurtune.core.family_contract) applied to every registered family,
shipped and the example plugin: bad candidates finite and infeasible with a reason, a
reproducible identity, the documented report and simulate columns, robust and multi-objective
tuning by config alone, and the same result on one worker and on two."""

from __future__ import annotations

from pathlib import Path

import pytest

from heurtune.core.families import families, get_family
from heurtune.core.family_contract import CHECKS, run_checks
from heurtune.runner.config import list_experiments, load_config

ROOT = Path(__file__).resolve().parents[2]
PLUGIN_EXAMPLE = ROOT / "experiments" / "example_plugin_plant.toml"


def _examples() -> dict:
    """One shipped experiment per plant family: {family name: config name or path}."""
    if PLUGIN_EXAMPLE.is_file():
        load_config(str(PLUGIN_EXAMPLE))  # registers the plugin family
    out = {}
    for name in list_experiments():
        cfg = load_config(name)
        family = get_family(cfg.get("plant", {}).get("model", "qtp")).name
        out.setdefault(family, name)
    if PLUGIN_EXAMPLE.is_file():
        cfg = load_config(str(PLUGIN_EXAMPLE))
        family = get_family(cfg["plant"]["model"]).name
        out[family] = str(PLUGIN_EXAMPLE)
    return out


EXAMPLES = _examples()


def test_every_registered_family_has_an_example_experiment():
    assert {f.name for f in families()} <= set(EXAMPLES), "a family without an experiment cannot be contract-tested"
    assert {"qtp", "tito"} <= set(EXAMPLES)


@pytest.mark.parametrize("check", list(CHECKS))
@pytest.mark.parametrize("family", sorted(EXAMPLES))
def test_every_family_meets_the_contract(family, check):
    """heurtune.core.family_contract on one experiment of every registered family."""
    [(name, ok, reason)] = run_checks(load_config(EXAMPLES[family]), [check])
    assert ok, f"{family}: {name}: {reason}"


@pytest.mark.long  # 18 s on the EPYC: `make test` runs the same contract on every family above
def test_check_plugin_runs_the_family_contract_and_names_a_broken_check(tmp_path):
    """``check_plugin FAMILY.py --config EXPERIMENT.toml``: the example family passes every
    check; a copy whose identity is not reproducible fails ``identity`` only."""
    import io

    from heurtune.runner.check_plugin import run as check_plugin

    plugin = ROOT / "experiments" / "plugins" / "conical_tanks.py"
    out = io.StringIO()
    assert check_plugin([str(plugin), "--config", str(PLUGIN_EXAMPLE)], stream=out) == 0
    assert out.getvalue().splitlines()[-1] == f"{len(CHECKS)} of {len(CHECKS)} checks passed"
    broken = tmp_path / "broken_tanks.py"
    text = plugin.read_text().replace('"conical_tanks"', '"broken_tanks"')
    text = text.replace(
        'return dict(family="broken_tanks",', 'return dict(noise=float(np.random.rand()), family="broken_tanks",'
    )
    broken.write_text(text)
    config = tmp_path / "broken.toml"
    config.write_text(PLUGIN_EXAMPLE.read_text().replace("plugins/conical_tanks.py", str(broken))
                      .replace('model = "conical_tanks"', 'model = "broken_tanks"'))
    out = io.StringIO()
    assert check_plugin([str(broken), "--config", str(config)], stream=out) == 1
    lines = out.getvalue().splitlines()
    assert "FAIL  family broken_tanks: identity: the problem_id is not reproducible" in lines
    assert sum(line.startswith("FAIL") for line in lines) == 1


def test_a_family_plugin_without_a_config_is_a_one_line_error(capsys):
    from heurtune.runner.check_plugin import run as check_plugin

    assert check_plugin([str(ROOT / "experiments" / "plugins" / "conical_tanks.py")]) == 2
    err = capsys.readouterr().err.strip()
    assert "registers the plant family" in err and "--config" in err and "\n" not in err
