"""The tuning-problem contract every plant family implements.

A plant family (``objectives/<family>/``, or one plugin file) registers an experiment class
with :func:`heurtune.core.families.register_family`. The runner, the evaluate command,
compare, the exports and the figures then only use what is defined here:

- :class:`ExperimentBase`: a config's cases (plant x controller type), its optimisers, and the
  hooks the runner calls (``problem``, ``baseline_names``, ``structure_warnings``,
  ``write_outputs``).
- :class:`TuningProblem`: one case's named decision vector within bounds, its scenarios and
  ``evaluate(X) -> Evaluation`` (never raising for a bad candidate), ``simulate``, ``report``,
  ``identity`` (hashed into the problem_id), ``warm_up`` and optional ``margins`` and
  ``baseline``.

Data flow: config -> experiment -> problem -> evaluate -> kernel -> metrics -> constraints
(see docs/architecture.md).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json

import numpy as np
import pandas as pd

from heurtune.core import registry
from heurtune.core.errors import ConfigError
from heurtune.core.plugins import load_plugins

__all__ = ["Evaluation", "TuningProblem", "ExperimentBase", "StructureWarning", "FAILED_OBJECTIVE",
           "FAILED_VIOLATION", "FAILURE_REASONS", "problem_fingerprint", "RANGE_RTOL", "DEFAULT_SIGNAL_LABELS"]

# A candidate that cannot be simulated gets these (finite) values.
FAILED_OBJECTIVE = 1.0e10
FAILED_VIOLATION = 1.0e6
# Why a candidate was not simulated to the end ("" when it was).
FAILURE_REASONS = ("invalid_parameter", "riccati_failed", "invalid_controller", "unstable", "diverged",
                   "non_finite")
# Values within this relative distance of a physical limit count as inside it.
RANGE_RTOL = 1e-9
# Names and units of a problem's signals on response figures (TuningProblem.signal_labels).
DEFAULT_SIGNAL_LABELS = {"output": "output", "input": "input", "y_label": "y{i}", "u_label": "u{i}",
                         "y_unit": "", "u_unit": ""}


class StructureWarning(UserWarning):
    """The configured controller structure cannot meet the problem on this plant (said once
    by the runner and the evaluate command, then silenced)."""


@dataclasses.dataclass
class Evaluation:
    """Batch evaluation of candidates.

    Attributes
    ----------
    f : (n,) objective values (``FAILED_OBJECTIVE`` for failed candidates)
    g : (n, m) normalised constraint values ``metric / limit - 1``; ``g <= 0`` is feasible.
        Failed candidates get ``FAILED_VIOLATION``; unstable ones ``FAILED_VIOLATION`` times a
        factor above 1 that grows with how unstable they are (QTP: ``1 + max Re(eig)`` of the
        closed loop), so that less unstable candidates rank better
    feasible : (n,) bool
    metrics : (n, k) metric values in the order of ``metric_names`` (NaN when not simulated)
    metric_names : tuple of str
    constraint_names : tuple of str
    F : (n, k) or None, a problem with several objectives (``objective_names``): their values
        (``FAILED_OBJECTIVE`` for failed candidates); ``f`` is then the first of them
    objective_names : tuple of str
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
    F: np.ndarray | None = None
    objective_names: tuple = ()

    def to_frame(self) -> pd.DataFrame:
        """One row per candidate: f, feasible, reason, the constraints (g_*) and metrics."""
        df = pd.DataFrame(self.metrics, columns=list(self.metric_names))
        for j, name in enumerate(self.constraint_names):
            df.insert(j, f"g_{name}", self.g[:, j])
        df.insert(0, "reason", self.reason)
        df.insert(0, "feasible", self.feasible)
        df.insert(0, "f", self.f)
        return df


