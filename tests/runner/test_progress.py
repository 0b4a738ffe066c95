"""The progress line: evaluations done of the total, the time left, the best over every run,
updated from inside running runs through their heartbeats."""

import io
import json
import os
import pickle
import time

import numpy as np
import pandas as pd
import pytest
from numerics import assert_same_bits

from heurtune.core.engine import SearchSpace
from heurtune.core.engine import run as run_optimiser
from heurtune.core.evaluator import Evaluator
from heurtune.runner.experiment import run_experiment
from heurtune.runner.progress import HEARTBEAT_SUFFIX, Heartbeat, Progress, clear_heartbeats


def _sphere(X):
    return (X ** 2).sum(axis=1)


def test_the_engine_reports_every_epoch_and_the_run_is_the_same_without_it():
    calls = []
    space = SearchSpace(-np.ones(3), np.ones(3))
    with Evaluator(_sphere) as ev:
        watched = run_optimiser("cs", ev, space, seed=4, max_epochs=5, progress=lambda *a: calls.append(a))
        alone = run_optimiser("cs", ev, space, seed=4, max_epochs=5)
    assert [c[1] for c in calls] == list(range(6))  # epochs 0 (the initial population) to 5
    assert [c[0] for c in calls] == watched.history["n_evals"].tolist()
    assert calls[-1][2] == watched.f and calls[-1][3] == 0.0  # exact: the value reported is the one kept
    assert_same_bits(watched.f, alone.f, because="same seed")
    assert_same_bits(watched.x, alone.x, because="same seed")
    assert_same_bits(watched.history.drop(columns="wall_time_s"), alone.history.drop(columns="wall_time_s"),
                     because="same seed")


def test_heartbeat_writes_at_most_once_per_interval_and_travels_to_workers(tmp_path):
    path = tmp_path / f"r{HEARTBEAT_SUFFIX}"
    beat = Heartbeat(path, interval=60.0)
    beat(10, 0, 5.0, 0.0)
    beat(20, 1, 4.0, 0.0)  # within the interval: not written
    assert json.loads(path.read_text()) == dict(n_evals=10, epoch=0, best_f=5.0, best_violation=0.0)
    clone = pickle.loads(pickle.dumps(beat))  # a fresh clock on the worker
    clone(30, 2, 3.0, 0.0)
    assert json.loads(path.read_text())["n_evals"] == 30
    elsewhere = Heartbeat(tmp_path / "missing" / "r.progress.json", interval=0.0)
    elsewhere(1, 0, 1.0, 0.0)  # a folder this worker does not have: it gives up quietly
    assert not (tmp_path / "missing").exists()
    clear_heartbeats(tmp_path)
    assert not path.exists()


def _kept(**row):
    return pd.Series(
        dict(dict(case="min", algorithm="cs", feasible=True, best_f=10.0, violation=0.0, n_evals=100), **row)
    )


def test_the_line_counts_runs_in_flight_and_shows_their_best(tmp_path):
    planned = {"a": ("min", "cs", 100), "b": ("nmp", "cs", 100), "c": ("nmp", "pso", 100)}
    stream = io.StringIO()
    bar = Progress(4, 1, stream, finished_rows=[_kept()], planned=planned, parts=tmp_path, predicted_rate=50.0,
                   log_interval=0.0)
    Heartbeat(tmp_path / f"a{HEARTBEAT_SUFFIX}", 0.0)(40, 3, 8.0, 0.0)  # better than the kept run
    Heartbeat(tmp_path / f"b{HEARTBEAT_SUFFIX}", 0.0)(30, 2, 1e10, 2.5)  # nothing feasible yet
    Heartbeat(tmp_path / f"zzz{HEARTBEAT_SUFFIX}", 0.0)(999, 2, 1.0, 0.0)  # not a run of this plan
    bar.poll()
    line = stream.getvalue().splitlines()[-1]
    assert line.startswith("[######..................] 1/4 runs, 170/400 evals, ")
    # 70 evaluations of this invocation seen just now: the time left is the calibration's
    assert "starting" not in line and "evals/s" not in line and "4.6 s left" in line
    assert "best min: 8 [cs], nmp: 2.5 (infeasible) [cs]" in line
    # a run ends: its actual count replaces its plan
    bar.update(dict(case="min", algorithm="cs", feasible=True, best_f=7.0, violation=0.0, n_evals=90), "a")
    line = stream.getvalue().splitlines()[-1]
    assert "2/4 runs, 220/390 evals" in line and "best min: 7 [cs]" in line
    bar.close()


