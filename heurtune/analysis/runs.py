"""Results as data: loading experiment folders, classifying runs, choosing best runs.

The first step of every comparison (:mod:`heurtune.analysis.compare`), report and export: read
``runs.parquet`` (and ``margins.parquet``, ``history.parquet``) of one or more experiment folders
into one frame, refuse what cannot be compared (mixed problem ids, duplicated runs, a folder given
twice), label variants, tell failed and infeasible runs from successful ones, and pick each
algorithm's best run and its re-evaluation per scenario.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.core.errors import ConfigError
from heurtune.core.problem import FAILED_OBJECTIVE

__all__ = [
    "check_metric", "REEVALUATION_COLUMNS", "REQUIRED_COLUMNS", "MARGIN_KEY_COLUMNS",
    "experiment_folder", "load_runs", "load_margins", "load_histories", "margins_table",
    "failed_runs", "successful_runs", "best_runs", "best_run_index", "reevaluation_table",
]


REEVALUATION_COLUMNS = ("Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2", "J1", "J2", "J")


REQUIRED_COLUMNS = ("experiment", "case", "algorithm", "problem_id", "run")


MARGIN_KEY_COLUMNS = ("experiment", "case", "algorithm", "input", "output", "gain_crossover_rad_s",
                      "phase_margin_deg")


_KEY = ["experiment", "case", "algorithm", "run"]


def _read_one(d) -> pd.DataFrame:
    path = Path(d)
    file = path if path.suffix == ".parquet" and not path.is_dir() else path / "runs.parquet"
    if not file.is_file():
        raise ConfigError(f"{d}: no runs.parquet found")
    try:
        df = pd.read_parquet(file)
    except Exception as exc:  # corrupt or foreign file: report it on one line
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"{file}: cannot be read as parquet ({first})") from exc
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise ConfigError(f"{file}: missing column(s) {', '.join(missing)}")
    return df


def experiment_folder(d) -> Path:
    """The experiment folder that ``d`` stands for.

    Parameters
    ----------
    d : str or Path
        A folder, or a ``.parquet`` file in it.

    Returns
    -------
    Path
    """
    path = Path(d)
    return path.parent if path.suffix == ".parquet" and not path.is_dir() else path


def _source_key(d) -> str:
    """Resolved folder path of ``d``: the identity of a variant across load_runs/load_margins."""
    return str(experiment_folder(d).resolve())


def _variant_labels(dirs, labels) -> tuple[list[str], set[str]]:
    """Label of each folder in ``dirs`` and the set of labels the caller gave explicitly.

    Explicit labels (``labels``: label -> folder) are validated; the other folders are
    labelled by their name, extended by parent folders (``seed1/exp``) where names clash.
    """
    keys = [_source_key(d) for d in dirs]
    seen = {}
    for d, key in zip(dirs, keys):
        if key in seen:
            raise ConfigError(f"the same folder is given twice: {seen[key]} and {d}")
        seen[key] = d
    given = {}
    for name, d in (labels or {}).items():
        name = str(name)
        if not name.strip() or "[" in name or "]" in name:
            raise ConfigError(f"label '{name}' for {d} must be non-empty and free of '[' and ']'")
        key = _source_key(d)
        if key not in seen:
            raise ConfigError(f"label '{name}': {d} is not among the folders compared")
        if key in given:
            raise ConfigError(f"folder {d} has two labels: '{given[key]}' and '{name}'")
        given[key] = name
    if len(set(given.values())) < len(given):  # only reachable with str()-equal keys
        raise ConfigError("two labels are the same after conversion to text")
    out = [given.get(key) for key in keys]
    depth = {i: 1 for i, lab in enumerate(out) if lab is None}
    while depth:
        for i, k in depth.items():
            parts = Path(keys[i]).parts
            out[i] = "/".join(parts[-k:]) if len(parts) > 1 else keys[i]
        clash = {i for i in depth if out[i] in given.values()
                 or sum(out[j] == out[i] for j in range(len(out))) > 1}
        grow = {i for i in clash if depth[i] < len(Path(keys[i]).parts) - 1}
        if clash and not grow:
            i = min(clash)
            raise ConfigError(f"cannot label {dirs[i]} by its folder name ('{out[i]}' is taken); "
                              f"name it with --label NAME=DIR")
        depth = {i: depth[i] + 1 for i in grow}
    return out, set(given.values())


# The axes a comparison can be made along: the optimiser (the default) or the controller structure.
AXES = ("algorithm", "controller")
# The config keys two folders compared by controller may differ in (everything else, the plant,
# the scenarios, the objective and constraints, must be the same problem).
_STRUCTURE_KEYS = ("controller", "optimisers", "name", "source", "description", "runs", "seed", "plugins",
                   "baselines")


def _flat(d, prefix="") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


def _problem_config(folder) -> dict | None:
    """A folder's config without what a structure comparison varies (None without meta.json)."""
    import json

    meta = experiment_folder(folder) / "meta.json"
    if not meta.is_file():
        return None
    config = dict(json.loads(meta.read_text(encoding="utf-8")).get("config", {}))
    for key in _STRUCTURE_KEYS:
        config.pop(key, None)
    problem = dict(config.get("problem", {}))
    problem.pop("bounds", None)
    config["problem"] = problem
    plant = dict(config.get("plant", {}))
    plant.pop("cases", None)
    config["plant"] = plant
    return _flat(config)


