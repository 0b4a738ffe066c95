"""The conical-tanks plant family (experiments/plugins/conical_tanks.py): physics, kernel, contract.

The kernel is checked against scipy's Radau integrator at tight tolerances on the same
equations written out independently here, open loop and in closed loop with the same sampled
PI/PID law; the operating point against the right-hand side; the linearised stability check
against the nonlinear loop; failed candidates against the problem protocol; and the plugin end
to end through the experiment runner (load, run, resume) and the evaluate command.
"""

import io
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numerics import assert_same_bits
from scipy.integrate import solve_ivp

from heurtune.core.families import get_family
from heurtune.core.plugins import load_plugin

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "experiments" / "plugins" / "conical_tanks.py"


@pytest.fixture(scope="module")
def ct():
    """The plugin module, loaded the way a config's ``plugins`` key loads it."""
    return load_plugin(str(PLUGIN))


def experiment(ct, **over):
    """A small in-memory experiment of the family (config tables merged over a default)."""
    config = {"name": "t", "plant": {"model": "conical_tanks", "cases": ["low", "high"]},
              "controller": {"type": "pi", "baselines": ["simc"]},
              "problem": {"objective": "iae", "constraints": {"Mp": 10.0, "ts": 300.0}}}
    for key, table in over.items():
        config[key] = dict(config.get(key, {}), **table)
    return get_family("conical_tanks").cls(config)


def reference_rhs(p, a_factor=1.0):
    """dh/dt of the model written from its equations (plain square roots, no laminar zone)."""
    g = p.g

    def f(h, u):
        h1, h2 = h
        A1 = p.A0[0] + math.pi * (p.R[0] * h1 / p.H[0]) ** 2
        A2 = p.A0[1] + math.pi * (p.R[1] * h2 / p.H[1]) ** 2
        q12 = p.a12 * math.copysign(math.sqrt(2 * g * abs(h1 - h2)), h1 - h2)
        q1 = a_factor * p.a[0] * math.sqrt(2 * g * h1)
        q2 = a_factor * p.a[1] * math.sqrt(2 * g * h2)
        return [(p.k[0] * u[0] - q1 - q12) / A1, (p.k[1] * u[1] - q2 + q12) / A2]

    return f


def test_operating_point_is_stationary(ct):
    p = ct.ConicalTanksParams()
    for levels in ct.OPERATING_POINTS.values():
        for a_factor in (0.8, 1.0, 1.2):
            u = ct.operating_point(p, levels, a_factor)
            lo, hi = p.u_range
            assert np.all((u > lo) & (u < hi))
            rate = ct.plant_rhs(np.array(levels), u, p.coefficients(a_factor))
            # the balance is exact: only rounding remains (flows are ~50 cm^3/s, areas ~100 cm^2)
            assert np.max(np.abs(rate)) < 1e-12
            assert np.allclose(reference_rhs(p, a_factor)(levels, u), 0.0, atol=1e-12)


def test_open_loop_kernel_matches_radau(ct):
    """RK4 steps of the kernel against Radau (rtol = atol = 1e-11) for held pump voltages.

    RK4's global error is O(dt^4): with dt = 1 s against the fastest mode (29 s at the low
    point) it was measured at 6e-8 cm over 300 s (4e-9 cm at dt = 0.5 s, a ratio of 16: fourth
    order). The check asserts 1e-6 cm, and that halving dt cuts the error by more than 10.
    """
    p = ct.ConicalTanksParams()
    c = p.coefficients()
    levels = np.array(ct.OPERATING_POINTS["low"])
    u = ct.operating_point(p, levels) + np.array([1.5, -0.8])
    T = 300.0
    ref = solve_ivp(lambda t, h: reference_rhs(p)(h, u), (0.0, T), levels, method="Radau",
                    rtol=1e-11, atol=1e-11, t_eval=np.arange(0.0, T + 0.5, 10.0))
    errs = []
    for dt in (1.0, 0.5):
        h = levels.copy()
        out = [h]
        per = int(round(10.0 / dt))
        for k in range(int(round(T / dt))):
            h = ct.rk4_step(h, u, c, dt)
            if (k + 1) % per == 0:
                out.append(h)
        errs.append(np.max(np.abs(np.array(out) - ref.y.T)))
    assert np.max(np.abs(ref.y[:, -1] - levels)) > 2.0  # the levels really moved
    assert errs[0] < 1e-6
    assert errs[0] / errs[1] > 10.0


