"""Experiments and their tuning problems (thesis eq. 3.10-3.11).

>>> import heurtune
>>> exp = heurtune.load_experiment("cs_folqi_qtp")
>>> prob = exp.problem("min")
>>> prob.names[:3]
('Q11', 'Q22', 'Q33')
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pandas as pd

from heurtune.config import load_config
from heurtune.errors import ConfigError
from heurtune.objectives.controllers import (
    CONTROLLER_TYPES, PAIRED_TYPES, ControllerDesignError, dc_gain, decision_names, default_bounds,
    integral_action_obstruction,
)
from heurtune.objectives.loop import METRIC_NAMES, ClosedLoop, Scenario, physical_range_flags
from heurtune.objectives.qtp import QTPParams, linearise, preset

__all__ = ["DecisionVectors", "Experiment", "ExperimentBase", "Problem", "Evaluation", "load_experiment", "make_experiment",
           "FAILED_OBJECTIVE", "FAILED_VIOLATION", "IntegralActionWarning", "STABILITY_CONSTRAINT"]

# A candidate that cannot be simulated gets these (finite) values.
FAILED_OBJECTIVE = 1.0e10
FAILED_VIOLATION = 1.0e6
# Unstable candidates' violations grow with the largest closed-loop real part, up to this cap.
UNSTABLE_MARGIN_CAP = 1.0e3

DEFAULT_UNCERTAINTY = {"nominal": 1.0, "-30%": 0.7, "+30%": 1.3}
DEFAULT_CONSTRAINTS = {"Mp": 10.0, "ts": 70.0, "ess": 1.0}
_OBJECTIVES = {
    "effort": ("J1", "J2"),
    "effort_deviation": ("Jdev1", "Jdev2"),
    "iae": ("IAE1", "IAE2"),
    "ise": ("ISE1", "ISE2"),
    "itae": ("ITAE1", "ITAE2"),
}
_METRIC_INDEX = {name: i for i, name in enumerate(METRIC_NAMES)}
# Metrics a weighted objective may combine (each summed over both loops or pumps).
WEIGHTED_METRICS = ("J", "Jdev", "IAE", "ISE", "ITAE", "TV")
# The constraint that a problem without performance constraints keeps: the candidate's loop is
# stable and its simulation finished (g = 0), else it carries the failure's violation.
STABILITY_CONSTRAINT = "stability"


# Thesis chapters whose tables the runner can write next to the printed values (heurtune.thesis).
THESIS_CHAPTERS = (4, 5, 6)


class IntegralActionWarning(UserWarning):
    """The configured controller structure cannot hold integral action on this plant."""


@dataclasses.dataclass
class Evaluation:
    """Batch evaluation of candidates.

    Attributes
    ----------
    f : (n,) objective values (``FAILED_OBJECTIVE`` for failed candidates)
    g : (n, m) normalised constraint values ``metric / limit - 1``; ``g <= 0`` is feasible.
        Failed candidates get ``FAILED_VIOLATION``; unstable ones ``FAILED_VIOLATION * (1 +
        max Re(eig))``, so that less unstable candidates rank better
    feasible : (n,) bool
    metrics : (n, k) metric values in the order of ``metric_names`` (NaN when not simulated)
    metric_names : tuple of str
    constraint_names : tuple of str
    reason : (n,) object array: "" for a simulated candidate, else ``invalid_parameter``,
        ``riccati_failed``, ``invalid_controller``, ``unstable``, ``diverged`` or ``non_finite``
    """

    f: np.ndarray
    g: np.ndarray
    feasible: np.ndarray
    metrics: np.ndarray
    metric_names: tuple
    constraint_names: tuple
    reason: np.ndarray

    def to_frame(self) -> pd.DataFrame:
        """One row per candidate: f, feasible, reason, the constraints (g_*) and metrics."""
        df = pd.DataFrame(self.metrics, columns=list(self.metric_names))
        for j, name in enumerate(self.constraint_names):
            df.insert(j, f"g_{name}", self.g[:, j])
        df.insert(0, "reason", self.reason)
        df.insert(0, "feasible", self.feasible)
        df.insert(0, "f", self.f)
        return df


class DecisionVectors:
    """Named decision vectors within bounds: what every tuning problem shares.

    Subclasses set ``names`` (tuple of str), ``lower`` and ``upper`` ((d,) arrays).
    """

    scenario_type = object  # the class of this problem's scenarios

    @property
    def dim(self) -> int:
        return len(self.names)

    def scenario(self, scenario):
        """A scenario from its name in ``self.scenarios`` (a ``scenario_type`` is returned as is)."""
        if isinstance(scenario, self.scenario_type):
            return scenario
        try:
            return self.scenarios[scenario]
        except KeyError:
            raise ConfigError(f"unknown scenario {scenario!r}; allowed: {', '.join(self.scenarios)}") from None

    def batch(self, X) -> np.ndarray:
        """``X`` as a float (n, d) array (a single vector becomes one row); ConfigError otherwise."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        if X.ndim != 2 or X.shape[1] != self.dim:
            raise ConfigError(f"X must have shape (n, {self.dim}), got {X.shape}")
        return X

    def values(self, x) -> dict:
        """Map a decision vector (or a dict) to ``{name: value}``, checking names and length."""
        if isinstance(x, dict):
            unknown = [k for k in x if k not in self.names]
            if unknown:
                raise ConfigError(f"unknown variable {unknown[0]!r}; allowed: {', '.join(self.names)}")
            missing = [k for k in self.names if k not in x]
            if missing:
                raise ConfigError(f"missing variable(s) {', '.join(missing)}; required: {', '.join(self.names)}")
            return {k: float(x[k]) for k in self.names}
        x = np.asarray(x, dtype=np.float64).ravel()
        if x.shape != (self.dim,):
            raise ConfigError(f"decision vector must have {self.dim} values ({', '.join(self.names)}), got {x.size}")
        return dict(zip(self.names, x.tolist()))

    def parse(self, text: str, *, check_bounds: bool = True) -> np.ndarray:
        """Parse ``"NAME=VALUE,..."`` (e.g. ``"Q11=0.44,Q22=0.30,..."``) into a vector.

        Unknown, missing and non-numeric names give a one-line ConfigError, and so do values
        outside ``[lower, upper]`` unless ``check_bounds=False`` (the values are then returned
        as given, never clipped).
        """
        values = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            key, sep, val = item.partition("=")
            key = key.strip()
            if not sep:
                raise ConfigError(f"expected NAME=VALUE, got {item!r}")
            try:
                values[key] = float(val)
            except ValueError:
                raise ConfigError(f"{key}: {val.strip()!r} is not a number") from None
        vals = self.values(values)
        for i, name in enumerate(self.names):
            v = vals[name]
            if check_bounds and not (self.lower[i] <= v <= self.upper[i]):
                raise ConfigError(f"{name}={v:g} is outside its bounds [{self.lower[i]:g}, {self.upper[i]:g}]")
        return np.array([vals[n] for n in self.names])


