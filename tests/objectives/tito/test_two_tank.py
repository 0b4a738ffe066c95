"""Nonlinear coupled two-tank plant: equilibria, linearisation, calibration, closed-loop simulator.

Independent references: central finite differences of a right-hand side written here, scipy
``solve_ivp`` (Radau) of the same loop written here, and ``simulate_tito`` on the linearisation.
"""

import dataclasses
import math

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits
from scipy.integrate import solve_ivp

from heurtune.core.errors import ConfigError
from heurtune.objectives.tito import two_tank_kernels as _k
from heurtune.objectives.tito.model import (
    PIController,
    PIDController,
    TITOPlant,
    fit_fopdt,
    gpm_pi,
    inverted_decoupler,
    preset,
)
from heurtune.objectives.tito.sim import TITOScenario, loop_metrics, simulate_tito
from heurtune.objectives.tito.two_tank import (
    TwoTankParams,
    calibrate,
    equilibrium_levels,
    from_config,
    linear_tito_plant,
    linearise,
    operating_point,
    simulate_two_tank,
    two_tank_rhs,
)

DEFAULT = TwoTankParams()
# h1 > h2 regime (tank 2 outlet open, coupling flow from tank 1 to tank 2)
FORWARD = TwoTankParams(a1=0.06, a2=0.06, a12=0.05, levels=(8.0, 7.0), pump_delays=(2.0, 3.5),
                        sensor_delays=(0.0, 1.2), name="forward")
OPEN = (PIController(Kc=0.0, Ti=1.0), PIController(Kc=0.0, Ti=1.0))
COLUMNS = ["t", "r1", "r2", "y1", "y2", "ym1", "ym2", "u1", "u2", "v1", "v2"]


def _rhs(h, u, p):
    """The model of paper 002 section II, written out again (signed root, levels clipped at 0)."""
    r = math.sqrt(2.0 * p.g)
    h1, h2 = max(h[0], 0.0), max(h[1], 0.0)
    d = h1 - h2
    q12 = p.a12 / p.A * r * np.sign(d) * math.sqrt(abs(d))
    return np.array([p.eta[0] * u[0] - p.a1 / p.A * r * math.sqrt(h1) - q12,
                     p.eta[1] * u[1] - p.a2 / p.A * r * math.sqrt(h2) + q12])


def _rhs_fixed_input(t, h, u, p):
    return _rhs(h, u, p)


def _gpm_design(p):
    """Decoupler and GPM PI (Am = 3, phim = 60 deg) designed on the linearisation of ``p``."""
    G = linear_tito_plant(p)
    dec = inverted_decoupler(G)
    ctrl = tuple(PIController(*gpm_pi(fit_fopdt(z), 3.0, 60.0)) for z in (dec.z11, dec.z22))
    return G, dec, ctrl


# --------------------------------------------------------------------------------------------
# Operating point and linearisation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("p", [DEFAULT, FORWARD], ids=["default", "forward"])
def test_operating_point_round_trip(p):
    op = operating_point(p)
    assert np.all(op.u >= 0)
    # inflows are O(0.03) cm/s; 1e-15 cm/s is round-off
    for rhs in (_rhs(op.h, op.u, p), two_tank_rhs(op.h, op.u, p), _k.two_tank_rhs(op.h, op.u, p.coefficients())):
        assert np.max(np.abs(rhs)) < 1e-15
    np.testing.assert_allclose(equilibrium_levels(p, op.u), p.levels, rtol=1e-12)
    # levels -> inputs -> levels from another point too
    u = op.u * np.array([1.3, 0.9])
    h = equilibrium_levels(p, u)
    np.testing.assert_allclose(operating_point(p, h).u, u, rtol=1e-10)