class TuningProblem:
    """One case's tuning problem: the protocol the runner, the optimisers and the reports use.

    A subclass sets, in its ``__init__``:

    ``case`` (str), ``controller`` (str, the controller type), ``names`` (tuple of str),
    ``lower`` and ``upper`` ((d,) float arrays), ``scenarios`` (dict of name to scenario, with
    ``"nominal"``), ``tuning_scenario`` (str), ``objective`` (str) and ``constraint_names``
    (tuple of str); and implements :meth:`evaluate`, :meth:`simulate`, :meth:`report`,
    :meth:`identity` and :meth:`warm_up`. The rest has defaults here.

    Any numbers of inputs and outputs: :meth:`simulate` names them ``u1 .. un`` and
    ``y1 .. ym``, :meth:`physical_limits` gives one output range per output, and the figures
    are sized from them. What the runner's calibration needs of a scenario (the time of one
    evaluation, ``heurtune.runner.workplan``): its ``horizon`` (s) and the simulated seconds
    per kernel step, ``kernel_step`` or ``dt``; a scenario without them is not calibrated
    (the plan then gives no time estimate and refuses nothing).
    """

    scenario_type = object  # the class of this problem's scenarios
    # The unit of each metric, by its name without the loop number ({"IAE": "cm s", ...}):
    # tables of results show them beside the column names. Empty: no units said.
    metric_units: dict = {}
    # The objectives a config may name in problem.objectives, each the sum of these metric
    # columns (e.g. {"iae": ("IAE1", "IAE2")}); None: the family gives F itself or has none.
    objective_metrics = None
    # One line saying why the configured controller structure cannot meet the problem on this
    # plant (said by the runner and the evaluate command), or None.
    structure_warning = None
    # Report columns the evaluate command prints (None: all of them).
    report_columns = None
    # heurtune.core.robust.RobustTuning when the objective aggregates several tuning scenarios.
    robust = None
    # Several objectives (config problem.objectives): their names, the reference point of the
    # hypervolume and the weights of the decision step; None for one objective.
    objective_names = None
    reference_point = None
    decision_weights = None
    # Panel names and units of response figures (see DEFAULT_SIGNAL_LABELS), and the objective
    # with its unit for convergence figures (None: "best objective").
    signal_labels = DEFAULT_SIGNAL_LABELS
    objective_label = None
    # Where the simulations of an evaluation run (set_device): the devices this family offers,
    # and the chosen one.
    devices = ("cpu",)
    device = "cpu"

    def objective_axis_label(self, name: str) -> str:
        """Objective ``name`` with its unit for a figure's axis (a family with units overrides
        it; here the name itself).

        Parameters
        ----------
        name : str

        Returns
        -------
        str
        """
        return str(name)

    def __init_subclass__(cls, **kwargs):
        """Robust and multi-objective tuning for every family, by construction: a subclass's
        ``evaluate`` aggregates its tuning scenarios when the problem is tuned robustly (and
        gives ``F`` from :attr:`objective_metrics` when it has several objectives and the
        family gives none), and its ``identity`` includes :meth:`tuning_identity`."""
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("evaluate")
        if own is not None and not getattr(own, "_tuning", False):
            @functools.wraps(own)
            def evaluate(self, X, scenario=None, **options):
                if scenario is None and self.robust is not None:
                    return self.robust.evaluate(self, X, **options)
                return self._with_objectives(own(self, X, scenario, **options))

            evaluate._tuning = True
            cls.evaluate = evaluate
        own_identity = cls.__dict__.get("identity")
        if own_identity is not None and not getattr(own_identity, "_tuning", False):
            @functools.wraps(own_identity)
            def identity(self):
                return {**own_identity(self), **self.tuning_identity()}

            identity._tuning = True
            cls.identity = identity

    def _with_objectives(self, ev: Evaluation) -> Evaluation:
        """``ev`` with the values of every objective as ``F`` when the problem has several and
        the family's evaluation gave none (each the sum of its :attr:`objective_metrics`
        columns; FAILED_OBJECTIVE for a failed candidate)."""
        if self.objective_names is None or ev.F is not None or not isinstance(ev, Evaluation):
            return ev
        col = {name: i for i, name in enumerate(ev.metric_names)}
        F = np.column_stack([ev.metrics[:, [col[m] for m in self.objective_metrics[name]]].sum(axis=1)
                             for name in self.objective_names])
        F[np.asarray(ev.reason) != ""] = FAILED_OBJECTIVE
        return dataclasses.replace(ev, F=F, objective_names=self.objective_names)

    # -- what a family implements ---------------------------------------------------------------
    def evaluate(self, X, scenario=None) -> Evaluation:
        """Evaluate a batch ``X`` (n, d) under a scenario (default: the tuning scenario).

        Never raises for a bad candidate: it gets ``FAILED_OBJECTIVE``, ``FAILED_VIOLATION``
        (or a graded violation) and a reason among ``FAILURE_REASONS``.
        """
        raise NotImplementedError

    def simulate(self, x, scenario="nominal") -> pd.DataFrame:
        """Trajectories of one candidate: columns ``t``, the outputs ``y1 .. ym`` and the
        inputs ``u1 .. un`` (any numbers of each, numbered from 1; figures are sized from
        them), optionally the set-points ``r1 .. rm`` and internal states (e.g. levels
        ``h1..h4``)."""
        raise NotImplementedError

    def report(self, x, scenarios=None) -> pd.DataFrame:
        """One row per scenario (index ``scenario``): ``f``, ``feasible``, ``reason`` and the
        metrics of one candidate."""
        raise NotImplementedError

    def identity(self) -> dict:
        """Everything that defines the problem, JSON-able (hashed into the problem_id)."""
        raise NotImplementedError

    def warm_up(self) -> None:
        """Compile or load the jitted kernels (called in the parent before workers start)."""

    # -- optional -----------------------------------------------------------------------------
    def set_device(self, device: str) -> None:
        """Run this problem's simulations on ``device``, one of :attr:`devices`.

        ``"cpu"`` simulates one candidate at a time (the numbers of the shipped experiments);
        a family may offer ``"cpu-batch"`` (a batch of candidates in one compiled call on the CPU)
        and ``"gpu"`` (one GPU thread per candidate and scenario), whose metrics equal the
        ``"cpu"`` ones within a stated rounding tolerance.

        Raises
        ------
        ConfigError
            For a device this family does not offer, or one this machine lacks.
        """
        if not isinstance(device, str) or device not in self.devices:
            raise ConfigError(f"device must be one of {', '.join(map(repr, self.devices))} for this plant family, "
                              f"got {device!r}")
        self.device = device

    def set_objectives(self, names, reference_point, decision_weights=None) -> None:
        """Make this a problem of several objectives (the family's names, the first being
        ``self.objective``): its ``evaluate`` then gives their values as ``F``."""
        self.objective_names = tuple(names)
        self.reference_point = tuple(reference_point)
        self.decision_weights = None if decision_weights is None else tuple(decision_weights)

    def tuning_identity(self) -> dict:
        """The robust and multi-objective parts of :meth:`identity` (empty when unused, so that
        problems without them keep their problem_id)."""
        out = {}
        if self.robust is not None:
            out["robust"] = self.robust.identity()
        if self.objective_names is not None:
            out.update(objectives=list(self.objective_names), reference_point=list(self.reference_point),
                       decision_weights=self.decision_weights and list(self.decision_weights))
        return out

    def evaluate_scenarios(self, X, scenarios, **options) -> list:
        """One :class:`Evaluation` of ``X`` per scenario (robust tuning evaluates a candidate's
        scenarios through this; ``options`` go to :meth:`evaluate`). A family overrides it to
        share work across the scenarios."""
        return [self.evaluate(X, s, **options) for s in scenarios]

    def evaluation_scenarios(self) -> list:
        """The scenarios one evaluation simulates: the tuning scenario, or every scenario the
        objective aggregates when the problem is tuned robustly (the runner's calibration
        counts their steps)."""
        names = self.robust.scenarios if self.robust is not None else (self.tuning_scenario,)
        return [self.scenario(name) for name in names]

    def margins(self, x) -> pd.DataFrame | None:
        """Stability margins of one design, one row per loop, or None when the family has none."""
        return None

    def baseline(self, name: str) -> np.ndarray:
        """Decision vector of a fixed design named by the experiment's ``baseline_names``."""
        raise ConfigError(f"case {self.case!r}: unknown baseline {name!r}; allowed: none")

    def controller_record(self, x) -> dict | None:
        """What the ``.mat`` export writes of one design besides its gains (e.g. controller
        matrices and a response as a DataFrame under ``"response"``), or None."""
        return None

    def physical_limits(self) -> dict | None:
        """Ranges drawn on response figures: ``{"y": [(lo, hi), ...]}`` one per output, ``"u"``
        one ``(lo, hi)`` for every input or a list of one per input (and ``"h"``: one range per
        internal level), or None."""
        return None

    # -- shared -------------------------------------------------------------------------------
    def __call__(self, X):
        """``(f, g)`` of a batch, the form :func:`heurtune.minimize` and the evaluators take
        (``f`` is (n, k) for a problem with several objectives)."""
        ev = self.evaluate(X)
        return (ev.f if ev.F is None else ev.F), ev.g

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
            if key in values:
                raise ConfigError(f"{key} is given twice ({values[key]:g} and {val.strip()})")
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


