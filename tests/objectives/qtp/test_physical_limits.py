"""Physical limits of the QTP (tank heights, pump voltage range) and the physical-range metrics."""

import dataclasses

import numpy as np
import pytest
import reference_qtp as ref
from numerics import assert_exact, assert_same_bits
from scipy.integrate import solve_ivp

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import kernels as _kernels
from heurtune.objectives.qtp.controllers import LinearController
from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario, physical_range_flags
from heurtune.objectives.qtp.model import PRESETS, QTPParams, preset

RANGE = ("hmin", "hmax", "umin", "umax")
IDX = [METRIC_NAMES.index(k) for k in RANGE]
# The best CS/FOLQI nmp design quoted in the README: it drives u2 to about -4 V.
NMP_FOLQI = dict(Q11=0.01, Q22=1.783, Q33=1.318, Q44=0.01, R11=0.1, R22=0.4171, Ki1=0.1, Ki2=10.0,
                 alpha1=0.1358, alpha2=0.1807)
THESIS_MIN = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
                  Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


def plant_kwargs(name="min", **over):
    p = preset(name)
    kw = dict(A=p.A, a=p.a, k=p.k, gamma=p.gamma, levels=p.levels, name="test")
    kw.update(over)
    return kw


# -- parameters and validation ------------------------------------------------------------

@pytest.mark.parametrize("name, height", [("P-", 20.0), ("P+", 20.0), ("min", 50.0), ("nmp", 50.0)])
def test_presets_carry_limits(name, height):
    p = preset(name)
    assert p.has_limits
    assert p.height == (height,) * 4 and p.u_range == (0.0, 10.0)
    h, u = p.physical_limits()
    assert_exact(h, [height] * 4)
    assert u == (0.0, 10.0)
    # uncertainty keeps the limits; the kernels' plant vector is unchanged
    assert p.scaled(1.3).height == p.height and p.scaled(0.7).u_range == p.u_range
    assert p.as_array().shape == (13,)


def test_limits_are_optional_and_lists_become_tuples():
    p = QTPParams(**plant_kwargs())
    assert p.height is None and p.u_range is None and not p.has_limits
    with pytest.raises(ConfigError, match=r"plant 'test': scenario.limits = 'physical' needs plant height "
                                          r"and u_range \(give plant.custom.test.height and u_range\)"):
        p.physical_limits()
    q = QTPParams(**plant_kwargs(height=[30, 30, 30, 30], u_range=[0, 12]))
    assert q.height == (30.0,) * 4 and q.u_range == (0.0, 12.0) and q.has_limits
    assert not QTPParams(**plant_kwargs(height=[30] * 4)).has_limits  # u_range missing


@pytest.mark.parametrize("over, message", [
    (dict(height=(50, 50, 50)), r"plant 'test': height must have 4 values, got 3"),
    (dict(height=(50, -1, 50, 50)), r"plant 'test': height values must lie in \(0, inf\]"),
    (dict(height=(50, 0, 50, 50)), r"plant 'test': height values must lie in \(0, inf\]"),
    (dict(height=(50, float("nan"), 50, 50)), r"height values must lie"),
    (dict(height="tall"), r"plant 'test': height must be 4 numbers"),
    (dict(u_range=(10, 0)), r"plant 'test': u_range must be finite with lo < hi, got \(10, 0\)"),
    (dict(u_range=(5, 5)), r"u_range must be finite with lo < hi"),
    (dict(u_range=(0, float("inf"))), r"u_range must be finite with lo < hi"),
    (dict(u_range=(0, 5, 10)), r"plant 'test': u_range must be two numbers"),
])
def test_limit_validation(over, message):
    with pytest.raises(ConfigError, match=message):
        QTPParams(**plant_kwargs(**over))


def test_scenario_limits_validation():
    assert Scenario(dt=0.01).limits == "none"
    assert Scenario(dt=0.01, limits="physical").limits == "physical"
    with pytest.raises(ConfigError, match=r"scenario.limits must be one of 'none', 'physical', got 'hard'"):
        Scenario(dt=0.01, limits="hard")
    with pytest.raises(ConfigError, match=r"scenario.saturation and scenario.limits = 'physical' both set "
                                          r"pump limits; give one"):
        Scenario(dt=0.01, limits="physical", saturation=(0.0, 10.0))


