"""The QTP closed loop: scenario, controller design for one plant case, simulation, metrics.

This is the Python facade over the jitted kernels in :mod:`heurtune.objectives.qtp.kernels`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from heurtune.core.errors import ConfigError
from heurtune.core.problem import RANGE_RTOL
from heurtune.objectives.qtp import continuous as _continuous
from heurtune.objectives.qtp import continuous_kernels as _continuous_kernels
from heurtune.objectives.qtp import design_kernels as _design_kernels
from heurtune.objectives.qtp import kernels as _kernels
from heurtune.objectives.qtp import linearised as _linearised
from heurtune.objectives.qtp import structures as _structures
from heurtune.objectives.qtp.batch_design import discretise_many
from heurtune.objectives.qtp.bond_graph import BondGraphElements, pressure_coefficients
from heurtune.objectives.qtp.controllers import LinearController, PlantLinearisation
from heurtune.objectives.qtp.model import QTPParams, linearise, operating_point

# Step plans kept per loop (scenario, step); cleared when full.
_PLAN_CACHE_SIZE = 256
# The records of a run that keeps none (no rows: the kernels write nothing to them).
_NO_RECORD2, _NO_RECORD4 = np.empty((0, 2)), np.empty((0, 4))

__all__ = ["Scenario", "ClosedLoop", "SimulationResult", "METRIC_NAMES", "LIMITS", "PLANT_MODELS",
           "physical_range_flags"]

METRIC_NAMES = _kernels.METRIC_NAMES

# Allowed values of ClosedLoop's plant_model: the level model of heurtune.objectives.qtp.model, or the
# pressure (bond-graph) formulation of heurtune.objectives.qtp.bond_graph.
PLANT_MODELS = ("qtp", "qtp_bond_graph")

# Lanes per call of the batched CPU kernel: from 16 to 2,048 lanes its cost per lane and step
# was lowest at 128 to 256 (77 ns) and rose past that as the lanes' state left the cache.
CPU_TILE = 256

# The longest RK4 step of the plant in the sampled loop: a longer sample period (a slow digital
# controller, [controller] sample_time) steps the plant several times between samples.
MAX_PLANT_STEP = 0.05

# Allowed values of Scenario.limits: the thesis' unlimited model, or the plant's physical limits.
LIMITS = ("none", "physical")
# The continuous loop's integrators: "switching" (continuous.py: the controller's modes exact, the
# plant and the feedback explicit, saturation and limits followed as events) and "linearised"
# (linearised.py: the whole linearised loop exact, no saturation or limits).
INTEGRATORS = ("switching", "linearised")

# physical_range_flags uses the core's RANGE_RTOL: a clipped level or saturated voltage sits
# exactly on its limit and must not count as leaving the range.


def _pair(key, value):
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"scenario.{key} must be two numbers, got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ConfigError(f"scenario.{key} must be finite, got {value!r}")
    return (a, b)


@dataclasses.dataclass(frozen=True)
class Scenario:
    """What a closed-loop simulation exercises.

    Parameters
    ----------
    horizon : float
        Simulated time T in s (thesis: 350).
    dt : float or None
        Sample period in s of the sampled-data loop (a digital controller with zero-order hold,
        the plant stepped by RK4; ``horizon`` must be a whole number of samples). None
        (default): the continuous-time loop. ``dt = 0.01`` is the loop of heurtune before the
        continuous loop became the default, bit for bit.
    output_disturbance : (float, float)
        Additive step on the measured levels y1 = h1 + d1, y2 = h2 + d2 in cm (thesis: 1 cm).
    disturbance_time : float
        When the output disturbance starts, s (thesis: 50).
    input_disturbance : (float, float)
        Additive step on the pump voltages in V (off by default).
    input_disturbance_time : float
        When the input disturbance starts, s.
    setpoint_step : (float, float)
        Step of the set-points r1, r2 in cm from the operating levels (off by default; the
        continuous loop only). A structure that does not read the reference sees the error
        ``y - r`` (for it a set-point step of ``s`` equals a measured-level step of ``-s``); one
        that does (``reads_reference``) sees the measured deviations and the set-point
        deviations apart (docs/controllers_reference.md, "The reference path").
    setpoint_time : float
        When the set-point step happens, s.
    noise_sd : float
        Standard deviation in cm of white measurement noise on all four measured levels.
    noise_seed : int
        Seed of that noise.
    saturation : (float, float) or None
        Pump limits [u_min, u_max] in V with conditional-integration anti-windup; None = off.
    uncertainty : float
        Factor on every A_i and a_i of the plant (1.0 nominal; thesis robustness 0.7 and 1.3).
    limits : {"none", "physical"}
        ``"none"`` (default): the thesis' model, with no bound on levels or voltages.
        ``"physical"``: the pumps saturate at the plant's ``u_range`` (with the anti-windup of
        ``saturation``) and every level stays in [0, H_i], the water above a rim being lost;
        needs a plant with ``height`` and ``u_range``. Excludes ``saturation``.
    tolerance : float or None
        Largest level error in cm of the continuous-time loop
        (:mod:`heurtune.objectives.qtp.continuous`): set, the loop is simulated in continuous
        time by exponential integration with the step that the rule
        :func:`~heurtune.objectives.qtp.continuous.step_for_tolerance` gives for it. Left at
        None with ``dt`` and ``step`` also None, it is
        :data:`~heurtune.objectives.qtp.continuous.DEFAULT_TOLERANCE` (0.005 cm): the
        continuous loop is the default.
    step : float or None
        An explicit step in s of the continuous-time loop (overrides the rule of
        ``tolerance``; either key selects the continuous loop).
    output_dt : float
        Spacing in s of the recorded trajectory of the continuous loop (its dense output);
        the sampled loop records every ``dt``.
    integrator : {"switching", "linearised"}
        The continuous loop's method. ``"switching"`` (default): exponential integration of
        the controller's modes with the plant explicit, saturation and limits followed
        (:mod:`heurtune.objectives.qtp.continuous`). ``"linearised"``: the whole loop's
        linearisation integrated exactly, only the outflows' curvature explicit, adaptive
        steps; metrics exact to about 1e-5 where the switching loop's can be 1e-3 off on weakly
        damped loops, but no saturation or limits (:mod:`heurtune.objectives.qtp.linearised`).
    """

    horizon: float = 350.0
    dt: float | None = None
    output_disturbance: tuple = (1.0, 1.0)
    disturbance_time: float = 50.0
    input_disturbance: tuple = (0.0, 0.0)
    input_disturbance_time: float = 0.0
    setpoint_step: tuple = (0.0, 0.0)
    setpoint_time: float = 0.0
    noise_sd: float = 0.0
    noise_seed: int = 0
    saturation: tuple | None = None
    uncertainty: float = 1.0
    limits: str = "none"
    tolerance: float | None = None
    step: float | None = None
    output_dt: float = 0.01
    integrator: str = "switching"

    def __post_init__(self):
        if self.dt is not None:
            for key in ("tolerance", "step"):
                if getattr(self, key) is not None:
                    raise ConfigError(f"scenario.dt (the sampled loop's sample period) and scenario.{key} (the "
                                      f"continuous loop's) both set; give one")
        elif self.tolerance is None and self.step is None:
            object.__setattr__(self, "tolerance", _continuous.DEFAULT_TOLERANCE)
        for key in ("horizon", "dt", "disturbance_time", "input_disturbance_time", "setpoint_time", "noise_sd",
                    "uncertainty"):
            v = getattr(self, key)
            if v is None and key == "dt":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"scenario.{key} must be a finite number, got {v!r}")
        if self.horizon <= 0:
            raise ConfigError(f"scenario.horizon must be positive, got {self.horizon}")
        for key in ("disturbance_time", "input_disturbance_time", "setpoint_time"):
            t = getattr(self, key)
            if not 0 <= t <= self.horizon:
                raise ConfigError(f"scenario.{key} must lie in [0, horizon], got {t}")
        if self.dt is not None:
            self._check_sampled()
        if self.noise_sd < 0:
            raise ConfigError(f"scenario.noise_sd must be >= 0, got {self.noise_sd}")
        if self.uncertainty <= 0:
            raise ConfigError(f"scenario.uncertainty must be positive, got {self.uncertainty}")
        if isinstance(self.noise_seed, bool) or not isinstance(self.noise_seed, int) or self.noise_seed < 0:
            raise ConfigError(f"scenario.noise_seed must be a non-negative integer, got {self.noise_seed!r}")
        object.__setattr__(self, "output_disturbance", _pair("output_disturbance", self.output_disturbance))
        object.__setattr__(self, "input_disturbance", _pair("input_disturbance", self.input_disturbance))
        object.__setattr__(self, "setpoint_step", _pair("setpoint_step", self.setpoint_step))
        if self.dt is not None and self.has_setpoint_step:
            raise ConfigError("scenario.setpoint_step needs the continuous-time loop: leave scenario.dt and "
                              "controller.sample_time unset, or set setpoint_step = [0, 0]")
        if self.saturation is not None:
            lo, hi = _pair("saturation", self.saturation)
            if not lo < hi:
                raise ConfigError(f"scenario.saturation needs u_min < u_max, got {self.saturation!r}")
            object.__setattr__(self, "saturation", (lo, hi))
        if not isinstance(self.limits, str) or self.limits not in LIMITS:
            raise ConfigError(f"scenario.limits must be one of {', '.join(map(repr, LIMITS))}, got {self.limits!r}")
        if self.limits == "physical" and self.saturation is not None:
            raise ConfigError("scenario.saturation and scenario.limits = 'physical' both set pump limits; give one")
        self._check_continuous()
        self._check_integrator()

    def _check_integrator(self):
        """``integrator`` one of :data:`INTEGRATORS`; the linearised one only on a continuous
        scenario without saturation or limits."""
        if not isinstance(self.integrator, str) or self.integrator not in INTEGRATORS:
            raise ConfigError(f"scenario.integrator must be one of {', '.join(map(repr, INTEGRATORS))}, "
                              f"got {self.integrator!r}")
        if self.integrator != "linearised":
            return
        if not self.continuous:
            raise ConfigError("scenario.integrator = 'linearised' is a method of the continuous-time loop; leave "
                              "scenario.dt and controller.sample_time unset, or use integrator = 'switching'")
        if self.saturation is not None or self.limits != "none":
            key = "saturation" if self.saturation is not None else "limits"
            raise ConfigError(f"scenario.integrator = 'linearised' cannot follow pump saturation or level limits "
                              f"(scenario.{key} is set); use integrator = 'switching' (the default) with them")

    def _check_sampled(self):
        """The sample period of the sampled loop: positive, no longer than the horizon, and a
        divisor of the horizon and of both disturbance times."""
        if self.dt <= 0:
            raise ConfigError(f"scenario.dt (the sample period in s) must be > 0, got {self.dt}")
        if self.dt > self.horizon:
            raise ConfigError(f"scenario.dt ({self.dt}) must not exceed scenario.horizon ({self.horizon})")
        if abs(self.n_steps * self.dt - self.horizon) > 1e-9 * self.horizon:
            raise ConfigError(f"scenario.horizon ({self.horizon}) must be a whole number of steps dt ({self.dt})")
        for key in ("disturbance_time", "input_disturbance_time"):
            t = getattr(self, key)
            if abs(round(t / self.dt) * self.dt - t) > 1e-9 * max(1.0, t):
                raise ConfigError(f"scenario.{key} ({t}) must be a multiple of dt ({self.dt})")

    def _check_continuous(self):
        """The keys of the continuous-time loop: positive and finite, a step budget, and what
        the continuous loop does not simulate (measurement noise) refused by name."""
        for key, what in (("tolerance", "the largest level error in cm"), ("step", "the step in s"),
                          ("output_dt", "the spacing of the recorded trajectory in s")):
            v = getattr(self, key)
            if v is None and key != "output_dt":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"scenario.{key} ({what}) must be a finite number > 0, got {v!r}")
        if not self.continuous:
            return
        if self.tolerance is not None and self.step is not None:
            raise ConfigError("scenario.tolerance and scenario.step both set the continuous loop's step; give one")
        if self.tolerance is not None and _continuous.step_for_tolerance(self.tolerance, None) <= _continuous.MIN_STEP:
            ratio = _continuous.MIN_STEP / _continuous.DEFAULT_STEP_AT_REFERENCE
            floor = _continuous.REFERENCE_TOLERANCE * ratio ** 4
            raise ConfigError(f"scenario.tolerance = {self.tolerance!r} is below what the loop can meet (its smallest "
                              f"step, {_continuous.MIN_STEP:g} s, reaches about {floor:.1g} cm); give a tolerance "
                              f"above that")
        for key in ("step", "output_dt"):
            v = getattr(self, key)
            if v is not None and v > self.horizon:
                raise ConfigError(f"scenario.{key} must not exceed scenario.horizon ({self.horizon}), got {v!r}")
        if abs(round(self.horizon / self.output_dt) * self.output_dt - self.horizon) > 1e-9 * self.horizon:
            raise ConfigError(f"scenario.horizon ({self.horizon}) must be a whole number of scenario.output_dt "
                              f"({self.output_dt})")
        steps = self.horizon / self.continuous_step
        if steps > _continuous.MAX_STEPS:
            key = "tolerance" if self.tolerance is not None else "step"
            raise ConfigError(
                f"scenario.{key} = {getattr(self, key)!r} needs a step of {self.continuous_step:.3g} s, "
                f"{steps:,.0f} steps over scenario.horizon = {self.horizon:g} s, more than the budget of "
                f"{_continuous.MAX_STEPS:,}; raise scenario.{key} or shorten scenario.horizon")
        if self.noise_sd > 0:
            raise ConfigError("scenario.noise_sd > 0 needs a digital controller: measurement noise is drawn "
                              "per sample; give controller.sample_time (e.g. 0.01 s, the sampled loop), or set "
                              "noise_sd = 0")

    @property
    def has_setpoint_step(self) -> bool:
        """Whether the set-points step (a non-zero ``setpoint_step``)."""
        return self.setpoint_step[0] != 0.0 or self.setpoint_step[1] != 0.0

    @property
    def windows(self) -> dict:
        """``{"servo": (t0, t1), "regulatory": (t1, horizon)}`` for a scenario with a set-point
        step followed by a measured-level or input step (``{"servo": (t0, horizon)}`` without
        one; ``{}`` without a set-point step): the windows whose integrals
        :meth:`~heurtune.objectives.qtp.problem.QTPProblem.report` gives apart."""
        if not self.has_setpoint_step:
            return {}
        later = [t for t, step in ((self.disturbance_time, self.output_disturbance),
                                   (self.input_disturbance_time, self.input_disturbance))
                 if (step[0] != 0.0 or step[1] != 0.0) and self.setpoint_time < t < self.horizon]
        if not later:
            return {"servo": (float(self.setpoint_time), float(self.horizon))}
        t1 = float(min(later))
        return {"servo": (float(self.setpoint_time), t1), "regulatory": (t1, float(self.horizon))}

    def cut(self, horizon: float) -> Scenario:
        """The scenario up to ``horizon`` (steps after it dropped): the same trajectory up
        to there, on the same step plan (its segments end at the same breakpoints)."""
        changes = dict(horizon=float(horizon))
        for step_key, time_key in (("output_disturbance", "disturbance_time"),
                                   ("input_disturbance", "input_disturbance_time"),
                                   ("setpoint_step", "setpoint_time")):
            if getattr(self, time_key) >= horizon:
                changes[step_key], changes[time_key] = (0.0, 0.0), 0.0
        return dataclasses.replace(self, **changes)

    @property
    def event_time(self) -> float:
        """The time from which overshoot and settling are measured
        (:func:`~heurtune.objectives.qtp.continuous.first_event_time`)."""
        return _continuous.first_event_time(self.output_disturbance, self.disturbance_time, self.setpoint_step,
                                            self.setpoint_time)

    @property
    def continuous(self) -> bool:
        """Whether this scenario simulates the continuous-time loop (no sample period ``dt``)."""
        return self.dt is None

    def continuous_step_for(self, kind: str | None = None) -> float:
        """The largest step of the continuous loop under a controller of type ``kind``:
        ``step``, else the rule's step for ``tolerance`` (:func:`continuous.step_for_tolerance`)."""
        if self.step is not None:
            return float(self.step)
        return _continuous.step_for_tolerance(float(self.tolerance), kind)

    @property
    def continuous_step(self) -> float:
        """:meth:`continuous_step_for` the controller type with the smallest step."""
        return self.continuous_step_for(None)

    def step_plan(self, kind: str | None = None, step: float | None = None, top: int = 0):
        """The segments and steps of the continuous loop (:func:`continuous.plan_steps`), with
        steps of at most ``step`` when given, else :meth:`continuous_step_for` ``kind``.

        ``top`` > 1 (a ``tolerance`` scenario only) lets adaptive pairs of steps go up to
        ``2^(top - 1)`` times that step (:func:`continuous.adaptive_top`)."""
        h = self.continuous_step_for(kind) if step is None else float(step)
        adaptive = {}
        if top > 1 and self.step is None:
            adaptive = dict(local_tol=_continuous.ADAPTIVE_LOCAL_FRACTION * float(self.tolerance), top=int(top),
                            local_rel=_continuous.ADAPTIVE_RELATIVE, local_per=_continuous.ADAPTIVE_PERIOD)
        return _continuous.plan_steps(self.horizon, h, self.output_disturbance, self.disturbance_time,
                                      self.input_disturbance, self.input_disturbance_time, **adaptive,
                                      setpoint_step=self.setpoint_step, setpoint_time=self.setpoint_time)

    @property
    def kernel_step(self) -> float:
        """Simulated seconds per step of the kernel: the sample period ``dt`` of the sampled
        loop, the (largest) step of the continuous one. The runner's calibration cuts a
        scenario to a number of these (:func:`heurtune.runner.workplan.calibrate`)."""
        return float(self.dt) if self.dt is not None else self.continuous_step

    @property
    def n_steps(self) -> int:
        return int(round(self.horizon / self.dt))

    @property
    def plant_substeps(self) -> int:
        """RK4 steps of the plant per sample of the sampled loop (``dt`` over MAX_PLANT_STEP)."""
        return max(1, math.ceil(self.dt / MAX_PLANT_STEP - 1e-9))

    @property
    def disturbance_index(self) -> int:
        return int(round(self.disturbance_time / self.dt))

    @property
    def input_disturbance_index(self) -> int:
        return int(round(self.input_disturbance_time / self.dt))

    def noise(self) -> np.ndarray:
        """Measurement noise (n_steps + 1, 4) drawn from ``noise_seed``, or an empty (0, 4)."""
        if self.noise_sd == 0:
            return np.zeros((0, 4))
        rng = np.random.default_rng(self.noise_seed)
        return rng.normal(0.0, self.noise_sd, size=(self.n_steps + 1, 4))


