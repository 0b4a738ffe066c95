"""heurtune.compare: loading, statistics (Kruskal-Wallis, Dunn, Wilcoxon rank-sum, Holm, A12, Friedman/Nemenyi
across cases), winners, rendering, CLI."""

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from numerics import assert_exact, assert_same_bits
from scipy import stats

from heurtune.analysis import compare, render
from heurtune.analysis.compare import (
    find_winners,
    friedman_across_cases,
    holm,
    kruskal_test,
    load_runs,
    pairwise_tests,
    reevaluation_table,
    report,
    run,
    summary_table,
)
from heurtune.core.errors import ConfigError

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
                   "convergence_epoch": 10 + r, "convergence_evals": 20 * (10 + r), "wall_time_s": 0.5,
                   "stop_reason": "budget",
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


def test_summary_table_values():
    runs = make_runs({"cs": [1.0, 2.0, 4.0, 0.5], "pso": [3.0, 3.0, 3.0]})
    runs.loc[3, "feasible"] = False  # cs run 3: best candidate infeasible, not a success
    s = summary_table(runs, "best_f").set_index("algorithm")
    assert s.loc["cs", "n"] == 3 and s.loc["cs", "runs"] == 4 and s.loc["cs", "infeasible"] == 1
    assert s.loc["cs", "success_rate"] == pytest.approx(3 / 4) and s.loc["cs", "failed"] == 0
    assert s.loc["cs", "mean"] == pytest.approx(7 / 3)
    assert s.loc["cs", "sd"] == pytest.approx(np.std([1, 2, 4], ddof=1))
    assert (s.loc["cs", "median"], s.loc["cs", "best"], s.loc["cs", "worst"]) == (2.0, 1.0, 4.0)
    assert s.loc["cs", "mean_convergence_epoch"] == pytest.approx(11.5)
    assert s.loc["cs", "mean_convergence_evals"] == pytest.approx(230.0)
    assert s.loc["cs", "feasible_rate"] == pytest.approx(3 / 4)
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
    assert row["J"] == src["J@-30%"] and row["ts2"] == src["ts2@-30%"]  # exact: copied from the runs

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
    twice = write(tmp_path, "twice", pd.concat([make_runs({"cs": [1, 2]})] * 2, ignore_index=True))
    with pytest.raises(ConfigError, match=r"duplicate run: experiment 'exp', case 'min', algorithm 'cs', run 0 "
                                          r"in .*twice \(1 more"):
        load_runs([twice])
    bad = tmp_path / "bad"
    bad.mkdir()
    make_runs({"cs": [1]}).drop(columns="problem_id").to_parquet(bad / "runs.parquet")
    with pytest.raises(ConfigError, match="missing column.*problem_id"):
        load_runs([bad])


def seed_variants(tmp_path):
    """Two folders of the same experiment (smoke-like), run with different seeds."""
    root = tmp_path / "results"
    root.mkdir()
    dirs = []
    for seed in (1, 2):
        rng = np.random.default_rng(seed)
        runs = pd.concat([make_runs({"cs": rng.normal(1, 0.1, 5), "pso": rng.normal(2, 0.1, 5)},
                                    experiment="smoke", case=case, problem_id=f"pid-{case}", seed=seed)
                          for case in ("min", "nmp")], ignore_index=True)
        dirs.append(write(root, f"seed{seed}", runs))
    return dirs


def test_same_experiment_in_two_folders_is_compared_as_variants(tmp_path):
    a, b = seed_variants(tmp_path)
    runs = load_runs([a, b])
    assert list(pd.unique(runs.algorithm)) == ["cs [seed1]", "pso [seed1]", "cs [seed2]", "pso [seed2]"]
    assert len(runs) == 40 and (runs.groupby(["case", "algorithm"]).size() == 5).all()
    # explicit labels win; a folder without one keeps its name
    runs = load_runs([a, str(b / "runs.parquet")], labels={"tuned": b})
    assert list(pd.unique(runs.algorithm)) == ["cs [seed1]", "pso [seed1]", "cs [tuned]", "pso [tuned]"]
    # an explicit label is used even where the experiment names would tell the folders apart
    c = write(tmp_path, "c", make_runs({"cs": [1, 2]}, experiment="other", problem_id="pid-min"))
    assert set(load_runs([a, c]).query("case == 'min'").algorithm) == {"cs [smoke]", "pso", "cs [other]"}
    assert set(load_runs([a, c], labels={"A": a}).query("case == 'min'").algorithm) == {"cs [A]", "pso", "cs [c]"}
    assert set(load_runs([a, c]).query("case == 'nmp'").algorithm) == {"cs", "pso"}  # one source there