def test_the_measured_rate_replaces_the_calibrated_one(tmp_path, monkeypatch):
    from heurtune.runner import progress

    monkeypatch.setattr(progress, "RATE_AFTER_S", 0.05)
    stream = io.StringIO()
    bar = Progress(1, 0, stream, planned={"a": ("min", "cs", 1000)}, parts=tmp_path, predicted_rate=1.0,
                   log_interval=0.0)
    Heartbeat(tmp_path / f"a{HEARTBEAT_SUFFIX}", 0.0)(100, 1, 1.0, 0.0)
    bar.poll()
    time.sleep(0.1)
    Heartbeat(tmp_path / f"a{HEARTBEAT_SUFFIX}", 0.0)(300, 2, 1.0, 0.0)
    bar.poll()
    line = stream.getvalue().splitlines()[-1]
    rate = float(line.split(" evals/s")[0].rsplit(", ", 1)[1])
    assert 200 < rate < 2000  # 200 evaluations in about 0.1 s, not the calibration's 1 per s
    assert "min left" not in line and "h " not in line


def test_runs_with_no_count_in_advance_take_that_of_their_finished_siblings(tmp_path):
    stream = io.StringIO()
    bar = Progress(3, 1, stream, finished_rows=[_kept(algorithm="sqp_multistart", n_evals=400)],
                   planned={"a": ("min", "sqp_multistart", None), "b": ("min", "sqp_multistart", None)})
    assert bar.evaluations() == (400, 1200)
    bar2 = Progress(
        2, 0, io.StringIO(), planned={"a": ("min", "sqp_multistart", None), "b": ("min", "sqp_multistart", None)}
    )
    assert bar2.evaluations() == (0, None)
    bar2.update(
        dict(case="min", algorithm="sqp_multistart", feasible=True, best_f=1.0, violation=0.0, n_evals=500), "a"
    )
    assert bar2.evaluations() == (500, 1000)
    assert "1/2 runs, 500/1,000 evals" in bar2.stream.getvalue()


class _Terminal(io.StringIO):
    def isatty(self):
        return True


# two workers: 17 s on the EPYC, `make test-long` (one worker moves the same line)
@pytest.mark.parametrize("jobs", [1, pytest.param(2, marks=pytest.mark.long)])
def test_a_terminal_sees_the_line_move_inside_a_run(tmp_path, jobs, monkeypatch):
    """In this process (one worker) and from the workers' heartbeats (two workers, whole runs),
    the line counts evaluations before any run has finished. The line is read every second and
    a heartbeat written at most every second, so each run is given 60 generations (3,000
    evaluations, several seconds; a loaded machine only makes it longer)."""
    monkeypatch.setenv("COLUMNS", "200")  # a wide terminal: the whole line, bests included
    stream = _Terminal()
    run_experiment("cs_folqi_qtp", runs=1 if jobs == 1 else 2, max_epochs=60, jobs=jobs, out=tmp_path / "r",
                   progress_stream=stream, figures=False)
    frames = [f.strip() for f in stream.getvalue().split("\r")]
    inside = [f for f in frames if " 0/" in f and " runs, " in f and not f.split(" runs, ")[1].startswith("0/")]
    assert inside, frames
    assert "best min: " in inside[-1]


@pytest.mark.parametrize("columns", [100, 60])
def test_a_terminal_line_fits_its_width(monkeypatch, columns):
    """Each redraw is one column shorter than the terminal (a full-width line would wrap and
    every redraw leave a copy: 12 stacked lines in a 100-column tmux, issue 53)."""
    import shutil

    monkeypatch.setattr(shutil, "get_terminal_size", lambda fallback=None: os.terminal_size((columns, 24)))
    stream = _Terminal()  # a StringIO: no file descriptor, so the shutil width
    bar = Progress(total=3, done=0, stream=stream)
    for k in range(3):
        bar.update(dict(case="min" * 20, algorithm="cs", feasible=True, best_f=1234.5 + k, violation=0.0,
                        n_evals=100), name=f"r{k}")
    bar.close()
    frames = [f for f in stream.getvalue().split("\r") if f]
    assert frames and all(len(f.rstrip("\n")) == columns - 1 for f in frames), [len(f) for f in frames]


def test_a_pseudo_terminal_of_80_columns_gets_lines_of_79(monkeypatch):
    """On a real (pseudo-)terminal of 80 columns, its own size read from its file descriptor,
    not the environment's COLUMNS: every redraw is 79 characters, so none wraps (issue 53)."""
    import fcntl
    import select
    import struct
    import termios

    monkeypatch.setenv("COLUMNS", "200")  # what the terminal says wins over the environment
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    stream = os.fdopen(slave, "w", buffering=1, encoding="utf-8")
    try:
        assert stream.isatty()
        bar = Progress(total=3, done=0, stream=stream)
        for k in range(3):
            bar.update(dict(case="min" * 20, algorithm="cs", feasible=True, best_f=1234.5 + k, violation=0.0,
                            n_evals=100), name=f"r{k}")
        bar.close()
        stream.flush()
        out = b""
        while True:  # what the terminal received
            if not select.select([master], [], [], 0.2)[0]:
                break
            out += os.read(master, 65536)
    finally:
        stream.close()
        os.close(master)
    frames = [f for f in out.decode().replace("\n", "\r").split("\r") if f.strip()]
    assert frames and all(len(f) <= 79 for f in frames), [len(f) for f in frames]
    assert any(len(f) == 79 for f in frames)
