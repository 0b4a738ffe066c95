"""Papers 000, 001 and 002 table by table: the printed values beside heurtune's.

:func:`write_paper` writes, for each table of a paper, ``out_dir/tables/table_<n>.md`` and
``.tex`` (the layout of :mod:`heurtune.analysis.side_by_side`: each quantity as ``printed``,
``heurtune``, ``diff``, ``diff %``), an index ``README.md`` and the paper's figures. It is the
``[report] paper = "000"`` hook of a TITO experiment (``experiments/paper_000.toml`` and its
siblings). What heurtune computes, per kind of table:

* **Performance tables** (paper 000 Tables 1-3, paper 001 Tables 1-3). Part A: the rows the
  paper compares. A row whose controller the paper prints (the proposed PID of paper 000, eqs.
  48, 53, 58; the GPM PI and PID of paper 001) is that controller simulated by heurtune on the
  paper's plant with heurtune's inverted decoupler, under the experiment's nominal scenario; a
  controller unstable there (by its closed-loop poles with Pade(10) delays, where the tuning
  problem's check says unstable: :func:`~heurtune.objectives.tito.papers.simulated.simulate_printed`)
  gets no numbers and a note; the rows of controllers whose parameters the paper does not give
  (its literature comparisons) are left empty, and a note says so. Part B: heurtune's own designs
  of the same plant (each optimiser's best run, the analytic baselines) with their gains, with no
  printed counterpart. The notes give the conditions of the simulations.
* **Kharitonov tables** (paper 000 Tables 4-6, :mod:`heurtune.objectives.tito.kharitonov`). Part A:
  the printed Hurwitz and row-reduced matrices beside those of the printed Kharitonov polynomials
  (QTS). Part B: the MIMO Kharitonov test of det(I + C A) of the printed PID over the +-variation
  box of the decoupled loops' FOPDT parameters, B1 on the printed FOPDT models with Taylor delays
  (the paper's method), B2 on heurtune's FOPDT fits with Pade delays. Part C (QTS): eq. 66 beside
  the determinant recomputed from the paper's eqs. 64 and 62.
* **Paper 002 Table I**: the GPM PI recomputed from the FOPDT fit of the decoupled identified
  model (eq. 28) at the printed (Am, phim), and the margins it achieves; Table II: ts, max |u|,
  RMS error, IAE and TV per loop of the printed proposed PI and of heurtune's GPM PI, on the
  identified model and on the nonlinear rig, and heurtune's own designs on the rig.

docs/papers.md says, table by table, what matches, what does not, and why.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.analysis.runs import best_run_index
from heurtune.analysis.side_by_side import (
    SideBySideTable,
    add_quantity,
    fmt,
    make_part,
    md_cell,
    number,
    render_latex,
    render_markdown,
    write_text,
)
from heurtune.core.errors import ConfigError
from heurtune.objectives.tito.papers.printed import printed_table
from heurtune.objectives.tito.papers.simulated import (
    PAPER_TABLES,
    TABLE_PLANT,
    check_paper,
    printed_controllers,
    problem_of,
    simulate_printed,
    simulation_notes,
)

__all__ = ["PAPER_TABLES", "paper_tables", "write_paper"]

# ----------------------------------------------------------------------------------------------
# Performance tables
# ----------------------------------------------------------------------------------------------

def _metric_key(metric: str, window: str | None, loop: int) -> str:
    return f"{metric}{loop}" if window is None else f"{metric}_{window}{loop}"


_WINDOWED = {"000": ("servo", "regulatory"), "001": ()}
_METRICS = ("IAE", "ISE", "ITAE")


def _decimals(text: str) -> int:
    """Decimals of a heurtune cell: those of the printed number when it has a decimal point, else
    four significant digits (-1 for :func:`~heurtune.analysis.side_by_side.fmt`)."""
    text = text or ""
    if "." in text and "e" not in text.lower():
        return len(text.split(".")[1])
    return -1


def _add(cells, label: str, printed_text: str, value: float, **kw) -> None:
    add_quantity(cells, label, printed_text, value, decimals=_decimals(printed_text), **kw)


def _conditions(exp) -> str:
    """The nominal scenario in one line: what a reader needs to rerun the numbers."""
    sc = exp.scenarios["nominal"]
    steps = "; ".join(f"loop {i}: " + ", ".join(f"{v:g} at {t:g} s" for t, v in loop)
                      for i, loop in enumerate(sc.setpoints, start=1))
    parts = [f"set-point steps ({steps})"]
    for name, (t, size) in (("input", sc.input_disturbance), ("output", sc.output_disturbance)):
        if any(size):
            parts.append(f"{name} disturbance {size[0]:g}, {size[1]:g} at {t:g} s")
    if max(np.atleast_1d(sc.noise_power)) > 0:
        parts.append(f"measurement noise power {sc.noise_power}")
    parts.append(f"horizon {sc.horizon:g} s, dt {sc.dt:g} s; the papers give no sizes: these are heurtune's "
                 f"(experiments/{exp.name}.toml)")
    return "conditions: " + "; ".join(parts)


def _filter_note(exp) -> str:
    return (f"heurtune's PID filters its derivative, Tf = Td / N with N = {exp.N:g} (docs/tito.md); the printed "
            "PIDs are ideal, Kp + Ki/s + Kd s")


def _performance_table(paper: str, table: str, exp, runs: pd.DataFrame | None) -> SideBySideTable:
    plant = TABLE_PLANT[paper][table]
    printed = printed_table(paper, f"table_{table}", raw=True)
    windows = _WINDOWED[paper]
    columns = [(m, w) for w in windows for m in _METRICS] if windows else [(m, None) for m in _METRICS]
    notes = []
    case = plant if plant in exp.cases else None
    prob = problem_of(exp, case) if case is not None else None
    sims = {}
    if prob is not None:
        for label, gains in printed_controllers(paper, plant).items():
            sims[label] = simulate_printed(prob, gains)
            notes += simulation_notes(label, sims[label], f"heurtune's {plant.upper()} with its inverted decoupler")
    else:
        notes.append(f"the experiment has no case {plant!r}: no heurtune numbers")
    missing = sorted({str(c) for c in printed["controller"]} - set(sims))
    if missing:
        notes.append("no parameters printed for " + ", ".join(missing) + ": their heurtune cells are empty")
    rows = []
    for _, r in printed.iterrows():
        label, loop = str(r["controller"]), int(r["loop"])
        sim = sims.get(label)
        disp, vals = {"controller": label, "loop": f"h{loop}"}, {"controller": label, "loop": f"h{loop}"}
        for metric, window in columns:
            col = f"{metric}_{window}" if window else metric
            key = _metric_key(metric, window, loop)
            h = sim.metrics.get(key, math.nan) if sim is not None and not sim.reason else math.nan
            _add((disp, vals), col.replace("_regulatory", " reg.").replace("_servo", " servo"),
                 _printed_text(r[col]), h)
        rows.append((disp, vals))
    parts = [make_part(f"A: the paper's rows ({plant.upper()})", rows)]
    if runs is not None and case is not None and len(runs):
        metric_cols = [(f"{m} {w}" if w else m, lambda loop, m=m, w=w: _metric_key(m, w, loop)) for m, w in columns]
        parts.append(_designs_part(runs, case, metric_cols, exp, notes))
    notes.insert(0, _conditions(exp))
    if exp.controller == "pid":
        notes.append(_filter_note(exp))
    where = ("servo window 0-500 s, regulatory 500 s to the horizon" if windows
             else "whole response")
    meaning = (f"heurtune: the printed controller simulated on heurtune's {plant.upper()} model and decoupler "
               f"(nominal scenario of {exp.name}, {where}); part B: heurtune's own designs")
    title = f"Paper {paper}, Table {table}: performance indices, {plant.upper()}"
    return SideBySideTable(table, title, meaning, parts, notes)


def _printed_text(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return str(v)


def _designs_part(runs: pd.DataFrame, case: str, columns, exp, notes: list, loop_label: str = "h{loop}"):
    """Part B: the best run of each optimiser and each analytic design of ``case``, with its gains
    and the metrics ``columns`` (``(label, key_of_loop)``) of its nominal response."""
    rows = []
    mine = runs[runs["case"] == case]
    per = 3 if exp.controller == "pid" else 2
    for alg, g in mine.groupby("algorithm", sort=False):
        best = g.loc[best_run_index(g)]
        label = alg if best.get("stop_reason") == "analytic design" else f"{alg} (best of {len(g)} runs)"
        feasible = bool(best.get("feasible", True))
        for loop in (1, 2):
            lab = loop_label.format(loop=loop)
            disp, vals = {"design": label, "loop": lab}, {"design": label, "loop": lab}
            for gain in ("Kp", "Ki", "Kd")[:per]:
                v = number(best.get(f"{gain}{loop}", math.nan))
                disp[gain], vals[gain] = fmt(v, -1), v
            for col, key_of in columns:
                v = number(best.get(f"{key_of(loop)}@nominal", math.nan)) if feasible else math.nan
                disp[col], vals[col] = fmt(v, -1), v
            rows.append((disp, vals))
        if not feasible:
            notes.append(f"part B, {label}: no feasible run ({best.get('status', 'infeasible')}), so its metrics "
                         "are empty; its gains are those of the best run")
    if "gpm" in getattr(exp, "baselines", ()) and "gpm" not in set(mine["algorithm"]):
        notes.append("part B has no GPM design: no FOPDT model fits a decoupled loop of this plant "
                     "(design.parquet)")
    return make_part("B: heurtune's designs of the same plant (no printed counterpart)", rows)


# ----------------------------------------------------------------------------------------------
# Paper 002
# ----------------------------------------------------------------------------------------------

def _table_I(exp) -> SideBySideTable:
    from heurtune.objectives.tito import model as tito

    printed = printed_table("002", "table_I", raw=True)
    prob = _identified_experiment(exp).problem("two_tank")
    rows, notes = [], []
    for _, r in printed.iterrows():
        loop = int(r["loop"])
        fo = prob.chain.fopdt[loop - 1]
        disp, vals = {"loop": f"u{loop}-y{loop}"}, {"loop": f"u{loop}-y{loop}"}
        kc = ti = am = pm = math.nan
        if fo is not None:
            try:
                kc, ti = tito.gpm_pi(fo, float(r["Am"]), float(r["phim"]))
                m = tito.exact_margins(prob.chain.element(loop), tito.PIController(kc, ti).freqresp)
                am, pm = m.gain_margin, m.phase_margin_deg
            except ConfigError as exc:
                notes.append(f"loop {loop}: {exc}")
        _add((disp, vals), "Kc", _printed_text(r["Kc"]), kc)
        _add((disp, vals), "tau_i (s)", _printed_text(r["tau_i"]), ti)
        _add((disp, vals), "tau_D (s)", _printed_text(r["tau_D"]), math.nan)
        _add((disp, vals), "Am", _printed_text(r["Am"]), am)
        _add((disp, vals), "phim (deg)", _printed_text(r["phim"]), pm)
        rows.append((disp, vals))
    notes.append("heurtune designs a PI (no tau_D): the GPM PI (paper 001 eq. 17-27) on the FOPDT fit of the "
                 "decoupled identified model (eq. 28) at the printed Am and phim; its Am and phim columns are the "
                 "margins that design achieves on the exact decoupled loop. The GPM formulas (Ho, Hang and Cao's "
                 "arctan approximation) are exact only on phim = 90 (1 - 1/Am) deg, 60 deg for Am = 3; at 38 deg "
                 "they miss, and the FOPDT fit adds its own error (docs/tito.md)")
    meaning = "heurtune: GPM PI recomputed from eq. 28 at the printed specification, and its exact margins"
    return SideBySideTable("I", "Paper 002, Table I: controller parameters", meaning,
                           [make_part("Proposed optimal GPM PI", rows)], notes)


@functools.lru_cache(maxsize=4)
def _identified_experiment(exp):
    """The experiment's config on the identified linear model (``[plant] model = "tito"``,
    case ``two_tank``), for the rows of Table II on the model."""
    if exp.model == "tito" and "two_tank" in exp.cases:
        return exp
    cfg = dict(exp.config)
    cfg["plant"] = {"model": "tito", "cases": ["two_tank"]}
    cfg["report"] = {}
    return type(exp)(cfg)


def _table_II(exp, runs: pd.DataFrame | None = None) -> SideBySideTable:
    printed = printed_table("002", "table_II", raw=True)
    plants = {"nonlinear rig": problem_of(exp, exp.cases[0])}
    try:
        plants = {"identified model (eq. 28)": _identified_experiment(exp).problem("two_tank"), **plants}
    except ConfigError:
        pass
    proposed = printed_controllers("002", "two_tank")["Proposed Optimal GPM PI"]
    notes = [_conditions(exp)]
    parts = []
    servo = "servo" in exp.windows
    ts_key = "ts_servo" if servo else "ts"
    for where, prob in plants.items():
        gpm = prob.baseline("gpm") if all(c is not None for c in prob.chain.gpm) else None
        designs = {"Proposed Optimal GPM PI": proposed}
        if gpm is not None:
            per = len(prob.names) // 2
            designs["GPM PI [1]"] = tuple(tuple(gpm[i * per:(i + 1) * per]) + (0.0,) * (3 - per) for i in (0, 1))
        sims = {label: simulate_printed(prob, g) for label, g in designs.items()}
        rows = []
        for _, r in printed.iterrows():
            label, loop = str(r["controller"]), int(r["loop"])
            key = "Proposed Optimal GPM PI" if label.lower().startswith("proposed") else "GPM PI [1]"
            sim = sims.get(key)
            ok = sim is not None and not sim.reason
            disp, vals = {"controller": label, "loop": f"u{loop}-y{loop}"}, {"controller": label,
                                                                             "loop": f"u{loop}-y{loop}"}
            for col, metric in (("ts", ts_key), ("u_inf", "max_u"), ("e_t", "rms_e"), ("IAE", "IAE"),
                                ("TV", "tv_u")):
                _add((disp, vals), col, _printed_text(r[col]),
                     sim.metrics.get(f"{metric}{loop}", math.nan) if ok else math.nan)
            rows.append((disp, vals))
        for label, sim in sims.items():
            notes += simulation_notes(label, sim, f"the {where}")
        parts.append(make_part(f"on the {where}", rows))
    notes.append(("ts: time to enter the 2 % band of the set-point for good, within the servo window "
                  f"{exp.windows['servo'][0]:g}-{exp.windows['servo'][1]:g} s" if servo else
                  "ts: time to enter the 2 % band of the set-point for good, over the whole response")
                 + "; inf: the response has not settled by the window's end. u_inf, e_t (RMS error), IAE and TV "
                 "over the whole response. The paper gives neither its set-point sizes nor the units of u: only "
                 "the ordering of the two controllers is comparable, not the magnitudes (docs/papers.md)")
    if runs is not None and len(runs):
        rig = exp.cases[0]
        parts.append(_designs_part(runs, rig, [("ts", lambda loop: f"{ts_key}{loop}"),
                                               ("u_inf", lambda loop: f"max_u{loop}"),
                                               ("e_t", lambda loop: f"rms_e{loop}"),
                                               ("IAE", lambda loop: f"IAE{loop}"), ("TV", lambda loop: f"tv_u{loop}")],
                                   exp, notes, loop_label="u{loop}-y{loop}"))
    notes.append("GPM PI [1]: the paper does not print its parameters; heurtune's GPM PI of the experiment's "
                 f"[controller] gpm specification (Am {exp.gpm['Am']:g}, phim {exp.gpm['phim']:g} deg) stands in "
                 "for it")
    meaning = (f"heurtune: each controller simulated under the nominal scenario of {exp.name} "
               "(ts: settling time, u_inf: max |u|, e_t: RMS error, TV: total variation of u)")
    return SideBySideTable("II", "Paper 002, Table II: performance analysis", meaning, parts, notes)


# ----------------------------------------------------------------------------------------------
# Kharitonov tables
# ----------------------------------------------------------------------------------------------

def _printed_matrices_part(table: str, plant: str, notes: list):
    """Part A: the printed Hurwitz and row-reduced matrices beside those heurtune computes from
    the paper's own Kharitonov polynomials (printed for the QTS only, eqs. 67-70). The paper lays
    the Hurwitz matrix out transposed (its first row is a1, a0): heurtune's cells are ``H^T``."""
    from heurtune.objectives.robustness import hurwitz_matrix
    from heurtune.objectives.tito.kharitonov import row_reduce

    printed = printed_table("000", f"table_{table}", raw=True)
    polys = {}
    if plant == "qts":
        pt = printed_table("000", "polynomials")
        for _, r in pt[pt["name"].astype(str).str.startswith("K")].iterrows():
            polys[str(r["name"])] = np.array([float(r[f"s{k}"]) for k in range(6, -1, -1)])
    else:
        notes.append("the paper prints no Kharitonov polynomials for this plant: part A has no heurtune cells")
    mats = {}
    for name, c in polys.items():
        HT = hurwitz_matrix(c).T
        mats[(name, "HM")], mats[(name, "HMr")] = HT, row_reduce(HT)
    rows = []
    for _, r in printed.iterrows():
        key = (str(r["polynomial"]), str(r["matrix"]))
        i = int(r["i"])
        disp = {"polynomial": key[0], "matrix": key[1], "row": str(i)}
        vals = dict(disp)
        M = mats.get(key)
        for j in range(1, 7):
            h = float(M[i - 1, j - 1]) if M is not None and i <= M.shape[0] and j <= M.shape[1] else math.nan
            add_quantity((disp, vals), f"c{j}", _printed_text(r[f"c{j}"]), h, decimals=1, relative=False)
        rows.append((disp, vals))
    return make_part("A: the printed matrices beside heurtune's, from the printed Kharitonov polynomials", rows)


