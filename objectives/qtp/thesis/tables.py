"""The thesis' tables (Chapters 4-6) next to heurtune's numbers.

:func:`write_chapter` writes, for each table of a chapter, ``out_dir/tables/table_<X>_<Y>.md``
and ``.tex`` in the thesis' row layout. Each quantity comes as the columns ``printed``,
``heurtune``, ``diff`` (heurtune minus printed) and, where a ratio means something (gains,
efforts, crossover frequencies, phase margins, J statistics), ``diff %`` (relative to the
printed value). Overshoot, settling time and steady-state error get the absolute difference
only: they are already percentages or near zero. An ``out_dir/tables/README.md`` indexes the
files written.

What "heurtune" means, per kind of table (each file says it in its header line):

* **Gain tables** (4.6, 5.2, 6.3, 6.4): part A gives heurtune's best tuned run of the same case
  and algorithm (lowest objective among feasible runs, else lowest violation, as
  :func:`heurtune.analysis.compare.best_run_index`) and its effort ``J@nominal``; part B the effort of the
  *printed* gains simulated by heurtune next to the printed effort (Table 4.6's own, Table 5.4's
  for 5.2, Table 6.5's nominal for 6.3 and 6.4).
* **Start tables** (4.2-4.5): from ``starts.parquet`` (one row per SQP start). heurtune's
  feasible starts are ranked by their objective ``f``, and the k-th best is set beside the printed
  row whose J ranks k-th, so the highlighted minimal-effort row meets heurtune's best start. 4.2 and
  4.4 compare initial guesses (random on both sides: no differences are given), 4.3 and 4.5 the
  converged values. ``starts_distribution`` gives the spread (min, quartiles, max) of the
  converged values over all feasible starts per case, beside the printed range.
* **4.7** (LADR): the printed parameters beside those of heurtune's best LADR run (the
  ``table_4_7`` baseline evaluates the printed ones, so the differences are then zero), and the
  effort of the printed parameters simulated by heurtune beside Table 4.8's.
* **Metric tables** (4.8-4.10, 5.4-5.7, 6.5): two comparisons. Part A: the *printed* gains
  simulated by heurtune (same gains, heurtune's model: this shows the model differences).
  Part B: heurtune's own best tuned run of the same case and algorithm (``<metric>@<scenario>``
  of ``runs.parquet``). The printed gains are: FOLQI, Table 4.3/4.5's minimal-effort row; IOLQI,
  Table 4.6; LADR, Table 4.7 (Chapter 4); Table 5.2 (Chapter 5); Tables 6.3/6.4 (Chapter 6).
  Efforts are absolute (J = integral of u1^2 + u2^2; the printed J x 10^3 multiplied out).
* **Margin tables** (4.11, 4.12, 5.8-5.10): part A the margins heurtune computes for the printed
  gains, part B those of heurtune's best run (``margins.parquet``, computed when absent), both
  from :func:`heurtune.objectives.qtp.margins.loop_margins` and its reading of "input i, output j". Printed and
  heurtune rows are matched by their place in the thesis' fixed loop order (1 1, 1 2, 2 1, 2 2).
* **5.3**: the mean convergence epoch over the runs and the mean and SD (ddof = 1) of the final
  objective over the runs that found a simulable candidate, beside the printed ones.

Missing inputs (no ``starts.parquet``, an algorithm or case not run, a scenario the experiment
lacks, printed gains that heurtune cannot simulate) leave the heurtune cells empty; the file then
says why in a note. Nothing here raises for missing data.

Examples
--------
>>> from heurtune.objectives.qtp.thesis.tables import write_chapter                      # doctest: +SKIP
>>> write_chapter(5, exp, "results/thesis_ch5")                           # doctest: +SKIP
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.analysis.runs import best_run_index, successful_runs
from heurtune.analysis.side_by_side import (
    Part,
    SideBySideTable,
    add_quantity,
    decimals_of,
    fmt,
    make_part,
    md_cell,
    number,
    render_latex,
    render_markdown,
    write_text,
)
from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.margins import loop_margins
from heurtune.objectives.qtp.structures import controller_label
from heurtune.objectives.qtp.thesis.figures import chapter_figures
from heurtune.objectives.qtp.thesis.printed import TABLES, printed_table

__all__ = ["ThesisTable", "Part", "CHAPTER_TABLES", "chapter_tables", "write_chapter", "render_markdown",
           "render_latex"]

GAINS = ("Q11", "Q22", "Q33", "Q44", "R11", "R22", "Ki1", "Ki2", "alpha1", "alpha2")
LADR = tuple(f"beta{i}{j}" for j in (1, 2, 3) for i in (1, 2, 3, 4)) + tuple(f"b{i}" for i in range(1, 5)) + tuple(
    f"r{i}" for i in range(1, 5))
ALG_LABEL = {"cs": "CS", "apso": "APSO", "firefly": "FF", "newton_raphson": "NR", "dfp": "DFP",
             "steepest_descent": "SD", "bfgs": "BFGS", "sqp_multistart": "SQP"}
COND_LABEL = {"min": "Minimum", "nmp": "Non-minimum"}
# Which tables each chapter writes, in order ("starts" is the distribution of SQP solutions).
CHAPTER_TABLES = {
    4: ("4.2", "4.3", "4.4", "4.5", "starts", "4.6", "4.7", "4.8", "4.9", "4.10", "4.11", "4.12"),
    5: ("5.2", "5.3", "5.4", "5.5", "5.6", "5.7", "5.8", "5.9", "5.10"),
    6: ("6.3", "6.4", "6.5"),
}
CH4_ALGORITHM = "sqp_multistart"
# Quantities whose relative difference is given (others: absolute only).
_NO_RELATIVE = {"Mp", "ts", "ess", "convergence_epoch", "Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2"}
_METRIC_ALG = {"5.5": "cs", "5.6": "apso", "5.7": "firefly", "5.8": "cs", "5.9": "apso", "5.10": "firefly"}


class ThesisTable(SideBySideTable):
    """A thesis table with heurtune's numbers beside the printed ones
    (:class:`heurtune.analysis.side_by_side.SideBySideTable`; ``name`` is ``"4.3"`` ... or
    ``"starts"``)."""

    @property
    def stem(self) -> str:
        return "starts_distribution" if self.name == "starts" else f"table_{self.name.replace('.', '_')}"


# ----------------------------------------------------------------------------------------------
# Inputs
# ----------------------------------------------------------------------------------------------

class _Inputs:
    """Runs, history, margins, starts and the experiment, with cached simulations of gains."""

    def __init__(self, exp, runs, history, margins, starts):
        self.exp = exp
        self.runs = runs if runs is not None else pd.DataFrame()
        self.history = history if history is not None else pd.DataFrame()
        self.margins = margins if margins is not None else pd.DataFrame()
        self.starts = starts if starts is not None else pd.DataFrame()
        self._problems = {}
        self._reports = {}
        self._margins = {}
        self.notes = []

    def problem(self, case):
        if case not in self._problems:
            try:
                cases = getattr(self.exp, "cases", None)
                if cases is not None and case not in cases:
                    raise ConfigError(f"unknown case {case!r}")
                self._problems[case] = self.exp.problem(case)
            except Exception as exc:  # noqa: BLE001 - a missing case leaves cells empty
                self._problems[case] = None
                self.notes.append(f"case {case}: not in the experiment ({exc})")
        return self._problems[case]

    def scenarios(self, case) -> list:
        prob = self.problem(case)
        return list(getattr(prob, "scenarios", {}) or []) if prob is not None else []

    def report(self, case, values: dict, scenarios) -> pd.DataFrame | None:
        """heurtune's metrics of given gains (``{name: value}``), rows = scenarios; None if impossible."""
        prob = self.problem(case)
        if prob is None:
            return None
        try:
            x = np.array([float(values[n]) for n in prob.names])
        except KeyError as exc:
            self.notes.append(f"case {case}: printed gains lack {exc.args[0]}")
            return None
        have = [s for s in scenarios if s in self.scenarios(case)]
        if not have:
            return None
        key = (case, tuple(x.tolist()), tuple(have))
        if key not in self._reports:
            notes = []
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    rep = prob.report(x, have)
                if "reason" in rep:
                    for sc, reason in rep["reason"].items():
                        if str(reason):
                            notes.append(f"case {case}: the printed gains fail in heurtune under {sc} ({reason})")
            except Exception as exc:  # noqa: BLE001
                notes.append(f"case {case}: the printed gains could not be simulated ({exc})")
                rep = None
            self._reports[key] = (rep, notes)
        rep, notes = self._reports[key]
        self.notes += notes  # again for every table that uses them
        return rep

    def gain_margins(self, case, values: dict) -> pd.DataFrame | None:
        """Margins (input, output, gain_crossover_rad_s, phase_margin_deg) of given gains."""
        prob = self.problem(case)
        if prob is None:
            return None
        try:
            x = np.array([float(values[n]) for n in prob.names])
        except KeyError:
            return None
        key = (case, tuple(x.tolist()))
        if key not in self._margins:
            notes = []
            try:
                m = prob.margins(x)
                if m is None:  # LADR: the runner keeps none, the chapter tables compare them
                    m = loop_margins(prob, x)
            except Exception as exc:  # noqa: BLE001
                notes.append(f"case {case}: margins of the gains could not be computed ({exc})")
                m = None
            self._margins[key] = (m, notes)
        m, notes = self._margins[key]
        self.notes += notes
        return m

    def case_runs(self, case, algorithm=None) -> pd.DataFrame:
        r = self.runs
        if r.empty or "case" not in r:
            return r.iloc[:0]
        sel = r["case"] == case
        if algorithm is not None and "algorithm" in r:
            sel &= r["algorithm"] == algorithm
        return r[sel]

    def best(self, case, algorithm=None) -> pd.Series | None:
        """heurtune's best run of a case (and algorithm), or None."""
        g = self.case_runs(case, algorithm)
        if g.empty or "best_f" not in g:
            return None
        best = g.loc[best_run_index(g)]
        if best.get("status") == "failed":  # no stable candidate: a failure, not gains to compare
            self.notes.append(f"case {case}" + (f", {algorithm}" if algorithm else "")
                              + f": every run failed ({best.get('failure', '')}); heurtune cells empty")
            return None
        return best

    def best_margins(self, case, algorithm=None) -> pd.DataFrame | None:
        b = self.best(case, algorithm)
        if b is None:
            return None
        m = self.margins
        if not m.empty and {"case", "input", "output"} <= set(m.columns):
            sel = m["case"] == case
            if "algorithm" in m:
                sel &= m["algorithm"] == b.get("algorithm", algorithm)
            if "run" in m and "run" in b:
                sel &= m["run"] == b["run"]
            if sel.any():
                return m[sel]
        prob = self.problem(case)
        if prob is None:
            return None
        if not all(n in b for n in prob.names):
            return None
        return self.gain_margins(case, {n: b[n] for n in prob.names})


