"""The comparison report as text: markdown, CSV or LaTeX tables of the summary, the tests, the
re-evaluated best runs and the margins, per case (:func:`report`). :mod:`heurtune.analysis.compare`
is its command line.
"""

from __future__ import annotations

import io
import re

import numpy as np
import pandas as pd

from heurtune.analysis.figures import cd_diagram
from heurtune.analysis.runs import check_metric, margins_table, reevaluation_table
from heurtune.analysis.stats import (
    A12_THRESHOLDS,
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    CI_LEVEL,
    find_winners,
    friedman_across_cases,
    kruskal_test,
    pairwise_tests,
    summary_table,
)
from heurtune.core.errors import ConfigError

__all__ = [
    "FORMATS", "LATEX_MAX_COLUMNS", "LATEX_PACKAGES", "report", "report_blocks",
]


FORMATS = ("md", "csv", "latex")


def _fmt(x, digits: int = 5) -> str:
    if x is None or x is pd.NA:
        return ""
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        if np.isnan(x):
            return ""
        return f"{x:.{digits}g}"
    return str(x)


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
        "<": r"\textless{}", ">": r"\textgreater{}", "|": r"\textbar{}"}


def _tex(s: str) -> str:
    return "".join(_TEX.get(ch, ch) for ch in str(s))


def _numeric_columns(df: pd.DataFrame) -> list[bool]:
    return [pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c])
            for c in df.columns]


def _md_table(df: pd.DataFrame, formats: dict) -> str:
    num = _numeric_columns(df)
    head = [str(c).replace("|", r"\|") for c in df.columns]
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join("---:" if n else ":---" for n in num) + "|"]
    for _, r in df.iterrows():
        cells = [_fmt(v, formats.get(c, 5)).replace("|", r"\|") for c, v in r.items()]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _have_jinja2() -> bool:
    try:
        import jinja2  # noqa: F401
    except ImportError:
        return False
    return True


def _tabular(cells: pd.DataFrame, column_format: str) -> str:
    """A booktabs tabular of pre-formatted, pre-escaped string cells (pandas' to_latex layout)."""
    lines = [f"\\begin{{tabular}}{{{column_format}}}", r"\toprule",
             " & ".join(cells.columns) + r" \\", r"\midrule"]
    lines += [" & ".join(r) + r" \\" for r in cells.itertuples(index=False, name=None)]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


# The widest LaTeX table: its leading text columns (algorithm, pair) and at most this many
# others. A wider one is split into parts that repeat the leading columns, so that every part
# fits an A4 or letter text width in \\small (measured with pdflatex on benchmark_qtp's report).
LATEX_MAX_COLUMNS = 7


# What the LaTeX output needs in the preamble (said in its first line).
LATEX_PACKAGES = ("booktabs",)


def _latex_label(title: str) -> str:
    """A \\label key from a table's title: ``tab:`` and its words, lowercase, joined by ``-``."""
    words, key = re.findall(r"[a-z0-9]+", title.lower()), ""
    for word in words:  # whole words, up to 120 characters
        if key and len(key) + 1 + len(word) > 120:
            break
        key = f"{key}-{word}" if key else word
    return "tab:" + key


def _latex_table(df: pd.DataFrame, formats: dict, title: str, use_pandas: bool | None = None,
                 label_prefix: str = "", used: set | None = None) -> str:
    num = _numeric_columns(df)
    cols = list(df.columns)
    keys = []
    for c, n in zip(cols, num):  # the leading text columns, repeated in every part
        if n or len(keys) == 2:
            break
        keys.append(c)
    rest = [c for c in cols if c not in keys]
    width = max(1, LATEX_MAX_COLUMNS - len(keys))
    chunks = [rest[i:i + width] for i in range(0, len(rest), width)] or [[]]
    if use_pandas is None:
        use_pandas = _have_jinja2()
    out = []
    for k, chunk in enumerate(chunks):
        part = df[keys + chunk]
        flags = [num[cols.index(c)] for c in part.columns]
        colfmt = "".join("r" if n else "l" for n in flags)
        cells = pd.DataFrame({_tex(c): [_tex(_fmt(v, formats.get(c, 5))) for v in part[c]] for c in part.columns},
                             columns=[_tex(c) for c in part.columns])
        body = (cells.to_latex(index=False, escape=False, column_format=colfmt) if use_pandas
                else _tabular(cells, colfmt))
        caption = title if len(chunks) == 1 else f"{title} (part {k + 1} of {len(chunks)})"
        label = _latex_label(f"{label_prefix} {title}") + ("" if len(chunks) == 1 else f"-{k + 1}")
        if used is not None:  # unique in the document: a repeat gets a number
            again, n = label, 2
            while again in used:
                again, n = f"{label}-{n}", n + 1
            label = again
            used.add(label)
        out.append("\\begin{table}[htbp]\n\\centering\n\\small\n" + f"\\caption{{{_tex(caption)}}}\n"
                   + f"\\label{{{label}}}\n" + body + "\\end{table}")
    return "\n\n".join(out)


