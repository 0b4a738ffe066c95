"""heurtune.compare: loading, statistics (Wilcoxon rank-sum + Holm, Friedman), winners, rendering, CLI."""

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from heurtune import compare
from heurtune.compare import (find_winners, friedman_test, holm, load_runs, pairwise_tests, reevaluation_table,
                              report, run, summary_table)
from heurtune.errors import ConfigError

SCENARIOS = ("nominal", "-30%", "+30%")
METRICS = ("Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2", "J1", "J2", "J")


def make_runs(values, *, experiment="exp", case="min", problem_id="pid-min", seed=0):
    """Rows shaped like runs.parquet; ``values`` maps algorithm -> best_f per run."""
    rng = np.random.default_rng(seed)
    rows = []
    for alg, fs in values.items():
        for r, f in enumerate(fs):
            row = {"experiment": experiment, "case": case, "algorithm": alg, "controller": "folqi",
                   "problem_id": problem_id, "run": r, "seed": 12345, "seed_key": f"{alg}/{r}",
                   "best_f": float(f), "feasible": True, "violation": 0.0, "n_evals": 1000, "n_epochs": 50,
                   "convergence_epoch": 10 + r, "wall_time_s": 0.5, "stop_reason": "budget",
                   "Q11": rng.random(), "alpha2": rng.random()}
            for sc in SCENARIOS:
                for m in METRICS:
                    row[f"{m}@{sc}"] = rng.random()
                row[f"feasible@{sc}"] = True
            rows.append(row)
    return pd.DataFrame(rows)


def write(tmp_path, name, df):
    d = tmp_path / name
    d.mkdir()
    df.to_parquet(d / "runs.parquet", index=False)
    return d


def clear_winner_runs():
    rng = np.random.default_rng(1)
    return pd.concat([
        make_runs({"cs": rng.normal(1.0, 0.1, 10), "pso": rng.normal(10.0, 0.1, 10),
                   "ga": rng.normal(10.0, 0.1, 10)}, case="min", problem_id="pid-min"),
        make_runs({"cs": rng.normal(5.0, 0.1, 10), "pso": rng.normal(5.0, 0.1, 10),
                   "ga": rng.normal(5.0, 0.1, 10)}, case="nmp", problem_id="pid-nmp"),
    ], ignore_index=True)


# ------------------------------------------------------------------------------------------------ statistics

def test_holm_against_hand_computation():
    # sorted: 0.005*4 = 0.02, 0.01*3 = 0.03, 0.03*2 = 0.06, 0.04*1 = 0.04 -> monotone 0.06
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    # capped at 1; a missing p-value stays missing and does not count in m
    out = holm([0.5, np.nan, 0.6])
    assert out[0] == 1.0 and np.isnan(out[1]) and out[2] == 1.0
    assert holm([0.02]) == pytest.approx([0.02])
    assert holm([]).size == 0


def test_clear_winner_is_marked():
    runs = clear_winner_runs()
    pairs = pairwise_tests(runs, "best_f")
    pmin = pairs[pairs.case == "min"]
    assert len(pmin) == 3 and len(pairs) == 6
    cs = pmin[(pmin.algorithm_a == "cs") | (pmin.algorithm_b == "cs")]
    assert (cs.p_holm < 0.05).all() and cs.significant.all() and (cs.better == "cs").all()
    # Holm within the case, on the raw two-sided Mann-Whitney p-values
    raw = [stats.mannwhitneyu(runs.query("case == 'min' and algorithm == @a").best_f,
                              runs.query("case == 'min' and algorithm == @b").best_f,
                              alternative="two-sided").pvalue for a, b in zip(pmin.algorithm_a, pmin.algorithm_b)]
    assert pmin.p.to_numpy() == pytest.approx(raw)
    assert pmin.p_holm.to_numpy() == pytest.approx(holm(raw))
    assert find_winners(pairs) == {"min": "cs", "nmp": None}

    text = report(runs, fmt="md")
    assert "| cs* |" in text and "\\* cs: significantly better than every other algorithm" in text
    assert "No winner" in text  # case nmp
    assert "pso*" not in text and "ga*" not in text