def test_physical_limits_need_a_plant_with_limits_that_holds_its_operating_point():
    ctrl = LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), np.zeros((2, 4)), (), ())
    sc = Scenario(dt=0.01, horizon=1.0, disturbance_time=0.5, limits="physical")
    bare = ClosedLoop(QTPParams(**plant_kwargs()), "iolqi")
    bare.run(ctrl, Scenario(dt=0.01, horizon=1.0, disturbance_time=0.5))  # fine without limits
    with pytest.raises(ConfigError, match=r"needs plant height and u_range"):
        bare.run(ctrl, sc)
    low = ClosedLoop(QTPParams(**plant_kwargs(height=(16.0, 20, 20, 20), u_range=(0, 10))), "iolqi")
    with pytest.raises(ConfigError, match=r"operating levels .* exceed the tank heights"):
        low.run(ctrl, sc)
    weak = ClosedLoop(QTPParams(**plant_kwargs(height=(50,) * 4, u_range=(0, 2))), "iolqi")
    with pytest.raises(ConfigError, match=r"operating voltages .* lie outside u_range"):
        weak.run(ctrl, sc)


def test_config_schema_and_custom_limits(tmp_path):
    path = tmp_path / "lim.toml"
    path.write_text('extends = "cs_folqi_qtp"\n[plant]\ncases = ["rig", "nmp"]\n'
                    '[plant.custom.rig]\nA = [28, 32, 28, 32]\na = [0.071, 0.057, 0.071, 0.057]\n'
                    'k = [3.33, 3.35]\ngamma = [0.7, 0.6]\nlevels = [12.4, 12.7]\n'
                    'height = [20, 20, 20, 20]\nu_range = [0, 10]\n'
                    '[scenario]\nlimits = "physical"\nhorizon = 100.0\n')
    exp = heurtune.load_experiment(str(path))
    prob = exp.problem("rig")
    assert prob.loop.plant.height == (20.0,) * 4 and prob.loop.plant.u_range == (0.0, 10.0)
    assert all(sc.limits == "physical" for sc in exp.scenarios.values())
    ev = exp.problem("nmp").evaluate(exp.problem("nmp").parse(
        ",".join(f"{k}={v}" for k, v in NMP_FOLQI.items())))
    assert ev.reason[0] == ""
    assert ev.metrics[0, METRIC_NAMES.index("umin")] >= 0.0
    bad = tmp_path / "bad.toml"
    bad.write_text('extends = "cs_folqi_qtp"\n[scenario]\nlimits = "hard"\n')
    with pytest.raises(ConfigError, match=r"bad.toml: scenario.limits: got 'hard'; allowed: none, physical"):
        heurtune.load_experiment(str(bad))
    bad.write_text('extends = "cs_folqi_qtp"\n[plant.custom.x]\nu_range = [1, 2, 3]\n')
    with pytest.raises(ConfigError, match=r"plant.custom.x.u_range: expected two numbers"):
        heurtune.load_experiment(str(bad))


# -- range metrics --------------------------------------------------------------------------

def test_metric_names_end_with_the_range():
    assert METRIC_NAMES[-4:] == RANGE
    assert _kernels.N_METRICS == 22