def test_variant_folder_names_that_clash_take_their_parent(tmp_path):
    runs = make_runs({"cs": [1, 2]})
    (tmp_path / "x").mkdir()
    (tmp_path / "y").mkdir()
    a, b = write(tmp_path / "x", "exp", runs), write(tmp_path / "y", "exp", runs)
    assert set(load_runs([a, b]).algorithm) == {"cs [x/exp]", "cs [y/exp]"}
    assert set(load_runs([a, b], labels={"exp": a}).algorithm) == {"cs [exp]", "cs [y/exp]"}


def test_variant_margins_follow_the_folder_labels(tmp_path):
    a, b = seed_variants(tmp_path)
    make_margins("smoke", ["cs"], cases=("min",)).to_parquet(b / "margins.parquet", index=False)
    loaded = load_runs([a, b], labels={"new": b})
    assert set(compare.load_margins([a, b], loaded).algorithm) == {"cs [new]"}


def test_same_folder_twice_and_bad_labels_are_refused(tmp_path):
    a, b = seed_variants(tmp_path)
    for dirs in ([a, a], [a, str(b), str(b / ".." / "seed2")], [a, a / "runs.parquet"]):
        with pytest.raises(ConfigError, match=r"^the same folder is given twice: \S*seed\d and \S*seed\d\S*$"):
            load_runs(dirs)
    with pytest.raises(ConfigError, match=r"label 'x': .*elsewhere is not among the folders compared"):
        load_runs([a, b], labels={"x": tmp_path / "elsewhere"})
    with pytest.raises(ConfigError, match=r"folder .*seed1 has two labels: 'x' and 'y'"):
        load_runs([a, b], labels={"x": a, "y": a})
    with pytest.raises(ConfigError, match=r"label 'a\]' .* free of"):
        load_runs([a, b], labels={"a]": a})


def test_variants_with_different_problems_are_refused(tmp_path):
    a, b = seed_variants(tmp_path)
    other = pd.read_parquet(b / "runs.parquet").assign(problem_id=lambda df: df.problem_id + "-changed")
    other.to_parquet(b / "runs.parquet", index=False)
    with pytest.raises(ConfigError) as err:
        load_runs([a, b])
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("case 'min': runs are not comparable, problem_id differs: ")
    assert "pid-min (smoke) in " in msg and "pid-min-changed (smoke) in " in msg and "seed2" in msg


def test_unknown_or_non_numeric_metric_is_refused():
    runs = make_runs({"cs": [1, 2]})
    with pytest.raises(ConfigError, match="unknown metric column 'nope'.*best_f"):
        summary_table(runs, "nope")
    with pytest.raises(ConfigError, match="not numeric"):
        pairwise_tests(runs, "stop_reason")
    with pytest.raises(ConfigError, match="not numeric"):
        kruskal_test(runs, "feasible@nominal")


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
    assert "Kruskal-Wallis test over 30 successful runs of 3 algorithms (0 failed or infeasible" in out
    assert "Friedman test on the medians of the successful runs, 2 cases (blocks) x 3 algorithms" in out
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
    monkeypatch.setattr(render, "_have_jinja2", lambda: False)
    assert run([*two_dirs, "--format", "latex", "--alpha", "0.01"]) == 0
    assert capsys.readouterr().out == out


