"""Fault injection on a results folder: parts of another config, damaged or misplaced parts,
two writers, unwritable folders, a best run whose design fails.

Each test checks the one-line outcome and, where the folder recovers, that the result equals
an uninterrupted run exactly (wall times aside). Nothing here depends on timing.
"""

import json
import os
import shutil
import socket
import subprocess
import sys

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from numerics import assert_same_bits

from heurtune.runner.experiment import run, status_table
from heurtune.runner.resultdir import LOCK_FILE, METADATA_KEY, read_part

BASE = '''extends = "cs_folqi_qtp"
runs = 2
[[optimisers]]
name = "cs"
settings = { n = 6, pa = 0.25 }
max_epochs = 2
'''


def write_config(folder, extra="", base=BASE):
    path = folder / "exp.toml"
    path.write_text(base + extra)
    return path


def results(out):
    """The gathered runs without their wall times (the one column a rerun may change)."""
    return pd.read_parquet(out / "runs.parquet").drop(columns=["wall_time_s"])


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """An uninterrupted run of the base config: what every recovery must reproduce."""
    folder = tmp_path_factory.mktemp("clean")
    cfg = write_config(folder)
    assert run([str(cfg), "--out", str(folder / "out"), "--no-figures"]) == 0
    return cfg, folder / "out"


@pytest.fixture
def copy(clean, tmp_path):
    """A copy of the clean folder to break."""
    cfg, out = clean
    target = tmp_path / "out"
    shutil.copytree(out, target)
    return cfg, target


def one_error_line(capsys, *needles):
    """The one ``error:`` line on stderr (warnings about the config may come before it)."""
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    others = [line for line in err.splitlines() if not line.startswith(("error: ", "warning: "))]
    assert len(errors) == 1 and not others, err
    for needle in needles:
        assert needle in errors[0], err
    return errors[0]


