"""Bond-graph (pressure) formulation of the QTP against the level model and independent solvers."""

import math
import pickle

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits
from scipy.integrate import solve_ivp

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import kernels as _kernels
from heurtune.objectives.qtp.bond_graph import (
    RHO_WATER,
    BondGraphElements,
    level_of_pressure,
    linearise_pressure,
    pressure_coefficients,
    pressure_of_level,
    pressure_rhs,
)
from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario
from heurtune.objectives.qtp.model import linearise, operating_point, preset, qtp_rhs

FOLQI = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
             Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)
IOLQI = dict(Q11=2.4266, Q22=1.1754, Q33=0.1141, Q44=2.3565, R11=4.9639, R22=3.8190,
             Ki1=1.0003, Ki2=1.0205)
GAINS = {"folqi": FOLQI, "iolqi": IOLQI}


def loops(case, kind, **options):
    """The same plant case and controller with the level model and with the bond graph."""
    return (ClosedLoop(preset(case), kind, **options),
            ClosedLoop(preset(case), kind, plant_model="qtp_bond_graph", **options))


# -- elements and right-hand side ----------------------------------------------------------

def test_elements_of_the_thesis_plant():
    p = preset("nmp")
    el = BondGraphElements.from_plant(p)
    # Hand values: rho = 1 g/cm^3, g = 981 cm/s^2, A = 176.71 cm^2, a1 = 2.54 cm^2.
    assert el.rho == RHO_WATER == 1.0 and el.g == 981.0 and el.rho_g == 981.0  # exact: 1.0 x 981.0
    assert el.C == pytest.approx((176.71 / 981.0,) * 4, rel=1e-15)
    assert el.kappa[0] == pytest.approx(2.54 * math.sqrt(2.0), rel=1e-15)
    assert el.k == (186.86, 186.86)
    assert el.tf == pytest.approx((0.45, 0.35, 0.65, 0.55), rel=1e-15)
    # Each pump's two transformers route all of its flow.
    assert el.tf[0] + el.tf[3] == pytest.approx(1.0) and el.tf[1] + el.tf[2] == pytest.approx(1.0)
    P = pressure_of_level([10.0, 1.0, 0.0, 2.5], el)
    np.testing.assert_allclose(P, [9810.0, 981.0, 0.0, 2452.5], rtol=1e-15)
    np.testing.assert_allclose(level_of_pressure(P, el), [10.0, 1.0, 0.0, 2.5], rtol=1e-15)


@pytest.mark.parametrize("rho", [0.0, -1.0, float("nan"), float("inf"), "water", True])
def test_bad_density(rho):
    with pytest.raises(ConfigError, match=r"plant.rho must be a positive finite number \(g/cm\^3\), got"):
        BondGraphElements.from_plant(preset("min"), rho)


@pytest.mark.parametrize("case", ["min", "nmp", "P-", "P+"])
@pytest.mark.parametrize("rho", [1.0, 0.8])
def test_pressure_rhs_is_rho_g_times_the_level_rhs(case, rho):
    # dP/dt = rho g dh/dt at P = rho g h: the element-by-element assembly against qtp.qtp_rhs.
    # Both sides are a handful of products and one square root per tank, so they agree to a few
    # ulps of the terms they add (which may cancel): 1e-12 relative to the sum of the terms'
    # magnitudes in each equation.
    p = preset(case).scaled(1.3)
    el = BondGraphElements.from_plant(p, rho)
    A, a, k, (g1, g2) = np.array(p.A), np.array(p.a), np.array(p.k), p.gamma
    rng = np.random.default_rng(7)
    for _ in range(200):
        h = rng.uniform(0.0, 40.0, 4)
        u = rng.uniform(0.0, 10.0, 2)
        dP = pressure_rhs(pressure_of_level(h, el), u, el)
        ref = el.rho_g * qtp_rhs(h, u, p)
        q = a * np.sqrt(2.0 * p.g * h)
        inflow = np.array([g1 * k[0] * u[0], g2 * k[1] * u[1], (1 - g2) * k[1] * u[1], (1 - g1) * k[0] * u[0]])
        terms = (q + inflow + np.array([q[2], q[3], 0.0, 0.0])) / A
        np.testing.assert_array_less(np.abs(dP - ref), 1e-12 * el.rho_g * terms)
    # Empty tanks (negative pressures are clipped under the roots like negative levels).
    h = np.array([-1.0, 0.0, 3.0, -2.0])
    np.testing.assert_allclose(pressure_rhs(pressure_of_level(h, el), [1.0, 2.0], el),
                               el.rho_g * qtp_rhs(h, [1.0, 2.0], p), rtol=1e-12)


