"""The tuning suite (``python -m heurtune.suite``): its table, instances, targets, measures and command."""

import dataclasses
import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest
from numerics import assert_close, assert_same_bits

from heurtune.analysis import leaderboard as lb
from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.instances import PERTURBED
from heurtune.objectives.qtp.model import operating_point, preset
from heurtune.runner import suite as S
from heurtune.runner.config import load_config


@pytest.fixture(scope="module")
def suite():
    return S.load_suite()


def test_the_shipped_table_has_the_problems_the_issue_asks_for(suite):
    names = {p.name for p in suite.problems}
    assert len(names) >= 16 and suite.instances >= 5
    for kind in ("iolqi", "pid", "fopid", "folqi", "lqi"):
        for case in ("min", "nmp"):
            assert {f"{kind}-{case}", f"{kind}-{case}-limits"} <= names
    assert sum(p.group == "robust" for p in suite.problems) >= 2
    assert {"tito-csts-pi", "tito-ccts-pid", "tito-qts-pid"} <= names
    pair = [p for p in suite.problems if p.multi_objective]  # IAE against TV, scored by hypervolume
    assert pair and all(p.objectives == ("iae", "tv") for p in pair)
    assert all(p.volume == p.reference_point[0] * p.reference_point[1] > 0 for p in pair)


def test_multi_objective_rows_go_to_the_multi_objective_optimisers_and_random_search_runs_both(suite):
    mo, so = suite.problem("pid-min-iae-tv"), suite.problem("pid-min")
    assert S.takes("nsga2", mo) and S.takes("sms_emoa", mo) and not S.takes("cs", mo)
    assert S.takes("cs", so) and not S.takes("nsga2", so)
    assert S.takes("random_search", mo) and S.takes("random_search", so)


def test_the_score_of_a_front_is_its_hypervolume_deficit_in_the_reference_box():
    # best_f is minus the front's hypervolume; 0 when nothing dominates the reference point
    hv = pd.Series([-60.0, 0.0, -240.0])
    assert lb.suite_value(hv, 240.0).tolist() == [0.75, 1.0, 0.0]
    assert lb.suite_value(hv, None) is hv  # one objective: the value itself


def test_instance_one_is_the_preset_and_the_others_are_seeded_draws_in_range(suite):
    for case in ("min", "nmp"):
        base = preset(case)
        one = S.instance_plant(case, 1, suite)
        assert one["A"] == list(base.A) and one["gamma"] == list(base.gamma) and one["levels"] == list(base.levels)
        for k in range(2, suite.instances + 1):
            p = S.instance_plant(case, k, suite)
            assert p == S.instance_plant(case, k, suite)  # seeded: the same plant every time
            for key, relative in PERTURBED.items():
                width = suite.perturbation["qtp"][key]
                new, old = np.array(p[key]), np.array(getattr(base, key))
                spread = np.abs(new / old - 1.0) if relative else np.abs(new - old)
                assert np.all(spread <= width + 1e-12), (case, k, key)
            assert (sum(p["gamma"]) > 1) == (sum(base.gamma) > 1)  # the case keeps its phase
            params = base.__class__(**{**p, "name": case})
            u = operating_point(params).u
            assert np.all((u > 0) & (u < 10))
        assert S.instance_plant(case, 2, suite) != S.instance_plant(case, 3, suite)


def test_a_problem_config_runs_the_instances_as_cases_with_the_budget(tmp_path, suite):
    p = suite.problem("pid-nmp-limits")
    path = S.problem_config(suite, p, "cs", [1, 3], 7.0, 2, tmp_path / "x.toml")
    config = load_config(str(path))
    # every instance is a case (its place sets its runs' seeds); the optimiser tunes the selected
    assert config["plant"]["cases"] == [f"i{k}" for k in range(1, suite.instances + 1)]
    assert config["plant"]["custom"]["i3"] == S.instance_plant("nmp", 3, suite)
    assert config["problem"]["bounds"]["Kp1"] == [0.0, 1.5]  # the row's override
    assert config["scenario"]["limits"] == "physical"  # the experiment's own
    assert config["optimisers"] == [{"name": "cs", "max_evals": 42, "cases": ["i1", "i3"]}]  # 7 x 6 dimensions
    assert config["runs"] == 2 and config["seed"] == suite.seed
    every = load_config(str(S.problem_config(suite, p, "cs", list(range(1, suite.instances + 1)), 7.0, 2,
                                             tmp_path / "all.toml")))
    assert every["optimisers"] == [{"name": "cs", "max_evals": 42}]  # all instances: no restriction


def test_an_instance_run_alone_makes_the_runs_it_makes_in_the_full_suite(tmp_path, suite):
    """A run's seed follows its case's place in the config: instance 2 selected alone has the
    seeds, and so the results, that it has among instances 1-2 (it had the seeds of instance 1
    when the config held the selected instances only)."""
    p = suite.problem("pid-min")
    log = open(tmp_path / "log", "w")
    [(_, _, both)] = S.run_suite(suite, [p], ["random_search"], [1, 2], tmp_path / "both", multiplier=1.0, runs=1,
                                 stream=log)
    [(_, _, alone)] = S.run_suite(suite, [p], ["random_search"], [2], tmp_path / "alone", multiplier=1.0, runs=1,
                                  stream=log)
    runs_both = pd.read_parquet(both / "runs.parquet").set_index("case")
    runs_alone = pd.read_parquet(alone / "runs.parquet").set_index("case")
    assert list(runs_alone.index) == ["i2"]
    assert runs_alone.loc["i2", "seed_key"] == runs_both.loc["i2", "seed_key"] == "1.0.0"
    assert_same_bits(runs_alone.loc["i2", "best_f"], runs_both.loc["i2", "best_f"], because="same seed")


