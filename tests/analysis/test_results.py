"""heurtune.load_results: a results folder as DataFrames."""

from __future__ import annotations

import json

import pandas as pd
import pytest

import heurtune


def _folder(tmp_path, with_summary):
    runs = pd.DataFrame([dict(experiment="x", case="min", algorithm="cs", optimiser_index=0, run=r, best_f=f,
                              feasible=ok, violation=0.0 if ok else 1.0, status=st, n_evals=10)
                         for r, f, ok, st in [(0, 3.0, True, "feasible"), (1, 2.0, False, "infeasible"),
                                              (2, 1e10, False, "failed")]])
    runs.to_parquet(tmp_path / "runs.parquet")
    pd.DataFrame(dict(case=["min"], algorithm=["cs"], run=[0], epoch=[0], n_evals=[10], best_f=[3.0])).to_parquet(
        tmp_path / "history.parquet")
    if with_summary:
        pd.DataFrame(dict(case=["min"], algorithm=["cs"], median=[3.0])).to_parquet(tmp_path / "summary.parquet")
    (tmp_path / "meta.json").write_text(json.dumps({"config": {"name": "x"}}))
    return tmp_path


@pytest.mark.parametrize("with_summary", [True, False])
def test_load_results_reads_every_file(tmp_path, with_summary):
    res = heurtune.load_results(_folder(tmp_path, with_summary))
    assert len(res.runs) == 3 and len(res.history) == 1 and res.meta["config"]["name"] == "x"
    assert res.margins is None
    assert len(res.summary) == 1  # read, or computed from the runs
    assert list(res.best().run) == [0]  # the feasible run, not the lower infeasible one
    assert list(res.successful().run) == [0, 1]


def test_a_folder_without_runs_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="runs.parquet not found"):
        heurtune.load_results(tmp_path)
