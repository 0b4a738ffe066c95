"""The transcribed tables of papers 000, 001 and 002 against the seed text, and their loader.

Every CSV row names the seed line where its numbers are printed (column ``line``); each number of
the row must be among the numbers parsed from that line (relative tolerance 1e-12), and for the
numbered tables the numbers of each such line must all be transcribed. The seed texts are looked
for in ``shared/seeds`` beside or above the checkout (or ``$HEURTUNE_SEEDS``); without them those
tests are skipped.
"""

from __future__ import annotations

import math
import os
import re
from importlib import resources
from pathlib import Path

import pandas as pd
import pytest

from heurtune.core.errors import ConfigError
from heurtune.objectives.tito.papers.printed import PAPERS, TABLES, printed_path, printed_table, printed_tables

SEED_FILES = {"000": "000_3e18fbfb14721aa8.txt", "001": "001_0fd6583242fa7715.txt",
              "002": "002_2879d5f8d36ee37b.txt"}

# Columns that are keys, labels or references, not printed quantities.
KEYS = {"row", "controller", "loop", "plant", "element", "polynomial", "matrix", "i", "comment", "name",
        "equation", "line"}
# Tables whose rows' numbers spread over more than one seed line: (paper, table) -> number of lines
# read from ``line`` on (numerator, blank line, denominator).
SPAN = {("002", "model"): 3, ("002", "fopdt"): 3}

ALL = [(paper, table) for paper in PAPERS for table in TABLES[paper]]
NUMBERED = [(paper, table) for paper, table in ALL if table.startswith("table_")]

SHAPES = {
    ("000", "table_1"): (10, 10), ("000", "table_2"): (10, 10), ("000", "table_3"): (10, 10),
    ("000", "table_4"): (42, 12), ("000", "table_5"): (48, 12), ("000", "table_6"): (48, 12),
    ("000", "fopdt"): (8, 8), ("000", "controllers"): (8, 8), ("000", "polynomials"): (5, 11),
    ("000", "plants"): (18, 11),
    ("001", "table_1"): (12, 7), ("001", "table_2"): (12, 7), ("001", "table_3"): (12, 7),
    ("001", "fopdt"): (6, 8), ("001", "controllers"): (12, 12), ("001", "plants"): (16, 11),
    ("002", "table_I"): (2, 8), ("002", "table_II"): (4, 9), ("002", "model"): (6, 11), ("002", "fopdt"): (2, 8),
}


# ----------------------------------------------------------------------------------------------
# Reading numbers off a seed line
# ----------------------------------------------------------------------------------------------

# One printed number, left to right: a×10^{b} in the paper's notations (1.55×10^{-4}, 1.172 \times 10^{5},
# 7.16 imes 10^4 with the backslash lost), a bare 10^{b}, or a plain unsigned number.
_NUMBER = re.compile(r"(\d+(?:\.\d+)?)\s*(?:×|\\times|imes)\s*10\^\{?(-?\d+)\}?|10\^\{?(-?\d+)\}?|\d+(?:\.\d+)?")
# A term whose coefficient 1 is implicit: e^{-s} (dead time 1), "s^6 + ..." (monic polynomial).
_UNIT = re.compile(r"e\^\{-s\}|(?<![\d.}])s\^")
# Labels whose digits are not printed values: citations [47], h_1, u1-y1, K^1(s).
_LABELS = re.compile(r"\[\d+\]|h_\{?\d\}?|u\d\s*-\s*y\d|\^\{?\d\}?\(s\)")


def numbers_on(text: str) -> list[float]:
    """All unsigned numbers printed on a piece of seed text in printed order, a×10^{b} read as one
    number; a 1 is appended where a coefficient 1 is implicit."""
    out = []
    for m in _NUMBER.finditer(text.replace("−", "-")):
        if m.group(1) is not None:
            out.append(float(f"{m.group(1)}e{m.group(2)}"))
        elif m.group(3) is not None:
            out.append(float(f"1e{m.group(3)}"))
        else:
            out.append(float(m.group(0)))
    if _UNIT.search(text):
        out.append(1.0)
    return out