def _read(out_dir: Path, name: str) -> pd.DataFrame | None:
    path = out_dir / name
    if not path.exists():
        return None
    try:
        return pd.read_parquet(path)
    except Exception:  # noqa: BLE001 - an unreadable file counts as missing
        return None


def _case(inputs: _Inputs, plant: str, ctrl: str) -> str:
    """heurtune's case name for a plant case and controller type (``min-folqi``, or ``min``
    when the experiment has the one controller type)."""
    name = f"{plant}-{ctrl}"
    cases = getattr(inputs.exp, "cases", None)
    if cases is not None and name not in cases and plant in cases:
        controllers = getattr(inputs.exp, "controllers", None)
        if controllers is not None and tuple(controllers) == (ctrl,):
            return plant
    return name


def _split(case: str):
    plant, _, ctrl = case.partition("-")
    return plant, ctrl


# ----------------------------------------------------------------------------------------------
# Formatting
# ----------------------------------------------------------------------------------------------

def _triple(rows_out, q: str, label: str, printed_text: str, heur: float, *, relative: bool | None = None,
            diff: bool = True):
    """Append the cells of one quantity (printed, heurtune, diff[, diff %]) to the row dicts:
    :func:`~heurtune.analysis.side_by_side.add_quantity` with the thesis' decimals (one for
    convergence epochs) and relative differences (none for ``_NO_RELATIVE``)."""
    decimals = 1 if q == "convergence_epoch" else decimals_of(printed_text or "", number(heur))
    add_quantity(rows_out, label, printed_text, heur, decimals=decimals,
                 relative=q not in _NO_RELATIVE if relative is None else relative, diff=diff)


