"""The quadruple-tank family: experiment configs of the QTP under any registered controller structure.

``[plant] model = "qtp"`` (the default) or ``"qtp_bond_graph"`` (the thesis' chapter-6
bond-graph form). Each case is a plant preset (``min``, ``nmp``) or a ``plant.custom`` table,
times each configured controller type (:mod:`heurtune.objectives.qtp.structures`: FOLQI,
IOLQI, LQI, LADR, PID, FOPID and plugins'); :meth:`Experiment.problem` builds its
:class:`heurtune.objectives.qtp.problem.Problem`.
"""

from __future__ import annotations

import math

import numpy as np

from heurtune.core.errors import ConfigError, config_warning
from heurtune.core.families import register_family
from heurtune.core.problem import ExperimentBase
from heurtune.core.robust import ROBUST_SCHEMA, robust_tuning
from heurtune.core.schema import COMMON_SCHEMA, MULTI_OBJECTIVE_SCHEMA, NUMBER, PAIR
from heurtune.core.structures import on_register
from heurtune.objectives.qtp import (
    structure_checks,  # noqa: F401  (registers the structure contract)
    structures,
)
from heurtune.objectives.qtp.controllers import dc_gain, integral_action_obstruction
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
from heurtune.objectives.qtp.model import QTPParams, linearise, preset
from heurtune.objectives.qtp.problem import OBJECTIVES, WEIGHTED_METRICS, Problem
from heurtune.objectives.qtp.structures import decision_names, default_bounds, paired_types
from heurtune.objectives.qtp.thesis.printed import printed_row
from heurtune.objectives.qtp.thesis.tables import write_chapter

__all__ = ["Experiment", "SCHEMA", "MODELS"]

MODELS = ("qtp", "qtp_bond_graph")
DEFAULT_UNCERTAINTY = {"nominal": 1.0, "-30%": 0.7, "+30%": 1.3}
DEFAULT_CONSTRAINTS = {"Mp": 10.0, "ts": 70.0, "ess": 1.0}
# Thesis chapters whose tables the runner can write next to the printed values (heurtune.objectives.qtp.thesis).
THESIS_CHAPTERS = (4, 5, 6)

SCHEMA = dict(COMMON_SCHEMA, **{
    "plant": {
        # "qtp_bond_graph": the thesis' chapter-6 bond-graph form (pressure states) of the QTP
        "model": MODELS,
        "cases": ("list", str),
        "custom": ("map", {
            "A": ("list", NUMBER), "a": ("list", NUMBER), "k": ("list", NUMBER),
            "gamma": ("list", NUMBER), "levels": ("list", NUMBER), "g": NUMBER,
            "height": ("list", NUMBER), "u_range": PAIR,
        }),
    },
    "controller": {
        # one registered structure, or a list (one case per type); the choices and each
        # structure's options (FOLQI's oustaloup_order, band, realisation; PID's
        # derivative_filter, decoupler; a plugin's) are added as structures register (below)
        "type": ("choices", ()),
        # a digital controller: sampled with zero-order hold every sample_time s (the sampled loop)
        "sample_time": NUMBER,
        # One pairing for every case, "auto" (the one the sign of det G(0) allows), or a table
        # naming it per plant case.
        "pairing": ("oneof", (("diagonal", "anti-diagonal", "auto"),
                              ("map", ("diagonal", "anti-diagonal", "auto")))),
    },
    "scenario": {
        "horizon": NUMBER, "dt": NUMBER,
        "output_disturbance": PAIR, "disturbance_time": NUMBER,
        "input_disturbance": PAIR, "input_disturbance_time": NUMBER,
        # set-point steps (cm from the operating levels) and when they happen
        "setpoint_step": PAIR, "setpoint_time": NUMBER,
        "noise_sd": NUMBER, "noise_seed": int,
        "saturation": PAIR,
        "limits": ("none", "physical"),
        "uncertainty": ("map", NUMBER),
        # the continuous-time loop: largest level error (cm) or an explicit step (s), and the
        # spacing of its recorded trajectory
        "tolerance": NUMBER, "step": NUMBER, "output_dt": NUMBER,
        # its method: "switching" (default; follows saturation and limits) or "linearised" (the
        # whole linearised loop exact, adaptive steps; no saturation or limits)
        "integrator": ("switching", "linearised"),
    },
    "problem": {
        "objective": tuple(OBJECTIVES) + ("weighted",),
        # objective = "weighted": sum over the named metrics of weight * (metric1 + metric2)
        "weights": {name: NUMBER for name in WEIGHTED_METRICS},
        "settling_band": NUMBER,
        "tuning_scenario": str,
        # robust tuning: the objective aggregated over these scenarios, constraints in all
        **ROBUST_SCHEMA,
        # several objectives (names of `objective`), the hypervolume's reference point, the
        # decision step's weights
        **MULTI_OBJECTIVE_SCHEMA,
        # "none": no performance constraints (stability is always required)
        "constraints": ("oneof", ({"Mp": NUMBER, "ts": NUMBER, "ess": NUMBER}, ("none",))),
        "bounds": ("map", PAIR),
    },
    # Fixed controllers evaluated as runs of their own (one evaluation, no search), e.g. the
    # thesis' printed gains: x = {name = value, ...} or printed = {table = "4.7", row = "min"}.
    "baselines": ("list", {"name": str, "case": str, "x": ("map", NUMBER),
                           "printed": {"table": str, "row": str}}),
    # thesis_chapter = 4, 5 or 6: write that chapter's tables next to the printed values.
    "report": {"thesis_chapter": int},
})