@dataclasses.dataclass
class SimulationResult:
    """A closed-loop run: ``metrics`` (in the order of METRIC_NAMES; NaN when diverged), the
    ``diverged`` flag, the operating point used and, when recorded, the sampled response ``y``
    (n+1, 2) measured levels, ``u`` (n+1, 2) voltages and ``h`` (n+1, 4) true levels (cm, for
    either plant model). ``P`` (n+1, 4) holds the tank pressures in dyn/cm^2 when the plant
    model is ``"qtp_bond_graph"`` and the levels were recorded; None otherwise. ``steps`` is
    the number of steps the kernel kept (continuous loop) or its samples (sampled loop)."""

    t: np.ndarray | None
    y: np.ndarray | None
    u: np.ndarray | None
    h: np.ndarray | None
    diverged: bool
    h_op: np.ndarray
    u_op: np.ndarray
    metrics: np.ndarray
    P: np.ndarray | None = None
    steps: int | None = None

    def to_frame(self) -> pd.DataFrame:
        """Columns t, h1..h4 (if recorded), P1..P4 (bond-graph model), y1, y2, u1, u2."""
        if self.y is None:
            raise ValueError("this run was not recorded (run(..., record=True))")
        cols = {"t": self.t}
        if self.h is not None:
            for i in range(4):
                cols[f"h{i + 1}"] = self.h[:, i]
        if self.P is not None:
            for i in range(4):
                cols[f"P{i + 1}"] = self.P[:, i]
        cols.update(y1=self.y[:, 0], y2=self.y[:, 1], u1=self.u[:, 0], u2=self.u[:, 1])
        return pd.DataFrame(cols)


