"""The planned work printed before an experiment starts: evaluations per run, the calibrated cost
of one evaluation, and the refusal of a configuration too costly to evaluate."""

import dataclasses
import io
import re
import time

import numpy as np
import pandas as pd
import pytest

from heurtune.core import registry
from heurtune.core.engine import SearchSpace
from heurtune.core.engine import run as run_optimiser
from heurtune.core.errors import ConfigError
from heurtune.core.evaluator import Evaluator
from heurtune.core.problem import Evaluation, TuningProblem
from heurtune.runner.experiment import RunSpec, run, run_experiment
from heurtune.runner.workplan import (
    Calibration,
    borrow_step_cost,
    calibrate,
    check_evaluation_time,
    estimate_line,
    format_duration,
    planned_evaluations,
)

# Metaheuristics spend a number of evaluations per generation that does not depend on the values:
# their planned count must be exact.
FIXED_COUNT = ("apso", "cs", "firefly", "ga", "pso")


def _constrained_valley(X):
    f = (100 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1 - X[:, :-1]) ** 2).sum(axis=1)
    return f, X[:, :1] - 0.3


def _spec(name, budget):
    settings = dataclasses.asdict(registry.make_settings(name, None))
    return RunSpec("c", 0, name, 0, 0, settings, budget, 0)


@pytest.mark.parametrize("budget", [dict(max_epochs=4), dict(max_evals=157)])
def test_planned_evaluations_equal_what_a_run_spends(budget):
    """Counted on stand-in objectives, checked on another one (a constrained valley, other
    bounds, another seed): an exact count must be met; an estimate says so."""
    registry.load_algorithms()
    exact_ones = set()
    for name in registry.available():
        info = registry.get(name)
        if info.multi_objective or info.kind == "driver":
            continue
        count, exact = planned_evaluations(_spec(name, budget), 4, 1)
        with Evaluator(_constrained_valley) as ev:
            res = run_optimiser(name, ev, SearchSpace(-2 * np.ones(4), 2 * np.ones(4)), seed=3, **budget)
        if exact:
            exact_ones.add(name)
            assert count == res.n_evals, name
        else:
            assert count > 0
    assert set(FIXED_COUNT) <= exact_ones


def test_planned_evaluations_of_drivers_tolerances_and_several_objectives():
    assert planned_evaluations(_spec("sqp_multistart", dict(max_epochs=3)), 4, 1) == (None, False)
    assert planned_evaluations(_spec("sqp_multistart", dict(max_evals=300)), 4, 1) == (300, False)
    count, exact = planned_evaluations(_spec("cs", dict(max_epochs=3, tol=1e-6)), 4, 1)
    assert count == 25 + 3 * 50 and not exact  # a tolerance may stop the run earlier
    count, exact = planned_evaluations(_spec("nsga2", dict(max_epochs=3)), 4, 1, n_objectives=2)
    settings = registry.make_settings("nsga2", None)
    assert exact and count == 4 * settings.n
    assert planned_evaluations(dataclasses.replace(_spec("cs", {}), baseline=True), 4, 1) == (1, True)
    assert planned_evaluations(_spec("cs", dict(max_time=60.0)), 4, 1) == (None, False)


class _Timed(TuningProblem):
    """A problem whose evaluation sleeps ``fixed`` s per candidate plus ``per_step`` s per
    simulated step of the candidates with x0 > 0.5 (the others are rejected before simulating)."""

    @dataclasses.dataclass(frozen=True)
    class Scenario:
        horizon: float = 100.0
        dt: float = 0.01

    scenario_type = Scenario

    def __init__(self, fixed=2e-3, per_step=4e-7, horizon=100.0):
        self.case, self.controller, self.names = "toy", "none", ("x0", "x1")
        self.lower, self.upper = np.zeros(2), np.ones(2)
        self.scenarios = {"nominal": self.Scenario(horizon=horizon), "long": self.Scenario(horizon=2 * horizon)}
        self.tuning_scenario, self.objective, self.constraint_names = "nominal", "f", ()
        self.fixed, self.per_step = fixed, per_step

    def evaluate(self, X, scenario=None):
        X = self.batch(X)
        sc = self.scenario(scenario if scenario is not None else self.tuning_scenario)
        simulated = X[:, 0] > 0.5
        steps = round(sc.horizon / sc.dt)
        time.sleep(len(X) * self.fixed + simulated.sum() * steps * self.per_step)
        n = len(X)
        return Evaluation(
            f=X.sum(axis=1),
            g=np.zeros((n, 0)),
            feasible=np.ones(n, bool),
            metrics=np.zeros((n, 0)),
            metric_names=(),
            constraint_names=(),
            reason=np.where(simulated, "", "unstable").astype(object),
        )

    def identity(self):
        return {}