def _methods_note(alpha: float) -> str:
    th = ", ".join(f"{name} >= {t:g}" for name, t in A12_THRESHOLDS)
    return (f"Only successful runs (not failed, best candidate feasible) enter the statistics; failed and "
            f"infeasible runs are counted in the success rate. Within a case the runs of different algorithms "
            f"are independent samples: Kruskal-Wallis test, Dunn's post-hoc test and two-sided Wilcoxon "
            f"rank-sum (Mann-Whitney U) tests, both Holm-corrected within the case, alpha = {alpha:g}. "
            f"Effect size: Vargha-Delaney A12 = P(a run of A is lower than one of B), ties count half, 0.5 = "
            f"no effect; magnitude of |A12 - 0.5|: negligible below 0.06, {th}. A pair is won only when "
            f"both Holm-adjusted p-values (Dunn, rank-sum) are < {alpha:g} and the effect is at least small. "
            f"Intervals: {CI_LEVEL:.0%} percentile bootstrap, {BOOTSTRAP_RESAMPLES} resamples, "
            f"seed {BOOTSTRAP_SEED}. Across cases: Friedman test on the per-case medians with Nemenyi's post-hoc test.")


def report_blocks(runs: pd.DataFrame, metric: str, alpha: float, margins: pd.DataFrame | None = None,
                  cd_path=None) -> list:
    """The statistical comparison as format-free blocks, which :func:`report` writes as text,
    markdown or LaTeX and the HTML report (:mod:`heurtune.analysis.report`) as HTML.

    Parameters
    ----------
    runs : pandas.DataFrame
        Runs as :func:`heurtune.analysis.runs.load_runs` returns them.
    metric : str
        The column compared (lower is better).
    alpha : float
        Significance level of the tests.
    margins : pandas.DataFrame, optional
        Stability margins of the best runs, for their table.
    cd_path : path-like, optional
        Where the critical-difference diagram is drawn, when one is.

    Returns
    -------
    list of tuple
        ``("heading", level, text)``, ``("note", text)`` and ``("table", title, df, formats)``
        in reading order.
    """
    marg = margins_table(margins) if margins is not None and len(margins) else pd.DataFrame()
    summary = summary_table(runs, metric)
    pairs = pairwise_tests(runs, metric, alpha)
    kw = kruskal_test(runs, metric)
    winners = find_winners(pairs, alpha)
    reeval = reevaluation_table(runs) if "best_f" in runs.columns else pd.DataFrame()
    fried = friedman_across_cases(runs, metric, alpha)

    experiments = ", ".join(pd.unique(runs["experiment"])) if "experiment" in runs else ""
    by_structure = runs.attrs.get("compared_by") == "controller"
    optimisers = ", ".join(pd.unique(runs["optimiser"])) if by_structure and "optimiser" in runs else ""
    blocks = [("heading", 1, f"Statistical comparison of {metric}"
               + (" between controller structures" if by_structure else "")),
              ("note", f"Experiments: {experiments}. Metric {metric}, lower is better."
               + (f" The rows are controller structures, tuned by {optimisers}." if by_structure else "")),
              ("note", _methods_note(alpha))]
    p_fmt = {"p": 3, "p (Holm)": 3, "p Dunn": 3, "p Dunn (Holm)": 3, "A12": 3, "A12 low": 3, "A12 high": 3}
    for case in pd.unique(runs["case"]):
        rows = runs[runs["case"] == case]
        winner = winners.get(case)
        blocks.append(("heading", 2, f"Case {case}"))
        if "problem_id" in rows:
            blocks.append(("note", f"problem_id {', '.join(pd.unique(rows['problem_id']))}"))

        s = summary[summary["case"] == case].drop(columns="case").reset_index(drop=True)
        k = kw[kw["case"] == case]
        s["mean rank"] = s["algorithm"].map(dict(zip(k["algorithm"], k["mean_rank"])))
        s["algorithm"] = [a + "*" if a == winner else a for a in s["algorithm"]]
        s = s.rename(columns={"sd": "SD", "median_ci_low": "median CI low", "median_ci_high": "median CI high",
                              "mean_convergence_epoch": "conv. epoch",
                              "mean_convergence_evals": "conv. evals", "feasible_rate": "feasible rate",
                              "success_rate": "success rate"})
        blocks.append(("table", f"Case {case}: {metric} over successful runs", s,
                       {"mean rank": 3, "feasible rate": 3, "success rate": 3}))

        algs = pd.unique(rows["algorithm"])
        if winner is not None:
            blocks.append(("note", f"* {winner}: significantly better than every other algorithm of this "
                                   f"case (Holm-adjusted Dunn and rank-sum p < {alpha:g}, A12 effect at least small)."))
        elif len(algs) > 1:
            blocks.append(("note", f"No winner: no algorithm wins against every other (Holm-adjusted Dunn "
                                   f"and rank-sum p < {alpha:g}, A12 effect at least small)."))
        else:
            blocks.append(("note", "Only one algorithm: nothing to compare."))
        if len(algs) > 1 and len(k):
            r = k.iloc[0]
            n_ok, n_all = int(k["n"].sum()), int(len(rows))
            used = int((k["n"] > 0).sum())
            if np.isnan(r["statistic"]):
                why = ("fewer than two algorithms with a successful run" if used < 2 else "all values are equal")
                blocks.append(("note", f"Kruskal-Wallis test not computed: {why} ({n_ok} of {n_all} runs "
                                       f"successful)."))
            else:
                blocks.append(("note", f"Kruskal-Wallis test over {n_ok} successful runs of {used} algorithms "
                                       f"({n_all - n_ok} failed or infeasible runs left out): "
                                       f"H = {_fmt(r['statistic'], 4)}, df = {int(r['df'])}, "
                                       f"p = {_fmt(r['p'], 3)}."))

        pc = pairs[pairs["case"] == case]
        if len(pc):
            t = pd.DataFrame({"A": pc["algorithm_a"], "B": pc["algorithm_b"], "n A": pc["n_a"], "n B": pc["n_b"],
                              "median A": pc["median_a"], "median B": pc["median_b"], "U": pc["U"],
                              "p": pc["p"], "p (Holm)": pc["p_holm"], "p Dunn": pc["p_dunn"],
                              "p Dunn (Holm)": pc["p_dunn_holm"], "A12": pc["a12"], "A12 low": pc["a12_low"],
                              "A12 high": pc["a12_high"], "effect": pc["effect"], "better": pc["better"],
                              "win": pc["win"]}).reset_index(drop=True)
            blocks.append(("table", f"Case {case}: pairwise tests (Wilcoxon rank-sum, Dunn) and A12 effect sizes",
                           t, p_fmt))

        rc = reeval[reeval["case"] == case] if len(reeval) else reeval
        if len(rc):
            t = rc.drop(columns="case").reset_index(drop=True)
            t["algorithm"] = [a + "*" if a == winner else a for a in t["algorithm"]]
            blocks.append(("table", f"Case {case}: best run of each algorithm per scenario", t, {}))

        mc = marg[marg["case"] == case] if len(marg) else marg
        if len(mc):
            t = mc.drop(columns="case").reset_index(drop=True)
            t["algorithm"] = [a + "*" if a == winner else a for a in t["algorithm"]]
            blocks.append(("table", f"Case {case}: loop margins of each algorithm's best run (input i, output j)",
                           t, {"gain crossover (rad/s)": 4, "phase margin (deg)": 4}))

    blocks.append(("heading", 2, "Across cases"))
    if fried.cases_left_out:
        blocks.append(
            ("note", f"Cases left out (no algorithm has a successful run): {', '.join(fried.cases_left_out)}.")
        )
    if fried.left_out:
        blocks.append(("note", f"Left out (no successful run in some case): {', '.join(fried.left_out)}."))
    if fried.skipped:
        blocks.append(("note", f"Friedman test across cases skipped: {fried.skipped}."))
        if cd_path is not None:
            blocks.append(("note", f"No critical-difference diagram written to {cd_path}."))
        return blocks
    n_cases, k = fried.medians.shape
    stat = _fmt(fried.statistic, 4) or "n/a"
    blocks.append(("note", f"Friedman test on the medians of the successful runs, {n_cases} cases (blocks) x "
                           f"{k} algorithms: chi2 = {stat}, df = {k - 1}, p = {_fmt(fried.p, 3) or 'n/a'}. "
                           f"Nemenyi critical difference of mean ranks at alpha = {alpha:g}: "
                           f"CD = {_fmt(fried.cd, 4)}."))
    t = fried.medians.T.reset_index().rename(columns={"index": "algorithm"})
    t.columns = [str(c) for c in t.columns]
    t["mean rank"] = fried.mean_ranks.to_numpy()
    blocks.append(("table", "Across cases: median per case and mean rank", t, {"mean rank": 3}))
    nem = fried.nemenyi.reset_index().rename(columns={"index": "algorithm"})
    nem.columns = [str(c) for c in nem.columns]
    blocks.append(("table", "Across cases: Nemenyi p-values", nem, {str(c): 3 for c in fried.nemenyi.columns}))
    if cd_path is not None:
        cd_diagram(fried, cd_path)
        blocks.append(("note", f"Critical-difference diagram written to {cd_path}."))
    return blocks