def test_equal_distributions_have_no_winner():
    values = np.linspace(1.0, 2.0, 10)
    rng = np.random.default_rng(3)
    runs = make_runs({a: rng.permutation(values) for a in ("cs", "pso", "ga")})
    pairs = pairwise_tests(runs, "best_f")
    assert pairs.p.to_numpy() == pytest.approx(1.0)
    assert not pairs.significant.any()
    assert find_winners(pairs) == {"min": None}
    assert "*" not in report(runs, fmt="md").replace("\\*", "")


def test_winner_needs_to_beat_every_other_algorithm():
    rng = np.random.default_rng(4)
    # cs and pso are both far better than ga but indistinguishable from each other: no winner
    runs = make_runs({"cs": rng.normal(1, 0.1, 10), "pso": rng.normal(1, 0.1, 10), "ga": rng.normal(9, 0.1, 10)})
    pairs = pairwise_tests(runs, "best_f")
    assert pairs.significant.sum() == 2
    assert find_winners(pairs) == {"min": None}


def test_friedman_against_scipy_and_hand_ranks():
    table = {"a": [1.0, 2.0, 1.0, 3.0], "b": [2.0, 1.0, 1.0, 1.0], "c": [3.0, 3.0, 2.0, 2.0]}
    runs = make_runs(table)
    # run 4 exists for a and b only, and c's run 1 is missing a value elsewhere: not a complete block
    runs = pd.concat([runs, make_runs({"a": [0, 0, 0, 0, 9.0], "b": [0, 0, 0, 0, 9.0]}).query("run == 4")],
                     ignore_index=True)
    res = friedman_test(runs, "best_f")
    ref = stats.friedmanchisquare(table["a"], table["b"], table["c"])
    assert res.algorithm.tolist() == ["a", "b", "c"]
    assert (res.n_blocks == 4).all()
    assert res.statistic.iloc[0] == pytest.approx(ref.statistic)
    assert res.p.iloc[0] == pytest.approx(ref.pvalue)
    # block ranks: (1,2,3), (2,1,3), (1.5,1.5,3), (3,1,2)
    assert res.mean_rank.tolist() == pytest.approx([7.5 / 4, 5.5 / 4, 11 / 4])

    with_nan = runs.copy()
    with_nan.loc[(with_nan.algorithm == "c") & (with_nan.run == 1), "best_f"] = np.nan
    assert (friedman_test(with_nan, "best_f").n_blocks == 3).all()
    # fewer than three algorithms: no Friedman row
    assert friedman_test(runs[runs.algorithm != "c"], "best_f").empty


def test_summary_table_values():
    runs = make_runs({"cs": [1.0, 2.0, 4.0], "pso": [3.0, 3.0, 3.0]})
    runs.loc[2, "feasible"] = False
    s = summary_table(runs, "best_f").set_index("algorithm")
    assert s.loc["cs", "n"] == 3
    assert s.loc["cs", "mean"] == pytest.approx(7 / 3)
    assert s.loc["cs", "sd"] == pytest.approx(np.std([1, 2, 4], ddof=1))
    assert (s.loc["cs", "median"], s.loc["cs", "best"], s.loc["cs", "worst"]) == (2.0, 1.0, 4.0)
    assert s.loc["cs", "mean_convergence_epoch"] == pytest.approx(11.0)
    assert s.loc["cs", "feasible_rate"] == pytest.approx(2 / 3)
    assert s.loc["pso", "sd"] == 0.0 and s.loc["pso", "feasible_rate"] == 1.0
    assert s.case.tolist() == ["min", "min"]


def test_reevaluation_table_picks_best_feasible_run():
    runs = make_runs({"cs": [0.5, 1.0, 2.0], "pso": [3.0, 2.0, 1.0]})
    runs.loc[0, "feasible"] = False  # cs run 0 has the lowest best_f but is infeasible
    pso = runs.algorithm == "pso"
    runs.loc[pso, "feasible"] = False
    runs.loc[pso, "violation"] = [0.3, 0.1, 0.2]  # none feasible: lowest violation -> run 1
    runs = runs.drop(columns=[c for c in runs.columns if c.startswith("Mp2@")])
    t = reevaluation_table(runs)
    assert list(t.columns) == ["case", "algorithm", "scenario", "run", "Mp1", "ts1", "ts2", "ess1", "ess2",
                               "J1", "J2", "J", "feasible"]
    assert t.scenario.tolist() == list(SCENARIOS) * 2
    assert t[t.algorithm == "cs"].run.unique().tolist() == [1]
    assert t[t.algorithm == "pso"].run.unique().tolist() == [1]
    src = runs[(runs.algorithm == "cs") & (runs.run == 1)].iloc[0]
    row = t[(t.algorithm == "cs") & (t.scenario == "-30%")].iloc[0]
    assert row["J"] == src["J@-30%"] and row["ts2"] == src["ts2@-30%"]

    bare = runs[[c for c in runs.columns if "@" not in c]]
    assert reevaluation_table(bare).empty


