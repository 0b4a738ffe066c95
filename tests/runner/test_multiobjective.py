"""Several objectives through the whole runner: config, problems (QTP and TITO), NSGA-II runs,
pareto.parquet, the decision step and the hypervolume."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.core.families import make_experiment
from heurtune.core.pareto import hypervolume
from heurtune.runner.config import load_config
from heurtune.runner.experiment import run_experiment

THESIS_MIN = ("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,Ki2=7.1716,"
              "alpha1=0.9814,alpha2=0.8437")


def test_qtp_objectives_are_the_named_metric_sums():
    prob = heurtune.load_experiment("nsga2_folqi_qtp").problem("min")
    x = prob.parse(THESIS_MIN)
    X = np.vstack([x, x * 1.03, np.full(prob.dim, np.nan)])
    ev = prob.evaluate(X)
    m = pd.DataFrame(ev.metrics, columns=ev.metric_names)
    # each objective is one addition of two metrics, the same correctly rounded sum either way
    assert_same_bits(ev.F[:2, 0], (m["J1"] + m["J2"])[:2].to_numpy(), because="same code")
    assert_same_bits(ev.F[:2, 1], (m["IAE1"] + m["IAE2"])[:2].to_numpy(), because="same code")
    assert ev.objective_names == ("effort", "iae")
    assert_exact(ev.f, ev.F[:, 0])  # a copy
    assert ev.F[2].tolist() == [1e10, 1e10] and ev.reason[2] == "invalid_parameter"
    f, g = prob(X)
    assert f.shape == (3, 2)


def test_tito_objectives_bandwidth_and_peak():
    prob = heurtune.load_experiment("nsga2_pid_qts").problem("qts")
    single = heurtune.load_experiment("optimal_pid_qts").problem("qts")
    x = 0.5 * (prob.lower + prob.upper)
    X = np.vstack([x, 0.3 * prob.lower + 0.7 * prob.upper])
    ev, ref = prob.evaluate(X), single.evaluate(X)
    ok = ev.reason == ""
    assert ok.any()
    # -(w_b1 + w_b2), as the bandwidth problem's f: the same design evaluation on the same candidates
    assert_same_bits(ev.F[ok, 0], ref.f[ok], because="same code")
    m = pd.DataFrame(ev.metrics, columns=ev.metric_names)
    assert_exact(ev.F[ok, 1], np.maximum(m["Mt1"], m["Mt2"])[ok].to_numpy())  # the larger peak, picked


def test_robust_and_several_objectives_aggregate_each_objective():
    config = load_config("nsga2_folqi_qtp")
    config["problem"].update(tuning_scenarios=["nominal", "+30%"])
    prob = make_experiment(config).problem("min")
    x = prob.parse(THESIS_MIN)
    ev = prob.evaluate(x)
    per = [prob.evaluate(x, s) for s in ("nominal", "+30%")]
    # each scenario's objectives as evaluate gives them alone (evaluate_scenarios shares only the
    # design), the larger picked
    assert_same_bits(ev.F, np.maximum(per[0].F, per[1].F), because="same code")


@pytest.mark.parametrize("problem, message", [
    (dict(objectives=["effort", "speed"], reference_point=[1, 1]), "unknown objective 'speed'; allowed: effort"),
    (dict(objectives=["effort", "iae"]), "reference_point must give one value per objective"),
    (dict(objectives=["effort"], reference_point=[1]), "two or three distinct objectives"),
    (dict(reference_point=[1, 1]), "problem.reference_point needs problem.objectives"),
    (dict(objectives=["effort", "iae"], reference_point=[1, 1], decision_weights=[1, 0]), "one positive weight"),
    (dict(objectives=["iae", "effort"], reference_point=[1, 1], objective="effort"), "first of problem.objectives"),
])
def test_config_errors(problem, message):
    config = load_config("nsga2_folqi_qtp")
    config["problem"] = {k: v for k, v in config["problem"].items()
                         if k not in ("objectives", "reference_point", "objective")}
    config["problem"].update(problem)
    with pytest.raises(ConfigError, match=message):
        make_experiment(config)


def test_single_objective_optimisers_are_refused():
    config = load_config("nsga2_folqi_qtp")
    config["optimisers"] = [{"name": "cs", "settings": {"n": 5}}]
    with pytest.raises(ConfigError, match="optimisers\\[0\\]: 'cs' takes one objective"):
        make_experiment(config)


def test_nsga2_run_writes_the_front_and_reports_the_chosen_controller(tmp_path, monkeypatch):
    from heurtune.analysis import figures

    drawn = {}  # what the figures are told to draw (issue 53: hypervolume, not "effort J", and units)
    for name in ("convergence_figure", "boxplot_figure", "pareto_figure"):
        original = getattr(figures, name)

        def spy(*args, _name=name, _original=original, **kwargs):
            drawn.setdefault(_name, []).append((args, kwargs))
            return _original(*args, **kwargs)

        monkeypatch.setattr(figures, name, spy)
    out = run_experiment("nsga2_folqi_qtp", smoke=True, out=tmp_path / "mo", progress_stream=open("/dev/null", "w"))
    (conv_args, conv_kwargs), *_ = drawn["convergence_figure"]
    assert conv_kwargs["ylabel"].startswith("hypervolume") and (conv_args[0]["best_f"] >= 0).all()
    assert drawn["boxplot_figure"][0][1] == dict(metric="hypervolume", ylabel=conv_kwargs["ylabel"])
    assert drawn["pareto_figure"][0][1]["axis_labels"] == ["effort J (V² s)", "IAE (cm s)"]
    runs = pd.read_parquet(out / "runs.parquet")
    fronts = pd.read_parquet(out / "pareto.parquet")
    history = pd.read_parquet(out / "history.parquet")
    exp = heurtune.load_experiment("nsga2_folqi_qtp")
    assert (out / "pareto_min.png").exists()
    for _, r in runs.iterrows():
        front = fronts[(fronts["case"] == r["case"]) & (fronts["algorithm"] == r["algorithm"])
                       & (fronts["run"] == r["run"])]
        chosen = front[front["chosen"]]
        assert len(chosen) == 1
        prob = exp.problem(r["case"])
        x = np.array([r[n] for n in prob.names])
        assert_exact(chosen[list(prob.names)].to_numpy()[0], x)  # the chosen row's gains, copied
        assert r["hypervolume"] == -r["best_f"] + 0.0  # exact: a negation
        if r["feasible"]:
            assert r["hypervolume"] == pytest.approx(hypervolume(front[["f_effort", "f_iae"]].to_numpy(),
                                                                 prob.reference_point))
            ev = prob.evaluate(x)  # the chosen controller, re-evaluated alone (the run had it in a population)
            assert_same_bits([r["f_effort"], r["f_iae"]], ev.F[0], because="shared kernel")
        h = history[(history["case"] == r["case"]) & (history["algorithm"] == r["algorithm"])
                    & (history["run"] == r["run"])]["hypervolume"].to_numpy()
        assert np.all(np.diff(h) >= 0)


@pytest.mark.parametrize("name", ["nsga2_pid_qts", "robust_ga_pi_ccts"])
def test_tito_robust_and_multiobjective_experiments_run(name, tmp_path):
    out = run_experiment(name, smoke=True, out=tmp_path / name, figures=False, progress_stream=open("/dev/null", "w"))
    runs = pd.read_parquet(out / "runs.parquet")
    assert len(runs) and runs["problem_id"].nunique() == 1
    assert (out / "pareto.parquet").exists() == (name == "nsga2_pid_qts")