@pytest.mark.parametrize("pid", [False, True])
def test_closed_loop_kernel_matches_radau(ct, pid):
    """The sampled PI(D) loop of the kernel against Radau between the same control samples.

    The reference recomputes the control law in Python at every sample from Radau's levels and
    integrates the held input to the next sample. Tolerance 1e-6 cm on levels and 1e-6 V on
    the pump voltages: RK4's O(dt^4) error at dt = 1 s on this slow operating point (modes of
    185-595 s) was measured at 2e-10 cm and 4e-10 V; the margin covers other machines'
    rounding and the Radau tolerance (1e-11), and is five orders below the 2 % band of a 5 cm
    step (0.1 cm).
    """
    p = ct.ConicalTanksParams()
    c = p.coefficients(0.8)
    levels = np.array(ct.OPERATING_POINTS["high"])
    u0 = ct.operating_point(p, levels, 0.8)
    dt, nsub, n = 1.0, 2, 1200
    Ts = dt * nsub
    r = np.tile(levels, (n + 1, 1))
    r[:, 0] += 5.0
    r[400:, 1] -= 4.0
    d = np.zeros((n + 1, 2))
    d[800:, 1] = 1.0
    gains = np.array([2.0, 0.02, 20.0 if pid else 0.0, 1.5, 0.015, 10.0 if pid else 0.0])
    Tf = np.array([5.0, 8.0])
    y = np.empty_like(r)
    u = np.empty_like(r)
    assert ct.simulate_loop(c, levels, gains, Tf, 0.0, 10.0, u0, dt, nsub, r, d, y, u) == ct.STATUS_OK

    f = reference_rhs(p, 0.8)
    h = levels.copy()
    integral = u0.copy()
    D = np.zeros(2)
    yp = levels.copy()
    kp, ki, kd = gains[[0, 3]], gains[[1, 4]], gains[[2, 5]]
    yr, ur = [], []
    saturated = 0
    for k in range(0, n, nsub):
        e = r[k] - h
        D = Tf / (Tf + Ts) * D - kd / (Tf + Ts) * (h - yp)
        yp = h.copy()
        v = kp * e + integral + D
        us = np.clip(v, 0.0, 10.0)
        saturated += int(np.any(us != v))
        w = ki * Ts * e
        hold = ((v >= 10.0) & (w > 0)) | ((v <= 0.0) & (w < 0))
        integral = np.where(hold, integral, integral + w)
        yr.append(h.copy())
        ur.append(us.copy())
        q = us + d[k]
        sol = solve_ivp(lambda t, x: f(x, q), (0.0, Ts), h, method="Radau", rtol=1e-11, atol=1e-11)  # noqa: B023 - called within this iteration
        h = sol.y[:, -1]
        assert h[0] - h[1] > 0.1  # the plain square roots of the reference stay valid
    yr, ur = np.array(yr), np.array(ur)
    assert saturated > 0  # the anti-windup path was exercised
    assert np.max(np.abs(y[::nsub][: len(yr)] - yr)) < 1e-6
    assert np.max(np.abs(u[::nsub][: len(ur)] - ur)) < 1e-6
    assert abs(y[-1, 0] - r[-1, 0]) < 0.05 and abs(y[-1, 1] - r[-1, 1]) < 0.05  # it tracks


