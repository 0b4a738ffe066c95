"""python -m heurtune.precompile: the shipped experiments' kernels compiled once into numba's
cache, split over two processes without overlap."""

import os
import subprocess
import sys

from heurtune.runner.config import list_experiments
from heurtune.runner.precompile import CONTINUOUS, LINEARISED, SAMPLED, _groups, warm


def test_two_groups_cover_every_experiment_once_per_device():
    one, = _groups(1)
    a, b = _groups(2)
    names = (set(list_experiments()) | {f"{n}:sampled" for n in SAMPLED} | {f"{n}:continuous" for n in CONTINUOUS}
             | {f"{n}:linearised" for n in LINEARISED})
    assert {n.split("@")[0] for n in one} == names
    assert {n.split("@")[0] for n in a + b} == names
    # a QTP experiment's one-candidate kernels in one process, its batched ones in the other
    assert all(n.endswith("@cpu") for n in a) and "cs_folqi_qtp@cpu-batch" in b
    assert len(a + b) == len(set(a + b))


def test_warm_says_what_it_did_and_names_what_it_could_not():
    lines = warm(["paper_002@cpu", "no_such_experiment"])
    assert lines[0].startswith("paper_002@cpu: ") and lines[0].endswith(" s")
    assert lines[1].startswith("no_such_experiment: not compiled (ConfigError")


def test_the_command_fills_an_empty_cache(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    done = subprocess.run([sys.executable, "-m", "heurtune.precompile", "paper_002"], env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "paper_002: " in done.stdout and "1 experiments' kernels in numba's cache" in done.stderr
    assert any((tmp_path / "cache").rglob("*.nbi"))


def test_a_stamp_skips_an_unchanged_cache_and_any_change_runs_it_again(tmp_path, monkeypatch, capsys):
    """The stamp holds while numba, the CPU, the sources and the index files it saw are as they
    were; an index file written since does not matter; a changed or removed one, or an edited
    source, does."""
    import json

    from heurtune.runner import precompile

    cache = tmp_path / "cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    (cache / "kernels").mkdir(parents=True)
    index = cache / "kernels" / "loop.run-1.py311.nbi"
    index.write_bytes(b"index")
    assert not precompile._up_to_date()  # no stamp yet
    precompile._write_stamp()
    assert precompile._up_to_date()
    (cache / "kernels" / "test_only.run-9.py311.nbi").write_bytes(b"a kernel compiled by a test")
    assert precompile._up_to_date()
    os.utime(index, ns=(0, 0))  # recompiled since
    assert not precompile._up_to_date()
    precompile._write_stamp()
    index.unlink()  # the cache removed
    assert not precompile._up_to_date()
    index.write_bytes(b"index")
    precompile._write_stamp()
    stamp = cache / precompile.STAMP
    state = json.loads(stamp.read_text())
    state["sources"]["objectives/qtp/kernels.py"][1] -= 1  # a kernel edited since
    stamp.write_text(json.dumps(state))
    assert not precompile._up_to_date()
    # the command: up to date, it says so and compiles nothing; --force runs it
    precompile._write_stamp()
    ran = []
    monkeypatch.setattr(precompile, "_groups", lambda jobs: ran.append(jobs) or [[]])
    precompile.main(["--quiet"])
    assert not ran and "numba's cache is up to date" in capsys.readouterr().err
    precompile.main(["--quiet", "--force"])
    assert ran