class Problem(DecisionVectors):
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
        None (see :func:`heurtune.objectives.controllers.integral_action_obstruction`).
    """

    scenario_type = Scenario

    def __init__(self, case: str, loop: ClosedLoop, names, lower, upper, *, objective: str,
                 constraints: dict, settling_band: float, scenarios: dict, tuning_scenario: str,
                 weights: dict | None = None, structure_warning: str | None = None):
        self.case = case
        self.loop = loop
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
            self._objective_idx = [_METRIC_INDEX[m] for m in _OBJECTIVES[objective]]
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

    def __repr__(self):
        return (f"Problem(case={self.case!r}, controller={self.loop.kind!r}, dim={self.dim}, "
                f"objective={self.objective!r}, constraints={self.constraints})")

    # -- evaluation -------------------------------------------------------------------
    def _evaluate_one(self, x, scenario: Scenario, metrics_row: np.ndarray):
        """Reason ("" when simulated) and, for an unstable loop, its eigenvalue margin."""
        if not np.all(np.isfinite(x)):
            return "invalid_parameter", 0.0
        try:
            ctrl = self.loop.controller(dict(zip(self.names, x.tolist())))
        except ControllerDesignError as exc:
            return exc.reason, 0.0
        except ConfigError:
            return "invalid_parameter", 0.0
        margin = self.loop.stability_margin(ctrl)
        if not margin < 0.0:
            return "unstable", margin
        sim = self.loop.run(ctrl, scenario, settling_band=self.settling_band, record=False)
        if sim.diverged:
            return "diverged", 0.0
        metrics_row[:] = sim.metrics
        if not np.all(np.isfinite(metrics_row)):
            return "non_finite", 0.0
        return "", 0.0

    def evaluate(self, X, scenario=None) -> Evaluation:
        """Evaluate a batch of candidates.

        Parameters
        ----------
        X : array_like, shape (n, d) or (d,)
        scenario : str or Scenario, optional
            Defaults to the tuning scenario.

        Returns
        -------
        Evaluation
            Never raises for a bad candidate: unstable, undesignable or diverging candidates get
            ``FAILED_OBJECTIVE``, violations ``FAILED_VIOLATION`` and a reason.
        """
        X = self.batch(X)
        sc = self.scenario(self.tuning_scenario if scenario is None else scenario)
        n = X.shape[0]
        m = len(self.constraint_names)
        metrics = np.full((n, len(METRIC_NAMES)), np.nan)
        f = np.full(n, FAILED_OBJECTIVE)
        g = np.full((n, m), FAILED_VIOLATION)
        reason = np.empty(n, dtype=object)
        for i in range(n):
            reason[i], margin = self._evaluate_one(X[i], sc, metrics[i])
            if reason[i] == "":
                if self._objective_w is None:
                    f[i] = metrics[i, self._objective_idx].sum()
                else:
                    f[i] = metrics[i, self._objective_idx] @ self._objective_w
                g[i] = 0.0 if self._stability_only else (
                    metrics[i, self._constraint_idx] / self._constraint_limit - 1.0)
            else:
                metrics[i] = np.nan
                if reason[i] == "unstable":
                    # Graded: the less unstable, the smaller the violation, so Deb's rules and
                    # SLSQP both see a way back to stability.
                    g[i] = FAILED_VIOLATION * (1.0 + min(margin, UNSTABLE_MARGIN_CAP))
        feasible = (reason == "") & np.all(g <= 0.0, axis=1)
        return Evaluation(f, g, feasible, metrics, METRIC_NAMES, self.constraint_names, reason)

    def __call__(self, X):
        """``(f, g)`` of a batch, the form :func:`heurtune.minimize` and the evaluators take."""
        ev = self.evaluate(X)
        return ev.f, ev.g

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

    def simulate(self, x, scenario="nominal", *, record_levels: bool = True) -> pd.DataFrame:
        """Trajectories of one candidate: columns t, h1..h4, y1, y2, u1, u2.

        Raises
        ------
        ControllerDesignError
            When the controller cannot be designed for ``x``.
        """
        sc = self.scenario(scenario)
        ctrl = self.loop.controller(self.values(x))
        return self.loop.run(ctrl, sc, record_levels=record_levels).to_frame()

    def report(self, x, scenarios=None) -> pd.DataFrame:
        """Metrics of one candidate per scenario (rows) with its objective and feasibility.

        Column ``range`` names where the trajectory leaves the plant's physical range (levels
        outside [0, height], voltages outside ``u_range``; "" when inside or when the plant has
        no limits), see :func:`heurtune.objectives.loop.physical_range_flags`.

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
            rows.append(row)
        return pd.DataFrame(rows).set_index("scenario")