def _fopdt_plant(models) -> list | None:
    """The decoupled 2x2 plant ``diag(K_i e^{-L_i s} / (T_i s + 1))`` of per-loop FOPDT models
    (:class:`~heurtune.objectives.tito.model.FOPDT`), or None when a loop has none."""
    if any(m is None for m in models):
        return None
    return [[models[0], 0.0], [0.0, models[1]]]


def _mimo_part(A, gains, delta: float, delay: str, pade_order: int, subtitle: str, notes: list):
    """The MIMO Kharitonov test of ``gains`` (ideal PID, as printed) on the 2x2 plant ``A``
    (:func:`heurtune.objectives.tito.kharitonov.mimo_kharitonov_test`)."""
    from heurtune.objectives.robustness import hurwitz_determinants
    from heurtune.objectives.tito import kharitonov

    ctrls = [tuple(g) for g in gains]
    res = kharitonov.mimo_kharitonov_test(A, ctrls, delta, delay=delay, pade_order=pade_order)
    nominal = kharitonov.characteristic_polynomial(A, ctrls, delay=delay, pade_order=pade_order)
    rows = []
    entries = [("nominal", nominal)] + [(f"K{k + 1}", p) for k, p in enumerate(res.polynomials)]
    for name, poly in entries:
        poly = np.asarray(poly, dtype=float)
        if poly[0] < 0:
            poly = -poly
        dets = hurwitz_determinants(poly) if poly.size > 1 else np.array([])
        bad = np.flatnonzero(~(dets > 0))
        cells = {"polynomial": name, "degree": str(poly.size - 1),
                 "coefficients (highest power first)": " ".join(f"{v:.4g}" for v in poly),
                 "Hurwitz determinants > 0": "all" if bad.size == 0 else
                 f"no: Delta_{bad[0] + 1} = {dets[bad[0]]:.3g}",
                 "verdict": "Hurwitz stable" if bad.size == 0 else "not Hurwitz"}
        rows.append((cells, dict(cells)))
    verdict = "robustly stable" if res.robustly_stable else "not robustly stable (" + "; ".join(res.failing) + ")"
    notes.append(f"{subtitle.split(':')[0]}: {verdict}")
    return make_part(subtitle, rows)