def _keys(**kw):
    return dict(kw), dict(kw)


# ----------------------------------------------------------------------------------------------
# Printed gains per case
# ----------------------------------------------------------------------------------------------

def _min_effort_row(table: str) -> str:
    t = printed_table(table)
    return str(t.loc[t["J"].idxmin(), "row"])


def _printed_gains(chapter: int, case: str, algorithm: str | None):
    """(source table, row, {name: value}) of the printed gains of a case, or None."""
    plant, ctrl = _split(case)
    if chapter == 4:
        src = {("min", "folqi"): ("4.3", None), ("nmp", "folqi"): ("4.5", None),
               ("min", "iolqi"): ("4.6", f"{plant}-iolqi"), ("nmp", "iolqi"): ("4.6", f"{plant}-iolqi"),
               ("min", "ladr"): ("4.7", f"{plant}-ladr"), ("nmp", "ladr"): ("4.7", f"{plant}-ladr")}.get((plant, ctrl))
        if src is None:
            return None
        table, row = src
        if row is None:
            row = _min_effort_row(table)
    else:
        row = f"{plant}-{ctrl}/{algorithm}"
        table = "5.2" if chapter == 5 else ("6.3" if algorithm in ("newton_raphson", "dfp") else "6.4")
    t = printed_table(table)
    hit = t[t["row"] == row]
    if hit.empty:
        return None
    r = hit.iloc[0]
    names = LADR if ctrl == "ladr" else GAINS
    values = {n: float(r[n]) for n in names if n in r and np.isfinite(r[n])}
    return table, row, values