# ------------------------------------------------------------------------------------------------ loading

def test_load_runs_merges_directories(tmp_path):
    a = write(tmp_path, "a", make_runs({"cs": [1, 2]}, experiment="e1"))
    b = write(tmp_path, "b", make_runs({"pso": [3, 4]}, experiment="e2"))
    runs = load_runs([a, b])
    assert runs.algorithm.tolist() == ["cs", "cs", "pso", "pso"]
    assert runs.index.tolist() == [0, 1, 2, 3]


def test_same_algorithm_in_two_experiments_is_labelled(tmp_path):
    a = write(tmp_path, "a", make_runs({"cs": [1, 2], "pso": [3, 4]}, experiment="e1"))
    b = write(tmp_path, "b", make_runs({"cs": [5, 6]}, experiment="e2"))
    runs = load_runs([a, b])
    assert list(pd.unique(runs.algorithm)) == ["cs [e1]", "pso", "cs [e2]"]


def test_mismatched_problem_id_is_refused(tmp_path):
    a = write(tmp_path, "a", make_runs({"cs": [1, 2]}, experiment="e1", problem_id="aaa111"))
    b = write(tmp_path, "b", make_runs({"pso": [3, 4]}, experiment="e2", problem_id="bbb222"))
    with pytest.raises(ConfigError) as err:
        load_runs([a, b])
    msg = str(err.value)
    assert "\n" not in msg
    for token in ("case 'min'", "aaa111 (e1)", "bbb222 (e2)"):
        assert token in msg
    # different cases may have different problem ids
    c = write(tmp_path, "c", make_runs({"pso": [3, 4]}, experiment="e2", case="nmp", problem_id="ccc333"))
    assert len(load_runs([a, c])) == 4


def test_missing_file_and_duplicates_are_refused(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ConfigError, match=r"empty: no runs.parquet"):
        load_runs([empty])
    with pytest.raises(ConfigError, match="no experiment directories"):
        load_runs([])
    a = write(tmp_path, "a", make_runs({"cs": [1, 2]}))
    b = write(tmp_path, "b", make_runs({"cs": [1, 2]}))
    with pytest.raises(ConfigError, match=r"duplicate run: experiment 'exp', case 'min', algorithm 'cs', run 0 "
                                          r"in .*a and .*b \(1 more"):
        load_runs([a, b])
    bad = tmp_path / "bad"
    bad.mkdir()
    make_runs({"cs": [1]}).drop(columns="problem_id").to_parquet(bad / "runs.parquet")
    with pytest.raises(ConfigError, match="missing column.*problem_id"):
        load_runs([bad])


def test_unknown_or_non_numeric_metric_is_refused():
    runs = make_runs({"cs": [1, 2]})
    with pytest.raises(ConfigError, match="unknown metric column 'nope'.*best_f"):
        summary_table(runs, "nope")
    with pytest.raises(ConfigError, match="not numeric"):
        pairwise_tests(runs, "stop_reason")
    with pytest.raises(ConfigError, match="not numeric"):
        friedman_test(runs, "feasible@nominal")


# ------------------------------------------------------------------------------------------------ CLI

@pytest.fixture
def two_dirs(tmp_path):
    runs = clear_winner_runs()
    a = write(tmp_path, "a", runs[runs.algorithm != "ga"].assign(experiment="e1"))
    b = write(tmp_path, "b", runs[runs.algorithm == "ga"].assign(experiment="e2"))
    return str(a), str(b)