def _by_controller(runs: pd.DataFrame, dirs) -> pd.DataFrame:
    """Runs relabelled for a comparison of controller structures: ``algorithm`` the structure
    (``"pid [cs]"`` where a case holds it under several optimisers), ``case`` the plant case (a
    config with ``type = [...]`` names its cases ``<plant case>-<type>``), ``optimiser`` the
    optimiser; the folders must pose the same problem but for the controller."""
    if "controller" not in runs.columns:
        raise ConfigError("--by controller: runs.parquet has no 'controller' column (results of an older heurtune); "
                          "compare them by algorithm")
    configs = {str(d): _problem_config(d) for d in dirs}
    known = {d: c for d, c in configs.items() if c is not None}
    if len(known) > 1:
        (d0, c0), *rest = known.items()
        for d, c in rest:
            differ = sorted(k for k in set(c0) | set(c) if c0.get(k) != c.get(k))
            if differ:
                raise ConfigError(f"--by controller: {d} and {d0} pose different problems, not only other "
                                  f"controllers: they differ in {', '.join(differ[:5])}"
                                  + (f" and {len(differ) - 5} more" if len(differ) > 5 else ""))
    out = runs.copy()
    kind = out["controller"].astype(str)
    out["case"] = [c[:-len(k) - 1] if c.endswith("-" + k) else c for c, k in zip(out["case"], kind)]
    out["optimiser"] = out["algorithm"]
    several = out.groupby(["case", "controller"])["optimiser"].transform("nunique") > 1
    out["algorithm"] = np.where(several, kind + " [" + out["optimiser"] + "]", kind)
    out.attrs["compared_by"] = "controller"
    return out