class ExperimentBase:
    """An experiment config of one plant family: cases per (plant, controller type), optimisers.

    A family's subclass sets ``config`` and ``name`` (``config["name"]``), calls
    :meth:`_set_cases` and :meth:`_load_optimisers`, and implements :meth:`problem`. The other
    hooks the runner calls have defaults here.
    """

    # Set by the runner for a --smoke run, so that work a family adds to its outputs (a design
    # sweep, say) keeps to smoke budgets as the runs do.
    smoke = False

    def problem(self, case: str) -> TuningProblem:
        """The tuning problem of one case."""
        raise NotImplementedError

    # Applies the config's robust and multi-objective tuning to a family's problem, where the
    # family did not (heurtune.core.robust.apply_tuning, installed by register_family).
    _tuning_hook = None

    def __init_subclass__(cls, **kwargs):
        """A subclass's ``problem`` hands back its problem with the config's robust and
        multi-objective tuning applied (:attr:`_tuning_hook`), unless the family set them."""
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("problem")
        if own is not None and not getattr(own, "_tuning", False):
            @functools.wraps(own)
            def problem(self, case):
                prob = own(self, case)
                hook = type(self)._tuning_hook
                return prob if hook is None else hook(self, prob)

            problem._tuning = True
            cls.problem = problem

    def baseline_names(self, case: str) -> tuple:
        """Fixed designs run once each for ``case`` (names for ``problem.baseline``)."""
        return ()

    def structure_warnings(self) -> dict:
        """``{case: one line}`` for cases whose controller structure cannot meet the problem."""
        found = {case: self.problem(case).structure_warning for case in self.cases}
        return {case: msg for case, msg in found.items() if msg}

    def write_outputs(self, out_dir, *, runs: pd.DataFrame, history: pd.DataFrame, best: pd.DataFrame,
                      figures: bool = True) -> None:
        """Files of this family beside the runner's (design tables, robustness, chapter tables);
        ``best`` holds the best run per case and optimiser."""

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

    def _positive_limits(self, constraints: dict) -> dict:
        """``problem.constraints`` checked: every limit positive (one-line ConfigError)."""
        for key, lim in constraints.items():
            if not lim > 0:
                raise ConfigError(f"{self.name}: problem.constraints.{key} must be positive, got {lim}")
        return dict(constraints)

    def _tuning_scenario(self, problem: dict) -> str:
        """``problem.tuning_scenario``, one of ``self.scenarios``: by default ``"nominal"``, or
        the first of ``problem.tuning_scenarios`` when the problem is tuned robustly."""
        name = problem.get("tuning_scenario", (problem.get("tuning_scenarios") or ["nominal"])[0])
        if name not in self.scenarios:
            raise ConfigError(f"{self.name}: problem.tuning_scenario {name!r}; allowed: {', '.join(self.scenarios)}")
        return name

    def _settling_band(self, problem: dict, default: float) -> float:
        """``problem.settling_band`` in percent, inside (0, 100)."""
        band = problem.get("settling_band", default)
        if not 0 < band < 100:
            raise ConfigError(f"{self.name}: problem.settling_band must lie in (0, 100), got {band}")
        return band

    def _objectives(self, problem: dict, allowed) -> None:
        """``problem.objectives`` (two or three of ``allowed``), ``reference_point`` (one value
        per objective, required with them) and ``decision_weights`` (optional, positive) into
        ``self.objective_names``, ``self.reference_point``, ``self.decision_weights`` (None for
        one objective)."""
        names = problem.get("objectives")
        self.objective_names = self.reference_point = self.decision_weights = None
        if names is None:
            for key in ("reference_point", "decision_weights"):
                if key in problem:
                    raise ConfigError(f"{self.name}: problem.{key} needs problem.objectives")
            return
        if not 2 <= len(names) <= 3 or len(set(names)) != len(names):
            raise ConfigError(
                f"{self.name}: problem.objectives must name two or three distinct objectives, got {names}"
            )
        unknown = [n for n in names if n not in allowed]
        if unknown:
            raise ConfigError(f"{self.name}: problem.objectives: unknown objective {unknown[0]!r}; "
                              f"allowed: {', '.join(allowed)}")
        ref = problem.get("reference_point")
        if ref is None or len(ref) != len(names):
            raise ConfigError(f"{self.name}: problem.reference_point must give one value per objective "
                              f"({', '.join(names)}): the point bounding the hypervolume")
        weights = problem.get("decision_weights")
        if weights is not None and (len(weights) != len(names) or not all(w > 0 for w in weights)):
            raise ConfigError(f"{self.name}: problem.decision_weights must give one positive weight per objective")
        self.objective_names = tuple(names)
        self.reference_point = tuple(float(r) for r in ref)
        self.decision_weights = None if weights is None else tuple(float(w) for w in weights)

    def _check_multi_objective_optimisers(self) -> None:
        """With several objectives every ``[[optimisers]]`` entry must take them."""
        if self.objective_names is None:
            return
        for i, opt in enumerate(self.optimisers):
            if not registry.get(opt["name"]).multi_objective:
                raise ConfigError(f"{self.name}: optimisers[{i}]: {opt['name']!r} takes one objective and "
                                  f"problem.objectives names {len(self.objective_names)}; use a multi-objective "
                                  "optimiser (e.g. nsga2)")

    def _override_bounds(self, bounds: dict, given: dict, known, allowed) -> dict:
        """``bounds`` (name -> (lo, hi)) with the config's ``problem.bounds`` over them.

        A name in ``known`` but not in ``bounds`` (a variable of another controller type) is
        ignored; a name outside ``known`` or lower > upper is a one-line ConfigError listing
        ``allowed``.
        """
        out = dict(bounds)
        for key, (lo, hi) in given.items():
            if key not in known:
                raise ConfigError(f"{self.name}: problem.bounds: unknown variable {key!r}; "
                                  f"allowed: {', '.join(dict.fromkeys(allowed))}")
            if not lo <= hi:
                raise ConfigError(f"{self.name}: problem.bounds.{key}: lower {lo} > upper {hi}")
            if key in out:
                out[key] = (float(lo), float(hi))
        return out

    def _load_optimisers(self, config: dict) -> None:
        """Load the config's plugins and validate each ``[[optimisers]]`` entry's settings."""
        load_plugins(config.get("plugins", []))
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


def problem_fingerprint(prob) -> str:
    """A short hash of everything that defines a tuning problem.

    Parameters
    ----------
    prob : TuningProblem
        A problem; its ``identity()`` is hashed.

    Returns
    -------
    str
        The ``problem_id`` of ``runs.parquet``.
    """
    text = json.dumps(prob.identity(), sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:12]