@pytest.mark.parametrize("p", [DEFAULT, FORWARD], ids=["default", "forward"])
def test_linearisation_matches_central_differences(p):
    op = operating_point(p)
    A, B, C = linearise(p)
    eps = 1e-5
    Afd = np.column_stack([(_rhs(op.h + eps * e, op.u, p) - _rhs(op.h - eps * e, op.u, p)) / (2 * eps)
                           for e in np.eye(2)])
    Bfd = np.column_stack([(_rhs(op.h, op.u + eps * e, p) - _rhs(op.h, op.u - eps * e, p)) / (2 * eps)
                           for e in np.eye(2)])
    # central differences: truncation O(eps^2 f''') ~ 1e-11 relative here, round-off ~1e-11 / eps
    np.testing.assert_allclose(A, Afd, rtol=1e-6, atol=1e-6 * np.max(np.abs(A)))
    np.testing.assert_allclose(B, Bfd, rtol=1e-9, atol=0)
    assert_exact(C, np.eye(2))  # literals
    assert np.all(np.linalg.eigvalsh(A) < 0)


@pytest.mark.parametrize("p", [DEFAULT, FORWARD], ids=["default", "forward"])
def test_linear_tito_plant_is_the_state_space_model(p):
    A, B, C = linearise(p)
    G = linear_tito_plant(p)
    w = np.geomspace(1e-5, 10.0, 60)
    ref = np.array([C @ np.linalg.solve(1j * x * np.eye(2) - A, B) for x in w])
    ref = ref * np.exp(-1j * w[:, None, None] * p.delays()[None])
    np.testing.assert_allclose(G.freqresp(w), ref, rtol=1e-10, atol=0)
    for e in (G.g11, G.g12, G.g21, G.g22):
        assert len(e.lags) == 2 and all(t > 0 for t in e.lags)
    assert G.g12.L == p.sensor_delays[0] + p.pump_delays[1]  # same bits: same code (the one addition)


def test_default_calibration_reproduces_identified_dc_gains():
    ident = preset("two_tank")
    G = linear_tito_plant(DEFAULT)
    # rounding the defaults to 5 significant digits costs < 1e-5 relative
    np.testing.assert_allclose(G.dc_gain(), ident.dc_gain(), rtol=1e-5)
    # a2 = 0: pump 1 raises both levels alike, as identified (same bits: same code; the two gains
    # are one expression on operands that a2 = 0 leaves equal)
    assert G.g11.K == G.g21.K
    t_slow = np.mean([e.lags[0] for e in (ident.g11, ident.g12, ident.g21, ident.g22)])
    assert G.g11.lags[0] == pytest.approx(t_slow, rel=1e-5)  # 608.21 s
    assert G.g11.lags[1] == pytest.approx(30.61, abs=0.01)  # the fast mode, absent from eq. 28
    assert (G.g11.leads[0], G.g22.leads[0]) == pytest.approx((64.88, 52.92), abs=0.01)
    np.testing.assert_allclose(DEFAULT.delays(), [[7.4, 7.4], [30.0, 30.0]])
    cal = calibrate(ident, t_slow, A=150.0, levels=(7.0, 7.8), pump_delays=(5.5, 5.5), sensor_delays=(1.9, 24.5))
    for key in ("a1", "a2", "a12", "eta"):
        np.testing.assert_allclose(getattr(cal, key), getattr(DEFAULT, key), rtol=1e-4)
    np.testing.assert_allclose(linear_tito_plant(cal).dc_gain(), ident.dc_gain(), rtol=1e-12)
    np.testing.assert_allclose(operating_point(DEFAULT).u, [3.1512, 3.0769], atol=5e-4)
    # decoupled loops: same static gains as the identified model, faster dynamics (see docs)
    dec = inverted_decoupler(G)
    assert dec.column_delays == (0.0, 0.0)
    f1, f2 = fit_fopdt(dec.z11), fit_fopdt(dec.z22)
    assert (f1.K, f1.T, f1.L) == pytest.approx((0.4051, 52.92, 7.4), rel=1e-3)
    assert (f2.K, f2.T, f2.L) == pytest.approx((0.5200, 64.88, 30.0), rel=1e-3)


def test_calibrate_rejects_gains_no_two_tank_plant_has():
    with pytest.raises(ConfigError, match="K11 >= K21"):
        calibrate([[2.0, 1.0], [2.5, 3.0]], 600.0, A=100.0, levels=(5.0, 6.0))


