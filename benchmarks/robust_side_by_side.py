"""The nominal-tuned and the robust-tuned controllers side by side, from two results folders.

    python benchmarks/robust_side_by_side.py results/cs_folqi_qtp results/robust_cs_folqi_qtp

For each case and optimiser (fixed designs such as the GPM baseline left out), the best run of
each folder (heurtune.analysis.compare.best_runs) and its
re-evaluation under every scenario, as ``runs.parquet`` holds it (``<metric>@<scenario>``):
the objective, the constrained metrics, feasibility, and whether it is feasible in every
scenario. Prints a markdown table (the one in docs/robust.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from heurtune.analysis.runs import best_runs


def rows(folder: Path) -> list:
    runs = pd.read_parquet(folder / "runs.parquet")
    meta = json.loads((folder / "meta.json").read_text())
    problem = meta["config"].get("problem", {})
    tuned = ("worst of " + ", ".join(problem["tuning_scenarios"])) if "tuning_scenarios" in problem else \
        problem.get("tuning_scenario", "nominal")
    limits = problem.get("constraints", {})
    scenarios = [c[2:] for c in runs.columns if c.startswith("f@")]
    out = []
    tuned_runs = runs[runs["stop_reason"] != "analytic design"]
    for _, r in best_runs(tuned_runs).iterrows():
        feasible_all = all(bool(r[f"feasible@{s}"]) for s in scenarios)
        for s in scenarios:
            row = {"case": r["case"], "algorithm": r["algorithm"], "tuned for": tuned, "run": int(r["run"]),
                   "scenario": s, "f": r[f"f@{s}"]}
            for key in limits:  # the worst of the two loops, and the limit
                vals = [r.get(f"{key}{i}@{s}") for i in (1, 2)]
                row[f"{key} (<= {limits[key]:g})"] = max(v for v in vals if v is not None)
            row["feasible"] = bool(r[f"feasible@{s}"])
            row["feasible in all"] = feasible_all
            out.append(row)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+", help="results folders (e.g. the nominal and the robust experiment)")
    args = ap.parse_args(argv)
    table = pd.DataFrame([r for folder in args.folders for r in rows(Path(folder))])
    table["order"] = range(len(table))
    table = table.sort_values(["case", "order"], kind="stable").drop(columns="order")
    print(markdown(table))


def markdown(table: pd.DataFrame) -> str:
    """A markdown table, numbers to 4 significant digits."""
    def cell(v):
        if isinstance(v, (bool, str)):
            return str(v)
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
