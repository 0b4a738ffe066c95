"""Export an experiment's results for other tools: IOHprofiler files or MATLAB .mat files.

Usage::

    python -m heurtune.export DIR --format ioh|mat [--out OUT]

``DIR`` is a results folder of :mod:`heurtune.experiment` (``runs.parquet``,
``history.parquet``, ``meta.json``); ``OUT`` defaults to ``DIR/ioh`` or ``DIR/mat``.

``ioh``
    The IOHprofiler layout that IOHanalyzer and iohinspector read, as ioh's ``Analyzer``
    logger writes it (ioh 0.4): per optimiser a folder ``OUT/<algorithm>/`` holding, per case,
    ``IOHprofiler_f<id>_<case>.json`` (metadata: function, algorithm, one scenario per
    dimension with its runs) and ``data_f<id>_<case>/IOHprofiler_f<id>_DIM<d>.dat``: each run
    starts with the header line ``evaluations raw_y`` followed by ``evaluations value`` lines.
    function = case (ids 1, 2, ... in the experiment's order), suite = experiment, algorithm =
    heurtune's algorithm name, dimension = number of gains, instance = 0 (every run tunes the
    same problem); the value is the run's best feasible objective so far (minimised), logged
    at each epoch where it improves and at the run's last evaluation. Readers split runs at
    ``evaluations == 1``, so each run starts with a line at evaluation 1; until the run has a
    feasible candidate its value is the placeholder ``max(FAILED_OBJECTIVE, worst value of the
    case)`` (1e10 for the QTP problems) plus the run's place in its file (0, 1, 2, ...), which no
    target below it counts as reached. The places keep runs apart for a reader that drops
    repeated values over a whole file: iohinspector 0.0.8's ``load(monotonic=True)`` takes its
    differences across runs, and with one placeholder a failed run after another failed run
    vanished (5 of thesis_ch5's 24).

``mat``
    ``runs.mat`` (struct ``runs``: one field per column of runs.parquet), ``history.mat``
    (struct ``history``) and ``best.mat``: cell array ``best`` with one struct per (case,
    optimiser): its best run, gain names and values and, for QTP problems, the plant (its
    parameters and linearisation), the operating point, the scenario, the continuous controller
    (``A, B, C, D``, its blocks as 1-based rows), its zero-order-hold discretisation
    (``discrete``: ``Phi, Gamma, C, D, dt``) and the nominal response (``response``: ``t,
    h1..h4, y1, y2, u1, u2``). ``README.txt`` beside them says what each field is, in which unit,
    and how to rebuild the loop in MATLAB or Octave. Column names that are not MATLAB
    identifiers (``Mp1@+30%``) are rewritten (``Mp1_at_p30pct``); ``column_names`` in each file
    maps them back.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune import _startup
from heurtune.analysis.anytime import feasible_best
from heurtune.analysis.runs import best_runs
from heurtune.core.cli import exit_codes
from heurtune.core.errors import ConfigError
from heurtune.core.families import make_experiment
from heurtune.core.io import atomic_path, check_output_folder
from heurtune.core.problem import FAILED_OBJECTIVE

__all__ = [
    "load_results",
    "ioh_lines",
    "write_ioh",
    "export_ioh",
    "matlab_name",
    "write_mat",
    "mat_readme",
    "export_mat",
    "best_runs",
    "main",
]

IOH_VERSION = "0.4.2"  # the ioh release whose Analyzer layout these files follow
FORMATS = ("ioh", "mat")


# -- loading ---------------------------------------------------------------------------------
def load_results(results_dir) -> tuple:
    """``(runs, history, meta)`` of a results folder.

    Parameters
    ----------
    results_dir : str or Path
        A folder written by ``python -m heurtune.experiment``.

    Returns
    -------
    tuple
        ``runs.parquet`` and ``history.parquet`` as DataFrames, and ``meta.json`` as a dict.

    Raises
    ------
    FileNotFoundError
        When ``runs.parquet`` or ``history.parquet`` is missing (``meta.json`` is optional:
        ``{}`` then).
    """
    d = Path(results_dir)
    for name in ("runs.parquet", "history.parquet"):
        if not (d / name).is_file():
            raise FileNotFoundError(f"{d / name} not found (is {results_dir} a results folder?)")
    meta = json.loads((d / "meta.json").read_text()) if (d / "meta.json").is_file() else {}
    return pd.read_parquet(d / "runs.parquet"), pd.read_parquet(d / "history.parquet"), meta


def _experiment(meta: dict):
    """The experiment object of a results folder's resolved config (``meta.json``)."""
    config = meta.get("config")
    if not config:
        raise ConfigError("meta.json holds no config: cannot rebuild the problems")
    return make_experiment(config)