def test_metrics_of_a_known_response(ct):
    """Hand-built arrays: a first-order rise with a 10 % overshoot bump."""
    dt, n = 1.0, 200
    t = np.arange(n + 1) * dt
    r = np.zeros((n + 1, 2))
    r[:, 0] = 2.0
    y = np.zeros((n + 1, 2))
    y[:, 0] = 2.0 * (1 - np.exp(-t / 10.0))
    y[30, 0] = 2.2  # one sample 10 % above
    u = np.full((n + 1, 2), 3.0)
    u[5, 1] = -7.0
    steps = np.array([[0.0, 0.0, n + 1, 2.0]])
    out = np.empty(ct.N_METRICS)
    ct.loop_metrics(r, y, u, dt, steps, 0.02, out)
    m = dict(zip(ct.METRIC_NAMES, out))
    assert m["Mp1"] == pytest.approx(10.0)
    assert m["ts1"] == pytest.approx(40.0)  # 2 e^(-t/10) <= 0.04 from t = 39.1: sample 40
    e = r[:, 0] - y[:, 0]  # the set-point is constant: the kernel's rule is the trapezoid rule
    assert m["IAE1"] == pytest.approx(np.trapezoid(np.abs(e), t), rel=1e-12)
    assert m["ISE1"] == pytest.approx(np.trapezoid(e * e, t), rel=1e-12)
    assert m["ITAE1"] == pytest.approx(np.trapezoid(t * np.abs(e), t), rel=1e-12)
    assert m["IAE1"] == pytest.approx(20.0, abs=0.15)  # 2 * tau, plus the bump and O(dt^2)
    assert m["hmax1"] == 2.2 and m["umax1"] == 3.0  # exact: maxima and sums of the literals above
    assert m["umax2"] == 7.0 and m["IAE2"] == 0.0 and m["Mp2"] == 0.0 and m["ts2"] == 0.0


def test_bad_candidates_are_finite_infeasible_and_explained(ct):
    prob = experiment(ct).problem("low")
    X = np.array([[1e9, 1e9, 1e9, 1e9],       # huge: the sampled loop is unstable
                  [-1.0, 0.01, 2.0, 0.01],    # negative gain
                  [np.nan, 0.01, 2.0, 0.01],  # not a number
                  [2.0, np.inf, 2.0, 0.01],
                  [2.0, 0.05, 2.0, 0.05]])    # a good one, for contrast
    ev = prob.evaluate(X)
    assert ev.f.shape == (5,) and ev.g.shape == (5, 4) and ev.metrics.shape == (5, len(ct.METRIC_NAMES))
    assert np.all(np.isfinite(ev.f)) and np.all(np.isfinite(ev.g))
    assert list(ev.reason) == ["unstable", "invalid_parameter", "invalid_parameter", "invalid_parameter", ""]
    assert not ev.feasible[:4].any() and ev.feasible[4]
    assert np.all(ev.f[:4] == ct.FAILED_OBJECTIVE) and np.all(ev.g[:4] >= ct.FAILED_VIOLATION)
    assert np.isnan(ev.metrics[:4]).all() and np.isfinite(ev.metrics[4]).all()
    # the protocol's (f, g) form, and a diverging simulation is flagged, not raised
    f, g = prob(X)
    assert_same_bits(f, ev.f, because="same code")  # prob(X) is evaluate(X)
    assert_same_bits(g, ev.g, because="same code")
    df = prob.simulate([np.nan, 0.01, 2.0, 0.01])
    assert df.attrs["status"] == "diverged" and df["y1"].isna().all()


def test_stability_check_agrees_with_the_nonlinear_loop(ct):
    """Kp2 = 2 / (B22 Ts) (about 10.1 V/cm at the low point) is where the sampled loop 2 loses
    stability; just above, the nonlinear loop falls into a pump-saturating limit cycle."""
    prob = experiment(ct, controller={"bounds": {"Kp": [0.0, 20.0]}}).problem("low")
    sc = ct.TankScenario(name="probe", horizon=800.0, dt=1.0, steps1=(), steps2=((0.0, 1e-3),), disturbance=None)
    for kp2, unstable in ((9.5, False), (10.5, True)):
        x = np.array([2.0, 0.02, kp2, 0.02])
        assert (prob.spectral_radius(x[None, :])[0] > 1.0) == unstable
        assert (prob.evaluate(x[None, :]).reason[0] == "unstable") == unstable
        tail = prob.simulate(x, sc).iloc[-100:]
        swing = tail["u2"].max() - tail["u2"].min()
        assert (swing > 1.0) if unstable else (swing < 1e-6)