def load_runs(dirs, *, labels: dict | None = None, by: str = "algorithm") -> pd.DataFrame:
    """Read and merge the ``runs.parquet`` files of experiment output folders.

    Every folder is a *variant*: folders of the same experiment run with other settings or
    seeds are compared side by side instead of being refused.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders, each containing ``runs.parquet`` (a path to a ``.parquet``
        file is accepted as well and stands for its folder).
    labels : dict, optional
        Variant label -> folder (one of ``dirs``). A folder without a label here is labelled by
        its name, or by its name with as many parent folders as needed to tell it apart from
        the others (``seed1/exp``).
    by : {"algorithm", "controller"}
        The axis compared. ``"controller"``: the controller structures are the treatments
        (``algorithm`` holds the structure, ``optimiser`` the optimiser), a case is the plant
        case, and the folders must pose the same problem but for the controller and its bounds
        (their ``meta.json`` configs are compared); runs of different structures then have
        different problem ids, which the comparison allows.

    Returns
    -------
    pandas.DataFrame
        All rows, in folder order, with a fresh index. ``experiment``, ``case``,
        ``algorithm`` and ``problem_id`` are strings and ``run`` is an integer. If one
        algorithm name of a case comes from several folders, its rows are relabelled: by
        experiment, ``"name [experiment]"``, when the experiment names tell the folders apart
        and none of them has an explicit label; otherwise by variant, ``"name [label]"``.
        ``attrs["algorithm_labels"]`` maps (resolved folder, experiment, case, algorithm) to
        the label used, so that :func:`load_margins` can follow it.

    Raises
    ------
    ConfigError
        No folder given; the same folder given twice (after resolving the paths); a label
        that is empty, names a folder not in ``dirs`` or gives a folder a second label; a
        folder without ``runs.parquet``; a file missing the columns ``experiment, case,
        algorithm, problem_id, run``; a case whose rows have different ``problem_id`` (not
        comparable); a run (experiment, case, algorithm, run) present more than once in one
        folder.
    """
    dirs = list(dirs)
    if not dirs:
        raise ConfigError("no experiment directories given")
    if by not in AXES:
        raise ConfigError(f"--by: unknown axis {by!r}; allowed: {', '.join(AXES)}")
    names, explicit = _variant_labels(dirs, labels)
    frames, sources, keys, variants = [], [], [], []
    for d, name in zip(dirs, names):
        df = _read_one(d)
        frames.append(df)
        sources.extend([str(d)] * len(df))
        keys.extend([_source_key(d)] * len(df))
        variants.extend([name] * len(df))
    runs = pd.concat(frames, ignore_index=True, sort=False)
    for col in ("experiment", "case", "algorithm", "problem_id"):
        runs[col] = runs[col].astype(str)
    try:
        runs["run"] = runs["run"].astype(int)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"column 'run' must hold integers ({exc})") from exc
    source = pd.Series(sources, index=runs.index)
    key = pd.Series(keys, index=runs.index)
    variant = pd.Series(variants, index=runs.index)
    # the case and algorithm each file names: histories and margins are found by them
    file_case, file_algorithm = runs["case"].copy(), runs["algorithm"].copy()
    if by == "controller":
        runs = _by_controller(runs, dirs)
    # runs compared must pose one problem: per case, or per case and structure by controller
    for case, rows in runs.groupby(["case", "algorithm"] if by == "controller" else "case", sort=False):
        ids = pd.unique(rows["problem_id"])
        if len(ids) > 1:
            parts = []
            for pid in ids:
                same = rows["problem_id"] == pid
                exps = ", ".join(pd.unique(rows.loc[same, "experiment"]))
                where = ", ".join(pd.unique(source[same.index[same]]))
                parts.append(f"{pid} ({exps}) in {where}")
            what = f"case '{case[0]}', controller '{case[1]}'" if by == "controller" else f"case '{case}'"
            raise ConfigError(f"{what}: runs are not comparable, problem_id differs: " + "; ".join(parts))

    dup = runs.assign(_key=key).duplicated(_KEY + ["_key"], keep=False)
    if dup.any():
        first = runs.loc[dup].iloc[0]
        n_dup = int(runs.assign(_key=key).duplicated(_KEY + ["_key"], keep="first").sum())
        more = f" ({n_dup - 1} more duplicate(s))" if n_dup > 1 else ""
        raise ConfigError(f"duplicate run: experiment '{first['experiment']}', case '{first['case']}', "
                          f"algorithm '{first['algorithm']}', run {first['run']} in "
                          f"{source[dup.index[dup][0]]}{more}")

    original = runs["algorithm"].copy()
    for _, idx in runs.groupby(["case", "algorithm"], sort=False).groups.items():
        n_src, n_exp = key[idx].nunique(), runs.loc[idx, "experiment"].nunique()
        if n_src == 1 and n_exp == 1:
            continue
        pairs = runs.loc[idx, "experiment"] + "\0" + key[idx]
        by_experiment = pairs.nunique() == n_exp and not set(variant[idx]) & explicit
        if by_experiment:
            tag = runs.loc[idx, "experiment"]
        elif pairs.nunique() == n_src:  # one experiment per folder
            tag = variant[idx]
        else:  # a folder holding several experiments of this algorithm
            tag = variant[idx] + ": " + runs.loc[idx, "experiment"]
        runs.loc[idx, "algorithm"] = original[idx] + " [" + tag + "]"
    mapping = pd.DataFrame({"k": key, "e": runs["experiment"], "c": file_case, "a": file_algorithm,
                            "l": runs["algorithm"], "nc": runs["case"]}).drop_duplicates(["k", "e", "c", "a"])
    runs.attrs["algorithm_labels"] = {(k, e, c, a): lab for k, e, c, a, lab, _ in mapping.itertuples(index=False)}
    if by == "controller":  # the plant case a structure's case belongs to
        runs.attrs["case_labels"] = {(k, e, c, a): nc for k, e, c, a, _, nc in mapping.itertuples(index=False)}
    return runs