def _optimisers(df: pd.DataFrame) -> list:
    """``[(case, algorithm, optimiser_index, label)]`` in order of appearance; the label is the
    algorithm, with ``-<optimiser_index>`` where one algorithm appears with several indices."""
    idx = df["optimiser_index"] if "optimiser_index" in df.columns else pd.Series(0, index=df.index)
    pairs = pd.DataFrame({"case": df["case"], "algorithm": df["algorithm"], "oi": idx}).drop_duplicates()
    several = pairs.groupby("algorithm")["oi"].nunique()
    return [(c, a, int(i), f"{a}-{int(i)}" if several[a] > 1 else str(a))
            for c, a, i in pairs.itertuples(index=False)]


# -- IOHprofiler -----------------------------------------------------------------------------
def _placeholder(h: pd.DataFrame) -> float:
    f = h["f_feasible"].to_numpy(float)
    f = f[np.isfinite(f)]
    return float(max(FAILED_OBJECTIVE, f.max() if f.size else FAILED_OBJECTIVE))


def ioh_lines(n_evals, f_feasible, placeholder: float) -> list:
    """The ``(evaluations, value)`` lines of one run in an IOHprofiler ``.dat`` file.

    Parameters
    ----------
    n_evals : sequence of int
        Evaluations at the end of each epoch (non-decreasing).
    f_feasible : sequence of float
        Best feasible objective so far at each epoch (``inf`` before the first feasible one).
    placeholder : float
        Value written while no feasible candidate is known.

    Returns
    -------
    list of (int, float)
        A line at evaluation 1 (the placeholder unless the first epoch is that one
        evaluation), a line where the value improves, and one at the last evaluation.
    """
    lines = []
    n = np.asarray(n_evals, dtype=np.int64)
    f = np.where(np.isfinite(np.asarray(f_feasible, dtype=float)), f_feasible, placeholder)
    if n.size == 0:
        return lines
    if n[0] > 1 or not np.isfinite(f_feasible[0]):
        lines.append((1, placeholder))
    for ni, fi in zip(n.tolist(), f.tolist()):
        ni = max(ni, 1)
        if lines and fi >= lines[-1][1]:
            continue
        if lines and lines[-1][0] == ni:
            lines[-1] = (ni, fi)
        else:
            lines.append((ni, fi))
    last = max(int(n[-1]), 1)
    if lines[-1][0] != last:
        lines.append((last, lines[-1][1]))
    return lines


def _fmt(value: float) -> str:
    return format(float(value), ".15g")