def test_latex_tables_fit_the_page_and_carry_labels(two_dirs, capsys, tmp_path):
    """Every table has its leading text columns and at most LATEX_MAX_COLUMNS in all (wider ones
    are split into parts), a small font, a unique label; the first line names the packages; a
    case's tables stay before the next case's heading. With pdflatex on the machine the report
    compiles on A4 and letter paper without an overfull box."""
    import re
    import shutil
    import subprocess

    assert run([*two_dirs, "--format", "latex"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("% heurtune.compare: needs \\usepackage{booktabs}")
    specs = re.findall(r"\\begin\{tabular\}\{([lr]+)\}", out)
    assert specs and all(len(spec) <= render.LATEX_MAX_COLUMNS + 2 for spec in specs)
    labels = re.findall(r"\\label\{(tab:[a-z0-9-]+)\}", out)
    assert len(labels) == len(specs) == len(set(labels))
    assert "(part 1 of" in out and out.count("\\small") == len(specs)
    assert out.index("\\clearpage") < out.index("\\subsection*{Case nmp}")
    if shutil.which("pdflatex") is None:
        return
    (tmp_path / "report.tex").write_text(out)
    for paper in ("a4paper", "letterpaper"):
        doc = tmp_path / f"doc_{paper}.tex"
        doc.write_text(f"\\documentclass[{paper}]{{article}}\n\\usepackage{{booktabs}}\n\\begin{{document}}\n"
                       "\\input{report}\n\\end{document}\n")
        subprocess.run(["pdflatex", "-interaction=nonstopmode", doc.name], cwd=tmp_path, capture_output=True,
                       timeout=120)
        log = (tmp_path / f"doc_{paper}.log").read_text(errors="replace")
        assert "Output written" in log and "Overfull \\hbox" not in log, paper


@pytest.mark.parametrize("args, message", [
    ([], "error: the following arguments are required: DIR"),
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


def test_cli_compares_variants_with_labels(tmp_path, capsys):
    a, b = seed_variants(tmp_path)
    assert run([str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "| cs [seed1]" in out and "| pso [seed2]" in out
    assert run([str(a), str(b), "--label", f"old={a}", "--label", f"new={b}", "--format", "csv"]) == 0
    out = capsys.readouterr().out
    assert "cs [old]" in out and "pso [new]" in out and "seed1" not in out


@pytest.mark.parametrize("extra, message", [
    (["--label", "nope"], "error: --label 'nope' must have the form NAME=DIR"),
    (["--label", "=x"], "error: --label '=x' must have the form NAME=DIR"),
    (["--label", "x={missing}"], "is not among the folders compared"),
    (["--label", "x={a}", "--label", "x={b}"], "error: --label name 'x' is given twice"),
    (["{a}"], "error: the same folder is given twice"),
])
def test_cli_label_errors(tmp_path, capsys, extra, message):
    a, b = seed_variants(tmp_path)
    args = [str(a), str(b)] + [x.format(a=a, b=b, missing=tmp_path / "missing") for x in extra]
    assert run(args) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith("error: ") and captured.err.count("\n") == 1
    assert message in captured.err


def test_module_entry_point(two_dirs):
    res = subprocess.run([sys.executable, "-m", "heurtune.compare", *two_dirs, "--format", "html"],
                         capture_output=True, text=True)
    assert res.returncode == 2 and res.stderr.startswith("error: unknown format")


# ------------------------------------------------------------------------------------------------ margins

def make_margins(experiment, algorithms, cases=("min", "nmp")):
    """Rows shaped like margins.parquet (heurtune.objectives.qtp.margins.MARGIN_COLUMNS plus the run keys)."""
    from heurtune.objectives.qtp.margins import ELEMENT_LOOP, MARGIN_COLUMNS

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
    assert_exact(t, ref)  # csv of shortest round-trip reprs, read back
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
    from heurtune.objectives.qtp.margins import loop_margins

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    x = prob.parse("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,"
                   "Ki2=7.1716,alpha1=0.9814,alpha2=0.8437")
    m = loop_margins(prob, x).assign(experiment="exp", case="min", algorithm="cs", run=0)
    d = write(tmp_path, "a", make_runs({"cs": [1.0]}))
    m.to_parquet(d / "margins.parquet", index=False)
    t = compare.margins_table(compare.load_margins([d]))
    assert t["gain crossover (rad/s)"].round(3).tolist()[0::3] == [1.023, 2.244]
    assert t["phase margin (deg)"].round(2).tolist() == [20.31, np.inf, np.inf, 21.52]


# ------------------------------------------------------------------------------------------------ issue 11:
# independent-sample tests within a case, Friedman/Nemenyi across cases, A12 effect sizes, success rates

def test_holm_matches_statsmodels():
    from statsmodels.stats.multitest import multipletests

    p = [0.01, 0.04, 0.03, 0.005, 0.2, 0.0001]
    assert holm(p) == pytest.approx(multipletests(p, method="holm")[1], rel=1e-12)


def test_kruskal_wallis_against_scipy_on_successful_runs():
    # ties across groups (3.0, 5.0); cs has a failed run (sentinel) and an infeasible run, both left out
    values = {"cs": [1.0, 3.0, 2.0, 1e10, 0.1], "pso": [3.0, 5.0, 4.0, 6.0], "ga": [5.0, 7.0, 8.0]}
    runs = make_runs(values).assign(status="feasible")
    cs = runs.algorithm == "cs"
    runs.loc[cs & (runs.run == 3), "status"] = "failed"
    runs.loc[cs & (runs.run == 4), ["status", "feasible"]] = ["infeasible", False]
    res = kruskal_test(runs, "best_f")
    ok = {"cs": [1.0, 3.0, 2.0], "pso": values["pso"], "ga": values["ga"]}
    ref = stats.kruskal(*ok.values())
    assert res.algorithm.tolist() == ["cs", "pso", "ga"] and res.n.tolist() == [3, 4, 3]
    assert res.statistic.iloc[0] == pytest.approx(ref.statistic, rel=1e-12)
    assert res.p.iloc[0] == pytest.approx(ref.pvalue, rel=1e-12)
    assert (res.df == 2).all()
    # pooled ranks: 1->1, 2->2, 3,3->3.5, 4->5, 5,5->6.5, 6->8, 7->9, 8->10
    assert res.mean_rank.tolist() == pytest.approx([(1 + 3.5 + 2) / 3, (3.5 + 6.5 + 5 + 8) / 4, (6.5 + 9 + 10) / 3])
    text = report(runs, fmt="md")
    assert "Kruskal-Wallis test over 10 successful runs of 3 algorithms (2 failed or infeasible runs left out)" in text
    # all values equal: no test
    flat = kruskal_test(make_runs({"a": [1.0, 1.0], "b": [1.0, 1.0]}), "best_f")
    assert flat.statistic.isna().all() and flat.p.isna().all()


def test_dunn_holm_against_hand_computation_and_scikit_posthocs():
    import scikit_posthocs as sp

    # scikit-posthocs' documented example for posthoc_dunn (its NaN dropped)
    x = {"g1": [1, 2, 3, 5, 1], "g2": [12, 31, 54], "g3": [10, 12, 6, 74, 11]}
    res = compare.dunn_test(make_runs(x), "best_f")
    # by hand: pooled ranks g1 (1.5, 3, 4, 5, 1.5), g2 (9.5, 11, 12), g3 (7, 9.5, 6, 13, 8); N = 13, two ties of 2
    mean_rank = {"g1": 15 / 5, "g2": 32.5 / 3, "g3": 43.5 / 5}
    n = {"g1": 5, "g2": 3, "g3": 5}
    var = 13 * 14 / 12 - (2 * (2**3 - 2)) / (12 * (13 - 1))  # N(N+1)/12 minus the tie correction
    hand = [2 * stats.norm.sf(abs(mean_rank[a] - mean_rank[b]) / np.sqrt(var * (1 / n[a] + 1 / n[b])))
            for a, b in (("g1", "g2"), ("g1", "g3"), ("g2", "g3"))]
    assert hand == pytest.approx([0.00575, 0.0203, 0.452], abs=5e-4)  # z = 2.762, 2.321, 0.752
    assert res[["algorithm_a", "algorithm_b"]].values.tolist() == [["g1", "g2"], ["g1", "g3"], ["g2", "g3"]]
    assert res.p.to_numpy() == pytest.approx(hand, rel=1e-10)
    # Holm by hand: sorted 0.00575 * 3, 0.0203 * 2, 0.452 * 1
    assert res.p_holm.to_numpy() == pytest.approx([3 * hand[0], 2 * hand[1], hand[2]], rel=1e-10)
    ref = sp.posthoc_dunn(list(x.values()), p_adjust="holm")
    assert res.p_holm.to_numpy() == pytest.approx([ref.loc[1, 2], ref.loc[1, 3], ref.loc[2, 3]], rel=1e-10)


def friedman_runs(matrix, algorithms=("a", "b", "c")):
    """One case per row; each algorithm gets three runs whose median is the matrix entry."""
    frames = []
    for i, row in enumerate(matrix):
        vals = {alg: [v - 1.0, v, v + 5.0] for alg, v in zip(algorithms, row)}
        frames.append(make_runs(vals, case=f"c{i}", problem_id=f"p{i}"))
    return pd.concat(frames, ignore_index=True)


def test_friedman_and_nemenyi_across_cases():
    import scikit_posthocs as sp

    # scikit-posthocs' documented example for posthoc_nemenyi_friedman: rows are blocks (cases)
    x = np.array([[31, 27, 24], [31, 28, 31], [45, 29, 46], [21, 18, 48], [42, 36, 46], [32, 17, 40]], dtype=float)
    runs = friedman_runs(x)
    # a fourth algorithm missing from case c5 is left out, not a reason to drop the case
    runs = pd.concat([runs, make_runs({"d": [1.0]}, case="c0", problem_id="p0")], ignore_index=True)
    res = friedman_across_cases(runs, "best_f")
    assert res.skipped == "" and res.left_out == ["d"]
    assert res.medians.to_numpy() == pytest.approx(x)
    ref = stats.friedmanchisquare(*x.T)
    assert res.statistic == pytest.approx(ref.statistic, rel=1e-12)
    assert res.p == pytest.approx(ref.pvalue, rel=1e-12)
    # block ranks by hand: (3,2,1), (2.5,1,2.5), then (2,1,3) four times
    assert res.mean_ranks.to_numpy() == pytest.approx([13.5 / 6, 7 / 6, 15.5 / 6])
    nem = sp.posthoc_nemenyi_friedman(x)
    assert res.nemenyi.to_numpy() == pytest.approx(nem.to_numpy(), rel=1e-10)
    # Nemenyi by hand: q = |R_i - R_j| / sqrt(k(k+1)/(6n)), p from the studentized range of q*sqrt(2)
    q = abs(13.5 / 6 - 7 / 6) / np.sqrt(3 * 4 / 36)
    assert res.nemenyi.loc["a", "b"] == pytest.approx(stats.studentized_range.sf(q * np.sqrt(2), 3, np.inf), rel=1e-8)
    # critical difference: Demsar (2006) Table 5(a), q_0.05 = 2.343 for k = 3
    assert res.cd == pytest.approx(2.343 * np.sqrt(3 * 4 / 36), abs=1e-3)


def test_critical_difference_against_demsar_table():
    # Demsar (2006) Table 5(a): two-tailed Nemenyi q_0.05 for k = 2..6 and q_0.10 for k = 3
    for k, q in ((2, 1.960), (3, 2.343), (4, 2.569), (5, 2.728), (6, 2.850)):
        assert compare.critical_difference(k, 1) == pytest.approx(q * np.sqrt(k * (k + 1) / 6), abs=2e-3)
    assert compare.critical_difference(3, 1, alpha=0.10) == pytest.approx(2.052 * np.sqrt(2), abs=2e-3)


def test_friedman_across_cases_is_skipped_with_a_reason():
    one_case = friedman_runs([[1.0, 2.0, 3.0]])
    res = friedman_across_cases(one_case, "best_f")
    assert res.skipped.startswith("needs at least 2 cases and 3 algorithms") and "have 1 case(s)" in res.skipped
    two_algs = friedman_runs([[1.0, 2.0], [2.0, 1.0]], algorithms=("a", "b"))
    assert "have 2 case(s) and 2 such algorithm(s)" in friedman_across_cases(two_algs, "best_f").skipped
    text = report(one_case, fmt="md")
    assert "## Across cases" in text and "Friedman test across cases skipped: needs at least 2 cases" in text
    with pytest.raises(ConfigError, match="no critical-difference diagram: Friedman test skipped"):
        compare.cd_diagram(res, "never.png")


def test_a12_known_values():
    a12 = compare.vargha_delaney_a12
    assert a12([1, 2, 3], [4, 5, 6]) == 1.0
    assert a12([4, 5, 6], [1, 2, 3]) == 0.0
    assert a12([1, 2, 3], [1, 2, 3]) == 0.5
    # ties count half: pairs (1,2) (1,3) (2,3) lower, (2,2) tied -> 3.5 / 4
    assert a12([1, 2], [2, 3]) == 0.875
    assert a12([2, 2], [2, 2]) == 0.5
    assert np.isnan(a12([], [1.0]))
    # against brute force and scipy's U on samples with ties
    rng = np.random.default_rng(7)
    x, y = rng.integers(0, 6, 13).astype(float), rng.integers(0, 6, 9).astype(float)
    brute = ((x[:, None] < y[None, :]).sum() + 0.5 * (x[:, None] == y[None, :]).sum()) / (x.size * y.size)
    assert a12(x, y) == pytest.approx(brute, abs=1e-12)
    assert a12(x, y) == pytest.approx(stats.mannwhitneyu(y, x).statistic / (x.size * y.size), abs=1e-12)
    mag = compare.effect_magnitude
    assert [mag(v) for v in (0.5, 0.559, 0.56, 0.44, 0.64, 0.36, 0.71, 0.29, 1.0, np.nan)] == [
        "negligible", "negligible", "small", "small", "medium", "medium", "large", "large", "large", ""]
    assert compare.A12_THRESHOLDS == (("small", 0.06), ("medium", 0.14), ("large", 0.21))


def test_bootstrap_intervals_are_seeded_and_contain_the_estimate():
    rng = np.random.default_rng(3)
    a, b = rng.normal(0.0, 1.0, 15), rng.normal(0.7, 1.0, 12)
    ci = compare.a12_ci(a, b)
    assert_same_bits(ci, compare.a12_ci(a, b), because="same seed")  # same default seed, same interval
    assert ci != compare.a12_ci(a, b, seed=compare.BOOTSTRAP_SEED + 1)
    est = compare.vargha_delaney_a12(a, b)
    assert ci[0] <= est <= ci[1] and 0.0 <= ci[0] < ci[1] <= 1.0
    # the wrapper is scipy's percentile bootstrap with a fresh generator seeded with the seed
    ref = stats.bootstrap((a, b), lambda x, y: compare.vargha_delaney_a12(x, y), n_resamples=2000,
                          method="percentile", vectorized=False, paired=False,
                          random_state=np.random.default_rng(compare.BOOTSTRAP_SEED))
    assert ci == pytest.approx((ref.confidence_interval.low, ref.confidence_interval.high), abs=1e-12)
    lo, hi = compare.median_ci(a)
    assert lo <= np.median(a) <= hi
    assert_same_bits((lo, hi), compare.median_ci(a), because="same seed")
    assert compare.a12_ci([1, 2, 3], [4, 5, 6]) == (1.0, 1.0)  # exact: every resample separates them
    assert np.isnan(compare.median_ci([1.0])).all() and np.isnan(compare.a12_ci([1.0], [2.0, 3.0])).all()
    s = summary_table(make_runs({"cs": a}), "best_f").iloc[0]
    assert_same_bits((s.median_ci_low, s.median_ci_high), (lo, hi), because="same seed")


def test_significant_but_negligible_difference_is_not_a_win():
    base = np.arange(1000, dtype=float)
    # a shift of 50 in 1000: A12 ~ 0.549 (negligible) yet p ~ 1e-4 with 1000 runs each
    runs = make_runs({"a": base, "b": base + 50})
    pair = pairwise_tests(runs, "best_f").iloc[0]
    assert pair.p_dunn_holm < 0.05 and pair.significant
    assert pair.a12 == pytest.approx(0.5 + 0.05 - 0.05**2 / 2, abs=1e-3) and pair.effect == "negligible"
    assert pair.better == "a" and pair.win == ""
    assert find_winners(pairwise_tests(runs, "best_f")) == {"min": None}
    # a shift of 100: A12 ~ 0.595, small, and significant: a wins
    runs = make_runs({"a": base, "b": base + 100})
    pair = pairwise_tests(runs, "best_f").iloc[0]
    assert pair.effect == "small" and pair.win == "a"
    assert find_winners(pairwise_tests(runs, "best_f")) == {"min": "a"}
    # three runs each, fully separated: a large effect, and Dunn's normal approximation gives p = 0.0495,
    # but the exact rank-sum test cannot go below p = 0.1 with 3 + 3 runs: not significant, no win
    small = pairwise_tests(make_runs({"a": [1.0, 2.0, 3.0], "b": [4.0, 5.0, 6.0]}), "best_f").iloc[0]
    assert small.effect == "large" and small.p_dunn_holm == pytest.approx(0.0495, abs=1e-4)
    assert small.p_holm == pytest.approx(0.1) and small.win == ""


def test_failed_runs_are_excluded_and_counted():
    runs = make_runs({"cs": [1.0, 2.0, 3.0, 1e10, 0.5], "pso": [4.0, 5.0, 6.0, 7.0, 8.0],
                      "ga": [1e10, 1e10, 1e10]}).assign(status="feasible")
    cs = runs.algorithm == "cs"
    runs.loc[cs & (runs.run == 3), "status"] = "failed"
    runs.loc[cs & (runs.run == 4), ["status", "feasible"]] = ["infeasible", False]
    runs.loc[runs.algorithm == "ga", ["status", "feasible"]] = ["failed", False]
    runs.loc[(runs.algorithm == "pso") & (runs.run == 4), ["status", "best_f"]] = [None, 1e10]  # old row: sentinel
    assert compare.failed_runs(runs).sum() == 5 and compare.successful_runs(runs).sum() == 7
    s = summary_table(runs, "best_f").set_index("algorithm")
    assert s.loc["cs", ["n", "runs", "failed", "infeasible"]].tolist() == [3, 5, 1, 1]
    assert s.loc["cs", "success_rate"] == pytest.approx(3 / 5)
    assert s.loc["cs", "mean"] == pytest.approx(2.0) and s.loc["cs", "median"] == 2.0
    assert s.loc["cs", "sd"] == pytest.approx(1.0) and s.loc["cs", "worst"] == 3.0
    assert s.loc["pso", ["n", "failed"]].tolist() == [4, 1] and s.loc["pso", "mean"] == pytest.approx(5.5)
    assert s.loc["ga", ["n", "failed", "success_rate"]].tolist() == [0, 3, 0.0] and np.isnan(s.loc["ga", "mean"])
    pairs = pairwise_tests(runs, "best_f").set_index(["algorithm_a", "algorithm_b"])
    assert pairs.loc[("cs", "pso"), ["n_a", "n_b"]].tolist() == [3, 4]
    assert pairs.loc[("cs", "pso"), "p"] == pytest.approx(stats.mannwhitneyu([1, 2, 3], [4, 5, 6, 7]).pvalue)
    assert np.isnan(pairs.loc[("cs", "ga"), "p_dunn"]) and pairs.loc[("cs", "ga"), "win"] == ""
    kw = kruskal_test(runs, "best_f")
    assert kw.n.tolist() == [3, 4, 0] and kw.df.iloc[0] == 1
    text = report(runs, fmt="md")
    assert "Kruskal-Wallis test over 7 successful runs of 2 algorithms (6 failed or infeasible runs left out)" in text
    assert "1e+10" not in text.split("### Case min: pairwise")[0]  # no sentinel in the summary
    assert "Left out (no successful run in some case): ga." in text


def test_cli_writes_the_cd_diagram(two_dirs, tmp_path, capsys):
    png = tmp_path / "figs" / "cd.png"
    assert run([*two_dirs, "--cd-diagram", str(png)]) == 0
    out = capsys.readouterr().out
    assert f"Critical-difference diagram written to {png}." in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 1000
    assert not list(png.parent.glob(".*"))  # written atomically
    one = write(tmp_path, "one", friedman_runs([[1.0, 2.0, 3.0]]))
    other = tmp_path / "other.png"
    assert run([str(one), "--cd-diagram", str(other)]) == 0
    assert f"No critical-difference diagram written to {other}." in capsys.readouterr().out
    assert not other.exists()


def test_a_case_where_every_algorithm_failed_leaves_the_friedman_blocks_not_the_algorithms():
    x = np.array([[31, 27, 24], [31, 28, 31], [45, 29, 46]], dtype=float)
    runs = friedman_runs(x)
    dead = friedman_runs([[1.0, 2.0, 3.0]]).assign(case="dead", problem_id="pdead", status="failed",
                                                  feasible=False, best_f=1e10)
    res = friedman_across_cases(pd.concat([runs, dead], ignore_index=True), "best_f")
    ref = friedman_across_cases(runs, "best_f")
    assert res.skipped == "" and res.cases_left_out == ["dead"] and res.left_out == []
    # the failed case's blocks are dropped: the test then runs on the same table
    assert_same_bits([res.statistic, res.p], [ref.statistic, ref.p], because="same code")
    text = report(pd.concat([runs, dead], ignore_index=True), fmt="md")
    assert "Cases left out (no algorithm has a successful run): dead." in text


# ------------------------------------------------------------------------------------------------ --by controller

def _structure_folder(tmp_path, name, controller, values, *, objective="iae", case="min", experiment=None):
    """A results folder of one structure under cs, with the meta.json config a comparison reads."""
    import json

    df = make_runs({"cs": values}, experiment=experiment or name, case=case, problem_id=f"{controller}-{case}")
    df["controller"] = controller
    d = write(tmp_path, name, df)
    config = {"name": name, "plant": {"model": "qtp", "cases": [case.split("-")[0]]},
              "controller": {"type": controller}, "scenario": {"horizon": 350.0, "limits": "physical"},
              "problem": {"objective": objective, "bounds": {"Kp1": [0, 1]}}, "optimisers": [{"name": "cs"}]}
    (d / "meta.json").write_text(json.dumps({"config": config}))
    return d


def test_by_controller_compares_structures_with_the_same_statistics(tmp_path, capsys):
    rng = np.random.default_rng(5)
    a = _structure_folder(tmp_path, "pid_run", "pid", rng.normal(1.0, 0.05, 12))
    b = _structure_folder(tmp_path, "fopid_run", "fopid", rng.normal(2.0, 0.05, 12))
    c = _structure_folder(tmp_path, "folqi_run", "folqi", rng.normal(2.0, 0.05, 12))
    with pytest.raises(ConfigError, match="problem_id differs"):
        load_runs([a, b, c])  # by algorithm: cs on three problems
    runs = load_runs([a, b, c], by="controller")
    assert sorted(pd.unique(runs["algorithm"])) == ["folqi", "fopid", "pid"]
    assert set(runs["optimiser"]) == {"cs"} and set(runs["case"]) == {"min"}
    assert run([str(a), str(b), str(c), "--by", "controller"]) == 0
    out = capsys.readouterr().out
    assert "between controller structures" in out and "tuned by cs" in out
    assert "| pid | fopid |" in out.replace("*", "")  # the pairwise row of two structures
    assert "Kruskal-Wallis test over 36 successful runs of 3 algorithms" in out


def test_by_controller_takes_a_type_list_case_and_refuses_other_problems(tmp_path, capsys):
    one = _structure_folder(tmp_path, "types", "pid", [1.0, 1.1, 1.2], case="min-pid", experiment="types")
    df = pd.read_parquet(one / "runs.parquet")
    other = df.assign(case="min-fopid", controller="fopid", problem_id="fopid-min", best_f=df["best_f"] + 1)
    pd.concat([df, other]).to_parquet(one / "runs.parquet", index=False)
    runs = load_runs([one], by="controller")
    assert set(runs["case"]) == {"min"} and set(runs["algorithm"]) == {"pid", "fopid"}
    bad = _structure_folder(tmp_path, "effort", "folqi", [3.0, 3.1], objective="effort")
    assert run([str(one), str(bad), "--by", "controller"]) == 2
    err = capsys.readouterr().err
    assert "pose different problems, not only other controllers: they differ in problem.objective" in err
    assert run([str(one), "--by", "plant"]) == 2
    assert "--by: unknown axis 'plant'; allowed: algorithm, controller" in capsys.readouterr().err


def test_by_controller_relabels_histories_and_the_report_compares_structures(tmp_path):
    """A type-list folder's histories follow its runs (plant case, structure), and the report
    takes --by controller as compare does."""
    from heurtune.analysis.report import build_report
    from heurtune.analysis.report import run as report_run
    from heurtune.analysis.runs import load_histories

    one = _structure_folder(tmp_path, "types", "pid", [1.0, 1.1, 1.2], case="min-pid", experiment="types")
    df = pd.read_parquet(one / "runs.parquet")
    other = df.assign(case="min-fopid", controller="fopid", problem_id="fopid-min", best_f=df["best_f"] + 1)
    pd.concat([df, other]).to_parquet(one / "runs.parquet", index=False)
    hist = pd.DataFrame(dict(experiment="types", case=["min-pid", "min-fopid"], algorithm="cs", run=0, epoch=0,
                             n_evals=10, best_f=[1.0, 2.0], best_violation=0.0))
    hist.to_parquet(one / "history.parquet", index=False)
    runs = load_runs([one], by="controller")
    h = load_histories([one], runs)
    assert sorted(zip(h["case"], h["algorithm"])) == [("min", "fopid"), ("min", "pid")]
    page = build_report([one], tmp_path / "rep", responses=False, by="controller").read_text()
    assert "between controller structures" in page
    assert report_run([str(one), "--out", str(tmp_path / "rep2"), "--by", "plant"]) == 2


def test_the_report_labels_best_f_with_the_objective_and_its_unit(tmp_path, monkeypatch):
    """The report's box plot (and convergence) axes say what best_f is, from the problem
    rebuilt from meta.json: "IAE (cm s)", not "best_f" (issue 53)."""
    from heurtune.analysis import figures
    from heurtune.analysis.report import build_report

    seen = []
    original = figures.boxplot_figure

    def spy(*args, **kwargs):
        seen.append(kwargs.get("ylabel"))
        return original(*args, **kwargs)

    monkeypatch.setattr(figures, "boxplot_figure", spy)
    import json

    one = _structure_folder(tmp_path, "pid_run", "pid", [1.0, 1.1, 1.2])
    meta = json.loads((one / "meta.json").read_text())
    (one / "meta.json").write_text(json.dumps({"experiment": "pid_run", **meta}))
    build_report([one], tmp_path / "rep", responses=False)
    assert seen == ["IAE (cm s)"]