def _chain_part(notes: list):
    """Part C (QTS): eq. 66 beside the characteristic polynomial recomputed from the paper's own
    eq. 64 and eq. 62 (:func:`heurtune.objectives.tito.kharitonov.paper000_qts_chain`)."""
    from heurtune.objectives.tito import kharitonov

    pt = printed_table("000", "polynomials", raw=True)
    eq66 = pt[pt["name"] == "characteristic"].iloc[0]
    rows = []
    for source in ("eq64", "eq62"):
        poly = kharitonov.paper000_qts_chain(source)
        disp = {"recomputed from": source.replace("eq", "eq. ")}
        vals = dict(disp)
        for k, v in zip(range(6, -1, -1), poly):
            add_quantity((disp, vals), f"s^{k}", _printed_text(eq66[f"s{k}"]), float(v), decimals=-1, relative=False,
                         diff=False)
        rows.append((disp, vals))
    printed66 = np.array([float(eq66[f"s{k}"]) for k in range(6, -1, -1)])
    right = [r for r in np.roots(printed66) if r.real > 0]
    where = ", ".join(f"{r.real:.3f} {'+' if r.imag >= 0 else '-'} {abs(r.imag):.3f}j" for r in right)
    notes.append("eq. 66 is eq. 64's determinant with its signs and powers of ten dropped (eq. 64 itself differs "
                 "from eq. 62 by a sign error in the s terms); with its true signs it changes sign, so the QTS "
                 "loop of eqs. 62-63 is not Hurwitz, and eq. 66 as printed is not Hurwitz either (roots "
                 f"{where})")
    return make_part("C: eq. 66 beside the determinant recomputed from the paper's eqs. 64 and 62 (Taylor delays)",
                     rows)


