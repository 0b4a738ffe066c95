"""The papers' commands (``python -m heurtune.experiment paper_000`` and its siblings): each smoke
run writes every table of its paper beside the printed values, and the numbers in heurtune's
cells are what heurtune computes for the printed controllers.

The heurtune cells are checked against an independent path: the printed controller simulated by
``TITOProblem.simulate`` and integrated here by the trapezoid rule (the metric definitions of
docs/tito.md), to 1e-9 relative (the same samples, summed in another order)."""

import numpy as np
import pandas as pd
import pytest

from heurtune import load_experiment
from heurtune.core.errors import ConfigError
from heurtune.objectives.tito.papers import simulated
from heurtune.objectives.tito.papers import tables as papers
from heurtune.objectives.tito.papers.printed import printed_table
from heurtune.runner.experiment import run_experiment


@pytest.fixture(scope="module")
def smoke_runs(tmp_path_factory):
    """The three papers' smoke runs, once for the module."""
    root = tmp_path_factory.mktemp("papers")
    return {paper: run_experiment(f"paper_{paper}", smoke=True, out=root / paper, progress_stream=None)
            for paper in papers.PAPER_TABLES}


@pytest.mark.long
@pytest.mark.parametrize("paper", sorted(papers.PAPER_TABLES))
def test_a_smoke_run_writes_every_table_beside_the_printed_values(smoke_runs, paper):
    tdir = smoke_runs[paper] / "tables"
    index = (tdir / "README.md").read_text()
    for table in papers.PAPER_TABLES[paper]:
        md = (tdir / f"table_{table}.md").read_text()
        tex = (tdir / f"table_{table}.tex").read_text()
        assert f"Table {table}" in index
        assert "printed" in md and "heurtune" in md
        assert tex.startswith("% needs \\usepackage{booktabs}") and "\\begin{tabular}" in tex
        # the notes a reader needs are in the PDF too, and a smoke run says it is one
        assert "Notes: (1) A --smoke run" in tex and "- note: A --smoke run" in md
    # every printed number of the performance tables is in the written table, digits as printed
    for table in papers.PAPER_TABLES[paper]:
        try:
            printed = printed_table(paper, f"table_{table}", raw=True)
        except ConfigError:
            continue
        md = (tdir / f"table_{table}.md").read_text()
        for col in printed.columns:
            if col in ("row", "line", "controller", "loop", "polynomial", "matrix", "i", "comment"):
                continue
            for text in printed[col]:
                if text:
                    assert f"| {text} |" in md, (table, col, text)


@pytest.mark.long
def test_the_tables_state_their_conditions(smoke_runs):
    md = (smoke_runs["000"] / "tables" / "table_1.md").read_text()
    assert ("conditions: set-point steps (loop 1: 1 at 0 s; loop 2: 1 at 0 s); input disturbance 0.1, 0.1 at 500 s; "
            "output disturbance 0.1, 0.1 at 800 s; horizon 1000 s, dt 0.02 s") in md
    assert "Tf = Td / N with N = 100" in md


def _trapezoid_iae(df, loop, t0, t1):
    sel = (df["t"] >= t0 - 1e-9) & (df["t"] <= t1 + 1e-9)
    t = df["t"][sel].to_numpy()
    e = np.abs((df[f"r{loop}"] - df[f"y{loop}"])[sel].to_numpy())
    return float(np.sum((e[1:] + e[:-1]) * np.diff(t)) / 2.0)


