"""The transcribed thesis tables and the writer that sets heurtune's numbers beside them."""

from __future__ import annotations

import io
import math
from importlib import resources

import numpy as np
import pandas as pd
import pytest

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.thesis import tables as T
from heurtune.objectives.qtp.thesis.printed import TABLES, available_tables, printed_row, printed_table

GAINS = ["Q11", "Q22", "Q33", "Q44", "R11", "R22", "Ki1", "Ki2", "alpha1", "alpha2"]


# ----------------------------------------------------------------------------------------------
# The data files
# ----------------------------------------------------------------------------------------------

def test_every_table_loads_with_unique_row_keys():
    folder = resources.files("heurtune.experiments") / "printed" / "thesis"
    files = sorted(p.name for p in folder.iterdir() if p.name.endswith(".csv"))
    assert files == sorted(f"table_{t.replace('.', '_')}.csv" for t in available_tables())
    assert (folder / "README.md").is_file()
    for table in available_tables():
        df = printed_table(table)
        assert df.columns[0] == "row", table
        assert len(df) > 0 and df["row"].is_unique, table
        assert not df["row"].isna().any(), table
        # Every value column is numeric (a stray character would make it object).
        keys = {"row", "case", "algorithm", "scenario"}
        for col in df.columns:
            if col not in keys:
                assert pd.api.types.is_numeric_dtype(df[col]), (table, col)


@pytest.mark.parametrize("table, row, column, value", [
    ("4.2", "min/5", "Ki1", 9.6015),
    ("4.3", "min/2", "J", 3302.5),
    ("4.3", "min/1", "alpha2", 0.8348),
    ("4.4", "nmp/2", "R22", 0.1000),
    ("4.5", "nmp/5", "J", 3932.1),
    ("4.6", "nmp-iolqi", "Ki2", 0.1952),
    ("4.6", "min-iolqi", "J", 3795.0),
    ("4.7", "nmp-ladr", "beta11", 91.7276),
    ("4.7", "min-ladr", "beta42", 100.8996),
    ("4.7", "min-ladr", "r2", 0.0454),
    ("4.8", "min-iolqi", "ts1", 32.5670),
    ("4.8", "nmp-ladr", "Mp2", 7.5023),
    ("4.8", "nmp-folqi", "J2", 2001.0),
    ("4.9", "min-folqi/+5%", "ts2", 11.7360),
    ("4.10", "nmp-iolqi/+5%", "Mp2", 11.5327),
    ("4.10", "nmp-ladr/+5%", "J", 5280.0),
    ("4.11", "min-folqi/21", "gain_crossover_rad_s", 0.459),
    ("4.11", "min-folqi/21", "phase_margin_deg", 25.6),
    ("4.11", "nmp-folqi/22", "phase_margin_deg", 27.3),
    ("4.12", "min-ladr/22", "gain_crossover_rad_s", 8.0),
    ("5.2", "min-folqi/cs", "Ki2", 7.1716),
    ("5.2", "nmp-folqi/firefly", "alpha1", 0.9994),
    ("5.3", "min-iolqi/cs", "convergence_epoch", 74),
    ("5.3", "min-iolqi/cs", "J_mean", 1403.34),
    ("5.3", "min-iolqi/cs", "J_sd", 118.10),
    ("5.3", "nmp-iolqi/apso", "J_mean", 1490.91),
    ("5.3", "min-folqi/firefly", "J_sd", 30.62),
    ("5.3", "nmp-folqi/firefly", "convergence_epoch", 54),
    ("5.4", "nmp-iolqi/firefly", "ts2", 48.4790),
    ("5.4", "nmp-folqi/firefly", "Mp2", 4.64869),
    ("5.5", "min-iolqi/-30%", "J2", 909.2),
    ("5.5", "nmp-folqi/+30%", "Mp2", 7.4975),
    ("5.6", "min-folqi/-30%", "Mp1", 4.2845),
    ("5.6", "nmp-iolqi/-30%", "ts2", 47.4860),
    ("5.7", "nmp-folqi/nominal", "J", 3512.9),
    ("5.8", "nmp-folqi/21", "phase_margin_deg", 13.5),
    ("5.9", "min-folqi/22", "gain_crossover_rad_s", 0.160),
    ("5.10", "nmp-iolqi/12", "phase_margin_deg", 3.35),
    ("6.3", "nmp-iolqi/newton_raphson", "Ki2", 7.0607),
    ("6.3", "min-folqi/dfp", "alpha1", 0.3240),
    ("6.4", "min-folqi/steepest_descent", "alpha1", 0.8022),
    ("6.4", "nmp-iolqi/bfgs", "Ki1", 0.1140),
    ("6.5", "min-folqi/newton_raphson", "J@nominal", 3507.5),
    ("6.5", "nmp-iolqi/dfp", "J@+30%", 6569.1),
    ("6.5", "min-iolqi/bfgs", "J@-30%", 1733.8),
])
def test_sample_of_values_against_the_thesis_text(table, row, column, value):
    assert printed_row(table, row)[column] == pytest.approx(value, abs=1e-9)