# ----------------------------------------------------------------------------------------------
# Table builders
# ----------------------------------------------------------------------------------------------

def _raw(table):
    return printed_table(table, raw=True).set_index("row", drop=False)


def _title(table: str) -> str:
    meta = TABLES[table]
    return f"Table {table}: {meta['title']} (thesis line {meta['line']})"


def _start_table(inp: _Inputs, table: str, converged: bool) -> ThesisTable:
    raw = _raw(table)
    plant = raw["case"].iloc[0]
    case = _case(inp, plant, "folqi")
    st = inp.starts
    notes = []
    heur = pd.DataFrame()
    if st.empty or "case" not in st:
        notes.append("no starts.parquet: heurtune cells are empty")
    else:
        heur = st[st["case"] == case]
        if "feasible" in heur:
            heur = heur[heur["feasible"].astype(bool)]
        heur = heur.sort_values("f", kind="mergesort") if "f" in heur else heur.iloc[:0]
        if heur.empty:
            notes.append(f"no feasible start of case {case} in starts.parquet")
    # Printed rows ranked by their J (the converged table's J also ranks the initial guesses).
    conv = printed_table("4.3" if plant == "min" else "4.5")
    rank = {r: k for k, r in enumerate(conv.sort_values("J", kind="mergesort")["row"])}
    rows = []
    for key, r in raw.iterrows():
        k = rank[key]
        h = heur.iloc[k] if k < len(heur) else None
        disp, vals = _keys(row=key, start=r["start"])
        disp["heurtune start"] = "" if h is None else str(int(h["start"])) if "start" in h else ""
        vals["heurtune start"] = math.nan if h is None or "start" not in h else float(h["start"])
        for n in GAINS:
            col = n if converged else f"x0_{n}"
            hv = h[col] if h is not None and col in h else math.nan
            _triple((disp, vals), n, n, r[n], hv, diff=converged)
        if converged:
            _triple((disp, vals), "J", "J", r["J"], h["f"] if h is not None else math.nan)
        rows.append((disp, vals))
    what = "converged values" if converged else "initial guesses"
    meaning = (f"heurtune: the {what} of its feasible SQP starts on {case}, ranked by objective f; "
               f"the k-th best beside the printed row whose J ranks k-th"
               + ("" if converged else " (random guesses on both sides: no differences)"))
    return ThesisTable(table, _title(table), meaning, [make_part("Printed vs heurtune", rows)], notes)


def _starts_distribution(inp: _Inputs) -> ThesisTable:
    st = inp.starts
    notes = []
    rows = []
    if st.empty or "case" not in st:
        notes.append("no starts.parquet: nothing to summarise")
    else:
        for case in pd.unique(st["case"]):
            g = st[st["case"] == case]
            feas = g[g["feasible"].astype(bool)] if "feasible" in g else g
            plant, ctrl = _split(case)
            printed = None
            if ctrl in ("folqi", "") and plant in ("min", "nmp"):
                printed = printed_table("4.3" if plant == "min" else "4.5")
            elif ctrl == "iolqi":
                printed = printed_table("4.6")
                printed = printed[printed["row"] == case]
            names = [n for n in GAINS + LADR if n in g.columns] + (["f"] if "f" in g else [])
            for n in names:
                v = feas[n].astype(float).to_numpy() if n in feas else np.array([])
                q = np.percentile(v, [0, 25, 50, 75, 100]) if v.size else [math.nan] * 5
                pcol = "J" if n == "f" else n
                pv = printed[pcol].astype(float).to_numpy() if printed is not None and pcol in printed else np.array([])
                pv = pv[np.isfinite(pv)]
                disp, vals = _keys(case=case, variable=n)
                disp["feasible starts"] = f"{v.size}/{len(g)}"
                vals["feasible starts"] = float(v.size)
                for lab, x in zip(("min", "q25", "median", "q75", "max"), q):
                    disp[lab] = fmt(x, 1 if n == "f" else 4)
                    vals[lab] = x
                disp["printed min"] = fmt(pv.min(), 4) if pv.size else ""
                vals["printed min"] = pv.min() if pv.size else math.nan
                disp["printed max"] = fmt(pv.max(), 4) if pv.size else ""
                vals["printed max"] = pv.max() if pv.size else math.nan
                rows.append((disp, vals))
    meaning = ("heurtune: spread of the converged values over all feasible SQP starts per case "
               "(f is the objective, J); printed min/max over the thesis' five converged rows (4.3, 4.5) "
               "or its one IOLQI row (4.6)")
    subtitle = "Distribution of converged solutions"
    part = make_part(subtitle, rows) if rows else Part(subtitle, pd.DataFrame(), pd.DataFrame())
    return ThesisTable("starts", "Converged SQP solutions over all starts (Tables 4.3 and 4.5 extended)",
                       meaning, [part], notes)