def test_signed_square_root_reverses_the_coupling_flow():
    p = dataclasses.replace(DEFAULT, a1=0.0, a2=0.0, eta=(1.0, 1.0))
    c12 = p.a12 * math.sqrt(2 * p.g) / p.A
    for h, sign in (((5.0, 3.0), 1.0), ((3.0, 5.0), -1.0)):
        q = sign * c12 * math.sqrt(2.0)  # flow from tank 1 to tank 2
        np.testing.assert_allclose(two_tank_rhs(h, (0.0, 0.0), p), [-q, q], rtol=1e-15)
        np.testing.assert_allclose(_k.two_tank_rhs(np.array(h), np.zeros(2), p.coefficients()), [-q, q],
                                   rtol=1e-15)
    # negative levels are clipped under the roots: an empty tank 2 below 0 drains nothing
    np.testing.assert_allclose(two_tank_rhs((-1.0, -2.0), (0.0, 0.0), DEFAULT), [0.0, 0.0], atol=0)


def test_kernel_rk4_step_is_textbook_rk4():
    p, dt = FORWARD, 0.7
    h, u = np.array([6.5, 6.9]), np.array([2.0, 5.0])  # levels cross within the stages' reach

    def f(x):
        return _rhs(x, u, p)

    k1 = f(h)
    k2 = f(h + dt / 2 * k1)
    k3 = f(h + dt / 2 * k2)
    k4 = f(h + dt * k3)
    ref = h + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(_k.rk4_step(h, u, p.coefficients(), dt), ref, rtol=1e-14)


# --------------------------------------------------------------------------------------------
# Closed loop against references
# --------------------------------------------------------------------------------------------


def test_small_signal_agrees_with_simulate_tito_quadratically():
    """Set-point, input- and output-disturbance steps of size a about the default operating point."""
    G, dec, ctrl = _gpm_design(DEFAULT)
    amps = np.array([0.01, 0.02, 0.04])
    err_y, err_u = [], []
    for a in amps:
        sc = TITOScenario(horizon=600.0, setpoints=(((0.0, a),), ((100.0, -a),)), input_disturbance=(300.0, (a, a)),
                          output_disturbance=(450.0, (-a, a)))
        nl = simulate_two_tank(DEFAULT, ctrl, dec, sc)
        lin = simulate_tito(G, ctrl, dec, sc)
        assert nl.attrs["status"] == lin.attrs["status"] == "ok"
        assert_same_bits(nl[["t", "r1", "r2"]].to_numpy(), lin[["t", "r1", "r2"]].to_numpy(), because="same code")
        assert np.max(np.abs(lin[["y1", "y2"]].to_numpy())) > a  # the responses are of size a (u: 14 a)
        err_y.append(np.max(np.abs(nl[["y1", "y2"]].to_numpy() - lin[["y1", "y2"]].to_numpy())))
        err_u.append(np.max(np.abs(nl[["u1", "u2", "v1", "v2"]].to_numpy() - lin[["u1", "u2", "v1", "v2"]].to_numpy())))
    err_y, err_u = np.array(err_y), np.array(err_u)
    # measured max |nonlinear - linear|: levels 1.12, 1.14, 1.19 a^2 cm; pump inputs 9.1, 9.3, 9.7 a^2 V
    assert np.all(err_y <= 1.5 * amps**2) and np.all(err_u <= 11.0 * amps**2)
    for err in (err_y, err_u):
        ratios = err[1:] / err[:-1]
        assert np.all((3.7 < ratios) & (ratios < 4.3)), ratios  # doubling a quadruples the error


def _piecewise_open_loop(p, d_in, t_d, horizon):
    """Levels of the open loop by Radau, the input of pump j stepping by d_in[j] at t_d + Lu_j."""
    op = operating_point(p)
    events = sorted((t_d + p.pump_delays[j], j) for j in range(2))
    segs, h, u, t0 = [], op.h.copy(), op.u.copy(), 0.0
    for te, j in [*events, (horizon, None)]:
        if te > t0:
            s = solve_ivp(_rhs_fixed_input, (t0, te), h, args=(u.copy(), p), method="Radau",
                          rtol=1e-11, atol=1e-12, dense_output=True)
            segs.append((t0, te, s.sol))
            h, t0 = s.y[:, -1], te
        if j is not None:
            u = u.copy()
            u[j] += d_in[j]

    def levels(t):
        out = np.tile(op.h, (t.size, 1))
        for a, b, sol in segs:
            m = (t > a) & (t <= b)
            if m.any():
                out[m] = sol(t[m]).T
        return out

    return op, levels


