"""Two versions of the continuous-time kernels, side by side in one process: the same loops,
checked bit for bit, then timed in alternating passes.

Machines differ and this project's machine drifts by tens of percent within an hour, so a
change to ``objectives/qtp/continuous_kernels.py`` is timed here against a reference version
of the same file, loaded as a second module in the same process, on the same candidates:

    python benchmarks/kernels_side_by_side.py --rev c15ae9f
    python benchmarks/kernels_side_by_side.py --reference old.py --candidate new.py

The candidates are random points of the problem's bounds whose linearised loop is stable
(``--experiment``, ``--case``, ``--candidates``), run under its nominal scenario without
records. The script fails (exit 1) when a metric, a status or a step count differs in any bit.
Each version compiles into a fresh numba cache (a module loaded from a path cannot be
reloaded from numba's cache), which takes a minute or two. BLAS is pinned to one thread.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
if "NUMBA_CACHE_DIR" not in os.environ:  # before numba is imported
    import tempfile

    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="heurtune-side-by-side-")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import heurtune  # noqa: E402
from heurtune.objectives.qtp import continuous as _continuous  # noqa: E402
from heurtune.objectives.qtp import kernels as _kernels  # noqa: E402
from heurtune.runner.machine import cpu_name  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KERNELS = "objectives/qtp/continuous_kernels.py"


def load_module(path: Path, name: str):
    """``path`` imported as a module of its own named ``name``."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def lane_inputs(experiment: str, case: str, n: int, seed: int) -> list:
    """Inputs of ``simulate_continuous`` (without the outputs) for the stable ones among ``n``
    random candidates of the problem's bounds."""
    prob = heurtune.load_experiment(experiment).problem(case)
    loop, sc = prob.loop, prob.scenario(prob.tuning_scenario)
    rng = np.random.default_rng(seed)
    X = prob.lower + (prob.upper - prob.lower) * rng.random((n, prob.dim))
    inputs = []
    for x in X:
        ctrl, reason, _ = prob._design(x)
        if ctrl is None:
            continue
        cc = _continuous.ContinuousController.from_linear(ctrl)
        plan = loop.step_plan(ctrl, sc, cc)
        inputs.append((loop._scenario_table(sc), loop._level_per_state, loop._state_op(), loop.op.h, cc.lam, cc.b,
                       cc.col, cc.Cm, cc.Aq, cc.Bq, cc.Cq, cc.D, cc.channel, plan.table, prob.settling_band))
    return inputs


def run(module, inputs):
    """Metrics, status and step count of one lane."""
    metrics = np.empty(_kernels.N_METRICS)
    status, steps = module.simulate_continuous(*inputs, metrics, 0.01, np.empty((0, 2)), np.empty((0, 2)),
                                               np.empty((0, 4)))
    return metrics, status, steps


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ref = ap.add_mutually_exclusive_group(required=True)
    ref.add_argument("--rev", help=f"git revision whose {KERNELS} is the reference")
    ref.add_argument("--reference", type=Path, help="path of the reference kernels file")
    ap.add_argument("--candidate", type=Path, default=ROOT / KERNELS, help="kernels file to time (default: the tree's)")
    ap.add_argument("--experiment", default="thesis_ch4")
    ap.add_argument("--case", default="min-folqi")
    ap.add_argument("--candidates", type=int, default=300, help="random candidates drawn (the stable ones run)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--passes", type=int, default=10, help="timed passes of each version, alternating")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        reference = args.reference
        if args.rev:
            reference = Path(tmp) / "reference_kernels.py"
            reference.write_text(subprocess.run(["git", "show", f"{args.rev}:{KERNELS}"], cwd=ROOT, check=True,
                                                capture_output=True, text=True).stdout)
        versions = [load_module(reference, "reference_kernels"), load_module(args.candidate, "candidate_kernels")]
        inputs = lane_inputs(args.experiment, args.case, args.candidates, args.seed)
        differ = 0
        for lane in inputs:
            (m0, s0, n0), (m1, s1, n1) = run(versions[0], lane), run(versions[1], lane)
            differ += not (np.array_equal(m0, m1, equal_nan=True) and s0 == s1 and n0 == n1)
        times = [[], []]
        for p in range(args.passes):
            for k in (0, 1) if p % 2 == 0 else (1, 0):
                t0 = time.perf_counter()
                for lane in inputs:
                    run(versions[k], lane)
                times[k].append((time.perf_counter() - t0) / len(inputs) * 1e3)
        ref_ms, new_ms = np.array(times[0]), np.array(times[1])
        print(f"{args.experiment} {args.case}: {len(inputs)} stable of {args.candidates} candidates, "
              f"{args.passes} passes each, one core of {cpu_name()}")
        print(f"  reference ({args.rev or reference.name})  median {np.median(ref_ms):.3f} ms per loop, "
              f"best pass {ref_ms.min():.3f}")
        print(f"  candidate ({args.candidate.name})  median {np.median(new_ms):.3f} ms per loop, "
              f"best pass {new_ms.min():.3f}")
        print(f"  candidate / reference, median of the passes' ratios: {np.median(new_ms / ref_ms):.3f}")
        print(f"  loops whose results differ in any bit: {differ} of {len(inputs)}")
        return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