def test_configs_are_checked_with_one_line_errors(ct):
    from heurtune import ConfigError

    for over, match in (
        ({"plant": {"cases": ["medium"]}}, r"plant.cases: unknown operating point 'medium'; allowed: low, mid, high"),
        ({"plant": {"levels": {"top": [80.0, 30.0]}, "cases": ["top"]}}, r"plant.levels.top: levels"),
        ({"plant": {"levels": {"hungry": [60.0, 5.0]}, "cases": ["hungry"]}}, r"outside plant.u_range"),
        ({"controller": {"Ts": 1.5}}, r"controller.Ts \(1.5 s\) must be a whole number of scenario.dt"),
        ({"problem": {"constraints": {"ts": 700.0}}}, r"problem.constraints.ts \(700 s\) must be shorter"),
        ({"problem": {"tuning_scenario": "worst"}}, r"tuning_scenario 'worst'; allowed: nominal, -20%, \+20%"),
        ({"scenario": {"steps1": [[0.5, 5.0]], "dt": 1.0}},
         r"scenario.steps1: time 0.5 must lie in \[0, horizon\) on the dt grid"),
        ({"scenario": {"steps2": [[0.0, 45.0]]}}, r"scenario.steps2: the step of 45 cm"),
    ):
        with pytest.raises(ConfigError, match=match) as info:
            experiment(ct, **over)
        assert "\n" not in str(info.value) and str(info.value).startswith("t: ")


@pytest.mark.long  # 9 s on the EPYC: `make test` runs the family contract on the plugin (test_family_contract)
def test_plugin_end_to_end_resume_and_evaluate(ct, tmp_path):
    from heurtune.runner.evaluate import run as evaluate
    from heurtune.runner.experiment import run_experiment

    out = tmp_path / "exp"
    log = io.StringIO()
    run_experiment("example_plugin_plant", smoke=True, out=out, jobs=1, progress_stream=log)
    runs = pd.read_parquet(out / "runs.parquet")
    assert set(runs["case"]) == {"low", "high"} and set(runs["algorithm"]) == {"cs", "pso", "simc"}
    assert np.isfinite(runs["best_f"]).all() and (runs["status"] != "failed").all()
    assert {"f@-20%", "Mp1@+20%", "ts2@nominal"} <= set(runs.columns)
    parts = {p.name: p.stat().st_mtime_ns for p in (out / "parts").iterdir()}
    assert "runs to do" in log.getvalue()
    # the same command again: everything is done, nothing is rerun
    log2 = io.StringIO()
    run_experiment("example_plugin_plant", smoke=True, out=out, jobs=1, progress_stream=log2)
    assert "runs to do" not in log2.getvalue()
    assert {p.name: p.stat().st_mtime_ns for p in (out / "parts").iterdir()} == parts
    assert_same_bits(pd.read_parquet(out / "runs.parquet"), runs, because="resume")  # wall times read back too
    # the evaluate command on the best design of a case
    best = runs[runs["case"] == "high"].sort_values("best_f").iloc[0]
    x = ",".join(f"{k}={float(best[k])!r}" for k in ("Kp1", "Ki1", "Kp2", "Ki2"))
    assert evaluate(["example_plugin_plant", "--case", "high", "--x", x, "--out", str(tmp_path / "traj.parquet")]) == 0
    traj = pd.read_parquet(tmp_path / "traj.parquet")
    assert {"t", "r1", "r2", "y1", "y2", "u1", "u2"} <= set(traj.columns)
    # figures and the statistics of the finished experiment
    assert {"convergence_low.png", "responses_high.png", "boxplot_best_f.png"} <= {p.name for p in out.iterdir()}
    from heurtune.analysis.compare import run as compare

    assert compare([str(out)]) == 0