def test_table_shapes_follow_the_thesis():
    shapes = {"4.2": 5, "4.3": 5, "4.4": 5, "4.5": 5, "4.6": 2, "4.7": 2, "4.8": 6, "4.9": 9, "4.10": 9,
              "4.11": 8, "4.12": 16, "5.2": 12, "5.3": 12, "5.4": 12, "5.5": 12, "5.6": 12, "5.7": 12,
              "5.8": 16, "5.9": 16, "5.10": 16, "6.3": 8, "6.4": 8, "6.5": 16}
    assert {t: len(printed_table(t)) for t in available_tables()} == shapes
    assert printed_table("4.7").shape[1] == 2 + 20
    # IOLQI rows have no alpha: empty cells, not zeros.
    assert math.isnan(printed_row("5.2", "min-iolqi/cs")["alpha1"])


def test_totals_equal_the_pump_efforts_except_the_documented_misprint():
    for table in ("4.8", "4.9", "4.10", "5.4", "5.5", "5.6", "5.7"):
        df = printed_table(table)
        off = df[(df["J"] - (df["J1"] + df["J2"])).abs() > 3.0]
        expected = ["nmp-ladr/+5%"] if table == "4.10" else []
        assert list(off["row"]) == expected, table


def test_raw_keeps_the_printed_digits_and_the_margin_oddity():
    raw = printed_table("4.8", raw=True).set_index("row")
    assert raw.loc["min-ladr", "ts1"] == "0.1180"
    assert raw.loc["min-iolqi", "J1"] == "2040"
    last = printed_row("4.12", "nmp-ladr/22")
    assert (last["input"], last["output"]) == (2, 1)  # printed twice as "2 1"


def test_unknown_table_or_row_is_a_config_error_naming_the_allowed():
    with pytest.raises(ConfigError, match="allowed: 4.2, 4.3"):
        printed_table("4.1")
    with pytest.raises(ConfigError, match="min/1, min/2"):
        printed_row("4.3", "min/9")
    assert printed_table("table_4_3").equals(printed_table("4.3"))
    assert set(TABLES) == set(available_tables())


# ----------------------------------------------------------------------------------------------
# The writer on hand-made inputs (no simulation)
# ----------------------------------------------------------------------------------------------

class FakeProblem:
    """Metrics are simple functions of the gains, so the expected cells can be computed here."""

    def __init__(self, case, names, scenarios):
        self.case = case
        self.names = tuple(names)
        self.scenarios = {s: None for s in scenarios}
        self.reported = []

    def metrics(self, x, scenario):
        x = np.asarray(x, dtype=float)
        factor = {"nominal": 1.0, "-30%": 0.7, "+30%": 1.3, "-5%": 0.95, "+5%": 1.05}[scenario]
        return dict(reason="", Mp1=5.0 + x[0], Mp2=6.0, ts1=10.0, ts2=20.0, ess1=0.1, ess2=0.2,
                    J1=1000.0 * factor, J2=2000.0 * factor + x[1], J=3000.0 * factor + x[1])

    def report(self, x, scenarios=None):
        self.reported.append(tuple(np.asarray(x, dtype=float)))
        rows = {s: self.metrics(x, s) for s in scenarios}
        return pd.DataFrame.from_dict(rows, orient="index").rename_axis("scenario")

    def margins(self, x):
        rows = [dict(input=i, output=j, gain_crossover_rad_s=1.0 + i / 10 + j / 100,
                     phase_margin_deg=10.0 * i + j) for i in (1, 2) for j in (1, 2)]
        return pd.DataFrame(rows)


