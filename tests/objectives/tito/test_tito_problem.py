"""TITO tuning problems and experiments (heurtune.objectives.tito.problem, heurtune.objectives.tito.report).

Numbers are checked against independent computations: the objective against the TITO
simulator's own record and numpy's trapezoid rule, the bandwidth and margins against a dense
grid with brentq, the stability verdicts against the closed-loop poles of a python-control model
with high-order Pade delays.
"""

import math

import control
import numpy as np
import pandas as pd
import pytest
from numerics import assert_same_bits
from scipy.optimize import brentq

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.core.problem import FAILED_OBJECTIVE
from heurtune.objectives.tito import model as tito
from heurtune.objectives.tito.sim import loop_metrics, simulate_tito
from heurtune.runner.experiment import run


@pytest.fixture(scope="module")
def ccts():
    return heurtune.load_experiment("ga_pi_ccts").problem("ccts")


def write_config(tmp_path, text, name="exp.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


BANDWIDTH = """
extends = "ga_pi_ccts"
[problem]
objective = "bandwidth"
[problem.constraints]
Am = 2.0
phim = 45.0
Mt = 1.3
"""


def test_problem_interface_and_gpm_chain(ccts):
    assert ccts.names == ("Kp1", "Ki1", "Kp2", "Ki2")
    assert ccts.constraint_names == ("Ms1", "Ms2")
    assert set(ccts.scenarios) == {"nominal", "-10%", "+10%", "-20%", "+20%", "-30%", "+30%"}
    design = ccts.design_table()
    # The FOPDT fits by their defining equations (DC gain, and the response at the element's
    # phase crossover); then the GPM design's exact margins near the specification (the
    # arctan approximation and the fit's error on the true loop: 2 % and 7 deg).
    for i in (1, 2):
        z = ccts.chain.element(i)
        fit = ccts.chain.fopdt[i - 1]
        assert fit.K == pytest.approx(z(np.array([1e-12]))[0].real, rel=1e-9)
        row = design.iloc[i - 1]
        assert row["Am_exact"] == pytest.approx(3.0, rel=0.02)
        assert abs(row["phim_exact"] - 60.0) < 7.0
    x = ccts.baseline("gpm")
    assert ccts.lower.min() == 0.0 and np.all(ccts.upper > x)


def test_time_objective_equals_the_simulators_record(tmp_path):
    """On the sampled loop, f = IAE1 + IAE2 over the whole tuning scenario, against
    simulate_tito and its own (pandas / numpy.trapezoid) metrics: same samples, so agreement
    to rounding. (The continuous loop's quadrature: test_continuous_tito.py.)"""
    ccts = heurtune.load_experiment(write_config(tmp_path, 'extends = "ga_pi_ccts"\n[scenario]\nsample_time = 0.5\n')
                                    ).problem("ccts")
    x = ccts.baseline("gpm") * np.array([1.2, 0.8, 0.9, 1.1])
    ev = ccts.evaluate(x)
    assert ev.reason[0] == "" and ev.feasible[0]
    sc = ccts.scenario("nominal")
    df = simulate_tito(ccts.chain.plant, ccts.controllers(x), ccts.chain.decoupler, sc)
    ref = loop_metrics(df, {"all": (0.0, sc.horizon), "servo": (0.0, 500.0)})
    assert ev.f[0] == pytest.approx(ref["IAE_all"].sum(), rel=1e-10)
    m = dict(zip(ev.metric_names, ev.metrics[0]))
    for i in (1, 2):
        assert m[f"ISE{i}"] == pytest.approx(ref.loc[i, "ISE_all"], rel=1e-10)
        assert m[f"IAE_servo{i}"] == pytest.approx(ref.loc[i, "IAE_servo"], rel=1e-10)
        assert m[f"ITAE_servo{i}"] == pytest.approx(ref.loc[i, "ITAE_servo"], rel=1e-10)
        # same bits: same code (the simulator's kernel on the same inputs both ways; a settling
        # time is a sample time picked by the same threshold, where the integrals above are sums
        # written differently)
        assert m[f"ts_servo{i}"] == ref.loc[i, "ts_servo"] and m[f"ts{i}"] == ref.loc[i, "ts_all"]


def test_bandwidth_objective_against_a_dense_grid(tmp_path):
    prob = heurtune.load_experiment(write_config(tmp_path, BANDWIDTH)).problem("ccts")
    assert prob.objective == "bandwidth"
    x = prob.baseline("gpm") * np.array([1.3, 1.1, 0.9, 1.2])
    ev = prob.evaluate(x)
    assert ev.reason[0] == ""
    m = dict(zip(ev.metric_names, ev.metrics[0]))
    total = 0.0
    for i, c in enumerate(prob.controllers(x), start=1):
        z = prob.chain.element(i)

        def T(w, z=z, c=c):
            L = z(np.atleast_1d(w)) * c.freqresp(np.atleast_1d(w))
            return np.abs(L / (1 + L))[0]

        w = np.geomspace(1e-5, 10, 200001)
        L = z(w) * c.freqresp(w)
        Tw = np.abs(L / (1 + L))
        k = int(np.flatnonzero(Tw < 1 / math.sqrt(2))[0])
        wb = brentq(lambda v: T(v) - 1 / math.sqrt(2), w[k - 1], w[k], xtol=1e-14)
        total += wb
        assert m[f"w_b{i}"] == pytest.approx(wb, rel=1e-4)
        assert m[f"Mt{i}"] == pytest.approx(Tw.max(), rel=1e-4)
        exact = tito.exact_margins(z, c.freqresp)
        assert m[f"Am{i}"] == pytest.approx(exact.gain_margin, rel=1e-4)
        assert m[f"phim{i}"] == pytest.approx(exact.phase_margin_deg, abs=1e-3)
        g = dict(zip(ev.constraint_names, ev.g[0]))
        assert g[f"Am{i}"] == pytest.approx(1 - m[f"Am{i}"] / 2.0)
        assert g[f"Mt{i}"] == pytest.approx(m[f"Mt{i}"] / 1.3 - 1)
    assert ev.f[0] == pytest.approx(-total, rel=1e-4)


def _pade_loop_poles(plant, ctrl, i, order=8):
    """Closed-loop poles of decoupled loop i (1 + z_ii C = 0) of an FOPDT plant, with every
    net delay of z_ii = g_ii - g_ij g_ji / g_jj replaced by a Pade approximant."""
    j = 3 - i
    gii, gij, gji, gjj = (plant.element(*ij) for ij in ((i, i), (i, j), (j, i), (j, j)))

    def rat(e):
        return control.tf([e.K], [e.lags[0], 1.0])

    def delay(L):
        num, den = control.pade(L, order)
        return control.tf(num, den)

    cross = rat(gij) * rat(gji) * control.tf([gjj.lags[0], 1.0], [gjj.K])
    z = rat(gii) * delay(gii.L) - cross * delay(gij.L + gji.L - gjj.L)
    C = control.tf([ctrl.Kp, ctrl.Ki], [1.0, 0.0])
    return control.feedback(z * C, 1).poles()


@pytest.mark.parametrize("factor, stable", [(0.5, True), (1.0, True), (2.0, True), (4.5, False), (8.0, False)])
def test_stability_verdicts_agree_with_pade_poles(ccts, factor, stable):
    """Scaling the GPM design (gain margins 3.0) across the stability boundary."""
    x = ccts.baseline("gpm") * np.array([factor, factor, factor, factor])
    ev = ccts.evaluate(x)
    poles_stable = all(np.max(_pade_loop_poles(ccts.chain.plant, c, i).real) < 0
                       for i, c in enumerate(ccts.controllers(x), start=1))
    assert poles_stable == stable
    assert (ev.reason[0] != "unstable") == stable
    if not stable:
        assert not ev.feasible[0] and ev.f[0] == FAILED_OBJECTIVE and np.all(np.isfinite(ev.g))


def test_absurd_candidates_never_raise(ccts):
    X = np.array([
        [np.nan, 1.0, 1.0, 0.01],
        [np.inf, 0.0, 0.0, 0.0],
        [1e12, 1e12, 1e12, 1e12],
        [-5.0, -0.1, 3.0, 0.01],
        [0.0, 0.0, 0.0, 0.0],
    ])
    ev = ccts.evaluate(X)
    assert list(ev.reason[:2]) == ["invalid_parameter", "invalid_parameter"]
    assert ev.reason[2] == "unstable" and ev.reason[3] == "unstable"
    assert np.all(np.isfinite(ev.f)) and np.all(np.isfinite(ev.g))
    assert not ev.feasible[:4].any()
    with pytest.raises(ConfigError, match="shape"):
        ccts.evaluate(np.zeros((2, 3)))


def test_no_decoupler_uses_the_mimo_nyquist_criterion(tmp_path):
    prob = heurtune.load_experiment(write_config(tmp_path, 'extends = "ga_pi_ccts"\n[decoupler]\ntype = "none"\n')
                                    ).problem("ccts")
    assert prob.chain.decoupler is None
    x = prob.baseline("gpm")
    ev = prob.evaluate(np.vstack([x, 6 * x]))
    assert list(ev.reason) == ["", "unstable"]


def test_robustness_report_of_the_gpm_design(ccts):
    summary, sr = ccts.robustness(ccts.baseline("gpm"))
    assert summary["spectral_radius_pass"] and summary["rho_input_peak"] < 1
    assert summary["kharitonov_pass1"] and summary["kharitonov_pass2"]
    assert sr.rho_input.shape == sr.w.shape


@pytest.mark.parametrize(
    "text, message",
    [
        (
            '[plant]\nmodel = "tito"\ncases = ["ccts"]\n[controller]\ntype = "pi"\nbaselines = ["gpm"]\n'
            '[decoupler]\ncase = 3\n',
            "decoupler.case must be 1 or 2",
        ),
        (
            '[plant]\nmodel = "tito"\ncases = ["nope"]\n[controller]\nbaselines = ["gpm"]\n',
            "unknown TITO preset 'nope'",
        ),
        ('[plant]\nmodel = "tito"\ncases = ["ccts"]\n[controller]\ntype = "pid"\nbogus = 1\n', "unknown key 'bogus'"),
        (
            '[plant]\nmodel = "tito"\ncases = ["ccts"]\n[problem]\nobjective = "speed"\n',
            "allowed: iae, ise, itae, bandwidth",
        ),
        ('[plant]\nmodel = "tito"\ncases = ["ccts"]\n', "give [[optimisers]] or controller.baselines"),
        (
            '[plant]\nmodel = "tito"\ncases = ["r"]\n[plant.custom.r]\ng11 = { K = 1.0, lags = [10.0], L = 5.0 }\n'
            "g12 = { K = 0.5, lags = [10.0], L = 1.0 }\ng21 = { K = 0.5, lags = [10.0], L = 8.0 }\n"
            'g22 = { K = 1.0, lags = [10.0], L = 2.0 }\n[controller]\nbaselines = ["gpm"]\n',
            "non-causal",
        ),
        (
            '[plant]\nmodel = "tito"\ncases = ["r"]\n[plant.custom.r]\ng11 = { K = 1.0, lags = [10.0] }\n'
            '[controller]\nbaselines = ["gpm"]\n',
            "missing key.s. g12, g21, g22",
        ),
        (
            '[plant]\nmodel = "tito"\ncases = ["r"]\n[plant.custom.r]\ng11 = { K = 1.0, tau = [10.0] }\n'
            "g12 = { K = 0.5 }\ng21 = { K = 0.5 }\ng22 = { K = 1.0, lags = [3.0], L = 1.0 }\n"
            '[controller]\nbaselines = ["gpm"]\n',
            "g11: unknown key.s. tau; allowed: K, leads, lags, L",
        ),
    ],
)
def test_config_errors_name_the_key(tmp_path, text, message):
    with pytest.raises(ConfigError, match=message.replace("[[", r"\[\[").replace("]]", r"\]\]")):
        heurtune.load_experiment(write_config(tmp_path, text))


def test_runner_writes_tito_outputs_and_resumes(tmp_path, capsys):
    out = tmp_path / "ga"
    assert run(["ga_pi_ccts", "--smoke", "--out", str(out)]) == 0
    for name in ("runs.parquet", "history.parquet", "meta.json", "margins.parquet", "design.parquet",
                 "robustness.parquet", "performance.parquet", "performance.md", "responses_ccts.png",
                 "spectral_radius_ccts.png"):
        assert (out / name).is_file(), name
    runs = pd.read_parquet(out / "runs.parquet")
    assert sorted(runs["algorithm"]) == ["ga", "ga", "gpm"]
    gpm = runs[runs["algorithm"] == "gpm"].iloc[0]
    assert gpm["stop_reason"] == "analytic design" and gpm["n_evals"] == 1
    for col in ("IAE1@nominal", "ITAE2@+30%", "IAE_regulatory1@nominal", "Am1@nominal"):
        assert col in runs.columns
    table = (out / "performance.md").read_text()
    assert "| ccts | gpm |" in table and "| ccts | ga (best of runs) |" in table
    # the continuous loop's accuracy for each reported design: the step kept, its estimate
    assert "to tolerance 0.001 on the outputs" in table and "| ccts | gpm | 5.556 |" in table, table
    robust = pd.read_parquet(out / "robustness.parquet")
    assert set(robust["algorithm"]) == {"ga", "gpm"}
    capsys.readouterr()
    assert run(["ga_pi_ccts", "--smoke", "--out", str(out), "--no-figures"]) == 0
    assert "runs to do" not in capsys.readouterr().out  # everything was done: nothing re-run
    assert_same_bits(pd.read_parquet(out / "runs.parquet")["best_f"], runs["best_f"], because="resume")


@pytest.mark.long  # 15 s on the EPYC: `make test` has the QTP's (test_experiment) and the SQP starts'
def test_same_seed_same_results_with_two_workers(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert run(["ga_pi_ccts", "--smoke", "--no-figures", "--out", str(a)]) == 0
    assert run(["ga_pi_ccts", "--smoke", "--no-figures", "--jobs", "2", "--out", str(b)]) == 0
    ra, rb = (pd.read_parquet(p / "runs.parquet").sort_values(["algorithm", "run"]) for p in (a, b))
    assert_same_bits(ra["best_f"].to_numpy(), rb["best_f"].to_numpy(), because="workers")
    assert_same_bits(ra["Kp1"].to_numpy(), rb["Kp1"].to_numpy(), because="workers")


def test_custom_plant_through_the_chain_with_one_command(tmp_path):
    out = tmp_path / "custom"
    assert run(["example_custom_tito", "--out", str(out), "--no-figures"]) == 0
    design = pd.read_parquet(out / "design.parquet")
    assert list(design["loop"]) == [1, 2] and design["gpm_Kc"].notna().all()
    robust = pd.read_parquet(out / "robustness.parquet")
    assert robust["spectral_radius_pass"].iloc[0]
    runs = pd.read_parquet(out / "runs.parquet")
    assert runs["feasible"].all() and "IAE1@+20%" in runs.columns


def test_nonlinear_two_tank_problem():
    prob = heurtune.load_experiment("pso_pi_two_tank_nonlinear").problem("rig")
    assert prob.nonlinear is not None
    x = prob.baseline("gpm")
    ev = prob.evaluate(np.vstack([x, 50 * x]))
    assert ev.reason[0] == "" and ev.feasible[0] and ev.reason[1] == "unstable"
    df = prob.simulate(x)
    assert df.attrs["status"] == "ok" and abs(df["y1"].iloc[-1] - df["r1"].iloc[-1]) < 0.05


@pytest.mark.parametrize("name", ["gpm_pid_ccts", "optimal_pid_qts", "pso_pi_csts", "ga_pi_ccts",
                                  "pso_pi_two_tank_nonlinear", "example_custom_tito"])
def test_shipped_tito_experiments_load(name):
    exp = heurtune.load_experiment(name)
    for case in exp.cases:
        prob = exp.problem(case)
        assert prob.lower.shape == prob.upper.shape == (prob.dim,)
        assert np.all(prob.lower <= prob.upper)


def test_robustness_with_negative_gains_and_a_loop_without_fit():
    """QTS: both decoupled loops have negative static gains; loop 1 has no FOPDT fit."""
    prob = heurtune.load_experiment("optimal_pid_qts").problem("qts")
    x = np.array([-0.33, -0.0077, -1.0, -0.4, -0.0075, -1.0])
    summary, _ = prob.robustness(x)
    assert summary["kharitonov_pass1"] is None and "no FOPDT fit" in summary["kharitonov_error1"]
    assert isinstance(summary["kharitonov_pass2"], bool)
    assert summary["spectral_radius_pass"]


def test_varied_plant_is_checked_behind_the_nominal_decoupler(ccts):
    """2.5 x the GPM gains (gain margins 1.2) are stable on the nominal CCTS but not with every
    parameter 30 % larger: the verdict under that scenario comes from the generalised Nyquist
    criterion on the varied plant, and the simulation agrees (the oscillation grows)."""
    x = 2.5 * ccts.baseline("gpm")
    assert ccts.evaluate(x, "nominal").reason[0] == ""
    assert ccts.evaluate(x, "+30%").reason[0] == "unstable"
    sc = ccts.scenario("+30%")
    df = simulate_tito(ccts.chain.plant, ccts.controllers(x), ccts.chain.decoupler, sc)
    e = np.abs(df["r1"] - df["y1"]).to_numpy()
    t = df["t"].to_numpy()
    assert e[(t > 300) & (t < 450)].max() > 2 * e[(t > 100) & (t < 250)].max()


@pytest.mark.parametrize("factor, stable", [(0.5, True), (1.0, True), (2.0, True), (3.6, False), (5.0, False)])
def test_biproper_loop_verdicts_agree_with_pade_poles(factor, stable):
    """example_custom_tito's g22 is a lead-lag, so its decoupled z22 does not roll off (|z22| ->
    0.15): the Nyquist count ends on a bound of |L| beyond the grid. Loop 2's gains are scaled
    across its boundary (GPM gain margin 3.2), loop 1 stays at its GPM design; poles of
    1 + z22 C2 with Pade(8) delays in python-control decide."""
    prob = heurtune.load_experiment("example_custom_tito").problem("my_rig")
    x = prob.baseline("gpm") * np.array([1.0, 1.0, factor, factor])
    p = prob.chain.plant

    def rat(e):
        num = np.array([e.K])
        for t in e.leads:
            num = np.polymul(num, [t, 1.0])
        den = np.array([1.0])
        for t in e.lags:
            den = np.polymul(den, [t, 1.0])
        return control.tf(num, den)

    def delay(L):
        num, den = control.pade(L, 8)
        return control.tf(num, den)

    z22 = rat(p.g22) * delay(p.g22.L) - rat(p.g12) * rat(p.g21) / rat(p.g11) * delay(p.g12.L + p.g21.L - p.g11.L)
    c2 = prob.controllers(x)[1]
    poles = control.feedback(z22 * control.tf([c2.Kp, c2.Ki], [1.0, 0.0]), 1).poles()
    assert (np.max(poles.real) < 0) == stable
    assert (prob.evaluate(x).reason[0] == "") == stable


@pytest.mark.parametrize("name, case", [("example_custom_tito", "my_rig"), ("ga_pi_ccts", "ccts"),
                                        ("optimal_pid_qts", "qts")])
def test_element_magnitude_bound_holds_beyond_every_sample(name, case):
    from heurtune.objectives.tito.problem import _element_terms, _magnitude_tail

    prob = heurtune.load_experiment(name).problem(case)
    w = np.geomspace(1e-4, 1e4, 40001)
    for i in (1, 2):
        q = np.abs(prob.chain.element(i)(w))
        sup_beyond = np.maximum.accumulate(q[::-1])[::-1]
        bound = _magnitude_tail(_element_terms(prob.chain, i), w)
        assert np.all(bound >= sup_beyond * (1 - 1e-12))


def test_a_failed_design_is_not_robustly_stable_and_is_marked(tmp_path, monkeypatch):
    """A best run that failed (an unstable nominal loop) passes neither robustness test, with a
    note saying why, and its spectral-radius line is labelled failed (issue 53)."""
    from heurtune.objectives.tito import report

    out = tmp_path / "ga"
    assert run(["ga_pi_ccts", "--smoke", "--out", str(out), "--no-figures"]) == 0
    runs = pd.read_parquet(out / "runs.parquet")
    best = runs[runs["algorithm"] == "gpm"].copy()
    best["status"], best["failure"] = "failed", "unstable"
    drawn = {}
    monkeypatch.setattr(report, "spectral_radius_figure", lambda results, path, title="", **kw: drawn.update(results))
    exp = heurtune.load_experiment("ga_pi_ccts")
    report.write_outputs(exp, runs, best, out, figures=True)
    robust = pd.read_parquet(out / "robustness.parquet").iloc[0]
    assert not robust["spectral_radius_pass"] and robust["kharitonov_pass1"] is not True
    assert "run failed (unstable)" in robust["robustness_note"]
    assert list(drawn) == ["gpm (run 0), failed: unstable"]
    ok = runs[runs["algorithm"] == "gpm"].copy()  # the same design, not failed: its own verdicts
    report.write_outputs(exp, runs, ok, out, figures=False)
    assert pd.read_parquet(out / "robustness.parquet")["spectral_radius_pass"].iloc[0]