def _effort_of_printed(inp: _Inputs, chapter: int, case: str, hcase: str, algorithm: str | None) -> float:
    """heurtune's nominal J (case ``hcase``) of the printed gains of the thesis' ``case`` (NaN when
    it cannot be had)."""
    src = _printed_gains(chapter, case, algorithm)
    rep = inp.report(hcase, src[2], ["nominal"]) if src else None
    h = rep.loc["nominal", "J"] if rep is not None and "nominal" in rep.index else math.nan
    return h


def _gain_table(inp: _Inputs, chapter: int, table: str) -> ThesisTable:
    raw = _raw(table)
    notes = []
    rows_a, rows_b = [], []
    for _, r in raw.iterrows():
        case = r["case"]
        alg = r.get("algorithm", None) if "algorithm" in raw else None
        plant, ctrl = _split(case)
        hcase = _case(inp, plant, ctrl)
        best = inp.best(hcase, alg if chapter != 4 else None)
        if best is None and inp.case_runs(hcase, alg if chapter != 4 else None).empty:
            notes.append(f"no run of {hcase}" + (f" by {alg}" if alg else "") + ": heurtune cells empty")
        keys = dict(controller=f"{controller_label(ctrl)} / {COND_LABEL.get(plant, plant)}")
        if alg:
            keys = dict(algorithm=ALG_LABEL.get(alg, alg), **keys)
        disp, vals = _keys(**keys)
        names = LADR if ctrl == "ladr" else [n for n in GAINS if n in raw.columns]
        for n in names:
            _triple((disp, vals), n, n, r[n], best[n] if best is not None and n in best else math.nan)
        if "J" in raw.columns:
            hj = best.get("J@nominal", math.nan) if best is not None else math.nan
            _triple((disp, vals), "J", "J", r["J"], hj)
        rows_a.append((disp, vals))
        # Part B: the effort of the printed gains.
        if chapter == 4:
            pj = r["J"] if "J" in raw.columns else _raw("4.8").loc[case, "J"]
        elif chapter == 5:
            pj = _raw("5.4").loc[f"{case}/{alg}", "J"]
        else:
            pj = _raw("6.5").loc[f"{case}/{alg}", "J@nominal"]
        disp, vals = _keys(**keys)
        _triple((disp, vals), "J", "J", pj, _effort_of_printed(inp, chapter, case, hcase, alg))
        rows_b.append((disp, vals))
    src_b = {4: "Table 4.8" if table == "4.7" else f"Table {table}", 5: "Table 5.4", 6: "Table 6.5 (nominal)"}[chapter]
    meaning = ("heurtune: part A its best tuned run of the same case" + (" and algorithm" if chapter != 4 else "")
               + f" (gains and J@nominal); part B the printed gains simulated by heurtune, J beside {src_b}")
    if table == "4.7":
        meaning = ("heurtune: part A the parameters of its best LADR run (the table_4_7 baseline evaluates the "
                   "printed ones); part B the printed parameters simulated by heurtune, J beside Table 4.8's")
    parts = [make_part("A: printed vs heurtune's best tuned run", rows_a),
             make_part("B: effort of the printed gains, simulated by heurtune", rows_b)]
    return ThesisTable(table, _title(table), meaning, parts, notes)


def _level_rows(keys: dict, printed: pd.Series | None, heur: dict | None):
    """Two display rows (h1, h2) of a metric table: Mp, ts, ess, J_i and the total J on h1."""
    out = []
    for lvl in (1, 2):
        k = dict(keys) if lvl == 1 else {key: "" for key in keys}
        disp, vals = _keys(**k, level=f"h{lvl}")
        for q in ("Mp", "ts", "ess", "J"):
            col = f"{q}{lvl}"
            pt = printed[col] if printed is not None else ""
            hv = heur.get(col, math.nan) if heur is not None else math.nan
            _triple((disp, vals), q, "effort" if q == "J" else q, pt, hv, relative=(q == "J"))
        pt = printed["J"] if (printed is not None and lvl == 1) else ""
        hv = heur.get("J", math.nan) if (heur is not None and lvl == 1) else math.nan
        _triple((disp, vals), "J", "J", pt, hv)
        out.append((disp, vals))
    return out