class FakeExperiment:
    def __init__(self, cases, scenarios=("nominal", "-30%", "+30%")):
        self.name = "fake"
        self.cases = tuple(cases)
        self.scenarios = scenarios
        self.problems = {}

    def problem(self, case):
        if case not in self.cases:
            raise ConfigError(f"unknown case {case!r}")
        if case not in self.problems:
            kind = case.split("-")[1]
            names = GAINS if kind == "folqi" else GAINS[:8] if kind == "iolqi" else T.LADR
            self.problems[case] = FakeProblem(case, names, self.scenarios)
        return self.problems[case]


def _runs(cases, algorithms, n_runs=3):
    rows = []
    for case in cases:
        names = GAINS if case.endswith("folqi") else GAINS[:8]
        for alg in algorithms:
            for run in range(n_runs):
                row = dict(case=case, algorithm=alg, run=run, best_f=4000.0 + 10 * run, feasible=True,
                           violation=0.0, convergence_epoch=10 + run, status="feasible")
                row.update({n: 0.5 + 0.01 * k + run for k, n in enumerate(names)})
                for sc, fac in (("nominal", 1.0), ("-30%", 0.7), ("+30%", 1.3)):
                    row.update({f"Mp1@{sc}": 3.0, f"Mp2@{sc}": 4.0, f"ts1@{sc}": 5.0, f"ts2@{sc}": 6.0,
                                f"ess1@{sc}": 0.01, f"ess2@{sc}": 0.02, f"J1@{sc}": 1900.0 * fac,
                                f"J2@{sc}": 2100.0 * fac, f"J@{sc}": (4000.0 + 10 * run) * fac})
                rows.append(row)
    return pd.DataFrame(rows)


CH5_CASES = ("min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi")


def _by_name(tables):
    return {t.name: t for t in tables}


def _row(part, **keys):
    v = part.values
    sel = np.ones(len(v), dtype=bool)
    for k, val in keys.items():
        sel &= (v[k] == val).to_numpy()
    assert sel.sum() == 1, keys
    return v[sel].iloc[0], part.display[sel].iloc[0]


def test_chapter5_gain_table_printed_heurtune_difference():
    exp = FakeExperiment(CH5_CASES)
    runs = _runs(CH5_CASES, ["cs", "firefly"])  # no APSO runs
    tabs = _by_name(T.chapter_tables(5, exp, runs=runs))
    assert list(tabs) == ["5.2", "5.3", "5.4", "5.5", "5.6", "5.7", "5.8", "5.9", "5.10"]
    a, b = tabs["5.2"].parts
    vals, disp = _row(a, algorithm="CS", controller="FOLQI / Minimum")
    best = runs[(runs.case == "min-folqi") & (runs.algorithm == "cs")].sort_values("best_f").iloc[0]
    assert disp["Q11 printed"] == "0.4431"
    assert vals["Q11 heurtune"] == pytest.approx(best["Q11"])
    assert vals["Q11 diff"] == pytest.approx(best["Q11"] - 0.4431)
    assert vals["Q11 diff %"] == pytest.approx(100 * (best["Q11"] - 0.4431) / 0.4431)
    assert disp["Q11 heurtune"] == f"{best['Q11']:.4f}"  # the printed number of decimals
    # IOLQI has no alpha: all four cells empty.
    vals, disp = _row(a, algorithm="CS", controller="IOLQI / Minimum")
    assert (disp["alpha1 printed"], disp["alpha1 heurtune"], disp["alpha1 diff"]) == ("", "", "")
    # APSO was not run: empty heurtune cells, the printed ones kept, and a note.
    vals, disp = _row(a, algorithm="APSO", controller="FOLQI / Minimum")
    assert disp["Q11 printed"] == "0.4670" and disp["Q11 heurtune"] == "" and math.isnan(vals["Q11 diff"])
    assert any("apso" in n for n in tabs["5.2"].notes)
    # Part B: J of the printed gains (the fake's J = 3000 + x[1]) beside Table 5.4's 3.5371e3.
    vals, disp = _row(b, algorithm="CS", controller="FOLQI / Minimum")
    assert vals["J printed"] == pytest.approx(3537.1)
    assert vals["J heurtune"] == pytest.approx(3000.0 + 0.3027)
    assert vals["J diff"] == pytest.approx(3000.3027 - 3537.1)
    assert exp.problems["min-folqi"].reported  # the printed gains went through report()