def test_calibration_separates_the_fixed_and_the_per_step_cost():
    """The two cut horizons recover the costs the stand-in sleeps (within 25 %: sleeps only
    overrun, and the timings are the best of three)."""
    prob = _Timed()
    cal = calibrate(prob, steps=20_000)
    assert cal.steps == 10_000 and cal.simulated == 8 and cal.horizons == "10000 and 5000 steps"
    assert cal.fixed_s == pytest.approx(2e-3, rel=0.25)
    assert cal.step_s == pytest.approx(4e-7, rel=0.25)
    assert cal.evaluation_s == pytest.approx(2e-3 + 4e-7 * 10_000, rel=0.25)
    # A long horizon is cut to the calibration's steps; its evaluation is predicted, not run.
    long = _Timed(horizon=1e7)
    cal = calibrate(long, steps=20_000)
    assert cal.steps == 1_000_000_000 and cal.horizons == "20000 and 10000 steps"
    assert cal.evaluation_s == pytest.approx(4e-7 * 1e9, rel=0.25)
    with pytest.raises(ConfigError, match=r"case 'toy': one evaluation would take about .*scenario\.horizon.*--force"):
        check_evaluation_time(cal)


def test_a_measured_evaluation_over_the_limit_is_refused_too():
    cal = Calibration("toy", None, 75.0, None, 0, 8, "the configured scenario")
    with pytest.raises(
        ConfigError, match=r"^case 'toy': one evaluation took 1 min 15 s here \(the configured scenario\)"
    ):
        check_evaluation_time(cal)
    check_evaluation_time(dataclasses.replace(cal, fixed_s=59.0))


def test_a_robust_evaluation_counts_the_steps_of_every_scenario():
    from heurtune.core.robust import RobustTuning

    prob = _Timed()
    prob.robust = RobustTuning(("nominal", "long"))
    assert calibrate(prob, steps=2000).steps == 10_000 + 20_000


def test_a_case_with_nothing_simulated_borrows_the_cost_per_step():
    cals = {"a": Calibration("a", 1000, 1e-3, 2e-7, 8, 8, "h"), "b": Calibration("b", 1000, 5e-4, None, 0, 64, "h")}
    done = borrow_step_cost(cals)
    assert done["a"] is cals["a"] and done["b"].step_s == 2e-7 and "other cases" in done["b"].horizons
    assert borrow_step_cost({"b": cals["b"]})["b"].step_s is None


def test_format_duration():
    assert [format_duration(s) for s in (0.84, 42.2, 200, 7500, 5e5)] == \
        ["0.8 s", "42 s", "3 min 20 s", "2 h 05 min", "5.8 days"]


ENDLESS = 'extends = "cs_folqi_qtp"\n[controller]\nsample_time = 0.01\n[scenario]\nhorizon = 1e9\n'