class ClosedLoop:
    """One plant case under one controller type: design, stability check, simulation, metrics.

    Parameters
    ----------
    plant : QTPParams
        The nominal plant; controllers are designed on its linearisation.
    kind : str
        A registered controller structure (:func:`heurtune.objectives.qtp.structures.names`:
        folqi, fopid, iolqi, ladr, lqi, pid and plugins').
    pairing : {"diagonal", "anti-diagonal"}
        Which error each pump integrates (see :func:`~heurtune.objectives.qtp.structures.build_controller`).
    **options
        The structure's options (FOLQI: ``oustaloup_order``, ``band``, ``realisation``; PID:
        ``derivative_filter``, ``decoupler``), each at the structure's default when left out;
        kept in :attr:`options` with ``pairing`` last (the problem id reads them).
    plant_model : {"qtp", "qtp_bond_graph"}
        The simulated plant: ``"qtp"`` integrates the four levels (cm); ``"qtp_bond_graph"``
        integrates the four tank pressures P = rho g h (dyn/cm^2, water, see
        :mod:`heurtune.objectives.qtp.bond_graph`) and its sensors read the levels P / (rho g).
        The controller is designed on the level linearisation in both cases, so the two loops
        agree up to rounding. Kept as :attr:`plant_model`, not in :attr:`options`.

    Raises
    ------
    ConfigError
        For an unknown ``plant_model``.
    """

    def __init__(self, plant: QTPParams, kind: str, *, pairing: str = "diagonal", plant_model: str = "qtp",
                 **options):
        if not isinstance(plant_model, str) or plant_model not in PLANT_MODELS:
            raise ConfigError(f"plant.model must be one of {', '.join(map(repr, PLANT_MODELS))}, "
                              f"got {plant_model!r}")
        self.plant = plant
        self.kind = kind
        _structures.structure(kind)  # a one-line error for an unknown type, here
        self.plant_model = plant_model
        self.options = _structures.loop_options(kind, dict(options, pairing=pairing))
        self.op = operating_point(plant)
        self.A, self.B, self.C = linearise(plant, self.op)
        # Plant state per level: the pressure model's state is rho g h (rho and g do not change
        # with the uncertainty factor, which scales areas only).
        if plant_model == "qtp_bond_graph":
            self._rho_g = BondGraphElements.from_plant(plant).rho_g
            self._level_per_state = 1.0 / self._rho_g
        else:
            self._rho_g = 1.0
            self._level_per_state = 1.0
        self._plants = {}
        self._scenarios = {}
        self._tables = {}
        self._plans = {}
        self._feedback = {}
        self._limits = None

    def __getstate__(self):
        # Caches are rebuilt on demand.
        state = self.__dict__.copy()
        state["_plants"] = {}
        state["_scenarios"] = {}
        state["_plans"] = {}
        state["_feedback"] = {}
        state["_limits"] = None
        return state

    def __setstate__(self, state):
        state.setdefault("_limits", None)
        state.setdefault("_plans", {})
        state.setdefault("_feedback", {})
        # Pickles from before the bond-graph model are level models.
        state.setdefault("plant_model", "qtp")
        state.setdefault("_rho_g", 1.0)
        state.setdefault("_level_per_state", 1.0)
        self.__dict__.update(state)

    # -- design ---------------------------------------------------------------------------
    @property
    def structure(self):
        """The registered controller structure of :attr:`kind` (looked up, not pickled: a
        worker finds it in its own registry, plugins loaded first)."""
        return _structures.structure(self.kind)

    @property
    def plant_linearisation(self) -> PlantLinearisation:
        """The nominal linearisation ``(A, B, C)`` the structure designs on."""
        return PlantLinearisation(self.A, self.B, self.C)

    def controller(self, values: dict) -> LinearController:
        """Design the controller for named tuning ``values`` (raises ControllerDesignError)."""
        return self.structure.design(values, self.plant_linearisation, self.options)

    def step_plan(self, ctrl: LinearController, scenario: Scenario, cc=None):
        """The continuous loop's step plan of ``ctrl`` under ``scenario``: the scenario's
        (:meth:`Scenario.step_plan` of this type) unless the scenario gives ``step`` and

        - a structure that declares ``explicit_step`` gets the step its static feedback allows
          (:func:`~heurtune.objectives.qtp.continuous.explicit_step`);
        - one that declares ``feedback_step`` gets its step halved while the plant under its
          effective static feedback is too fast for it
          (:func:`~heurtune.objectives.qtp.continuous.feedback_step`, on the scenario's plant),
          and adaptive pairs of longer steps as far as that plant stays stable under them
          (:func:`~heurtune.objectives.qtp.continuous.adaptive_top`; docs/model.md, "Adaptive
          steps").

        ``cc``: the controller's :class:`~heurtune.objectives.qtp.continuous.ContinuousController`
        when the caller has it."""
        extras = self.structure.extras
        if scenario.step is None and extras.get("explicit_step"):
            h = min(scenario.continuous_step_for(self.kind),
                    _continuous.explicit_step(self.A, self.B, ctrl.D, float(scenario.tolerance)))
            return scenario.step_plan(self.kind, step=h)
        h = None  # the scenario's step for this type
        top = 0
        if scenario.step is None and extras.get("feedback_step"):
            A, B, h_max, radius = self._feedback_inputs(scenario)
            if cc is None:
                cc = _continuous.ContinuousController.from_linear(ctrl)
            h, top = _continuous.feedback_rule(A, B, cc, h_max, radius)
            if h >= h_max:
                h = None
        return self._cached_plan(scenario, h, top)

    def _cached_plan(self, scenario: Scenario, h=None, top: int = 0):
        """``scenario.step_plan(kind, step=h, top=top)``, kept: plans are read-only for the
        kernels, and a scenario has one per step of the ladder h_max 2^-k and adaptive range."""
        key = (scenario, h, top)
        plan = self._plans.get(key)
        if plan is None:
            if len(self._plans) >= _PLAN_CACHE_SIZE:
                self._plans.clear()
            plan = self._plans[key] = scenario.step_plan(self.kind, step=h, top=top)
        return plan

    def _feedback_inputs(self, scenario: Scenario) -> tuple:
        """The scenario's part of the step rule of a ``feedback_step`` structure
        (:func:`~heurtune.objectives.qtp.continuous.feedback_rule`), the same for every
        candidate: the linearised plant ``A`` and the scenario's input matrix (the nominal one
        divided by its uncertainty factor, which scales the tank areas), both C-contiguous; the
        structure's step for the scenario's tolerance and the radius of that tolerance. Built
        once per scenario."""
        inputs = self._feedback.get(scenario)
        if inputs is None:
            inputs = self._feedback[scenario] = (
                np.ascontiguousarray(self.A, dtype=np.float64),
                np.ascontiguousarray(self.B / scenario.uncertainty, dtype=np.float64),
                float(scenario.continuous_step_for(self.kind)), _continuous.feedback_radius(float(scenario.tolerance)))
        return inputs

    def stability_margin(self, ctrl: LinearController) -> float:
        """Largest real part of the linearised closed-loop eigenvalues (negative = stable)."""
        # one compiled call: the loop's matrix (of the minimal realisation) and LAPACK dgeev
        return float(_design_kernels.loop_margin(self.A, self.B, *ctrl.minimal_realisation()))

    # -- simulation -----------------------------------------------------------------------
    def _scenario_arrays(self, scenario: Scenario):
        """Kernel arrays of a scenario, drawn once (the noise is seeded, hence the same)."""
        if scenario not in self._scenarios:
            self._scenarios[scenario] = (np.asarray(scenario.output_disturbance, dtype=np.float64),
                                         np.asarray(scenario.input_disturbance, dtype=np.float64),
                                         scenario.noise())
        return self._scenarios[scenario]

    def _perturbed(self, factor: float):
        if factor not in self._plants:
            p = self.plant if factor == 1.0 else self.plant.scaled(factor)
            if self.plant_model == "qtp_bond_graph":
                coef = pressure_coefficients(BondGraphElements.from_plant(p))
            else:
                coef = _kernels.plant_coefficients(p.as_array())
            self._plants[factor] = (coef, operating_point(p).u)
        return self._plants[factor]

    def check_scenario(self, scenario: Scenario) -> None:
        """Raise ConfigError now if ``scenario`` cannot run on this plant (``limits =
        "physical"`` on a plant without limits, or whose operating point they exclude), so
        that a bad config fails when it is loaded, not in every evaluation."""
        if scenario.limits == "physical":
            self._physical_limits(self._perturbed(scenario.uncertainty)[1])

    def _physical_limits(self, u_op: np.ndarray):
        """Tank heights (4,) and pump range of the nominal plant, checked against the operating
        point (raises ConfigError when the plant has no limits or cannot hold that point)."""
        if self._limits is None:
            self._limits = self.plant.physical_limits()
        height, (lo, hi) = self._limits
        if np.any(self.op.h > height):
            raise ConfigError(
                f"plant '{self.plant.name}': operating levels {np.round(self.op.h, 4).tolist()} exceed the "
                f"tank heights {list(self.plant.height)}; scenario.limits = 'physical' cannot hold them"
            )
        if np.any(u_op < lo) or np.any(u_op > hi):
            raise ConfigError(
                f"plant '{self.plant.name}': operating voltages {np.round(u_op, 4).tolist()} lie outside "
                f"u_range {self.plant.u_range}; scenario.limits = 'physical' cannot hold them"
            )
        return height, lo, hi

    def run(self, ctrl: LinearController, scenario: Scenario, *, settling_band: float = 3.0,
            record: bool = True, record_levels: bool | None = None, discrete=None) -> SimulationResult:
        """Simulate the nonlinear loop and its metrics (kernel :func:`simulate_loop`).

        Parameters
        ----------
        ctrl : LinearController
        scenario : Scenario
            With ``limits = "physical"`` the pumps saturate at the nominal plant's ``u_range``
            and the levels stay within [0, height] (uncertainty scales areas, not heights).
        settling_band : float
            Band of the settling time, percent of the operating level.
        record : bool
            Keep the sampled y and u; ``False`` keeps only the metrics (what a tuning
            evaluation needs).
        record_levels : bool, optional
            Keep the true levels h1..h4 as well (and, for the bond-graph model, the pressures
            P1..P4); default: as ``record``.
        discrete : optional
            ``ctrl.discretise(scenario.dt)`` when the caller has it already (several scenarios
            of one controller).

        Returns
        -------
        SimulationResult
            ``h`` holds levels in cm for both plant models; ``P`` the pressures of the
            bond-graph model.

        Raises
        ------
        ConfigError
            ``limits = "physical"`` on a plant without height and u_range, or whose operating
            point lies outside them.
        """
        if record_levels is None:
            record_levels = record
        if scenario.continuous:
            return self._run_continuous(ctrl, scenario, settling_band, record, record_levels)
        table = self._scenario_table(scenario)
        u_op = table[_kernels.P_UOP:_kernels.P_UOP + 2]
        n = scenario.n_steps
        rows = n + 1 if record else 0
        y, u = np.empty((rows, 2)), np.empty((rows, 2))
        h = np.empty((n + 1 if record_levels else 0, 4))
        metrics = np.empty(_kernels.N_METRICS)
        dc = ctrl.discretise(scenario.dt) if discrete is None else discrete
        noise = self._scenario_arrays(scenario)[2]
        pressure = self.plant_model == "qtp_bond_graph"
        x_op = self._state_op()  # initial plant state
        # substeps only when needed: the call without them is the kernel specialised to one step
        extra = (scenario.plant_substeps,) if scenario.plant_substeps > 1 else ()
        status, _ = _kernels.simulate_loop(
            table, self._level_per_state, x_op, self.op.h, dc.ad, dc.bd, dc.state_input, dc.Ad, dc.Bd, dc.Cc, dc.Dc,
            dc.state_channel, dc.segments, scenario.dt, n, noise, float(settling_band), metrics, y, u, h, *extra,
        )
        t = np.arange(n + 1) * scenario.dt if record or record_levels else None
        P = None
        if record_levels and pressure:
            P, h = h, h * self._level_per_state  # the kernel records its state, the pressures
        return SimulationResult(t, y if record else None, u if record else None,
                                h if record_levels else None, status != _kernels.STATUS_OK,
                                self.op.h.copy(), u_op.copy(), metrics, P, n)

    def _run_continuous(self, ctrl, scenario: Scenario, settling_band: float, record: bool,
                        record_levels: bool) -> SimulationResult:
        """:meth:`run` of a continuous-time scenario (kernel ``simulate_continuous``, or the
        linearised integrator's lane)."""
        table = self._scenario_table(scenario)
        u_op = table[_kernels.P_UOP:_kernels.P_UOP + 2]
        n_out = int(round(scenario.horizon / scenario.output_dt))
        t = None
        if record or record_levels:
            t = np.arange(n_out + 1) * scenario.output_dt
            t[-1] = min(t[-1], scenario.horizon)
        rows = n_out + 1 if (record or record_levels) else 0
        y, u, h = np.empty((rows, 2)), np.empty((rows, 2)), np.empty((rows, 4))
        metrics = np.empty(_kernels.N_METRICS)
        pressure = self.plant_model == "qtp_bond_graph"
        run = self._run_linearised(ctrl, scenario, settling_band, metrics, y, u, h)
        if run is None:
            cc = _continuous.ContinuousController.from_linear(ctrl)
            plan = self.step_plan(ctrl, scenario, cc)
            status, steps = _continuous_kernels.simulate_continuous(
                table, self._level_per_state, self._state_op(), self.op.h, cc.lam, cc.b, cc.col,
                cc.Cm, cc.Aq, cc.Bq, cc.Cq, cc.D, cc.channel, plan.table, float(settling_band), metrics,
                float(scenario.output_dt), y, u, h)
        else:
            status, steps = run
        P = None
        if record_levels and pressure:
            P, h = h, h * self._level_per_state
        return SimulationResult(t, y if record else None, u if record else None, h if record_levels else None,
                                status != _kernels.STATUS_OK, self.op.h.copy(), u_op.copy(), metrics, P, steps)

    def _continuous_metrics(self, ctrl, scenario: Scenario, settling_band: float) -> tuple:
        """``(diverged, metrics)`` of :meth:`_run_continuous` without records: the same kernel
        call on the same inputs, without the result object a tuning evaluation does not read."""
        if scenario.integrator == "linearised":
            metrics = np.empty(_kernels.N_METRICS)
            run = self._run_linearised(ctrl, scenario, settling_band, metrics, _NO_RECORD2, _NO_RECORD2, _NO_RECORD4)
            if run is not None:
                return run[0] != _kernels.STATUS_OK, metrics
        cc = _continuous.ContinuousController.from_linear(ctrl)
        plan = self.step_plan(ctrl, scenario, cc)
        metrics = np.empty(_kernels.N_METRICS)
        status, _ = _continuous_kernels.simulate_continuous(
            self._scenario_table(scenario), self._level_per_state, self._state_op(), self.op.h, cc.lam, cc.b, cc.col,
            cc.Cm, cc.Aq, cc.Bq, cc.Cq, cc.D, cc.channel, plan.table, float(settling_band), metrics,
            float(scenario.output_dt), _NO_RECORD2, _NO_RECORD2, _NO_RECORD4)
        return status != _kernels.STATUS_OK, metrics

    def _run_linearised(self, ctrl, scenario: Scenario, settling_band: float, metrics, y, u, h):
        """One run of the linearised integrator (``scenario.integrator = "linearised"``) into
        ``metrics`` and the records ``y``, ``u``, ``h`` (0 rows: none): ``(status, steps)``, or
        None where the scenario uses the switching integrator or the candidate's loop has an
        ill-conditioned modal basis (said once per process; the caller runs the switching
        kernel)."""
        if scenario.integrator != "linearised":
            return None
        table = self._scenario_table(scenario)
        x_op = self._state_op()
        key = table[_kernels.P_COEF:_kernels.P_UOP + 2].tobytes()
        forms = ctrl.__dict__.setdefault("_linearised_forms", {})
        form = forms.get(key)
        if form is None:
            form = forms[key] = _linearised.linearised_form(ctrl, table, x_op, self._level_per_state)
        if not form.ok:
            _linearised.warn_fallback()
            return None
        plan = self._cached_plan(scenario)  # its segments; the lane chooses its own steps
        return _linearised.simulate(form, table, self._level_per_state, x_op, self.op.h, plan, settling_band,
                                    _linearised.step_rule(scenario), metrics, float(scenario.output_dt), y, u, h)

    def _scenario_table(self, scenario: Scenario) -> np.ndarray:
        """The scenario's parameter table of the loop kernels (:func:`scenario_table`): plant
        coefficients, operating voltages, pump limits, level clipping and the heights it clips
        at, disturbances, their sample indices (-1 for a continuous scenario), the output
        disturbance time and the horizon. Built once per scenario; the kernels only read it."""
        if scenario in self._tables:
            return self._tables[scenario]
        coef, u_op, (saturate, u_lo, u_hi), clip, h_max = self._kernel_inputs(scenario)
        out_dist, in_dist, _ = self._scenario_arrays(scenario)
        sampled = not scenario.continuous
        P = _kernels.scenario_table(
            coef, u_op, saturate, u_lo, u_hi, clip, h_max, out_dist, scenario.disturbance_index if sampled else -1,
            in_dist, scenario.input_disturbance_index if sampled else -1, scenario.event_time, scenario.horizon)
        self._tables[scenario] = P
        return P

    def _state_op(self) -> np.ndarray:
        """The operating point in the kernels' state: levels, or pressures for the bond graph."""
        return self.op.h * self._rho_g if self.plant_model == "qtp_bond_graph" else self.op.h

    def _kernel_inputs(self, scenario: Scenario):
        """The scenario-dependent kernel inputs of :meth:`run`: plant coefficients, operating
        voltages, saturation (on, low, high), level clipping and the heights it clips at."""
        coef, u_op = self._perturbed(scenario.uncertainty)
        sat = scenario.saturation
        clip = scenario.limits == "physical"
        if clip:
            h_max, u_lo, u_hi = self._physical_limits(u_op)
            sat = (u_lo, u_hi)
            if self.plant_model == "qtp_bond_graph":
                h_max = h_max * self._rho_g  # tank heights as pressures
        else:
            h_max = self.op.h  # not read by the kernel
        return coef, u_op, (sat is not None, sat[0] if sat else 0.0, sat[1] if sat else 0.0), clip, h_max

    def run_scenarios(self, ctrl: LinearController, scenarios, *, settling_band: float = 3.0) -> list:
        """Metrics of one controller under several scenarios. The controller is discretised once
        per time step, and the scenarios that share the step, the horizon and the form of their
        noise run in one kernel call (:func:`simulate_scenarios`); a scenario alone in its group
        runs by :meth:`run`. Returns ``[(diverged, metrics), ...]`` in the order of
        ``scenarios``, each equal to what :meth:`run` gives with ``record=False``."""
        scenarios = list(scenarios)
        groups = {}
        discrete, out = {}, [None] * len(scenarios)
        for i, sc in enumerate(scenarios):
            if sc.continuous:
                out[i] = self._continuous_metrics(ctrl, sc, settling_band)
                continue
            groups.setdefault((sc.dt, sc.n_steps, self._scenario_arrays(sc)[2].shape), []).append(i)
        for (dt, n_steps, _), members in groups.items():
            if dt not in discrete:
                discrete[dt] = ctrl.discretise(dt)
            dc = discrete[dt]
            if len(members) == 1 or scenarios[members[0]].plant_substeps > 1:
                for i in members:
                    sim = self.run(ctrl, scenarios[i], settling_band=settling_band, record=False, discrete=dc)
                    out[i] = (sim.diverged, sim.metrics)
                continue
            group = [scenarios[i] for i in members]
            metrics = np.empty((len(group), _kernels.N_METRICS))
            status = np.empty(len(group), dtype=np.int64)
            _kernels.simulate_scenarios(
                np.stack([self._scenario_table(sc) for sc in group], axis=1), self._level_per_state, self._state_op(),
                self.op.h, dc.ad, dc.bd, dc.state_input, dc.Ad, dc.Bd, dc.Cc, dc.Dc, dc.state_channel, dc.segments,
                dt, n_steps, np.ascontiguousarray(np.stack([self._scenario_arrays(sc)[2] for sc in group])),
                float(settling_band), metrics, status)
            for k, i in enumerate(members):
                out[i] = (bool(status[k] != _kernels.STATUS_OK), metrics[k])
        return out

    def run_batch(self, ctrls, scenarios, *, settling_band: float = 3.0, device: str = "cpu-batch"):
        """Metrics of several controllers under several scenarios, as the lanes of one batched call.

        The controllers are discretised once per time step (:func:`discretise_many`); the
        pairs (controller, scenario) whose scenarios share the step and the horizon and whose
        discrete controllers share their structure run as the lanes of one call
        (:func:`heurtune.objectives.qtp.kernels.simulate_lanes` on the CPU, or
        :func:`heurtune.objectives.qtp.gpu.simulate_lanes` with ``device="gpu"``), whose
        per-lane loop is the one-candidate kernel's own
        (:func:`~heurtune.objectives.qtp.kernels.sampled_lane`). The pairs
        of continuous-time scenarios run as the lanes of
        :func:`~heurtune.objectives.qtp.continuous_kernels.simulate_continuous_lanes` (or
        :func:`heurtune.objectives.qtp.gpu.simulate_continuous_lanes`), whose per-lane step is
        the one-candidate kernel's own (:func:`~heurtune.objectives.qtp.continuous_kernels.continuous_lane`).

        Parameters
        ----------
        ctrls : sequence of LinearController
        scenarios : sequence of Scenario
        settling_band : float
        device : {"cpu-batch", "gpu"}

        Returns
        -------
        diverged : (n, S) bool ndarray
        metrics : (n, S, N_METRICS) ndarray
            Each pair's metrics equal :meth:`run`'s within the rounding of the batched design
            (see ``tests/objectives/qtp/test_batch_kernels.py`` for the bound).
        """
        ctrls, scenarios = list(ctrls), list(scenarios)
        n, S = len(ctrls), len(scenarios)
        diverged = np.zeros((n, S), dtype=bool)
        metrics = np.full((n, S, _kernels.N_METRICS), np.nan)
        if n == 0 or S == 0:
            return diverged, metrics
        steps, continuous = {}, []
        for s, sc in enumerate(scenarios):
            if sc.continuous and sc.integrator == "linearised":  # one candidate at a time, on the CPU
                for i, ctrl in enumerate(ctrls):
                    diverged[i, s], metrics[i, s] = self._continuous_metrics(ctrl, sc, settling_band)
            elif sc.continuous:
                continuous.append(s)
            elif sc.plant_substeps > 1:  # not batched (yet): one candidate at a time
                for i, ctrl in enumerate(ctrls):
                    sim = self.run(ctrl, sc, settling_band=settling_band, record=False)
                    diverged[i, s], metrics[i, s] = sim.diverged, sim.metrics
            else:
                steps.setdefault((sc.dt, sc.n_steps), []).append(s)
        if continuous:
            self._run_continuous_lanes(ctrls, scenarios, continuous, float(settling_band), device, diverged, metrics)
        for (dt, n_steps), members in steps.items():
            groups = {}
            for i, dc in enumerate(discretise_many(ctrls, dt)):
                groups.setdefault(_lane_shape(dc), []).append((i, dc))
            for lanes in groups.values():
                pairs = [(i, dc, s) for i, dc in lanes for s in members]
                # On the CPU in tiles whose state stays in cache (measured best near 128-256 lanes)
                tile = len(pairs) if device == "gpu" else CPU_TILE
                for start in range(0, len(pairs), tile):
                    part = pairs[start:start + tile]
                    status, values = self._simulate_lanes(part, {s: scenarios[s] for s in members}, dt, n_steps,
                                                          float(settling_band), device)
                    for (i, _, s), st, row in zip(part, status, values):
                        diverged[i, s] = st != _kernels.STATUS_OK
                        metrics[i, s] = row
        return diverged, metrics

    def _run_continuous_lanes(self, ctrls, scenarios, members, band, device, diverged, metrics):
        """The continuous-time scenarios ``members`` of :meth:`run_batch`: every (controller,
        scenario) pair is a lane of :func:`continuous_kernels.simulate_continuous_lanes` (or the
        CUDA kernel with ``device="gpu"``), lanes of one controller structure per call; fills
        ``diverged`` and ``metrics`` in place."""
        forms = [_continuous.ContinuousController.from_linear(c) for c in ctrls]
        extras = self.structure.extras
        if extras.get("explicit_step") or extras.get("feedback_step"):
            plans = {(i, s): self.step_plan(c, scenarios[s], forms[i]) for i, c in enumerate(ctrls) for s in members}
        else:
            shared = {s: scenarios[s].step_plan(self.kind) for s in members}
            plans = {(i, s): shared[s] for i in range(len(ctrls)) for s in members}
        tables = {s: self._scenario_table(scenarios[s]) for s in members}
        groups = {}
        for i, cc in enumerate(forms):
            groups.setdefault((cc.lam.size, cc.Aq.shape[0]), []).append(i)
        x_op = self._state_op()
        for members_i in groups.values():
            pairs = [(i, s) for i in members_i for s in members]
            lanes = _continuous.pack_lanes([forms[i] for i, _ in pairs], [plans[p] for p in pairs],
                                           [tables[s] for _, s in pairs])
            if device == "gpu":
                from heurtune.objectives.qtp import gpu

                status, values = gpu.simulate_continuous_lanes(lanes, self._level_per_state, x_op, self.op.h, band)
            else:
                status, values, _ = _continuous_kernels.simulate_continuous_lanes(
                    lanes, self._level_per_state, x_op, self.op.h, band)
            for (i, s), st, row in zip(pairs, status, values):
                diverged[i, s] = st != _kernels.STATUS_OK
                metrics[i, s] = row

    def _simulate_lanes(self, pairs, by_scenario, dt, n_steps, band, device):
        """Pack ``pairs`` of (candidate, discrete controller, scenario index) of one structure,
        step and horizon into arrays of one lane per row (``by_scenario``: index to Scenario) and run
        them on ``device``."""
        L = len(pairs)
        first = pairs[0][1]
        tables = {s: self._scenario_table(sc) for s, sc in by_scenario.items()}
        noises = {s: self._scenario_arrays(sc)[2] for s, sc in by_scenario.items()}
        noisy = [s for s in by_scenario if noises[s].shape[0] > 0]
        noise = np.stack([noises[s] for s in noisy]) if noisy else np.zeros((0, n_steps + 1, 4))
        noise_index = {s: k for k, s in enumerate(noisy)}
        P = np.stack([tables[s] for _, _, s in pairs])

        def lanes(name):  # a discrete controller's array, one lane per row
            return np.ascontiguousarray(np.stack([getattr(dc, name) for _, dc, _ in pairs]), dtype=np.float64)

        args = dict(
            P=P, level_per_state=self._level_per_state,
            h_init=self._state_op(), h_op=self.op.h,
            ad=lanes("ad"), bd=lanes("bd"), state_input=first.state_input, Ad=lanes("Ad"), Bd=lanes("Bd"),
            Cc=lanes("Cc"), Dc=lanes("Dc"), state_channel=first.state_channel, segments=first.segments,
            dt=float(dt), n_steps=int(n_steps), noise=noise,
            lane_noise=np.array([noise_index.get(s, -1) for _, _, s in pairs], dtype=np.int64), band_pct=band,
        )
        if device == "gpu":
            from heurtune.objectives.qtp import gpu

            return gpu.simulate_lanes(**args)
        metrics = np.empty((L, _kernels.N_METRICS))
        status = np.empty(L, dtype=np.int64)
        _kernels.simulate_lanes(**args, metrics=metrics, status=status)
        return status, metrics

    def metrics(self, sim: SimulationResult, scenario: Scenario, settling_band: float) -> np.ndarray:
        """Metrics recomputed from a recorded run (:func:`loop_metrics`; NaN when diverged).

        hmin and hmax need the recorded true levels ``sim.h``: NaN for a run without them.
        """
        out = np.full(_kernels.N_METRICS, np.nan)
        if sim.diverged:
            return out
        if scenario.continuous:  # the run's own sub-step metrics: the record is its dense output
            return sim.metrics.copy()
        _kernels.loop_metrics(sim.y, sim.u, sim.h_op[:2], sim.u_op, scenario.dt,
                              scenario.disturbance_index, settling_band, out, sim.h)
        return out

    def warm_up(self):
        """Compile (or load from cache) the kernels on a tiny problem."""
        sc = Scenario(horizon=0.02, dt=0.01, disturbance_time=0.0)
        A = np.zeros((1, 1))
        ctrl = LinearController(A, np.zeros((1, 4)), np.zeros((2, 1)), np.zeros((2, 4)), ((0, 1),), (0,))
        self.metrics(self.run(ctrl, sc), sc, 3.0)
        self.run(ctrl, sc, record=False)