def _kharitonov_table(table: str, exp) -> SideBySideTable:
    from heurtune.objectives.tito.model import FOPDT

    plant = TABLE_PLANT["000"][table]
    notes = []
    parts = [_printed_matrices_part(table, plant, notes)]
    gains = printed_controllers("000", plant).get("Proposed PID")
    opts = problem_of(exp, plant).robustness_options if plant in exp.cases else {}
    delta = float(opts.get("variation", 0.2))
    order = int(opts.get("pade_order", 2))
    fo = printed_table("000", "fopdt")
    fo = fo[fo["plant"] == plant].groupby("loop", sort=True).head(1)
    printed_plant = (_fopdt_plant([FOPDT(float(r["K"]), float(r["T"]), float(r["L"])) for _, r in fo.iterrows()])
                     if len(fo) == 2 else None)
    if printed_plant is not None and gains is not None:
        parts.append(_mimo_part(printed_plant, gains, delta, "taylor", order,
                                f"B1: the paper's method done by heurtune: the printed PID on the printed FOPDT loops "
                                f"(decoupled: 0 off the diagonal), Taylor delays, K, T, L +-{delta:.0%}", notes))
    heur_plant = _fopdt_plant(problem_of(exp, plant).chain.fopdt) if plant in exp.cases else None
    if heur_plant is not None and gains is not None:
        parts.append(_mimo_part(heur_plant, gains, delta, "pade", order,
                                f"B2: the printed PID on heurtune's FOPDT fits of its decoupled {plant.upper()} loops, "
                                f"Pade({order}) delays, K, T, L +-{delta:.0%}", notes))
    elif plant in exp.cases:
        notes.append(f"B2: no FOPDT model fits a decoupled loop of heurtune's {plant.upper()}: no test on its fits")
    if plant == "qts":
        parts.append(_chain_part(notes))
    meaning = ("heurtune: part A, the Hurwitz (transposed, as printed) and row-reduced matrices of the printed "
               "Kharitonov polynomials; part B, the MIMO Kharitonov test of det(I + C A) of the printed PID over "
               "the box of the decoupled loops' FOPDT parameters (heurtune.objectives.tito.kharitonov)")
    title = f"Paper 000, Table {table}: Hurwitz and row-reduced Hurwitz matrices, {plant.upper()}"
    return SideBySideTable(table, title, meaning, parts, notes)


