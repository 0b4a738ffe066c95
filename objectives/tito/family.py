"""The TITO family: decentralised PI/PID of two-input two-output coupled tanks with dead time.

``[plant] model = "tito"`` (transfer-function plants: the presets of papers 000-002 or
``plant.custom`` tables) or ``"two_tank_nonlinear"`` (the nonlinear two-tank rig of paper 002,
tuned on its identified linear model and simulated nonlinear). Each case gets its design chain
(decoupler, FOPDT fits, GPM baseline) and a :class:`heurtune.objectives.tito.problem.TITOProblem`.
"""

from __future__ import annotations

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.core.families import register_family
from heurtune.core.problem import ExperimentBase
from heurtune.core.robust import ROBUST_SCHEMA, robust_tuning
from heurtune.core.schema import COMMON_SCHEMA, MULTI_OBJECTIVE_SCHEMA, NUMBER, PAIR
from heurtune.objectives.tito import model as tito
from heurtune.objectives.tito import report, two_tank
from heurtune.objectives.tito.continuous import DEFAULT_TOLERANCE, check_continuous_plant
from heurtune.objectives.tito.problem import (
    DEFAULT_GPM,
    MULTI_OBJECTIVES,
    OBJECTIVES,
    DesignChain,
    TITOProblem,
    default_bounds,
    fopdt_fit,
    gain_names,
)
from heurtune.objectives.tito.sim import LOOPS, TITOScenario

__all__ = ["TITOExperiment", "SCHEMA", "MODELS"]

MODELS = ("tito", "two_tank_nonlinear")
DEFAULT_BANDWIDTH_CONSTRAINTS = {"Am": 3.0, "phim": 60.0, "Mt": 1.3}
DEFAULT_VARIATION = {"nominal": 0.0, "-20%": -0.2, "+20%": 0.2}

STEPS = ("list", ("list", PAIR))  # per loop, [[time, value], ...]

SCHEMA = dict(COMMON_SCHEMA, **{
    "plant": {
        "model": MODELS,
        "cases": ("list", str),
        # TITO: {g11 = {K, lags, leads, L}, ...}; two_tank_nonlinear: TwoTankParams fields.
        # Validated by the plant constructors, which name the key.
        "custom": ("map", ("map", None)),
    },
    "decoupler": {"type": ("inverted", "none"), "case": int, "delay_compensation": bool},
    "controller": {
        "type": ("choices", ("pi", "pid")),
        "N": NUMBER,
        "baselines": ("list", ("gpm",)),
        "gpm": {"Am": NUMBER, "phim": NUMBER},
    },
    "scenario": {
        "horizon": NUMBER, "dt": NUMBER,
        "setpoints": STEPS,
        "input_disturbance": {"time": NUMBER, "size": PAIR},
        "output_disturbance": {"time": NUMBER, "size": PAIR},
        "noise_power": NUMBER, "noise_seed": int,
        # Noise on the plant inputs (after the decoupler), per loop: a number or [P1, P2].
        "input_noise_power": ("oneof", (NUMBER, PAIR)), "input_noise_seed": int,
        "variation": ("map", NUMBER),
        "vary": ("list", ("K", "lags", "leads", "L")),
        "loop": LOOPS,
        # the loop: sample_time = the sampled loop's step; tolerance = the continuous loop's
        # error on the outputs (docs/tito.md, "Which loop")
        "sample_time": NUMBER, "tolerance": NUMBER,
        # the sampled loop with derivative filters shorter than 10 dt (sim.check_sampling)
        "allow_coarse_sampling": bool,
    },
    "problem": {
        "objective": OBJECTIVES,
        "tuning_scenario": str,
        **ROBUST_SCHEMA,
        **MULTI_OBJECTIVE_SCHEMA,
        "settling_band": NUMBER,
        "windows": ("map", PAIR),
        "constraints": {"Am": NUMBER, "phim": NUMBER, "Mt": NUMBER, "Ms": NUMBER},
        "bounds": ("map", PAIR),
    },
    "robustness": {"uncertainty": NUMBER, "variation": NUMBER, "pade_order": int, "w": PAIR},
    # paper = "000", "001" or "002": write that paper's tables next to the printed values.
    # sweep = {param, values, max_evals, implied_margins}: the response family of a design parameter
    # (heurtune.objectives.tito.sweep), written beside the results.
    "report": {"paper": ("000", "001", "002"),
               "sweep": {"param": str, "values": ("list", NUMBER), "max_evals": int, "implied_margins": bool}},
})


