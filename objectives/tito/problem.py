"""Tuning problems of decentralised PI/PID control of TITO coupled tanks (papers 000-002).

An experiment config with ``[plant] model = "tito"`` (or ``"two_tank_nonlinear"``) is a
:class:`TITOExperiment`; its cases are plants, each giving a :class:`TITOProblem` with the same
interface as the QTP :class:`heurtune.objectives.qtp.problem.Problem` (names, bounds, ``evaluate``, ``report``,
``simulate``), so the registry, evaluators and experiment runner work unchanged.

The design chain of a case::

    plant G  ->  decoupler D (inverted, paper 002 cases 1/2, or none)
             ->  loop elements q_ii of G D (z_ii with a decoupler, g_ii without)
             ->  FOPDT fits of q_ii (w = 0 and the phase crossover)  ->  GPM PI baseline
             ->  controllers C = diag(c1, c2), c_i = (Kp + Ki/s + Kd s) / (1 + Tf s)

Decision vector: ``Kp1, Ki1[, Kd1], Kp2, Ki2[, Kd2]`` (parallel gains; ``Tf = Td / N``).

Objectives (``[problem] objective``):

``iae``, ``ise``, ``itae``
    The sum over both loops of that integral of ``e_i = r_i - y_i`` over the whole tuning
    scenario (set-point steps, input and output disturbances), from the jitted simulation
    (the "GA PI" / "PSO PI" baselines of the papers). Optional constraints on the loop margins.
``bandwidth``
    ``-(w_b1 + w_b2)``: maximise the closed-loop bandwidths subject to gain margin >= ``Am``,
    phase margin >= ``phim`` (degrees) and ``max |T| <= Mt`` on every loop (the "optimal"
    PI/PID of papers 000 and 002), computed exactly in frequency (delays as ``e^(-j w L)``).

Every candidate's closed loop is checked for stability first (Nyquist on each decoupled loop;
the generalised Nyquist criterion on ``det(I + G D C)`` when there is no decoupler, or when the
scenario varies the plant behind the nominal decoupler); an unstable candidate is infeasible
with a finite violation, never an exception.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from heurtune.core.errors import ConfigError
from heurtune.core.problem import FAILED_OBJECTIVE, FAILED_VIOLATION, Evaluation, TuningProblem
from heurtune.objectives.robustness import (
    interval_characteristic_polynomial,
    kharitonov_test,
    pade,
    spectral_radius_test,
)
from heurtune.objectives.tito import design as tito_design
from heurtune.objectives.tito import margins as tito_margins
from heurtune.objectives.tito import model as tito
from heurtune.objectives.tito import two_tank
from heurtune.objectives.tito.continuous import ContinuousTITOSimulator
from heurtune.objectives.tito.sim import TITOScenario, TITOSimulator, check_sampling

__all__ = ["TITOProblem", "DesignChain", "gain_names", "default_bounds", "fopdt_fit", "DEFAULT_GPM"]

OBJECTIVES = ("iae", "ise", "itae", "bandwidth")
TIME_OBJECTIVES = ("iae", "ise", "itae")  # need a simulation
# What problem.objectives may name: the objectives, and Mt (the larger |T| peak of the loops).
MULTI_OBJECTIVES = OBJECTIVES + ("Mt",)
DEFAULT_GPM = {"Am": 3.0, "phim": 60.0}
DEFAULT_ROBUSTNESS = {"uncertainty": 0.2, "variation": 0.2, "pade_order": 2}
LOOP_METRICS = ("IAE", "ISE", "ITAE", "ts", "max_u", "rms_e", "tv_u", "Am", "phim", "w_b", "Mt", "Ms")
_TIME_METRICS = LOOP_METRICS[:7]
_FREQ_METRICS = LOOP_METRICS[7:]


def gain_names(kind: str) -> tuple:
    """The decision variables of a decentralised PI or PID.

    Parameters
    ----------
    kind : {"pi", "pid"}

    Returns
    -------
    tuple of str
        ``Kp1, Ki1, Kp2, Ki2`` (and ``Kd1``, ``Kd2`` for a PID, loop by loop).
    """
    per = ("Kp", "Ki") if kind == "pi" else ("Kp", "Ki", "Kd")
    return tuple(f"{g}{i}" for i in (1, 2) for g in per)


def default_bounds(kind: str, gpm_x: np.ndarray | None, signs) -> dict:
    """Bounds when the config gives none: loop ``i``'s gains share the sign of its element's
    static gain ``q_ii(0)`` (``signs``), up to 5 times the GPM design's magnitude (Kd: 20 times
    its Kp), or up to 10 without a GPM design.

    Parameters
    ----------
    kind : {"pi", "pid"}
    gpm_x : ndarray, optional
        The GPM design's gains.
    signs : sequence of float
        The signs of ``q_11(0)``, ``q_22(0)``.

    Returns
    -------
    dict of str to (float, float)
    """
    per = ("Kp", "Ki") if kind == "pi" else ("Kp", "Ki", "Kd")
    out = {}
    for i, sign in zip((1, 2), signs):
        for j, g in enumerate(per):
            if gpm_x is not None:
                ref = abs(gpm_x[(i - 1) * 2 + min(j, 1)]) * (20.0 if g == "Kd" else 5.0)
                if g == "Kd":
                    ref = abs(gpm_x[(i - 1) * 2]) * 20.0
            else:
                ref = 10.0
            out[f"{g}{i}"] = (0.0, ref) if sign >= 0 else (-ref, 0.0)
    return out


@dataclasses.dataclass(frozen=True)
class DesignChain:
    """What the design chain gives for one plant (all exact where it can be)."""

    plant: tito.TITOPlant
    decoupler: tito.Decoupler | None
    fopdt: tuple  # per loop: FOPDT or None (no phase crossover / fit impossible)
    fopdt_error: tuple  # per loop: "" or why the fit failed
    gpm: tuple  # per loop: PIController or None
    gpm_margins: tuple  # per loop: tito.Margins on the exact loop, or None

    def element(self, i: int):
        """Frequency response callable of loop element ``q_ii`` (1-based)."""
        if self.decoupler is None:
            return self.plant.element(i, i).freqresp
        return self.decoupler.z11 if i == 1 else self.decoupler.z22


def fopdt_fit(chain_element, label: str):
    """The FOPDT fit of an element, or None and the reason.

    Parameters
    ----------
    chain_element : TFElement
    label : str
        Names the element in the reason.

    Returns
    -------
    tuple
        ``(FOPDT or None, reason)``.
    """
    try:
        return tito.fit_fopdt(chain_element), ""
    except ConfigError as exc:
        return None, f"{label}: {exc}"


def _element_terms(chain: DesignChain, i: int) -> list:
    """Loop element ``q_ii`` as a sum of terms ``prod(num elements) / prod(den elements)`` (each
    times a pure delay, which does not change magnitudes)."""
    p, dec = chain.plant, chain.decoupler
    if dec is None:
        return [((p.element(i, i),), ())]
    j = 3 - i
    if dec.case == 1:  # z_ii = g_ii - g_ij g_ji / g_jj
        return [((p.element(i, i),), ()), ((p.element(i, j), p.element(j, i)), (p.element(j, j),))]
    # case 2: h_ii = g_ij - g_ii g_jj / g_ji
    return [((p.element(i, j),), ()), ((p.element(i, i), p.element(j, j)), (p.element(j, i),))]


def _loop_terms(chain: DesignChain, i: int) -> tuple:
    """Loop element ``q_ii`` as signed :class:`~heurtune.objectives.tito.margins.LoopTerm` (with
    the decoupler's column delay), for the candidate grids of :mod:`.margins`."""
    extra = 0.0 if chain.decoupler is None else float(chain.decoupler.column_delays[i - 1])
    return tuple(tito_margins.LoopTerm(tuple(num), tuple(den), sign=-1.0 if k else 1.0, extra_delay=extra)
                 for k, (num, den) in enumerate(_element_terms(chain, i)))


def _magnitude_tail(terms: list, w: np.ndarray) -> np.ndarray:
    """``B[k] >= sup over w' >= w[k] of |q(j w')|`` for ``q`` a sum of ``terms`` (triangle inequality).

    In each term the zero factors ``|1 + j w Tz|`` are paired with pole factors ``|1 + j w Tp|``
    (largest with largest); a pair's ratio is monotone in ``w``, so its supremum beyond ``w[k]``
    is the larger of its value there and ``Tz / Tp``; an unpaired pole factor decreases. A term
    with more zeros than poles gets no bound (``inf``).
    """
    total = np.zeros(w.size)
    for num, den in terms:
        gain = (
            abs(np.prod([e.K for e in num]) / np.prod([e.K for e in den])) if den else abs(np.prod([e.K for e in num]))
        )
        zeros = sorted([abs(t) for e in num for t in e.leads] + [abs(t) for e in den for t in e.lags], reverse=True)
        poles = sorted([abs(t) for e in num for t in e.lags] + [abs(t) for e in den for t in e.leads], reverse=True)
        zeros = [t for t in zeros if t > 0]
        poles = [t for t in poles if t > 0]
        if len(zeros) > len(poles):
            return np.full(w.size, np.inf)
        bound = np.full(w.size, gain)
        for k, tp in enumerate(poles):
            den_f = np.sqrt(1.0 + (w * tp) ** 2)
            if k < len(zeros):
                tz = zeros[k]
                bound *= np.maximum(np.sqrt(1.0 + (w * tz) ** 2) / den_f, tz / tp)
            else:
                bound /= den_f
        total += bound
    return total


def _controller_tail(X: np.ndarray, kind: str, N: float, w: np.ndarray) -> np.ndarray:
    """``B[r, k] >= sup over w' >= w[k] of |C_r(j w')|`` for ``C = (Kp + Ki/s + Kd s)/(1 + Tf s)``:
    ``|Kp| + |Ki|/w[k] + |Kd|/Tf`` (``inf`` for ``Kd != 0`` without a filter)."""
    Kp, Ki = np.abs(X[:, 0]), np.abs(X[:, 1])
    if kind == "pid":
        Kd = X[:, 2]
        Tf = tito_design.pid_filter_time(X[:, 0], X[:, 1], Kd, N)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.where(Kd == 0, 0.0, np.where(Tf > 0, np.abs(Kd) / Tf, np.inf))
    else:
        d = np.zeros(X.shape[0])
    return (Kp + d)[:, None] + Ki[:, None] / w[None, :]


class TITOProblem(TuningProblem):
    """Tuning problem of one TITO case; see the module docstring.

    Attributes
    ----------
    names, lower, upper, constraint_names, scenarios, tuning_scenario, objective
        As for :class:`heurtune.objectives.qtp.problem.Problem`.
    chain : DesignChain
        Decoupler, FOPDT fits and GPM baseline of the case.
    """

    scenario_type = TITOScenario
    report_columns = ("f", "IAE1", "IAE2", "ISE1", "ISE2", "ITAE1", "ITAE2", "ts1", "ts2", "Am1", "Am2",
                      "phim1", "phim2", "Ms1", "Ms2", "feasible", "reason")
    # The papers print their transfer functions without units (deviations of levels and of
    # pump inputs): the axes say so rather than show bare numbers.
    signal_labels = {"output": "loop", "input": "input", "y_label": "y{i} (model units)",
                     "u_label": "u{i} (model units)", "y_unit": "", "u_unit": ""}

    def __init__(self, case: str, kind: str, chain: DesignChain, bounds: dict, *, objective: str,
                 constraints: dict, scenarios: dict, tuning_scenario: str, N: float, windows: dict,
                 settling_band: float, nonlinear: two_tank.TwoTankParams | None, robustness: dict,
                 gpm_spec: dict | None = None, grid_cache: dict | None = None):
        self.case = case
        self.kind = kind
        self.controller = kind
        self.chain = chain
        self.names = gain_names(kind)
        self.lower = np.array([bounds[n][0] for n in self.names], dtype=np.float64)
        self.upper = np.array([bounds[n][1] for n in self.names], dtype=np.float64)
        self.objective = objective
        self.constraints = dict(constraints)
        self.scenarios = dict(scenarios)
        self.tuning_scenario = tuning_scenario
        self.N = float(N)
        self.windows = dict(windows)
        self.settling_band = float(settling_band)
        self.nonlinear = nonlinear
        self.robustness_options = dict(robustness)
        self.gpm_spec = dict(DEFAULT_GPM if gpm_spec is None else gpm_spec)
        if kind == "pid" and (np.any(self.lower[2::3] != 0.0) or np.any(self.upper[2::3] != 0.0)):
            for sc in self.scenarios.values():  # a derivative the sampled loop may not follow
                check_sampling(sc, N=self.N)
        self.constraint_names = tuple(f"{k}{i}" for k in self.constraints for i in (1, 2))
        self.metric_names = tuple(f"{m}{i}" for m in LOOP_METRICS for i in (1, 2)) + tuple(
            f"{m}_{w}{i}" for w in self.windows for m in ("IAE", "ISE", "ITAE", "ts") for i in (1, 2))
        self._midx = {n: k for k, n in enumerate(self.metric_names)}
        # (w, q(jw), bound of |q| beyond w) of each loop
        self._grids = [self._shared_design_grid(i, grid_cache) for i in (1, 2)]
        self._terms = [_loop_terms(chain, i) for i in (1, 2)]
        self._simulators = {}

    def _shared_design_grid(self, i: int, cache: dict | None):
        """:meth:`_design_grid` of loop ``i``, from ``cache`` where a problem of the same chain,
        structure, bounds, filter and tuning step made it (the family keeps one cache per
        experiment, whose problems are built many times over a run); its arrays read-only."""
        if cache is None:
            return self._design_grid(i)
        key = (id(self.chain), self.kind, i, self.lower.tobytes(), self.upper.tobytes(), self.N,
               self.scenario(self.tuning_scenario).dt)
        hit = cache.get(key)
        if hit is None or hit[0] is not self.chain:  # the chain is kept with its grids: its id stays its own
            grid = self._design_grid(i)
            for array in grid:
                array.flags.writeable = False
            cache[key] = hit = (self.chain, grid)
        return hit[1]

    def _design_grid(self, i: int, n_max: int = 48000):
        """Frequency grid of loop ``i``: from well below the slowest plant time scale up to where
        the element times the largest controller gain in the box falls below 1/8; refined
        (doubling the points) until the Nyquist count of probe controllers (the box's corners
        and the GPM design) is resolved."""
        per = 2 if self.kind == "pi" else 3
        el = self.chain.element(i)
        lo, hi = self.lower[(i - 1) * per:i * per], self.upper[(i - 1) * per:i * per]
        kp_hi = max(abs(hi[0]), abs(lo[0]), 1e-6)
        c_max = kp_hi * (1.0 + (self.N if self.kind == "pid" else 0.0))
        w_min = 1e-3 / max(1.0, _slowest(self.chain.plant))
        probes = [hi, lo, 0.5 * (lo + hi)]
        gpm = self.chain.gpm[i - 1]
        if gpm is not None:
            probes.append(np.array(gpm.parallel()[:per]))
        probes = np.array(probes)
        Kd = probes[:, 2] if per == 3 else np.zeros(len(probes))
        n = 3000
        w_max = None
        try:
            tito_design.design_grid(el, w_min, None, 100, mag_floor=1.0 / (8.0 * c_max))
        except ConfigError:
            # A loop element that does not roll off (a lead, a biproper ratio): stop well
            # above the Nyquist frequency of the sampled controllers.
            w_max = 20.0 * math.pi / self.scenario(self.tuning_scenario).dt
        terms = _element_terms(self.chain, i)
        while True:
            w = tito_design.design_grid(el, w_min, w_max, n, mag_floor=1.0 / (8.0 * c_max))
            Pw = np.asarray(el(w), dtype=np.complex128)
            Pt = _magnitude_tail(terms, w)
            Cw = tito_design.pid_freqresp(probes[:, 0], probes[:, 1], Kd, self.N, w)
            tail = Pt[None, :] * _controller_tail(probes, self.kind, self.N, w)
            m = tito_design.loop_metrics_batch(Pw, w, Cw, Ki=probes[:, 1], tail=tail)
            # A probe whose |L| neither rolls off below 1/8 nor is bounded below TAIL_LEVEL at
            # the grid's end cannot be resolved by more points.
            end = np.abs(Pw[-1] * Cw[:, -1])
            hopeless = (tail[:, -1] >= tito_design.TAIL_LEVEL) & ~(end < tito_design.RESOLVE_LEVEL)
            if np.all(m.resolved | hopeless) or 2 * n > n_max:
                return w, Pw, Pt
            n *= 2

    # -- interface shared with heurtune.objectives.qtp.problem.Problem --------------------------------------
    def __repr__(self):
        return (f"TITOProblem(case={self.case!r}, controller={self.kind!r}, dim={self.dim}, "
                f"objective={self.objective!r}, constraints={self.constraints})")

    def controllers(self, x) -> tuple:
        """The pair of :class:`~heurtune.objectives.tito.model.ParallelPID` of a decision vector."""
        x = np.asarray([self.values(x)[n] for n in self.names]) if isinstance(x, dict) else np.asarray(x, float)
        per = 2 if self.kind == "pi" else 3
        out = []
        for i in range(2):
            g = x[i * per:(i + 1) * per]
            out.append(tito_design.parallel_controller(g[0], g[1], g[2] if per == 3 else 0.0, self.N))
        return tuple(out)

    # -- evaluation -------------------------------------------------------------------------
    def _frequency(self, X: np.ndarray):
        """Per loop (f, g, stable, LoopMetrics) of the bandwidth design for the batch ``X``.

        Each candidate is evaluated on a grid of its own with its crossings refined on the exact
        response (:mod:`heurtune.objectives.tito.margins`). A candidate whose loop would need more
        than ``margins.N_MAX`` points is not resolved, hence not stable; its metrics stay those of
        the problem's shared grid, which grade how far it is from the specification."""
        per = 2 if self.kind == "pi" else 3
        c = self.constraints
        spec = dict(Am_min=c.get("Am", 1.0 + 1e-9), phim_min_deg=c.get("phim", 1e-9), Mt_max=c.get("Mt", 1e9))
        out = []
        for i, (w, Pw, Pt) in enumerate(self._grids):
            Xi = X[:, i * per:(i + 1) * per]
            finite = np.isfinite(Xi).all(axis=1)
            exact = [self._exact_loop_metrics(i + 1, Xi[k]) if finite[k] else None for k in range(len(Xi))]
            wide = np.array([m is None for m in exact], dtype=bool)
            fields = {f.name: np.array([np.nan if m is None else getattr(m, f.name)[0] for m in exact])
                      for f in dataclasses.fields(tito_design.LoopMetrics)}
            if wide.any():  # the shared grid's metrics grade how far these are from the specification
                Xw = np.where(finite[wide, None], Xi[wide], 0.0)
                with np.errstate(all="ignore"):
                    tail = Pt[None, :] * _controller_tail(Xw, self.kind, self.N, w)
                _, _, _, shared = tito_design.bandwidth_design_eval(
                    Pw, w, Xw, self.kind, self.N, return_metrics=True, tail=np.nan_to_num(tail, nan=np.inf), **spec)
                for name, arr in fields.items():
                    arr[wide] = getattr(shared, name)
            fields["stable"] = fields["stable"].astype(bool) & ~wide
            fields["resolved"] = fields["resolved"].astype(bool) & ~wide
            fields["n_rhp"] = np.nan_to_num(fields["n_rhp"]).astype(np.int64)
            metrics = tito_design.LoopMetrics(**fields)
            f, g, stable = tito_design.bandwidth_design_values(metrics, finite, **spec)
            out.append((f, g, stable, metrics))
        return out

    def _exact_loop_metrics(self, i: int, gains: np.ndarray):
        """Exact loop metrics of loop ``i`` (1-based) for one candidate's gains, or None where its
        grid would need more than ``margins.N_MAX`` points."""
        terms = self._terms[i - 1]
        w = self._grids[i - 1][0]
        kd = float(gains[2]) if self.kind == "pid" else 0.0
        row = np.array([[gains[0], gains[1], kd]])

        def tail(ww):
            with np.errstate(all="ignore"):
                bound = _magnitude_tail(_element_terms(self.chain, i), ww) * _controller_tail(
                    row[:, :2] if self.kind == "pi" else row, self.kind, self.N, ww)[0]
            return np.nan_to_num(bound, nan=np.inf)

        return tito_margins.candidate_loop_metrics(terms, (gains[0], gains[1], kd), self.N, float(w[0]),
                                                   float(w[-1]), tail=tail)

    def _simulator(self, sc: TITOScenario):
        if sc not in self._simulators:
            if self.nonlinear is None and sc.loop == "continuous":
                self._simulators[sc] = ContinuousTITOSimulator(self.chain.plant, self.chain.decoupler, sc,
                                                                controller_outputs=False)
            elif self.nonlinear is None:
                self._simulators[sc] = TITOSimulator(self.chain.plant, self.chain.decoupler, sc)
            else:
                self._simulators[sc] = None  # simulate_two_tank per call
        return self._simulators[sc]

    def _run(self, controllers, sc: TITOScenario):
        """``(status, t, r, y, u, errors)`` of one simulation; ``errors`` is the continuous loop's
        :class:`~heurtune.objectives.tito.continuous.ErrorCubics` (None on a sampled loop)."""
        sim = self._simulator(sc)
        if isinstance(sim, ContinuousTITOSimulator):
            res = sim.run(controllers)
            return res.status, res.t, res.r, res.y, res.u, res.errors
        if sim is not None:
            status, y, _, u, _ = sim.arrays(controllers)
            return status, sim.t, sim.r, y, u, None
        df = two_tank.simulate_two_tank(self.nonlinear, controllers, self.chain.decoupler, sc)
        return (df.attrs["status"], df["t"].to_numpy(), df[["r1", "r2"]].to_numpy(),
                df[["y1", "y2"]].to_numpy(), df[["u1", "u2"]].to_numpy(), None)

    def _time_metrics(self, t, r, y, u, row: np.ndarray, errors=None):
        """Fill ``row``'s time-domain metrics. On samples (trapezoid rule, the settling time at
        the samples) for a sampled loop; for the continuous loop (``errors`` given) IAE, ISE,
        ITAE, RMS error and settling time are exact on its error cubics, ``max_u`` and ``tv_u``
        on the step boundaries."""
        e = r - y
        band = self.settling_band / 100.0
        dt = t[1] - t[0] if t.size > 1 else 1.0
        for i in range(2):
            ei = e[:, i]
            ae = np.abs(ei)
            scale = float(np.max(np.abs(r[:, i])))
            band_i = band * (scale if scale > 0 else 1.0)
            if errors is None:
                vals = dict(IAE=_trapz(ae, dt), ISE=_trapz(ei * ei, dt), ITAE=_trapz(t * ae, dt),
                            ts=_settling(t, ae, band_i), rms_e=float(np.sqrt(np.mean(ei * ei))))
            else:
                iae, ise, itae = errors.integrals(i)
                vals = dict(IAE=iae, ISE=ise, ITAE=itae, ts=errors.settling_time(i, band_i),
                            rms_e=math.sqrt(ise / (t[-1] - t[0])))
            vals.update(max_u=float(np.max(np.abs(u[:, i]))), tv_u=float(np.sum(np.abs(np.diff(u[:, i])))))
            for key, v in vals.items():
                row[self._midx[f"{key}{i + 1}"]] = v
            for wname, (t0, t1) in self.windows.items():
                if errors is not None:
                    iae, ise, itae = errors.integrals(i, t0, t1)
                    row[self._midx[f"IAE_{wname}{i + 1}"]] = iae
                    row[self._midx[f"ISE_{wname}{i + 1}"]] = ise
                    row[self._midx[f"ITAE_{wname}{i + 1}"]] = itae
                    row[self._midx[f"ts_{wname}{i + 1}"]] = errors.settling_time(i, band_i, t0, t1)
                    continue
                sel = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
                tw, ew = t[sel], ei[sel]
                if tw.size >= 2:
                    aw = np.abs(ew)
                    row[self._midx[f"IAE_{wname}{i + 1}"]] = _trapz(aw, dt)
                    row[self._midx[f"ISE_{wname}{i + 1}"]] = _trapz(ew * ew, dt)
                    row[self._midx[f"ITAE_{wname}{i + 1}"]] = _trapz((tw - tw[0]) * aw, dt)
                    row[self._midx[f"ts_{wname}{i + 1}"]] = _settling(tw, aw, band_i)

    def evaluate(self, X, scenario=None, *, with_time: bool | None = None) -> Evaluation:
        """Evaluate a batch of candidates (never raises for a bad candidate).

        Parameters
        ----------
        X : array_like, shape (n, d) or (d,)
        scenario : str or TITOScenario, optional
            Defaults to the tuning scenario (time-domain objectives and metrics).
        with_time : bool, optional
            Simulate also for the ``bandwidth`` objective (default: only when the objective
            needs it).

        Returns
        -------
        heurtune.objectives.qtp.problem.Evaluation
            ``reason``: "" when evaluated, else ``invalid_parameter``, ``unstable``,
            ``diverged`` or ``non_finite``.
        """
        if scenario is None and self.robust is not None:  # every tuning scenario, aggregated
            return self.robust.evaluate(self, X, with_time=with_time)
        X = self.batch(X)
        sc = self.scenario(self.tuning_scenario if scenario is None else scenario)
        n = X.shape[0]
        m = len(self.constraint_names)
        metrics = np.full((n, len(self.metric_names)), np.nan)
        f = np.full(n, FAILED_OBJECTIVE)
        g = np.full((n, m), FAILED_VIOLATION)
        reason = np.full(n, "", dtype=object)
        finite = np.isfinite(X).all(axis=1)
        reason[~finite] = "invalid_parameter"
        freq = self._frequency(np.where(finite[:, None], X, 0.0))
        stable = finite.copy()
        for i, (_, _, st, lm) in enumerate(freq):
            stable &= st
            for key, arr in (("Am", lm.gain_margin), ("phim", lm.phase_margin_deg), ("w_b", lm.w_b),
                             ("Mt", lm.Mt), ("Ms", lm.Ms)):
                metrics[:, self._midx[f"{key}{i + 1}"]] = arr
        varied = sc.variation != 0.0 and self.nonlinear is None
        if self.chain.decoupler is None or varied:
            # The loops interact (no decoupler, or a varied plant behind the nominal decoupler):
            # generalised Nyquist on det(I + G D C) of the simulated plant for the loop-stable ones.
            plant = self._simulator(sc).plant if varied else self.chain.plant
            w = self._grids[0][0]
            for k in np.flatnonzero(stable):
                try:
                    stable[k] = tito_design.tito_closed_loop_stable(plant, self.chain.decoupler,
                                                                    self.controllers(X[k]), w)
                except ConfigError:
                    stable[k] = False
        reason[finite & ~stable] = "unstable"
        names = self.objective_names or (self.objective,)
        in_time = any(name in TIME_OBJECTIVES for name in names)
        time_needed = in_time if with_time is None else with_time or in_time
        F = np.full((n, len(names)), FAILED_OBJECTIVE)
        for k in range(n):
            if reason[k]:
                continue
            if time_needed:
                try:
                    status, t, r, y, u, errors = self._run(self.controllers(X[k]), sc)
                except ConfigError:
                    reason[k] = "invalid_parameter"
                    continue
                if status != "ok":
                    reason[k] = "diverged"
                    continue
                self._time_metrics(t, r, y, u, metrics[k], errors)
            F[k] = [self._objective_value(name, metrics[k], freq, k) for name in names]
            f[k] = F[k, 0]
            g[k] = self._constraint_values(metrics[k])
            if not (np.all(np.isfinite(F[k])) and np.all(np.isfinite(g[k]))):
                reason[k] = "non_finite"
                F[k], f[k], g[k] = FAILED_OBJECTIVE, FAILED_OBJECTIVE, FAILED_VIOLATION
        # Unstable candidates: graded by how far their margins are from the specification
        # (the design evaluator's violations), so that the search finds its way back.
        for k in np.flatnonzero(reason == "unstable"):
            excess = max(float(np.max(freq[0][1][k])), float(np.max(freq[1][1][k]))) - tito_design.UNSTABLE_VIOLATION
            g[k] = FAILED_VIOLATION * (1.0 + min(max(excess, 0.0), 1e3) / 1e3)
        bad = reason != ""
        metrics[bad & (reason != "unstable")] = np.nan
        feasible = ~bad & np.all(g <= 0.0, axis=1)
        if self.objective_names is None:
            return Evaluation(f, g, feasible, metrics, self.metric_names, self.constraint_names, reason)
        return Evaluation(f, g, feasible, metrics, self.metric_names, self.constraint_names, reason, F,
                          self.objective_names)

    def _objective_value(self, name: str, row: np.ndarray, freq, k: int) -> float:
        """One objective of candidate ``k``: ``bandwidth`` is ``-(w_b1 + w_b2)``, ``Mt`` the
        larger closed-loop peak of the two loops, the others the sum over both loops."""
        if name == "bandwidth":
            return float(freq[0][0][k] + freq[1][0][k])
        if name == "Mt":
            return float(max(row[self._midx["Mt1"]], row[self._midx["Mt2"]]))
        key = name.upper()
        return float(row[self._midx[f"{key}1"]] + row[self._midx[f"{key}2"]])

    def _constraint_values(self, row: np.ndarray) -> np.ndarray:
        out = []
        for key, lim in self.constraints.items():
            for i in (1, 2):
                v = row[self._midx[f"{key}{i}"]]
                if key in ("Am", "phim"):  # lower bounds
                    out.append(1.0 - v / lim if np.isfinite(v) else -1.0)
                else:  # upper bounds
                    out.append(v / lim - 1.0)
        return np.clip(np.array(out, dtype=np.float64), -1e6, 1e6)

    def warm_up(self):
        """Compile (or load) the jitted TITO kernel on a tiny scenario."""
        sc = TITOScenario(horizon=2 * 0.1, dt=0.1)
        TITOSimulator(tito.preset("wood_berry"), None, sc).arrays(
            (tito.ParallelPID(0.1, 0.01), tito.ParallelPID(-0.05, -0.005)))

    def simulate(self, x, scenario="nominal") -> pd.DataFrame:
        """Trajectories of one candidate: columns t, r1, r2, y1, y2, u1, u2."""
        sc = self.scenario(scenario)
        status, t, r, y, u, _ = self._run(self.controllers(np.array([self.values(x)[n] for n in self.names])), sc)
        df = pd.DataFrame({"t": t, "r1": r[:, 0], "r2": r[:, 1], "y1": y[:, 0], "y2": y[:, 1],
                           "u1": u[:, 0], "u2": u[:, 1]})
        df.attrs["status"] = status
        return df

    def simulation_accuracy(self, x, scenario="nominal") -> dict | None:
        """How accurately the loop simulates one candidate: on the continuous loop with a
        tolerance, the step its run kept, that run's error estimate (the largest output
        difference from the run at twice the step) and the tolerance it was held to; None on
        the sampled loop and on a fixed step (no estimate).

        Parameters
        ----------
        x : array_like or dict
            Gains (see ``names``).
        scenario : str or TITOScenario

        Returns
        -------
        dict or None
            ``step``, ``error_estimate``, ``tolerance``, ``within`` (the estimate within
            ``tolerance * max(1, max|y|)``, what the run was kept for) and ``status``.
        """
        sc = self.scenario(scenario)
        sim = self._simulator(sc)
        if not isinstance(sim, ContinuousTITOSimulator) or sim.tolerance is None:
            return None
        res = sim.run(self.controllers(np.array([self.values(x)[n] for n in self.names])))
        peak = float(np.nanmax(np.abs(res.y))) if np.isfinite(res.y).any() else math.inf
        within = bool(res.error_estimate <= sim.tolerance * max(1.0, peak))
        return dict(step=float(res.step), error_estimate=float(res.error_estimate), tolerance=float(sim.tolerance),
                    within=within, status=res.status)

    def simulated_metrics(self, x, scenario="nominal") -> tuple[str, dict]:
        """The time-domain metrics of one candidate from its simulation alone, without the
        stability check that :meth:`evaluate` runs first (a frequency-domain verdict, which can
        reject a loop that the simulation finds bounded: docs/papers.md).

        Parameters
        ----------
        x : array_like or dict
            Gains (see ``names``); bounds are not checked.
        scenario : str or TITOScenario

        Returns
        -------
        status : str
            ``"ok"``, or the simulator's reason (e.g. ``"diverged"``); the metrics are NaN then.
        metrics : dict
            ``IAE1``, ``ISE1``, ``ITAE1``, ``ts1``, ``max_u1``, ``rms_e1``, ``tv_u1``, the same
            for loop 2, and per window ``IAE_<window><loop>``...
        """
        row = np.full(len(self.metric_names), np.nan)
        status, t, r, y, u, errors = self._run(self.controllers(np.array([self.values(x)[n] for n in self.names])),
                                               self.scenario(scenario))
        if status == "ok":
            self._time_metrics(t, r, y, u, row, errors)
        names = [n for n in self.metric_names if n[:-1].rstrip("_") not in _FREQ_METRICS]
        return status, {n: float(row[self._midx[n]]) for n in names}

    def report(self, x, scenarios=None) -> pd.DataFrame:
        """Metrics of one candidate per scenario (rows) with its objective and feasibility."""
        x = np.array([self.values(x)[n] for n in self.names])
        rows = []
        for name in (scenarios or list(self.scenarios)):
            ev = self.evaluate(x[None, :], name, with_time=True)
            row = {"scenario": name, "f": ev.f[0], "feasible": bool(ev.feasible[0]), "reason": ev.reason[0]}
            row.update(zip(self.metric_names, ev.metrics[0]))
            rows.append(row)
        return pd.DataFrame(rows).set_index("scenario")

    # -- what the runner writes besides the runs ----------------------------------------------
    def baseline(self, name: str) -> np.ndarray:
        """Decision vector of an analytic design (``"gpm"``: GPM PI on the FOPDT fits, Kd = 0)."""
        if name != "gpm":
            raise ConfigError(f"unknown baseline {name!r}; allowed: gpm")
        if any(c is None for c in self.chain.gpm):
            why = "; ".join(e for e in self.chain.fopdt_error if e) or "no FOPDT fit"
            raise ConfigError(f"case {self.case!r}: no GPM design ({why})")
        per = 2 if self.kind == "pi" else 3
        x = np.zeros(self.dim)
        for i, c in enumerate(self.chain.gpm):
            kp, ki, _ = c.parallel()
            x[i * per], x[i * per + 1] = kp, ki
        return x

    def identity(self) -> dict:
        """Everything that defines the tuning problem (hashed into the runner's problem_id)."""
        p = self.chain.plant
        payload = dict(
            plant={k: dataclasses.asdict(getattr(p, k)) for k in ("g11", "g12", "g21", "g22")},
            nonlinear=dataclasses.asdict(self.nonlinear) if self.nonlinear is not None else None,
            decoupler=None if self.chain.decoupler is None else dict(
                case=self.chain.decoupler.case, delays=list(self.chain.decoupler.column_delays)),
            controller=self.kind, N=self.N, objective=self.objective, constraints=self.constraints,
            scenario=self.scenario(self.tuning_scenario).identity(), windows=self.windows,
            bounds=dict(zip(self.names, zip(self.lower.tolist(), self.upper.tolist()))),
            # loop metrics on each candidate's own grid, crossings exact (since issue 49)
            frequency="candidate grid",
        )
        payload.update(self.tuning_identity())
        return payload

    def design_table(self) -> pd.DataFrame:
        """Per loop: the FOPDT fit, the GPM design and its exact margins next to the specified."""
        rows = []
        for i in (1, 2):
            fo, gp, mg = self.chain.fopdt[i - 1], self.chain.gpm[i - 1], self.chain.gpm_margins[i - 1]
            rows.append(dict(
                loop=i, fopdt_K=fo.K if fo else np.nan, fopdt_T=fo.T if fo else np.nan,
                fopdt_L=fo.L if fo else np.nan, fit_error=self.chain.fopdt_error[i - 1],
                gpm_Kc=gp.Kc if gp else np.nan, gpm_Ti=gp.Ti if gp else np.nan,
                Am_spec=self.gpm_spec["Am"], phim_spec=self.gpm_spec["phim"],
                Am_exact=mg.gain_margin if mg else np.nan, phim_exact=mg.phase_margin_deg if mg else np.nan,
            ))
        return pd.DataFrame(rows)

    def margins(self, x) -> pd.DataFrame:
        """Exact loop margins of a design, one row per loop: the candidate's own grid and brentq on
        the exact response (:mod:`heurtune.objectives.tito.margins`); a loop too wide for that grid
        falls back to :func:`~heurtune.objectives.tito.model.exact_margins`."""
        x = np.asarray(x, float)
        per = 2 if self.kind == "pi" else 3
        rows = []
        for i, c in enumerate(self.controllers(x), start=1):
            m = self._exact_loop_metrics(i, x[(i - 1) * per:i * per])
            if m is None:
                m = tito.exact_margins(self.chain.element(i), c.freqresp)
                vals = (m.gain_margin, m.phase_margin_deg, m.w_pc, m.w_gc)
            else:
                vals = (m.gain_margin[0], m.phase_margin_deg[0], m.w_pc[0], m.w_gc[0])
            rows.append(dict(zip(("loop", "gain_margin", "phase_margin_deg", "w_pc", "w_gc"), (i, *map(float, vals)))))
        return pd.DataFrame(rows)

    def robustness(self, x) -> tuple[dict, object]:
        """Spectral-radius and Kharitonov verdicts of a design.

        Returns
        -------
        summary : dict
            ``rho_input_peak``, ``rho_output_peak`` (uncertainty weight ``robustness.uncertainty``),
            their verdicts, and per loop the Kharitonov verdict of the loop's characteristic
            polynomial over the box ``K, T, L`` of its FOPDT fit varied by +-``robustness.variation``
            (delay by a Pade approximant of ``robustness.pade_order``), with the Hurwitz determinants.
        spectral : SpectralRadiusResult
            For the plot.
        """
        opts = {**DEFAULT_ROBUSTNESS, **self.robustness_options}
        ctrls = self.controllers(np.asarray(x, float))
        lo, hi = opts.get("w", (1e-2 / max(1.0, _slowest(self.chain.plant)), 10.0))
        w = np.geomspace(lo, hi, 2000)
        Gw = self.chain.plant.freqresp(w)
        Cw = np.zeros((w.size, 2, 2), dtype=np.complex128)
        Cw[:, 0, 0] = ctrls[0].freqresp(w)
        Cw[:, 1, 1] = ctrls[1].freqresp(w)
        Kw = Cw if self.chain.decoupler is None else self.chain.decoupler.freqresp(w) @ Cw
        sr = spectral_radius_test(Gw, Kw, w, opts["uncertainty"])
        out = dict(uncertainty=opts["uncertainty"], rho_input_peak=sr.rho_input_peak,
                   rho_input_peak_w=sr.rho_input_peak_w, rho_output_peak=sr.rho_output_peak,
                   rho_output_peak_w=sr.rho_output_peak_w, spectral_radius_pass=bool(sr.robustly_stable))
        var, order = opts["variation"], int(opts["pade_order"])
        for i, (fo, c) in enumerate(zip(self.chain.fopdt, ctrls), start=1):
            if fo is None:
                out[f"kharitonov_pass{i}"] = None
                out[f"kharitonov_error{i}"] = "no FOPDT fit of this loop"
                continue
            num_c, den_c = (np.trim_zeros(np.asarray(p, float), "f") for p in c.rational())

            def poly(p, num_c=num_c, den_c=den_c):
                pn, pd_ = pade(p["L"], order)
                plant_num = p["K"] * np.asarray(pn)
                plant_den = np.polymul([p["T"], 1.0], pd_)
                return np.polyadd(np.polymul(den_c, plant_den), np.polymul(num_c, plant_num))

            box = {k: tuple(sorted((v * (1 - var), v * (1 + var)))) for k, v in (("K", fo.K), ("T", fo.T), ("L", fo.L))}
            try:
                lower, upper = interval_characteristic_polynomial(poly, box)
                kt = kharitonov_test(lower, upper)
                out[f"kharitonov_pass{i}"] = bool(kt.robustly_stable)
                out[f"hurwitz_min_det{i}"] = float(min(np.min(d) for d in kt.determinants))
            except ConfigError as exc:
                out[f"kharitonov_pass{i}"] = None
                out[f"kharitonov_error{i}"] = str(exc)
        out.update(variation=var, pade_order=order)
        return out, sr


def _settling(t: np.ndarray, ae: np.ndarray, band: float) -> float:
    """Time from ``t[0]`` to the first sample after the last one with ``|e| > band`` (0 if none;
    ``inf`` if the last sample is outside), as :func:`heurtune.objectives.tito.sim.loop_metrics`."""
    out = np.flatnonzero(ae > band)
    if out.size == 0:
        return 0.0
    return math.inf if out[-1] == t.size - 1 else float(t[out[-1] + 1] - t[0])


def _trapz(v: np.ndarray, dt: float) -> float:
    return float(dt * (np.sum(v) - 0.5 * (v[0] + v[-1]))) if v.size > 1 else 0.0


def _slowest(plant: tito.TITOPlant) -> float:
    """Largest time constant or dead time of the plant (s)."""
    vals = [1.0]
    for i in (1, 2):
        for j in (1, 2):
            e = plant.element(i, j)
            vals += [abs(t) for t in e.lags] + [abs(t) for t in e.leads] + [e.L]
    return max(vals)