def test_chapter5_metric_tables_have_two_heurtune_comparisons():
    exp = FakeExperiment(CH5_CASES)
    runs = _runs(CH5_CASES, ["cs", "apso", "firefly"])
    tabs = _by_name(T.chapter_tables(5, exp, runs=runs))
    a, b = tabs["5.5"].parts
    assert a.subtitle.startswith("A: printed gains") and b.subtitle.startswith("B: heurtune's best")
    # Layout: one row per level, the total J on the h1 row only.
    assert list(a.display.columns[:4]) == ["controller", "scenario", "level", "Mp printed"]
    assert len(a.display) == 24
    vals, disp = _row(a, controller="IOLQI / Minimum", scenario="-30%", level="h1")
    x = printed_row("5.2", "min-iolqi/cs")
    assert vals["Mp heurtune"] == pytest.approx(5.0 + x["Q11"])
    assert vals["J heurtune"] == pytest.approx(3000 * 0.7 + x["Q22"])
    assert vals["J printed"] == pytest.approx(1812.2)
    h2 = a.values.iloc[list(a.values.index).index(vals.name) + 1]
    assert h2["level"] == "h2" and h2["effort printed"] == pytest.approx(909.2)
    assert a.display.loc[vals.name + 1, "J printed"] == ""
    # Part B takes the best run's <metric>@<scenario>.
    vals, _ = _row(b, controller="FOLQI / Non-minimum", scenario="+30%", level="h1")
    assert vals["J heurtune"] == pytest.approx(4000.0 * 1.3)
    assert vals["ts heurtune"] == pytest.approx(5.0) and vals["ts diff"] == pytest.approx(5.0 - 2.4790)
    assert "ts diff %" not in a.values.columns and "J diff %" in a.values.columns


def test_chapter5_convergence_and_margins():
    exp = FakeExperiment(CH5_CASES)
    runs = _runs(CH5_CASES, ["cs", "apso", "firefly"])
    margins = pd.DataFrame([dict(case="min-folqi", algorithm="cs", run=0, input=i, output=j,
                                 gain_crossover_rad_s=0.5 * i + j, phase_margin_deg=7.0 * i - j)
                            for i in (1, 2) for j in (1, 2)])
    tabs = _by_name(T.chapter_tables(5, exp, runs=runs, margins=margins))
    (part,) = tabs["5.3"].parts
    vals, disp = _row(part, algorithm="CS", controller="IOLQI / Minimum")
    assert disp["epoch printed"] == "74" and vals["epoch heurtune"] == pytest.approx(11.0)
    assert vals["mean J heurtune"] == pytest.approx(4010.0)
    assert vals["SD J heurtune"] == pytest.approx(10.0)
    assert vals["SD J diff"] == pytest.approx(10.0 - 118.10)
    a, b = tabs["5.8"].parts
    vals, _ = _row(b, controller="FOLQI / Minimum", input="2", output="1")
    assert vals["crossover rad/s heurtune"] == pytest.approx(2.0)  # from margins.parquet
    assert vals["PM deg printed"] == pytest.approx(15.3)
    vals, _ = _row(b, controller="IOLQI / Minimum", input="1", output="2")
    assert vals["PM deg heurtune"] == pytest.approx(12.0)  # not in margins: computed (fake margins())
    vals, _ = _row(a, controller="FOLQI / Minimum", input="2", output="2")
    assert vals["crossover rad/s heurtune"] == pytest.approx(1.22)


