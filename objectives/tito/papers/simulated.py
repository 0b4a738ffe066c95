"""The papers' printed controllers as heurtune's decision vectors, and their simulation.

Shared by :mod:`heurtune.objectives.tito.papers.tables` and
:mod:`heurtune.objectives.tito.papers.figures`.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from heurtune.analysis.side_by_side import number
from heurtune.core.errors import ConfigError
from heurtune.objectives.tito.papers.printed import printed_table

__all__ = ["PAPER_TABLES", "TABLE_PLANT", "printed_controllers", "problem_of", "simulate_printed"]

# The tables each paper's command writes, in order.
PAPER_TABLES = {"000": ("1", "2", "3", "4", "5", "6"), "001": ("1", "2", "3"), "002": ("I", "II")}
# The plant case of each performance or Kharitonov table.
TABLE_PLANT = {
    "000": {"1": "qts", "2": "ccts", "3": "csts", "4": "qts", "5": "csts", "6": "ccts"},
    "001": {"1": "ccts", "2": "csts", "3": "qts"},
}


def check_paper(paper) -> str:
    """A paper's key, checked.

    Parameters
    ----------
    paper : str or int

    Returns
    -------
    str
        ``"000"``, ``"001"`` or ``"002"``.

    Raises
    ------
    ConfigError
        For another paper (the message names the allowed ones).
    """
    paper = str(paper)
    if paper not in PAPER_TABLES:
        raise ConfigError(f"unknown paper {paper!r}; allowed: {', '.join(PAPER_TABLES)}")
    return paper


def printed_controllers(paper: str, plant: str) -> dict:
    """The controllers a paper prints for one plant, as parallel gains per loop.

    Parameters
    ----------
    paper : {"000", "001", "002"}
    plant : str
        heurtune's plant case (``qts``, ``ccts``, ``csts``; paper 002: ``two_tank``).

    Returns
    -------
    dict
        ``{label: ((Kp1, Ki1, Kd1), (Kp2, Ki2, Kd2))}``, the label as the paper's tables name
        the controller (``"Proposed PID"``, ``"Proposed PI"``, ``"Proposed Optimal GPM PI"``).
        Empty when the paper prints none for this plant.
    """
    paper = check_paper(paper)
    if paper == "002":
        t = printed_table("002", "table_I")
        gains = []
        for loop in (1, 2):
            r = t[t["loop"].astype(int) == loop].iloc[0]
            kc, ti = float(r["Kc"]), float(r["tau_i"])
            gains.append((kc, kc / ti, 0.0))
        return {"Proposed Optimal GPM PI": tuple(gains)}
    t = printed_table(paper, "controllers")
    t = t[t["plant"].astype(str) == plant]
    if t.empty:
        return {}
    out = {}
    if paper == "000":
        # eq. 48 is the controller of the QTS text; eq. 60 (appendix) repeats it with Ki1 = 0.2985
        first = t.groupby("loop", sort=True).head(1)
        out["Proposed PID"] = tuple((float(r["Kp"]), float(r["Ki"]), float(number(r["Kd"]) or 0.0))
                                    for _, r in first.sort_values("loop").iterrows())
        return out
    for kind, label in (("pi", "Proposed PI"), ("pid", "Proposed PID")):
        rows = t[t["controller"].astype(str).str.lower() == kind].sort_values("loop")
        if len(rows) != 2:
            continue
        loops = []
        for _, r in rows.iterrows():
            kp, ki, kd = number(r.get("Kp")), number(r.get("Ki")), number(r.get("Kd"))
            if not np.isfinite(kp):  # printed as Kc, Ti (, Td): the parallel form
                kc, ti, td = number(r.get("Kc")), number(r.get("Ti")), number(r.get("Td"))
                kp, ki, kd = kc, kc / ti, kc * td if np.isfinite(td) else 0.0
            loops.append((kp, ki, kd if np.isfinite(kd) else 0.0))
        out[label] = tuple(loops)
    return out


def decision_vector(prob, gains) -> np.ndarray:
    """A problem's decision vector from per-loop parallel gains (Kd dropped for a PI problem).

    Parameters
    ----------
    prob : TITOProblem
    gains : sequence of (Kp, Ki, Kd)
        One triple per loop.

    Returns
    -------
    numpy.ndarray
        In the order of ``prob.names``.
    """
    per = len(prob.names) // 2
    return np.array([g for loop in gains for g in loop[:per]], dtype=np.float64)


# The Pade order of the closed-loop poles that confirm or overrule the tuning check's verdict.
PADE_ORDER = 10


@dataclasses.dataclass
class Simulated:
    """A printed controller simulated by heurtune: ``reason`` is "" when the loop is stable and
    the simulation ran to the horizon (its metrics are then given), else why not (the simulation
    diverged, or the closed-loop poles are unstable); ``check`` is the tuning problem's verdict
    (``evaluate``'s reason: "" or e.g. "unstable"), which can be conservative: when it says
    unstable, the closed-loop poles with Pade(PADE_ORDER) delays decide."""

    reason: str
    metrics: dict
    check: str


@functools.lru_cache(maxsize=16)
def problem_of(exp, case: str):
    """``exp.problem(case)``, built once for the tables and figures of one paper (a TITO problem
    computes its frequency grids when built).

    Parameters
    ----------
    exp : TITOExperiment
    case : str

    Returns
    -------
    TITOProblem
    """
    return exp.problem(case)


@functools.lru_cache(maxsize=64)
def simulate_printed(prob, gains, scenario: str = "nominal") -> Simulated:
    """Simulate a printed controller on a problem's plant, whatever its tuning check says.

    Parameters
    ----------
    prob : TITOProblem
    gains : tuple of (Kp, Ki, Kd)
        One triple per loop (tuples: the result is kept for the next table or figure that asks).
    scenario : str

    Returns
    -------
    Simulated
    """
    x = decision_vector(prob, gains)
    check = str(prob.evaluate(x[None, :], scenario, with_time=False).reason[0])
    status, metrics = prob.simulated_metrics(x, scenario)
    reason = "" if status == "ok" else f"the simulation {status}"
    if check and prob.chain.decoupler is not None and prob.nonlinear is None:
        # a second opinion on the check's verdict: the closed-loop poles with Pade(10) delays
        from heurtune.objectives.tito.kharitonov import closed_loop_poles

        worst = float(np.max(closed_loop_poles(prob.chain.decoupler, prob.controllers(x), delay="pade",
                                               pade_order=PADE_ORDER).real))
        if worst > 0 or not np.isfinite(worst):
            reason = f"closed-loop poles up to Re = {worst:.3g} (Pade({PADE_ORDER}) delays)"
    return Simulated(reason, metrics, check)


def simulation_notes(label: str, sim: Simulated, where: str) -> list:
    """The table notes a simulated printed controller needs (none when all went as expected).

    Parameters
    ----------
    label : str
        The controller's name in the paper.
    sim : Simulated
    where : str
        The plant it ran on, in words.

    Returns
    -------
    list of str
    """
    if sim.reason:
        return [f"{label}: unstable on {where} ({sim.reason}), so it has no heurtune numbers; see docs/papers.md"]
    if sim.check:
        return [f"{label}: heurtune's per-loop Nyquist check (the tuning problem's) calls it {sim.check}, but its "
                f"closed-loop poles on {where} are stable and the simulation stays bounded: its numbers are given "
                "(docs/papers.md)"]
    return []