def _metric_table(inp: _Inputs, chapter: int, table: str) -> ThesisTable:
    raw = _raw(table)
    rows_a, rows_b = [], []
    fixed_alg = _METRIC_ALG.get(table)
    for _, r in raw.iterrows():
        case = r["case"]
        plant, ctrl = _split(case)
        hcase = _case(inp, plant, ctrl)
        alg = r["algorithm"] if "algorithm" in raw else fixed_alg
        scenario = r["scenario"] if "scenario" in raw else "nominal"
        keys = dict(controller=f"{controller_label(ctrl)} / {COND_LABEL.get(plant, plant)}")
        if "algorithm" in raw:
            keys["algorithm"] = ALG_LABEL.get(alg, alg)
        if "scenario" in raw:
            keys["scenario"] = scenario
        # A: printed gains simulated.
        src = _printed_gains(chapter, case, alg)
        rep = inp.report(hcase, src[2], [scenario]) if src else None
        ha = rep.loc[scenario].to_dict() if rep is not None and scenario in rep.index else None
        rows_a += _level_rows(keys, r, ha)
        # B: heurtune's best tuned run.
        best = inp.best(hcase, alg if chapter != 4 else (None if ctrl == "ladr" else CH4_ALGORITHM))
        if best is None and chapter == 4 and ctrl != "ladr":
            best = inp.best(hcase)
        hb = None
        if best is not None:
            hb = {c.split("@")[0]: best[c] for c in best.index if isinstance(c, str) and c.endswith(f"@{scenario}")}
            if not hb:
                inp.notes.append(f"{hcase}: runs.parquet has no metrics under scenario {scenario}")
                hb = None
        rows_b += _level_rows(keys, r, hb)
    meaning = ("heurtune: part A the printed gains simulated by heurtune (model differences); part B heurtune's "
               "best tuned run of the same case" + (" and algorithm" if chapter != 4 else "")
               + "; efforts absolute (J = integral of u^2)")
    parts = [make_part("A: printed gains simulated by heurtune", rows_a),
             make_part("B: heurtune's best tuned run", rows_b)]
    return ThesisTable(table, _title(table), meaning, parts, [])


def _effort_table(inp: _Inputs) -> ThesisTable:
    raw = _raw("6.5")
    rows_a, rows_b = [], []
    scen = ["-30%", "nominal", "+30%"]
    for _, r in raw.iterrows():
        case, alg = r["case"], r["algorithm"]
        plant, ctrl = _split(case)
        hcase = _case(inp, plant, ctrl)
        keys = dict(algorithm=ALG_LABEL.get(alg, alg),
                    controller=f"{controller_label(ctrl)} / {COND_LABEL.get(plant, plant)}")
        src = _printed_gains(6, case, alg)
        rep = inp.report(hcase, src[2], scen) if src else None
        best = inp.best(hcase, alg)
        da, va = _keys(**keys)
        db, vb = _keys(**keys)
        for s in scen:
            ha = rep.loc[s, "J"] if rep is not None and s in rep.index else math.nan
            hb = best.get(f"J@{s}", math.nan) if best is not None else math.nan
            _triple((da, va), "J", f"J@{s}", r[f"J@{s}"], ha)
            _triple((db, vb), "J", f"J@{s}", r[f"J@{s}"], hb)
        rows_a.append((da, va))
        rows_b.append((db, vb))
    meaning = ("heurtune: part A the printed gains (Tables 6.3, 6.4) simulated by heurtune; part B heurtune's best "
               "tuned run of the same case and algorithm; absolute effort J = integral of u^2 (the printed values "
               "are read as J x 10^3: they match Tables 5.5-5.7)")
    return ThesisTable("6.5", _title("6.5"), meaning, [make_part("A: printed gains simulated by heurtune", rows_a),
                                                       make_part("B: heurtune's best tuned run", rows_b)], [])