def test_another_experiment_into_the_folder_is_refused_and_changes_nothing(copy, capsys):
    cfg, out = copy
    before = (out / "runs.parquet").read_bytes()
    capsys.readouterr()
    assert run(["cs_iolqi_qtp", "--smoke", "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, "holds 4 run(s) of a different config", "problem.controller", "--fresh")
    assert (out / "runs.parquet").read_bytes() == before
    assert not (out / LOCK_FILE).exists()


@pytest.mark.parametrize("prefix, suffix, key", [
    ("", "[problem.bounds]\nQ11 = [2.0, 2.5]\n", "problem.bounds.Q11"),
    ("", "[problem.constraints]\nMp = 1.0\n", "problem.constraints.Mp"),
    ("seed = 99\n", "", "seed"),
])
def test_an_edited_config_is_refused_naming_the_key(copy, tmp_path, capsys, prefix, suffix, key):
    _, out = copy
    capsys.readouterr()
    edited = write_config(tmp_path, base=prefix + BASE + suffix)
    assert run([str(edited), "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, "different config", key)


def test_an_edited_setting_is_refused_naming_it(copy, tmp_path, capsys):
    _, out = copy
    capsys.readouterr()
    edited = write_config(tmp_path, base=BASE.replace("pa = 0.25", "pa = 0.9"))
    assert run([str(edited), "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, "different config", "settings.pa")


def test_fresh_discards_the_other_config(copy, tmp_path, capsys):
    _, out = copy
    edited = write_config(tmp_path, base=BASE.replace("pa = 0.25", "pa = 0.9"))
    assert run([str(edited), "--out", str(out), "--no-figures", "--fresh"]) == 0
    assert (out / "runs.parquet").exists() and not (out / LOCK_FILE).exists()


def damage_truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def damage_empty(path):
    path.write_bytes(b"")


def damage_garbage(path):
    path.write_bytes(b"not a parquet file\n" * 20)


@pytest.mark.parametrize("kind", ["truncated", "empty", "garbage", "missing history", "damaged history",
                                  "another run's part"])
def test_a_damaged_part_is_set_aside_and_its_run_computed_again(clean, copy, capsys, kind):
    _, expected = clean
    cfg, out = copy
    parts = out / "parts"
    runs = sorted(parts.glob("*.run.parquet"))
    victim = runs[0]
    name = victim.name[:-len(".run.parquet")]
    history = parts / f"{name}.history.parquet"
    if kind == "truncated":
        damage_truncate(victim)
    elif kind == "empty":
        damage_empty(victim)
    elif kind == "garbage":
        damage_garbage(victim)
    elif kind == "missing history":
        history.unlink()
    elif kind == "damaged history":
        damage_truncate(history)
    else:  # the nmp run's part copied over the min run's
        shutil.copy(runs[-1], victim)
    (out / "runs.parquet").unlink()
    assert status_table(out.parent, out.name)["done"].iloc[0] == (4 if kind in ("missing history", "damaged history")
                                                                  else 3)
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if "set aside" in line]
    assert len(warnings) == 1 and name in warnings[0] and "set aside" in warnings[0], err
    assert (parts / "corrupt" / victim.name).exists() or (parts / "corrupt" / history.name).exists()
    assert_same_bits(results(out), results(expected), because="resume")


def test_a_damaged_plan_file_is_rewritten(clean, copy, capsys):
    _, expected = clean
    cfg, out = copy
    (out / "plan.json").write_text("{not json")
    (out / "planned.json").write_text("[")
    assert run(["--status", "--out", str(out)]) == 0
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    assert_same_bits(results(out), results(expected), because="resume")
    assert json.loads((out / "planned.json").read_text())["experiment"] == "exp"


def test_a_second_writer_is_refused_naming_the_holder(copy, capsys):
    cfg, out = copy
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / LOCK_FILE).write_text(json.dumps(dict(pid=holder.pid, host=socket.gethostname(), since="now")))
        capsys.readouterr()
        assert run([str(cfg), "--out", str(out), "--no-figures"]) == 2
        one_error_line(capsys, f"is being written by pid {holder.pid}")
        assert (out / LOCK_FILE).exists()  # the holder's lock stays
    finally:
        holder.kill()
        holder.wait()


def test_a_stale_lock_is_taken_over_with_a_warning(clean, copy, capsys):
    _, expected = clean
    cfg, out = copy
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (out / LOCK_FILE).write_text(json.dumps(dict(pid=int(gone.stdout), host=socket.gethostname(), since="then")))
    (out / "runs.parquet").unlink()
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    assert "taking over" in capsys.readouterr().err
    assert not (out / LOCK_FILE).exists()
    assert_same_bits(results(out), results(expected), because="resume")


def test_two_processes_at_once_one_refused(clean, tmp_path):
    """Two writers started together: one runs, the other stops with one line (whichever
    comes second); the folder ends complete and equal to the clean run."""
    cfg, expected = clean
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "heurtune.experiment", str(cfg), "--out", str(out), "--no-figures"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    codes, errs = zip(*[(p.wait(timeout=600), p.stderr.read()) for p in procs])
    for p in procs:
        p.stderr.close()
    if sorted(codes) == [0, 2]:  # they overlapped: the second was refused
        err = errs[codes.index(2)]
        assert err.startswith("error: ") and "is being written by pid" in err and err.count("\n") == 1
    else:  # the first had finished before the second looked: both complete
        assert codes == (0, 0)
    assert_same_bits(results(out), results(expected), because="resume")


def test_an_unwritable_output_is_one_line(tmp_path, capsys):
    cfg = write_config(tmp_path)
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    assert run([str(cfg), "--out", str(a_file), "--no-figures"]) == 2
    one_error_line(capsys, "is a file, not a folder")
    assert run([str(cfg), "--out", str(a_file / "sub"), "--no-figures"]) == 2
    one_error_line(capsys, "cannot write in")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_output_is_one_line(copy, capsys):
    cfg, out = copy
    os.chmod(out, 0o555)
    try:
        assert run([str(cfg), "--out", str(out), "--no-figures"]) == 2
        one_error_line(capsys, "cannot write in")
    finally:
        os.chmod(out, 0o755)


def test_a_best_run_whose_design_fails_still_gathers(tmp_path, capsys):
    """Bounds so wide that the best gains fail the design when the margins are computed: the
    margins record the failure, and the summary and every other file are written."""
    cfg = write_config(
        tmp_path, base=BASE.replace("runs = 2", "runs = 1") + "[problem.bounds]\nQ11 = [1e-300, 1e300]\n"
    )
    out = tmp_path / "out"
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    assert "no margins for the best cs run (ControllerDesignError" in capsys.readouterr().err
    for name in ("runs.parquet", "summary.parquet", "meta.json", "margins.parquet"):
        assert (out / name).exists(), name
    margins = pd.read_parquet(out / "margins.parquet")
    assert margins["failure"].str.startswith("ControllerDesignError").all()


def test_saved_solves_of_another_config_are_refused_and_damaged_ones_set_aside(tmp_path, capsys):
    """A multistart's ``.starts.parquet``: its run key must match; a damaged one is redone."""
    import numpy as np

    from heurtune.core.errors import ConfigError
    from heurtune.runner.experiment import StartsFile

    names = ["a", "b"]
    solve = dict(start=0, round=0, cap=None, x0=np.zeros(2), x=np.ones(2), f=1.0, violation=0.0, g=np.zeros(1),
                 nfev=3, nit=2, success=True, message="ok")
    path = tmp_path / "parts" / "r.starts.parquet"
    path.parent.mkdir()
    StartsFile(path, names, "key1").save([solve])
    assert len(StartsFile(path, names, "key1").load()) == 1
    with pytest.raises(ConfigError, match="another configuration of this run"):
        StartsFile(path, names, "key2").load()
    damage_truncate(path)
    capsys.readouterr()
    assert StartsFile(path, names, "key1").load() == []
    assert (path.parent / "corrupt" / path.name).exists() and "set aside" in capsys.readouterr().err


@pytest.mark.parametrize("text, message", [
    ("[controller]\noustaloup_order = 5000\n", "controller.oustaloup_order: must be <= 20, got 5000"),
    ("[controller]\noustaloup_order = 0\n", "controller.oustaloup_order: must be >= 1, got 0"),
    ("[controller]\nband = [1e3, 1e-3]\n", "controller.band must be [low, high] rad/s with 0 < low < high"),
    ("[controller]\nband = [0, 1e3]\n", "controller.band must be"),
    ("[controller]\nband = [1e-3, inf]\n", "both finite"),
    ("runs = 0\n", "runs: must be >= 1, got 0"),
    ("seed = -1\n", "seed: must be >= 0, got -1"),
    ("runs = 10000000\n", "20,000,000 runs planned"),
    ('[[optimisers]]\nname = "cs"\nsettings = { n = 1000000000 }\n', "settings.n = 1,000,000,000 needs about"),
    ('[plant]\ncases = ["min", "min"]\n', "plant.cases names 'min' more than once"),
    ('plugins = ["json"]\n', "plugin 'json' registers no optimiser, no plant family and no controller structure"),
    ("[problem.bounds]\nR11 = [-5, 5]\n", "problem.bounds.R11: the lower bound must be > 0, got -5.0"),
    ("[problem.bounds]\nQ11 = [-1, 2]\n", "problem.bounds.Q11: the lower bound must be >= 0"),
    ('[[optimisers]]\nname = "cs"\ntol_window = 0\n', "optimisers[0].tol_window: must be >= 1, got 0"),
    ('[[optimisers]]\nname = "cs"\nmax_epochs = -1\n', "optimisers[0].max_epochs: must be >= 0"),
    ('[[optimisers]]\nname = "cs"\nmax_time = -1\n', "optimisers[0].max_time: must be > 0"),
    ('[[optimisers]]\nname = "cs"\ntol = -1\n', "optimisers[0].tol: must be >= 0"),
    ('[[optimisers]]\nname = "cs"\nconstraint_handling = "penalty"\npenalty = -1\n', "penalty: must be > 0"),
])
def test_a_config_that_would_fail_later_is_refused_before_anything_is_written(tmp_path, capsys, text, message):
    cfg = tmp_path / "bad.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\n' + text)
    out = tmp_path / "out"
    assert run([str(cfg), "--out", str(out)]) == 2
    one_error_line(capsys, message)
    assert not out.exists()


def test_a_config_that_is_not_utf8_and_a_negative_seed_option_are_one_line(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_bytes(b'extends = "cs_folqi_qtp"\n# \xff\xfe\n')
    assert run([str(cfg), "--out", str(tmp_path / "out")]) == 2
    one_error_line(capsys, "not UTF-8 text")
    assert run(["cs_folqi_qtp", "--seed", "-1", "--out", str(tmp_path / "out")]) == 2
    one_error_line(capsys, "--seed must be >= 0, got -1")
    assert not (tmp_path / "out").exists()


def test_a_full_disk_is_one_line_and_the_finished_runs_are_kept(clean, tmp_path, monkeypatch, capsys):
    import errno

    import heurtune.runner.experiment as experiment

    cfg, expected = clean
    out = tmp_path / "out"
    real = experiment.write_parquet
    calls = []

    def full_after_two_runs(df, path, metadata=None):
        calls.append(path)
        if len(calls) > 4:  # a run is two parts: history, then the run
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(df, path, metadata)

    monkeypatch.setattr(experiment, "write_parquet", full_after_two_runs)
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, "No space left on device", "the finished runs are kept")
    assert len(list((out / "parts").glob("*.run.parquet"))) == 2
    monkeypatch.setattr(experiment, "write_parquet", real)
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    assert_same_bits(results(out), results(expected), because="resume")


@pytest.mark.long  # 50 s on the EPYC: `make test` kills a worker under a spread run below
def test_a_killed_worker_names_the_run_and_the_folder_resumes(tmp_path, capsys):
    """An optimiser plugin that kills its worker process (as the OOM killer would)."""
    (tmp_path / "die_opt.py").write_text(
        "import dataclasses, multiprocessing, os, signal\n"
        "from heurtune.core.engine import Optimizer\n"
        "from heurtune.core.registry import register\n"
        "@dataclasses.dataclass(frozen=True)\n"
        "class S:\n    n: int = 4\n"
        "@register('die_in_worker', settings=S, description='test: kills its worker process')\n"
        "class Die(Optimizer):\n"
        "    def ask(self):\n"
        "        if os.environ.get('DIE_IN_WORKERS') and 'Loky' in multiprocessing.current_process().name:\n"
        "            os.kill(os.getpid(), signal.SIGKILL)\n"
        "        return self.space.uniform(self.rng, self.settings.n)\n"
        "    def tell(self, X, f, v):\n        self.X, self.f, self.v = X, f, v\n        return True\n")
    cfg = tmp_path / "die.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\nplugins = ["die_opt.py"]\nruns = 2\n'
                   '[[optimisers]]\nname = "die_in_worker"\nmax_epochs = 2\n')
    # three epochs of CS beside it: the runs that finish before the worker dies
    cmd = [sys.executable, "-m", "heurtune.experiment", str(cfg), "--out", str(tmp_path / "out"), "--jobs", "2",
           "--no-figures", "--max-epochs", "3"]
    died = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=dict(os.environ, DIE_IN_WORKERS="1"))
    assert died.returncode == 2, died.stderr
    errors = [line for line in died.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "a worker process died" in errors[0] and "die_in_worker__000" in errors[0]
    assert "finished run(s) are kept" in errors[0] and "Traceback" not in died.stderr
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    whole = subprocess.run(cmd[:cmd.index("--out") + 1] + [str(tmp_path / "whole")] + cmd[cmd.index("--out") + 2:],
                           capture_output=True, text=True, timeout=600)
    assert whole.returncode == 0, whole.stderr
    assert_same_bits(results(tmp_path / "out"), results(tmp_path / "whole"), because="resume")


def test_a_worker_killed_under_a_spread_run_names_that_run(tmp_path):
    """A driver that spreads its work units over all the workers (``spreads_work``): the
    first run ends, a worker dies under the second, in its first work unit. The error names
    the second run (not the run at the unit's index), and the first run is kept."""
    (tmp_path / "die_spread.py").write_text(
        "import dataclasses, multiprocessing, os, pathlib, signal\n"
        "from heurtune.core.engine import Driver\n"
        "from heurtune.core.registry import register\n"
        "@dataclasses.dataclass(frozen=True)\n"
        "class S:\n    n: int = 4\n"
        "MARK = pathlib.Path(os.environ['DIE_SPREAD_MARK'])\n"
        "def _unit(item):\n"
        "    if item == 0 and MARK.exists() and 'Loky' in multiprocessing.current_process().name:\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "    return item\n"
        "@register('die_spread', kind='driver', settings=S, description='test: kills a worker in a work unit')\n"
        "class DieSpread(Driver):\n"
        "    @staticmethod\n"
        "    def spreads_work(budget):\n        return True\n"
        "    def run(self, ctx):\n"
        "        f, v, _ = ctx.evaluate(self.space.uniform(self.rng, 1))\n"
        "        ctx.record_epoch(f, v)\n"
        "        for _ in ctx.map_unordered(_unit, list(range(self.settings.n))):\n            pass\n"
        "        MARK.touch()\n")
    cfg = tmp_path / "die.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\nplugins = ["die_spread.py"]\nruns = 1\n'
                   '[[optimisers]]\nname = "die_spread"\nmax_epochs = 2\n')
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "heurtune.experiment", str(cfg), "--out", str(out), "--jobs", "2", "--no-figures"]
    died = subprocess.run(cmd, capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, DIE_SPREAD_MARK=str(tmp_path / "mark")))
    assert died.returncode == 2, died.stderr
    errors = [line for line in died.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "a worker process died" in errors[0] and "nmp__0-die_spread__0000" in errors[0]
    assert "Traceback" not in died.stderr
    assert [p.name for p in (out / "parts").glob("*.run.parquet")] == ["min__0-die_spread__0000.run.parquet"]


def test_a_folder_of_an_earlier_heurtune_is_refused_in_one_line(copy, capsys):
    """Parts without a fingerprint (as every earlier version wrote them): what made them cannot
    be checked, so they are neither reused nor silently redone."""
    cfg, out = copy
    for path in (out / "parts").glob("*.parquet"):
        df = pd.read_parquet(path)
        df.to_parquet(path, index=False)  # the same table, without heurtune's metadata
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, "was written by an earlier heurtune", "--fresh")


