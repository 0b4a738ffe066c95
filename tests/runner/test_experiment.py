"""The experiment runner end to end: files, columns, re-simulation, resume, determinism, errors."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.runner.experiment import run

RUN_COLUMNS = ["experiment", "case", "algorithm", "controller", "run", "seed", "best_f", "feasible", "n_evals",
               "n_epochs", "convergence_epoch", "wall_time_s", "stop_reason"]
GAINS = ["Q11", "Q22", "Q33", "Q44", "R11", "R22", "Ki1", "Ki2", "alpha1", "alpha2"]


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("smoke") / "cs"
    assert run(["cs_folqi_qtp", "--smoke", "--out", str(out)]) == 0
    return out


def test_smoke_run_writes_every_file(smoke):
    for name in ("runs.parquet", "history.parquet", "meta.json"):
        assert (smoke / name).is_file()
    runs = pd.read_parquet(smoke / "runs.parquet")
    for col in RUN_COLUMNS + GAINS:
        assert col in runs.columns
    for scenario in ("nominal", "-30%", "+30%"):
        for metric in ("Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2", "J1", "J2", "J"):
            assert f"{metric}@{scenario}" in runs.columns
    assert sorted(runs["case"].unique()) == ["min", "nmp"] and len(runs) == 4
    hist = pd.read_parquet(smoke / "history.parquet")
    for col in ("case", "algorithm", "run", "epoch", "n_evals", "best_f", "mean_f", "sd_f", "feasible_fraction"):
        assert col in hist.columns
    meta = json.loads((smoke / "meta.json").read_text())
    assert meta["config"]["name"] == "cs_folqi_qtp" and meta["versions"]["numpy"]
    assert {"seed", "spawn_key"} <= set(next(iter(meta["seeds"].values())))
    assert not list(smoke.glob("**/.*"))  # no temporary files left


def test_stored_gains_resimulate_to_the_stored_objective(smoke):
    runs = pd.read_parquet(smoke / "runs.parquet")
    exp = heurtune.load_experiment("cs_folqi_qtp")
    for _, row in runs.iterrows():
        prob = exp.problem(row["case"])
        ev = prob.evaluate(np.array([row[n] for n in prob.names]))
        # the run evaluated it in a population, here alone: one candidate at a time either way
        assert_same_bits(ev.f[0], row["best_f"], because="shared kernel")
        assert bool(ev.feasible[0]) == row["feasible"]
        assert ev.f[0] == pytest.approx(row["f@nominal"])


def test_same_results_with_one_and_two_workers(smoke, tmp_path):
    out = tmp_path / "two"
    assert run(["cs_folqi_qtp", "--smoke", "--jobs", "2", "--out", str(out), "--no-figures"]) == 0
    a = pd.read_parquet(smoke / "runs.parquet").sort_values(["case", "run"]).reset_index(drop=True)
    b = pd.read_parquet(out / "runs.parquet").sort_values(["case", "run"]).reset_index(drop=True)
    assert_same_bits(a[["case", "run", "best_f", "n_evals"] + GAINS], b[["case", "run", "best_f", "n_evals"] + GAINS],
                     because="workers")


def test_rerun_resumes_without_redoing(smoke, capsys):
    before = pd.read_parquet(smoke / "runs.parquet")
    assert run(["cs_folqi_qtp", "--smoke", "--out", str(smoke), "--no-figures"]) == 0
    assert "runs to do" not in capsys.readouterr().out  # nothing was redone
    after = pd.read_parquet(smoke / "runs.parquet")
    assert_same_bits(before, after, because="resume")  # wall times too: read back, not measured again


def test_interrupted_run_resumes_and_completes(tmp_path):
    cfg = tmp_path / "slowish.toml"
    cfg.write_text(
        'extends = "cs_folqi_qtp"\nruns = 4\n[[optimisers]]\nname = "cs"\nsettings = { n = 6 }\nmax_epochs = 4\n'
    )
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "heurtune.experiment", str(cfg), "--out", str(out), "--no-figures"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    parts = out / "parts"
    deadline = time.time() + 120
    while time.time() < deadline and len(list(parts.glob("*.run.parquet"))) < 2:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = {p.name: pd.read_parquet(p) for p in parts.glob("*.run.parquet")}
    assert 2 <= len(finished) < 8, "the kill should land mid-experiment"
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    runs = pd.read_parquet(out / "runs.parquet")
    assert len(runs) == 8 and not runs.duplicated(["case", "algorithm", "run"]).any()
    for name, row in finished.items():  # finished runs were kept, not redone
        assert_same_bits(row, pd.read_parquet(parts / name), because="resume")


def test_list_commands(capsys):
    assert run(["--list"]) == 0
    out = capsys.readouterr().out
    for name in ("cs_folqi_qtp", "apso_iolqi_qtp", "thesis_heuristics", "sqp_folqi_qtp"):
        assert name in out
    assert run(["--list-algorithms"]) == 0
    assert "sqp_multistart:" in capsys.readouterr().out


@pytest.mark.parametrize("args, message", [
    (["nope"], "unknown experiment 'nope'"),
    (["cs_folqi_qtp", "--runs", "0"], "--runs must be >= 1"),
    (["cs_folqi_qtp", "--backend", "mpi"], "unknown backend 'mpi'"),
    (["cs_folqi_qtp", "--backend", "dask"], "--backend dask needs --scheduler"),
    (["cs_folqi_qtp", "--plugin", "/no/such/file.py"], "does not exist"),
    ([], "name an experiment"),
])
def test_command_errors_are_one_line(args, message, capsys):
    assert run(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_plan_change_is_refused(smoke, capsys):
    assert run(["cs_folqi_qtp", "--out", str(smoke), "--max-epochs", "1"]) == 2
    err = capsys.readouterr().err
    assert "different config" in err and "budget.max_epochs" in err and err.count("\n") == 1


def test_all_shipped_experiments_plan(tmp_path):
    from heurtune.runner.config import list_experiments
    from heurtune.runner.experiment import plan

    for name in list_experiments():
        exp = heurtune.load_experiment(name)
        specs = plan(exp, smoke=True)
        assert specs and {s.case for s in specs} == set(exp.cases)
    matrix = heurtune.load_experiment("thesis_heuristics")
    assert set(matrix.cases) == {"min-folqi", "nmp-folqi", "min-iolqi", "nmp-iolqi"}
    assert [o["name"] for o in matrix.optimisers] == ["cs", "apso", "firefly"]


def test_compare_reads_two_smoke_experiments(smoke, tmp_path, capsys):
    from heurtune.analysis import compare

    other = tmp_path / "apso"
    assert run(["apso_folqi_qtp", "--smoke", "--out", str(other), "--no-figures"]) == 0
    capsys.readouterr()
    assert compare.run([str(smoke), str(other)]) == 0
    text = capsys.readouterr().out
    assert "## Case min" in text and "## Case nmp" in text
    assert "| cs |" in text and "| apso |" in text
    # an IOLQI experiment is a different problem for the same case names: refused
    iolqi = tmp_path / "iolqi"
    assert run(["cs_iolqi_qtp", "--smoke", "--out", str(iolqi), "--no-figures"]) == 0
    capsys.readouterr()
    assert compare.run([str(smoke), str(iolqi)]) == 2
    assert "problem_id" in capsys.readouterr().err


@pytest.mark.long  # 15 s on the EPYC: `make test` runs tasks on a local Dask cluster (test_parallel)
def test_dask_backend_runs_whole_runs(smoke, tmp_path, capfd):
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        assert run(["cs_folqi_qtp", "--smoke", "--out", str(out), "--no-figures", "--backend", "dask",
                    "--scheduler", cluster.scheduler_address]) == 0
        assert f"the Dask cluster at {cluster.scheduler_address} (2 workers)" in capfd.readouterr().out
    a = pd.read_parquet(smoke / "runs.parquet").sort_values(["case", "run"]).reset_index(drop=True)
    b = pd.read_parquet(out / "runs.parquet").sort_values(["case", "run"]).reset_index(drop=True)
    assert_same_bits(a[["case", "run", "best_f"] + GAINS], b[["case", "run", "best_f"] + GAINS], because="workers")


def test_summary_parquet_holds_the_printed_statistics_and_meta_says_where_it_ran(smoke):
    runs = pd.read_parquet(smoke / "runs.parquet")
    summary = pd.read_parquet(smoke / "summary.parquet")
    assert list(summary["case"]) == ["min", "nmp"] and (summary["runs"] == 2).all()
    for _, row in summary.iterrows():
        grp = runs[(runs["case"] == row["case"]) & (runs["optimiser_index"] == row["optimiser_index"])]
        ok = grp[(grp["status"] != "failed") & grp["feasible"]]["best_f"]
        assert row["failed"] == (grp["status"] == "failed").sum() and row["feasible_runs"] == grp["feasible"].sum()
        assert row["successes"] == len(ok)
        if len(ok):
            assert_exact(row["best"], ok.min())  # a copy of the smallest
            assert row["mean"] == pytest.approx(ok.mean())
            assert row["median"] == pytest.approx(ok.median())
        # a standard deviation needs two successes (compare leaves it blank too), not 0.0
        assert np.isnan(row["sd"]) if len(ok) < 2 else row["sd"] == pytest.approx(ok.std(ddof=1))
        # means of two integer counts: exact
        assert row["n_evals"] == grp["n_evals"].mean() and row["wall_s"] == pytest.approx(grp["wall_time_s"].sum())
        assert row["conv_evals"] == grp["convergence_evals"].mean()
        best = grp[grp["run"] == row["best_run"]].iloc[0]
        assert_exact(row[GAINS].to_numpy(dtype=float), best[GAINS].to_numpy(dtype=float))  # copied
    # the convergence point in evaluations is the history's count at the convergence epoch
    hist = pd.read_parquet(smoke / "history.parquet")
    for _, one in runs.iterrows():
        h = hist[(hist["case"] == one["case"]) & (hist["run"] == one["run"])
                 & (hist["optimiser_index"] == one["optimiser_index"])]
        assert one["convergence_evals"] == h.loc[h["epoch"] == one["convergence_epoch"], "n_evals"].iloc[0]
    meta = json.loads((smoke / "meta.json").read_text())
    assert meta["platform"]["cpu_count"] >= 1 and meta["platform"]["cpu"] and meta["platform"]["system"]
    assert isinstance(meta["platform"]["blas"], list)
    assert meta["git_dirty"] in (True, False, None)


def test_status_lists_result_folders_with_runs_done_and_planned(tmp_path, capsys):
    from heurtune.runner.experiment import status_table

    root = tmp_path / "results"
    assert run(["cs_folqi_qtp", "--smoke", "--out", str(root / "a"), "--no-figures"]) == 0
    assert run(["ga_pi_ccts", "--smoke", "--out", str(root / "b"), "--no-figures"]) == 0
    capsys.readouterr()
    table = status_table(root)
    assert list(table["experiment"]) == ["cs_folqi_qtp", "ga_pi_ccts"]
    assert list(table["done"]) == list(table["planned"]) and table["complete"].all()
    assert list(table["smoke"]) == [True, True]  # a smoke folder says so
    # a lost run and no gathered table: incomplete, and what is missing is counted
    next((root / "a" / "parts").glob("*.run.parquet")).unlink()
    (root / "a" / "runs.parquet").unlink()
    (root / "b" / "planned.json").unlink()  # a folder written before planned.json existed
    assert run(["--status", "--out", str(root)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "3/4 runs  incomplete: run the same command to resume  (--smoke: tiny budgets, a check)" in lines[0]
    assert "/? runs" in lines[1] and "--smoke" not in lines[1]  # not known without planned.json
    assert run(["--status", "--out", str(root / "a")]) == 0 and len(capsys.readouterr().out.splitlines()) == 1


def test_progress_shows_the_best_including_runs_kept_from_before_a_resume():
    import io

    from heurtune.runner.experiment import Progress

    stream = io.StringIO()
    kept = [pd.Series(dict(case="min", algorithm="cs", feasible=True, best_f=10.0, violation=0.0, n_evals=5))]
    bar = Progress(3, 1, stream, finished_rows=kept)
    bar.update(dict(case="min", algorithm="pso", feasible=True, best_f=12.0, violation=0.0, n_evals=5))
    bar.update(dict(case="nmp", algorithm="pso", feasible=False, best_f=1e10, violation=3.0, n_evals=5))
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("[################........] 2/3 runs") and "best min: 10 [cs]" in lines[0]
    assert "nmp: 3 (infeasible) [pso]" in lines[1]


def test_the_commit_recorded_is_the_checkouts_when_the_process_started(tmp_path, monkeypatch):
    """meta.json names the commit the checkout had when run_experiment started, not when it
    wrote the file: a checkout pulled while a long process runs must not relabel what the process
    computed with the code it had imported (it did, for a reference run of the suite)."""
    import heurtune.runner.experiment as E

    finished = []
    persist = E._persist

    def counting_persist(*args, **kwargs):
        finished.append(1)
        return persist(*args, **kwargs)

    def fake_git(*args):
        # the "checkout" moves on as soon as a run has finished
        return ("after" if finished else "before") if args[0] == "rev-parse" else ""

    monkeypatch.setattr(E, "_persist", counting_persist)
    monkeypatch.setattr(E, "_git", fake_git)
    E._git_commit.cache_clear(), E._git_dirty.cache_clear()
    try:
        out = E.run_experiment("cs_folqi_qtp", runs=1, max_epochs=2, out=tmp_path / "r", figures=False,
                               progress_stream=open(os.devnull, "w"))
        assert finished and json.loads((out / "meta.json").read_text())["git_commit"] == "before"
    finally:
        E._git_commit.cache_clear(), E._git_dirty.cache_clear()  # the real checkout for later tests


def test_runs_keep_the_commit_that_made_them_when_a_later_process_gathers_the_folder(tmp_path, monkeypatch):
    """meta.json's git_commit is the last process's (the folder is gathered by every command);
    run_origins names, per run, the commit of the process that ran it, which a later gathering
    (a suite scoring finished folders at another commit) must not relabel."""
    import heurtune.runner.experiment as E
    from heurtune.runner.resultdir import part_origin

    def run_at(commit):
        monkeypatch.setattr(E, "_git", lambda *args: commit if args[0] == "rev-parse" else "")
        E._git_commit.cache_clear(), E._git_dirty.cache_clear()
        return E.run_experiment("cs_folqi_qtp", runs=1, max_epochs=2, out=tmp_path / "r", figures=False,
                                progress_stream=open(os.devnull, "w"))

    try:
        out = run_at("made")
        time.sleep(1.1)  # the gathering's time stamp a second later at least (to the second)
        out = run_at("later")  # nothing left to run: only the gathering
    finally:
        E._git_commit.cache_clear(), E._git_dirty.cache_clear()  # the real checkout for later tests
    meta = json.loads((out / "meta.json").read_text())
    assert meta["git_commit"] == "later"
    parts = sorted((out / "parts").glob("*.run.parquet"))
    assert parts and set(meta["run_origins"]) == {p.name[:-len(".run.parquet")] for p in parts}
    made = {name: {k: v for k, v in o.items() if k != "written"} for name, o in meta["run_origins"].items()}
    assert all(o == {"git_commit": "made", "git_dirty": False} for o in made.values())
    origin = part_origin(parts[0])
    assert origin == meta["run_origins"][parts[0].name[:-len(".run.parquet")]]
    # the time of the run's writing, not of the later gathering
    assert origin["written"] < meta["written"]


def test_the_problem_cache_keeps_the_problems_used_last(monkeypatch):
    # a suite worker serves many folders: it keeps the last problems it used, not every one
    from heurtune.runner import experiment as E
    from heurtune.runner.config import load_config

    monkeypatch.setattr(E, "_PROBLEMS", type(E._PROBLEMS)())
    monkeypatch.setattr(E, "_PROBLEMS_KEPT", 2)
    config = load_config("cs_pid_qtp")
    first, second = (E._problem(dict(config, name=f"cache_{k}"), "min") for k in (1, 2))
    assert E._problem(dict(config, name="cache_1"), "min") is first  # used again: now the newest
    E._problem(dict(config, name="cache_3"), "min")
    assert len(E._PROBLEMS) == 2
    assert E._problem(dict(config, name="cache_1"), "min") is first
    assert E._problem(dict(config, name="cache_2"), "min") is not second  # the oldest went: built anew