def test_numbers_on_reads_the_papers_notations():
    assert numbers_on("Proposed PID\th_1\t6.96\t235\t1.55×10^{-4}") == [1.0, 6.96, 235.0, 1.55e-4]
    assert numbers_on("$7.16 imes 10^4 \\ 3.58 imes 10^4$") == [7.16e4, 3.58e4]
    assert numbers_on("\\begin{array}{c} 1.172 \\times 10^{5} \\\\ 8.228 \\times 10^{4}") == [1.172e5, 8.228e4]
    assert numbers_on("x 10^{5} y") == [1e5]
    assert numbers_on("2.197e(−5.5s)") == [2.197, 5.5]
    assert 1.0 in numbers_on("\\frac{-(246.33s+0.73)}{762.72s+1.84} e^{-s}")
    assert 1.0 in numbers_on("= s^6 + 31.06s^5")
    assert 1.0 not in numbers_on("859.2s^6 + 589.7s^5")


def cell_values(cell) -> list[float]:
    """The numbers of one CSV cell as stored: a float, or space-separated floats (``lags``, ``num``)."""
    if isinstance(cell, str):
        return [float(x) for x in cell.split()]
    return [] if pd.isna(cell) else [float(cell)]


def value_columns(df: pd.DataFrame) -> list[str]:
    return [c for c in df.columns if c not in KEYS]


def _seed_dir() -> Path | None:
    env = os.environ.get("HEURTUNE_SEEDS")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates += [parent / "shared" / "seeds" for parent in here.parents]
    return next((c for c in candidates if (c / SEED_FILES["000"]).is_file()), None)


@pytest.fixture(scope="module")
def seeds() -> dict[str, list[str]]:
    folder = _seed_dir()
    if folder is None:
        pytest.skip("seed texts not found (shared/seeds or $HEURTUNE_SEEDS)")
    return {paper: (folder / name).read_text(encoding="utf-8").split("\n") for paper, name in SEED_FILES.items()}


# ----------------------------------------------------------------------------------------------
# The transcription against the seed text
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("paper, table", ALL)
def test_every_number_is_printed_on_its_line(seeds, paper, table):
    lines = seeds[paper]
    df = printed_table(paper, table)
    span = SPAN.get((paper, table), 1)
    checked = 0
    for _, rec in df.iterrows():
        line = int(rec["line"])
        assert 1 <= line <= len(lines), (table, rec["row"], line)
        printed = numbers_on("\n".join(lines[line - 1:line - 1 + span]))
        for col in value_columns(df):
            for value in cell_values(rec[col]):
                assert any(math.isclose(abs(value), p, rel_tol=1e-12) for p in printed), (
                    f"paper {paper} {table} row {rec['row']!r} {col}={value} not on seed line {line}: "
                    f"{lines[line - 1][:200]!r}")
                checked += 1
    assert checked > 0


@pytest.mark.parametrize("paper, table", NUMBERED)
def test_every_number_of_a_table_line_is_transcribed_in_order(seeds, paper, table):
    # The other way round: each seed line a numbered table points to holds exactly the rows' numbers
    # (labels' digits such as citations [47], h_1, u1-y1 and K^1(s) left aside), printed either row
    # after row (Tables 1-6 of paper 000: HM row, then HMr row) or column after column (paper 001's
    # Tables 1-2: h_1 and h_2 of IAE, then of ISE, ...).
    df = printed_table(paper, table)
    cols = value_columns(df)
    for line, rows in df.groupby("line", sort=False):
        cells = [[float(rec[c]) for c in cols] for _, rec in rows.iterrows()]
        by_row = [v for row in cells for v in row]
        by_column = [row[j] for j in range(len(cols)) for row in cells]
        printed = numbers_on(_LABELS.sub(" ", seeds[paper][int(line) - 1]))

        def same(stored, printed=printed):
            return len(stored) == len(printed) and all(
                math.isclose(a, b, rel_tol=1e-12) for a, b in zip(stored, printed))

        assert same(by_row) or same(by_column), (paper, table, line, cells, printed)