def test_an_unwritable_folder_is_one_line_even_with_nothing_left_to_do(copy, monkeypatch, capsys):
    """The write probe fails as a read-only folder makes it fail (root ignores permissions, so
    the failure is injected): every run is done, yet the folder cannot take the lock or the
    gathered files."""
    import pathlib

    cfg, out = copy
    real = pathlib.Path.write_text

    def read_only(self, *args, **kwargs):
        if self.name.startswith(".heurtune-write-test"):
            raise PermissionError(13, "Permission denied", str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "write_text", read_only)
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, f"cannot write in {out}: Permission denied")


def test_a_part_of_another_plan_dropped_in_is_refused(clean, copy, tmp_path, capsys):
    """A part written under the same name by another plan (here --max-epochs 1) cannot be
    gathered: the folder is refused naming the budget."""
    cfg, out = copy
    other = tmp_path / "other"
    assert run([str(cfg), "--out", str(other), "--no-figures", "--max-epochs", "1"]) == 0
    victim = sorted((out / "parts").glob("*.run.parquet"))[0]
    name = victim.name[:-len(".run.parquet")]
    for kind in ("run", "history"):
        shutil.copy(other / "parts" / f"{name}.{kind}.parquet", out / "parts" / f"{name}.{kind}.parquet")
    capsys.readouterr()
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 2
    one_error_line(capsys, "holds 1 run(s) of a different config", "budget.max_epochs")