def write_ioh(history: pd.DataFrame, out, *, dimensions, runs: pd.DataFrame | None = None,
              gain_names=None, suite: str | None = None) -> list:
    """Write histories in the IOHprofiler layout (see the module docstring).

    Parameters
    ----------
    history : pandas.DataFrame
        Rows of ``history.parquet``.
    out : path
        Output folder; one subfolder per optimiser.
    dimensions : int or dict of str to int
        Number of gains, for every case or per case.
    runs : pandas.DataFrame, optional
        Rows of ``runs.parquet``: with ``gain_names``, gives each run's best gains (``x``)
        and the optimiser's settings (``algorithm.info``).
    gain_names : dict of str to sequence of str, optional
        Gain names per case.
    suite : str, optional
        Suite name (default: the ``experiment`` column, else ``"heurtune"``).

    Returns
    -------
    list of pathlib.Path
        The ``.json`` files written.
    """
    out = Path(out)
    h = feasible_best(history)
    if suite is None:
        suite = str(h["experiment"].iloc[0]) if "experiment" in h.columns and len(h) else "heurtune"
    if "optimiser_index" not in h.columns:
        h["optimiser_index"] = 0
    cases = list(dict.fromkeys(h["case"]))
    fid = {c: i + 1 for i, c in enumerate(cases)}
    placeholder = {c: _placeholder(g) for c, g in h.groupby("case", sort=False)}
    written = []
    for case, alg, oi, label in _optimisers(h):
        dim = int(dimensions[case] if isinstance(dimensions, dict) else dimensions)
        g = h[(h["case"] == case) & (h["algorithm"] == alg) & (h["optimiser_index"] == oi)]
        safe_case = _slug(case)
        folder = out / _slug(label)
        data_rel = f"data_f{fid[case]}_{safe_case}/IOHprofiler_f{fid[case]}_DIM{dim}.dat"
        text, run_meta = [], []
        for place, (run, rg) in enumerate(g.groupby("run", sort=True)):
            # one placeholder per run: no run starts on the value the one before it ended on
            lines = ioh_lines(rg["n_evals"].to_numpy(), rg["f_feasible"].to_numpy(), placeholder[case] + place)
            text.append("evaluations raw_y")
            text.extend(f"{e} {_fmt(v)}" for e, v in lines)
            best_v = lines[-1][1]
            best_e = next(e for e, v in lines if v == best_v)
            run_meta.append({"instance": 0, "evals": int(lines[-1][0]),
                             "best": {"evals": int(best_e), "y": float(best_v),
                                      "x": _gains(runs, gain_names, case, alg, oi, run)}})
        info = ""
        if runs is not None and "settings" in runs.columns:
            sel = _select(runs, case, alg, oi)
            info = str(sel["settings"].iloc[0]) if len(sel) else ""
        meta = {"version": IOH_VERSION, "suite": suite, "function_id": fid[case], "function_name": str(case),
                "maximization": False, "algorithm": {"name": str(alg), "info": info},
                "attributes": ["evaluations", "raw_y"],
                "scenarios": [{"dimension": dim, "path": data_rel, "runs": run_meta}]}
        with atomic_path(folder / data_rel) as tmp:
            tmp.write_text("\n".join(text) + "\n")
        json_path = folder / f"IOHprofiler_f{fid[case]}_{safe_case}.json"
        with atomic_path(json_path) as tmp:
            tmp.write_text(json.dumps(meta, indent=1, allow_nan=False))
        written.append(json_path)
    return written


def _select(runs, case, alg, oi):
    sel = (runs["case"] == case) & (runs["algorithm"] == alg)
    if "optimiser_index" in runs.columns:
        sel &= runs["optimiser_index"] == oi
    return runs[sel]


def _gains(runs, gain_names, case, alg, oi, run) -> list:
    if runs is None or not gain_names or case not in gain_names:
        return []
    sel = _select(runs, case, alg, oi)
    sel = sel[sel["run"] == run]
    if not len(sel):
        return []
    return [float(sel[n].iloc[0]) for n in gain_names[case]]


def _slug(text) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(text))


def export_ioh(results_dir, out) -> list:
    """Write a results folder in the IOHprofiler layout.

    Parameters
    ----------
    results_dir : str or Path
        A folder written by ``python -m heurtune.experiment``.
    out : str or Path
        The folder to write (created).

    Returns
    -------
    list of Path
        The ``.json`` files written, one per case and algorithm.
    """
    runs, history, meta = load_results(results_dir)
    exp = _experiment(meta)
    names = {c: tuple(exp.problem(c).names) for c in dict.fromkeys(history["case"])}
    return write_ioh(history, out, dimensions={c: len(n) for c, n in names.items()}, runs=runs,
                     gain_names=names, suite=meta.get("experiment"))


# -- MATLAB ----------------------------------------------------------------------------------
_SIGNS = {"@": "_at_", "+": "p", "-": "m", "%": "pct", ".": "_"}


def matlab_name(name: str) -> str:
    """A valid MATLAB field name for a column name.

    Parameters
    ----------
    name : str
        A column name (``Mp1@+30%``).

    Returns
    -------
    str
        Letters, digits and underscores, starting with a letter (``Mp1_at_p30pct``).
    """
    s = "".join(_SIGNS.get(ch, ch if (ch.isascii() and (ch.isalnum() or ch == "_")) else "_") for ch in str(name))
    s = re.sub(r"_+", "_", s).strip("_") or "x"
    if not s[0].isalpha():
        s = "x" + s
    return s[:63]