def test_cli_markdown(two_dirs, capsys):
    assert run([*two_dirs]) == 0
    out = capsys.readouterr().out
    assert "## Case min" in out and "## Case nmp" in out
    assert "| cs* |" in out and "\\* cs: significantly better" in out
    assert "Friedman test over 10 paired runs" in out
    for col in ("mean rank", "SD", "p (Holm)", "Mp1", "ts2", "J"):
        assert col in out


def test_cli_csv_to_file(two_dirs, tmp_path, capsys):
    out = tmp_path / "out" / "report.csv"
    assert run([*two_dirs, "--format", "csv", "--metric", "J@nominal", "--out", str(out)]) == 0
    assert "report written to" in capsys.readouterr().out
    text = out.read_text()
    assert text.startswith("# Statistical comparison of J@nominal")
    assert not list(out.parent.glob(".*"))  # no temporary file left behind
    sections = [s for s in text.split("\n\n") if not s.startswith("# ") or "\n" in s]
    summary = pd.read_csv(__import__("io").StringIO(sections[0]), comment="#")
    assert summary.columns[:3].tolist() == ["algorithm", "n", "mean"]
    assert summary.n.tolist() == [10, 10, 10]


def test_cli_latex(two_dirs, capsys, monkeypatch):
    assert run([*two_dirs, "--format", "latex", "--alpha", "0.01"]) == 0
    out = capsys.readouterr().out
    assert "\\subsection*{Case min}" in out and "\\begin{tabular}" in out and "\\toprule" in out
    assert "cs* &" in out and "-30\\%" in out and "best\\_f" in out and "p \\textless{} 0.01" in out
    # without jinja2 the own tabular writer gives the same text as pandas' to_latex
    monkeypatch.setattr(compare, "_have_jinja2", lambda: False)
    assert run([*two_dirs, "--format", "latex", "--alpha", "0.01"]) == 0
    assert capsys.readouterr().out == out


@pytest.mark.parametrize("args, message", [
    ([], "error: no experiment directories given"),
    (["{a}", "--format", "html"], "error: unknown format 'html' (choose from md, csv, latex)"),
    (["{a}", "--metric", "nope"], "error: unknown metric column 'nope'"),
    (["{a}", "--alpha", "1.5"], "error: --alpha must lie in (0, 1)"),
    (["{a}", "--alpha", "x"], "error: argument --alpha: invalid float value: 'x'"),
    (["{a}", "--bogus"], "error: unrecognized arguments: --bogus"),
    (["{missing}"], "no runs.parquet found"),
])
def test_cli_errors(two_dirs, tmp_path, capsys, args, message):
    args = [x.format(a=two_dirs[0], missing=tmp_path / "missing") for x in args]
    assert run(args) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1
    assert message in captured.err


def test_module_entry_point(two_dirs):
    res = subprocess.run([sys.executable, "-m", "heurtune.compare", *two_dirs, "--format", "html"],
                         capture_output=True, text=True)
    assert res.returncode == 2 and res.stderr.startswith("error: unknown format")


# ------------------------------------------------------------------------------------------------ margins

def make_margins(experiment, algorithms, cases=("min", "nmp")):
    """Rows shaped like margins.parquet (heurtune.margins.MARGIN_COLUMNS plus the run keys)."""
    from heurtune.margins import ELEMENT_LOOP, MARGIN_COLUMNS

    rows = []
    for c, case in enumerate(cases):
        for a, alg in enumerate(algorithms):
            for i in (1, 2):
                for j in (1, 2):
                    cross = i != j
                    row = dict(zip(MARGIN_COLUMNS, [i, j, np.nan if cross else 1.0 + i + 0.1 * a + c,
                                                    np.inf if cross else 20.0 + i + a + 10 * c, np.nan, np.inf,
                                                    0 if cross else 1, 0, 0, ELEMENT_LOOP]))
                    rows.append(dict(experiment=experiment, case=case, algorithm=alg, run=3, **row))
    # stored in the writer's order: (output, input) shuffled to check the sort
    return pd.DataFrame(rows).iloc[::-1].reset_index(drop=True)


@pytest.fixture
def dirs_with_margins(two_dirs):
    a, b = two_dirs  # a: cs and pso of e1 with margins; b: ga of e2 without margins.parquet
    make_margins("e1", ["cs", "pso"]).to_parquet(f"{a}/margins.parquet", index=False)
    return a, b