# Ends the error of an unknown [controller] type: a plugin's type is known once its file is loaded.
_PLUGIN_TYPE_HINT = "a plugin's type needs its file: plugins = [\"FILE.py\"] in the config, or --plugin FILE.py"


def _add_structure(structure) -> None:
    """Keep the schema's ``controller`` table up to date with the registered structures: their
    names as the choices of ``type``, their options as keys (one spec per key: two structures
    that read one key must agree on it)."""
    table = SCHEMA["controller"]
    for key, (spec, _) in structure.options.items():
        if key in table and table[key] != spec:
            raise ConfigError(f"controller structure {structure.name!r}: option {key!r} is declared with "
                              f"another schema by another structure")
    # type, the structures' options, then the keys of every type (the order error messages list)
    fixed = {key: table[key] for key in _EVERY_TYPE_KEYS}
    options = {key: spec for key, spec in table.items() if key not in fixed and key != "type"}
    options.update({key: spec for key, (spec, _) in structure.options.items()})
    table.clear()
    table.update({"type": ("choices", structures.names(), _PLUGIN_TYPE_HINT), **options, **fixed})


# The [controller] keys every type reads (the others are the structures' options).
_EVERY_TYPE_KEYS = ("sample_time", "pairing")


on_register(structures.FAMILY, _add_structure)


@register_family("qtp", models=MODELS, schema=SCHEMA,
                 description="quadruple tank process (nonlinear, minimum and non-minimum phase) under "
                             "FOLQI, IOLQI, LQI, LADR, PID, FOPID or a plugin structure")