def test_a_configuration_too_costly_to_evaluate_is_refused_before_anything_is_written(tmp_path, capsys):
    """The sampled loop at 0.01 s over 1e9 s is calibrated on cut horizons and refused; the
    continuous loop refuses such a horizon at load, by its step budget."""
    config = tmp_path / "endless.toml"
    config.write_text('extends = "cs_folqi_qtp"\n[scenario]\nhorizon = 1e9\n')
    assert run([str(config), "--runs", "1", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "more than the budget of 10,000,000; raise scenario.tolerance" in err[0]
    config.write_text(ENDLESS)
    out = tmp_path / "out"
    assert run([str(config), "--runs", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.match(r"error: case '(min|nmp)': one evaluation would take about ", err[0])
    assert "100,000,000,000 simulated steps" in err[0] and "scenario.horizon" in err[0] and "--force" in err[0]
    assert not out.exists()


def test_the_plan_line_counts_the_evaluations_the_runs_spend(tmp_path):
    stream = io.StringIO()
    out = run_experiment("cs_folqi_qtp", runs=1, max_epochs=2, out=tmp_path / "r", progress_stream=stream,
                         figures=False)
    lines = stream.getvalue().splitlines()
    runs = pd.read_parquet(out / "runs.parquet")
    total = int(runs["n_evals"].sum())
    plan = next(line for line in lines if line.startswith("plan: "))
    assert plan.startswith(f"plan: 2 runs, {total:,} evaluations; one evaluation of a simulated candidate: min ")
    assert "estimated time" in plan and "on 1 worker(s)" in plan
    assert f"] 2/2 runs, {total:,}/{total:,} evals" in lines[-1]
    assert not list((out / "parts").glob("*.progress.json"))  # heartbeats go with their runs


def test_the_plan_line_says_what_is_not_known_in_advance():
    cals = {"a": Calibration("a", 1000, 1e-3, 1e-6, 8, 8, "1000 and 500 steps")}  # 2 ms per evaluation
    line, seconds = estimate_line(cals, {"a": (3000, 0, False)}, 3, 2)
    assert seconds == pytest.approx(3.0)
    assert line == (
        "plan: 3 runs, 3,000 evaluations; one evaluation of a simulated candidate: a 2 ms (calibrated on "
        "8 candidates, 1000 and 500 steps); estimated time 3.0 s on 2 worker(s) if every candidate is simulated"
    )
    line, _ = estimate_line(cals, {"a": (3000, 1, True)}, 4, 2)
    assert "about 3,000 evaluations + 1 runs with no evaluation cap" in line and "estimated time at least 3.0 s" in line
    line, _ = estimate_line(cals, {"a": (0, 4, False)}, 4, 2)
    assert "4 runs with no evaluation cap: evaluations not known in advance" in line and "time left shown once" in line


def test_force_takes_the_costly_configuration_anyway(tmp_path, monkeypatch):
    import heurtune.runner.experiment as runner
    from heurtune.core.families import make_experiment
    from heurtune.runner.config import load_config

    config_file = tmp_path / "endless.toml"
    config_file.write_text(ENDLESS)
    config = load_config(str(config_file))
    exp = make_experiment(config)
    pending = runner.plan(exp, runs=1)
    with pytest.raises(ConfigError, match="--force"):
        runner._calibrate(exp, config, pending, force=False)
    calibrations, shapes = runner._calibrate(exp, config, pending, force=True)
    assert calibrations["min"].evaluation_s > 60 and shapes["min"] == (10, 6, 1)  # 10 gains, Mp, ts, ess per loop
    seen = {}
    monkeypatch.setattr(runner, "run_experiment", lambda name, **kw: seen.update(kw))
    assert run([str(config_file), "--force"]) == 0 and seen["force"] is True


def test_a_long_calibration_says_why_and_a_short_one_says_nothing():
    """CompileNotice: the line explaining the wait (numba compiling on a first run) comes once
    the calibration outlasts its threshold, and a closing line gives the time; under the
    threshold nothing is printed. No timing is assumed: the first case waits for the line
    itself, the second has a threshold no test reaches."""
    import io
    import threading

    from heurtune.runner.workplan import CompileNotice

    stream = io.StringIO()
    seen = threading.Event()
    notice = CompileNotice("exp", stream, after_s=0.0)
    original = notice._show
    notice._show = lambda: (original(), seen.set())
    with notice:
        assert seen.wait(60.0)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 2 and "numba is compiling" in lines[0] and "make setup" in lines[0], lines
    assert lines[1].startswith("exp: calibrated in ") and "compiled and cached" in lines[1], lines
    quiet = io.StringIO()
    with CompileNotice("exp", quiet, after_s=1e6):
        pass
    assert quiet.getvalue() == ""