@pytest.mark.parametrize("p, d_in, bound", [
    (DEFAULT, (0.8, -0.5), 1e-9),
    (FORWARD, (-3.0, 3.0), 1e-5),  # h1 - h2 goes from +1 to -0.21 cm: crosses the root's kink
], ids=["default", "reversal"])
def test_open_loop_matches_solve_ivp_with_dead_times(p, d_in, bound):
    horizon, t_d = 600.0, 10.0
    sc = TITOScenario(horizon=horizon, setpoints=((), ()), input_disturbance=(t_d, d_in))
    df = simulate_two_tank(p, OPEN, None, sc)
    op, levels = _piecewise_open_loop(p, d_in, t_d, horizon)
    t = df["t"].to_numpy()
    ref = np.column_stack([levels(t - p.sensor_delays[i])[:, i] for i in range(2)]) - op.h
    # measured: 1.8e-11 cm (smooth), 2.3e-6 cm with the crossing (RK4 loses order at the kink)
    assert np.max(np.abs(df[["y1", "y2"]].to_numpy() - ref)) < bound
    h = levels(t)
    gap = h[:, 0] - h[:, 1]
    if p is FORWARD:
        assert gap[0] > 0.9 and gap[-1] < -0.2  # the coupling flow reversed
    else:
        assert np.all(gap < 0)
    assert np.all(df[["u1", "u2", "v1", "v2"]].to_numpy() == 0.0)


def test_closed_loop_with_dead_times_matches_sampled_data_reference():
    """Sampled PI (ZOH, exactly what a digital controller does) + Radau between samples."""
    p, dt, horizon = DEFAULT, 0.5, 200.0
    Kc, Ti = np.array([3.0, 1.0]), np.array([50.0, 65.0])
    ctrl = (PIController(Kc=Kc[0], Ti=Ti[0]), PIController(Kc=Kc[1], Ti=Ti[1]))
    sc = TITOScenario(horizon=horizon, dt=dt, setpoints=(((0.0, 0.4),), ((20.0, -0.3),)),
                      input_disturbance=(100.0, (0.3, 0.2)), output_disturbance=(150.0, (0.1, -0.05)))
    df = simulate_two_tank(p, ctrl, None, sc)
    op = operating_point(p)
    ndu = np.round(np.array(p.pump_delays) / dt).astype(int)
    ndy = np.round(np.array(p.sensor_delays) / dt).astype(int)
    h, hist, cmd, z, Y, U = op.h.copy(), [op.h.copy()], [], np.zeros(2), [], []
    n = round(horizon / dt)
    for k in range(n + 1):
        tk = k * dt
        r = np.array([0.4, -0.3 if tk >= 20.0 else 0.0])
        d_out = np.array([0.1, -0.05]) * (tk >= 150.0)
        d_in = np.array([0.3, 0.2]) * (tk >= 100.0)
        y = np.array([hist[max(k - ndy[i], 0)][i] - op.h[i] for i in range(2)]) + d_out
        e = r - y
        u = Kc * (e + z / Ti)
        z = z + dt * e
        cmd.append(u + d_in)
        Y.append(y)
        U.append(u)
        if k == n:
            break
        ua = op.u + np.array([cmd[k - ndu[j]][j] if k >= ndu[j] else 0.0 for j in range(2)])
        h = solve_ivp(_rhs_fixed_input, (0.0, dt), h, args=(ua, p), method="Radau", rtol=1e-11, atol=1e-12).y[:, -1]
        hist.append(h.copy())
    # measured: 6.5e-11 cm in y, 2.1e-10 V in u
    assert np.max(np.abs(df[["y1", "y2"]].to_numpy() - np.array(Y))) < 1e-8
    assert np.max(np.abs(df[["u1", "u2"]].to_numpy() - np.array(U))) < 1e-8


