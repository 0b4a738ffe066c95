"""The printed tables of papers 000, 001 and 002 (TITO coupled tanks) as data.

Each table lives in ``experiments/printed/paper_<nnn>/<table>.csv`` (installed as
``heurtune.experiments/printed/paper_<nnn>``): a ``row`` key column first, unique within the table,
then key columns (``controller``, ``plant``, ``loop``, ``element``, ``polynomial``, ``matrix``,
``i``, ``name``), one column per printed quantity and last the ``line`` of the seed text where the
row's numbers are printed. Numbers keep the printed digits (``1.55×10^{-4}`` is stored ``1.55e-4``);
a value that is not printed is an empty cell (NaN). Besides the numbered tables (``table_1`` ...,
``table_I``, ``table_II``) the printed equations are gathered in ``fopdt``, ``controllers``,
``plants`` / ``model`` and ``polynomials``. Each folder's README.md gives the format, every table's
caption line and the remarks made while transcribing (typos kept as printed).

Examples
--------
>>> from heurtune.objectives.tito.papers.printed import printed_table, printed_tables
>>> printed_tables("002")
['table_I', 'table_II', 'model', 'fopdt']
>>> df = printed_table("000", "table_1")
>>> float(df.loc[df["row"] == "Proposed PID/1", "ITAE_regulatory"].iloc[0])
0.000155
"""

from __future__ import annotations

import functools
import io
from importlib import resources
from pathlib import Path

import pandas as pd

from heurtune.core.errors import ConfigError

__all__ = ["PAPERS", "TABLES", "printed_path", "printed_table", "printed_tables"]

PAPERS = ("000", "001", "002")

# Per paper and table: its title (shortened) and the line of its caption in the seed text (for the
# tables gathered from equations: the line of the first equation).
TABLES = {
    "000": {
        "table_1": dict(title="Quadruple tank system (QTS): IAE, ISE, ITAE, servo and regulatory", line=296),
        "table_2": dict(title="Coupled conical tank system (CCTS): IAE, ISE, ITAE, servo and regulatory", line=347),
        "table_3": dict(title="Coupled spherical tank system (CSTS): IAE, ISE, ITAE, servo and regulatory",
                        line=408),
        "table_4": dict(title="Hurwitz matrix and row-reduced Hurwitz matrix, QTS", line=503),
        "table_5": dict(title="Hurwitz matrix and row-reduced Hurwitz matrix, CSTS", line=528),
        "table_6": dict(title="Hurwitz matrix and row-reduced Hurwitz matrix, CCTS", line=584),
        "fopdt": dict(title="FOPDT models of the decoupled loops (eqs. 46-47, 51-52, 56-57, 59)", line=286),
        "controllers": dict(title="Proposed decentralized PID controllers (eqs. 48, 53, 58, 60)", line=292),
        "polynomials": dict(title="QTS characteristic polynomial and Kharitonov polynomials (eqs. 66-70)",
                            line=489),
        "plants": dict(title="TITO plants and decouplers (eqs. 44-45, 49-50, 54-55)", line=272),
    },
    "001": {
        "table_1": dict(title="Coupled conical tank (CCTS): IAE, ISE, ITAE", line=281),
        "table_2": dict(title="Coupled spherical tank (CSTS): IAE, ISE, ITAE", line=359),
        "table_3": dict(title="Quadruple tank system (QTS): IAE, ISE, ITAE", line=446),
        "fopdt": dict(title="FOPDT models of the decoupled loops (eqs. 37-38, 43-44, 49-50)", line=257),
        "controllers": dict(title="GPM PI and PID controllers (eqs. 39-40, 45-46, 51-52)", line=263),
        "plants": dict(title="TITO plants and decouplers (eqs. 35-36, 41-42, 47-48)", line=247),
    },
    "002": {
        "table_I": dict(title="Proposed controller parameters for simulation", line=1023),
        "table_II": dict(title="Performance analysis: ts, max|u|, RMS error, IAE, TV", line=1211),
        "model": dict(title="Identified TITO model (eq. 28) and decoupler (eq. 29)", line=905),
        "fopdt": dict(title="FOPDT models of the decoupled loops (eq. 31)", line=966),
    },
}