def _lane_shape(dc) -> tuple:
    """What the lanes of one batched kernel call share: the discrete controller's shape, the
    inputs and pumps of its states and its ``segments``."""
    return (dc.ad.size, dc.Ad.shape[0], dc.state_input.tobytes(), dc.state_channel.tobytes(), dc.segments.tobytes())


def physical_range_flags(metrics, plant: QTPParams) -> list[str]:
    """Say where a run leaves the plant's physical range.

    Parameters
    ----------
    metrics : mapping or array_like
        The run's metrics: a mapping (dict, pandas Series) with any of ``hmin``, ``hmax``,
        ``umin``, ``umax``, or a vector in the order of :data:`METRIC_NAMES`.
    plant : QTPParams
        Its tank heights and pump voltage range are the limits.

    Returns
    -------
    list of str
        One flag per limit crossed, e.g. ``"levels below 0 cm (min -226.1)"`` or
        ``"u above 10 V (max 12.3)"``; empty when the run stays inside, when the plant has no
        limits, or for missing or NaN values (a diverged run, levels not recorded). A value on a
        limit (a clipped level, a saturated pump) is inside: the comparison allows a relative
        ``RANGE_RTOL``. ``hmax`` is the highest level of any tank, so it is compared with the
        tallest tank's height.
    """
    if not getattr(plant, "has_limits", False):
        return []
    if isinstance(metrics, (Mapping, pd.Series)):
        values = {k: metrics[k] for k in ("hmin", "hmax", "umin", "umax") if k in metrics}
    else:
        row = np.asarray(metrics, dtype=np.float64)
        if row.shape != (len(METRIC_NAMES),):
            raise ValueError(f"physical_range_flags: a metrics vector needs {len(METRIC_NAMES)} values, "
                             f"got shape {row.shape}")
        values = {k: row[METRIC_NAMES.index(k)] for k in ("hmin", "hmax", "umin", "umax")}
    h_top = max(plant.height)
    u_lo, u_hi = plant.u_range
    checks = (
        ("hmin", "levels below", 0.0, "cm", "min", -1.0, h_top),
        ("hmax", "levels above", h_top, "cm", "max", 1.0, h_top),
        ("umin", "u below", u_lo, "V", "min", -1.0, max(abs(u_lo), abs(u_hi))),
        ("umax", "u above", u_hi, "V", "max", 1.0, max(abs(u_lo), abs(u_hi))),
    )
    flags = []
    for key, what, limit, unit, stat, sign, scale in checks:
        v = values.get(key)
        if v is None or not math.isfinite(float(v)):
            continue
        if sign * (float(v) - limit) > RANGE_RTOL * max(scale, 1.0):
            flags.append(f"{what} {limit:g} {unit} ({stat} {float(v):.4g})")
    return flags