@register_family(
    "tito",
    models=MODELS,
    schema=SCHEMA,
    description="two-input two-output coupled tanks with dead time (papers 000-002) under decentralised PI/PID",
)
class TITOExperiment(ExperimentBase):
    """A named TITO experiment config (``[plant] model = "tito"`` or ``"two_tank_nonlinear"``).

    Use :func:`heurtune.load_experiment`, which picks this class from the config's plant model.
    """

    def __init__(self, config: dict):
        self.config = config
        self.name = config["name"]
        plant = config.get("plant", {})
        self.model = plant.get("model", "tito")
        cases = tuple(plant.get("cases", []))
        if not cases:
            raise ConfigError(f"{self.name}: plant.cases must name at least one plant "
                              f"(presets: {', '.join(tito.PRESETS)}, or plant.custom.<name>)")
        self._custom = plant.get("custom", {})
        ctrl = config.get("controller", {})
        self._set_cases(cases, ctrl.get("type", "pi"))
        self.N = float(ctrl.get("N", 100.0))
        if not self.N > 0:
            raise ConfigError(f"{self.name}: controller.N must be > 0, got {self.N}")
        self.baselines = tuple(ctrl.get("baselines", []))
        self.gpm = {**DEFAULT_GPM, **ctrl.get("gpm", {})}
        dec = config.get("decoupler", {})
        self.decoupler_type = dec.get("type", "inverted")
        self.decoupler_case = dec.get("case", 1)
        if self.decoupler_case not in (1, 2):
            raise ConfigError(f"{self.name}: decoupler.case must be 1 or 2, got {self.decoupler_case}")
        self.delay_compensation = dec.get("delay_compensation", False)
        self.scenarios = self._scenarios(config.get("scenario", {}))
        prob = config.get("problem", {})
        self.objective = prob.get("objective", "iae")
        self._objectives(prob, MULTI_OBJECTIVES)
        if self.objective_names is not None:
            first = self.objective_names[0]
            if first not in OBJECTIVES or ("objective" in prob and prob["objective"] != first):
                raise ConfigError(f"{self.name}: the first of problem.objectives is the problem's objective: one of "
                                  f"{', '.join(OBJECTIVES)}, equal to problem.objective if given")
            self.objective = first
        default_c = DEFAULT_BANDWIDTH_CONSTRAINTS if self.objective == "bandwidth" else {}
        self.constraints = self._positive_limits(prob.get("constraints", default_c))
        if self.objective == "bandwidth":
            for key in ("Am", "phim", "Mt"):
                self.constraints.setdefault(key, DEFAULT_BANDWIDTH_CONSTRAINTS[key])
        if not self.constraints:
            # A tuning problem needs one constraint: the sensitivity peak, loose by default.
            self.constraints = {"Ms": 5.0}
        self.tuning_scenario = self._tuning_scenario(prob)
        self.robust = robust_tuning(prob, self.scenarios, self.name)
        self.settling_band = float(self._settling_band(prob, 2.0))
        nominal = self.scenarios["nominal"]
        t_in = nominal.input_disturbance[0]
        default_windows = ({"servo": (0.0, t_in), "regulatory": (t_in, nominal.horizon)}
                           if 0 < t_in < nominal.horizon else {})
        self.windows = {k: tuple(v) for k, v in prob.get("windows", default_windows).items()}
        self.bounds_config = prob.get("bounds", {})
        self.robustness = dict(config.get("robustness", {}))
        sweep = config.get("report", {}).get("sweep")
        if sweep is not None:  # checked now, not after the runs
            from heurtune.objectives.tito.sweep import check_sweep

            try:
                check_sweep(sweep.get("param", ""), sweep.get("values", ()))
            except ConfigError as exc:
                raise ConfigError(f"{self.name}: report.sweep: {exc}") from None
        self._load_optimisers(config)
        self._check_multi_objective_optimisers()
        if not self.optimisers and not self.baselines:
            raise ConfigError(f"{self.name}: give [[optimisers]] or controller.baselines (e.g. [\"gpm\"])")
        self._chains = {}
        self._grid_cache = {}  # the problems' frequency grids (TITOProblem._shared_design_grid)
        for case in cases:
            self._chain(case)  # validate plants and decouplers early

    @staticmethod
    def suite_instance(case: str, instance: int, seed: int, perturbation: dict) -> dict:
        """Instance ``instance`` of preset ``case`` for the tuning suite, as ``plant.custom`` takes
        it (:func:`heurtune.objectives.tito.instances.instance_plant`)."""
        from heurtune.objectives.tito.instances import instance_plant

        return instance_plant(case, instance, seed, perturbation)

    def baseline_names(self, case: str) -> tuple:
        """Names of the analytic designs (``controller.baselines``) run for ``case``: all of them,
        except the GPM design of a case with a loop that no FOPDT model fits (it has none; the
        case's ``design.parquet`` says why)."""
        chain, _ = self._chain(self._variant(case)[0])
        return tuple(b for b in self.baselines if b != "gpm" or all(c is not None for c in chain.gpm))

    def __repr__(self):
        return f"TITOExperiment({self.name!r}, cases={self.cases}, controllers={self.controllers})"

    def _scenarios(self, sc: dict) -> dict:
        kw = {}
        for key in ("horizon", "dt", "noise_power", "noise_seed", "input_noise_power", "input_noise_seed", "loop",
                    "allow_coarse_sampling", "tolerance"):
            if key in sc:
                kw[key] = tuple(sc[key]) if isinstance(sc[key], list) else sc[key]
        kw.update(self._loop_choice(sc))
        power = kw.get("input_noise_power", 0.0)
        if self.model == "two_tank_nonlinear" and kw.get("loop", "sampled") != "sampled":
            raise ConfigError(f"{self.name}: scenario.loop: the nonlinear two-tank simulator is sampled; allowed with "
                              f"plant.model = 'tito' only ('sampled' or leave it out here)")
        if self.model == "two_tank_nonlinear" and any(p != 0 for p in np.atleast_1d(power)):
            raise ConfigError(f"{self.name}: scenario.input_noise_power: the nonlinear two-tank simulator has no "
                              f"input noise; allowed with plant.model = 'tito' only (0 or leave it out here)")
        if "setpoints" in sc:
            if len(sc["setpoints"]) != 2:
                raise ConfigError(f"{self.name}: scenario.setpoints must hold two lists (one per loop)")
            kw["setpoints"] = tuple(tuple(tuple(p) for p in loop) for loop in sc["setpoints"])
        for key in ("input_disturbance", "output_disturbance"):
            if key in sc:
                d = sc[key]
                kw[key] = (d.get("time", 0.0), tuple(d.get("size", (0.0, 0.0))))
        if "vary" in sc:
            kw["vary"] = tuple(sc["vary"])
        variation = dict(sc.get("variation", DEFAULT_VARIATION))
        if "nominal" not in variation:
            variation = {"nominal": 0.0, **variation}
        try:
            return {k: TITOScenario(**kw, variation=float(v)) for k, v in variation.items()}
        except ConfigError as exc:
            raise ConfigError(f"{self.name}: {exc}") from None

    def _loop_choice(self, sc: dict) -> dict:
        """The scenario keys that choose the loop (docs/tito.md, "Which loop"):

        - ``sample_time``: the sampled loop at that step (``dt`` alone, the older spelling, too);
        - ``tolerance``: the continuous loop, each run's step chosen to that tolerance;
        - ``loop = "continuous"`` with ``dt``: the continuous loop on the fixed step ``dt``;
        - none of them: the continuous loop to ``DEFAULT_TOLERANCE`` (the sampled loop for the
          nonlinear two-tank rig, whose simulator has no other).
        """
        where = f"{self.name}: scenario"
        loop = sc.get("loop")
        if "sample_time" in sc:
            if "dt" in sc:
                raise ConfigError(f"{where}.sample_time: give sample_time or dt, not both (dt is its older spelling)")
            if "tolerance" in sc or loop == "continuous":
                raise ConfigError(f"{where}.sample_time: sample_time sets the sampled loop; the continuous loop takes "
                                  "tolerance (give one of them)")
            return {"loop": "sampled", "dt": sc["sample_time"]}
        if "tolerance" in sc:
            if loop == "sampled":
                raise ConfigError(f"{where}.tolerance: tolerance sets the continuous loop; the sampled loop takes "
                                  "sample_time (give one of them)")
            if self.model == "two_tank_nonlinear":
                raise ConfigError(f"{where}.tolerance: the nonlinear two-tank simulator is sampled; allowed with "
                                  "plant.model = 'tito' only (use sample_time here)")
            return {"loop": "continuous"}
        if loop is None and "dt" not in sc and self.model != "two_tank_nonlinear":
            return {"loop": "continuous", "tolerance": DEFAULT_TOLERANCE}
        if loop == "continuous" and "dt" not in sc:
            return {"tolerance": DEFAULT_TOLERANCE}
        return {}

    def _plant(self, case: str):
        """``(TITOPlant, TwoTankParams or None)`` of a plant case."""
        where = f"{self.name}: plant.custom.{case}"
        if self.model == "two_tank_nonlinear":
            cfg = self._custom.get(case)
            if cfg is None:
                if case not in ("rig", "default"):
                    raise ConfigError(f"{self.name}: plant.cases: {case!r} is not defined; use 'rig' (the "
                                      f"calibrated default) or define plant.custom.{case}")
                params = two_tank.TwoTankParams()
            else:
                try:
                    params = two_tank.from_config(dict(cfg, name=cfg.get("name", case)))
                except ConfigError as exc:
                    raise ConfigError(f"{where}: {exc}") from None
            return two_tank.linear_tito_plant(params, name=case), params
        if case in self._custom:
            try:
                return tito.TITOPlant.from_config(dict(self._custom[case], name=case)), None
            except ConfigError as exc:
                raise ConfigError(f"{where}: {exc}") from None
        try:
            return tito.preset(case), None
        except ConfigError as exc:
            raise ConfigError(f"{self.name}: plant.cases: {exc} (or define plant.custom.{case})") from None

    def _chain(self, case: str) -> tuple:
        if case in self._chains:
            return self._chains[case]
        plant, params = self._plant(case)
        dec = None
        if self.decoupler_type == "inverted":
            try:
                dec = tito.inverted_decoupler(plant, delay_compensation=self.delay_compensation,
                                              case=self.decoupler_case)
            except ConfigError as exc:
                raise ConfigError(f"{self.name}: decoupler for {case!r}: {exc}") from None
        els = [plant.element(1, 1).freqresp, plant.element(2, 2).freqresp] if dec is None else [dec.z11, dec.z22]
        fits = [fopdt_fit(el, f"loop {i}") for i, el in enumerate(els, start=1)]
        gpm, gpm_m = [], []
        for i, (fo, _) in enumerate(fits):
            if fo is None:
                gpm.append(None)
                gpm_m.append(None)
                continue
            try:
                Kc, Ti = tito.gpm_pi(fo, self.gpm["Am"], self.gpm["phim"])
                c = tito.PIController(Kc, Ti)
                gpm.append(c)
                gpm_m.append(tito.exact_margins(els[i], c.freqresp))
            except ConfigError as exc:
                fits[i] = (fo, f"loop {i + 1}: GPM: {exc}")
                gpm.append(None)
                gpm_m.append(None)
        chain = DesignChain(plant, dec, tuple(f[0] for f in fits), tuple(f[1] for f in fits), tuple(gpm), tuple(gpm_m))
        self._chains[case] = (chain, params)
        return self._chains[case]

    def problem(self, case: str) -> TITOProblem:
        """The tuning problem of one case."""
        plant_case, kind = self._variant(case)
        chain, params = self._chain(plant_case)
        gpm_x = None
        if all(c is not None for c in chain.gpm):
            gpm_x = np.array([v for c in chain.gpm for v in c.parallel()[:2]])
        signs = [float(np.real(chain.element(i)(np.array([1e-9]))[0])) for i in (1, 2)]
        bounds = default_bounds(kind, gpm_x, signs)
        bounds = self._override_bounds(bounds, self.bounds_config, set(gain_names("pid")), gain_names(kind))
        if params is None and any(sc.loop == "continuous" for sc in self.scenarios.values()):
            try:
                check_continuous_plant(chain.plant)
            except ConfigError as exc:
                raise ConfigError(f"{self.name}: case {case!r}: {exc}; scenario.sample_time = X runs the sampled "
                                  f"loop, which takes it") from None
        prob = TITOProblem(case, kind, chain, bounds, objective=self.objective, constraints=self.constraints,
                           scenarios=self.scenarios, tuning_scenario=self.tuning_scenario, N=self.N,
                           windows=self.windows, settling_band=self.settling_band, nonlinear=params,
                           robustness=self.robustness, gpm_spec=self.gpm, grid_cache=self._grid_cache)
        prob.robust = self.robust
        if self.objective_names is not None:
            prob.set_objectives(self.objective_names, self.reference_point, self.decision_weights)
        return prob

    def write_outputs(self, out_dir, *, runs, history, best, figures: bool = True) -> None:
        """``design.parquet``, ``robustness.parquet``, ``performance.{parquet,md}`` and the
        spectral-radius figures of the best designs (:func:`heurtune.objectives.tito.report.write_outputs`);
        with ``[report] paper``, that paper's tables and figures in ``out_dir/tables/``
        (:func:`heurtune.objectives.tito.papers.tables.write_paper`)."""
        report.write_outputs(self, runs, best, out_dir, figures=figures)
        rep = self.config.get("report", {})
        if "sweep" in rep:  # the response family of a design parameter
            from heurtune.objectives.tito.sweep import DEFAULT_MAX_EVALS, SMOKE_BUDGET, run_sweep

            sw = rep["sweep"]
            budget = dict(max_evals=sw.get("max_evals", DEFAULT_MAX_EVALS))
            if self.smoke:  # a --smoke run's sweep is a check of the code, as its runs are
                budget = dict(SMOKE_BUDGET, max_evals=min(budget["max_evals"], SMOKE_BUDGET["max_evals"]))
            run_sweep(self, sw.get("param", ""), sw.get("values", ()), out_dir, figures=figures,
                      implied_margins=sw.get("implied_margins", False), **budget)
        if rep.get("paper") is not None:  # the paper's tables next to the printed values
            from heurtune.objectives.tito.papers.tables import write_paper

            write_paper(rep["paper"], self, out_dir, runs=runs, figures=figures)