def test_a_redefined_problem_with_results_is_refused_with_the_folder_to_remove(tmp_path, suite):
    """The suite has no --fresh: a results folder of an earlier definition of a problem is named in
    one line with what to do, and nothing in it is touched."""
    p = suite.problem("pid-nmp-limits")
    log = open(tmp_path / "log", "w")
    [(_, _, folder)] = S.run_suite(suite, [p], ["random_search"], [1], tmp_path, multiplier=0.5, runs=1, stream=log)
    before = sorted(f.name for f in (folder / "parts").iterdir())
    tighter = dataclasses.replace(p, overrides={**p.overrides, "scenario": {"tolerance": 0.004}})
    with pytest.raises(ConfigError) as err:
        S.run_suite(suite, [tighter], ["random_search"], [1], tmp_path, multiplier=0.5, runs=1, stream=log)
    message = str(err.value)
    assert message.startswith(f"{folder} holds 1 run(s) of pid-nmp-limits made with another config (differing: "
                              "problem.scenario.tolerance") and "remove that folder" in message
    assert "--fresh" not in message and "\n" not in message
    assert sorted(f.name for f in (folder / "parts").iterdir()) == before


@pytest.mark.parametrize("text, message", [
    ("[suite]\ninstances = 0\n[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n",
     "suite.instances must be an integer >= 1"),
    ("[suite]\nbudget_multiplier = -1\n[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n",
     "suite.budget_multiplier must be a number > 0"),
    ("[suite]\nrandom_runs = 0\n[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n",
     "suite.random_runs must be an integer >= 1"),
    ("[suite]\nrandom_run = 5\n[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n",
     "suite.random_run: unknown key; allowed: budget_multiplier, instances, perturbation, random_runs, runs, seed"),
    ("[suite.perturbation.qtp]\nA = 1.5\n[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n",
     "suite.perturbation.qtp.A must be a number in [0, 1)"),
    ("[suite.perturbation]\nA = 0.1\n[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n",
     "suite.perturbation.A must be a table of half-widths"),
    ("[[problem]]\nname='a'\nexperiment='nope'\ncase='min'\n", "unknown experiment 'nope'; allowed:"),
    ("[[problem]]\nname='a'\nexperiment='benchmark_qtp'\ncase='min'\n[[problem]]\nname='a'\n"
     "experiment='benchmark_qtp'\ncase='nmp'\n", "name 'a' is used twice"),
    ("[[problem]]\nname='a b'\nexperiment='benchmark_qtp'\ncase='min'\n", "may hold only letters"),
    ("[[problem]]\nname='a'\nexperiment='benchmark_qtp'\n", "case must be a non-empty string"),
    ("[suite]\n", "no [[problem]] tables"),
    ("[[problem]]\nname='a'\nexperiment='cs_pid_qtp'\ncase='min'\n"
     "overrides = { problem = { objectives = ['iae', 'tv'], reference_point = [20.0, 0.0] } }\n",
     "problem.reference_point must be 2 numbers > 0"),
])
def test_a_bad_table_is_one_line_naming_the_key(tmp_path, text, message):
    path = tmp_path / "problems.toml"
    path.write_text(textwrap.dedent(text))
    with pytest.raises(ConfigError, match=None) as err:
        S.load_suite(path)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_an_unknown_perturbation_is_named_when_the_instances_are_drawn(suite):
    import dataclasses

    bad = dataclasses.replace(suite, perturbation={"qtp": {"height": 0.1}})
    with pytest.raises(ConfigError, match="suite.perturbation.qtp.height: unknown key for the qtp plant; allowed: "
                                          "A, a, k, levels, gamma"):
        S.instance_plant("min", 2, bad)


def test_tito_instances_keep_signs_and_the_sign_of_det_g0(suite):
    from heurtune.objectives.tito.model import TITOPlant, preset

    for case in ("ccts", "qts", "wood_berry"):
        base = preset(case)
        one = S.instance_plant(case, 1, suite, "tito")
        assert one["g12"]["K"] == base.g12.K and one["g21"]["L"] == base.g21.L
        for k in range(2, 6):
            p = S.instance_plant(case, k, suite, "tito")
            assert p == S.instance_plant(case, k, suite, "tito")
            plant = TITOPlant.from_config(dict(p, name=case))  # a valid plant.custom table
            for key in ("g11", "g12", "g21", "g22"):
                e, b = plant.element(int(key[1]), int(key[2])), getattr(base, key)
                assert np.sign(e.K) == np.sign(b.K) and abs(e.K / b.K - 1) <= 0.1 + 1e-12
                assert abs(e.L / b.L - 1) <= 0.1 + 1e-12 if b.L else e.L == 0.0
                assert e.leads == b.leads
            det = lambda g: g.g11.K * g.g22.K - g.g12.K * g.g21.K  # noqa: E731
            assert np.sign(det(plant)) == np.sign(det(base))