class Experiment(ExperimentBase):
    """A named experiment config: plant cases, controller, scenario, problem (and optimisers).

    Use :func:`heurtune.load_experiment` to create one.
    """

    def __init__(self, config: dict):
        self.config = config
        self.name = config["name"]
        plant = config.get("plant", {})
        self.plant_model = plant.get("model", "qtp")
        plant_cases = tuple(plant.get("cases", ["min", "nmp"]))
        if not plant_cases:
            raise ConfigError(f"{self.name}: plant.cases must name at least one case")
        repeated = sorted({c for c in plant_cases if plant_cases.count(c) > 1})
        if repeated:
            raise ConfigError(f"{self.name}: plant.cases names {repeated[0]!r} more than once")
        self._custom = plant.get("custom", {})
        for case in plant_cases:
            self._plant(case)  # validate early
        ctrl = config.get("controller", {})
        self._set_cases(plant_cases, ctrl.get("type", "folqi"))
        read = {key for kind in self.controllers for key in structures.structure(kind).options}
        unread = [key for key in ctrl if key not in read and key not in ("type", "sample_time", "pairing")]
        if unread:  # another structure's option (inherited through extends, as unused bounds are)
            config_warning(f"{self.name}: controller.{', controller.'.join(unread)} not read by "
                           f"{', '.join(self.controllers)} (it reads: {', '.join(sorted(read)) or 'no options'}); "
                           f"ignored")
        # each type's own options, from the config where given (their defaults otherwise)
        self.controller_options = {
            kind: {key: ctrl[key] for key in structures.structure(kind).options if key in ctrl}
            for kind in self.controllers}
        if "band" in ctrl:
            lo, hi = ctrl["band"]
            if not (0.0 < lo < hi < math.inf):
                raise ConfigError(f"{self.name}: controller.band must be [low, high] rad/s with 0 < low < high, "
                                  f"both finite, got {[lo, hi]}")
        self.pairing = ctrl.get("pairing", "diagonal")
        if isinstance(self.pairing, dict):
            unknown = [c for c in self.pairing if c not in plant_cases]
            if unknown:
                raise ConfigError(f"{self.name}: controller.pairing: unknown case {unknown[0]!r}; "
                                  f"allowed: {', '.join(plant_cases)}")
        unpaired = [k for k in self.controllers if k not in paired_types()]
        if unpaired and self.pairing != "diagonal" and len(self.controllers) == len(unpaired):
            raise ConfigError(f"{self.name}: controller.pairing applies to {', '.join(paired_types())}; "
                              f"{unpaired[0]} designs its full integral gain (leave pairing out)")
        sc = dict(config.get("scenario", {}))
        self._digital_controller(ctrl.get("sample_time"), sc)
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
        self.constraints = self._positive_limits(self.constraints)
        self._objectives(prob, tuple(OBJECTIVES))
        if self.objective_names is not None:
            if "objective" in prob and prob["objective"] != self.objective_names[0]:
                raise ConfigError(f"{self.name}: problem.objective must be the first of problem.objectives "
                                  f"({self.objective_names[0]!r}) or left out")
            self.objective = self.objective_names[0]
        self.settling_band = self._settling_band(prob, 3.0)
        self.tuning_scenario = self._tuning_scenario(prob)
        self.robust = robust_tuning(prob, self.scenarios, self.name)
        names = [n for kind in self.controllers for n in decision_names(kind)]
        bounds = {}
        for kind in self.controllers:
            bounds.update(default_bounds(kind))
        # Bounds of variables no configured controller uses (e.g. alpha inherited by an IOLQI
        # config extending a FOLQI one) are ignored; a name no controller knows is an error.
        known = {n for kind in structures.names() for n in decision_names(kind)}
        self.bounds = self._override_bounds(bounds, prob.get("bounds", {}), known, names)
        for name, (lo, _) in self.bounds.items():
            for kind in self.controllers:
                low, strict = structures.structure(kind).domain(name)
                if lo < low or (strict and lo == low):
                    raise ConfigError(f"{self.name}: problem.bounds.{name}: the lower bound must be "
                                      f"{'>' if strict else '>='} {low:g}, got {lo} (R, Ki and alpha "
                                      "are positive; Q, Qi, beta, b, r, Kp and Kd are not negative)")
        self._load_optimisers(config)
        self._check_multi_objective_optimisers()
        self.baselines = self._fixed_controllers(config.get("baselines", []))
        chapter = config.get("report", {}).get("thesis_chapter")
        if chapter is not None and chapter not in THESIS_CHAPTERS:
            raise ConfigError(f"{self.name}: report.thesis_chapter: got {chapter!r}; "
                              f"allowed: {', '.join(map(str, THESIS_CHAPTERS))}")

    def __repr__(self):
        return f"Experiment({self.name!r}, cases={self.cases}, controllers={self.controllers})"

    def _digital_controller(self, sample_time, sc: dict) -> None:
        """``[controller] sample_time``: the controller is digital, sampled with zero-order hold
        every ``sample_time`` s, which is the sampled loop with ``dt = sample_time`` (the plant
        stepped by RK4 in between, several steps when it is long). Writes it into the scenario
        keys ``sc``; the problem, and its id, are those of the same ``dt``.

        A ``scenario.dt`` without ``sample_time`` is what configs of earlier versions wrote for
        the sampled loop, then the default: it is read as ``sample_time``, with a warning naming
        both keys (the continuous loop is the default now)."""
        if sample_time is None:
            if "dt" in sc:
                config_warning(f"{self.name}: scenario.dt = {sc['dt']!r} is read as controller.sample_time = "
                               f"{sc['dt']!r} (a digital controller, the sampled loop); the continuous-time loop "
                               f"is the default now: write controller.sample_time to keep the sampled loop, or "
                               f"leave both out")
            return
        where = f"{self.name}: controller.sample_time"
        if isinstance(sample_time, bool) or not isinstance(sample_time, (int, float)) \
                or not math.isfinite(sample_time) or sample_time <= 0:
            raise ConfigError(f"{where} must be a finite number > 0 (s), got {sample_time!r}")
        for key in ("tolerance", "step"):
            if key in sc:
                raise ConfigError(f"{where} and scenario.{key} both set: a digital controller runs the sampled "
                                  f"loop, scenario.{key} the continuous one; give one")
        if "dt" in sc and float(sc["dt"]) != float(sample_time):
            raise ConfigError(f"{where} ({sample_time}) and scenario.dt ({sc['dt']}) both set the sample period; "
                              f"give one")
        horizon = float(sc.get("horizon", 350.0))
        if sample_time > horizon:
            raise ConfigError(f"{where} ({sample_time}) must not exceed scenario.horizon ({horizon})")
        for key, default in (("horizon", 350.0), ("disturbance_time", 50.0), ("input_disturbance_time", 0.0)):
            t = float(sc.get(key, default))
            if abs(round(t / sample_time) * sample_time - t) > 1e-9 * max(1.0, t):
                raise ConfigError(f"{where} ({sample_time}) must divide scenario.{key} ({t:g})")
        sc["dt"] = float(sample_time)

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
                ref = entry["printed"]
                if set(ref) != {"table", "row"}:
                    raise ConfigError(f"{where}.printed: give table and row, got {sorted(ref)}")
                values = printed_row(ref["table"], ref["row"])
            else:
                values = entry["x"]
            names = decision_names(self.controller_of(case))
            missing = [n for n in names if n not in values or values[n] is None]
            if missing:
                raise ConfigError(
                    f"{where}: no value for {', '.join(missing)} (case {case!r} needs {', '.join(names)})"
                )
            if entry["name"] in out.get(case, {}):
                raise ConfigError(f"{where}: baseline {entry['name']!r} given twice for case {case!r}")
            out.setdefault(case, {})[entry["name"]] = np.array([float(values[n]) for n in names])
        return out

    @staticmethod
    def suite_instance(case: str, instance: int, seed: int, perturbation: dict) -> dict:
        """Instance ``instance`` of preset ``case`` for the tuning suite, as ``plant.custom`` takes
        it (:func:`heurtune.objectives.qtp.instances.instance_plant`)."""
        from heurtune.objectives.qtp.instances import instance_plant

        return instance_plant(case, instance, seed, perturbation)

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
        if kind not in paired_types():
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
        loop = ClosedLoop(self._plant(plant_case), kind, **self.controller_options[kind], pairing=pairing, **model)
        names = decision_names(kind)
        lower = [self.bounds[n][0] for n in names]
        upper = [self.bounds[n][1] for n in names]
        ki = tuple(self.bounds.get(k, (1.0, 1.0)) for k in ("Ki1", "Ki2"))
        extras = loop.structure.extras
        sign = extras["gain_sign"](loop.plant_linearisation, loop.options) if "gain_sign" in extras else 1
        warning = integral_action_obstruction(kind, pairing, loop.A, loop.B, loop.C, ki, gain_sign=sign)
        prob = Problem(case, loop, names, lower, upper, objective=self.objective,
                       constraints=self.constraints, settling_band=self.settling_band,
                       scenarios=self.scenarios, tuning_scenario=self.tuning_scenario,
                       weights=self.weights, structure_warning=warning)
        prob.baselines = dict(self.baselines.get(case, {}))
        prob.robust = self.robust
        if self.objective_names is not None:
            prob.set_objectives(self.objective_names, self.reference_point, self.decision_weights)
        return prob

    def write_outputs(self, out_dir, *, runs, history, best, figures: bool = True) -> None:
        """With ``[report] thesis_chapter``: the chapter's tables next to the printed values
        and its figures, in ``out_dir/tables/`` (:func:`heurtune.objectives.qtp.thesis.tables.write_chapter`)."""
        chapter = self.config.get("report", {}).get("thesis_chapter")
        if chapter is not None:
            write_chapter(chapter, self, out_dir, runs=runs, history=history, figures=figures)