def test_pressure_rhs_checks_shapes():
    el = BondGraphElements.from_plant(preset("min"))
    with pytest.raises(ValueError, match=r"pressure_rhs: P must have shape \(4,\) and u shape \(2,\)"):
        pressure_rhs(np.ones(3), np.ones(2), el)


@pytest.mark.parametrize("case", ["min", "P-"])
def test_kernel_coefficients_reproduce_the_element_rhs(case):
    # The jitted RHS fed the pressure coefficients equals the numpy element assembly (same
    # formula rearranged: agreement to rounding, 1e-12 relative).
    el = BondGraphElements.from_plant(preset(case).scaled(0.7))
    c = pressure_coefficients(el)
    rng = np.random.default_rng(3)
    for _ in range(50):
        P = rng.uniform(0.0, 4e4, 4)
        u = rng.uniform(0.0, 10.0, 2)
        np.testing.assert_allclose(_kernels.qtp_rhs(P, u, c), pressure_rhs(P, u, el), rtol=1e-12, atol=1e-9)
    # and the coefficients are rho g times (inputs) or sqrt(rho g) times (outflows) the level ones
    lev = _kernels.plant_coefficients(preset(case).scaled(0.7).as_array())
    np.testing.assert_allclose(c[:6], lev[:6] * math.sqrt(el.rho_g), rtol=1e-14)
    np.testing.assert_allclose(c[6:], lev[6:] * el.rho_g, rtol=1e-14)


@pytest.mark.parametrize("case", ["min", "nmp"])
def test_pressure_linearisation_is_the_finite_difference_jacobian(case):
    # Central differences of the element RHS about the operating pressures; step 1e-4 relative
    # gives a truncation error ~1e-8 relative and round-off ~1e-12 / 1e-4: 1e-6 bounds both.
    p = preset(case)
    el = BondGraphElements.from_plant(p)
    op = operating_point(p)
    P0 = pressure_of_level(op.h, el)
    A, B, C = linearise_pressure(p)
    J = np.empty((4, 4))
    for j in range(4):
        d = 1e-4 * P0[j]
        e = np.zeros(4)
        e[j] = d
        J[:, j] = (pressure_rhs(P0 + e, op.u, el) - pressure_rhs(P0 - e, op.u, el)) / (2 * d)
    Ju = np.empty((4, 2))
    for j in range(2):
        e = np.zeros(2)
        e[j] = 1e-3
        Ju[:, j] = (pressure_rhs(P0, op.u + e, el) - pressure_rhs(P0, op.u - e, el)) / 2e-3
    np.testing.assert_allclose(A, J, rtol=1e-6, atol=1e-6 * np.abs(J).max())
    np.testing.assert_allclose(B, Ju, rtol=1e-9, atol=1e-9 * np.abs(Ju).max())  # linear in u
    # and it is the level linearisation after dP = rho g dh
    Ah, Bh, Ch = linearise(p, op)
    np.testing.assert_allclose(A, Ah, rtol=1e-15)
    np.testing.assert_allclose(B / el.rho_g, Bh, rtol=1e-15)
    np.testing.assert_allclose(C * el.rho_g, Ch, rtol=1e-15)


# -- simulation against an independent integrator ----------------------------------------------

