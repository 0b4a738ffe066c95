"""Where PID and FOPID work on the QTP: stability and feasibility per decade of each gain.

Usage::

    python benchmarks/sweep_pid_gains.py [--structure pid|fopid] [--samples 1500] [--seed 1]

For each plant case the script draws candidates with every gain log-uniform over a wide range
(Kp in [1e-2, 1e2] V/cm, Ki in [1e-4, 10] V/(cm s), Kd in [1e-3, 1e2] V s/cm for PID and
[1e-4, 10] for FOPID; FOPID's lambda uniform in [0.1, 2] and mu in [0.1, 0.9]), evaluates them
with ``benchmark_qtp``'s problem (pairing by the sign of det G(0), pumps and tanks at their
physical limits, IAE, Mp < 10 %, ts < 70 s, ess < 1 %, nominal plant) and prints, per decade
of each gain, the share of candidates whose loop is stable, the share that is feasible and the
median IAE of the feasible ones. The default bounds of the ``pid`` and ``fopid`` structures
(:mod:`heurtune.objectives.qtp.structures`) come from it; docs/model.md ("PID and FOPID") quotes its output.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

import heurtune  # noqa: E402

RANGES = {
    "pid": {"Kp": (1e-2, 1e2), "Ki": (1e-4, 10.0), "Kd": (1e-3, 1e2)},
    "fopid": {"Kp": (1e-2, 1e2), "Ki": (1e-4, 10.0), "Kd": (1e-4, 10.0), "lambda": (0.1, 2.0), "mu": (0.1, 0.9)},
}
LINEAR = ("lambda", "mu")  # drawn uniformly, the gains log-uniformly


def problem(structure: str, case: str):
    """``benchmark_qtp``'s problem for ``case`` under ``structure``, its bounds the sweep's ranges."""
    bounds = "\n".join(f"{g}{i} = [{lo!r}, {hi!r}]" for g, (lo, hi) in RANGES[structure].items() for i in (1, 2))
    text = (f'extends = "benchmark_qtp"\n[plant]\ncases = ["{case}"]\n[controller]\ntype = "{structure}"\n'
            f"[problem.bounds]\n{bounds}\n")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"sweep_{structure}.toml"
        path.write_text(text)
        return heurtune.load_experiment(str(path)).problem(case)


def draw(prob, structure: str, n: int, rng) -> np.ndarray:
    """``n`` candidates: the gains log-uniform, lambda and mu uniform, over the sweep's ranges."""
    cols = []
    for name in prob.names:
        lo, hi = RANGES[structure][name[:-1]]
        u = rng.random(n)
        cols.append(lo + (hi - lo) * u if name[:-1] in LINEAR else lo * (hi / lo) ** u)
    return np.column_stack(cols)


def sweep(structure: str, case: str, samples: int, seed: int) -> pd.DataFrame:
    prob = problem(structure, case)
    X = draw(prob, structure, samples, np.random.default_rng(seed))
    ev = prob.evaluate(X)
    df = pd.DataFrame(X, columns=list(prob.names))
    df["stable"] = ev.reason != "unstable"
    df["simulated"] = ev.reason == ""
    df["feasible"] = ev.feasible
    df["iae"] = np.where(ev.feasible, ev.f, np.nan)
    return df


def per_decade(df: pd.DataFrame, structure: str) -> pd.DataFrame:
    """Per gain and decade of the larger of its two loops' values: shares and median IAE."""
    rows = []
    for gain, (lo, hi) in RANGES[structure].items():
        if gain in LINEAR:
            continue
        top = np.maximum(df[f"{gain}1"], df[f"{gain}2"])
        edges = 10.0 ** np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
        for a, b in zip(edges[:-1], edges[1:]):
            sel = (top >= a) & (top < b)
            if sel.sum() == 0:
                continue
            rows.append(dict(gain=gain, decade=f"[{a:g}, {b:g})", n=int(sel.sum()),
                             stable=df.stable[sel].mean(), feasible=df.feasible[sel].mean(),
                             median_iae=df.iae[sel].median()))
    return pd.DataFrame(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--structure", choices=tuple(RANGES), default="pid")
    ap.add_argument("--samples", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", nargs="+", default=["min", "nmp"])
    args = ap.parse_args(argv)
    for case in args.cases:
        df = sweep(args.structure, case, args.samples, args.seed)
        print(f"\n{args.structure} on {case}: {len(df)} candidates, {df.stable.mean():.1%} stable, "
              f"{df.feasible.mean():.1%} feasible")
        feasible = df[df.feasible]
        if len(feasible):
            print("feasible range per gain (min / 5 % / 95 % / max):")
            for name in df.columns[:-4]:
                q = feasible[name].quantile([0.0, 0.05, 0.95, 1.0]).to_numpy()
                print(f"  {name:8s} {q[0]:.3g} / {q[1]:.3g} / {q[2]:.3g} / {q[3]:.3g}")
        print(per_decade(df, args.structure).to_string(index=False, float_format=lambda v: f"{v:.3g}"))


if __name__ == "__main__":
    main()