def test_targets_are_log_spaced_from_random_search_to_the_best():
    t = S.targets_of(2.0, 200.0)
    assert t.size == S.N_TARGETS and t[0] == 200.0 and t[-1] == 2.0
    np.testing.assert_allclose(np.diff(np.log(t)), np.log(0.01) / 50, rtol=1e-12)
    assert S.targets_of(3.0, 2.0).tolist() == [3.0]  # random search better than the best known: one target
    with pytest.raises(ValueError):
        S.targets_of(0.0, 1.0)


def _history(rows):
    """A suite history: (case, algorithm, run, [(n_evals, best_f, violation), ...])."""
    out = []
    for case, alg, run, points in rows:
        for n, f, v in points:
            out.append(dict(case=case, algorithm=alg, run=run, n_evals=n, best_f=f, best_violation=v,
                            optimiser_index=0))
    return pd.DataFrame(out)


def test_measures_count_evaluations_per_dimension_and_the_area_is_exact():
    # one problem of dimension 2, budget 10 x 2 = 20 evaluations; targets 8 and 2
    hist = _history([("p/i1", "a", 0, [(2, 8.0, 0.0), (20, 2.0, 0.0)]),
                     ("p/i1", "b", 0, [(2, 9.0, 1.0), (20, 9.0, 0.0)])])
    targets = pd.DataFrame({"case": ["p/i1", "p/i1"], "target": [8.0, 2.0]})
    runs = pd.DataFrame(dict(case="p/i1", algorithm=["a", "b"], run=0, best_f=[2.0, 9.0], feasible=True,
                             problem="p", instance=1))
    m = lb.suite_measures(runs, hist, targets, {"p": 2}, 10.0, {"p": "g"})
    ft = m["fixed_target"].set_index(["algorithm", "target"])["evals_per_dim"]
    assert ft[("a", 8.0)] == 1.0 and ft[("a", 2.0)] == 10.0 and np.isinf(ft[("b", 8.0)])
    auc = m["auc"].set_index(["group", "algorithm"])["auc"]
    # a: one pair at 1 (area 1), one at the budget (area 0); b: none reached
    assert auc[("all", "a")] == pytest.approx(0.5) and auc[("all", "b")] == 0.0
    assert auc[("g", "a")] == auc[("all", "a")]


def test_friedman_counts_a_failed_algorithm_last_instead_of_leaving_it_out():
    rows = []
    for c in range(4):
        for alg, f in (("good", 1.0), ("mid", 2.0), ("bad", 3.0), ("fails", np.nan)):
            for r in range(3):
                rows.append(dict(case=f"p/i{c + 1}", algorithm=alg, run=r, best_f=f if np.isfinite(f) else 1e10,
                                 feasible=bool(np.isfinite(f))))
    res = lb.friedman_final(pd.DataFrame(rows))
    assert not res.skipped
    assert res.mean_ranks.sort_values().index.tolist() == ["good", "mid", "bad", "fails"]
    assert res.mean_ranks["fails"] == 4.0
    groups = lb.nemenyi_groups(res)
    assert groups[0][0] == "good" and groups[-1][-1] == "fails"


def _cli(*argv):
    return subprocess.run([sys.executable, "-m", "heurtune.suite", *argv], capture_output=True, text=True)


