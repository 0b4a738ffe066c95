"""The wheel installs one import name, heurtune, with the mapped folders inside it."""

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(out), str(ROOT)], check=True, capture_output=True)
    return next(out.glob("heurtune-*.whl"))


def test_wheel_contains_only_heurtune(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.startswith("heurtune-")}
    assert top == {"heurtune"}
    for required in ("heurtune/objectives/qtp/model.py", "heurtune/objectives/qtp/kernels.py",
                     "heurtune/objectives/tito/family.py", "heurtune/objectives/qtp/thesis/tables.py",
                     "heurtune/core/families.py", "heurtune/runner/experiment.py", "heurtune/analysis/compare.py",
                     "heurtune/algorithms/__init__.py", "heurtune/experiments/cs_folqi_qtp.toml",
                     "heurtune/experiments/plugins/conical_tanks.py"):
        assert required in names
    assert not any(n.startswith("tests/") for n in names)


def test_installed_wheel_imports_outside_the_repo(wheel, tmp_path):
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
                   check=True, capture_output=True)
    code = ("import heurtune, sys; p = heurtune.load_experiment('cs_folqi_qtp').problem('nmp'); "
            "print(heurtune.__file__); print(p.dim)")
    res = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(tmp_path / "nb")},
    )
    assert res.returncode == 0, res.stderr
    file, dim = res.stdout.split()
    assert file.startswith(str(target)) and dim == "10"