def _held_input_solution(el, P0, t, u):
    """Integrate the element equations with u[k] held over [t_k, t_k+1): one DOP853 solve per
    interval at tight tolerances, so the solver never steps across a switch."""
    P = np.empty((t.size, 4))
    P[0] = P0
    x = np.asarray(P0, dtype=np.float64)
    for k in range(t.size - 1):
        sol = solve_ivp(lambda _, s, uk=u[k]: pressure_rhs(s, uk, el), (t[k], t[k + 1]), x,
                        method="DOP853", rtol=1e-12, atol=1e-9)
        x = sol.y[:, -1]
        P[k + 1] = x
    return P


def test_closed_loop_pressures_match_scipy_with_the_recorded_input():
    # The kernel's recorded voltages held piecewise constant drive an independent DOP853
    # integration of the element equations, from the operating pressures. RK4 at dt = 0.1 s
    # against time constants of 24-90 s has a global error of order (dt / T)^4 ~ 1e-10 relative
    # or less; DOP853 at rtol 1e-12 adds ~1e-12. Measured: 4e-12 relative. The bound 1e-8
    # leaves room for other platforms and still catches a wrong element: 1 % off in C2 gives
    # 7e-4, the printed eq. 6.2's gamma1^2 in place of gamma2 gives 0.16.
    p = preset("nmp")
    loop = ClosedLoop(p, "folqi", plant_model="qtp_bond_graph")
    sc = Scenario(horizon=60.0, dt=0.1, disturbance_time=10.0, uncertainty=1.3)
    sim = loop.run(loop.controller(FOLQI), sc)
    assert not sim.diverged
    el = BondGraphElements.from_plant(p.scaled(1.3))
    P_ref = _held_input_solution(el, pressure_of_level(operating_point(p).h, el), sim.t, sim.u)
    assert np.max(np.abs(sim.P - P_ref)) <= 1e-8 * np.max(np.abs(P_ref))
    # the deviation from the operating point is what is tested, not just its large offset
    assert np.max(np.abs(P_ref - P_ref[0])) > 1e-3 * np.max(np.abs(P_ref))
    np.testing.assert_allclose(sim.h, level_of_pressure(sim.P, el), rtol=1e-15)


def test_open_loop_input_step_matches_scipy():
    # No controller (u = u_op) and a step on the pump voltages at 20 s: the pressures leave the
    # equilibrium. One switch, so a single DOP853 solve after it. Measured: 7e-13 relative, the
    # same at dt = 0.1 s (so it is the reference's round-off and tolerance, not RK4's error,
    # which is (dt / T)^4 ~ 1e-12 or less); the bound 1e-9 relative. The step moves the
    # pressures by 9 % of their largest value, far above the bound.
    from heurtune.objectives.qtp.controllers import LinearController

    p = preset("P-")
    loop = ClosedLoop(p, "folqi", plant_model="qtp_bond_graph")
    ctrl = LinearController(np.zeros((1, 1)), np.zeros((1, 4)), np.zeros((2, 1)), np.zeros((2, 4)), ((0, 1),), (0,))
    sc = Scenario(horizon=200.0, dt=0.01, disturbance_time=0.0, output_disturbance=(0.0, 0.0),
                  input_disturbance=(0.4, -0.3), input_disturbance_time=20.0)
    sim = loop.run(ctrl, sc)
    el = BondGraphElements.from_plant(p)
    op = operating_point(p)
    P0 = pressure_of_level(op.h, el)
    u1 = op.u + np.array([0.4, -0.3])
    s1 = solve_ivp(lambda _, s: pressure_rhs(s, u1, el), (20.0, 200.0), P0, method="DOP853",
                   rtol=1e-12, atol=1e-9, t_eval=sim.t[2000::100])
    ref = s1.y.T
    assert np.max(np.abs(sim.P[:2001] - P0)) < 1e-9 * P0.max()  # at rest before the step
    assert np.max(np.abs(sim.P[2000::100] - ref)) <= 1e-9 * np.max(np.abs(ref))
    assert np.max(np.abs(ref[-1] - P0)) > 0.05 * P0.max()
    # exact: the controller's output is zero, so the recorded input is the operating input plus zeros
    assert_exact(sim.u[2000:], np.broadcast_to(op.u, (sim.u.shape[0] - 2000, 2)))