def _run(capsys, *argv):
    """The command in this process: (exit code, stdout, stderr)."""
    code = S.run(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("argv, message", [
    (["--algorithms", "nope"], "--algorithms: unknown optimiser 'nope'; allowed:"),
    (["--problems", "nope"], "unknown suite problem 'nope'; allowed:"),
    (["--instances", "7"], "--instances: 7 out of range; allowed: 1 to 5"),
    (["--instances", "x"], "--instances: 'x' is not an instance number"),
    (["--budget-multiplier", "0"], "--budget-multiplier must be a number > 0"),
    (["--runs", "0"], "--runs must be >= 1"),
    (["--smoke", "--runs", "0"], "--runs must be >= 1"),  # not replaced by the smoke default
    (["--smoke", "--budget-multiplier", "0"], "--budget-multiplier must be a number > 0"),
    (["--make-targets", "--reference-runs", "0"], "--reference-runs must be >= 1"),
    (["--algorithms", "cs", "--problems", "pid-min-iae-tv"], "--algorithms: none of cs takes these problems"),
])
def test_bad_input_is_one_line_and_exit_2(capsys, argv, message):
    code, _, err = _run(capsys, *argv)
    assert code == 2 and err.startswith(f"error: {message}") and err.count("\n") == 1


def _target_row(problem, instance, f_best, reference, commit, reference_multiplier=50.0, problem_id="p0"):
    return dict(problem=problem, instance=instance, problem_id=problem_id, f_best=f_best, f_random=9.0, random_runs=5,
                random_feasible=5, reference=reference, reference_multiplier=reference_multiplier,
                budget_multiplier=100.0, commit=commit, date="2026-12-07")


def test_separate_make_targets_calls_fill_one_table_with_the_better_value(tmp_path):
    path = tmp_path / "targets.csv"
    S._write_targets(path, pd.DataFrame([_target_row("a", 1, 2.0, "cmaes_sqp", "c1"),
                                         _target_row("a", 2, 3.0, "cmaes_sqp", "c1")], columns=S.TARGET_COLUMNS))
    S._write_targets(path, pd.DataFrame([_target_row("a", 1, 2.5, "lshade", "c2"),
                                         _target_row("a", 2, 1.0, "lshade", "c2"),
                                         _target_row("b", 1, 4.0, "lshade", "c2")], columns=S.TARGET_COLUMNS))
    table = S.load_targets(path).set_index(["problem", "instance"])
    assert table.loc[("a", 1), ["f_best", "commit"]].tolist() == [2.0, "c1"]  # the earlier run was better
    assert table.loc[("a", 2), ["f_best", "commit"]].tolist() == [1.0, "c2"]
    assert set(table["reference"].iloc[:2]) == {"cmaes_sqp+lshade"} and table.loc[("b", 1), "reference"] == "lshade"
    # a tie (a resumed call that ran nothing new) keeps the commit that made the value
    S._write_targets(path, pd.DataFrame([_target_row("a", 2, 1.0, "lshade", "c9")], columns=S.TARGET_COLUMNS))
    assert S.load_targets(path).set_index(["problem", "instance"]).loc[("a", 2), "commit"] == "c2"
    # a row made for other budgets is replaced, not merged: its value answers another question
    S._write_targets(path, pd.DataFrame([_target_row("a", 1, 5.0, "jso", "c3", reference_multiplier=10.0)],
                                        columns=S.TARGET_COLUMNS))
    row = S.load_targets(path).set_index(["problem", "instance"]).loc[("a", 1)]
    assert (row["f_best"], row["reference"], row["reference_multiplier"]) == (5.0, "jso", 10.0)
    # so is a row of another definition of the problem, though its value is worse
    S._write_targets(path, pd.DataFrame([_target_row("a", 2, 1.5, "lshade", "c4", problem_id="p1")],
                                        columns=S.TARGET_COLUMNS))
    row = S.load_targets(path).set_index(["problem", "instance"]).loc[("a", 2)]
    assert (row["f_best"], row["reference"], row["problem_id"], row["commit"]) == (1.5, "lshade", "p1", "c4")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["targets.csv"]  # no temporary or lock file left


def test_a_table_row_gives_the_targets_only_of_runs_at_the_budget_it_was_made_for():
    table = pd.DataFrame([_target_row("a", 1, 2.0, "cmaes_sqp", "c1")], columns=S.TARGET_COLUMNS)  # 100 x dim
    runs = pd.DataFrame(dict(case=["a/i1"] * 3, problem="a", instance=1, algorithm=["cs", "cs", "random_search"],
                             best_f=[3.0, 4.0, 8.0], feasible=[True, True, True]))
    targets, used = lb.targets_table(table, runs, lb.N_TARGETS, multiplier=100.0)
    assert used[["f_best", "f_random", "source"]].values.tolist() == [[2.0, 9.0, "table"]]
    assert_close(targets["target"].to_numpy(), lb.targets_of(2.0, 9.0, lb.N_TARGETS), rtol=0.0,
                 because="the table's targets, computed once")
    # at 5 x dim the table's targets would be out of reach: the runs' own best and random median
    _, used = lb.targets_table(table, runs, lb.N_TARGETS, multiplier=5.0)
    assert used[["f_best", "f_random", "source"]].values.tolist() == [[3.0, 8.0, "results"]]
    # runs of the case as it is defined now (problem_id) use the row; runs of a redefined problem do not
    _, used = lb.targets_table(table, runs.assign(problem_id="p0"), lb.N_TARGETS, multiplier=100.0)
    assert used["source"].tolist() == ["table"]
    _, used = lb.targets_table(table, runs.assign(problem_id="p1"), lb.N_TARGETS, multiplier=100.0)
    assert used[["f_best", "f_random", "source"]].values.tolist() == [[3.0, 8.0, "stale"]]


def test_a_targets_table_from_before_the_problem_id_column_is_read_and_not_trusted(tmp_path):
    path = tmp_path / "targets.csv"
    pd.DataFrame([_target_row("a", 1, 2.0, "cmaes_sqp", "c1")]).drop(columns="problem_id").to_csv(path, index=False)
    table = S.load_targets(path)
    assert list(table.columns) == S.TARGET_COLUMNS and table["problem_id"].isna().all()
    runs = pd.DataFrame(dict(case=["a/i1"] * 2, problem="a", instance=1, algorithm=["cs", "random_search"],
                             best_f=[3.0, 8.0], feasible=[True, True], problem_id="p0"))
    _, used = lb.targets_table(table, runs, lb.N_TARGETS, multiplier=100.0)
    assert used["source"].tolist() == ["stale"]


def test_the_shipped_targets_rows_are_made_at_the_suite_budgets_by_a_commit_of_this_history(suite):
    table = S.load_targets()
    if table.empty:
        pytest.skip("experiments/suite/targets.csv is not made yet")
    names = {p.name: p for p in suite.problems}
    assert list(pd.read_csv(S.suite_dir() / "targets.csv", nrows=0).columns) == S.TARGET_COLUMNS
    assert set(table["problem"]) <= set(names), "a row names a problem the suite no longer has"
    assert table["instance"].between(1, suite.instances).all()
    assert not table.duplicated(["problem", "instance"]).any()
    assert (table["budget_multiplier"] == suite.budget_multiplier).all() and (table["reference_multiplier"] > 1).all()
    for row in table.itertuples():
        kind = S.MULTI_OBJECTIVE_REFERENCE if names[row.problem].multi_objective else S.REFERENCE
        assert set(row.reference.split("+")) <= set(kind), f"{row.problem}: reference {row.reference}"
        assert np.isfinite(row.f_best) and row.f_best <= row.f_random, row  # the reference beats random's median
        assert row.random_runs == suite.random_runs and len(str(row.commit)) >= 7
    root = S.suite_dir().parents[1]
    if shutil.which("git") is None or not (root / ".git").exists():
        return
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=root, capture_output=True, text=True)
    if shallow.stdout.strip() == "false":  # a shallow clone lacks the older commits
        for commit in set(table["commit"].astype(str)):
            known = subprocess.run(["git", "merge-base", "--is-ancestor", commit, "HEAD"], cwd=root,
                                   capture_output=True)
            assert known.returncode == 0, f"targets.csv: commit {commit} is not in this checkout's history"


