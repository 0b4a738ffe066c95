"""python -m heurtune.evaluate: table, parquet, plot, and one-line errors with exit code 2."""

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from heurtune.runner.evaluate import run

X = ("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,Ki1=1.7411,Ki2=7.1716,"
     "alpha1=0.9814,alpha2=0.8437")


def test_table_parquet_and_plot(tmp_path, capsys):
    out, png = tmp_path / "traj.parquet", tmp_path / "resp.png"
    assert run(["cs_folqi_qtp", "--case", "min", "--x", X, "--out", str(out), "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    for token in ("nominal", "-30%", "+30%", "Mp1", "ts2", "ess1", "J1", "J"):
        assert token in text
    df = pd.read_parquet(out)
    assert list(df.columns) == ["scenario", "t", "h1", "h2", "h3", "h4", "y1", "y2", "u1", "u2"]
    assert df.scenario.unique().tolist() == ["nominal", "-30%", "+30%"]
    assert len(df) == 3 * 35001
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind


def test_one_scenario(capsys):
    assert run(["cs_folqi_qtp", "--case", "nmp", "--x", X, "--scenario", "+30%"]) == 0
    text = capsys.readouterr().out
    assert "+30%" in text and "nominal" not in text


@pytest.mark.parametrize(
    "args, message",
    [
        (["nope", "--case", "min", "--x", X], "unknown experiment 'nope'"),
        (["cs_folqi_qtp", "--case", "mid", "--x", X], "unknown case 'mid'"),
        (["cs_folqi_qtp", "--case", "min", "--x", X + ",Q55=1"], "unknown variable 'Q55'"),
        (["cs_folqi_qtp", "--case", "min", "--x", X.replace(",alpha2=0.8437", "")], "missing variable(s) alpha2"),
        (
            ["cs_folqi_qtp", "--case", "min", "--x", X.replace("Ki1=1.7411", "Ki1=12")],
            "Ki1=12 is outside its bounds [0.1, 10]",
        ),
        (["cs_folqi_qtp", "--case", "min", "--x", X.replace("Ki1=1.7411", "Ki1=abc")], "Ki1: 'abc' is not a number"),
        (["cs_folqi_qtp", "--case", "min", "--x", X, "--scenario", "worst"], "unknown scenario 'worst'"),
        (["cs_folqi_qtp", "--case", "min", "--x", X + ",Q11=1.0"], "Q11 is given twice (0.4431 and 1.0)"),
        (["cs_folqi_qtp", "--case", "min", "--x", X, "--plot", "p.xyz"], "--plot p.xyz: unknown extension '.xyz'"),
        (["cs_folqi_qtp", "--case", "min", "--x", X, "--out", "."], "--out . is a folder; give a file name"),
        (
            ["cs_folqi_qtp", "--case", "min", "--x", X, "--out", "pyproject.toml/x.parquet"],
            "pyproject.toml is a file, not a folder",
        ),
    ],
)
def test_errors_are_one_line_with_exit_code_2(args, message, capsys):
    assert run(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err


def test_module_entry_point(tmp_path):
    res = subprocess.run([sys.executable, "-m", "heurtune.evaluate", "cs_folqi_qtp", "--case", "min", "--x", "Q11=1"],
                         capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 2 and "missing variable(s)" in res.stderr


# Thesis Table 6.3, NR / FOLQI / minimum phase: six of the ten gains lie below this experiment's
# lower bounds (Q22, Q33 < 0.01; R11, R22 < 0.1; Ki1, Ki2 < 0.1).
NR_X = ("Q11=0.0185,Q22=0.0021,Q33=0.0081,Q44=0.0118,R11=0.0094,R22=0.0124,Ki1=0.0103,Ki2=0.0056,"
        "alpha1=0.4946,alpha2=0.5439")
NR_OUTSIDE = ["Q22", "Q33", "R11", "R22", "Ki1", "Ki2"]


def test_outside_bounds_is_refused_without_the_flag(capsys):
    assert run(["cs_folqi_qtp", "--case", "min", "--x", NR_X]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: Q22=0.0021 is outside its bounds [0.01, 2.5]")
    assert "(and 5 more)" in err and "--outside-bounds" in err


def test_outside_bounds_flag_evaluates_the_given_values(capsys):
    from heurtune import load_experiment

    assert run(["cs_folqi_qtp", "--case", "min", "--x", NR_X, "--scenario", "nominal", "--outside-bounds"]) == 0
    cap = capsys.readouterr()
    lines = cap.err.splitlines()
    assert [line.split()[1] for line in lines] == NR_OUTSIDE  # one warning per variable, in order
    assert lines[0] == ("warning: Q22 = 0.0021 lies outside its bounds [0.01, 2.5]; "
                        "evaluated anyway (--outside-bounds)")
    assert all(line.endswith("evaluated anyway (--outside-bounds)") for line in lines)
    # the printed effort is that of the values as given, not of the values clipped to the box
    prob = load_experiment("cs_folqi_qtp").problem("min")
    x = prob.parse(NR_X, check_bounds=False)
    assert x.tolist() == [float(item.split("=")[1]) for item in NR_X.split(",")]
    J_given = prob.report(x, ["nominal"]).loc["nominal", "J"]
    J_clipped = prob.report(np.clip(x, prob.lower, prob.upper), ["nominal"]).loc["nominal", "J"]
    assert abs(J_given - J_clipped) > 1.0  # the two really differ
    row = next(line for line in cap.out.splitlines() if line.startswith("nominal"))
    assert float(row.split()[9]) == pytest.approx(J_given, abs=1e-4)  # printed with 4 decimals


def test_outside_bounds_flag_is_harmless_inside_the_bounds(capsys):
    assert run(["cs_folqi_qtp", "--case", "min", "--x", X, "--scenario", "nominal", "--outside-bounds"]) == 0
    assert capsys.readouterr().err == ""


def test_a_figure_is_written_in_the_format_its_name_says(tmp_path, capsys):
    pdf = tmp_path / "resp.pdf"
    assert run(["cs_folqi_qtp", "--case", "min", "--x", X, "--scenario", "nominal", "--plot", str(pdf)]) == 0
    assert pdf.read_bytes()[:5] == b"%PDF-"


def test_export_and_compare_refuse_wrong_outputs_in_one_line(tmp_path, capsys):
    from heurtune.analysis import compare, export
    from heurtune.runner.experiment import run as run_experiment

    out = tmp_path / "cs"
    assert run_experiment(["cs_folqi_qtp", "--smoke", "--out", str(out), "--no-figures"]) == 0
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    capsys.readouterr()
    assert export.run([str(out), "--format", "mat", "--out", str(a_file)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "is a file; give a folder" in err
    assert compare.run([str(out), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "is a folder; give a file name" in err


def test_out_into_a_missing_folder_creates_it(tmp_path, capsys):
    out = tmp_path / "new" / "folder" / "traj.parquet"
    assert run(["cs_folqi_qtp", "--case", "min", "--x", X, "--scenario", "nominal", "--out", str(out)]) == 0
    assert len(pd.read_parquet(out)) == 35001


@pytest.mark.parametrize("args", [["heurtune.experiment", "--list"], ["heurtune.experiment", "--list-algorithms"],
                                  ["heurtune.compare", "--help"]])
def test_a_reader_that_stops_early_ends_the_command_quietly(args):
    """``--list | head``: the reader closes the pipe before the command has written (it is still
    importing), so every write fails; the command stops with exit code 0 and no traceback."""
    import subprocess

    proc = subprocess.Popen([sys.executable, "-m", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0 and err == ""


def test_a_broken_pipe_other_than_stdout_is_not_hidden(monkeypatch):
    from heurtune import _startup

    def run():
        raise BrokenPipeError("a worker's pipe")

    monkeypatch.setattr(_startup, "_stdout_closed", lambda: False)
    with pytest.raises(BrokenPipeError, match="a worker's pipe"):
        _startup.run_command(run)


@pytest.mark.parametrize("command, codes", [
    ("experiment", (0, 2, 130, 143)), ("evaluate", (0, 2)), ("check_plugin", (0, 1, 2)), ("compare", (0, 2)),
    ("report", (0, 2)), ("anytime", (0, 2)), ("export", (0, 2)),
])
def test_every_help_states_the_exit_codes(command, codes, capsys):
    import importlib

    module = {"experiment": "heurtune.runner.experiment", "evaluate": "heurtune.runner.evaluate",
              "check_plugin": "heurtune.runner.check_plugin"}.get(command, f"heurtune.analysis.{command}")
    with pytest.raises(SystemExit) as done:
        importlib.import_module(module).run(["--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "exit codes: " in text
    for code in codes:
        assert f" {code} " in text.split("exit codes:")[1] + " "