def test_chapter4_starts_are_matched_by_rank_and_missing_starts_leave_cells_empty():
    cases = ("min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi", "min-ladr", "nmp-ladr")
    exp = FakeExperiment(cases, scenarios=("nominal", "-5%", "+5%"))
    runs = _runs(cases[:4], ["sqp_multistart"], n_runs=1)
    starts = []
    for s, f in enumerate([5000.0, 4100.0, 4500.0, 6000.0, 4300.0, 4200.0]):
        row = dict(case="min-folqi", algorithm="sqp_multistart", run=0, start=s, f=f, feasible=s != 3)
        row.update({n: 0.1 * s for n in GAINS})
        row.update({f"x0_{n}": 1.0 + s for n in GAINS})
        starts.append(row)
    starts = pd.DataFrame(starts)
    tabs = _by_name(T.chapter_tables(4, exp, runs=runs, starts=starts))
    (part,) = tabs["4.3"].parts
    # The printed minimal-effort row (min/2, J = 3302.5) meets heurtune's best start (start 1).
    vals, disp = _row(part, row="min/2")
    assert vals["heurtune start"] == 1 and vals["J heurtune"] == pytest.approx(4100.0)
    assert vals["J diff"] == pytest.approx(4100.0 - 3302.5)
    vals, _ = _row(part, row="min/5")  # printed J ranks last of five -> heurtune's 5th best: start 0
    assert vals["heurtune start"] == 0
    (part,) = tabs["4.2"].parts
    vals, disp = _row(part, row="min/2")
    assert vals["Q11 heurtune"] == pytest.approx(2.0) and "Q11 diff" not in part.values.columns
    (part,) = tabs["starts"].parts
    vals, _ = _row(part, case="min-folqi", variable="Q11")
    assert vals["min"] == pytest.approx(0.0) and vals["max"] == pytest.approx(0.5)
    assert vals["printed min"] == pytest.approx(0.1042) and vals["feasible starts"] == 5
    # The nmp FOLQI starts are missing: empty cells and a note; no starts at all: every cell empty.
    (part,) = tabs["4.5"].parts
    assert (part.display["J heurtune"] == "").all()
    tabs = _by_name(T.chapter_tables(4, exp, runs=runs))
    assert (tabs["4.3"].parts[0].display["J heurtune"] == "").all()
    assert any("starts.parquet" in n for n in tabs["4.3"].notes)
    # LADR: no runs, yet the printed parameters are simulated (part B) beside Table 4.8's J.
    a, b = tabs["4.7"].parts
    vals, disp = _row(b, controller="LADR / Non-minimum")
    assert vals["J printed"] == pytest.approx(4082.0)
    assert vals["J heurtune"] == pytest.approx(3000.0 + 28.6553)
    assert _row(a, controller="LADR / Non-minimum")[1]["beta11 heurtune"] == ""
    # 4.9 under -5 %: the printed FOLQI gains are Table 4.3's minimal-effort row.
    a, _ = tabs["4.9"].parts
    vals, _ = _row(a, controller="FOLQI / Minimum", scenario="-5%", level="h1")
    assert vals["Mp heurtune"] == pytest.approx(5.0 + 1.6121)


def test_chapter6_effort_table_and_unknown_scenarios():
    cases = CH5_CASES
    exp = FakeExperiment(cases, scenarios=("nominal",))  # the +-30 % scenarios are missing
    runs = _runs(cases, ["newton_raphson", "bfgs"])
    tabs = _by_name(T.chapter_tables(6, exp, runs=runs))
    assert list(tabs) == ["6.3", "6.4", "6.5"]
    a, b = tabs["6.5"].parts
    vals, disp = _row(a, algorithm="NR", controller="FOLQI / Minimum")
    x = printed_row("6.3", "min-folqi/newton_raphson")
    assert vals["J@nominal printed"] == pytest.approx(3507.5)
    assert vals["J@nominal heurtune"] == pytest.approx(3000 + x["Q22"])
    assert disp["J@-30% heurtune"] == ""  # no such scenario in the experiment
    vals, _ = _row(b, algorithm="NR", controller="FOLQI / Minimum")
    assert vals["J@+30% heurtune"] == pytest.approx(4000 * 1.3)  # runs hold it
    vals, disp = _row(b, algorithm="DFP", controller="FOLQI / Minimum")
    assert disp["J@nominal heurtune"] == ""