def test_an_optimiser_entry_for_no_case_plans_no_runs_and_keeps_its_place(tmp_path):
    """``cases = []``: the entry keeps its index (so the seeds of the entries after it), runs nothing."""
    import heurtune
    from heurtune.runner.experiment import plan

    cfg = write_config(tmp_path, base=BASE.replace('name = "cs"', 'name = "cs"\ncases = []')
                       + '[[optimisers]]\nname = "pso"\nmax_evals = 100\n')
    specs = plan(heurtune.load_experiment(str(cfg)))
    assert {s.algorithm for s in specs} == {"pso"} and {s.optimiser_index for s in specs} == {1}


def test_a_finished_folder_run_again_reads_each_part_once_and_gathers_the_same(clean, copy, monkeypatch):
    """The first look, the check under the lock, the progress bar and the gathering share one
    read of each part file (they read them five times before)."""
    _, expected = clean
    cfg, out = copy
    reads = []
    real = pq.read_table
    monkeypatch.setattr(pq, "read_table", lambda path, *a, **k: reads.append(str(path)) or real(path, *a, **k))
    assert run([str(cfg), "--out", str(out), "--no-figures"]) == 0
    part_reads = [p for p in reads if "/parts/" in p]
    assert part_reads and len(part_reads) == len(set(part_reads)), sorted(part_reads)
    assert len(set(part_reads)) == 2 * len(list((out / "parts").glob("*.run.parquet")))
    assert_same_bits(results(out), results(expected), because="resume")


def test_the_part_cache_reads_a_rewritten_file_again(copy):
    _, out = copy
    part = sorted((out / "parts").glob("*.run.parquet"))[0]
    cache = {}
    first, fingerprint = read_part(part, cache=cache)
    again, _ = read_part(part, cache=cache)
    assert again is first  # unchanged: the table read before
    table = first.copy()
    table["wall_time_s"] = table["wall_time_s"] + 1.0
    tmp = part.with_suffix(".tmp")
    meta = {METADATA_KEY: json.dumps(fingerprint).encode()}
    pq.write_table(pa.Table.from_pandas(table, preserve_index=False).replace_schema_metadata(meta), tmp)
    os.replace(tmp, part)  # a new file in its place, as an atomic write makes it
    fresh, fresh_fingerprint = read_part(part, cache=cache)
    assert fresh is not first and fresh_fingerprint == fingerprint
    assert fresh["wall_time_s"].iloc[0] == first["wall_time_s"].iloc[0] + 1.0