# -- closed loop: the bond graph is the level model after P = rho g h --------------------------

def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(a)))


SCENARIOS = {
    "nominal": Scenario(dt=0.01),
    "uncertain": Scenario(dt=0.01, uncertainty=1.3),
    "disturbed": Scenario(
        dt=0.01,
        noise_sd=0.05,
        noise_seed=4,
        input_disturbance=(0.3, -0.2),
        input_disturbance_time=120.0,
        saturation=(0.0, 10.0),
    ),
    # P-: a -8 cm measured step drives the pumps to 10 V and overflows tanks 1 and 2; +6 cm
    # shuts the pumps (0 V) and empties tank 3.
    "overflow": Scenario(
        dt=0.01, horizon=200.0, disturbance_time=10.0, output_disturbance=(-8.0, -8.0), limits="physical"
    ),
    "empty": Scenario(dt=0.01, horizon=200.0, disturbance_time=10.0, output_disturbance=(6.0, 6.0), limits="physical"),
}


@pytest.mark.parametrize("case, kind, scenario", [
    ("min", "folqi", "nominal"), ("min", "iolqi", "nominal"),
    ("nmp", "folqi", "nominal"), ("nmp", "iolqi", "nominal"),
    ("min", "folqi", "uncertain"), ("nmp", "iolqi", "uncertain"),
    ("min", "folqi", "disturbed"),
    ("P-", "folqi", "overflow"), ("P-", "folqi", "empty"), ("P-", "iolqi", "overflow"),
])
def test_bond_graph_loop_equals_level_loop(case, kind, scenario):
    # Same controller, same sampled loop, the plant state scaled by rho g = 981: the two runs
    # differ by rounding only (measured: 1e-14 relative on the trajectories, at most 3e-11 on
    # the metrics). Tolerance 1e-9 relative, with one exception: ess_i is the final deviation
    # of a level of ~15 cm, which can be 1e-8 cm (min/IOLQI: ess = 5e-7 %), so its rounding
    # (~1e-14 cm) is 1e-6 of it. ess is therefore compared to 1e-9 of the size of that output's
    # response, its peak deviation Mp_i, the same percentage scale.
    sc = SCENARIOS[scenario]
    lev, bg = loops(case, kind)
    assert bg.plant_model == "qtp_bond_graph" and lev.plant_model == "qtp"
    assert bg.options == lev.options  # the model is not an option (problem ids stay)
    gains = GAINS[kind]
    a = lev.run(lev.controller(gains), sc)
    b = bg.run(bg.controller(gains), sc)
    assert not a.diverged and not b.diverged
    assert a.P is None and b.P is not None
    for key in ("y", "u", "h"):
        assert _rel(getattr(a, key), getattr(b, key)) <= 1e-9, key
    atol = np.zeros(len(METRIC_NAMES))
    for i in (1, 2):
        atol[METRIC_NAMES.index(f"ess{i}")] = 1e-9 * a.metrics[METRIC_NAMES.index(f"Mp{i}")]
    assert np.all(np.abs(b.metrics - a.metrics) <= 1e-9 * np.abs(a.metrics) + atol)
    # the metrics recomputed from the record agree too (they read the levels b.h)
    mb, ma = bg.metrics(b, sc, 3.0), lev.metrics(a, sc, 3.0)
    assert np.all(np.abs(mb - ma) <= 1e-9 * np.abs(ma) + atol)
    # a run without records gives the same metrics
    assert_same_bits(bg.run(bg.controller(gains), sc, record=False).metrics, b.metrics, because="same code")
    frame = b.to_frame()
    assert list(frame.columns) == ["t", "h1", "h2", "h3", "h4", "P1", "P2", "P3", "P4", "y1", "y2", "u1", "u2"]
    np.testing.assert_allclose(frame[["P1", "P2", "P3", "P4"]].to_numpy(), 981.0 * b.h, rtol=1e-14)
    assert "P1" not in a.to_frame().columns
    if sc.limits == "physical":
        m = dict(zip(METRIC_NAMES, b.metrics))
        h = preset(case).height[0]
        assert m["hmin"] >= 0.0 and m["hmax"] <= h * (1 + 1e-12)
        assert m["umin"] >= 0.0 and m["umax"] <= 10.0
        if scenario == "overflow":
            assert m["hmax"] == pytest.approx(h, rel=1e-12) and m["umax"] == 10.0  # exact: clamped
        else:
            assert m["hmin"] == 0.0 and m["umin"] == 0.0  # exact: clamped to the limits