def test_margins_table_layout(dirs_with_margins):
    m = compare.load_margins(dirs_with_margins)
    assert len(m) == 16 and set(m.algorithm) == {"cs", "pso"}  # ga's folder has none: skipped
    t = compare.margins_table(m)
    assert t.columns.tolist() == ["case", "algorithm", "run", "input", "output", "gain crossover (rad/s)",
                                  "phase margin (deg)"]
    first = t[(t.case == "min") & (t.algorithm == "cs")]
    assert first[["input", "output"]].values.tolist() == [[1, 1], [1, 2], [2, 1], [2, 2]]
    assert first["gain crossover (rad/s)"].tolist()[0::3] == [2.0, 3.0]
    assert first["phase margin (deg)"].tolist() == [21.0, np.inf, np.inf, 22.0]


def test_cli_prints_margins_in_every_format(dirs_with_margins, capsys):
    assert run([*dirs_with_margins]) == 0
    out = capsys.readouterr().out
    assert "### Case min: loop margins of each algorithm's best run (input i, output j)" in out
    assert "| cs* | 3 | 1 | 1 | 2 | 21 |" in out and "| cs* | 3 | 1 | 2 |  | inf |" in out
    assert "| pso | 3 | 2 | 2 | 3.1 | 23 |" in out
    assert "| cs | 3 | 2 | 2 | 4 | 32 |" in out  # nmp: no winner, no asterisk
    assert run([*dirs_with_margins, "--format", "csv"]) == 0
    text = capsys.readouterr().out
    section = next(s for s in text.split("\n\n") if s.startswith("# Case nmp: loop margins"))
    t = pd.read_csv(__import__("io").StringIO(section), comment="#")
    ref = compare.margins_table(compare.load_margins(dirs_with_margins))
    ref = ref[ref.case == "nmp"].drop(columns="case").reset_index(drop=True)
    pd.testing.assert_frame_equal(t, ref, check_dtype=False)
    assert run([*dirs_with_margins, "--format", "latex"]) == 0
    out = capsys.readouterr().out
    assert "loop margins of each algorithm's best run" in out and "phase margin (deg)" in out


def test_margins_missing_or_foreign_are_skipped(two_dirs, tmp_path, capsys):
    assert compare.load_margins(two_dirs).empty
    # TITO experiments write per-loop margins (no input/output): not this table
    pd.DataFrame({"experiment": ["e1"], "case": ["min"], "algorithm": ["cs"], "loop": [1],
                  "gain_margin": [2.0], "phase_margin_deg": [45.0]}).to_parquet(f"{two_dirs[0]}/margins.parquet")
    assert compare.load_margins(two_dirs).empty
    assert run([*two_dirs]) == 0
    assert "loop margins" not in capsys.readouterr().out


def test_margins_follow_the_relabelled_algorithms(tmp_path):
    runs = make_runs({"cs": [1.0, 2.0]})
    a = write(tmp_path, "a", runs.assign(experiment="e1"))
    b = write(tmp_path, "b", runs.assign(experiment="e2"))
    make_margins("e1", ["cs"], cases=("min",)).to_parquet(a / "margins.parquet", index=False)
    loaded = load_runs([a, b])
    m = compare.load_margins([a, b], loaded)
    assert set(m.algorithm) == {"cs [e1]"}
    assert "| cs [e1] | 3 | 1 | 1 |" in report(loaded, margins=m)


def test_margins_from_heurtune_margins(tmp_path):
    # the real writer's schema: loop_margins of the thesis' CS/FOLQI/min gains
    import heurtune
    from heurtune.margins import loop_margins

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    x = prob.parse("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,"
                   "Ki2=7.1716,alpha1=0.9814,alpha2=0.8437")
    m = loop_margins(prob, x).assign(experiment="exp", case="min", algorithm="cs", run=0)
    d = write(tmp_path, "a", make_runs({"cs": [1.0]}))
    m.to_parquet(d / "margins.parquet", index=False)
    t = compare.margins_table(compare.load_margins([d]))
    assert t["gain crossover (rad/s)"].round(3).tolist()[0::3] == [1.023, 2.244]
    assert t["phase margin (deg)"].round(2).tolist() == [20.31, np.inf, np.inf, 21.52]
