"""Config loading: extends, and one test per error class (one-line messages naming the key)."""

import pytest

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.runner.config import list_experiments, load_config


def write(tmp_path, text, name="exp.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def load(tmp_path, text):
    return heurtune.load_experiment(write(tmp_path, text))


def test_shipped_experiments_load():
    assert "cs_folqi_qtp" in list_experiments()
    for name in list_experiments():
        exp = heurtune.load_experiment(name)
        assert exp.cases


def test_extends_overrides_keys(tmp_path):
    exp = load(tmp_path, 'extends = "cs_folqi_qtp"\n[controller]\ntype = "iolqi"\n'
                         '[problem.bounds]\nKi1 = [0.5, 2.0]\n[scenario]\nhorizon = 200.0\n')
    assert exp.controller == "iolqi"
    assert exp.cases == ("min", "nmp")  # inherited
    assert exp.bounds["Ki1"] == (0.5, 2.0) and exp.bounds["Q11"] == (0.01, 2.5)
    assert exp.scenarios["nominal"].horizon == 200.0 and exp.scenarios["nominal"].disturbance_time == 50.0
    assert exp.problem("nmp").names[-1] == "Ki2"


def test_custom_plant_case(tmp_path):
    exp = load(tmp_path, 'extends = "cs_folqi_qtp"\n[plant]\ncases = ["rig"]\n'
                         '[plant.custom.rig]\nA = [28, 32, 28, 32]\na = [0.071, 0.057, 0.071, 0.057]\n'
                         'k = [3.33, 3.35]\ngamma = [0.7, 0.6]\nlevels = [12.4, 12.7]\n')
    assert exp.problem("rig").loop.plant.A == (28.0, 32.0, 28.0, 32.0)


@pytest.mark.parametrize(
    "text, message",
    [
        (
            'extends = "cs_folqi_qtp"\n[controller]\ntypo = 1\n',
            r"exp.toml: controller: unknown key 'typo'; allowed: type, oustaloup_order",
        ),
        (
            'extends = "cs_folqi_qtp"\nrunz = 3\n',
            r"exp.toml: unknown top-level key or table 'runz'; allowed: description, extends, runs",
        ),
        (
            'extends = "cs_folqi_qtp"\n[senario]\nhorizon = 1.0\n',
            r"exp.toml: unknown top-level key or table 'senario'; allowed: ",
        ),
        (
            'extends = "cs_folqi_qtp"\n[controller]\ntype = "pdi"\n',
            r"controller.type: got 'pdi'; allowed: [a-z0-9_, ]*\bfolqi, fopid, [a-z0-9_, ]*\bpid\b",
        ),
        (
            'extends = "cs_folqi_qtp"\n[controller]\noustaloup_order = 2.5\n',
            r"controller.oustaloup_order: expected an integer",
        ),
        ('extends = "cs_folqi_qtp"\n[scenario]\nhorizon = "long"\n', r"scenario.horizon: expected a number"),
        (
            'extends = "cs_folqi_qtp"\n[problem.bounds]\nKi1 = [5.0, 1.0]\n',
            r"problem.bounds.Ki1: lower 5.0 > upper 1.0",
        ),
        ('extends = "cs_folqi_qtp"\n[problem.bounds]\nKi9 = [1.0, 2.0]\n', r"unknown variable 'Ki9'; allowed: Q11"),
        ('extends = "cs_folqi_qtp"\n[plant]\ncases = ["medium"]\n', r"unknown QTP preset 'medium'; allowed: min, nmp"),
        (
            'extends = "cs_folqi_qtp"\n[scenario]\nhorizon = 350.005\n',
            r"must be a whole number of scenario.output_dt \(0.01\)",
        ),
        (
            'extends = "cs_folqi_qtp"\n[problem]\ntuning_scenario = "worst"\n',
            r"tuning_scenario 'worst'; allowed: nominal",
        ),
        (
            'extends = "cs_folqi_qtp"\n[problem]\nobjective = "speed"\n',
            r"problem.objective: got 'speed'; allowed: effort",
        ),
        ('extends = "no_such_experiment"\n', r"unknown experiment 'no_such_experiment'; allowed: .*cs_folqi_qtp"),
        ("[plant\ncases = 1", r"exp.toml: not valid TOML"),
        (
            'extends = "cs_folqi_qtp"\n[[optimisers]]\nname = "hillclimb"\n',
            r"optimisers\[0\]: unknown optimiser 'hillclimb'; allowed: .*cs",
        ),
        (
            'extends = "cs_folqi_qtp"\n[[optimisers]]\nname = "cs"\nsettings = {npop = 3}\n',
            r"optimisers\[0\]: cs: unknown setting 'npop'; allowed: n, pa",
        ),
        # every bad setting in the one line, not only the first
        (
            'extends = "cs_folqi_qtp"\n[[optimisers]]\nname = "cs"\nsettings = {npop = 3, pa = "x", nn = 1}\n',
            r"cs: unknown setting 'npop'; unknown setting 'nn'; setting pa must be float, got 'x'; allowed: n, pa",
        ),
        (
            'extends = "cs_folqi_qtp"\n[[optimisers]]\nname = "cs"\nbudget = 3\n',
            r"optimisers\[0\]: unknown key 'budget'; allowed: name, settings",
        ),
        (
            'extends = "cs_folqi_qtp"\n[plant]\ncases = ["rig"]\n[plant.custom.rig]\nA = [1, 1, 1, 1]\n',
            r"plant.custom.rig: missing a, k, gamma, levels",
        ),
    ],
)
def test_config_errors_are_one_line_and_name_the_key(tmp_path, text, message):
    with pytest.raises(ConfigError, match=message) as info:
        load(tmp_path, text)
    assert "\n" not in str(info.value)


def test_circular_extends(tmp_path):
    write(tmp_path, 'extends = "b.toml"\n'.replace("b.toml", str(tmp_path / "b.toml")), "a.toml")
    write(tmp_path, f'extends = "{tmp_path / "a.toml"}"\n', "b.toml")
    with pytest.raises(ConfigError, match="circular"):
        load_config(str(tmp_path / "a.toml"))


def test_unknown_experiment_and_case():
    with pytest.raises(ConfigError, match="unknown experiment 'nope'"):
        heurtune.load_experiment("nope")
    with pytest.raises(ConfigError, match="unknown case 'mid' for cs_folqi_qtp; allowed: min, nmp"):
        heurtune.load_experiment("cs_folqi_qtp").problem("mid")


def test_relative_extends_path_resolves_beside_the_config(tmp_path, monkeypatch):
    sub = tmp_path / "configs"
    sub.mkdir()
    (sub / "base.toml").write_text('extends = "cs_folqi_qtp"\nruns = 3\n')
    (sub / "child.toml").write_text('extends = "base.toml"\nseed = 7\n')
    monkeypatch.chdir(tmp_path)  # not the configs' folder
    cfg = load_config(str(sub / "child.toml"))
    assert cfg["runs"] == 3 and cfg["seed"] == 7 and cfg["controller"]["type"] == "folqi"


def test_an_unknown_controller_type_says_how_a_plugin_type_is_loaded(tmp_path):
    cfg = tmp_path / "x.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\n[controller]\ntype = "my_pid"\n')
    with pytest.raises(ConfigError) as err:
        heurtune.load_experiment(str(cfg))
    message = str(err.value)
    assert "controller.type: got 'my_pid'" in message and "\n" not in message
    assert 'plugins = ["FILE.py"]' in message and "--plugin FILE.py" in message


def test_a_config_warning_is_printed_once_by_the_command_not_by_each_worker(tmp_path, capsys):
    """An inherited option the structure does not read is one warning when the config loads; the
    workers, which rebuild the same config for their runs, stay silent (issue 52)."""
    from heurtune.core.families import make_experiment
    from heurtune.runner.experiment import _problem

    path = tmp_path / "w.toml"
    path.write_text('extends = "cs_folqi_qtp"\n[controller]\ntype = "pid"\npairing = "auto"\n'
                    '[problem.bounds]\nKp1 = [0.0, 10.0]\nKp2 = [0.0, 10.0]\nKi1 = [0.0001, 1.0]\n'
                    'Ki2 = [0.0001, 1.0]\nKd1 = [0.0, 2.0]\nKd2 = [0.0, 2.0]\n')
    config = load_config(str(path))
    make_experiment(config)
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and "controller.oustaloup_order, controller.band, controller.realisation " \
                                              "not read by pid" in err
    _problem(config, "min")  # what a worker does first
    assert capsys.readouterr().err == ""
    make_experiment(config)  # outside a worker's build the warning is still there
    assert capsys.readouterr().err.count("warning:") == 1
