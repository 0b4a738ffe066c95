"""One self-contained HTML report of one or more experiment results folders.

Usage::

    python -m heurtune.report DIR [DIR ...] --out OUT [--metric best_f] [--alpha 0.05]

Writes ``OUT/index.html``: a single file with every figure embedded as a base64 PNG data URI
and a small inline style sheet, so it opens offline and can be mailed or archived as is. It
holds

* a header: the experiments, their folders, problem ids, the date each was written, the
  heurtune version recorded in its ``meta.json`` and the date of the report;
* per case: the summary statistics, the Kruskal-Wallis line, the pairwise table (Dunn and
  rank-sum p-values, A12 with its interval, win column), the re-evaluation of each algorithm's
  best run under the uncertainty scenarios and the loop-margins table (all computed by
  :mod:`heurtune.compare`), then the figures: convergence (median and IQR per epoch), the ECDF
  of evaluations to targets (:mod:`heurtune.anytime`), the box plot of the final objective and
  the responses of each algorithm's best controller (the problem rebuilt from ``meta.json``);
* across cases: the Friedman/Nemenyi tables and the critical-difference diagram, or why they
  were skipped.

A figure that cannot be drawn (no history, no ``meta.json``, ...) is replaced by a one-line
note saying why. Input mistakes (a folder without ``runs.parquet``, no ``--out``) end with a
one-line error and exit code 2.
"""

from __future__ import annotations

import argparse
import base64
import datetime as _dt
import html
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune import _startup
from heurtune.analysis import anytime, figures, render
from heurtune.analysis.runs import (
    best_run_index,
    check_metric,
    experiment_folder,
    load_histories,
    load_margins,
    load_runs,
)
from heurtune.core.cli import OneLineParser, UsageError, exit_codes, parse_labels
from heurtune.core.errors import ConfigError
from heurtune.core.families import make_experiment
from heurtune.core.io import atomic_path

__all__ = ["build_report", "render_html", "run", "main"]

STYLE = """
body{font-family:sans-serif;margin:1.5em auto;max-width:1250px;color:#222;line-height:1.4}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #aaa;margin-top:2em}
table{border-collapse:collapse;font-size:12px;margin:.5em 0 1em}
th,td{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#eee}
td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figcaption{font-size:13px;color:#555}img{max-width:100%}
p.note{font-size:13px}p.skip{font-size:13px;color:#a33}div.wide{overflow-x:auto}
"""


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


def _table(df: pd.DataFrame) -> str:
    def num(v):
        return f"{v:.5g}"

    return ('<div class="wide">' + df.to_html(escape=True, na_rep="", index=False, float_format=num, border=0)
            + "</div>")


def _img(png: Path, caption: str) -> str:
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{_esc(caption)}">'
            f"<figcaption>{_esc(caption)}</figcaption></figure>")


def _skip(what: str, why) -> str:
    first = (str(why).strip().splitlines() or [type(why).__name__])[0]
    return f'<p class="skip">{_esc(what)} not drawn: {_esc(first)}</p>'


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in str(text))


# ----------------------------------------------------------------------------------------------
# Inputs
# ----------------------------------------------------------------------------------------------