@pytest.mark.parametrize("n", [0, 1, 255, 256, 257, 1000])
def test_loop_metrics_range_on_synthetic_trajectories(n):
    """hmin..umax of loop_metrics are numpy's min and max over all samples and channels
    (block edges of the input fold included)."""
    rng = np.random.default_rng(n)
    y = 15.0 + rng.normal(0, 1, (n + 1, 2))
    u = 3.0 + rng.normal(0, 2, (n + 1, 2))
    h = 10.0 + rng.normal(0, 8, (n + 1, 4))
    out = np.empty(_kernels.N_METRICS)
    _kernels.loop_metrics(y, u, np.array([15.0, 15.0]), np.array([3.0, 3.0]), 0.01, n // 2, 3.0, out, h)
    assert out[IDX].tolist() == [h.min(), h.max(), u.min(), u.max()]  # exact: minima and maxima pick samples
    # without levels: NaN for the level range, the rest unchanged
    bare = np.empty(_kernels.N_METRICS)
    _kernels.loop_metrics(y, u, np.array([15.0, 15.0]), np.array([3.0, 3.0]), 0.01, n // 2, 3.0, bare)
    assert np.isnan(bare[IDX[:2]]).all()
    assert_same_bits(bare[:18], out[:18], because="same code")  # the same kernel, the levels' range aside
    assert_same_bits(bare[IDX[2:]], out[IDX[2:]], because="same code")
    empty = np.empty(_kernels.N_METRICS)
    _kernels.loop_metrics(y, u, np.array([15.0, 15.0]), np.array([3.0, 3.0]), 0.01, n // 2, 3.0, empty,
                          np.empty((0, 4)))
    assert_same_bits(empty, bare, because="same code")
    with pytest.raises(ValueError, match="h must have shape"):
        _kernels.loop_metrics(y, u, np.array([15.0, 15.0]), np.array([3.0, 3.0]), 0.01, 0, 3.0, out, h[:, :2])


@pytest.mark.parametrize("case, kind, gains, extra", [
    ("min", "folqi", THESIS_MIN, dict()),
    ("min", "folqi", THESIS_MIN, dict(noise_sd=0.05, noise_seed=3, input_disturbance=(0.3, -0.2),
                                      input_disturbance_time=120.0)),
    ("min", "folqi", THESIS_MIN, dict(saturation=(0.0, 3.6), horizon=200.0, disturbance_time=51.2)),
    ("nmp", "folqi", NMP_FOLQI, dict()),
    ("nmp", "folqi", NMP_FOLQI, dict(limits="physical")),
])
def test_kernel_range_equals_that_of_the_recorded_trajectory(case, kind, gains, extra):
    """The sampled loop records every sample, so its range is that of its trajectory (the
    continuous loop refines extremes between step points: tests/objectives/qtp/test_continuous.py)."""
    loop = ClosedLoop(preset(case), kind)
    sc = Scenario(dt=0.01, **extra)
    ctrl = loop.controller(gains)
    lean = loop.run(ctrl, sc, record=False)
    sim = loop.run(ctrl, sc, record_levels=True)
    np.testing.assert_allclose(lean.metrics, sim.metrics, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lean.metrics, loop.metrics(sim, sc, 3.0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lean.metrics[IDX], [sim.h.min(), sim.h.max(), sim.u.min(), sim.u.max()],
                               rtol=1e-12, atol=1e-12)


def test_a_diverged_run_has_nan_range():
    loop = ClosedLoop(preset("min"), "folqi")
    D = np.zeros((2, 4))
    D[0, 0] = D[1, 1] = 1e4
    ctrl = LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ())
    sim = loop.run(ctrl, Scenario(dt=0.01), record=False)
    assert sim.diverged and np.isnan(sim.metrics).all()


# -- limits against an independent model -----------------------------------------------------

def reference_limited(P, K, H, U, n, dt, i_d, d):
    """Sampled proportional control ``u = clip(u0 - K (y - y0))`` of the plant of
    reference_qtp with tanks of heights ``H`` (nothing from heurtune's simulator).

    Over each step the voltages are held and the projected ODE is integrated with tight
    tolerances: a level's slope is set to 0 when it sits at 0 and falls, or at its rim and
    rises (the water above the rim is lost)."""
    h0, u0 = ref.equilibrium(P)
    Hn = np.asarray(H, dtype=float)

    def rhs(t, h, u):
        dh = ref.plant_rhs(h, u, P)
        dh[(h <= 0.0) & (dh < 0.0)] = 0.0
        dh[(h >= Hn) & (dh > 0.0)] = 0.0
        return dh

    h = h0.copy()
    hs, us = np.empty((n + 1, 4)), np.empty((n + 1, 2))
    for k in range(n + 1):
        y = h[:2] + (d if k >= i_d else 0.0)
        u = np.clip(u0 - K * (y - h0[:2]), *U)
        hs[k], us[k] = h, u
        if k == n:
            break
        sol = solve_ivp(rhs, (0.0, dt), h, args=(u,), method="DOP853", rtol=1e-11, atol=1e-12)
        assert sol.success
        h = np.clip(sol.y[:, -1], 0.0, Hn)  # the solver may step past a limit by its tolerance
    return hs, us


def test_saturation_and_overflow_match_an_independent_model():
    """A static gain and a large measured-level step (-3, +15) cm on the `min` plant with low
    tanks: pump 1 runs at 10 V and pump 2 at 0 V, tanks 1 and 4 overflow, tank 3 runs dry."""
    base = preset("min")
    H, U, K = (18.0, 18.0, 10.0, 9.0), (0.0, 10.0), 3.0
    plant = QTPParams(A=base.A, a=base.a, k=base.k, gamma=base.gamma, levels=base.levels,
                      height=H, u_range=U, name="low")
    P = dict(A=list(base.A), a=list(base.a), k=list(base.k), gamma=list(base.gamma), levels=list(base.levels))
    D = np.zeros((2, 4))
    D[0, 0] = D[1, 1] = -K
    ctrl = LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ())
    d = np.array([-3.0, 15.0])
    sc = Scenario(horizon=40.0, dt=0.05, disturbance_time=5.0, output_disturbance=tuple(d), limits="physical")
    sim = ClosedLoop(plant, "iolqi").run(ctrl, sc, record_levels=True)
    assert not sim.diverged
    h_ref, u_ref = reference_limited(P, K, H, U, sc.n_steps, sc.dt, sc.disturbance_index, d)
    # the limits are active: both pump limits, two rims and an empty tank (exact: clamped to the limits)
    assert (u_ref[:, 0] == 10.0).any() and (u_ref[:, 1] == 0.0).sum() > 100
    assert (h_ref[:, 0] == 18.0).sum() > 100 and (h_ref[:, 3] == 9.0).sum() > 100
    assert (h_ref[:, 2] == 0.0).sum() > 100
    # the kernel keeps every level and voltage in range, and its range metrics show the limits
    assert sim.metrics[IDX].tolist() == [0.0, 18.0, 0.0, 10.0]  # exact: clamped to the limits
    assert (sim.h >= 0.0).all() and (sim.h <= np.array(H)).all()
    # Away from the instants where a level reaches a limit, RK4 on the projected slopes is as
    # accurate as ever (~1e-6 cm here at dt = 0.05 s). Over the step in which a level reaches a
    # rim or the floor, RK4 + clipping is only first-order accurate: 6.6e-3 cm measured (tank 1
    # reaching its rim), 1.6e-3 cm at dt = 0.025 s. The voltages carry K = 3 times that error.
    err_h = np.abs(sim.h - h_ref)
    assert err_h.max() < 0.015  # cm
    assert np.median(err_h) < 1e-5
    assert np.abs(sim.u - u_ref).max() < 3 * 0.015  # V
    np.testing.assert_allclose(sim.y, sim.h[:, :2] + np.where(sim.t[:, None] >= 5.0, d, 0.0), atol=1e-12)


def test_unlimited_run_leaves_the_range_that_a_physical_run_keeps():
    """The README's best nmp FOLQI design asks for negative pump voltage; limits keep it at 0 V."""
    plant = preset("nmp")
    loop = ClosedLoop(plant, "folqi")
    ctrl = loop.controller(NMP_FOLQI)
    free = loop.run(ctrl, Scenario(dt=0.01), record_levels=True)
    m_free = dict(zip(METRIC_NAMES, free.metrics))
    assert m_free["umin"] < -3.5
    flags = physical_range_flags(m_free, plant)
    assert flags == [f"u below 0 V (min {m_free['umin']:.4g})"]
    assert flags == ["u below 0 V (min -3.819)"]  # quoted in docs/model.md
    # the same flags from the metric vector, and from the trajectory itself
    assert physical_range_flags(free.metrics, plant) == flags
    traj = dict(hmin=free.h.min(), hmax=free.h.max(), umin=free.u.min(), umax=free.u.max())
    assert physical_range_flags(traj, plant) == flags

    held = loop.run(ctrl, Scenario(dt=0.01, limits="physical"), record_levels=True)
    m = dict(zip(METRIC_NAMES, held.metrics))
    assert not held.diverged
    assert m["umin"] == 0.0 and m["umax"] <= 10.0  # exact: clamped to the limit
    assert m["hmin"] >= 0.0 and m["hmax"] <= 50.0
    assert held.u.min() == 0.0 and held.h.min() >= 0.0 and held.h.max() <= 50.0  # exact: clamped
    assert physical_range_flags(m, plant) == []
    # the default stays the thesis' model: same numbers as an explicit limits = "none"
    assert_same_bits(free.metrics, loop.run(ctrl, Scenario(dt=0.01, limits="none")).metrics, because="same code")


def test_physical_range_flags():
    p = preset("min")  # 50 cm tanks, 0..10 V
    inside = dict(hmin=0.0, hmax=50.0, umin=0.0, umax=10.0)  # on the limits: clipped, saturated
    assert physical_range_flags(inside, p) == []
    assert physical_range_flags(dict(hmin=-1e-12, umax=10.0 + 1e-12), p) == []  # tolerance
    out = dict(hmin=-226.1, hmax=61.2, umin=-4.02, umax=12.3)
    assert physical_range_flags(out, p) == [
        "levels below 0 cm (min -226.1)", "levels above 50 cm (max 61.2)",
        "u below 0 V (min -4.02)", "u above 10 V (max 12.3)",
    ]
    assert physical_range_flags(dict(hmin=np.nan, umax=np.nan), p) == []  # diverged / not recorded
    assert physical_range_flags(out, QTPParams(**plant_kwargs())) == []  # no limits
    row = np.zeros(len(METRIC_NAMES))
    row[IDX] = [-1.0, 10.0, 1.0, 2.0]
    assert physical_range_flags(row, p) == ["levels below 0 cm (min -1)"]
    import pandas as pd

    assert physical_range_flags(pd.Series(out), p) == physical_range_flags(out, p)
    with pytest.raises(ValueError, match="metrics vector"):
        physical_range_flags([1.0, 2.0], p)
    # unequal heights: hmax is checked against the tallest rim
    tall = QTPParams(**plant_kwargs(height=(20, 20, 30, 30), u_range=(0, 10)))
    assert physical_range_flags(dict(hmax=30.0), tall) == []
    assert physical_range_flags(dict(hmax=31.0), tall) == ["levels above 30 cm (max 31)"]


# -- figures ---------------------------------------------------------------------------------

def test_response_figure_marks_a_run_outside_the_physical_range(tmp_path, monkeypatch):
    from figure_helpers import keep_figures

    from heurtune.analysis import figures
    from heurtune.analysis.figures import response_figure

    figs = keep_figures(monkeypatch, figures)
    exp = heurtune.load_experiment("cs_folqi_qtp")
    prob = exp.problem("nmp")
    x = prob.parse(",".join(f"{k}={v}" for k, v in NMP_FOLQI.items()))
    held = dataclasses.replace(prob.scenario("nominal"), limits="physical")
    response_figure(prob, x, tmp_path / "free.png", scenarios=("nominal",))
    response_figure(prob, x, tmp_path / "held.png", scenarios=(held,))
    assert (tmp_path / "free.png").stat().st_size > 10_000 and (tmp_path / "held.png").exists()
    free, limited = figs

    def titles(fig):
        return [ax.get_title() for ax in fig.axes]

    # the tanks' rims far above the levels: named in the title, not a legend entry for a line
    # off the panel (issue 53)
    off = [f"tank {i} (limits off scale: 0 and 50 cm)" for i in (1, 2)]
    assert titles(free) == off + ["pump 1: outside physical range", "pump 2: outside physical range"]
    assert "outside physical range: nominal" in free._suptitle.get_text()
    assert titles(limited) == off + ["pump 1", "pump 2"]
    assert "outside" not in limited._suptitle.get_text()
    labels = [t.get_text() for t in free.axes[2].get_legend().get_texts()]
    assert "pump range 0 to 10 V" in labels
    labels = [t.get_text() for t in free.axes[0].get_legend().get_texts()]
    assert "tank 1: 0 and 50 cm" not in labels


def test_presets_all_have_limits():
    assert all(p.has_limits for p in PRESETS.values())


def test_nodes_sharing_a_time_refine_nothing_and_raise_nothing():
    """A step cut at a switch down to nothing leaves two nodes at one time: the extreme and the
    band crossing fall back to the nodes and the chord (before, a ZeroDivisionError in the lane)."""
    from heurtune.objectives.qtp import continuous_kernels as ck

    assert ck._vertex(1.0, 0.2, 1.0, 0.7, 2.0, 0.1) == 0.7
    assert ck._vertex(1.0, 0.2, 2.0, 0.7, 2.0, 0.1) == 0.7
    # the chord through (t1, f1) and (t2, f2) where the parabola's first two nodes coincide
    assert ck._crossing(1.0, 0.5, 1.0, 0.4, 2.0, 0.2, 0.3, True) == pytest.approx(1.5, rel=1e-15)
    assert ck._crossing(1.0, 0.5, 2.0, 0.4, 2.0, 0.2, 0.3, True) == 2.0


def test_the_suite_candidate_that_crashed_the_lane_is_evaluated(tmp_path):
    """Found by the tuning suite (folqi-min-limits, instance 3, a random-search candidate): its
    settling-time parabola met two nodes at one time. It is a feasible candidate."""
    import heurtune
    from heurtune.runner import suite as S

    suite = S.load_suite()
    path = S.problem_config(suite, suite.problem("folqi-min-limits"), "cs", [3], 1.0, 1, tmp_path / "x.toml")
    prob = heurtune.load_experiment(str(path)).problem("i3")
    x = [2.3952011933479764, 1.8122979982018086, 0.8772805930229726, 1.7253687478273863, 3.125402451329635,
         1.3939769844481837, 4.381069610313709, 8.421366743759785, 0.5097456803694814, 0.9584651145218597]
    ev = prob.evaluate(np.array([x]))
    assert ev.reason[0] == "" and np.all(np.isfinite(ev.metrics))
