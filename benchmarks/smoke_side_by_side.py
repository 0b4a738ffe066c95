"""The shipped experiments' smoke runs at another revision and in this working tree, compared
file by file within the tolerances of shipped numbers: the check that a change keeps them.

    python benchmarks/smoke_side_by_side.py --rev c02129f                 # every shipped experiment
    python benchmarks/smoke_side_by_side.py --rev HEAD~1 cs_folqi_qtp thesis_ch5

The revision runs from a git worktree (added under the output folder, removed at the end), this
tree from where it is. Each side imports every heurtune package (``heurtune``, and
``heurtune.algorithms``, ``heurtune.objectives``, ``heurtune.experiments`` from the top-level
folders) from its own tree. An editable install maps the last three to the checkout it was
installed from, whatever ``PYTHONPATH`` says: a worktree put on ``PYTHONPATH`` alone would run
this tree's optimisers and plants on both sides, and the comparison would prove nothing.

Each run is ``python -m heurtune.experiment NAME --smoke --seed 7 --jobs 1 --no-figures`` (one
process, BLAS on one thread; numba compiles each tree into that tree's ``__pycache__``), the two
sides side by side. Parquet frames are compared column by column, wall-time columns aside, by
:mod:`heurtune.analysis.agreement` (docs/testing.md): floats within their field's tolerance
(1e-9 relative on objectives, integral metrics and gains; absolute on levels, overshoots, ess,
times and voltages), everything else exactly. Written tables and other text files must have the
same text, their numbers within 1e-9 relative or one unit in the last printed place; other
files (figures are off) the same bytes. The run records that hold times and hosts
(``meta.json``, ``plan.json``, ``planned.json``) are left out. Each experiment's line says
``same bits``, ``within tolerance`` or ``differs``; exit 1 when anything differs beyond its
tolerance or a run fails.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import importlib.abc
import importlib.util
import os
import runpy
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# heurtune's packages and the folders they come from, relative to a tree
PACKAGES = {"heurtune": "heurtune", "heurtune.algorithms": "algorithms", "heurtune.objectives": "objectives",
            "heurtune.experiments": "experiments"}
# result files that record when and where a run ran, not what it found
RUN_RECORDS = ("meta.json", "plan.json", "planned.json")
WALL_COLUMNS = ("wall", "time_s", "elapsed", "started", "finished")


class _TreeFinder(importlib.abc.MetaPathFinder):
    """Finds heurtune's packages in one tree, ahead of any installed finder."""

    def __init__(self, tree: Path):
        self.tree = tree

    def find_spec(self, fullname, path=None, target=None):
        folder = PACKAGES.get(fullname)
        if folder is None:
            return None
        root = self.tree / folder
        return importlib.util.spec_from_file_location(fullname, root / "__init__.py",
                                                      submodule_search_locations=[str(root)])


def _run_in_tree(tree: Path, argv: list) -> None:
    """Run ``python -m heurtune.experiment argv`` with heurtune imported from ``tree``."""
    sys.meta_path.insert(0, _TreeFinder(tree))
    sys.path = [p for p in sys.path if Path(p or ".").resolve() != ROOT]
    os.chdir(tree)
    sys.argv = ["heurtune.experiment", *argv]
    runpy.run_module("heurtune.experiment", run_name="__main__", alter_sys=True)


def _smoke(tree: Path, name: str, out: Path) -> bool:
    """One experiment's smoke run from ``tree`` into ``out/name``; whether it succeeded."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--in-tree", str(tree), name, "--smoke", "--seed", "7",
           "--jobs", "1", "--no-figures", "--out", str(out / name)]
    with open(out / f"{name}.log", "w") as log:
        return subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env).returncode == 0


TEXT_SUFFIXES = (".md", ".csv", ".tex", ".txt", ".json", ".toml")


def compare(a: Path, b: Path) -> tuple[list[str], bool]:
    """Lines naming each result file that differs beyond its tolerance between two result
    folders (or is missing), and whether every file is the same bit for bit."""
    import pandas as pd

    from heurtune.analysis.agreement import frame_differences, text_differences

    out, same_bits = [], True
    for f in sorted(p for p in a.rglob("*") if p.is_file() and p.name not in RUN_RECORDS):
        g = b / f.relative_to(a)
        if not g.is_file():
            out.append(f"{f.relative_to(a)}: missing on the other side")
            continue
        if f.read_bytes() == g.read_bytes():
            continue
        if f.suffix == ".parquet":
            x, y = pd.read_parquet(f), pd.read_parquet(g)
            x = x.drop(columns=[c for c in x.columns if any(w in c for w in WALL_COLUMNS)])
            y = y.drop(columns=[c for c in y.columns if any(w in c for w in WALL_COLUMNS)])
            if x.equals(y):  # the same values in files written at other times
                continue
            lines = frame_differences(x, y)
        elif f.suffix in TEXT_SUFFIXES:
            lines = text_differences(f.read_text(), g.read_text())
        else:
            lines = ["the bytes differ"]
        same_bits = False
        out += [f"{f.relative_to(a)}: {line[:200]}" for line in lines]
    return out, same_bits


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("experiments", nargs="*", help="names (default: every shipped experiment)")
    ap.add_argument("--rev", required=True, help="the git revision to compare this working tree with")
    ap.add_argument("--out", help="folder for the two sides' results (default: a new temporary folder)")
    args = ap.parse_args(argv)

    out = Path(args.out or tempfile.mkdtemp(prefix="heurtune-smoke-"))
    out.mkdir(parents=True, exist_ok=True)
    worktree = out / "worktree"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(worktree), args.rev], check=True,
                   stdout=subprocess.DEVNULL)
    try:
        names = args.experiments
        if not names:
            from heurtune.runner.config import list_experiments

            names = list_experiments()
        sides = {"rev": (worktree, out / "rev"), "tree": (ROOT, out / "tree")}
        for _, folder in sides.values():
            folder.mkdir(exist_ok=True)
        failed, differ = [], []
        with concurrent.futures.ThreadPoolExecutor(2) as pool:
            for name in names:
                runs = {side: pool.submit(_smoke, tree, name, folder) for side, (tree, folder) in sides.items()}
                ok = {side: run.result() for side, run in runs.items()}
                if all(ok.values()):
                    lines, same_bits = compare(out / "rev" / name, out / "tree" / name)
                    differ += [f"{name}/{line}" for line in lines]
                    status = "differs" if lines else "same bits" if same_bits else "within tolerance"
                else:
                    failed += [f"{name} ({side}; see {sides[side][1] / name}.log)" for side in ok if not ok[side]]
                    status = "failed"
                print(f"{name}: {status}", flush=True)
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(worktree)], check=False)
    print(f"{len(names)} experiments at {args.rev} and in this tree: {len(failed)} failed, "
          f"{len(differ)} result files differ beyond their tolerances (results in {out})")
    for line in failed + differ:
        print("  " + line)
    return 1 if failed or differ else 0


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--in-tree":
        _run_in_tree(Path(sys.argv[2]), sys.argv[3:])
    else:
        sys.exit(main())
