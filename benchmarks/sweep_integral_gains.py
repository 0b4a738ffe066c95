"""Where integral action works: stability and feasibility of random candidates per decade of
the integral gains (Ki of IOLQI, integral weights Qi of LQI), on the nonlinear QTP.

Usage::

    python benchmarks/sweep_integral_gains.py [--samples 3000] [--seed 1]

For each (plant case, controller, pairing) the script draws candidates with Q, R uniform in the
thesis bounds and the integral variables log-uniform over ``[1e-4, 10]`` (Qi: ``[1e-6, 10]``),
evaluates them with the chapter 5 problem (1 cm disturbance at 50 s, Mp < 10 %, ts < 70 s in a
3 % band, ess < 1 %, nominal plant) and prints, per decade of the larger integral variable, the
share of candidates whose loop is stable and the share that is feasible. docs/model.md quotes
its output; the shipped bounds of the paired IOLQI and the LQI come from it.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from heurtune.objectives.qtp.family import DEFAULT_CONSTRAINTS  # noqa: E402
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario  # noqa: E402
from heurtune.objectives.qtp.model import preset  # noqa: E402
from heurtune.objectives.qtp.problem import Problem  # noqa: E402
from heurtune.objectives.qtp.structures import decision_names, default_bounds  # noqa: E402

SETUPS = (
    ("min", "iolqi", "diagonal"),
    ("nmp", "iolqi", "anti-diagonal"),
    ("min", "lqi", "diagonal"),
    ("nmp", "lqi", "diagonal"),
)
RANGES = {"Ki": (1e-4, 10.0), "Qi": (1e-6, 10.0)}


def sweep(case: str, kind: str, pairing: str, samples: int, rng) -> pd.DataFrame:
    """One row per candidate: the larger integral variable, stable, feasible."""
    loop = ClosedLoop(preset(case), kind, pairing=pairing)
    names = decision_names(kind)
    bounds = default_bounds(kind)
    integral = [n for n in names if n.startswith(("Ki", "Qi"))]
    lo_i, hi_i = RANGES[integral[0][:2]]
    lower = np.array([lo_i if n in integral else bounds[n][0] for n in names])
    upper = np.array([hi_i if n in integral else bounds[n][1] for n in names])
    sc = Scenario(horizon=350.0, output_disturbance=(1.0, 1.0), disturbance_time=50.0)
    prob = Problem(case, loop, names, lower, upper, objective="effort", constraints=DEFAULT_CONSTRAINTS,
                   settling_band=3.0, scenarios={"nominal": sc}, tuning_scenario="nominal")
    X = rng.uniform(lower, upper, size=(samples, len(names)))
    idx = [names.index(n) for n in integral]
    X[:, idx] = np.exp(rng.uniform(np.log(lo_i), np.log(hi_i), size=(samples, len(idx))))
    ev = prob.evaluate(X)
    return pd.DataFrame({"case": case, "controller": kind, "pairing": pairing,
                         "integral_max": X[:, idx].max(axis=1),
                         "stable": ev.reason != "unstable", "simulated": ev.reason == "",
                         "feasible": ev.feasible})


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    frames = [sweep(*setup, args.samples, rng) for setup in SETUPS]
    df = pd.concat(frames, ignore_index=True)
    df["decade"] = np.floor(np.log10(df["integral_max"])).astype(int)
    table = (df.groupby(["case", "controller", "pairing", "decade"])
             .agg(n=("stable", "size"), stable=("stable", "mean"), feasible=("feasible", "mean")))
    table[["stable", "feasible"]] *= 100.0
    with pd.option_context("display.float_format", "{:.1f}".format, "display.width", 160):
        print(table.to_string())
        print()
        print(df.groupby(["case", "controller", "pairing"])[["stable", "feasible"]].mean().mul(100).to_string())


if __name__ == "__main__":
    main()
