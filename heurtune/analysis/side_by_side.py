"""Printed tables beside recomputed ones: the cells, the parts and their markdown and LaTeX.

A source's table (the thesis', a paper's) is set beside what heurtune computes for the same
rows. Each quantity takes the columns ``<label> printed`` (the printed digits as printed),
``<label> heurtune``, ``<label> diff`` (heurtune minus printed) and, where a ratio means
something, ``<label> diff %`` (relative to the printed value). A table has one or more parts
(sub-tables with a subtitle), a one-line meaning of its heurtune columns and notes that say why
cells are empty. :mod:`heurtune.objectives.qtp.thesis.tables` (the thesis, chapters 4-6) and
:mod:`heurtune.objectives.tito.papers.tables` (papers 000-002) build their tables from these
pieces, so both write the same layout.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.core.io import atomic_path

__all__ = ["Part", "SideBySideTable", "add_quantity", "decimals_of", "fmt", "make_part", "md_cell", "number",
           "render_latex", "render_markdown", "write_text"]


@dataclasses.dataclass
class Part:
    """One sub-table: a subtitle, the display cells (strings) and their numbers.

    Attributes
    ----------
    subtitle : str
    display : pandas.DataFrame
        Strings as written to the .md and .tex files (printed digits kept; "" for empty).
    values : pandas.DataFrame
        Same shape and columns: the numbers (NaN for empty) or the key strings.
    """

    subtitle: str
    display: pd.DataFrame
    values: pd.DataFrame


@dataclasses.dataclass
class SideBySideTable:
    """A printed table with heurtune's numbers beside the printed ones.

    Attributes
    ----------
    name : str
        The table's name in its source (``"4.3"``, ``"1"``, ``"II"``).
    title : str
    meaning : str
        One line: what the heurtune columns hold.
    parts : list of Part
    notes : list of str
        Why cells are empty, and other caveats.
    """

    name: str
    title: str
    meaning: str
    parts: list
    notes: list = dataclasses.field(default_factory=list)

    @property
    def stem(self) -> str:
        """File name without extension: ``table_<name>`` with dots as underscores."""
        return f"table_{self.name.replace('.', '_')}"


def number(v) -> float:
    """``float(v)``, or NaN for what is not a number (an empty cell, a label).

    Parameters
    ----------
    v : object

    Returns
    -------
    float
    """
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def decimals_of(text: str, value: float) -> int:
    """Decimals to show a recomputed value with: those of the printed text, else 1 for values of
    100 or more and 4 below.

    Parameters
    ----------
    text : str
        The printed digits ("" when nothing is printed).
    value : float
        The recomputed value.

    Returns
    -------
    int
    """
    if text and "e" in text.lower():
        return -1  # printed in powers of ten: show significant digits
    if text and "." in text:
        return max(len(text.split(".")[1].rstrip("%")), 1)
    if value is not None and np.isfinite(value) and abs(value) >= 100:
        return 1
    return 4


def fmt(v: float, decimals: int) -> str:
    """A cell's text: ``decimals`` fixed decimals (-1: four significant digits), "" for NaN.

    Parameters
    ----------
    v : float
    decimals : int

    Returns
    -------
    str
    """
    if v is None or not np.isfinite(v):
        return "" if v is None or np.isnan(v) else ("inf" if v > 0 else "-inf")
    if decimals < 0:  # powers of ten written as the sources print them: 1.92e4, not 1.92e+04
        return re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m.group(1) == "-" else "") + m.group(2), f"{v:.4g}")
    return f"{v:.{decimals}f}"


def add_quantity(cells: tuple, label: str, printed_text: str, value: float, *, decimals: int | None = None,
                 relative: bool = True, diff: bool = True) -> None:
    """Append the cells of one quantity (printed, heurtune, diff[, diff %]) to a row.

    Parameters
    ----------
    cells : tuple of (dict, dict)
        The row's display strings and numbers, filled in place.
    label : str
        The quantity's column label.
    printed_text : str
        The printed digits ("" or None when the source prints nothing).
    value : float
        heurtune's value (NaN when it has none).
    decimals : int, optional
        Decimals of the heurtune and diff cells (default :func:`decimals_of` the printed text).
    relative : bool
        Add ``diff %`` (relative to the printed value).
    diff : bool
        Add ``diff`` (and ``diff %``); False for values that are not meant to agree.
    """
    disp, vals = cells
    p = number(printed_text) if printed_text not in (None, "") else math.nan
    h = number(value)
    d = decimals_of(printed_text or "", h) if decimals is None else decimals
    disp[f"{label} printed"] = printed_text or ""
    vals[f"{label} printed"] = p
    disp[f"{label} heurtune"] = fmt(h, d)
    vals[f"{label} heurtune"] = h
    if not diff:
        return
    dv = h - p if np.isfinite(h) and np.isfinite(p) else math.nan
    disp[f"{label} diff"] = fmt(dv, d)
    vals[f"{label} diff"] = dv
    if relative:
        rv = 100.0 * dv / abs(p) if np.isfinite(dv) and p != 0 else math.nan
        disp[f"{label} diff %"] = fmt(rv, 1)
        vals[f"{label} diff %"] = rv


def make_part(subtitle: str, rows: list) -> Part:
    """A part from rows of ``(display, values)`` dicts (as :func:`add_quantity` fills them).

    Parameters
    ----------
    subtitle : str
    rows : list of tuple of (dict, dict)

    Returns
    -------
    Part
    """
    disp = pd.DataFrame([r[0] for r in rows])
    vals = pd.DataFrame([r[1] for r in rows])
    return Part(subtitle, disp.fillna(""), vals)


def md_cell(s) -> str:
    """A markdown table cell's text: ``s`` with its pipes escaped.

    Parameters
    ----------
    s : object

    Returns
    -------
    str
    """
    return str(s).replace("|", r"\|")


def render_markdown(table: SideBySideTable) -> str:
    """The .md text of a table: title, a 'heurtune:' header line, notes, one pipe table per part.

    Parameters
    ----------
    table : SideBySideTable

    Returns
    -------
    str
    """
    lines = [f"# {table.title}", "", table.meaning, ""]
    for note in table.notes:
        lines.append(f"- note: {note}")
    if table.notes:
        lines.append("")
    for part in table.parts:
        lines += [f"## {part.subtitle}", ""]
        d = part.display
        if d.empty:
            lines += ["(no rows)", ""]
            continue
        num = [not all(isinstance(v, str) for v in part.values[c]) for c in d.columns]
        lines.append("| " + " | ".join(md_cell(c) for c in d.columns) + " |")
        lines.append("|" + "|".join("---:" if n else ":---" for n in num) + "|")
        for _, r in d.iterrows():
            lines.append("| " + " | ".join(md_cell(v) for v in r) + " |")
        lines.append("")
    return "\n".join(lines)


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def _tex(s) -> str:
    return "".join(_TEX.get(ch, ch) for ch in str(s))


# Columns of one LaTeX tabular in \scriptsize: the leading key columns and whole quantities
# (printed, heurtune, diff, diff %) up to this many fit a portrait A4 or letter text width
# (measured with pdflatex on every shipped chapter and paper table, tests/analysis/test_latex_tables.py).
LATEX_MAX_COLUMNS = 7


def _caption(title: str, subtitle: str, k: int, n: int) -> str:
    """A table's caption without the ``Table 5.2:`` LaTeX adds its own number to: the title's
    rest, the source's table in parentheses, the part's subtitle, ``(columns k of n)``."""
    m = re.match(r"^(.*?\bTable [^:]+):\s*(.*)$", title)
    text = f"{m.group(2)} ({m.group(1)})" if m else title
    if subtitle:
        text += f". {subtitle}"
    return text + (f" (columns {k + 1} of {n})" if n > 1 else "")


# The columns :func:`add_quantity` gives a quantity: ``<label> printed``, ``<label> heurtune``, ...
_QUANTITY_COLUMN = re.compile(r"^(.*) (printed|heurtune|diff|diff %)$")


def _quantity_of(column):
    """The quantity's label of one of :func:`add_quantity`'s columns, else None."""
    m = _QUANTITY_COLUMN.match(str(column))
    return m.group(1) if m else None


def _column_groups(columns) -> list:
    """The columns after the keys in groups that stay together: a quantity's printed, heurtune,
    diff and diff % columns (one label), any other column alone."""
    groups, label = [], None
    for c in columns:
        head = _quantity_of(c)
        if groups and head is not None and head == label:
            groups[-1].append(c)
        else:
            groups.append([c])
        label = head
    return groups


def _chunks(columns, keys) -> list:
    """The columns after the keys split into tabulars of at most :data:`LATEX_MAX_COLUMNS` with
    the keys repeated, whole quantities kept together (a wider quantity alone)."""
    room = max(1, LATEX_MAX_COLUMNS - len(keys))
    chunks = []
    for group in _column_groups([c for c in columns if c not in keys]):
        if chunks and len(chunks[-1]) + len(group) <= room:
            chunks[-1] += group
        else:
            chunks.append(list(group))
    return chunks or [[]]


# A text column with a longer cell than this (a polynomial's coefficients) wraps in a paragraph
# column of WRAP_WIDTH rather than widening the table past the page.
WRAP_ABOVE = 20
WRAP_WIDTH = r"0.25\textwidth"
# Leading text columns repeated in every tabular of a split part (the rows' keys).
MAX_KEYS = 3


def _column_format(cells, is_text: bool) -> str:
    """``r`` for numbers, ``l`` for text, a wrapping ``p{...}`` for long text."""
    if not is_text:
        return "r"
    return f"p{{{WRAP_WIDTH}}}" if max((len(str(v)) for v in cells), default=0) > WRAP_ABOVE else "l"


def _stacked(name) -> str:
    """A column's name in its header cell: a long name of several words on two lines
    (``\\shortstack``), so that the name does not make the column wider than its numbers."""
    words = str(name).split(" ")
    if len(str(name)) <= 10 or len(words) < 2:
        return _tex(name)
    # the split into two lines of the most even lengths
    cut = min(range(1, len(words)), key=lambda i: abs(len(" ".join(words[:i])) - len(" ".join(words[i:]))))
    return f"\\shortstack{{{_tex(' '.join(words[:cut]))}\\\\{_tex(' '.join(words[cut:]))}}}"


def _header(keys, chunk) -> list:
    """The header rows of a tabular: a quantity's name once over its columns (``\\multicolumn``
    and a ``\\cmidrule``), then the keys' names and the columns' own (printed, heurtune, diff,
    diff %): a column is as wide as its numbers, not as its quantity's name."""
    groups = _column_groups(chunk)
    if all(len(g) == 1 for g in groups):
        return [" & ".join([_tex(c) for c in keys] + [_stacked(c) for c in chunk]) + r" \\"]
    top, rules, low, at = [""] * len(keys), [], [_tex(c) for c in keys], len(keys) + 1
    for g in groups:
        if len(g) == 1:
            top.append("")
            low.append(_stacked(g[0]))
        else:
            head = _quantity_of(g[0])
            top.append(f"\\multicolumn{{{len(g)}}}{{c}}{{{_tex(head)}}}")
            rules.append(f"\\cmidrule(lr){{{at}-{at + len(g) - 1}}}")
            low += [_tex(str(c)[len(head) + 1:]) for c in g]
        at += len(g)
    return [" & ".join(top) + r" \\", "".join(rules), " & ".join(low) + r" \\"]