class ExperimentBase:
    """What every experiment config shares: cases per (plant, controller type), optimisers."""

    def _set_cases(self, plant_cases: tuple, kinds) -> None:
        """One case per (controller, plant case); named by the plant alone when there is one
        controller type (``"min"``), else ``"<plant>-<controller>"`` (``"min-folqi"``)."""
        self.controllers = tuple(kinds) if isinstance(kinds, list) else (kinds,)
        self.controller = self.controllers[0]
        self._variants = {}
        for kind in self.controllers:
            for pc in plant_cases:
                self._variants[pc if len(self.controllers) == 1 else f"{pc}-{kind}"] = (pc, kind)
        self.cases = tuple(self._variants)

    def _load_optimisers(self, config: dict) -> None:
        """Load the config's plugins and validate each ``[[optimisers]]`` entry's settings."""
        from heurtune import registry

        for spec in config.get("plugins", []):
            registry.load_plugin(spec)
        self.optimisers = []
        for i, opt in enumerate(config.get("optimisers", [])):
            where = f"{self.name}: optimisers[{i}]"
            if "name" not in opt:
                raise ConfigError(f"{where}: missing key 'name'")
            try:
                settings = registry.make_settings(opt["name"], opt.get("settings", {}))
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc}") from None
            unknown = [c for c in opt.get("cases", []) if c not in self.cases]
            if unknown:
                raise ConfigError(f"{where}.cases: unknown case {unknown[0]!r}; allowed: {', '.join(self.cases)}")
            self.optimisers.append(dict(opt, settings=settings))

    def optimisers_of(self, case: str) -> list:
        """``(index, entry)`` of the ``[[optimisers]]`` that tune ``case`` (an entry's
        ``cases`` restricts it; the index is the entry's place in the config)."""
        return [(i, opt) for i, opt in enumerate(self.optimisers) if case in opt.get("cases", self.cases)]

    def controller_of(self, case: str) -> str:
        """The controller type of a case."""
        return self._variant(case)[1]

    def _variant(self, case: str):
        try:
            return self._variants[case]
        except KeyError:
            raise ConfigError(f"unknown case {case!r} for {self.name}; allowed: {', '.join(self.cases)}") from None