def _read_meta(dirs) -> dict:
    """``{experiment name: (folder, meta dict)}`` of the folders with a readable ``meta.json``."""
    metas = {}
    for d in dirs:
        file = experiment_folder(d) / "meta.json"
        try:
            meta = json.loads(file.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(meta, dict) and "experiment" in meta:
            metas.setdefault(str(meta["experiment"]), (experiment_folder(d), meta))
    return metas


# ----------------------------------------------------------------------------------------------
# Figures (each returns HTML: an embedded image or a note)
# ----------------------------------------------------------------------------------------------

def _best_f_axis(runs, case, metas, cache) -> tuple:
    """:func:`~heurtune.analysis.figures.best_f_axis` of the case's problem rebuilt from
    ``meta.json`` (``"IAE (cm s)"``, or the hypervolume for several objectives); ``(None, 1.0)``
    when it cannot be rebuilt."""
    rows = runs[runs["case"] == case]
    try:
        prob = _problem(metas, str(rows["experiment"].iloc[0]), case, cache)
    except (ConfigError, IndexError, KeyError):
        return None, 1.0
    return figures.best_f_axis(prob)


def _convergence(history, case, tmp: Path, axis=(None, 1.0)) -> str:
    what = "Convergence figure"
    if history.empty or "case" not in history or not (history["case"] == case).any():
        return _skip(what, "no history.parquet rows for this case")
    path = tmp / f"convergence_{_slug(case)}.png"
    ylabel, sign = axis
    try:
        figures.convergence_figure(figures.shown_best_f(history, sign), path, case=case, ylabel=ylabel)
    except ValueError as exc:
        return _skip(what, exc)
    return _img(path, f"Case {case}: median best objective per epoch, IQR band per algorithm")


def _ecdf(ecdf_table, case, tmp: Path) -> str:
    what = "ECDF figure"
    if isinstance(ecdf_table, str):
        return _skip(what, ecdf_table)
    if not (ecdf_table["case"] == case).any():
        return _skip(what, "no feasible history for this case")
    path = tmp / f"ecdf_{_slug(case)}.png"
    anytime.plot_ecdf(ecdf_table, path, case=case)
    return _img(path, f"Case {case}: fraction of (run, target) pairs reached against function evaluations")


def _ecdf_table(history):
    """The ECDF table of :mod:`heurtune.anytime`, or a string saying why there is none."""
    if history.empty:
        return "no history.parquet found"
    try:
        return anytime.ecdf(anytime.fixed_target(history))
    except (ValueError, KeyError) as exc:
        return str(exc) or type(exc).__name__


def _boxplot(runs, case, metric, tmp: Path, axis=(None, 1.0)) -> str:
    path = tmp / f"boxplot_{_slug(case)}.png"
    rows, ylabel = runs[runs["case"] == case], None
    if metric == "best_f":  # best_f as its axis names it
        ylabel, sign = axis
        rows = figures.shown_best_f(rows, sign)
    try:
        figures.boxplot_figure(rows, path, metric=metric, ylabel=ylabel)
    except ValueError as exc:
        return _skip("Box plot", exc)
    return _img(path, f"Case {case}: final {metric} per algorithm (red crosses: infeasible runs)")


def _problem(metas, experiment, case, cache):
    key = (experiment, case)
    if key not in cache:
        if experiment not in metas:
            raise ConfigError(f"no meta.json for experiment '{experiment}'")
        config = metas[experiment][1].get("config")
        if not isinstance(config, dict):
            raise ConfigError(f"meta.json of '{experiment}' has no config")
        cache[key] = make_experiment(config).problem(case)
    return cache[key]


def _with_units(table: pd.DataFrame, runs, case, metas, cache) -> pd.DataFrame:
    """``table`` with each metric column named with its unit (``IAE1 (cm s)``), from the
    family's ``metric_units``; as it is when the problem cannot be rebuilt or says none."""
    rows = runs[runs["case"] == case]
    try:
        units = _problem(metas, str(rows["experiment"].iloc[0]), case, cache).metric_units
    except (ConfigError, IndexError, KeyError):
        return table
    names = {}
    for col in table.columns:
        base = str(col).rstrip("0123456789")
        if base in units:
            names[col] = f"{col} ({units[base]})"
    return table.rename(columns=names)


def _responses(runs, case, metas, tmp: Path, cache) -> list:
    """One response figure (or note) per algorithm of the case: its best run, every scenario."""
    parts = []
    rows = runs[runs["case"] == case]
    for alg, g in rows.groupby("algorithm", sort=False):
        what = f"Response of the best {alg} controller"
        if "best_f" not in g:
            parts.append(_skip(what, "no best_f column"))
            continue
        best = g.loc[best_run_index(g)]
        try:
            prob = _problem(metas, str(best["experiment"]), case, cache)
            missing = [n for n in prob.names if n not in best.index]
            if missing:
                raise ConfigError(f"runs.parquet lacks the tuning column(s) {', '.join(missing)}")
            x = np.array([float(best[n]) for n in prob.names])
            status = str(best.get("status", "feasible"))
            state = "" if status == "feasible" else f", {status}: not a solution"  # a failed run says so
            title = f"{case}: best of {alg} (run {int(best['run'])}{state})"
            path = tmp / f"responses_{_slug(case)}_{len(parts)}.png"
            figures.response_figure(prob, x, path, scenarios=tuple(prob.scenarios), title=title)
        except Exception as exc:  # any failure costs only this figure; the note says why
            parts.append(_skip(what, exc))
            continue
        parts.append(_img(path, f"Case {case}: responses of the best {alg} controller (run "
                                f"{int(best['run'])}{state}) under every scenario"))
    return parts


# ----------------------------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------------------------

def _header(runs: pd.DataFrame, metas: dict, dirs) -> list:
    out = ["<h1>heurtune report</h1>",
           f'<p class="note">Report written {_esc(_dt.datetime.now().strftime("%Y-%m-%d %H:%M"))} '
           f"from {len(dirs)} folder(s).</p>"]
    rows = []
    for exp in pd.unique(runs["experiment"]):
        folder, meta = metas.get(exp, (None, {}))
        sub = runs[runs["experiment"] == exp]
        ids = "; ".join(f"{c}: {p}" for c, p in sub[["case", "problem_id"]].drop_duplicates().itertuples(index=False))
        versions = meta.get("versions") if isinstance(meta.get("versions"), dict) else {}
        rows.append({"experiment": exp, "folder": "" if folder is None else str(folder),
                     "algorithms": ", ".join(pd.unique(sub["algorithm"])), "runs": len(sub),
                     "problem ids": ids, "written": meta.get("written", ""),
                     "heurtune": versions.get("heurtune", ""), "git commit": meta.get("git_commit", "")})
    out.append("<h2>Experiments</h2>")
    out.append(_table(pd.DataFrame(rows)))
    return out


def render_html(runs: pd.DataFrame, *, dirs=(), history: pd.DataFrame | None = None, margins=None,
                metas: dict | None = None, metric: str = "best_f", alpha: float = 0.05,
                responses: bool = True) -> str:
    """Render the whole report as one HTML document.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`heurtune.analysis.compare.load_runs`.
    dirs : sequence of str or Path
        The folders read (only named in the header).
    history : pandas.DataFrame, optional
        Merged ``history.parquet`` rows; without them the convergence and ECDF figures are
        replaced by notes.
    margins : pandas.DataFrame, optional
        Rows of :func:`heurtune.analysis.compare.load_margins`.
    metas : dict, optional
        ``{experiment: (folder, meta)}`` from the folders' ``meta.json``; needed for the
        response figures (the problem is rebuilt from ``meta["config"]``).
    metric : str
        Column compared; lower is better.
    alpha : float
        Significance level of the tests.
    responses : bool
        Draw the response figures (they simulate each best controller).

    Returns
    -------
    str
        The HTML document; every image is a ``data:image/png;base64`` URI and every text is
        escaped.
    """
    history = pd.DataFrame() if history is None else history
    metas = metas or {}
    cases = list(pd.unique(runs["case"]))
    body = _header(runs, metas, list(dirs))
    with tempfile.TemporaryDirectory(prefix="heurtune_report_") as name:
        tmp = Path(name)
        cd_path = tmp / "cd_diagram.png"
        blocks = render.report_blocks(runs, metric, alpha, margins, cd_path=cd_path)
        ecdf_table = _ecdf_table(history)
        cache: dict = {}
        current = None  # index of the case whose blocks are being written

        def figures_of(i):
            case = cases[i]
            axis = _best_f_axis(runs, case, metas, cache)  # best_f with its unit
            parts = [f"<h3>Case {_esc(case)}: figures</h3>", _convergence(history, case, tmp, axis),
                     _ecdf(ecdf_table, case, tmp), _boxplot(runs, case, metric, tmp, axis)]
            if responses:
                parts += _responses(runs, case, metas, tmp, cache)
            return parts

        for block in blocks:
            kind = block[0]
            if kind == "heading":
                level, text = block[1], block[2]
                if level == 2:
                    if current is not None:
                        body += figures_of(current)
                    current = None if text == "Across cases" else (0 if current is None else current + 1)
                    anchor = "across" if current is None else f"case-{current}"
                    body.append(f'<h2 id="{anchor}">{_esc(text)}</h2>')
                else:
                    body.append(f"<h{level + 1}>{_esc(text)}</h{level + 1}>")  # h1 is the report's
            elif kind == "note":
                text = block[1]
                if text.startswith("Critical-difference diagram written to"):
                    body.append(_img(cd_path, "Critical-difference diagram: mean ranks across cases, "
                                              "algorithms joined by a bar do not differ (Nemenyi)"))
                elif text.startswith("No critical-difference diagram written to"):
                    body.append('<p class="note">No critical-difference diagram (Friedman test skipped).</p>')
                else:
                    body.append(f'<p class="note">{_esc(text)}</p>')
            else:
                body.append(f"<h3>{_esc(block[1])}</h3>")
                table = block[2]
                if "per scenario" in block[1] and current is not None:
                    table = _with_units(table, runs, cases[current], metas, cache)
                body.append(_table(table))
        if current is not None:  # no "Across cases" heading followed the last case
            body += figures_of(current)
    title = "heurtune report: " + ", ".join(map(str, pd.unique(runs["experiment"])))
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{_esc(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n"
            + "\n".join(body) + "\n</body>\n</html>\n")


def build_report(dirs, out, *, metric: str = "best_f", alpha: float = 0.05, responses: bool = True,
                 labels: dict | None = None, by: str = "algorithm") -> Path:
    """Read experiment folders and write ``out/index.html``.

    Parameters
    ----------
    dirs : sequence of str or Path
        Experiment results folders (each with ``runs.parquet``; ``history.parquet``,
        ``margins.parquet`` and ``meta.json`` are used when present).
    out : str or Path
        Output folder (created).
    metric : str
        Column compared; lower is better.
    alpha : float
        Significance level, in (0, 1).
    responses : bool
        Draw the response figure of each algorithm's best controller.
    labels : dict, optional
        ``{label: folder}`` for folders of one experiment compared as variants (as
        :func:`heurtune.analysis.compare.load_runs`); default: the folder names.
    by : {"algorithm", "controller"}
        What is compared: the optimisers of each case, or the controller structures of each
        plant case (folders that pose the same problem otherwise; as ``compare --by``).

    Returns
    -------
    Path
        The written ``index.html``.

    Raises
    ------
    ConfigError
        No folder, a folder without readable ``runs.parquet``, incomparable runs, an unknown
        metric or an alpha outside (0, 1).
    """
    dirs = list(dirs)
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must lie in (0, 1), got {alpha:g}")
    runs = load_runs(dirs, labels=labels, by=by)
    check_metric(runs, metric)
    page = render_html(runs, dirs=dirs, history=load_histories(dirs, runs), margins=load_margins(dirs, runs),
                       metas=_read_meta(dirs), metric=metric, alpha=alpha, responses=responses)
    path = Path(out) / "index.html"
    try:
        with atomic_path(path) as tmp:
            tmp.write_text(page, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return path


# ----------------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="python -m heurtune.report", description=__doc__.split("\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=exit_codes(("python -m heurtune.report results/thesis_ch5 --out report",
                                          "python -m heurtune.report results/cs_folqi_qtp results/pso_folqi_qtp "
                                          "--out report --no-responses",
                                          "python -m heurtune.report results/cs_pid_qtp results/cs_fopid_qtp "
                                          "--by controller --out report")))
    ap.add_argument("dirs", nargs="+", metavar="DIR", help="experiment results folder (with runs.parquet)")
    ap.add_argument("--out", help="output folder; the report is OUT/index.html")
    ap.add_argument("--metric", default="best_f", help="column compared, lower is better (default best_f)")
    ap.add_argument("--alpha", type=float, default=0.05, help="significance level (default 0.05)")
    ap.add_argument("--no-responses", action="store_true", help="skip the response figures (no simulation)")
    ap.add_argument("--label", action="append", default=[], metavar="NAME=DIR",
                    help="label of a folder's runs when folders of one experiment are compared as variants")
    ap.add_argument("--by", default="algorithm", metavar="AXIS",
                    help="what is compared: algorithm (default) or controller (the structures of each plant "
                         "case, as compare --by controller)")
    return ap


def run(argv=None) -> int:
    """Command-line entry point; returns the exit code (0 ok, 2 usage or input error).

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
    """
    try:
        args = _parser().parse_args(argv)
        if not args.dirs:
            raise ConfigError("no experiment directories given")
        if not args.out:
            raise ConfigError("--out OUT is required")
        for d in args.dirs:
            if not Path(d).exists():
                raise ConfigError(f"{d}: no such folder")
        path = build_report(args.dirs, args.out, metric=args.metric, alpha=args.alpha,
                            responses=not args.no_responses, labels=parse_labels(args.label), by=args.by)
    except (ConfigError, UsageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"report written to {path}")
    return 0


def main() -> None:
    """Run the command line and exit with its code."""
    _startup.release()  # python -m heurtune.<command>: its imports are done, its own handling takes over
    sys.exit(_startup.run_command(run))
