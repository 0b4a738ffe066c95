"""python -m heurtune.precompile: the shipped experiments' kernels compiled once into numba's
cache, split over two processes without overlap."""

import os
import subprocess
import sys

from heurtune.runner.config import list_experiments
from heurtune.runner.precompile import CONTINUOUS, SAMPLED, _groups, warm


def test_two_groups_cover_every_experiment_once_per_device():
    one, = _groups(1)
    a, b = _groups(2)
    names = set(list_experiments()) | {f"{n}:sampled" for n in SAMPLED} | {f"{n}:continuous" for n in CONTINUOUS}
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