@pytest.mark.parametrize("paper, table", ALL)
def test_captions_and_equation_numbers_are_where_the_readme_says(seeds, paper, table):
    lines = seeds[paper]
    caption = TABLES[paper][table]["line"]
    df = printed_table(paper, table)
    if table.startswith("table_"):
        number = table.split("_", 1)[1]
        assert re.match(rf"(?i)table\s+{number}\b", lines[caption - 1]), (paper, table, lines[caption - 1])
    else:
        assert caption == df["line"].min(), (paper, table)
    if "equation" in df.columns:
        for _, rec in df.iterrows():
            line, eq = int(rec["line"]), int(rec["equation"])
            window = "\n".join(lines[line - 1:line + 15])
            assert re.search(rf"[({{]{eq}[)}}]", window), (paper, table, rec["row"], eq)


def test_tables_5_and_6_of_paper_000_agree_with_their_garbled_copies(seeds):
    # The label line of each polynomial carries the same matrices as HTML and tab-separated text.
    lines = seeds["000"]
    for table in ("table_5", "table_6"):
        df = printed_table("000", table)
        for poly, rows in df.groupby("polynomial"):
            label = lines[int(rows["line"].min()) - 2]
            assert label.startswith(f"$K^{poly[1]}(s)$"), (table, poly)
            html = [float(x) for x in re.findall(r"<td>([^<]*)</td>", label)]
            plain = [float(x) for part in re.sub(r"<table.*?</table>", "|", label).split("|")[1:3]
                     for x in part.split("\t") if re.fullmatch(r"\d+(\.\d+)?", x.strip())]
            stored = [float(v) for m in ("HM", "HMr") for _, rec in rows[rows["matrix"] == m].iterrows()
                      for v in rec[["c1", "c2", "c3", "c4", "c5", "c6"]]]
            assert html == plain == stored, (table, poly)


# ----------------------------------------------------------------------------------------------
# The data files and the READMEs
# ----------------------------------------------------------------------------------------------

def _readme_tables(paper: str) -> list[tuple[str, int, int]]:
    folder = resources.files("heurtune.experiments") / "printed" / f"paper_{paper}"
    text = (folder / "README.md").read_text(encoding="utf-8")
    section = text.split("## Tables", 1)[1].split("\n## ", 1)[0]
    return [(m.group(1), int(m.group(2)), int(m.group(3)))
            for m in re.finditer(r"^\| `([^`]+)` \| (\d+) \| [^|\n]* \| (\d+) \|", section, re.M)]


@pytest.mark.parametrize("paper", PAPERS)
def test_readme_lists_exactly_the_tables_there_are(paper):
    folder = resources.files("heurtune.experiments") / "printed" / f"paper_{paper}"
    files = sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".csv"))
    listed = _readme_tables(paper)
    assert [name for name, _, _ in listed] == printed_tables(paper)
    assert sorted(printed_tables(paper)) == files
    for name, line, rows in listed:
        assert line == TABLES[paper][name]["line"], (paper, name)
        assert rows == len(printed_table(paper, name)), (paper, name)


@pytest.mark.parametrize("paper, table", ALL)
def test_tables_load_with_their_shape_and_unique_keys(paper, table):
    df = printed_table(paper, table)
    assert df.shape == SHAPES[(paper, table)]
    assert df.columns[0] == "row" and df.columns[-1] == "line"
    assert df["row"].is_unique and (df["row"] != "").all()
    assert pd.api.types.is_integer_dtype(df["line"])
    for col in value_columns(df):
        if col not in {"lags", "leads", "num", "den"}:
            assert pd.api.types.is_float_dtype(df[col]), (paper, table, col)
    if {"controller", "loop"} <= set(df.columns) and table.startswith("table_"):
        assert (df["row"] == df["controller"] + "/" + df["loop"].astype(str)).all()
    if "matrix" in df.columns:
        assert (df["row"] == df["polynomial"] + "/" + df["matrix"] + "/" + df["i"].astype(str)).all()
    if "element" in df.columns:
        assert (df["row"] == df["plant"] + "/" + df["element"]).all()
        assert set(df["element"]) <= {"g11", "g12", "g21", "g22", "d12", "d21"}
        for _, rec in df.iterrows():  # one of the two forms of an element
            assert (rec["den"] == "") == (rec["num"] == "") and (rec["den"] == "") != pd.isna(rec["K"])
    raw = printed_table(paper, table, raw=True)
    assert raw.shape == df.shape and (raw.map(lambda v: isinstance(v, str))).all().all()
    assert printed_path(paper, table).is_file()