def test_rendering_markdown_and_latex(tmp_path):
    exp = FakeExperiment(CH5_CASES)
    runs = _runs(CH5_CASES, ["cs"])
    paths = T.write_chapter(6, exp, tmp_path, runs=_runs(CH5_CASES, ["dfp"]), figures=False)
    names = sorted(p.name for p in paths)
    assert names == sorted(["table_6_3.md", "table_6_3.tex", "table_6_4.md", "table_6_4.tex", "table_6_5.md",
                            "table_6_5.tex", "README.md"])
    md = (tmp_path / "tables" / "table_6_3.md").read_text()
    assert md.splitlines()[0].startswith("# Table 6.3:")
    assert md.splitlines()[2].startswith("heurtune: part A")
    assert "| DFP | FOLQI / Minimum | 0.0074 |" in md
    tex = (tmp_path / "tables" / "table_6_5.tex").read_text()
    assert r"\begin{tabular}{ll" in tex and r"\bottomrule" in tex
    # a quantity's name once over its printed, heurtune, diff and diff % columns
    assert r"\multicolumn{4}{c}{J@-30\%}" in tex and "& printed & heurtune & diff & diff \\% \\\\" in tex
    assert "NR & IOLQI / Minimum & 1812.0 &" in tex
    # two parts, each split so that it fits the page (its keys repeated)
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") > 2
    readme = (tmp_path / "tables" / "README.md").read_text()
    assert "[table_6_5.md](table_6_5.md)" in readme
    # Reading from out_dir: no parquet files at all still writes every table, with empty cells.
    empty = tmp_path / "empty"
    empty.mkdir()
    T.write_chapter(5, exp, empty, figures=False)
    md = (empty / "tables" / "table_5_2.md").read_text()
    assert "| CS | IOLQI / Minimum | 2.4409 |  |  |  |" in md
    with pytest.raises(ConfigError, match="allowed: 4, 5, 6"):
        T.write_chapter(7, exp, tmp_path, runs=runs)


# ----------------------------------------------------------------------------------------------
# End to end on a real smoke run
# ----------------------------------------------------------------------------------------------

@pytest.mark.long  # 18 s on the EPYC: `make test` writes the tables from printed rows
def test_write_chapter5_on_a_real_smoke_run(tmp_path):
    import heurtune
    from heurtune.runner.experiment import run_experiment

    cfg = tmp_path / "tiny.toml"
    cfg.write_text('extends = "thesis_heuristics"\nruns = 1\n[plant]\ncases = ["min"]\n')
    out = run_experiment(str(cfg), runs=1, smoke=True, out=tmp_path / "res", figures=False,
                         progress_stream=io.StringIO())
    exp = heurtune.load_experiment(str(cfg))
    paths = T.write_chapter(5, exp, out)
    names = {p.name for p in paths}
    assert {"table_5_2.md", "table_5_4.tex", "table_5_10.md", "README.md"} <= names
    assert {"figure_5_responses_min-folqi.png", "figure_5_convergence.png"} <= names
    md = (out / "tables" / "table_5_4.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| FOLQI / Minimum | CS | h1 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[3] == "4.3728" and cells[4] != ""  # printed and heurtune (printed gains simulated)
    assert "IOLQI / Non-minimum" in md  # the case not run: printed cells kept


def test_a_case_whose_runs_all_failed_has_empty_heurtune_cells_and_says_why():
    from heurtune.objectives.qtp.thesis.tables import _Inputs

    runs = pd.DataFrame([dict(case="nmp-iolqi", algorithm="sqp_multistart", run=0, best_f=1e10, feasible=False,
                              violation=2e6, status="failed", failure="unstable", Q11=2.5)])
    inp = _Inputs(None, runs, None, None, None)
    assert inp.best("nmp-iolqi") is None
    assert inp.notes == ["case nmp-iolqi: every run failed (unstable); heurtune cells empty"]