def test_delay_free_loop_converges_to_continuous_pi_at_first_order():
    p = dataclasses.replace(DEFAULT, pump_delays=(0.0, 0.0), sensor_delays=(0.0, 0.0))
    op = operating_point(p)
    Kc, Ti, r = np.array([1.0, 0.8]), np.array([60.0, 80.0]), np.array([0.5, 0.3])
    horizon = 400.0

    def f(t, s):
        e = r - (s[:2] - op.h)
        return np.r_[_rhs(s[:2], op.u + Kc * (e + s[2:] / Ti), p), e]

    sol = solve_ivp(f, (0.0, horizon), np.r_[op.h, 0.0, 0.0], method="Radau", rtol=1e-10, atol=1e-12,
                    dense_output=True)
    ctrl = (PIController(Kc=Kc[0], Ti=Ti[0]), PIController(Kc=Kc[1], Ti=Ti[1]))
    errs = []
    for dt in (0.2, 0.1, 0.05):
        sc = TITOScenario(horizon=horizon, dt=dt, setpoints=(((0.0, r[0]),), ((0.0, r[1]),)))
        df = simulate_two_tank(p, ctrl, None, sc)
        ref = sol.sol(df["t"].to_numpy())[:2].T - op.h
        errs.append(np.max(np.abs(df[["y1", "y2"]].to_numpy() - ref)))
    # measured: 0.0019 dt cm (3.8e-4, 1.9e-4, 9.5e-5): the held measurement, first order in dt
    assert np.all(np.array(errs) < 0.0025 * np.array([0.2, 0.1, 0.05]))
    assert errs[0] / errs[1] == pytest.approx(2.0, rel=0.02) and errs[1] / errs[2] == pytest.approx(2.0, rel=0.02)


# --------------------------------------------------------------------------------------------
# Record, scenario, robustness of the evaluation
# --------------------------------------------------------------------------------------------


def test_record_matches_simulate_tito_layout_and_metrics_run():
    G, dec, ctrl = _gpm_design(DEFAULT)
    sc = TITOScenario(horizon=300.0, noise_power=1e-4, noise_seed=3)
    nl = simulate_two_tank(DEFAULT, ctrl, dec, sc)
    lin = simulate_tito(G, ctrl, dec, sc)
    assert list(nl.columns) == COLUMNS == list(lin.columns)
    assert set(lin.attrs) <= set(nl.attrs) and isinstance(nl.attrs["plant"], TITOPlant)
    assert nl.attrs["delay_rounding"] < 1e-9
    # identical noise draws
    np.testing.assert_allclose((nl["ym1"] - nl["y1"]).to_numpy(), (lin["ym1"] - lin["y1"]).to_numpy(), atol=1e-12)
    m = loop_metrics(nl, {"servo": (0.0, 300.0)})
    assert np.all(np.isfinite(m.to_numpy()))


def test_pid_controller_runs():
    _, dec, ctrl = _gpm_design(DEFAULT)
    pid = tuple(PIDController(Kc=c.Kc, Ti=c.Ti, Td=2.0, Tf=0.2) for c in ctrl)
    df = simulate_two_tank(DEFAULT, pid, dec, TITOScenario(horizon=300.0))
    assert df.attrs["status"] == "ok" and abs(df["y1"].iloc[-1] - 1.0) < 0.05