def _margin_table(inp: _Inputs, chapter: int, table: str) -> ThesisTable:
    raw = _raw(table)
    alg = _METRIC_ALG.get(table)
    rows_a, rows_b = [], []
    for key, r in raw.iterrows():
        case = r["case"]
        plant, ctrl = _split(case)
        hcase = _case(inp, plant, ctrl)
        digits = key.split("/")[1]
        pos = (int(digits[0]), int(digits[1]))  # the place in the thesis' loop order
        src = _printed_gains(chapter, case, alg)
        ma = inp.gain_margins(hcase, src[2]) if src else None
        best_alg = alg if chapter != 4 else (None if ctrl == "ladr" else CH4_ALGORITHM)
        mb = inp.best_margins(hcase, best_alg)
        if mb is None and chapter == 4 and ctrl != "ladr":
            mb = inp.best_margins(hcase)
        keys = dict(controller=f"{controller_label(ctrl)} / {COND_LABEL.get(plant, plant)}",
                    input=str(r["input"]), output=str(r["output"]))
        for m, rows in ((ma, rows_a), (mb, rows_b)):
            disp, vals = _keys(**keys)
            hit = None
            if m is not None and len(m):
                sel = m[(m["input"] == pos[0]) & (m["output"] == pos[1])]
                hit = sel.iloc[0] if len(sel) else None
            _triple((disp, vals), "wgc", "crossover rad/s", r["gain_crossover_rad_s"],
                    hit["gain_crossover_rad_s"] if hit is not None else math.nan)
            _triple((disp, vals), "pm", "PM deg", r["phase_margin_deg"],
                    hit["phase_margin_deg"] if hit is not None else math.nan)
            rows.append((disp, vals))
    meaning = (
        "heurtune: gain-crossover frequency and phase margin of the loop 'input i, output j' as "
        "heurtune.objectives.qtp.margins.loop_margins defines it; part A of the printed gains, part B of "
        "heurtune's best run "
        "(margins.parquet); rows matched by their place in the thesis' loop order; empty heurtune crossover and "
        "'inf' PM: no gain crossover"
    )
    parts = [make_part("A: margins of the printed gains", rows_a),
             make_part("B: margins of heurtune's best run", rows_b)]
    return ThesisTable(table, _title(table), meaning, parts, [])


def _convergence_table(inp: _Inputs) -> ThesisTable:
    raw = _raw("5.3")
    rows = []
    notes = []
    for _, r in raw.iterrows():
        case, alg = r["case"], r["algorithm"]
        plant, ctrl = _split(case)
        hcase = _case(inp, plant, ctrl)
        g = inp.case_runs(hcase, alg)
        ce = mean = sd = math.nan
        ok = g[successful_runs(g)] if len(g) and "best_f" in g else g.iloc[:0]
        if len(ok):
            ce = float(ok["convergence_epoch"].astype(float).mean()) if "convergence_epoch" in ok else math.nan
            f = ok["best_f"].astype(float)
            mean = float(f.mean())
            sd = float(f.std(ddof=1)) if len(f) > 1 else math.nan
        elif len(g):
            notes.append(f"{hcase} by {alg}: no successful run (all failed or infeasible): heurtune cells empty")
        else:
            notes.append(f"no run of {hcase} by {alg}: heurtune cells empty")
        disp, vals = _keys(algorithm=ALG_LABEL.get(alg, alg),
                           controller=f"{controller_label(ctrl)} / {COND_LABEL.get(plant, plant)}",
                           runs=str(len(g)))
        vals["runs"] = float(len(g))
        _triple((disp, vals), "convergence_epoch", "epoch", r["convergence_epoch"], ce)
        _triple((disp, vals), "J_mean", "mean J", r["J_mean"], mean)
        _triple((disp, vals), "J_sd", "SD J", r["J_sd"], sd)
        rows.append((disp, vals))
    meaning = ("heurtune: mean convergence epoch, mean and SD (ddof=1) of the final objective over its successful "
               "runs (not failed, feasible; absolute J; the printed unit is not stated); 'runs' counts all runs")
    return ThesisTable("5.3", _title("5.3"), meaning, [make_part("Printed vs heurtune", rows)], notes)