def _struct_of_columns(df: pd.DataFrame) -> tuple:
    """``(fields, names)``: a dict of MATLAB-safe column arrays and the ``(field, column)`` map."""
    fields, mapping = {}, []
    for col in df.columns:
        key = base = matlab_name(col)
        k = 2
        while key in fields:
            suffix = f"_{k}"
            key, k = base[:63 - len(suffix)] + suffix, k + 1
        s = df[col]
        if pd.api.types.is_bool_dtype(s) and not s.isna().any():
            arr = s.to_numpy(dtype=bool)
        elif pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s):
            arr = s.to_numpy(dtype=float, na_value=np.nan) if s.dtype.kind not in "iu" else s.to_numpy()
        else:
            arr = np.array(["" if v is None or (isinstance(v, float) and np.isnan(v)) else str(v) for v in s],
                           dtype=object)
        fields[key] = arr.reshape(-1, 1)
        mapping.append((key, str(col)))
    return fields, np.array(mapping, dtype=object).reshape(-1, 2)


def _controller_record(prob, x) -> dict:
    """What the problem's family records of a design (``controller_record``), response columns
    renamed for MATLAB."""
    rec = prob.controller_record(x)
    if not rec:
        return {}
    rec = dict(rec)
    if "response" in rec:
        resp = rec["response"]
        rec["response"] = {matlab_name(c): resp[c].to_numpy(dtype=float).reshape(-1, 1) for c in resp.columns}
    return rec


def write_mat(runs: pd.DataFrame, history: pd.DataFrame, out, *, experiment=None) -> list:
    """Write ``runs.mat``, ``history.mat`` and ``best.mat`` to ``out`` (see the module docstring).

    Parameters
    ----------
    runs, history : pandas.DataFrame
        Rows of ``runs.parquet`` and ``history.parquet``.
    out : path
        Output folder.
    experiment : Experiment, optional
        The experiment object: gives the gain names and, for QTP problems, the controllers and
        responses of the best runs. Without it, ``best.mat`` holds the best runs' rows only.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    import scipy.io

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for name, df in (("runs", runs), ("history", history)):
        fields, mapping = _struct_of_columns(df)
        with atomic_path(out / f"{name}.mat") as tmp:
            scipy.io.savemat(tmp, {name: fields, "column_names": mapping}, oned_as="column",
                             long_field_names=True, do_compression=True)
        files.append(out / f"{name}.mat")
    best = best_runs(runs)
    cells = np.empty((len(best), 1), dtype=object)
    for i, (_, r) in enumerate(best.iterrows()):
        rec = {"experiment": str(r.get("experiment", "")), "case": str(r["case"]), "algorithm": str(r["algorithm"]),
               "optimiser_index": int(r.get("optimiser_index", 0)), "run": int(r["run"]),
               "best_f": float(r["best_f"]), "feasible": bool(r["feasible"]),
               "status": str(r.get("status", ""))}
        if experiment is not None:
            prob = experiment.problem(r["case"])
            names = list(prob.names)
            x = np.array([float(r[n]) for n in names])
            rec["gain_names"] = np.array(names, dtype=object).reshape(1, -1)
            rec["gains"] = x.reshape(1, -1)
            rec.update(_controller_record(prob, x))
        cells[i, 0] = rec
    fields = ()
    units = {"run": "label (0-based)", "optimiser_index": "label (0-based)"}
    if experiment is not None and len(best):
        prob = experiment.problem(best.iloc[0]["case"])
        fields = getattr(prob, "CONTROLLER_RECORD_FIELDS", ())
        units.update(_units_of(prob))
    readme = mat_readme(fields)
    with atomic_path(out / "best.mat") as tmp:
        # the readme and the units travel inside the file as well (a copied best.mat keeps them)
        scipy.io.savemat(tmp, {"best": cells, "readme": readme, "units": units}, oned_as="column",
                         long_field_names=True, do_compression=True)
    files.append(out / "best.mat")
    with atomic_path(out / "README.txt") as tmp:
        Path(tmp).write_text(readme)
    files.append(out / "README.txt")
    return files


def _units_of(prob) -> dict:
    """``{field: unit}`` of a best record for ``best.mat``'s ``units``: the objective (its
    label and unit) and the response's time, outputs and inputs where the problem names them."""
    units = {"best_f": str(getattr(prob, "objective_label", "objective")), "response_t": "s"}
    labels = getattr(prob, "signal_labels", {}) or {}
    if labels.get("y_unit"):
        units["response_y"] = units["response_h"] = str(labels["y_unit"])
    if labels.get("u_unit"):
        units["response_u"] = str(labels["u_unit"])
    return units