@pytest.mark.long
def test_the_printed_csts_pid_of_paper_000_is_simulated_as_printed(smoke_runs):
    exp = load_experiment("paper_000")
    prob = exp.problem("csts")
    gains = simulated.printed_controllers("000", "csts")["Proposed PID"]
    fopdt = printed_table("000", "controllers")
    row = fopdt[(fopdt["plant"] == "csts") & (fopdt["loop"] == 1)].iloc[0]
    assert gains[0] == (row["Kp"], row["Ki"], row["Kd"])
    df = prob.simulate(simulated.decision_vector(prob, gains))
    assert df.attrs["status"] == "ok"
    md = (smoke_runs["000"] / "tables" / "table_3.md").read_text()
    line = next(s for s in md.splitlines() if s.startswith("| Proposed PID | h1 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    # columns: controller, loop, then per quantity printed, heurtune, diff, diff %
    iae_servo = float(cells[3])
    assert iae_servo == pytest.approx(_trapezoid_iae(df, 1, 0.0, 500.0), rel=1e-3)  # shown to 4 digits


@pytest.mark.long
def test_controllers_that_diverge_get_no_numbers_and_a_note(smoke_runs):
    md = (smoke_runs["000"] / "tables" / "table_1.md").read_text()  # QTS: the printed PID diverges
    assert "Proposed PID: unstable on heurtune's QTS" in md
    line = next(s for s in md.splitlines() if s.startswith("| Proposed PID | h1 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[2] == "6.96" and cells[3] == ""
    assert "no parameters printed for" in md


@pytest.mark.long
def test_paper_002_table_I_recomputes_the_gpm_pi_at_the_printed_specification(smoke_runs):
    from heurtune.objectives.tito import model as tito

    # independently of the experiment: eq. 28's preset, its decoupled loop 1, its FOPDT fit, the GPM PI
    z11 = tito.inverted_decoupler(tito.preset("two_tank")).z11
    kc, ti = tito.gpm_pi(tito.fit_fopdt(z11), 3.0, 38.0)
    md = (smoke_runs["002"] / "tables" / "table_I.md").read_text()
    line = next(s for s in md.splitlines() if s.startswith("| u1-y1 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1] == "30.8" and float(cells[2]) == pytest.approx(kc, abs=0.05)
    assert float(cells[6]) == pytest.approx(ti, abs=0.05)
    assert "identified model (eq. 28)" in (smoke_runs["002"] / "tables" / "table_II.md").read_text()


@pytest.mark.long
def test_paper_figures_are_drawn(smoke_runs):
    names = {p.name for p in (smoke_runs["000"] / "tables").glob("*.png")}
    assert {"spectral_radius_csts.png", "noise_input_csts.png", "noise_output_csts.png", "variation_csts.png"} <= names
    assert (smoke_runs["001"] / "tables" / "responses_csts.png").exists()
    assert (smoke_runs["002"] / "tables" / "responses_rig.png").exists()


def test_bad_paper_key_is_a_one_line_error(tmp_path):
    cfg = tmp_path / "bad.toml"
    src = (papers.Path(__file__).resolve().parents[3] / "experiments" / "paper_001.toml").read_text()
    cfg.write_text(src.replace('paper = "001"', 'paper = "003"'))
    with pytest.raises(ConfigError) as err:
        load_experiment(str(cfg))
    msg = str(err.value)
    assert "\n" not in msg and "report.paper" in msg and "000" in msg


def test_unknown_paper_in_the_library_is_a_one_line_error():
    with pytest.raises(ConfigError, match="allowed: 000, 001, 002"):
        papers.paper_tables("004", None)


@pytest.mark.long
def test_part_b_lists_heurtunes_designs(smoke_runs):
    runs = pd.read_parquet(smoke_runs["001"] / "runs.parquet")
    gpm_cases = set(runs.loc[runs["algorithm"] == "gpm", "case"])
    assert gpm_cases == {"ccts", "csts"}  # the QTS has no GPM design: no FOPDT fits its loop 1
    assert set(runs["case"]) == {"ccts", "csts", "qts"}  # the PSO runs on every plant
    md = (smoke_runs["001"] / "tables" / "table_1.md").read_text()
    assert "## B: heurtune's designs" in md and "| gpm | h1 |" in md
    perf = (smoke_runs["001"] / "performance.md").read_text()  # the CSTS GPM design fails its check
    assert "nan" not in perf and "An empty cell: that design has no simulated response" in perf