def _reference_row(problem, instance, algorithm, f_best, converged_at=10, evaluations=100, problem_id="p0"):
    return dict(problem=problem, instance=instance, problem_id=problem_id, algorithm=algorithm, f_best=f_best, runs=1,
                evaluations=evaluations, converged_at=converged_at, seconds=5.0, reference_multiplier=50.0,
                budget_multiplier=100.0, commit="c1", date="2026-12-07")


def test_the_reference_runs_table_keeps_each_algorithms_value_and_says_how_far_they_agree(tmp_path):
    path = tmp_path / "reference_runs.csv"
    S.write_reference_runs(path, [_reference_row("a", 1, "cmaes_sqp", 2.0), _reference_row("a", 1, "lshade", 2.0),
                                  _reference_row("a", 2, "cmaes_sqp", 3.0, converged_at=90),
                                  _reference_row("a", 2, "lshade", 3.3)])
    # the same algorithm, case and budgets again: replaced, not added
    table = S.write_reference_runs(path, [_reference_row("a", 2, "lshade", 3.03)])
    again = table[(table["instance"] == 2) & (table["algorithm"] == "lshade")]
    assert len(table) == 4 and again["f_best"].tolist() == [3.03]
    # the same value from a later commit (a resume that ran nothing): the commit that made it stays
    table = S.write_reference_runs(path, [{**_reference_row("a", 1, "lshade", 2.0), "commit": "c9"}])
    assert len(table) == 4 and set(table["commit"]) == {"c1"}
    agreement = S.reference_agreement(S.load_reference_runs(path)).iloc[0]
    assert agreement["reference"] == "cmaes_sqp+lshade" and agreement["cases"] == 2
    assert_close(agreement["largest_gap"], 0.01, rtol=1e-12, because="(3.03 - 3) / 3 in floating point")
    assert agreement["cases_apart"] == 1  # instance 1 is a tie
    assert agreement["won"] == "cmaes_sqp:2, lshade:1" and agreement["converged_by"] == "cmaes_sqp:90%, lshade:10%"
    report = S._reference_report(S.reference_agreement(S.load_reference_runs(path)))
    assert report.splitlines()[2].startswith("| a | cmaes_sqp+lshade | 2 | 0.01 | 1 |")
    # instance 2 redefined (another problem_id) and run by one algorithm: the other's row of the
    # earlier definition goes, whatever its value; instance 1 keeps both
    table = S.write_reference_runs(path, [_reference_row("a", 2, "lshade", 5.0, problem_id="p1")])
    assert sorted(table[["instance", "algorithm", "problem_id"]].values.tolist()) == [
        [1, "cmaes_sqp", "p0"], [1, "lshade", "p0"], [2, "lshade", "p1"]]


def test_commits_and_problem_ids_of_digits_only_are_read_back_as_text(tmp_path):
    # a commit 3554307 came back as an integer, a problem_id 1e45678901ab would come back as a float
    S._write_targets(tmp_path / "targets.csv", pd.DataFrame([_target_row("a", 1, 2.0, "cs", "3554307",
                                                                         problem_id="1e45678901ab")]))
    S.write_reference_runs(tmp_path / "reference_runs.csv", [{**_reference_row("a", 1, "cs", 2.0, problem_id="0123"),
                                                              "commit": "0012345"}])
    row = S.load_targets(tmp_path / "targets.csv").iloc[0]
    assert (row["commit"], row["problem_id"]) == ("3554307", "1e45678901ab")
    row = S.load_reference_runs(tmp_path / "reference_runs.csv").iloc[0]
    assert (row["commit"], row["problem_id"]) == ("0012345", "0123")
    # and a second write keeps them (the merge compares them as text)
    again = _target_row("a", 1, 2.0, "cs", "9", problem_id="1e45678901ab")
    S._write_targets(tmp_path / "targets.csv", pd.DataFrame([again]))
    assert S.load_targets(tmp_path / "targets.csv").iloc[0]["commit"] == "3554307"