def mat_readme(fields=()) -> str:
    """The README.txt of a ``.mat`` export: what each file and field holds, in which unit.

    Parameters
    ----------
    fields : sequence of (str, str)
        The family's ``(field, meaning)`` pairs of a best design's record.

    Returns
    -------
    str
    """
    lines = [
        "heurtune results as MATLAB/Octave files (python -m heurtune.export DIR --format mat)",
        "",
        "runs.mat     struct runs: one field per column of runs.parquet, one row per run (case, optimiser,",
        "             run): best_f, feasible, status, n_evals, the gains, and <metric>_at_<scenario> of the",
        "             best gains re-evaluated per scenario; column_names maps each field to its column",
        "             (Mp1_at_p30pct is Mp1@+30%).",
        "history.mat  struct history: one row per (run, epoch): n_evals, best_f, mean_f, sd_f, ...",
        "best.mat     cell array best, one struct per (case, optimiser): its best run (experiment, case,",
        "             algorithm, optimiser_index, run, best_f, feasible, status) and its gains (gain_names,",
        "             gains); run and optimiser_index are labels, numbered from 0 as in the parquet files.",
        "             best.mat also holds this text (readme) and the units of its fields (units: best_f,",
        "             response_t, response_y, response_u where the problem has them).",
        "",
        "A failed run (status 'failed': its best candidate could not be designed, was unstable or",
        f"diverged) keeps best_f = {FAILED_OBJECTIVE:g}, a placeholder, not a value: select status",
        "'feasible' (or feasible == 1) before averaging best_f.",
    ]
    if fields:
        lines += ["", "Each struct of best.mat also holds the design:", ""]
        width = max(len(name) for name, _ in fields)
        for name, meaning in fields:
            lines.append(f"  {name.ljust(width)}  {meaning}")
        lines += [
            "",
            "Every index in these fields is 1-based (MATLAB's convention). In MATLAB or Octave:",
            "",
            "  S = load('best.mat'); b = S.best{1};",
            "  K = ss(b.controller.A, b.controller.B, b.controller.C, b.controller.D);   % w -> du",
            "  Kd = ss(b.discrete.Phi, b.discrete.Gamma, b.discrete.C, b.discrete.D, b.discrete.dt);",
            "  P = ss(b.plant.linearisation.A, b.plant.linearisation.B, eye(4), zeros(4, 2));  % du -> w",
            "  L = feedback(P, K, +1);   % du = K w closes the loop (K holds the minus signs)",
            "  plot(b.response.t, b.response.y1)",
        ]
    return "\n".join(lines) + "\n"


def export_mat(results_dir, out) -> list:
    """Write a results folder as ``.mat`` files, with a ``README.txt`` of their fields.

    Parameters
    ----------
    results_dir : str or Path
        A folder written by ``python -m heurtune.experiment``.
    out : str or Path
        The folder to write (created).

    Returns
    -------
    list of Path
        The files written.
    """
    runs, history, meta = load_results(results_dir)
    return write_mat(runs, history, out, experiment=_experiment(meta))


# -- command line ----------------------------------------------------------------------------
def _parser():
    ap = argparse.ArgumentParser(prog="python -m heurtune.export", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=exit_codes(("python -m heurtune.export results/cs_folqi_qtp --format ioh",
                                                    "python -m heurtune.export results/thesis_ch5 --format mat "
                                                    "--out mat")))
    ap.add_argument("dir", help="results folder (runs.parquet, history.parquet, meta.json)")
    ap.add_argument("--format", required=True, help="ioh (IOHprofiler: IOHanalyzer, iohinspector) or mat")
    ap.add_argument("--out", help="output folder (default DIR/ioh or DIR/mat)")
    return ap


def run(argv=None) -> int:
    """Command-line entry point; returns the exit code (2 for a usage error)."""
    args = _parser().parse_args(argv)
    try:
        if args.format not in FORMATS:
            raise ConfigError(f"unknown format {args.format!r}; allowed: {', '.join(FORMATS)}")
        out = check_output_folder(args.out, "--out") if args.out else Path(args.dir) / args.format
        files = (export_ioh if args.format == "ioh" else export_mat)(args.dir, out)
    except (ConfigError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(files)} {'metadata files' if args.format == 'ioh' else 'files'} to {out}")
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