def test_variation_scales_physical_parameters():
    G, dec, ctrl = _gpm_design(DEFAULT)
    sc = TITOScenario(horizon=300.0, setpoints=(((0.0, 0.02),), ((0.0, 0.02),)), variation=0.2)
    df = simulate_two_tank(DEFAULT, ctrl, dec, sc)
    pv = df.attrs["params"]
    assert (pv.A, pv.a12) == pytest.approx((150.0 * 1.2, DEFAULT.a12 * 1.2))
    assert pv.eta == pytest.approx(tuple(e / 1.2 for e in DEFAULT.eta))  # same pump volume flow
    np.testing.assert_allclose(df.attrs["operating_point"].u, 1.2 * operating_point(DEFAULT).u, rtol=1e-12)
    Gv = df.attrs["plant"]
    np.testing.assert_allclose(Gv.dc_gain(), G.dc_gain() / 1.2, rtol=1e-12)
    assert Gv.g11.lags == pytest.approx(G.g11.lags, rel=1e-12)
    # small signal: the varied nonlinear loop follows the linear loop on the varied linearisation
    lin = simulate_tito(Gv, ctrl, dec, dataclasses.replace(sc, variation=0.0))
    assert np.max(np.abs(df[["y1", "y2"]].to_numpy() - lin[["y1", "y2"]].to_numpy())) < 3.0 * 0.02 ** 2
    delays = simulate_two_tank(DEFAULT, ctrl, dec, sc, vary=("pump_delays",)).attrs["plant"]
    assert delays.g11.L == pytest.approx(5.5 * 1.2 + 1.9) and delays.g11.K == pytest.approx(G.g11.K)
    with pytest.raises(ConfigError, match="allowed: A, a1, a2, a12, eta"):
        simulate_two_tank(DEFAULT, ctrl, dec, sc, vary=("K",))


@pytest.mark.parametrize("gains", [(1e8, 1e8), (-1e3, -1e3), (1e300, 1.0), (50.0, -50.0)])
def test_absurd_gains_end_as_diverged_without_exception(gains):
    ctrl = tuple(PIController(Kc=k, Ti=1.0) for k in gains)
    df = simulate_two_tank(DEFAULT, ctrl, None, TITOScenario(horizon=2000.0))
    assert df.attrs["status"] == "diverged"
    vals = df[COLUMNS[3:]].to_numpy()
    assert np.all(np.isfinite(vals) | np.isnan(vals)) and np.isnan(vals[-1]).all()


# --------------------------------------------------------------------------------------------
# Configuration errors
# --------------------------------------------------------------------------------------------


def test_from_config_defaults_overrides_and_inputs():
    assert from_config({"model": "two_tank_nonlinear"}) == DEFAULT
    p = from_config({"A": 120.0, "eta": 0.008, "a2": 0.02, "levels": [7.0, 7.5], "name": "mine"})
    assert p.eta == (0.008, 0.008) and p.A == 120.0 and p.name == "mine"
    q = from_config({"inputs": [3.0, 3.2]})
    np.testing.assert_allclose(operating_point(q).u, [3.0, 3.2], rtol=1e-10)


@pytest.mark.parametrize("cfg, match", [
    ({"a3": 1.0}, r"unknown key\(s\) a3; allowed: model, name, A, a1"),
    ({"model": "qtp"}, "model = 'qtp' is not handled here; allowed: 'two_tank_nonlinear'"),
    ({"a1": -0.1}, r"a1 must be a finite number >= 0 \(cm\^2\)"),
    ({"A": 0.0}, r"A must be a finite number > 0 \(cm\^2\)"),
    ({"eta": [0.01, -1.0]}, r"eta\[1\] must be a finite number > 0"),
    ({"levels": [7.0]}, "levels must be a pair"),
    ({"pump_delays": [1.0, "x"]}, r"pump_delays\[1\] must be a finite number >= 0 \(s\)"),
    ({"g": math.inf}, "g must be a finite number > 0"),
    ({"levels": [8.0, 7.0]}, r"need pump input u2 = -.* V < 0"),
    ({"levels": [7.0, 7.0]}, "h1 = h2 = 7 cm"),
    ({"levels": [1.0, 2.0], "inputs": [1.0, 1.0]}, "either levels or inputs"),
    ({"inputs": [1.0, -1.0]}, r"inputs\[1\] must be a finite number >= 0"),
])
def test_config_errors_name_the_key(cfg, match):
    with pytest.raises(ConfigError, match=match):
        from_config(cfg)


def test_simulate_validation():
    with pytest.raises(ConfigError, match="plant: must be a TwoTankParams"):
        simulate_two_tank(preset("two_tank"), OPEN)
    with pytest.raises(ConfigError, match="controllers"):
        simulate_two_tank(DEFAULT, OPEN[:1])
    with pytest.raises(ConfigError, match="scenario"):
        simulate_two_tank(DEFAULT, OPEN, None, {"horizon": 10})
