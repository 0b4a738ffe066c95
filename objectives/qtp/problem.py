"""The QTP tuning problem of one plant case (thesis eq. 3.10-3.11).

>>> import heurtune
>>> prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
>>> prob.names[:3]
('Q11', 'Q22', 'Q33')
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pandas as pd

from heurtune.core.errors import ConfigError
from heurtune.core.problem import FAILED_OBJECTIVE, FAILED_VIOLATION, Evaluation, StructureWarning, TuningProblem
from heurtune.objectives.qtp.batch_design import design_batch
from heurtune.objectives.qtp.controllers import ControllerDesignError
from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario, physical_range_flags
from heurtune.objectives.qtp.margins import linear_systems, loop_margins

# Where a QTP problem's simulations run (TuningProblem.set_device): one candidate at a time, a
# batch of lanes in one call on the CPU (the kernels' simulate_lanes), or a CUDA GPU (.gpu).
DEVICES = ("cpu", "cpu-batch", "gpu")

__all__ = ["Problem", "DEVICES", "IntegralActionWarning", "STABILITY_CONSTRAINT", "WEIGHTED_METRICS", "OBJECTIVES"]

# Unstable candidates' violations grow with the largest closed-loop real part, up to this cap.
UNSTABLE_MARGIN_CAP = 1.0e3

OBJECTIVES = {
    "effort": ("J1", "J2"),
    "effort_deviation": ("Jdev1", "Jdev2"),
    "iae": ("IAE1", "IAE2"),
    "ise": ("ISE1", "ISE2"),
    "itae": ("ITAE1", "ITAE2"),
    "tv": ("TV1", "TV2"),
}
# The unit of each objective (levels in cm, voltages in V, times in s) and its name on axes; an
# objective added to OBJECTIVES without them is drawn by its key alone.
OBJECTIVE_UNITS = {"effort": "V² s", "effort_deviation": "V² s", "iae": "cm s", "ise": "cm² s", "itae": "cm s²",
                   "tv": "V"}
OBJECTIVE_LABELS = {"effort": "effort J", "effort_deviation": "effort Jdev", "iae": "IAE", "ise": "ISE", "itae": "ITAE",
                    "tv": "TV"}
_METRIC_INDEX = {name: i for i, name in enumerate(METRIC_NAMES)}
# Metrics a weighted objective may combine (each summed over both loops or pumps).
WEIGHTED_METRICS = ("J", "Jdev", "IAE", "ISE", "ITAE", "TV")
# The constraint that a problem without performance constraints keeps: the candidate's loop is
# stable and its simulation finished (g = 0), else it carries the failure's violation.
STABILITY_CONSTRAINT = "stability"
# Controller types with an LQI structure, whose interaction-loop margins the problem reports.


class IntegralActionWarning(StructureWarning):
    """The configured controller structure cannot hold integral action on this plant."""


class Problem(TuningProblem):
    """Constrained tuning problem of one plant case.

    Minimise the objective (default: effort ``J = J1 + J2``, the integral of the squared
    absolute pump voltages; or ``Jdev``, IAE, ISE, ITAE, or a weighted sum of metrics) subject
    to ``Mp_i < Mp``, ``ts_i < ts`` and ``ess_i < ess`` for both lower tanks, under the tuning
    scenario. Stability is always required: a candidate that cannot be designed, whose loop is
    unstable or whose simulation diverges is never feasible. Without performance constraints
    (``constraints = {}``, the config's ``"none"``) a single ``stability`` constraint column
    carries that (0 when simulated, the failure's violation otherwise).

    Attributes
    ----------
    names : tuple of str
        Decision variables, e.g. ``Q11, Q22, Q33, Q44, R11, R22, Ki1, Ki2, alpha1, alpha2``.
    lower, upper : (d,) ndarray
        Bounds.
    constraint_names : tuple of str
        ``Mp1, Mp2, ts1, ts2, ess1, ess2`` (those configured).
    scenarios : dict of str to Scenario
        The tuning scenario and its uncertainty variants (``nominal``, ``-30%``, ``+30%``).
    weights : dict or None
        Metric weights of ``objective = "weighted"``.
    structure_warning : str or None
        Why the controller structure cannot hold integral action on this plant (one line), or
        None (see :func:`heurtune.objectives.qtp.controllers.integral_action_obstruction`).
    """

    scenario_type = Scenario
    devices = DEVICES
    report_columns = ("Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2", "J1", "J2", "J", "hmin", "hmax", "umin", "umax",
                      "feasible", "reason")
    # Mp and ess in percent of the operating level, the extremes of levels and voltages
    metric_units = {"Mp": "%", "ts": "s", "ess": "%", "IAE": "cm s", "ISE": "cm² s", "ITAE": "cm s²",
                    "J": "V² s", "Jdev": "V² s", "TV": "V", "hmin": "cm", "hmax": "cm", "umin": "V", "umax": "V"}
    signal_labels = {"output": "tank", "input": "pump", "y_label": "level {i} (cm)",
                     "u_label": "pump voltage u{i} (V)", "y_unit": "cm", "u_unit": "V"}

    def __init__(self, case: str, loop: ClosedLoop, names, lower, upper, *, objective: str,
                 constraints: dict, settling_band: float, scenarios: dict, tuning_scenario: str,
                 weights: dict | None = None, structure_warning: str | None = None):
        self.case = case
        self.loop = loop
        self.controller = loop.kind
        self.names = tuple(names)
        self.lower = np.asarray(lower, dtype=np.float64)
        self.upper = np.asarray(upper, dtype=np.float64)
        self.objective = objective
        self.constraints = dict(constraints)
        self.settling_band = float(settling_band)
        self.scenarios = dict(scenarios)
        self.tuning_scenario = tuning_scenario
        self.structure_warning = structure_warning
        self.baselines = {}  # name -> decision vector of a fixed controller (Experiment.problem)
        if objective == "weighted":
            if not weights:
                raise ConfigError("problem.objective = 'weighted' needs problem.weights "
                                  f"(a weight per metric among {', '.join(WEIGHTED_METRICS)})")
            self.weights = dict(weights)
            self._objective_idx = [_METRIC_INDEX[f"{m}{i}"] for m in self.weights for i in (1, 2)]
            self._objective_w = np.repeat([float(w) for w in self.weights.values()], 2)
        else:
            self.weights = None
            self._objective_idx = [_METRIC_INDEX[m] for m in OBJECTIVES[objective]]
            self._objective_w = None
        self._constraint_idx = []
        self._constraint_limit = []
        names_g = []
        for key, limit in self.constraints.items():
            for i in (1, 2):
                names_g.append(f"{key}{i}")
                self._constraint_idx.append(_METRIC_INDEX[f"{key}{i}"])
                self._constraint_limit.append(limit)
        # Without performance constraints a column still carries stability, so that an unstable
        # or diverging candidate is never feasible to the optimisers either.
        self._stability_only = not names_g
        self.constraint_names = (STABILITY_CONSTRAINT,) if self._stability_only else tuple(names_g)
        self._constraint_limit = np.array(self._constraint_limit)
        # the same indices as arrays, for the bookkeeping of simulated candidates (np.take)
        self._objective_take = np.array(self._objective_idx, dtype=np.intp)
        self._constraint_take = np.array(self._constraint_idx, dtype=np.intp)

    @property
    def objective_label(self) -> str:
        """The objective with its unit, for axes: e.g. ``"effort J (V² s)"``."""
        if self.objective == "weighted":
            return "weighted objective: " + " + ".join(f"{w:g} {m}" for m, w in self.weights.items())
        return self.objective_axis_label(self.objective)

    def objective_axis_label(self, name: str) -> str:
        """Objective ``name`` (one of :data:`OBJECTIVES`) with its unit, for an axis: e.g.
        ``"IAE (cm s)"`` (a Pareto front's axes)."""
        label = OBJECTIVE_LABELS.get(name, name)
        unit = OBJECTIVE_UNITS.get(name)
        return f"{label} ({unit})" if unit else label

    def __repr__(self):
        return (f"Problem(case={self.case!r}, controller={self.loop.kind!r}, dim={self.dim}, "
                f"objective={self.objective!r}, constraints={self.constraints})")

    # -- evaluation -------------------------------------------------------------------
    def _design(self, x):
        """The controller of candidate ``x`` if it can be designed and its linearised loop is
        stable, else None; with the reason ("" when designed and stable) and, for an unstable
        loop, its eigenvalue margin. Design and stability are those of the nominal
        linearisation, which no scenario changes."""
        if not np.isfinite(x).all():
            return None, "invalid_parameter", 0.0
        try:
            ctrl = self.loop.controller(dict(zip(self.names, x.tolist())))
        except ControllerDesignError as exc:
            return None, exc.reason, 0.0
        except ConfigError:
            return None, "invalid_parameter", 0.0
        margin = self.loop.stability_margin(ctrl)
        if not margin < 0.0:
            return None, "unstable", margin
        return ctrl, "", 0.0

    @staticmethod
    def _simulated_reason(diverged, values) -> str:
        return "diverged" if diverged else ("" if np.isfinite(values).all() else "non_finite")

    def _evaluate_one(self, x, scenarios: list, metrics_rows: np.ndarray) -> tuple:
        """Per scenario, the reason ("" when simulated), and for an unstable loop its
        eigenvalue margin. The controller is designed and checked once for all scenarios, then
        simulated by :meth:`~heurtune.objectives.qtp.loop.ClosedLoop.run_scenarios` (one
        discretisation per time step, one kernel call per group of like scenarios)."""
        ctrl, reason, margin = self._design(x)
        if ctrl is None:
            return [reason] * len(scenarios), margin
        reasons = []
        for row, (diverged, values) in zip(metrics_rows, self.loop.run_scenarios(ctrl, scenarios,
                                                                                 settling_band=self.settling_band)):
            if not diverged:
                row[:] = values
            reasons.append(self._simulated_reason(diverged, values))
        return reasons, 0.0

    def _evaluate_batch(self, X, scenarios: list, metrics: np.ndarray, reason: np.ndarray) -> np.ndarray:
        """:meth:`_evaluate_one` for all candidates at once on the batched device: the batch is
        designed and checked by :func:`~heurtune.objectives.qtp.batch_design.design_batch`, then
        every designed candidate under every scenario is one lane of
        :meth:`~heurtune.objectives.qtp.loop.ClosedLoop.run_batch`. Fills ``metrics`` (k, n, N)
        and ``reason`` (k, n); returns the margins (n,)."""
        ctrls, why, margins = design_batch(self.loop, self.names, X)
        reason[:, :] = why[None, :]
        designed = [(i, c) for i, c in enumerate(ctrls) if c is not None]
        diverged, values = self.loop.run_batch([c for _, c in designed], scenarios,
                                               settling_band=self.settling_band, device=self.device)
        for j, (i, _) in enumerate(designed):
            for s in range(len(scenarios)):
                if not diverged[j, s]:
                    metrics[s, i] = values[j, s]
                reason[s, i] = self._simulated_reason(diverged[j, s], values[j, s])
        return margins

    def evaluate(self, X, scenario=None) -> Evaluation:
        """Evaluate a batch of candidates.

        Parameters
        ----------
        X : array_like, shape (n, d) or (d,)
        scenario : str or Scenario, optional
            Defaults to the tuning scenario, or to every tuning scenario aggregated when the
            problem is tuned robustly (``robust``, :mod:`heurtune.core.robust`).

        Returns
        -------
        Evaluation
            Never raises for a bad candidate: unstable, undesignable or diverging candidates get
            ``FAILED_OBJECTIVE``, violations ``FAILED_VIOLATION`` and a reason.
        """
        if scenario is None and self.robust is not None:  # every tuning scenario, aggregated
            return self.robust.evaluate(self, X)
        return self.evaluate_scenarios(X, [self.tuning_scenario if scenario is None else scenario])[0]

    def evaluate_scenarios(self, X, scenarios) -> list:
        """One :class:`Evaluation` per scenario, each candidate's controller designed, checked
        and discretised once for all of them (the results equal :meth:`evaluate` per scenario)."""
        X = self.batch(X)
        scs = [self.scenario(s) for s in scenarios]
        n, k = X.shape[0], len(scs)
        m = len(self.constraint_names)
        metrics = np.full((k, n, len(METRIC_NAMES)), np.nan)
        reason = np.empty((k, n), dtype=object)
        if self.device != "cpu":
            margins = self._evaluate_batch(X, scs, metrics, reason)
        else:
            margins = np.zeros(n)
            for i in range(n):
                reason[:, i], margins[i] = self._evaluate_one(X[i], scs, metrics[:, i])
        if (reason[0, 0] == "" if reason.size == 1 else (reason == "").all()) and self._plain_bookkeeping():
            return self._simulated_evaluations(metrics, reason)
        simulated = reason == ""
        failed = not simulated.all()
        if failed:
            metrics[~simulated] = np.nan
        if self._objective_w is None:
            f = metrics[:, :, self._objective_idx].sum(axis=2)
        else:
            f = np.empty((k, n))
            for s, i in zip(*np.nonzero(simulated)):
                f[s, i] = metrics[s, i, self._objective_idx] @ self._objective_w
        if self._stability_only:
            g = np.zeros((k, n, m))
        else:
            g = metrics[:, :, self._constraint_idx] / self._constraint_limit - 1.0
        if failed:
            f[~simulated] = FAILED_OBJECTIVE
            g[~simulated] = FAILED_VIOLATION
            unstable = reason == "unstable"
            if unstable.any():
                # Graded: the less unstable, the smaller the violation, so Deb's rules and
                # SLSQP both see a way back to stability.
                graded = FAILED_VIOLATION * (1.0 + np.minimum(margins, UNSTABLE_MARGIN_CAP))
                g[unstable] = np.broadcast_to(graded, (k, n))[unstable][:, None]
        feasible = simulated & np.all(g <= 0.0, axis=2)
        out = []
        for s in range(k):
            F = None
            if self.objective_names is not None:
                F = np.column_stack([metrics[s][:, idx].sum(axis=1) for idx in self._objectives_idx])
                F[~simulated[s]] = FAILED_OBJECTIVE
            out.append(Evaluation(f[s], g[s], feasible[s], metrics[s], METRIC_NAMES, self.constraint_names, reason[s],
                                  F, self.objective_names or ()))
        return out

    def _plain_bookkeeping(self) -> bool:
        """Whether :meth:`_simulated_evaluations` applies: one objective, a sum of metrics, and
        performance constraints."""
        return self._objective_w is None and self.objective_names is None and not self._stability_only

    def _simulated_evaluations(self, metrics: np.ndarray, reason: np.ndarray) -> list:
        """The evaluations of :meth:`evaluate_scenarios` when every candidate was simulated,
        the usual case, whose bookkeeping matters when one candidate is evaluated at a time
        (line searches): the arithmetic of the general path without its masks, which would
        change nothing (the same sums and quotients of the same values, bit for bit)."""
        f = np.take(metrics, self._objective_take, axis=2).sum(axis=2)
        g = np.take(metrics, self._constraint_take, axis=2) / self._constraint_limit - 1.0
        feasible = (g <= 0.0).all(axis=2)
        return [Evaluation(f[s], g[s], feasible[s], metrics[s], METRIC_NAMES, self.constraint_names, reason[s])
                for s in range(len(metrics))]

    def set_device(self, device: str) -> None:
        """See :meth:`TuningProblem.set_device`; ``"gpu"`` needs a CUDA GPU (checked here)."""
        if device == "gpu":
            from heurtune.objectives.qtp import gpu

            gpu.require()
        super().set_device(device)

    def set_objectives(self, names, reference_point, decision_weights=None) -> None:
        """Several objectives, names of :data:`OBJECTIVES` (see :meth:`TuningProblem.set_objectives`)."""
        super().set_objectives(names, reference_point, decision_weights)
        self._objectives_idx = [[_METRIC_INDEX[m] for m in OBJECTIVES[name]] for name in self.objective_names]

    def baseline(self, name: str) -> np.ndarray:
        """Decision vector of a fixed controller named in the config's ``[[baselines]]``.

        Raises
        ------
        ConfigError
            For a name the case has no baseline of.
        """
        try:
            return self.baselines[name].copy()
        except KeyError:
            raise ConfigError(f"case {self.case!r}: unknown baseline {name!r}; "
                              f"allowed: {', '.join(self.baselines) or 'none'}") from None

    def warm_up(self):
        """Compile or load the jitted kernels (call in the parent before starting workers)."""
        self.loop.warm_up()

    def identity(self) -> dict:
        """Everything that defines the tuning problem (hashed into the runner's problem_id)."""
        p = self.loop.plant
        payload = dict(
            plant=dict(A=p.A, a=p.a, k=p.k, gamma=p.gamma, levels=p.levels, g=p.g),
            controller=self.loop.kind, options={k: list(v) if isinstance(v, tuple) else v
                                                for k, v in self.loop.options.items()
                                                if not (k == "pairing" and v == "diagonal")},
            scenario=dataclasses.asdict(self.scenario(self.tuning_scenario)),
            objective=self.objective, constraints=self.constraints, band=self.settling_band,
            bounds=dict(zip(self.names, zip(self.lower.tolist(), self.upper.tolist()))),
        )
        # Options added later enter only when set, so earlier problems keep their ids.
        if self.weights:
            payload["weights"] = self.weights
        if payload["scenario"].get("limits", "none") == "none":
            payload["scenario"].pop("limits", None)
        for key, default in (("dt", None), ("tolerance", None), ("step", None), ("output_dt", 0.01),
                             ("setpoint_step", (0.0, 0.0)), ("setpoint_time", 0.0), ("integrator", "switching")):
            if payload["scenario"].get(key, default) == default:
                payload["scenario"].pop(key, None)
        if self.loop.plant_model != "qtp":
            payload["plant"]["model"] = self.loop.plant_model
        tuning = self.scenario(self.tuning_scenario)
        if tuning.continuous and tuning.step is None and self.loop.structure.extras.get("feedback_step"):
            # The continuous loop's step of these structures shortens for a fast feedback
            # (continuous.feedback_step): results made before it was added never mix with its.
            payload["step_rule"] = "feedback"
        payload.update(self.tuning_identity())
        return payload

    def margins(self, x) -> pd.DataFrame | None:
        """Margins of the four interaction loops of the design
        (:func:`heurtune.objectives.qtp.margins.loop_margins`), for every structure whose
        realisation is minimal; None for one that declares ``extras["margins"] = False`` (LADR,
        whose observer has structural zero eigenvalues)."""
        if not self.loop.structure.extras.get("margins", True):
            return None
        return loop_margins(self, np.array([self.values(x)[n] for n in self.names]))

    def linear_systems(self, x, scenario="nominal") -> dict:
        """The plant linearisation, the controller, the closed loop and the four element loops
        of candidate ``x`` as python-control ``StateSpace`` objects with named signals
        (:func:`heurtune.objectives.qtp.margins.linear_systems`)."""
        return linear_systems(self, x, scenario)

    # What best.mat holds of a QTP design (the .mat export writes it into README.txt).
    CONTROLLER_RECORD_FIELDS = (
        ("plant.model", "qtp (levels in cm) or qtp_bond_graph (pressures; the controller still sees levels)"),
        ("plant.name", "the plant case (min, nmp, or a plant.custom name)"),
        ("plant.tank_area", "A1..A4, cm^2"),
        ("plant.outlet_area", "a1..a4, cm^2"),
        ("plant.pump_gain", "k1, k2, cm^3/(V s)"),
        ("plant.valve_split", "gamma1, gamma2: share of pump j's flow into lower tank j"),
        ("plant.gravity", "g, cm/s^2"),
        ("plant.levels", "operating levels h1o, h2o of the lower tanks, cm"),
        ("plant.height, plant.u_range", "tank heights (cm) and pump range (V) where the plant has them, else NaN"),
        ("plant.linearisation.A, .B, .C", "dx' = A dx + B du, dy = C dx at the operating point (x: h1..h4 in cm, "
                                          "u: V, y: h1, h2)"),
        ("operating_point.h0, .u0", "operating levels h1o..h4o (cm) and voltages u1o, u2o (V)"),
        ("scenario", "the scenario of the response: horizon (s), output_disturbance (cm, added to y1, y2 at "
                     "disturbance_time s), input_disturbance (V, added to u1, u2 at input_disturbance_time s), "
                     "saturation (V, NaN: none), limits, uncertainty (factor on every area), sample_time (s, NaN: "
                     "the continuous loop), tolerance (cm), setpoint_step (cm, set-points from h0 at setpoint_time s), "
                     "integrator (the continuous loop's method)"),
        ("controller.A, .B, .C, .D", "z' = A z + B w, du = C z + D w; w = [y1 - h1o, y2 - h2o, h3 - h3o, h4 - h4o] "
                                     "(cm), du = u - u0 (V); the error of a loop is -w"),
        ("controller.blocks", "one row per block of states: first and last state, 1-based, inclusive"),
        ("controller.block_pump", "the pump (1 or 2) each block belongs to (its anti-windup channel)"),
        ("controller.type", "the controller structure (folqi, pid, ...)"),
        ("controller.Br, .Dr", "a structure that reads the set-points r (cm from h0): z' = A z + B w + Br r, "
                               "du = C z + D w + Dr r, w then taken from h0 (absent otherwise)"),
        ("discrete.Phi, .Gamma, .C, .D, .dt", "the controller with zero-order hold at dt s: z[k+1] = Phi z[k] + "
                                              "Gamma w[k], du[k] = C z[k] + D w[k]"),
        ("response", "the nominal response: t (s), h1..h4 (cm), y1, y2 (cm, measured), u1, u2 (V)"),
    )

    def controller_record(self, x) -> dict:
        """What the ``.mat`` export writes of a design: the plant (parameters, linearisation),
        the operating point, the scenario of the response, the continuous controller (blocks as
        1-based rows), its zero-order-hold discretisation at the scenario's sample period
        (``output_dt`` for the continuous loop) and the nominal response
        (:attr:`CONTROLLER_RECORD_FIELDS` says what each field is, in which unit);
        ``controller_error`` instead when it cannot be designed."""
        import scipy.linalg

        scenario = "nominal" if "nominal" in self.scenarios else self.tuning_scenario
        try:
            ctrl = self.loop.controller(self.values(x))
            sc = self.scenario(scenario)
            dt = float(sc.output_dt if sc.dt is None else sc.dt)
            resp = self.simulate(x, scenario)
        except (ControllerDesignError, ConfigError) as exc:
            return {"controller_error": str(exc)}
        nz, nw = ctrl.B.shape
        M = np.zeros((nz + nw, nz + nw))
        M[:nz, :nz], M[:nz, nz:] = ctrl.A, ctrl.B
        E = scipy.linalg.expm(M * dt)
        p = self.loop.plant

        def numbers(value):
            return np.full(1, np.nan) if value is None else np.asarray(value, dtype=float)

        _, u_op = self.loop._perturbed(1.0)
        scen = dict(name=str(scenario), horizon=float(sc.horizon), output_disturbance=numbers(sc.output_disturbance),
                    disturbance_time=float(sc.disturbance_time), input_disturbance=numbers(sc.input_disturbance),
                    input_disturbance_time=float(sc.input_disturbance_time), saturation=numbers(sc.saturation),
                    limits=str(sc.limits), uncertainty=float(sc.uncertainty), noise_sd=float(sc.noise_sd),
                    sample_time=float(np.nan if sc.dt is None else sc.dt),
                    tolerance=float(np.nan if sc.tolerance is None else sc.tolerance),
                    setpoint_step=numbers(sc.setpoint_step), setpoint_time=float(sc.setpoint_time),
                    integrator=str(sc.integrator))
        lin = self.loop.plant_linearisation
        return {
            "plant": {"model": self.loop.plant_model, "name": str(p.name), "tank_area": numbers(p.A),
                      "outlet_area": numbers(p.a), "pump_gain": numbers(p.k), "valve_split": numbers(p.gamma),
                      "gravity": float(p.g), "levels": numbers(p.levels), "height": numbers(p.height),
                      "u_range": numbers(p.u_range), "linearisation": {"A": lin.A, "B": lin.B, "C": lin.C}},
            "operating_point": {"h0": np.asarray(self.loop.op.h, dtype=float), "u0": np.asarray(u_op, dtype=float)},
            "scenario": scen,
            "controller": {"A": ctrl.A, "B": ctrl.B, "C": ctrl.C, "D": ctrl.D, "type": self.loop.kind,
                           "blocks": np.array([(a + 1, b) for a, b in ctrl.blocks], dtype=float).reshape(-1, 2),
                           "block_pump": np.array(ctrl.block_channel, dtype=float) + 1.0,
                           **({"Br": np.asarray(ctrl.Br, dtype=float), "Dr": np.asarray(ctrl.Dr, dtype=float)}
                              if ctrl.reads_reference else {})},
            "discrete": {"dt": dt, "Phi": E[:nz, :nz], "Gamma": E[:nz, nz:], "C": ctrl.C, "D": ctrl.D},
            "response_scenario": scenario, "response": resp}

    def physical_limits(self) -> dict | None:
        """The tank heights (0 to height, cm) and the pump voltage range, when the plant has them."""
        p = self.loop.plant
        if not p.has_limits:
            return None
        return {"y": [(0.0, p.height[0]), (0.0, p.height[1])], "h": [(0.0, h) for h in p.height], "u": tuple(p.u_range)}

    def simulate(self, x, scenario="nominal", *, record_levels: bool = True) -> pd.DataFrame:
        """Trajectories of one candidate: columns t, h1..h4, y1, y2, u1, u2.

        A candidate whose linearised loop is unstable is simulated all the same (its trajectory
        shows why); one whose controller cannot be designed is not.

        Raises
        ------
        ControllerDesignError
            (a :class:`heurtune.core.errors.DesignError`) when the controller cannot be
            designed for ``x``; its ``reason`` is the one :meth:`evaluate` reports for ``x``
            (``invalid_parameter``, ``riccati_failed``, ...).
        """
        sc = self.scenario(scenario)
        values = self.values(x)
        ctrl, reason, _ = self._design(np.array([values[n] for n in self.names], dtype=np.float64))
        if ctrl is None and reason != "unstable":
            raise ControllerDesignError(reason, "no controller can be designed for these values")
        if ctrl is None:
            ctrl = self.loop.controller(values)
        return self.loop.run(ctrl, sc, record_levels=record_levels).to_frame()

    def report(self, x, scenarios=None) -> pd.DataFrame:
        """Metrics of one candidate per scenario (rows) with its objective and feasibility.

        Column ``range`` names where the trajectory leaves the plant's physical range (levels
        outside [0, height], voltages outside ``u_range``; "" when inside or when the plant has
        no limits), see :func:`heurtune.objectives.qtp.loop.physical_range_flags`.

        When the controller structure cannot hold integral action on this plant
        (``structure_warning``), an :class:`IntegralActionWarning` says so.
        """
        if self.structure_warning:
            warnings.warn(f"{self.case}: {self.structure_warning}", IntegralActionWarning, stacklevel=2)
        x = np.array([self.values(x)[n] for n in self.names])
        rows = []
        for name in (scenarios or list(self.scenarios)):
            ev = self.evaluate(x[None, :], name)
            row = {"scenario": name, "f": ev.f[0], "feasible": bool(ev.feasible[0]),
                   "reason": ev.reason[0]}
            row.update(zip(METRIC_NAMES, ev.metrics[0]))
            row["J"] = row["J1"] + row["J2"]
            row["range"] = "; ".join(physical_range_flags(ev.metrics[0], self.loop.plant))
            row.update(self.window_metrics(x, name, metrics=ev.metrics[0] if ev.reason[0] == "" else None))
            rows.append(row)
        return pd.DataFrame(rows).set_index("scenario")

    def window_metrics(self, x, scenario="nominal", *, metrics=None) -> dict:
        """IAE, ISE and ITAE of each loop per window of the scenario (:attr:`Scenario.windows`:
        servo from the set-point step, regulatory from the later disturbance), as
        ``IAE_servo1``, ``ITAE_regulatory2``, ...; ITAE counts time from the window's start.
        ``{}`` for a scenario without windows; NaN for a candidate that is not simulated.

        Each window's integrals are the differences of the whole-run integrals up to its ends:
        runs cut at the window boundaries follow the same trajectory on the same steps
        (:meth:`Scenario.cut`), so the windows add up to the run's own IAE, ISE and ITAE.
        ``metrics``: the whole run's metrics (in the order of ``METRIC_NAMES``), whose integrals
        close the last window; None for a candidate that was not simulated (NaN windows)."""
        sc = self.scenario(scenario)
        windows = sc.windows
        if not windows:
            return {}
        out = {f"{m}_{w}{i}": math.nan for w in windows for m in ("IAE", "ISE", "ITAE") for i in (1, 2)}
        if metrics is None or not sc.continuous:
            return out
        ctrl = self.loop.controller(dict(zip(self.names, np.asarray(x, dtype=np.float64).tolist())))
        idx = [_METRIC_INDEX[f"{m}{i}"] for m in ("IAE", "ISE", "ITAE") for i in (1, 2)]
        upto = {0.0: np.zeros(len(idx)), float(sc.horizon): np.asarray(metrics, dtype=np.float64)[idx]}
        for t in sorted({t for w in windows.values() for t in w if 0.0 < t < sc.horizon}):
            sim = self.loop.run(ctrl, sc.cut(t), settling_band=self.settling_band, record=False)
            upto[t] = np.full(len(idx), math.nan) if sim.diverged else sim.metrics[idx]
        for w, (t0, t1) in windows.items():
            iae1, iae2, ise1, ise2, itae1, itae2 = upto[t1] - upto[t0]
            for i, (iae, ise, itae) in enumerate(((iae1, ise1, itae1), (iae2, ise2, itae2)), start=1):
                out[f"IAE_{w}{i}"], out[f"ISE_{w}{i}"] = float(iae), float(ise)
                out[f"ITAE_{w}{i}"] = float(itae - t0 * iae)
        return out
