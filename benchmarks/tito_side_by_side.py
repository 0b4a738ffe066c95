"""The suite's TITO problems at another revision and in this working tree: time per evaluation
and whether the results are the same bits.

    python benchmarks/tito_side_by_side.py --rev HEAD~1 [--candidates 24] [--repeats 3]

For each TITO row of ``experiments/suite/problems.toml`` (instance 2, a perturbed plant) the
script draws ``--candidates`` uniform candidates in the row's box and evaluates them with
``Problem.evaluate`` in each tree, one process per tree and BLAS on one thread, as
``smoke_side_by_side.py`` imports a tree (its ``_TreeFinder``: every heurtune package from that
tree). Per row: milliseconds per evaluation (the best of ``--repeats`` batches, after one batch
that loads the kernels), the revision's time over the tree's, and whether objective, constraints
and metrics are the same bits (else the largest relative difference).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def measure(candidates: int, repeats: int, out: Path) -> None:
    """In the tree this process imports: time and results of every TITO row, to ``out``."""
    import time
    import warnings

    import numpy as np

    from heurtune.core.families import make_experiment
    from heurtune.runner import suite as S
    from heurtune.runner.config import load_config

    warnings.simplefilter("ignore")
    suite = S.load_suite(ROOT / "experiments" / "suite" / "problems.toml")
    rows, arrays = {}, {}
    for p in suite.problems:
        if p.group != "tito":
            continue
        with tempfile.TemporaryDirectory() as tmp:
            path = S.problem_config(suite, p, "random_search", [2], 1.0, 1, Path(tmp) / "row.toml")
            prob = make_experiment(load_config(str(path))).problem("i2")
        X = prob.lower + np.random.default_rng(5).random((candidates, prob.dim)) * (prob.upper - prob.lower)
        prob.evaluate(X[:2])
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            ev = prob.evaluate(X)
            best = min(best, time.perf_counter() - t0)
        rows[p.name] = 1e3 * best / candidates
        arrays[p.name] = np.column_stack([ev.f, ev.g, ev.metrics])
    np.savez(out.with_suffix(".npz"), **arrays)
    out.write_text(json.dumps(rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rev", required=True, help="the revision to compare with")
    ap.add_argument("--candidates", type=int, default=24)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--in-tree", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.in_tree:  # the child: import heurtune from that tree, then measure
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from smoke_side_by_side import _TreeFinder

        sys.meta_path.insert(0, _TreeFinder(Path(args.in_tree)))
        measure(args.candidates, args.repeats, Path(args.out))
        return 0
    import numpy as np

    from heurtune.runner.machine import cpu_name

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        worktree = tmp / "worktree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(worktree), args.rev],
                       check=True, capture_output=True)
        try:
            results = {}
            for side, tree in (("rev", worktree), ("tree", ROOT)):
                out = tmp / f"{side}.json"
                subprocess.run([sys.executable, __file__, "--rev", args.rev, "--in-tree", str(tree), "--out", str(out),
                                "--candidates", str(args.candidates), "--repeats", str(args.repeats)],
                               check=True, env=env, cwd=tree)
                results[side] = (json.loads(out.read_text()), np.load(out.with_suffix(".npz")))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(worktree)], check=False)
        print(f"TITO rows of the suite, {args.candidates} candidates each; {cpu_name()}, BLAS one thread")
        print(f"{'problem':16} {args.rev + ' ms':>12} {'tree ms':>9} {'ratio':>7}  results")
        (t_rev, a_rev), (t_tree, a_tree) = results["rev"], results["tree"]
        for name in t_tree:
            a, b = a_rev[name], a_tree[name]
            same = a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))
            scale = np.maximum(np.abs(a), 1e-300)
            with np.errstate(invalid="ignore"):  # inf - inf where both are inf (a metric of an unstable loop)
                rel = np.where(a == b, 0.0, np.abs(a - b) / scale)
            diff = "same bits" if same else f"differ, {np.nanmax(rel):.1e} relative"
            print(f"{name:16} {t_rev[name]:12.2f} {t_tree[name]:9.2f} {t_rev[name] / t_tree[name]:6.2f}x  {diff}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
