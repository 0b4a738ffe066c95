"""The thesis chapter experiments: configs, plans, fixed-gain baselines, optimisers per case."""

import textwrap

import numpy as np
import pandas as pd
import pytest

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.core.families import make_experiment
from heurtune.runner.config import load_config
from heurtune.runner.experiment import plan, problem_id, run

TABLE_4_7_MIN_BETA11 = 27.6941  # thesis Table 4.7, minimum phase


def _config(tmp_path, text: str, name="exp"):
    path = tmp_path / f"{name}.toml"
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize("name", ["thesis_ch4", "thesis_ch5", "thesis_ch6", "thesis_heuristics"])
def test_chapter_experiments_load(name):
    exp = heurtune.load_experiment(name)
    assert exp.config["report"]["thesis_chapter"] == {"thesis_ch4": 4, "thesis_ch6": 6}.get(name, 5)


def test_thesis_heuristics_is_thesis_ch5_with_five_runs(tmp_path):
    from qtp_cases import sampled_experiment

    old, new = heurtune.load_experiment("thesis_heuristics"), heurtune.load_experiment("thesis_ch5")
    assert old.cases == new.cases == ("min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi")
    assert [problem_id(old, c) for c in old.cases] == [problem_id(new, c) for c in new.cases]
    # With the sampled loop, the ids the earlier thesis_heuristics wrote: its results stay comparable.
    sampled = sampled_experiment("thesis_heuristics", tmp_path)
    assert [problem_id(sampled, c) for c in old.cases] == ["b82a33e350f3", "ed3cb6596bba", "154058fba0b2",
                                                            "322f7a74b55e"]
    assert old.config["runs"] == 5 and new.config["runs"] >= 20
    assert [o["name"] for o in old.optimisers] == [o["name"] for o in new.optimisers] == ["cs", "apso", "firefly"]


def test_chapter_4_plan_tunes_lqi_cases_and_evaluates_the_printed_ladr():
    exp = heurtune.load_experiment("thesis_ch4")
    specs = plan(exp)
    tuned = [(s.case, s.algorithm) for s in specs if not s.baseline]
    assert tuned == [(c, "sqp_multistart") for c in ("min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi")]
    fixed = [(s.case, s.algorithm) for s in specs if s.baseline]
    assert fixed == [("min-ladr", "table_4_7"), ("nmp-ladr", "table_4_7")]
    settings = specs[0].settings
    assert (settings["starts"], settings["max_iter"], settings["ftol"]) == (1000, 100, 1e-6)
    assert "max_evals" not in specs[0].budget
    prob = exp.problem("min-ladr")
    x = prob.baseline("table_4_7")
    assert x[prob.names.index("beta11")] == TABLE_4_7_MIN_BETA11
    # exact: the config's literals, parsed
    assert exp.scenarios["+5%"].uncertainty == 1.05 and prob.constraints == {"Mp": 15.0, "ts": 70.0, "ess": 3.0}


def test_chapter_6_is_the_unconstrained_effort_deviation_problem_on_the_bond_graph_plant():
    exp = heurtune.load_experiment("thesis_ch6")
    assert exp.cases == ("min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi")
    prob = exp.problem("nmp-iolqi")
    assert prob.objective == "effort_deviation" and prob.constraint_names == ("stability",)
    assert prob.loop.plant_model == "qtp_bond_graph"
    assert [o["name"] for o in exp.optimisers] == ["newton_raphson", "dfp", "steepest_descent", "bfgs"]
    # The bond-graph plant is a different problem from the level model's.
    level = make_experiment({**load_config("thesis_ch6"), "plant": {"model": "qtp", "cases": ["min", "nmp"]}})
    assert problem_id(exp, "min-folqi") != problem_id(level, "min-folqi")


BASE = """
    extends = "cs_folqi_qtp"
    runs = 1
    [controller]
    type = ["iolqi", "ladr"]
    [scenario]
    horizon = 80.0
    dt = 0.05
    disturbance_time = 10.0
    [[optimisers]]
    name = "cs"
    settings = { n = 4 }
    max_epochs = 1
    cases = ["min-iolqi"]
"""
X_MIN = dict(Q11=1.6734, Q22=1.0641, Q33=0.7957, Q44=0.5306, R11=2.7207, R22=1.5185, Ki1=0.7769, Ki2=0.9412)