def report(runs: pd.DataFrame, metric: str = "best_f", alpha: float = 0.05, fmt: str = "md",
           margins: pd.DataFrame | None = None, cd_path=None) -> str:
    """Render the full comparison (summary, tests, winner, re-evaluation, margins) for every case.

    The report ends with the comparison across cases (:func:`friedman_across_cases`), or a note
    saying why it was skipped.

    Parameters
    ----------
    runs : pandas.DataFrame
        Rows of :func:`load_runs`.
    metric : str
        Column compared; lower is better.
    alpha : float
        Significance level for the Holm-adjusted p-values.
    fmt : {"md", "csv", "latex"}
        ``md``: headings and pipe tables. ``csv``: one CSV table per block, separated by blank
        lines, headings and notes as ``# ...`` lines, numbers unrounded. ``latex``: starred
        sectioning commands and ``table`` environments with booktabs tabulars (needs
        ``\\usepackage{booktabs}``, said in a first comment line), each ``\\small`` with a
        ``\\label`` (``tab:``, the experiments' and its caption's words, unique in the report); a
        table wider than
        :data:`LATEX_MAX_COLUMNS` is split into parts that repeat its leading text columns, and
        each case starts on a new page (``\\clearpage``) so that no table drifts past the next
        case's heading.
    margins : pandas.DataFrame, optional
        Rows of :func:`load_margins`; when given and not empty, each case ends with the table
        of :func:`margins_table`.
    cd_path : str or Path, optional
        Where to write the critical-difference diagram (:func:`cd_diagram`) when the Friedman
        test across cases is run; nothing is written otherwise (the report says so).

    Returns
    -------
    str
        The report, ending with a newline. The winner of a case carries an asterisk and is
        explained in a note line.
    """
    if fmt not in FORMATS:
        raise ConfigError(f"unknown format '{fmt}' (choose from {', '.join(FORMATS)})")
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must lie in (0, 1), got {alpha:g}")
    check_metric(runs, metric)
    parts = []
    # labels start with the experiments compared: two reports input in one document stay apart
    prefix = " ".join(pd.unique(runs["experiment"].astype(str))) if "experiment" in runs else ""
    labels = set()
    for block in report_blocks(runs, metric, alpha, margins, cd_path):
        kind = block[0]
        if fmt == "md":
            if kind == "heading":
                parts.append("#" * block[1] + " " + block[2])
            elif kind == "note":
                text = block[1]
                parts.append("\\" + text if text.startswith("*") else text)
            else:
                parts.append(f"### {block[1]}\n\n" + _md_table(block[2], block[3]))
        elif fmt == "csv":
            if kind == "heading":
                parts.append("# " + block[2])
            elif kind == "note":
                parts.append("# " + block[1])
            else:
                buf = io.StringIO()
                block[2].to_csv(buf, index=False, lineterminator="\n")
                parts.append("# " + block[1] + "\n" + buf.getvalue().rstrip("\n"))
        else:
            if kind == "heading":
                cmd = {1: "section", 2: "subsection"}.get(block[1], "subsubsection")
                if block[1] <= 2 and len(parts) > 1:
                    parts.append("\\clearpage")  # the tables of one case stay before the next one's heading
                parts.append(f"\\{cmd}*{{{_tex(block[2])}}}")
            elif kind == "note":
                parts.append(_tex(block[1]))
            else:
                parts.append(_latex_table(block[2], block[3], block[1], label_prefix=prefix, used=labels))
    if fmt == "latex":
        parts.insert(0, f"% heurtune.compare: needs \\usepackage{{{', '.join(LATEX_PACKAGES)}}}; tables are "
                        f"labelled tab:<the experiments' and their caption's words>")
    return "\n\n".join(parts) + "\n"