def test_one_make_targets_call_refuses_runs_of_two_definitions_of_a_case(tmp_path):
    folder = tmp_path / "random_search"
    folder.mkdir()
    pd.DataFrame(dict(case=["i1", "i2"], problem_id=["p0", "p9"])).to_parquet(folder / "runs.parquet")
    reference = [_reference_row("a", 1, "cmaes_sqp", 2.0), _reference_row("a", 2, "cmaes_sqp", 2.0)]
    with pytest.raises(RuntimeError, match=r"instance\(s\) \[2\] solved different problems"):
        S._problem_ids(reference, folder)
    assert S._problem_ids(reference[:1], folder) == {1: "p0", 2: "p9"}


def test_the_shipped_targets_are_for_the_problems_as_defined_now(suite, tmp_path):
    """Each targets row's problem_id is the fingerprint of its case as problems.toml defines it
    today: an edited row (bounds, overrides, an integrator) or perturbation table without new
    reference runs fails here, and names the rows to make again."""
    from heurtune.core.families import make_experiment
    from heurtune.core.problem import problem_fingerprint
    from heurtune.runner.config import load_config

    table = S.load_targets()
    if table.empty:
        pytest.skip("experiments/suite/targets.csv is not made yet")
    stale = []
    for name, rows in table.groupby("problem"):
        path = S.problem_config(suite, suite.problem(name), "random_search", sorted(rows["instance"]), 1.0, 1,
                                tmp_path / f"{name}.toml")
        experiment = make_experiment(load_config(str(path)))
        stale += [f"{name} i{k}" for k, pid in zip(rows["instance"], rows["problem_id"])
                  if problem_fingerprint(experiment.problem(f"i{k}")) != pid]
    assert not stale, f"targets.csv rows made for another definition: {', '.join(stale)} (--make-targets)"


def test_the_shipped_reference_runs_give_the_targets_best_values(suite):
    """Every row of targets.csv has its reference algorithms' own values in reference_runs.csv,
    and its best known value is the best of them (the same floats, written by the same calls)."""
    from numerics import assert_exact

    table, runs = S.load_targets(), S.load_reference_runs()
    if table.empty:
        pytest.skip("experiments/suite/targets.csv is not made yet")
    assert list(pd.read_csv(S.suite_dir() / "reference_runs.csv", nrows=0).columns) == S.REFERENCE_RUN_COLUMNS
    assert not runs.duplicated(["problem", "instance", "algorithm", "reference_multiplier", "budget_multiplier"]).any()
    for row in table.itertuples():
        own = runs[(runs["problem"] == row.problem) & (runs["instance"] == row.instance)
                   & (runs["problem_id"] == row.problem_id)
                   & (runs["reference_multiplier"] == row.reference_multiplier)
                   & (runs["budget_multiplier"] == row.budget_multiplier)]
        names = row.reference.split("+")
        assert set(names) <= set(own["algorithm"]), f"{row.problem} i{row.instance}: {names} not all recorded"
        assert_exact(own[own["algorithm"].isin(names)]["f_best"].min(), row.f_best,
                     err_msg=f"{row.problem} i{row.instance}")


def test_the_docs_agreement_table_is_the_reference_report_of_the_shipped_table():
    """docs/suite.md shows ``--reference-report``'s table of the shipped reference_runs.csv: a row
    merged into the table without the docs brought along fails here."""
    docs = (S.suite_dir().parents[1] / "docs" / "suite.md").read_text(encoding="utf-8").splitlines()
    report = S._reference_report(S.reference_agreement()).splitlines()
    start = docs.index(report[0])
    assert docs[start:start + len(report)] == report
    assert not docs[start + len(report)].startswith("|"), "the docs table has rows the report does not"


def test_list_names_every_problem(capsys, suite):
    code, out, _ = _run(capsys, "--list")
    assert code == 0
    assert [line.split()[0] for line in out.splitlines()] == [p.name for p in suite.problems]


@pytest.mark.long
def test_smoke_runs_resumes_and_writes_the_leaderboard(tmp_path):
    out = tmp_path / "suite"
    first = _cli("--smoke", "--algorithms", "random_search,cs,pso", "--out", str(out), "--jobs", "2")
    assert first.returncode == 0, first.stderr
    board = pd.read_csv(out / "leaderboard.csv")
    assert sorted(board["algorithm"]) == ["cs", "pso", "random_search"]
    assert board["auc"].between(0, 1).all() and board["runs"].eq(8).all()
    for name in ("leaderboard.md", "leaderboard.tex", "problems.csv", "ert.csv", "targets_used.csv",
                 "ecdf_all.png", "cd_diagram.png"):
        assert (out / name).is_file(), name
    assert any((out / "ioh").rglob("*.json"))
    # the smoke's multi-objective row: random search alone takes it of these three
    assert pd.read_csv(out / "multiobjective" / "leaderboard.csv")["algorithm"].tolist() == ["random_search"]
    again = _cli("--smoke", "--algorithms", "random_search,cs,pso", "--out", str(out), "--jobs", "2")
    assert again.returncode == 0
    assert_same_bits(pd.read_csv(out / "leaderboard.csv"), board, because="resume")


