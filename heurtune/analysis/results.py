"""A results folder as pandas objects: ``heurtune.load_results("results/cs_folqi_qtp")``.

The runner writes, per experiment folder (README, "Output files"): ``runs.parquet`` (one row
per case, optimiser and run), ``history.parquet`` (one row per run and epoch),
``summary.parquet`` (one row per case and optimiser), ``margins.parquet`` (the best designs'
stability margins, where the family has them) and ``meta.json`` (the config and what ran).
:func:`load_results` reads them into a :class:`Results`; the analysis functions
(:mod:`heurtune.analysis.compare`, :mod:`heurtune.analysis.anytime`) take its frames as they are.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pandas as pd

from heurtune.analysis.export import load_results as _load_frames
from heurtune.analysis.runs import best_runs
from heurtune.analysis.stats import summary_table

__all__ = ["Results", "load_results"]


@dataclasses.dataclass(frozen=True, eq=False)
class Results:
    """The files of one results folder.

    Attributes
    ----------
    path : pathlib.Path
    runs : pandas.DataFrame
        ``runs.parquet``: experiment, case, algorithm, controller, problem_id, run, seed,
        best_f, feasible, status (``feasible``, ``infeasible``, ``failed``), n_evals, the gains,
        and ``<metric>@<scenario>`` of the best gains per scenario.
    history : pandas.DataFrame
        ``history.parquet``: per run and epoch, n_evals, best_f, mean_f, sd_f, ...
    summary : pandas.DataFrame
        ``summary.parquet`` when the folder has it, else computed from ``runs``
        (:func:`heurtune.analysis.compare.summary_table`).
    margins : pandas.DataFrame or None
        ``margins.parquet`` (one row per best design and loop), None without one.
    meta : dict
        ``meta.json`` (``{}`` without one): the config under ``"config"``.
    """

    path: Path
    runs: pd.DataFrame
    history: pd.DataFrame
    summary: pd.DataFrame
    margins: pd.DataFrame | None
    meta: dict

    def best(self) -> pd.DataFrame:
        """The best run of each case and optimiser (lowest feasible ``best_f``, else the
        lowest violation), rows of :attr:`runs`."""
        return best_runs(self.runs)

    def successful(self) -> pd.DataFrame:
        """The rows of :attr:`runs` whose run found a stable, simulable candidate (``status``
        not ``failed``): the ones whose ``best_f`` may be averaged."""
        if "status" not in self.runs.columns:
            return self.runs
        return self.runs[self.runs.status != "failed"]


def load_results(path) -> Results:
    """Read a results folder (what ``python -m heurtune.experiment`` and
    :func:`heurtune.runner.experiment.run_experiment` write) into a :class:`Results`.

    Parameters
    ----------
    path : str or Path
        The results folder.

    Returns
    -------
    Results

    Raises
    ------
    FileNotFoundError
        When ``runs.parquet`` or ``history.parquet`` is missing.
    """
    d = Path(path)
    runs, history, meta = _load_frames(d)
    summary = pd.read_parquet(d / "summary.parquet") if (d / "summary.parquet").is_file() else summary_table(runs)
    margins = pd.read_parquet(d / "margins.parquet") if (d / "margins.parquet").is_file() else None
    return Results(d, runs, history, summary, margins, meta)