def render_latex(table: SideBySideTable, *, label_prefix: str = "") -> str:
    """The .tex text of a table: booktabs ``table`` environments, one per part and group of
    columns (a wide part is split with its key columns repeated, so that each fits a portrait
    page), each with a caption and a unique ``\\label``; the notes under the last one. The first
    line names the package it needs.

    Parameters
    ----------
    table : SideBySideTable
    label_prefix : str
        Put before each label (the experiment's name), so that the tables of several
        experiments can be input in one document.

    Returns
    -------
    str
    """
    out = [r"% needs \usepackage{booktabs}", f"% {_tex(table.title)}", f"% {_tex(table.meaning)}"]
    for note in table.notes:
        out.append(f"% note: {_tex(note)}")
    shown = [p for p in table.parts if not p.display.empty]
    notes = (r"\par\smallskip{\footnotesize\raggedright Notes: "
             + " ".join(f"({k}) {_tex(n)}." for k, n in enumerate(table.notes, start=1)) + r"\par}")
    base = re.sub(r"[^a-z0-9]+", "-", f"{label_prefix} {table.stem}".lower()).strip("-")
    for i, part in enumerate(shown):
        d = part.display
        text = [all(isinstance(v, str) for v in part.values[c]) for c in d.columns]
        keys = []
        for c, is_text in zip(d.columns, text):  # the leading text columns: the rows' keys
            if not is_text or len(keys) == MAX_KEYS or len(keys) == len(d.columns) - 1:
                break
            keys.append(c)
        chunks = _chunks(list(d.columns), keys)
        for k, chunk in enumerate(chunks):
            cols = keys + chunk
            colfmt = "".join(_column_format(d[c], text[list(d.columns).index(c)]) for c in cols)
            label = f"tab:{base}" + (f"-{i + 1}" if len(shown) > 1 else "") + (f"-{k + 1}" if len(chunks) > 1 else "")
            out += [r"\begin{table}[htbp]", r"\centering", r"\scriptsize",
                    f"\\caption{{{_tex(_caption(table.title, part.subtitle, k, len(chunks)))}}}",
                    f"\\label{{{label}}}",
                    f"\\begin{{tabular}}{{{colfmt}}}", r"\toprule", *_header(keys, chunk), r"\midrule"]
            out += [" & ".join(_tex(v) for v in r) + r" \\" for r in d[cols].itertuples(index=False, name=None)]
            out += [r"\bottomrule", r"\end{tabular}"]
            if table.notes and part is shown[-1] and k == len(chunks) - 1:  # where a reader of the PDF sees them
                out += [notes]
            out += [r"\end{table}", ""]
    return "\n".join(out)


def write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8).

    Parameters
    ----------
    path : str or Path
    text : str

    Returns
    -------
    Path
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path
