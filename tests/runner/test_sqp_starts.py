"""starts.parquet of multistart SQP runs, and resuming an interrupted run start by start."""

import numpy as np
import pandas as pd
import pytest
from numerics import assert_same_bits

from heurtune.algorithms import sqp_multistart as sqp
from heurtune.runner.experiment import run

GAINS = ["Q11", "Q22", "Q33", "Q44", "R11", "R22", "Ki1", "Ki2", "alpha1", "alpha2"]
START_COLUMNS = (["experiment", "case", "algorithm", "optimiser_index", "run", "start", "round", "cap"]
                 + [f"x0_{n}" for n in GAINS] + GAINS
                 + ["f", "violation", "feasible", "nit", "nfev", "success", "message"])
# Numbers that must not change when a run is resumed (timings do).
RUN_KEYS = ["case", "algorithm", "run", "best_f", "feasible", "violation", "n_evals", "n_epochs",
            "convergence_epoch", "stop_reason", "status"] + GAINS
HISTORY_KEYS = ["case", "run", "epoch", "n_evals", "best_f", "best_violation", "mean_f", "sd_f", "feasible_fraction"]
STARTS = 5


def _config(folder, name="sqp_small", max_iter=3, extra="", starts=STARTS, batch=3):
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_text(
        'extends = "sqp_folqi_qtp"\nruns = 1\n'
        + extra
        + "[scenario]\nhorizon = 60.0\ndt = 0.05\n"
        + '[[optimisers]]\nname = "sqp_multistart"\n'
        + f"settings = {{ starts = {starts}, max_iter = {max_iter}, batch = {batch} }}\n"
    )
    return path