# Columns read as text (everything else that is not an integer key is a float).
_TEXT = {"row", "controller", "plant", "element", "polynomial", "matrix", "comment", "name",
         "lags", "leads", "num", "den"}
_INT = {"loop", "i", "equation", "line"}


def _paper(paper) -> str:
    key = str(paper).strip().lower()
    if key.startswith("paper"):
        key = key[5:].strip().lstrip("_ ")
    if key.isdigit():
        key = key.zfill(3)
    if key not in PAPERS:
        raise ConfigError(f"unknown paper {paper!r}; allowed: {', '.join(PAPERS)}")
    return key


def _table(paper: str, table) -> str:
    tables = TABLES[paper]
    key = str(table).strip()
    if key not in tables:
        low = key.lower().replace(" ", "_").replace(".", "")
        if low.startswith("table_"):
            low = low[6:]
        elif low.startswith("table"):
            low = low[5:]
        by_lower = {name.lower(): name for name in tables}
        key = by_lower.get(low) or by_lower.get(f"table_{low}") or key
    if key not in tables:
        raise ConfigError(f"paper {paper} has no table {table!r}; allowed: {', '.join(tables)}")
    return key


def printed_tables(paper) -> list[str]:
    """The transcribed tables of a paper, numbered tables first: e.g. ``['table_I', 'table_II', 'model',
    'fopdt']`` for ``"002"``.

    Parameters
    ----------
    paper : str or int
        ``"000"``, ``"001"`` or ``"002"`` (``0``, ``"paper_000"`` are accepted too).

    Returns
    -------
    list of str

    Raises
    ------
    ConfigError
        For an unknown paper (the message names the allowed ones).
    """
    return list(TABLES[_paper(paper)])


def printed_path(paper, table) -> Path:
    """The CSV file of one printed table, e.g. ``.../printed/paper_000/table_1.csv``.

    Parameters
    ----------
    paper : str or int
        See :func:`printed_tables`.
    table : str
        A name of :func:`printed_tables` (``"1"``, ``"Table 1"``, ``"I"`` are accepted for ``table_1``,
        ``table_I``).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ConfigError
        For an unknown paper or table (the message names the allowed values).
    """
    key = _paper(paper)
    name = _table(key, table)
    path = resources.files("heurtune.experiments") / "printed" / f"paper_{key}" / f"{name}.csv"
    return path if isinstance(path, Path) else Path(str(path))


@functools.cache
def _text(paper: str, table: str) -> str:
    path = printed_path(paper, table)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(
            f"paper {paper} table {table} has no data file {path.name} (installation incomplete?)"
        ) from None


def printed_table(paper, table, *, raw: bool = False) -> pd.DataFrame:
    """One printed table of a paper.

    Parameters
    ----------
    paper : str or int
        ``"000"``, ``"001"`` or ``"002"``; see :func:`printed_tables`.
    table : str
        A name of :func:`printed_tables`, e.g. ``"table_1"``, ``"fopdt"``, ``"table_II"``.
    raw : bool
        If True, every cell is the string as stored (the printed digits, e.g. ``"1.10e-4"``), empty
        cells ``""``. Default: the quantities as floats (NaN for a value not printed), the keys
        ``loop``, ``i``, ``equation`` and ``line`` as integers, the text columns (``row``,
        ``controller``, ``plant``, ``element``, ``polynomial``, ``matrix``, ``comment``, ``name`` and
        the space-separated ``lags``, ``leads``, ``num``, ``den``) as strings (``""`` when empty).

    Returns
    -------
    pandas.DataFrame
        Columns as stored, ``row`` first and ``line`` last, rows in the file's order; no index
        beyond the default one.

    Raises
    ------
    ConfigError
        For an unknown paper or table (the message names the allowed values).
    """
    key = _paper(paper)
    return _parsed(key, _table(key, table), bool(raw)).copy()


@functools.cache
def _parsed(paper: str, table: str, raw: bool) -> pd.DataFrame:
    df = pd.read_csv(io.StringIO(_text(paper, table)), dtype=str, keep_default_na=False)
    if raw:
        return df
    for col in df.columns:
        if col in _INT:
            df[col] = df[col].astype(int)
        elif col not in _TEXT:
            df[col] = pd.to_numeric(df[col].where(df[col] != "")).astype(float)
    return df