PLUGIN = '''
import dataclasses
from heurtune.core.engine import Optimizer
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class Settings:
    n: int = 4


@register("suite_walk", settings=Settings, source="test", description="a plugin optimiser for the suite test")
class Walk(Optimizer):
    def ask(self):
        return self.space.uniform(self.rng, self.settings.n)

    def tell(self, X, f, v):
        self.X, self.f, self.v = X, f, v
        return True
'''


@pytest.mark.long
def test_a_plugin_optimiser_joins_the_suite_with_one_command(tmp_path):
    plugin = tmp_path / "walk.py"
    plugin.write_text(PLUGIN)
    out = tmp_path / "suite"
    done = _cli("--plugin", str(plugin), "--algorithms", "suite_walk,random_search", "--problems", "pid-min",
                "--instances", "1", "--runs", "2", "--budget-multiplier", "2", "--out", str(out), "--no-figures",
                "--no-ioh")
    assert done.returncode == 0, done.stderr
    assert set(pd.read_csv(out / "leaderboard.csv")["algorithm"]) == {"suite_walk", "random_search"}


@pytest.mark.long
def test_the_multi_objective_pair_has_its_own_leaderboard_by_hypervolume(tmp_path, suite):
    out = tmp_path / "suite"
    done = _cli("--algorithms", "nsga2,random_search,cs", "--problems", "pid-min-iae-tv,pid-min", "--instances",
                "1", "--runs", "2", "--budget-multiplier", "20", "--out", str(out), "--no-figures", "--no-ioh")
    assert done.returncode == 0, done.stderr
    assert set(pd.read_csv(out / "leaderboard.csv")["algorithm"]) == {"cs", "random_search"}
    board = pd.read_csv(out / "multiobjective" / "leaderboard.csv")
    assert set(board["algorithm"]) == {"nsga2", "random_search"}  # cs takes one objective
    used = pd.read_csv(out / "multiobjective" / "targets_used.csv")
    runs = pd.read_parquet(out / "pid-min-iae-tv" / "nsga2" / "runs.parquet")
    volume = suite.problem("pid-min-iae-tv").volume
    # the best known is the best deficit of the runs, 1 - HV / volume of the best front: the
    # shipped table's rows are made for the suite's budget, not for this run's 20 x dim
    best = min(1.0 - pd.read_parquet(out / "pid-min-iae-tv" / alg / "runs.parquet")["hypervolume"].max() / volume
               for alg in ("nsga2", "random_search"))
    assert used["source"].iloc[0] == "results"
    assert 0.0 < used["f_best"].iloc[0] < 1.0
    assert_close(used["f_best"].iloc[0], best, rtol=1e-12, because="the same division of the same hypervolume")
    assert runs["hypervolume"].gt(0).all()
    assert "## Suite leaderboard: multi-objective problems" in (out / "leaderboard.md").read_text()


@pytest.mark.long
def test_make_targets_writes_the_table_the_leaderboard_reads(tmp_path, suite):
    table_path = tmp_path / "targets.csv"
    problem = suite.problem("pid-min")
    small = dataclasses.replace(suite, budget_multiplier=2.0)  # the table is made for the runs' budget
    table = S.make_targets(small, [problem], [1, 2], tmp_path / "ref", reference=("cs",), reference_multiplier=2.5,
                           reference_runs=2, runs=2, path=table_path, stream=open(tmp_path / "log", "w"))
    assert list(table["instance"]) == [1, 2] and set(table["problem"]) == {"pid-min"}
    assert (table["random_runs"] == 2).all() and table["reference"].eq("cs").all()
    assert (table["budget_multiplier"] == 2.0).all()
    ref = pd.read_parquet(tmp_path / "ref" / "reference" / "pid-min" / "cs" / "runs.parquet")
    assert len(ref) == 4 and ref["n_evals"].max() <= round(2.5 * 2 * 6)
    assert np.isfinite(table["f_best"]).all() and np.isfinite(table["f_random"]).all()
    recorded = S.load_reference_runs(tmp_path / "reference_runs.csv")  # beside the table
    assert recorded[["instance", "algorithm", "runs"]].values.tolist() == [[1, "cs", 2], [2, "cs", 2]]
    assert_same_bits(recorded["f_best"].to_numpy(), table["f_best"].to_numpy(), because="same code")
    assert table["commit"].tolist() == recorded["commit"].tolist()  # the commit its results folder records
    assert table["problem_id"].tolist() == ref.groupby("case")["problem_id"].first().tolist()
    assert recorded["problem_id"].tolist() == table["problem_id"].tolist()
    done = S.run_suite(suite, [problem], ["cs"], [1, 2], tmp_path / "runs", multiplier=2.0, runs=2,
                       stream=open(tmp_path / "log2", "w"))
    S.leaderboard(suite, done, tmp_path / "board", multiplier=2.0, figures=False, ioh=False, targets_path=table_path)
    used = pd.read_csv(tmp_path / "board" / "targets_used.csv")
    assert used["source"].eq("table").all()
    # the best known is the table's unless a run of the suite did better
    for row in used.itertuples():
        k = int(row.case.split("/i")[1])
        assert row.f_best <= table.loc[table["instance"] == k, "f_best"].iloc[0]