def _read(out):
    return {name: pd.read_parquet(out / f"{name}.parquet") for name in ("runs", "history", "starts")}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run of both cases (min, nmp), one run each, no evaluation budget."""
    tmp = tmp_path_factory.mktemp("sqp_starts")
    out = tmp / "whole"
    assert run([str(_config(tmp)), "--out", str(out), "--no-figures"]) == 0
    return tmp, out, _read(out)


def _same(a, b, because):
    """Bit for bit: every local solve is computed whole by one process, whatever the workers,
    the lockstep or the resume (``because``: which of these)."""
    assert_same_bits(a["runs"][RUN_KEYS], b["runs"][RUN_KEYS], because=because)
    assert_same_bits(a["history"][HISTORY_KEYS], b["history"][HISTORY_KEYS], because=because)
    assert_same_bits(a["starts"], b["starts"], because=because)


def test_starts_parquet_lists_every_local_solve_and_matches_the_runs(reference):
    _, out, res = reference
    starts, runs = res["starts"], res["runs"]
    assert list(starts.columns) == START_COLUMNS
    assert len(starts) == 2 * STARTS and set(starts["case"]) == {"min", "nmp"}
    assert (starts["feasible"] == (starts["violation"] == 0)).all()
    assert starts["cap"].isna().all() and (starts["nit"] <= 3).all()
    assert (starts["algorithm"] == "sqp_multistart").all() and (starts["experiment"] == "sqp_small").all()
    for _, r in runs.iterrows():
        s = starts[(starts["case"] == r["case"]) & (starts["run"] == r["run"])]
        assert list(s["start"]) == list(range(STARTS)) and list(s["round"]) == [0, 0, 0, 1, 1]
        assert s["nfev"].sum() == r["n_evals"]
        feasible = s[s["feasible"]]
        best = feasible.loc[feasible["f"].idxmin()] if len(feasible) else s.loc[s["violation"].idxmin()]
        # exact: the run's result is a copy of its best start's
        assert best["f"] == r["best_f"] and best["violation"] == r["violation"]
        assert [best[n] for n in GAINS] == [r[n] for n in GAINS]
        lower = np.array([0.01] * 4 + [0.1] * 4 + [0.1] * 2)
        assert np.all(s[[f"x0_{n}" for n in GAINS]].to_numpy() >= lower)
    assert not list(out.glob("**/.*"))  # no temporary files left


def test_interrupted_run_resumes_without_resolving_finished_starts(reference, monkeypatch, capsys):
    tmp, _, whole = reference
    out = tmp / "interrupted"
    solve = sqp._local_solve
    calls = []

    def stop_at_nmp_start_4(task, item):
        if len(calls) == STARTS + 4:  # min is done, nmp has solved starts 0-3 (one of round 1)
            raise KeyboardInterrupt
        calls.append(item[0])
        return solve(task, item)

    monkeypatch.setattr(sqp, "_local_solve", stop_at_nmp_start_4)
    assert run([str(_config(tmp)), "--out", str(out), "--no-figures"]) == 130
    saved = pd.read_parquet(out / "parts" / "nmp__0-sqp_multistart__0000.starts.parquet")
    assert list(saved["start"]) == [0, 1, 2, 3]
    assert not (out / "parts" / "nmp__0-sqp_multistart__0000.run.parquet").exists()

    # The same runs under other settings are refused, in one line: the finished min run by
    # its part's fingerprint, before anything runs.
    changed = _config(tmp / "changed", max_iter=4)
    assert run([str(changed), "--out", str(out), "--no-figures"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "different config" in errors[0] and "settings.max_iter" in errors[0]

    calls.clear()

    def counted(task, item):
        calls.append(item[0])
        return solve(task, item)

    monkeypatch.setattr(sqp, "_local_solve", counted)
    assert run([str(_config(tmp)), "--out", str(out), "--no-figures"]) == 0
    assert calls == [4]  # only the unfinished start of nmp was solved
    _same(_read(out), whole, "resume")


def test_same_starts_with_one_and_two_workers(reference):
    tmp, _, whole = reference
    out = tmp / "two"
    assert run([str(_config(tmp)), "--out", str(out), "--jobs", "2", "--no-figures"]) == 0
    _same(_read(out), whole, "workers")


@pytest.mark.long  # 23 s on the EPYC: `make test` has the same starts with one and two workers
def test_a_stop_at_max_epochs_keeps_the_closed_rounds_whatever_the_workers_or_lockstep(tmp_path):
    """Solves that end after the run's stop (begun on another worker, or in the lockstep's
    window) are saved for a resume but are not in starts.parquet, which is therefore the same
    with one worker, two, and in lockstep, and adds up to the runs' evaluations."""
    config = _config(tmp_path, name="sqp_stop", starts=12, batch=2)
    out = {}
    for tag, extra in (("one", []), ("two", ["--jobs", "2"]), ("lockstep", ["--jobs", "2", "--lockstep"])):
        out[tag] = tmp_path / tag
        assert run([str(config), "--out", str(out[tag]), "--max-epochs", "1", "--no-figures", *extra]) == 0
    res = {tag: _read(o) for tag, o in out.items()}
    starts, runs = res["one"]["starts"], res["one"]["runs"]
    assert set(starts["round"]) == {0, 1} and len(starts) == 2 * 4
    for _, r in runs.iterrows():
        assert starts.loc[starts["case"] == r["case"], "nfev"].sum() == r["n_evals"]
    _same(res["two"], res["one"], "workers")
    _same(res["lockstep"], res["one"], "lockstep")


def test_only_multistart_runs_without_a_budget_spread_their_starts_over_the_workers():
    """Such runs go one after another over all the workers (the two-worker run above took that
    path); every other run stays whole on one worker."""
    from heurtune.runner.experiment import RunSpec, _spreads_work

    def spec(algorithm, budget):
        return RunSpec("min", 0, algorithm, 0, 0, {}, budget, 1)

    assert _spreads_work(spec("sqp_multistart", {"max_epochs": 5}))
    assert not _spreads_work(spec("sqp_multistart", {"max_evals": 100}))
    assert not _spreads_work(spec("cmaes_sqp", {}))
    assert not _spreads_work(spec("cs", {}))


def test_no_starts_file_without_a_multistart_driver(tmp_path):
    cfg = tmp_path / "cs_small.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\nruns = 1\n[plant]\ncases = ["min"]\n'
                   "[scenario]\nhorizon = 60.0\ndt = 0.05\n"
                   '[[optimisers]]\nname = "cs"\nsettings = { n = 4 }\nmax_epochs = 1\n')
    out = tmp_path / "out"
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    assert (out / "runs.parquet").is_file()
    assert not (out / "starts.parquet").exists() and not list((out / "parts").glob("*.starts.parquet"))