class Experiment(ExperimentBase):
    """A named experiment config: plant cases, controller, scenario, problem (and optimisers).

    Use :func:`load_experiment` to create one.
    """

    def __init__(self, config: dict):
        self.config = config
        self.name = config["name"]
        plant = config.get("plant", {})
        self.plant_model = plant.get("model", "qtp")
        plant_cases = tuple(plant.get("cases", ["min", "nmp"]))
        if not plant_cases:
            raise ConfigError(f"{self.name}: plant.cases must name at least one case")
        self._custom = plant.get("custom", {})
        for case in plant_cases:
            self._plant(case)  # validate early
        ctrl = config.get("controller", {})
        self._set_cases(plant_cases, ctrl.get("type", "folqi"))
        self.controller_options = dict(
            oustaloup_order=ctrl.get("oustaloup_order", 5),
            band=tuple(ctrl.get("band", (1e-3, 1e3))),
            realisation=ctrl.get("realisation", "direct"),
        )
        self.pairing = ctrl.get("pairing", "diagonal")
        if isinstance(self.pairing, dict):
            unknown = [c for c in self.pairing if c not in plant_cases]
            if unknown:
                raise ConfigError(f"{self.name}: controller.pairing: unknown case {unknown[0]!r}; "
                                  f"allowed: {', '.join(plant_cases)}")
        unpaired = [k for k in self.controllers if k not in PAIRED_TYPES]
        if unpaired and self.pairing != "diagonal" and len(self.controllers) == len(unpaired):
            raise ConfigError(f"{self.name}: controller.pairing applies to {', '.join(PAIRED_TYPES)}; "
                              f"{unpaired[0]} designs its full integral gain (leave pairing out)")
        sc = dict(config.get("scenario", {}))
        uncertainty = sc.pop("uncertainty", DEFAULT_UNCERTAINTY)
        if "nominal" not in uncertainty:
            uncertainty = {"nominal": 1.0, **uncertainty}
        if "saturation" in sc:
            sc["saturation"] = tuple(sc["saturation"])
        try:
            self.scenarios = {k: Scenario(**sc, uncertainty=float(v)) for k, v in uncertainty.items()}
        except ConfigError as exc:
            raise ConfigError(f"{self.name}: {exc}") from None
        for case in plant_cases:  # fail at load, not in every evaluation (any controller type)
            loop = ClosedLoop(self._plant(case), "iolqi")
            for scenario in self.scenarios.values():
                try:
                    loop.check_scenario(scenario)
                except ConfigError as exc:
                    raise ConfigError(f"{self.name}: {exc}") from None
        prob = config.get("problem", {})
        self.objective = prob.get("objective", "effort")
        self.weights = prob.get("weights")
        if self.objective == "weighted" and not self.weights:
            raise ConfigError(f"{self.name}: problem.objective = 'weighted' needs problem.weights "
                              f"(a weight per metric among {', '.join(WEIGHTED_METRICS)})")
        if self.weights and self.objective != "weighted":
            raise ConfigError(f"{self.name}: problem.weights needs problem.objective = 'weighted', "
                              f"got {self.objective!r}")
        self.constraints = prob.get("constraints", DEFAULT_CONSTRAINTS)
        if self.constraints == "none":
            self.constraints = {}
        for key, lim in self.constraints.items():
            if lim <= 0:
                raise ConfigError(f"{self.name}: problem.constraints.{key} must be positive, got {lim}")
        self.settling_band = prob.get("settling_band", 3.0)
        if not 0 < self.settling_band < 100:
            raise ConfigError(f"{self.name}: problem.settling_band must lie in (0, 100), got {self.settling_band}")
        self.tuning_scenario = prob.get("tuning_scenario", "nominal")
        if self.tuning_scenario not in self.scenarios:
            raise ConfigError(f"{self.name}: problem.tuning_scenario {self.tuning_scenario!r}; "
                              f"allowed: {', '.join(self.scenarios)}")
        names = [n for kind in self.controllers for n in decision_names(kind)]
        bounds = {}
        for kind in self.controllers:
            bounds.update(default_bounds(kind))
        # Bounds of variables no configured controller uses (e.g. alpha inherited by an IOLQI
        # config extending a FOLQI one) are ignored; a name no controller knows is an error.
        known = {n for kind in CONTROLLER_TYPES for n in decision_names(kind)}
        for key, (lo, hi) in prob.get("bounds", {}).items():
            if key not in known:
                raise ConfigError(f"{self.name}: problem.bounds: unknown variable {key!r}; "
                                  f"allowed: {', '.join(dict.fromkeys(names))}")
            if not lo <= hi:
                raise ConfigError(f"{self.name}: problem.bounds.{key}: lower {lo} > upper {hi}")
            if key in bounds:
                bounds[key] = (float(lo), float(hi))
        self.bounds = bounds
        self._load_optimisers(config)
        self.baselines = self._fixed_controllers(config.get("baselines", []))
        chapter = config.get("report", {}).get("thesis_chapter")
        if chapter is not None and chapter not in THESIS_CHAPTERS:
            raise ConfigError(f"{self.name}: report.thesis_chapter: got {chapter!r}; "
                              f"allowed: {', '.join(map(str, THESIS_CHAPTERS))}")

    def __repr__(self):
        return f"Experiment({self.name!r}, cases={self.cases}, controllers={self.controllers})"

    def _fixed_controllers(self, entries: list) -> dict:
        """``{case: {name: x}}`` from the config's ``[[baselines]]`` (gains given as ``x`` or
        looked up in the thesis' printed tables as ``printed = {table, row}``)."""
        out = {}
        for i, entry in enumerate(entries):
            where = f"{self.name}: baselines[{i}]"
            for key in ("name", "case"):
                if key not in entry:
                    raise ConfigError(f"{where}: missing key {key!r}")
            case = entry["case"]
            if case not in self.cases:
                raise ConfigError(f"{where}.case: unknown case {case!r}; allowed: {', '.join(self.cases)}")
            if ("x" in entry) == ("printed" in entry):
                raise ConfigError(f"{where}: give the gains as x = {{...}} or printed = {{table, row}}, not both")
            if "printed" in entry:
                from heurtune.thesis.printed import printed_row

                ref = entry["printed"]
                if set(ref) != {"table", "row"}:
                    raise ConfigError(f"{where}.printed: give table and row, got {sorted(ref)}")
                values = printed_row(ref["table"], ref["row"])
            else:
                values = entry["x"]
            names = decision_names(self.controller_of(case))
            missing = [n for n in names if n not in values or values[n] is None]
            if missing:
                raise ConfigError(f"{where}: no value for {', '.join(missing)} (case {case!r} needs {', '.join(names)})")
            if entry["name"] in out.get(case, {}):
                raise ConfigError(f"{where}: baseline {entry['name']!r} given twice for case {case!r}")
            out.setdefault(case, {})[entry["name"]] = np.array([float(values[n]) for n in names])
        return out

    def baseline_names(self, case: str) -> tuple:
        """Names of the fixed controllers evaluated as runs of their own for ``case``."""
        return tuple(self.baselines.get(case, {}))

    def _plant(self, case: str) -> QTPParams:
        if case in self._custom:
            spec = self._custom[case]
            missing = [k for k in ("A", "a", "k", "gamma", "levels") if k not in spec]
            if missing:
                raise ConfigError(f"{self.name}: plant.custom.{case}: missing {', '.join(missing)}")
            return QTPParams(name=case, **spec)
        try:
            return preset(case)
        except ConfigError as exc:
            raise ConfigError(f"{self.name}: plant.cases: {exc} (or define plant.custom.{case})") from None

    def pairing_of(self, case: str) -> str:
        """The resolved integral pairing of a case: ``"diagonal"`` or ``"anti-diagonal"``.

        ``"auto"`` picks the pairing whose integral action can be stable on the case's plant:
        diagonal when det G(0) > 0, anti-diagonal when det G(0) < 0 (the pairing the relative
        gain array recommends for the QTP). Types without a pairing (``lqi``) get diagonal.
        """
        plant_case, kind = self._variant(case)
        choice = self.pairing.get(plant_case, "diagonal") if isinstance(self.pairing, dict) else self.pairing
        if kind not in PAIRED_TYPES:
            return "diagonal"
        if choice == "auto":
            A, B, C = linearise(self._plant(plant_case))
            choice = "diagonal" if np.linalg.det(dc_gain(A, B, C)) > 0 else "anti-diagonal"
        return choice

    def problem(self, case: str) -> Problem:
        """The tuning problem of one case (e.g. ``"min"``, or ``"min-folqi"`` when the experiment
        names several controllers)."""
        plant_case, kind = self._variant(case)
        pairing = self.pairing_of(case)
        model = {} if self.plant_model == "qtp" else {"plant_model": self.plant_model}
        loop = ClosedLoop(self._plant(plant_case), kind, **self.controller_options, pairing=pairing, **model)
        names = decision_names(kind)
        lower = [self.bounds[n][0] for n in names]
        upper = [self.bounds[n][1] for n in names]
        ki = tuple(self.bounds.get(k, (1.0, 1.0)) for k in ("Ki1", "Ki2"))
        warning = integral_action_obstruction(kind, pairing, loop.A, loop.B, loop.C, ki)
        prob = Problem(case, loop, names, lower, upper, objective=self.objective,
                       constraints=self.constraints, settling_band=self.settling_band,
                       scenarios=self.scenarios, tuning_scenario=self.tuning_scenario,
                       weights=self.weights, structure_warning=warning)
        prob.baselines = dict(self.baselines.get(case, {}))
        return prob

    def structure_warnings(self) -> dict:
        """``{case: one-line reason}`` for every case whose controller structure cannot hold
        integral action on its plant (see :func:`integral_action_obstruction`)."""
        found = {case: self.problem(case).structure_warning for case in self.cases}
        return {case: msg for case, msg in found.items() if msg}


def load_experiment(name: str) -> Experiment:
    """Load an experiment by name (``experiments/<name>.toml``) or path.

    Raises
    ------
    ConfigError
        With a one-line message naming the file, the key and the allowed values.
    """
    return make_experiment(load_config(name))


def make_experiment(config: dict):
    """The experiment object of a loaded config: :class:`Experiment` for the QTP,
    :class:`heurtune.tito_problem.TITOExperiment` for TITO plants (``plant.model``)."""
    if config.get("plant", {}).get("model", "qtp") in ("tito", "two_tank_nonlinear"):
        from heurtune.tito_problem import TITOExperiment

        return TITOExperiment(config)
    return Experiment(config)