def test_a_reference_row_names_the_commit_of_its_best_run_not_of_the_last_gathering(suite, tmp_path):
    # a reference folder gathered again at a later commit (a resumed call that ran nothing) kept
    # its runs' commits in run_origins; meta.json's git_commit names the later process
    from heurtune.runner.experiment import part_name

    folder = tmp_path / "cmaes_sqp"
    folder.mkdir()
    runs = pd.DataFrame(dict(case=["i1", "i1"], problem_id="p0", algorithm="cmaes_sqp", optimiser_index=0, run=[0, 1],
                             best_f=[2.0, 1.5], feasible=True, n_evals=100, convergence_evals=[40, 60],
                             wall_time_s=5.0))
    runs.to_parquet(folder / "runs.parquet")
    origins = {part_name("i1", 0, "cmaes_sqp", 0): {"git_commit": "aaaaaaa111", "git_dirty": False,
                                                    "written": "2026-12-01T09:00:00+0000"},
               part_name("i1", 0, "cmaes_sqp", 1): {"git_commit": "bbbbbbb222", "git_dirty": False,
                                                    "written": "2026-12-02T09:00:00+0000"}}
    meta = dict(git_commit="ccccccc333", written="2026-12-07T10:00:00", run_origins=origins)
    (folder / "meta.json").write_text(json.dumps(meta))
    [row] = S.reference_run_rows(folder, suite.problem("pid-min"), 50.0, 100.0)
    assert (row["f_best"], row["converged_at"], row["commit"], row["date"]) == (1.5, 60, "bbbbbbb", "2026-12-02")
    # an origin from before heurtune recorded its date: the folder's date beside the run's commit
    del origins[part_name("i1", 0, "cmaes_sqp", 1)]["written"]
    (folder / "meta.json").write_text(json.dumps(meta))
    row = S.reference_run_rows(folder, suite.problem("pid-min"), 50.0, 100.0)[0]
    assert (row["commit"], row["date"]) == ("bbbbbbb", "2026-12-07")
    # a folder from before run_origins: the folder's commit and date
    (folder / "meta.json").write_text(json.dumps({k: v for k, v in meta.items() if k != "run_origins"}))
    row = S.reference_run_rows(folder, suite.problem("pid-min"), 50.0, 100.0)[0]
    assert (row["commit"], row["date"]) == ("ccccccc", "2026-12-07")


def test_a_suite_folder_calibrates_its_first_instance_for_all(tmp_path, suite, monkeypatch):
    """The instances of a problem cost alike: the runner calibrates (and checks for dead
    variables) the first instance with runs to do and plans the others with its figure."""
    import heurtune.runner.experiment as E

    calibrated, checked = [], []
    real_calibrate, real_warn = E.calibrate, E._warn_dead_variables
    monkeypatch.setattr(E, "calibrate", lambda prob, *a, **k: calibrated.append(prob.case) or real_calibrate(prob))
    monkeypatch.setattr(E, "_warn_dead_variables",
                        lambda exp, case, *a: checked.append(case) or real_warn(exp, case, *a))
    log = open(tmp_path / "log", "w")
    [(_, _, folder)] = S.run_suite(suite, [suite.problem("lqi-nmp")], ["random_search"], [2, 3, 4], tmp_path,
                                   multiplier=0.5, runs=1, stream=log)
    assert calibrated == ["i2"] and checked == ["i2"]
    assert sorted(pd.read_parquet(folder / "runs.parquet")["case"]) == ["i2", "i3", "i4"]
    # an experiment's own cases are each calibrated (they may be different problems)
    calibrated.clear()
    E.run_experiment(str(tmp_path / "configs" / "lqi-nmp__random_search.toml"), out=tmp_path / "own",
                     figures=False, progress_stream=log)
    assert calibrated == ["i2", "i3", "i4"]


def test_folders_side_by_side_make_the_runs_one_after_another_makes_and_stop_at_a_failure(tmp_path, suite):
    # two workers and two folders: the folders open side by side, their runs on one shared pool
    problems = [suite.problem("pid-min"), suite.problem("iolqi-min-limits")]
    one = S.run_suite(suite, problems, ["pso"], [2], tmp_path / "one", multiplier=5.0, runs=2, jobs=1)
    two = S.run_suite(suite, problems, ["pso"], [2], tmp_path / "two", multiplier=5.0, runs=2, jobs=2)
    assert [(p.name, alg) for p, alg, _ in two] == [(p.name, alg) for p, alg, _ in one]
    for (_, _, a), (_, _, b) in zip(one, two):
        ra, rb = (pd.read_parquet(d / "runs.parquet").drop(columns="wall_time_s") for d in (a, b))
        assert_same_bits(rb, ra, because="workers")
    # another budget: pid-min's folder starts anew, iolqi's holds runs of another config and fails,
    # which stops pid-min's folder beside it
    shutil.rmtree(two[0][2])
    with pytest.raises(ConfigError, match="made with another config"):
        S.run_suite(suite, problems, ["pso"], [2], tmp_path / "two", multiplier=6.0, runs=2, jobs=2)
    assert not list(tmp_path.rglob(".heurtune.lock"))
