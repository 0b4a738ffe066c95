"""How much each candidate objective varies over the feasible set of a QTP tuning problem.

Usage::

    python benchmarks/objective_spread.py EXPERIMENT [--feasible 10000] [--seed 1] [--jobs 2]

Draws candidates uniformly within the experiment's bounds until ``--feasible`` of them are
feasible (stable, simulated, constraints met under the tuning scenario), per case, and prints
for each objective the median and the 5th-95th percentile range relative to the median. An
objective whose feasible values lie within a few percent of each other cannot separate
optimisers: any feasible point is nearly optimal. Objectives: J (integral of u^2, the thesis'),
Jdev (integral of (u - u0)^2, thesis chapter 6), IAE, ISE, ITAE (both lower tanks), TV (total
variation of both pumps) and IAE + w Jdev with w the ratio of their medians (equal shares at
the median). docs/model.md quotes the output.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from joblib import Parallel, delayed  # noqa: E402

from heurtune.runner.config import load_experiment  # noqa: E402

OBJECTIVES = ("J", "Jdev", "IAE", "ISE", "ITAE", "TV")


def _batch(name: str, case: str, n: int, seed) -> pd.DataFrame:
    prob = load_experiment(name).problem(case)
    rng = np.random.default_rng(seed)
    X = rng.uniform(prob.lower, prob.upper, size=(n, prob.dim))
    ev = prob.evaluate(X)
    df = pd.DataFrame(ev.metrics, columns=list(ev.metric_names))[ev.feasible]
    return pd.DataFrame({m: df[f"{m}1"] + df[f"{m}2"] for m in OBJECTIVES}).assign(drawn=n)


def feasible_sample(name: str, case: str, want: int, seed: int, jobs: int, batch: int = 2000):
    """Metrics of at least ``want`` feasible candidates and the number drawn."""
    frames, drawn, k = [], 0, 0
    root = np.random.SeedSequence(seed)
    with Parallel(n_jobs=jobs) as pool:
        while sum(len(f) for f in frames) < want:
            seeds = root.spawn(jobs)
            out = pool(delayed(_batch)(name, case, batch, s) for s in seeds)
            frames += out
            drawn += batch * jobs
            k += 1
            if k > 50:
                break
    df = pd.concat(frames, ignore_index=True).drop(columns="drawn").head(want)
    return df, drawn


def spread_table(df: pd.DataFrame) -> pd.DataFrame:
    """Median and (p95 - p5) / median per objective column."""
    w = df["IAE"].median() / df["Jdev"].median()
    df = df.assign(**{"IAE+w*Jdev": df["IAE"] + w * df["Jdev"]})
    q = df.quantile([0.05, 0.5, 0.95])
    out = pd.DataFrame({"median": q.loc[0.5], "p5": q.loc[0.05], "p95": q.loc[0.95]})
    out["spread_%"] = 100.0 * (out["p95"] - out["p5"]) / out["median"]
    out.attrs["w"] = w
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("experiment")
    ap.add_argument("--feasible", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    exp = load_experiment(args.experiment)
    for case in exp.cases:
        df, drawn = feasible_sample(args.experiment, case, args.feasible, args.seed, args.jobs)
        table = spread_table(df)
        print(f"{args.experiment} / {case}: {len(df)} feasible of {drawn} drawn "
              f"(w = {table.attrs['w']:.4g})")
        with pd.option_context("display.float_format", "{:.4g}".format, "display.width", 160):
            print(table.to_string())
        print()


if __name__ == "__main__":
    main()
