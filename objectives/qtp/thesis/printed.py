"""The thesis' printed tables (Chapters 4-6) as data.

Each table lives in ``experiments/printed/thesis/table_<chapter>_<number>.csv`` (installed as
``heurtune.experiments/printed/thesis``): a ``row`` key column first, unique within the table,
then key columns (``case``, ``algorithm``, ``scenario``, ``start``, ``input``, ``output``) and one
column per printed quantity under heurtune's names (``Q11`` ... ``alpha2``, ``beta11`` ... ``r4``,
``Mp1`` ... ``J``, ``gain_crossover_rad_s``, ``phase_margin_deg``). Control efforts are stored in
absolute units: where the thesis prints ``J x 10^3`` the stored value is the printed one times
1000 (e.g. Table 4.3's ``3.3025`` is stored as ``3302.5``). A ``-`` cell is empty (NaN). The
folder's README.md lists each table's title, line in the thesis text, row keys, printed scale and
the oddities found while transcribing.

Examples
--------
>>> from heurtune.objectives.qtp.thesis.printed import available_tables, printed_row
>>> available_tables()[:3]
['4.2', '4.3', '4.4']
>>> printed_row("4.3", "min/2")["J"]
3302.5
"""

from __future__ import annotations

import functools
import io
from importlib import resources

import pandas as pd

from heurtune.core.errors import ConfigError

__all__ = ["TABLES", "available_tables", "printed_table", "printed_row", "table_file"]

# Per table: its title (shortened), the line of its caption in the thesis text, and the scale
# at which the thesis prints the control efforts (1000: printed J x 10^3; None: no effort column).
TABLES = {
    "4.2": dict(title="Random initial guesses of FOLQI parameters, minimum phase", line=858, effort_scale=None),
    "4.3": dict(title="Converged FOLQI parameters, minimum phase", line=867, effort_scale=1000),
    "4.4": dict(title="Random initial guesses of FOLQI parameters, non-minimum phase", line=876, effort_scale=None),
    "4.5": dict(title="Converged FOLQI parameters, non-minimum phase", line=885, effort_scale=1000),
    "4.6": dict(title="IOLQI parameters of minimal effort", line=894, effort_scale=1000),
    "4.7": dict(title="LADR parameters of minimal effort", line=900, effort_scale=None),
    "4.8": dict(title="Time-domain metrics under d(t), minimum and non-minimum phase", line=921, effort_scale=1000),
    "4.9": dict(title="Time-domain metrics under d(t) and +-5 % uncertainty, minimum phase", line=959,
                effort_scale=1000),
    "4.10": dict(title="Time-domain metrics under d(t) and +-5 % uncertainty, non-minimum phase", line=981,
                 effort_scale=1000),
    "4.11": dict(title="Stability margins of FOLQI", line=1015, effort_scale=None),
    "4.12": dict(title="Stability margins of IOLQI and LADR", line=1028, effort_scale=None),
    "5.2": dict(title="Converged IOLQI and FOLQI parameters (CS, APSO, FF)", line=1217, effort_scale=None),
    "5.3": dict(title="Convergence epochs, mean and SD of J (CS, APSO, FF)", line=1239, effort_scale=None),
    "5.4": dict(title="Metrics of IOLQI and FOLQI under d(t) (CS, APSO, FF)", line=1264, effort_scale=1000),
    "5.5": dict(title="Metrics under d(t) and +-30 % uncertainty, CS", line=1322, effort_scale=1000),
    "5.6": dict(title="Metrics under d(t) and +-30 % uncertainty, APSO", line=1350, effort_scale=1000),
    "5.7": dict(title="Metrics under d(t) and +-30 % uncertainty, FF", line=1380, effort_scale=1000),
    "5.8": dict(title="Stability margins, CS", line=1450, effort_scale=None),
    "5.9": dict(title="Stability margins, APSO", line=1475, effort_scale=None),
    "5.10": dict(title="Stability margins, FF", line=1496, effort_scale=None),
    "6.3": dict(title="Converged IOLQI and FOLQI parameters (NR, DFP)", line=1825, effort_scale=None),
    "6.4": dict(title="Converged IOLQI and FOLQI parameters (SD, BFGS)", line=1837, effort_scale=None),
    "6.5": dict(title="Control effort under d(t) and +-30 % uncertainty (NR, DFP, SD, BFGS)", line=1849,
                effort_scale=1000),
}


def _key(table) -> str:
    key = str(table).strip()
    if key.lower().startswith("table"):
        key = key[5:].strip().lstrip("_ ")
    key = key.replace("_", ".")
    if key not in TABLES:
        raise ConfigError(f"unknown thesis table {table!r}; allowed: {', '.join(TABLES)}")
    return key


def table_file(table) -> str:
    """The CSV file name of a table, e.g. ``table_4_3.csv`` for ``"4.3"``.

    Parameters
    ----------
    table : str or float
        The table's number.

    Returns
    -------
    str
    """
    return f"table_{_key(table).replace('.', '_')}.csv"


def available_tables() -> list[str]:
    """The transcribed tables, in thesis order: ``['4.2', '4.3', ..., '6.5']``.

    Returns
    -------
    list of str
    """
    return list(TABLES)


@functools.cache
def _text(table: str) -> str:
    path = resources.files("heurtune.experiments") / "printed" / "thesis" / table_file(table)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(
            f"thesis table {table} has no data file {table_file(table)} (installation incomplete?)"
        ) from None


def printed_table(table, *, raw: bool = False) -> pd.DataFrame:
    """One printed table of the thesis.

    Parameters
    ----------
    table : str
        ``"4.2"`` ... ``"6.5"`` (``"table_4_2"`` is accepted too); see :func:`available_tables`.
    raw : bool
        If True, every cell is the string as stored (the printed digits, e.g. ``"0.1180"``,
        efforts scaled to absolute units), empty cells ``""``. Default: numbers as floats
        (``NaN`` for ``-`` cells), key columns ``start``, ``input``, ``output`` as integers.

    Returns
    -------
    pandas.DataFrame
        Columns as stored: ``row`` first, then key columns, then the quantities; the row
        order is the thesis'.

    Raises
    ------
    ConfigError
        For an unknown table (the message names the allowed ones).
    """
    return _parsed(_key(table), bool(raw)).copy()


@functools.cache
def _parsed(key: str, raw: bool) -> pd.DataFrame:
    text = _text(key)
    if raw:
        return pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False)
    return pd.read_csv(io.StringIO(text), dtype={"row": str, "case": str, "algorithm": str, "scenario": str},
                       keep_default_na=False, na_values=[""])


def printed_row(table, row: str) -> dict:
    """One row of a printed table as ``{column: value}`` (the ``row`` key included).

    Parameters
    ----------
    table : str
        See :func:`printed_table`.
    row : str
        The row key, e.g. ``"min/2"`` (Table 4.3), ``"nmp-ladr"`` (Table 4.7),
        ``"min-folqi/firefly"`` (Table 5.2), ``"min-folqi/21"`` (Table 4.11).

    Returns
    -------
    dict
        Floats for the quantities (NaN for an empty cell), strings or ints for the keys.

    Raises
    ------
    ConfigError
        For an unknown table or row (the message names the allowed values).
    """
    df = printed_table(table)
    hit = df[df["row"] == row]
    if hit.empty:
        raise ConfigError(f"table {_key(table)} has no row {row!r}; allowed: {', '.join(df['row'])}")
    out = hit.iloc[0].to_dict()
    return {k: (v.item() if hasattr(v, "item") else v) for k, v in out.items()}
