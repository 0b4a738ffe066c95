"""The figures of papers 000, 001 and 002, redrawn by heurtune beside the tables.

Each figure draws one controller per plant: the paper's printed controller where it is stable
on heurtune's plant (with heurtune's decoupler), else heurtune's best design of the experiment,
and the figure's title says which. Per paper:

* **000**: Fig. 8, the spectral radius rho(W T(jw)) for multiplicative input and output
  uncertainty (``spectral_radius_<plant>.png``); Fig. 9, the response with white noise at the
  plant input and, apart, on the measured outputs (powers 25, 35 and 45 for QTS, CCTS and CSTS,
  as the paper says; ``noise_input_<plant>.png``, ``noise_output_<plant>.png``); Fig. 10, the
  responses under the experiment's parameter variations (``variation_<plant>.png``); Fig. 7,
  the responses for several values of gamma_m* (``[report] sweep``, written beside the results
  by :mod:`heurtune.objectives.tito.sweep`).
* **001**: the servo and regulatory responses of the printed PI and PID (``responses_<plant>.png``)
  and their responses with input noise of power 20 (``noise_<plant>.png``).
* **002**: the responses of the printed proposed PI and of the GPM PI on the nonlinear rig
  (``responses_rig.png``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from heurtune.analysis.figures import plot_responses
from heurtune.analysis.runs import best_run_index
from heurtune.objectives.tito.papers.simulated import (
    TABLE_PLANT,
    decision_vector,
    printed_controllers,
    problem_of,
    simulate_printed,
)
from heurtune.objectives.tito.report import spectral_radius_figure

__all__ = ["paper_figures", "NOISE_POWER"]

# The white-noise powers of the papers' robustness figures, per plant (paper 000 Figs. 9, 15, 21;
# paper 001 Figs. 9-10 and 23-24: power 20 and 30 "in the process input").
NOISE_POWER = {"000": {"qts": 25.0, "ccts": 35.0, "csts": 45.0}, "001": {"ccts": 20.0, "csts": 20.0, "qts": 30.0}}


def _drawn_controller(paper: str, plant: str, prob, runs):
    """``(label, gains)`` of the controller a figure draws (see the module docstring), or None."""
    for label, gains in printed_controllers(paper, plant).items():
        if not simulate_printed(prob, gains).reason:
            return f"printed {label}", gains
    if runs is None or not len(runs):
        return None
    mine = runs[runs["case"] == prob.case]
    if mine.empty:
        return None
    best = mine.loc[best_run_index(mine)]
    x = np.array([best[n] for n in prob.names], dtype=np.float64)
    per = len(prob.names) // 2
    gains = tuple(tuple(x[i * per:(i + 1) * per]) + (0.0,) * (3 - per) for i in (0, 1))
    return f"heurtune {best['algorithm']} (the printed controller diverges)", gains


def _responses(prob, gains, scenarios: dict, path, title: str) -> Path:
    x = decision_vector(prob, gains)
    frames = [prob.simulate(x, sc).assign(scenario=label) for label, sc in scenarios.items()]
    plot_responses(pd.concat(frames, ignore_index=True), path, title=title, labels=prob.signal_labels)
    return Path(path)


def _noise_scenario(prob, power: float, *, output: bool, input_noise: bool = True):
    """The nominal scenario with white noise of ``power`` on the measured outputs (``output``)
    and at the plant inputs (``input_noise``)."""
    return dataclasses.replace(prob.scenario("nominal"), noise_power=power if output else 0.0,
                               input_noise_power=power if input_noise else 0.0)


def paper_figures(paper: str, exp, out_dir, *, runs: pd.DataFrame | None = None) -> list:
    """Draw a paper's figures (see the module docstring) into ``out_dir``.

    Parameters
    ----------
    paper : {"000", "001", "002"}
    exp : TITOExperiment
    out_dir : str or Path
    runs : pandas.DataFrame, optional
        The experiment's runs (heurtune's best design, where a printed controller is unstable).

    Returns
    -------
    list of Path
        The PNGs written.
    """
    out_dir = Path(out_dir)
    written = []
    if paper == "002":
        prob = problem_of(exp, exp.cases[0])
        designs = dict(printed_controllers("002", "two_tank"))
        if all(c is not None for c in prob.chain.gpm):
            g = prob.baseline("gpm")
            per = len(prob.names) // 2
            designs["GPM PI"] = tuple(tuple(g[i * per:(i + 1) * per]) + (0.0,) * (3 - per) for i in (0, 1))
        frames = [prob.simulate(decision_vector(prob, gains), "nominal").assign(scenario=label)
                  for label, gains in designs.items()]
        path = out_dir / "responses_rig.png"
        plot_responses(pd.concat(frames, ignore_index=True), path, title=f"{exp.name}: nonlinear rig, nominal",
                       labels=prob.signal_labels)
        return [path]
    for plant in dict.fromkeys(TABLE_PLANT[paper].values()):
        if plant not in exp.cases:
            continue
        prob = problem_of(exp, plant)
        drawn = _drawn_controller(paper, plant, prob, runs)
        if drawn is None:
            continue
        label, gains = drawn
        power = NOISE_POWER[paper][plant]
        if paper == "000":
            _, sr = prob.robustness(decision_vector(prob, gains))
            path = out_dir / f"spectral_radius_{plant}.png"
            spectral_radius_figure({label: sr}, path, title=f"Paper 000 Fig. 8: {plant.upper()}, {label}")
            written.append(path)
            for side, output in (("input", False), ("output", True)):
                sc = _noise_scenario(prob, power, output=output, input_noise=not output)
                written.append(_responses(prob, gains, {f"{side} noise": sc}, out_dir / f"noise_{side}_{plant}.png",
                                          f"Paper 000 Fig. 9: {plant.upper()}, white noise of power {power:g} at the "
                                          f"plant {side}, {label}"))
            written.append(_responses(prob, gains, dict(zip(prob.scenarios, prob.scenarios)),
                                      out_dir / f"variation_{plant}.png",
                                      f"Paper 000 Fig. 10: {plant.upper()}, parameter variations, {label}"))
        else:
            designs = {k: v for k, v in printed_controllers(paper, plant).items()
                       if not simulate_printed(prob, v).reason} or {label: gains}
            frames = [prob.simulate(decision_vector(prob, g), "nominal").assign(scenario=k) for k, g in designs.items()]
            path = out_dir / f"responses_{plant}.png"
            plot_responses(pd.concat(frames, ignore_index=True), path,
                           title=f"Paper 001: {plant.upper()}, servo and regulatory responses",
                           labels=prob.signal_labels)
            written.append(path)
            written.append(_responses(prob, gains, {"input noise": _noise_scenario(prob, power, output=False)},
                                      out_dir / f"noise_{plant}.png",
                                      f"Paper 001: {plant.upper()}, input noise of power {power:g}, {label}"))
    return written
