"""``[controller] sample_time = 0.01`` reproduces the release before the continuous-time loop
became the default, on every shipped QTP experiment's smoke run.

``sampled_release_smoke.json`` holds the ``runs.parquet`` of each shipped QTP experiment run at
commit e1bb82f (where the QTP configs said ``[scenario] dt = 0.01``, the sampled loop) as
``python -m heurtune.experiment NAME --smoke --seed 7 --jobs 1 --no-figures``; everything but
the wall time. The test reruns each with ``sample_time = 0.01`` and compares field by field
within the tolerances of the shipped numbers (docs/testing.md,
:mod:`heurtune.analysis.agreement`): the problem
ids, statuses, evaluation counts, seeds and texts exactly (the resolved settings may hold
settings added since, such as PSO's ``bounds``, at their defaults); objectives, integral metrics
and gains to 1e-9 relative; levels, overshoots and steady-state errors absolute (ess, a
difference of nearly equal levels, to 1e-10 % of the level); settling times to 1e-8 s; pump
voltages to 1e-8 V. The file was written on another CPU by an earlier release, so bits are not
the contract (other BLAS kernels and vector widths round otherwise): measured on the Intel Xeon
of 2026-12-06 the largest differences were 3.6e-12 % on ess, 1.9e-12 relative on TV and below
3e-13 relative on everything else; an AMD EPYC with AVX2 only (2026-12-04) gave 1.7e-9 relative
on umin of an nmp LQI (about 5e-9 V), whose augmented Riccati equation has condition numbers
up to 5e7 (tests/objectives/qtp/test_design_kernels.py), so the last bits of its gains move
the metrics most.

Such a difference in the last bits of an evaluation moves a finite-difference gradient by about
1e-8 relative, and an optimiser stepping along those gradients (SQP, Newton-Raphson, DFP, steepest
descent, BFGS) takes another path from there, to another best candidate. A run of one of those
that does not reproduce is checked instead by evaluating the release's best candidate again: its
metrics in every scenario must be the release's, within the same margins, and the fields that do
not depend on the path (problem id, seeds, settings) equal. On the machine that wrote the file
no such run needs it.

Rewrite the file (only on purpose: it pins a past release) with
``python tests/runner/test_sampled_release.py write ROOT``, ROOT holding one result folder per
experiment made by the earlier release.
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from qtp_cases import sampled_experiment

from heurtune.analysis.agreement import field_tolerance, values_agree

REFERENCE = Path(__file__).with_name("sampled_release_smoke.json")
SKIPPED_COLUMNS = ("wall_time_s",)
KEY = ["case", "algorithm", "run"]
# Optimisers whose steps follow finite-difference gradients (see the module docstring).
FINITE_DIFFERENCE = frozenset({"sqp_multistart", "newton_raphson", "dfp", "steepest_descent", "bfgs"})
# The fields of a run that its optimiser's path decides (the best candidate, its value, the counts).
PATH_FIELDS = ("best_f", "feasible", "violation", "status", "failure", "n_evals", "n_epochs", "convergence_epoch",
               "convergence_evals", "stop_reason")


def records(runs: pd.DataFrame) -> list[dict]:
    """The rows of a runs.parquet as JSON-ready dicts, ordered by case, algorithm and run."""
    runs = runs.drop(columns=[c for c in SKIPPED_COLUMNS if c in runs]).sort_values(KEY)
    out = []
    for row in runs.to_dict("records"):
        out.append({k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()})
    return out


def _reference() -> dict:
    return json.loads(REFERENCE.read_text())


def _same_settings(expected: str, got: str) -> bool:
    """The resolved optimiser settings (JSON): equal, but for settings added since the
    release (a key only in ``got``, at its default)."""
    e, g = json.loads(expected), json.loads(got)
    return all(k in g and g[k] == v for k, v in e.items())


def _same(a, b, exact: bool, key: str = "") -> bool:
    if not exact:
        return values_agree(a, b, key)
    # same bits: two records of one release, one machine, one seed (NaN is NaN)
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def differences(expected: list[dict], got: list[dict], exact: bool = False) -> list[str]:
    """Where two lists of records differ: one line per differing field, or per missing run.
    Runs of optimisers appended to a config since (a new ``optimiser_index``) are left out."""
    pairs = _paired(expected, got)
    if isinstance(pairs, str):
        return [pairs]
    return [line for e, g in pairs for line in _row_differences(e, g, exact)]


def _paired(expected: list[dict], got: list[dict]):
    """The runs of both lists side by side, or a line saying why they cannot be."""
    known = {r["optimiser_index"] for r in expected}
    got = [r for r in got if r["optimiser_index"] in known]
    if len(expected) != len(got):
        return f"{len(got)} runs, expected {len(expected)}"
    return list(zip(expected, got))


def _row_differences(e: dict, g: dict, exact: bool, keys=None) -> list[str]:
    """One line per field (of ``keys``, default all) in which run ``g`` differs from ``e``."""
    where = "/".join(str(e.get(k)) for k in KEY)
    out = []
    for key in sorted(set(e) | set(g)) if keys is None else keys:
        if key == "settings" and isinstance(e.get(key), str) and isinstance(g.get(key), str):
            if not _same_settings(e[key], g[key]):
                out.append(f"{where}: settings = {g[key]!r}, expected {e[key]!r}")
            continue
        if not _same(e.get(key), g.get(key), exact, key):
            out.append(f"{where}: {key} = {g.get(key)!r}, expected {e.get(key)!r}")
    return out


def _reevaluated(e: dict, g: dict, experiment) -> list[str]:
    """A finite-difference run that took another path (see the module docstring): how the
    release's best candidate, evaluated again, differs from the release's run ``e`` in its
    metrics per scenario; and how the rerun ``g`` differs from ``e`` in the fields that do not
    depend on the path."""
    prob = experiment.problem(e["case"])
    with warnings.catch_warnings():  # the experiment's structure warnings, said when it ran
        warnings.simplefilter("ignore")
        table = prob.report(np.array([e[name] for name in prob.names]))
    again = {f"{key}@{scenario}": value for scenario, values in table.iterrows() for key, value in values.items()}
    again = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in again.items()}
    where = "/".join(str(e.get(k)) for k in KEY)
    out = [f"{where} (its best candidate again): " + line.split(": ", 1)[1]
           for line in _row_differences(e, again, exact=False, keys=sorted(again))]
    fixed = sorted(k for k in set(e) | set(g) if "@" not in k and k not in PATH_FIELDS and k not in prob.names)
    return out + _row_differences(e, g, exact=False, keys=fixed)


EXPERIMENTS = sorted(_reference()["experiments"]) if REFERENCE.exists() else []
# Experiments that only rename another (same problem, optimisers and seeds, fewer full runs):
# their smoke runs are the other's, problem ids included, so the rerun of the other pins both.
SAME_SMOKE_AS = {"thesis_heuristics": "thesis_ch5"}
RERUN = [name for name in EXPERIMENTS if name not in SAME_SMOKE_AS]
# Shipped after the pinned release with controller types it did not have (pid, fopid, pi2dof, the
# example plugin's): they have no earlier numbers to keep.
NEWER_THAN_THE_RELEASE = ("cs_fopid_qtp", "cs_pid_qtp", "example_plugin_controller", "pi2dof_qtp")
RELEASED_TYPES = {"folqi", "iolqi", "ladr", "lqi"}


def test_every_shipped_qtp_experiment_is_pinned():
    """Every shipped QTP experiment of the release's controller types is pinned; the others use
    only types the release did not have."""
    import heurtune
    from heurtune.runner.config import list_experiments

    qtp = sorted(name for name in list_experiments() if heurtune.load_experiment(name).family == "qtp")
    assert sorted(set(qtp) - set(NEWER_THAN_THE_RELEASE)) == EXPERIMENTS
    for name in NEWER_THAN_THE_RELEASE:
        assert name in qtp and not set(heurtune.load_experiment(name).controllers) & RELEASED_TYPES, name


def test_the_comparison_holds_each_field_to_its_tolerance():
    """Moves within a field's tolerance pass, larger ones and any change of an id or a count
    are named."""
    base = {"case": "min", "algorithm": "cs", "run": 0, "optimiser_index": 0, "problem_id": "abc", "n_evals": 30,
            "J@nominal": 4283.77, "ess1@nominal": 2.4, "ts2@nominal": 55.5, "umin@nominal": -3.0, "Q11": 1.5}
    assert field_tolerance("J@nominal") == (1e-9, 0.0) and field_tolerance("ess1@+30%") == (0.0, 1e-10)
    assert field_tolerance("ts2@nominal") == (0.0, 1e-8) and field_tolerance("umax") == (0.0, 1e-8)
    inside = dict(base, **{"J@nominal": 4283.77 * (1 + 5e-10), "ess1@nominal": 2.4 + 5e-11,
                           "ts2@nominal": 55.5 + 5e-9, "umin@nominal": -3.0 + 5e-9, "Q11": 1.5 * (1 - 5e-10)})
    assert not differences([base], [inside])
    assert differences([base], [inside], exact=True)
    for key, value in [("J@nominal", 4283.77 * (1 + 2e-9)), ("ess1@nominal", 2.4 + 2e-10), ("Q11", 1.5 * (1 + 2e-9)),
                       ("umin@nominal", -3.0 + 2e-8), ("problem_id", "abd"), ("n_evals", 31)]:
        assert [line.split(": ")[1].split(" =")[0] for line in differences([base], [dict(base, **{key: value})])] \
            == [key], key


@pytest.mark.parametrize("alias, name", sorted(SAME_SMOKE_AS.items()))
def test_a_renamed_experiment_has_the_smoke_runs_of_the_one_it_renames(alias, name):
    """Its config differs from the other's only in name, description and full run count, and
    the release's smoke runs of the two are equal in every field but the experiment's name."""
    from heurtune.runner.config import load_config

    a, b = load_config(alias), load_config(name)
    ignored = {"name", "description", "runs", "extends", "source"}
    assert {k: v for k, v in a.items() if k not in ignored} == {k: v for k, v in b.items() if k not in ignored}
    ref = _reference()["experiments"]
    assert not differences(ref[name], [dict(r, experiment=name) for r in ref[alias]], exact=True)


@pytest.mark.long
@pytest.mark.parametrize("name", RERUN)
def test_sample_time_reproduces_the_sampled_release(tmp_path, name):
    from heurtune.runner.experiment import run

    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(f'extends = "{name}"\n[controller]\nsample_time = 0.01\n')
    out = tmp_path / "out"
    # one worker, as the reference was written (under make test the other core runs the other
    # pytest worker; a pool of two would only add its start-up)
    assert run([str(cfg), "--smoke", "--seed", "7", "--jobs", "1", "--no-figures", "--out", str(out)]) == 0
    got = records(pd.read_parquet(out / "runs.parquet"))
    for row in got:  # the config file's name is the experiment's
        row["experiment"] = name
    pairs = _paired(_reference()["experiments"][name], got)
    assert not isinstance(pairs, str), pairs
    diff = []
    for e, g in pairs:
        lines = _row_differences(e, g, exact=False)
        if lines and e["algorithm"] in FINITE_DIFFERENCE:
            lines = _reevaluated(e, g, sampled_experiment(name, tmp_path))
        diff += lines
    assert not diff, "\n".join(diff[:10])


def _write(root: Path) -> None:
    data = {"made_by": "heurtune e1bb82f: python -m heurtune.experiment NAME --smoke --seed 7 --jobs 1 "
                       "--no-figures (the sampled loop, [scenario] dt = 0.01)",
            "experiments": {}}
    for folder in sorted(p for p in root.iterdir() if (p / "runs.parquet").exists()):
        data["experiments"][folder.name] = records(pd.read_parquet(folder / "runs.parquet"))
    REFERENCE.write_text(json.dumps(data, sort_keys=True, separators=(",", ":")) + "\n")


def _compare(root: Path) -> int:
    """The result folders under ``root`` against the reference, within the tolerances; each
    experiment's line says whether it is within them and whether it is bit for bit. 0 when all
    are within."""
    failed = 0
    for name, expected in _reference()["experiments"].items():
        got = records(pd.read_parquet(root / name / "runs.parquet"))
        for row in got:
            row["experiment"] = name
        diff = differences(expected, got)
        failed += bool(diff)
        same = not differences(expected, got, exact=True)
        print(f"{name}: {diff[0] if diff else 'bit for bit' if same else 'within the tolerances'}")
    return int(failed > 0)


if __name__ == "__main__":
    if sys.argv[1:2] == ["write"]:
        _write(Path(sys.argv[2]))
    else:
        sys.exit(_compare(Path(sys.argv[2])))