def chapter_tables(chapter: int, exp, *, runs=None, history=None, margins=None, starts=None) -> list[ThesisTable]:
    """Build a chapter's tables (without writing them).

    Parameters
    ----------
    chapter : {4, 5, 6}
    exp : heurtune.Experiment
        Anything with ``problem(case)`` returning an object with ``names`` and
        ``report(x, scenarios)`` (and optionally ``cases`` and ``margins(x)``).
    runs, history, margins, starts : pandas.DataFrame, optional
        ``runs.parquet``, ``history.parquet``, ``margins.parquet`` and (Chapter 4)
        ``starts.parquet`` contents; None or missing columns leave heurtune cells empty.

    Returns
    -------
    list of ThesisTable

    Raises
    ------
    ConfigError
        For a chapter other than 4, 5 or 6.
    """
    if chapter not in CHAPTER_TABLES:
        raise ConfigError(f"unknown thesis chapter {chapter!r}; allowed: {', '.join(map(str, CHAPTER_TABLES))}")
    inp = _Inputs(exp, runs, history, margins, starts)
    out = []
    for name in CHAPTER_TABLES[chapter]:
        n_notes = len(inp.notes)
        if name in ("4.2", "4.4"):
            t = _start_table(inp, name, converged=False)
        elif name in ("4.3", "4.5"):
            t = _start_table(inp, name, converged=True)
        elif name == "starts":
            t = _starts_distribution(inp)
        elif name in ("4.6", "4.7", "5.2", "6.3", "6.4"):
            t = _gain_table(inp, chapter, name)
        elif name in ("4.8", "4.9", "4.10", "5.4", "5.5", "5.6", "5.7"):
            t = _metric_table(inp, chapter, name)
        elif name in ("4.11", "4.12", "5.8", "5.9", "5.10"):
            t = _margin_table(inp, chapter, name)
        elif name == "5.3":
            t = _convergence_table(inp)
        else:
            t = _effort_table(inp)
        t.notes = list(dict.fromkeys(t.notes + inp.notes[n_notes:]))
        out.append(t)
    return out


# ----------------------------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------------------------

def write_chapter(chapter: int, exp, out_dir, *, runs=None, history=None, margins=None, starts=None,
                  figures: bool = True) -> list[Path]:
    """Write a chapter's tables (and figures) beside an experiment's results.

    Parameters
    ----------
    chapter : {4, 5, 6}
    exp : heurtune.Experiment
        The experiment whose results are in ``out_dir`` (its problems simulate the printed gains).
    out_dir : str or Path
        The experiment's output folder; files go to ``out_dir/tables/``.
    runs, history, margins, starts : pandas.DataFrame, optional
        Default: ``runs.parquet``, ``history.parquet``, ``margins.parquet`` and
        ``starts.parquet`` read from ``out_dir`` (a missing file gives empty heurtune cells).
    figures : bool
        Also draw the chapter's figures (:func:`heurtune.objectives.qtp.thesis.figures.chapter_figures`).

    Returns
    -------
    list of pathlib.Path
        Files written: ``table_<X>_<Y>.md`` and ``.tex`` per table, the PNGs and ``README.md``.

    Raises
    ------
    ConfigError
        For a chapter other than 4, 5 or 6.
    """
    if chapter not in CHAPTER_TABLES:
        raise ConfigError(f"unknown thesis chapter {chapter!r}; allowed: {', '.join(map(str, CHAPTER_TABLES))}")
    out_dir = Path(out_dir)
    runs = _read(out_dir, "runs.parquet") if runs is None else runs
    history = _read(out_dir, "history.parquet") if history is None else history
    margins = _read(out_dir, "margins.parquet") if margins is None else margins
    starts = _read(out_dir, "starts.parquet") if starts is None else starts
    tdir = out_dir / "tables"
    tdir.mkdir(parents=True, exist_ok=True)
    tables = chapter_tables(chapter, exp, runs=runs, history=history, margins=margins, starts=starts)
    written = []
    index = [
        f"# Thesis Chapter {chapter}: printed tables beside heurtune",
        "",
        f"Experiment: {getattr(exp, 'name', '')}. Each quantity: printed, heurtune, diff (heurtune - printed) "
        "and, for gains, efforts and margins, diff % (relative to printed). Efforts are absolute "
        "(J = integral of u^2; the thesis' J x 10^3 multiplied out). See heurtune.objectives.qtp.thesis.tables.",
        "",
        "## Tables",
        "",
        "| table | files | heurtune columns hold |",
        "|---|---|---|",
    ]
    for t in tables:
        md = write_text(tdir / f"{t.stem}.md", render_markdown(t))
        tex = write_text(tdir / f"{t.stem}.tex", render_latex(t, label_prefix=getattr(exp, "name", "")))
        written += [md, tex]
        label = "distribution of SQP solutions" if t.name == "starts" else f"Table {t.name}"
        index.append(f"| {label} | [{md.name}]({md.name}), [{tex.name}]({tex.name}) | {md_cell(t.meaning)} |")
    pngs = []
    if figures:
        try:
            pngs = chapter_figures(chapter, exp, tdir, runs=runs, history=history)
        except Exception as exc:  # noqa: BLE001 - figures never cost the tables
            index += ["", f"Figures failed: {exc}"]
    if pngs:
        index += ["", "## Figures", ""]
        index += [f"- [{p.name}]({p.name})" for p in pngs]
        written += pngs
    written.append(write_text(tdir / "README.md", "\n".join(index) + "\n"))
    return written