def test_divergence_is_judged_on_levels():
    # An unstable design diverges in both models at about the same sample: the limit on
    # |h1| + ... + |h4| (1e6 cm) applies to the levels, not to the pressures (981 times larger).
    # The growth (about 6 % per 0.01 s sample here) starts from rounding differences between
    # the two models' arithmetic, whose sizes differ from CPU to CPU (measured 21 samples apart
    # on numba's generic target, fewer on AVX-512); a limit on the pressures would come
    # log(981) / 0.06 = 115 samples later. The test asks for less than half that gap, which
    # tells the two apart whatever the rounding. The last finite levels are below the limit.
    lev, bg = loops("nmp", "folqi")
    gains = dict(FOLQI, Ki1=10.0, Ki2=10.0, alpha1=1.9, alpha2=1.9)
    sc = Scenario(dt=0.01, horizon=2000.0)
    a = lev.run(lev.controller(gains), sc)
    b = bg.run(bg.controller(gains), sc)
    assert a.diverged and b.diverged
    assert np.isnan(b.metrics).all()
    ka, kb = (int(np.argmax(np.isnan(s.y[:, 0]))) for s in (a, b))
    pressure_gap = math.log(981.0) / 0.06  # samples
    assert abs(ka - kb) < pressure_gap / 2
    assert 1e5 < np.abs(b.h[kb - 1]).sum() < _kernels.LEVEL_LIMIT
    assert np.isnan(b.P[kb:]).all() and np.isnan(b.h[kb:]).all()


def test_pickle_round_trip():
    _, bg = loops("min", "folqi")
    sc = Scenario(dt=0.01, horizon=50.0, disturbance_time=10.0)
    before = bg.run(bg.controller(FOLQI), sc, record=False).metrics
    clone = pickle.loads(pickle.dumps(bg))
    assert clone.plant_model == "qtp_bond_graph"
    assert_same_bits(clone.run(clone.controller(FOLQI), sc, record=False).metrics, before, because="same code")
    # a pickle of a loop from before the bond-graph model loads as a level model
    lev = ClosedLoop(preset("min"), "folqi")
    state = lev.__getstate__()
    for key in ("plant_model", "_rho_g", "_level_per_state"):
        del state[key]
    old = ClosedLoop.__new__(ClosedLoop)
    old.__setstate__(state)
    assert old.plant_model == "qtp"
    assert_same_bits(old.run(old.controller(FOLQI), sc, record=False).metrics,
                     lev.run(lev.controller(FOLQI), sc, record=False).metrics, because="same code")


@pytest.mark.parametrize("model", ["bond_graph", "QTP", "", None, 1])
def test_unknown_plant_model(model):
    with pytest.raises(ConfigError, match=r"plant.model must be one of 'qtp', 'qtp_bond_graph', got "):
        ClosedLoop(preset("min"), "folqi", plant_model=model)


def test_warm_up_runs_for_the_bond_graph():
    _, bg = loops("min", "folqi")
    bg.warm_up()