# ----------------------------------------------------------------------------------------------
# Public
# ----------------------------------------------------------------------------------------------

def paper_tables(paper, exp, *, runs: pd.DataFrame | None = None) -> list:
    """A paper's tables with heurtune's numbers beside the printed ones.

    Parameters
    ----------
    paper : {"000", "001", "002"}
    exp : TITOExperiment
        The paper's experiment (``experiments/paper_<paper>.toml`` or one like it).
    runs : pandas.DataFrame, optional
        Its ``runs.parquet`` (part B of the performance tables).

    Returns
    -------
    list of SideBySideTable
    """
    paper = check_paper(paper)
    out = []
    for table in PAPER_TABLES[paper]:
        if paper == "002":
            out.append(_table_I(exp) if table == "I" else _table_II(exp, runs))
        elif paper == "000" and table in ("4", "5", "6"):
            out.append(_kharitonov_table(table, exp))
        else:
            out.append(_performance_table(paper, table, exp, runs))
    return out


SMOKE_NOTE = "A --smoke run (tiny budgets, a check): part B's designs are not study results."


def _smoke(out_dir: Path) -> bool:
    """Whether the experiment in ``out_dir`` was last run with ``--smoke`` (its meta.json says)."""
    try:
        return bool(json.loads((out_dir / "meta.json").read_text())["plan"].get("smoke"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def write_paper(paper, exp, out_dir, *, runs: pd.DataFrame | None = None, figures: bool = True) -> list:
    """Write a paper's tables (and figures) beside an experiment's results.

    Parameters
    ----------
    paper : {"000", "001", "002"}
    exp : TITOExperiment
    out_dir : str or Path
        The experiment's folder; the files go to ``out_dir/tables/``.
    runs : pandas.DataFrame, optional
        Default: ``runs.parquet`` of ``out_dir`` when there is one.
    figures : bool
        Also draw the paper's figures (:func:`heurtune.objectives.tito.papers.figures.paper_figures`).

    Returns
    -------
    list of Path
        The files written: ``table_<n>.md`` and ``.tex`` per table, the PNGs and ``README.md``.
    """
    paper = check_paper(paper)
    out_dir = Path(out_dir)
    if runs is None and (out_dir / "runs.parquet").exists():
        runs = pd.read_parquet(out_dir / "runs.parquet")
    tdir = out_dir / "tables"
    tdir.mkdir(parents=True, exist_ok=True)
    written = []
    index = [f"# Paper {paper}: printed tables beside heurtune", "",
             f"Experiment: {exp.name}. Each quantity: printed, heurtune, diff (heurtune - printed) and diff % "
             "(relative to printed). docs/papers.md explains every difference.", "",
             "| table | files | heurtune columns hold |", "|---|---|---|"]
    smoke = _smoke(out_dir)
    if smoke:
        index[2] += " " + SMOKE_NOTE
    for t in paper_tables(paper, exp, runs=runs):
        if smoke:
            t.notes.insert(0, SMOKE_NOTE)
        md = write_text(tdir / f"{t.stem}.md", render_markdown(t))
        tex = write_text(tdir / f"{t.stem}.tex", render_latex(t, label_prefix=getattr(exp, "name", "")))
        written += [md, tex]
        index.append(f"| Table {t.name} | [{md.name}]({md.name}), [{tex.name}]({tex.name}) | {md_cell(t.meaning)} |")
    if figures:
        from heurtune.objectives.tito.papers.figures import paper_figures

        try:
            pngs = paper_figures(paper, exp, tdir, runs=runs)
        except Exception as exc:  # noqa: BLE001 - figures never cost the tables
            pngs = []
            index += ["", f"Figures failed: {exc}"]
        if pngs:
            index += ["", "## Figures", ""] + [f"- [{p.name}]({p.name})" for p in pngs]
            written += pngs
    sweeps = sorted(out_dir.glob("sweep_*.png"))
    if sweeps:  # [report] sweep: the design parameter's response family (paper 000 Fig. 7)
        index += ["", "## Design-parameter sweep (the experiment folder)", ""]
        index += [f"- [{p.name}](../{p.name})" for p in sweeps]
    written.append(write_text(tdir / "README.md", "\n".join(index) + "\n"))
    return written