def load_margins(dirs, runs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Read and merge the ``margins.parquet`` files of experiment output folders.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders (a path to a ``.parquet`` file stands for its folder).
    runs : pandas.DataFrame, optional
        Rows of :func:`load_runs` for the same folders: an algorithm that :func:`load_runs`
        relabelled (``"name [experiment]"`` or ``"name [variant]"``) gets the same label here,
        read from ``runs.attrs["algorithm_labels"]`` (without it, only ``"name [experiment]"``
        is followed).

    Returns
    -------
    pandas.DataFrame
        All rows of the files found, in folder order, with a fresh index (empty, with the
        columns ``MARGIN_KEY_COLUMNS``, when there are none). Folders without
        ``margins.parquet``, and files that cannot be read or lack the columns ``experiment,
        case, algorithm, input, output, gain_crossover_rad_s, phase_margin_deg`` (e.g. TITO
        margins, which are per loop), are skipped without error.
    """
    return _load_labelled(dirs, runs, "margins.parquet", MARGIN_KEY_COLUMNS)


def load_histories(dirs, runs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Read and merge the ``history.parquet`` files of experiment output folders, with the
    algorithms labelled as :func:`load_runs` labelled them.

    Parameters
    ----------
    dirs : iterable of str or Path
        Experiment output folders (a path to a ``.parquet`` file stands for its folder).
    runs : pandas.DataFrame, optional
        Rows of :func:`load_runs` for the same folders, whose labels are followed (as
        :func:`load_margins` does).

    Returns
    -------
    pandas.DataFrame
        All rows of the readable files (empty when there are none).
    """
    return _load_labelled(dirs, runs, "history.parquet", ("experiment", "case", "algorithm"))


def _load_labelled(dirs, runs, filename: str, required) -> pd.DataFrame:
    """``filename`` of each folder, merged, algorithms relabelled to match ``runs``."""
    frames = []
    for d in dirs:
        file = experiment_folder(d) / filename
        if not file.is_file():
            continue
        try:
            df = pd.read_parquet(file)
        except Exception:  # unreadable: these files are an optional extra
            continue
        if all(c in df.columns for c in required):
            frames.append(df.assign(_source=_source_key(d)))
    if not frames:
        return pd.DataFrame(columns=list(required))
    m = pd.concat(frames, ignore_index=True, sort=False)
    for col in ("experiment", "case", "algorithm"):
        m[col] = m[col].astype(str)
    known = runs.attrs.get("algorithm_labels") if runs is not None else None
    if known and len(m):
        keys = list(zip(m["_source"], m["experiment"], m["case"], m["algorithm"]))
        m["algorithm"] = [known.get(k, k[3]) for k in keys]
        cases = runs.attrs.get("case_labels")
        if cases:  # compared by controller: the plant case
            m["case"] = [cases.get(k, k[2]) for k in keys]
    elif runs is not None and len(m):  # rows without the labels of load_runs: follow "name [experiment]"
        labels = set(zip(runs["case"], runs["algorithm"]))
        relabel = [(c, f"{a} [{e}]") in labels for e, c, a in zip(m["experiment"], m["case"], m["algorithm"])]
        relabel = np.array(relabel, dtype=bool)
        if relabel.any():
            m.loc[relabel, "algorithm"] = m.loc[relabel, "algorithm"] + " [" + m.loc[relabel, "experiment"] + "]"
    return m.drop(columns="_source")


def margins_table(margins: pd.DataFrame) -> pd.DataFrame:
    """Gain crossover and phase margin per (case, algorithm, input, output) (thesis Table 5.8 layout).

    Parameters
    ----------
    margins : pandas.DataFrame
        Rows of :func:`load_margins` (one per best run and interaction loop).

    Returns
    -------
    pandas.DataFrame
        Columns ``case, algorithm, run`` (when present), ``input, output``, ``gain crossover
        (rad/s)`` (NaN: |L| never reaches 1) and ``phase margin (deg)`` (``inf`` then), rows
        in file order, sorted by input and output within each (case, algorithm).
    """
    cols = ["case", "algorithm"] + (["run"] if "run" in margins.columns else []) + ["input", "output"]
    out = margins[cols + ["gain_crossover_rad_s", "phase_margin_deg"]].copy()
    out["input"] = out["input"].astype(int)
    out["output"] = out["output"].astype(int)
    if "run" in out:
        out["run"] = out["run"].astype(int)
    order = {}
    for key in zip(out["case"], out["algorithm"]):
        order.setdefault(key, len(order))
    out["_o"] = [order[key] for key in zip(out["case"], out["algorithm"])]
    out = out.sort_values(["_o", "input", "output"], kind="mergesort").drop(columns="_o")
    return out.rename(columns={"gain_crossover_rad_s": "gain crossover (rad/s)",
                               "phase_margin_deg": "phase margin (deg)"}).reset_index(drop=True)


def check_metric(runs: pd.DataFrame, metric: str) -> None:
    """Refuse a metric that the statistics cannot compare.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        The column to compare, lower being better.

    Raises
    ------
    ConfigError
        An unknown column (the numeric ones listed), or one that is not numeric.
    """
    if metric not in runs.columns:
        numeric = [c for c in runs.columns if pd.api.types.is_numeric_dtype(runs[c])
                   and not pd.api.types.is_bool_dtype(runs[c])]
        raise ConfigError(f"unknown metric column '{metric}' (numeric columns: {', '.join(map(str, numeric))})")
    col = runs[metric]
    if pd.api.types.is_bool_dtype(col) or not pd.api.types.is_numeric_dtype(col):
        raise ConfigError(f"metric column '{metric}' is not numeric ({col.dtype}); "
                          "choose a numeric metric where lower is better")


def _samples(rows: pd.DataFrame, metric: str) -> dict[str, np.ndarray]:
    """Metric values of the successful runs per algorithm, algorithms in order of appearance.

    Failed and infeasible runs (see :func:`successful_runs`) and missing values are left out.
    """
    ok = successful_runs(rows).to_numpy()
    out = {}
    for alg in pd.unique(rows["algorithm"]):
        sel = (rows["algorithm"] == alg).to_numpy() & ok
        v = rows.loc[sel, metric].to_numpy(dtype=float)
        out[alg] = v[~np.isnan(v)]
    return out


def failed_runs(runs: pd.DataFrame) -> pd.Series:
    """Which runs failed (no stable, simulable candidate; their objective is a sentinel).

    ``status == "failed"`` where the column exists; rows without a status (runs written before
    it existed) count as failed when ``best_f`` is at the failure sentinel.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.

    Returns
    -------
    pandas.Series of bool
        True for a failed run, aligned with ``runs``.
    """
    missing = runs["status"].isna() if "status" in runs else pd.Series(True, index=runs.index)
    failed = runs["status"].eq("failed") if "status" in runs else pd.Series(False, index=runs.index)
    if missing.any() and "best_f" in runs:
        failed |= missing & (runs["best_f"] >= FAILED_OBJECTIVE)
    return failed


def successful_runs(runs: pd.DataFrame) -> pd.Series:
    """Which runs succeeded: not failed (:func:`failed_runs`) and with a feasible best candidate.

    Feasibility is read from the ``feasible`` column of ``runs.parquet`` (the best candidate under
    the tuning scenario meets every constraint); without that column, a ``status`` of
    ``"infeasible"`` marks an infeasible run; without either, every run that did not fail counts.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.

    Returns
    -------
    pandas.Series of bool
        True for a successful run, aligned with ``runs``. Only these runs enter the means,
        medians and tests of this module.
    """
    ok = ~failed_runs(runs).astype(bool)
    if "feasible" in runs:
        ok &= runs["feasible"].astype("boolean").fillna(False).astype(bool)
    elif "status" in runs:
        ok &= ~runs["status"].eq("infeasible")
    return ok


def _scenario_columns(runs: pd.DataFrame):
    """``{scenario: {metric: column}}`` from ``<metric>@<scenario>`` columns, in column order."""
    found: dict[str, dict[str, str]] = {}
    for col in runs.columns:
        if isinstance(col, str) and "@" in col:
            metric, scenario = col.split("@", 1)
            found.setdefault(scenario, {})[metric] = col
    return found


def best_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The best run of every case and optimiser.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of ``runs.parquet``.

    Returns
    -------
    pandas.DataFrame
        Per case and optimiser (``optimiser_index``, else ``algorithm``), its best run as
        :func:`best_run_index` picks it, in order of appearance.
    """
    keys = ["case", "optimiser_index"] if "optimiser_index" in runs.columns else ["case", "algorithm"]
    return runs.loc[[best_run_index(g) for _, g in runs.groupby(keys, sort=False)]]


def best_run_index(g: pd.DataFrame):
    """Index of the best run of a group.

    Parameters
    ----------
    g : pandas.DataFrame
        Rows of ``runs.parquet`` (one optimiser of one case).

    Returns
    -------
    index label
        The run with the lowest ``best_f`` among the feasible ones, else the lowest violation.
    """
    feasible = g["feasible"].fillna(False).astype(bool) if "feasible" in g else pd.Series(True, index=g.index)
    best_f = g["best_f"].astype(float)
    if feasible.any():
        return best_f[feasible].fillna(np.inf).idxmin()
    if "violation" in g:
        key = g.assign(_v=g["violation"].astype(float).fillna(np.inf), _f=best_f.fillna(np.inf))
        return key.sort_values(["_v", "_f"], kind="mergesort").index[0]
    return best_f.fillna(np.inf).idxmin()


def reevaluation_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per-scenario metrics of each algorithm's best run (thesis Tables 5.5-5.7 layout).

    The best run of a (case, algorithm) is the one with the lowest ``best_f`` among feasible
    runs; if none is feasible, the one with the lowest ``violation`` (then lowest ``best_f``).

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs` with ``best_f`` and columns ``<metric>@<scenario>``, e.g.
        ``Mp1@nominal``, ``J@+30%``, ``feasible@-30%``.

    Returns
    -------
    pandas.DataFrame
        Rows (case, algorithm, scenario), scenarios in column order; columns ``case,
        algorithm, scenario, run`` (the chosen run), then those of ``Mp1, Mp2, ts1, ts2, ess1,
        ess2, J1, J2, J`` that exist, any other numeric ``<metric>@<scenario>`` metrics, and
        ``feasible`` if ``feasible@<scenario>`` exists. Empty (with these key columns) when
        there are no scenario columns.
    """
    if "best_f" not in runs.columns:
        raise ConfigError("column 'best_f' is needed to pick the best run")
    scen = _scenario_columns(runs)
    present = {m for cols in scen.values() for m in cols}
    metrics = [m for m in REEVALUATION_COLUMNS if m in present]
    extra = []
    for cols in scen.values():
        for m in cols:
            if m not in metrics and m not in extra and m != "feasible":
                extra.append(m)
    metrics += extra
    with_feasible = "feasible" in present
    columns = ["case", "algorithm", "scenario", "run"] + metrics + (["feasible"] if with_feasible else [])
    rows = []
    if scen:
        for (case, alg), g in runs.groupby(["case", "algorithm"], sort=False):
            best = g.loc[best_run_index(g)]
            for scenario, cols in scen.items():
                row = {"case": case, "algorithm": alg, "scenario": scenario, "run": int(best["run"])}
                for m in metrics:
                    row[m] = best[cols[m]] if m in cols else np.nan
                if with_feasible:
                    row["feasible"] = best[cols["feasible"]] if "feasible" in cols else pd.NA
                rows.append(row)
    return pd.DataFrame(rows, columns=columns)