@pytest.mark.parametrize("paper, table, row, column, value", [
    ("000", "table_1", "Proposed PID/1", "ITAE_regulatory", 1.55e-4),
    ("000", "table_1", "DR PID [24]/2", "ITAE_servo", 5.92e5),
    ("000", "table_3", "Ziegler Nichols [31]/1", "ITAE_servo", 1.571e5),
    ("000", "table_4", "K1/HMr/5", "c6", 848.5),
    ("000", "table_6", "K2/HMr/4", "c6", 10.72),
    ("000", "fopdt", "qts/2/eq59", "T", 110.659),
    ("000", "controllers", "qts/1/eq48", "Ki", 0.285),
    ("000", "controllers", "qts/1/eq60", "Ki", 0.2985),
    ("000", "polynomials", "characteristic", "s0", 0.3421),
    ("000", "plants", "qts/d21", "K", -1.678),
    ("001", "table_1", "Multiloop PID [41]/2", "ITAE", 3.58e4),
    ("001", "table_2", "Proposed PID/2", "ITAE", 1.234e4),
    ("001", "controllers", "qts/2/pid", "Kd", 0.02),
    ("002", "table_I", "u2-y2", "tau_i", 621.8),
    ("002", "table_II", "GPM PI [1]/2", "e_t", 4.7185),
    ("002", "model", "cts/d12", "L", 0.384),
])
def test_spot_values(paper, table, row, column, value):
    df = printed_table(paper, table)
    assert df.loc[df["row"] == row, column].item() == value


def test_text_columns_and_empty_cells():
    plants = printed_table("000", "plants").set_index("row")
    assert plants.loc["qts/g12", "lags"] == "10.231 6.57"
    assert plants.loc["ccts/d12", "num"] == "-246.33 -0.73" and math.isnan(plants.loc["ccts/d12", "K"])
    pid = printed_table("001", "controllers").set_index("row")
    assert math.isnan(pid.loc["ccts/1/pi", "Kd"]) and math.isnan(pid.loc["ccts/1/pid", "Kc"])
    assert printed_table("000", "table_1", raw=True)["ITAE_regulatory"].iloc[1] == "1.10e-4"
    assert math.isnan(printed_table("002", "model").set_index("row").loc["cts/d21", "L"])


def test_names_are_normalised():
    assert printed_tables(0) == printed_tables("paper_000") == printed_tables("000")
    assert printed_path("000", "Table 1") == printed_path("000", "1") == printed_path("000", "table_1")
    assert printed_path("002", "I").name == "table_I.csv"
    assert printed_path("002", "table II").name == "table_II.csv"
    assert printed_path("000", "table_1").parent.name == "paper_000"


def test_unknown_paper_or_table_names_the_allowed_values():
    with pytest.raises(ConfigError, match=r"unknown paper '004'; allowed: 000, 001, 002") as err:
        printed_table("004", "table_1")
    assert "\n" not in str(err.value)
    for call in (printed_tables, lambda p: printed_path(p, "table_1")):
        with pytest.raises(ConfigError, match="allowed: 000, 001, 002"):
            call("xyz")
    with pytest.raises(ConfigError, match=r"paper 002 has no table 'table_3'; allowed: table_I, table_II, model, fop"):
        printed_table("002", "table_3")
    with pytest.raises(ConfigError, match=r"allowed: table_1, table_2, table_3, fopdt, controllers, plants"):
        printed_path("001", "table_4")