def test_inline_baseline_runs_once_and_reproduces_its_gains(tmp_path):
    gains = ", ".join(f"{k} = {v}" for k, v in X_MIN.items())
    path = _config(tmp_path, BASE + f"""
    [[baselines]]
    name = "printed_iolqi"
    case = "min-iolqi"
    x = {{ {gains} }}
    """)
    exp = heurtune.load_experiment(str(path))
    specs = plan(exp)
    assert [(s.case, s.algorithm, s.baseline) for s in specs] == [
        ("min-iolqi", "cs", False), ("min-iolqi", "printed_iolqi", True)]
    out = tmp_path / "out"
    assert run([str(path), "--out", str(out), "--no-figures"]) == 0
    runs = pd.read_parquet(out / "runs.parquet")
    row = runs[runs["algorithm"] == "printed_iolqi"].iloc[0]
    assert row["n_evals"] == 1 and row["stop_reason"] == "analytic design"
    assert [row[k] for k in X_MIN] == list(X_MIN.values())
    prob = exp.problem("min-iolqi")
    ev = prob.evaluate(np.array(list(X_MIN.values())))
    assert row["best_f"] == ev.f[0]


@pytest.mark.parametrize("extra, message", [
    ('[[baselines]]\nname = "b"\ncase = "max-ladr"\nx = {}', "baselines[0].case: unknown case 'max-ladr'"),
    ('[[baselines]]\nname = "b"\ncase = "min-iolqi"\nx = { Q11 = 1.0 }', "baselines[0]: no value for Q22"),
    ('[[baselines]]\nname = "b"\ncase = "min-iolqi"', "give the gains as x"),
    ('[[baselines]]\nname = "b"\ncase = "min-ladr"\nprinted = { table = "9.9", row = "min-ladr" }', "9.9"),
    ('[report]\nthesis_chapter = 7', "report.thesis_chapter: got 7; allowed: 4, 5, 6"),
])
def test_bad_baselines_and_report_keys_are_one_line_errors(tmp_path, extra, message):
    path = _config(tmp_path, BASE + "\n" + extra + "\n")
    with pytest.raises(ConfigError, match=None) as info:
        heurtune.load_experiment(str(path))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_optimiser_cases_must_name_cases(tmp_path):
    path = _config(tmp_path, BASE.replace('cases = ["min-iolqi"]', 'cases = ["min-pid"]'))
    with pytest.raises(ConfigError, match=r"optimisers\[0\]\.cases: unknown case 'min-pid'; allowed: min-iolqi"):
        heurtune.load_experiment(str(path))


def test_optimiser_restricted_to_a_case_keeps_its_seed(tmp_path):
    # Restricting an optimiser to some cases does not move the seeds of the runs it keeps.
    everywhere = heurtune.load_experiment(str(_config(tmp_path, BASE.replace('cases = ["min-iolqi"]', ""), "all")))
    some = heurtune.load_experiment(str(_config(tmp_path, BASE, "some")))
    keys_all = {(s.case, s.run): s.spawn_key for s in plan(everywhere)}
    for s in plan(some):
        assert keys_all[(s.case, s.run)] == s.spawn_key


CHAPTER_TABLES = {
    "thesis_ch4": ["4_2", "4_3", "4_4", "4_5", "4_6", "4_7", "4_8", "4_9", "4_10", "4_11", "4_12"],
    "thesis_ch6": ["6_3", "6_4", "6_5"],
}


# 17-22 s a chapter on the EPYC: `make test-long`; `make test` runs the inline baseline above and
# writes the tables from printed rows (test_thesis_tables)
@pytest.mark.long
@pytest.mark.parametrize("name", sorted(CHAPTER_TABLES))
def test_chapter_smoke_run_writes_its_tables(name, tmp_path):
    # Chapter 5's end-to-end run is in test_thesis_tables.py.
    out = tmp_path / name
    assert run([name, "--smoke", "--runs", "1", "--out", str(out), "--no-figures"]) == 0
    for table in CHAPTER_TABLES[name]:
        md = (out / "tables" / f"table_{table}.md").read_text()
        assert "printed" in md and "heurtune" in md
        assert (out / "tables" / f"table_{table}.tex").read_text().count("\\begin{tabular}") >= 1
    runs = pd.read_parquet(out / "runs.parquet")
    if name == "thesis_ch4":
        starts = pd.read_parquet(out / "starts.parquet")
        assert set(starts["case"]) == {"min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi"}
        assert {"x0_Q11", "Q11", "f", "feasible", "nit", "nfev", "message"} <= set(starts.columns)
        ladr = runs[runs["algorithm"] == "table_4_7"]
        assert sorted(ladr["case"]) == ["min-ladr", "nmp-ladr"] and (ladr["n_evals"] == 1).all()
    else:
        assert not (out / "starts.parquet").exists()
        assert set(runs["algorithm"]) == {"newton_raphson", "dfp", "steepest_descent", "bfgs"}
