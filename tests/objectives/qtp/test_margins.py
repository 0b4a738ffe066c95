"""Stability margins (heurtune.objectives.qtp.margins) against closed forms and an independent numpy computation.

The independent computation evaluates the return ratio ``L(jw) = -K(jw) P(jw)`` and the
element loops ``L_ij(jw) = -K_ij(jw) [(I - P K')^-1 P]_ji`` (``K'``: ``K`` with element (i, j)
zeroed) straight from the state matrices by complex linear algebra, on a dense log grid (2000
points per decade); it finds |L| = 1 and arg L = -180 deg by linear interpolation in log w and
reads the phase there, and refines the gain crossovers with scipy's brentq on the exact
|L(jw)| - 1. The interpolation error is ~(ln 10 / 2000)^2 ~ 1e-6 relative, brentq's ~1e-12,
far inside the tolerances used below.
"""

import math
import warnings

import control
import numpy as np
import pytest
from numerics import assert_close
from scipy.optimize import brentq

import heurtune
from heurtune.objectives.qtp.margins import (
    ELEMENT_LOOP,
    MARGIN_COLUMNS,
    element_loop,
    frequency_grid,
    loop_margins,
    multivariable_margins,
    return_ratio,
    siso_margins,
)
from heurtune.objectives.qtp.model import linearise, operating_point

THESIS_X = ("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,"
            "Ki1=1.7411,Ki2=7.1716,alpha1=0.9814,alpha2=0.8437")


@pytest.fixture(scope="module")
def problem():
    return heurtune.load_experiment("cs_folqi_qtp").problem("min")


@pytest.fixture(scope="module")
def x(problem):
    return problem.parse(THESIS_X)


@pytest.fixture(scope="module")
def table(problem, x):
    return loop_margins(problem, x)


# -- independent reference ---------------------------------------------------------------------
def _frequency_response(A, B, C, D, w):
    """C (jwI - A)^-1 B + D for every w: array (len(w), p, m)."""
    n = A.shape[0]
    if n == 0:
        return np.broadcast_to(D, (len(w),) + D.shape).astype(complex)
    M = 1j * w[:, None, None] * np.eye(n) - A
    return C @ np.linalg.solve(M, np.broadcast_to(B, (len(w),) + B.shape)) + D


def _plant(problem, factor):
    if factor == 1.0:
        return problem.loop.A, problem.loop.B
    plant = problem.loop.plant.scaled(factor)
    A, B, _ = linearise(plant, operating_point(plant))
    return A, B


def _numpy_PK(problem, x, w, factor=1.0):
    ctrl = problem.loop.controller(problem.values(x))
    A, B = _plant(problem, factor)
    P = _frequency_response(A, B, np.eye(4), np.zeros((4, 2)), w)        # (nw, 4, 2)
    K = _frequency_response(ctrl.A, ctrl.B, ctrl.C, ctrl.D, w)           # (nw, 2, 4)
    return P, K


def _numpy_return_ratio(problem, x, w):
    P, K = _numpy_PK(problem, x, w)
    return -K @ P                                                         # (nw, 2, 2)


def _numpy_element_loop(problem, x, i, j, w, factor=1.0):
    """-K_ij [(I - P K')^-1 P]_ji, K' = K without element (i, j) (i, j from 0)."""
    P, K = _numpy_PK(problem, x, w, factor)
    Kr = K.copy()
    Kr[:, i, j] = 0.0
    T = np.linalg.solve(np.eye(4) - P @ Kr, P)                            # (nw, 4, 2)
    return -K[:, i, j] * T[:, j, i]


def _brentq_gain_crossovers(problem, x, i, j, w, L, factor=1.0):
    """Gain crossovers refined on the exact |L(jw)| = 1 and the phase margins there (deg)."""
    def logmag(lw):
        return np.log(np.abs(_numpy_element_loop(problem, x, i, j, np.array([math.exp(lw)]), factor)[0]))

    out = []
    lm = np.log(np.abs(L))
    for k in np.flatnonzero(np.sign(lm[:-1]) != np.sign(lm[1:])):
        wc = math.exp(brentq(logmag, math.log(w[k]), math.log(w[k + 1]), xtol=1e-14))
        ph = math.degrees(np.angle(_numpy_element_loop(problem, x, i, j, np.array([wc]), factor)[0]))
        out.append((wc, (ph % 360.0) - 180.0))
    return out


def _numpy_margins(L, w):
    """Gain crossovers and phase margins, phase crossovers and gain margins (dB) of samples."""
    logw = np.log(w)
    logmag = np.log(np.abs(L))
    phase = np.unwrap(np.angle(L))
    gc, pm = [], []
    for k in np.flatnonzero(np.sign(logmag[:-1]) != np.sign(logmag[1:])):
        t = logmag[k] / (logmag[k] - logmag[k + 1])
        gc.append(math.exp(logw[k] + t * (logw[k + 1] - logw[k])))
        ph = math.degrees(phase[k] + t * (phase[k + 1] - phase[k]))
        pm.append((ph % 360.0) - 180.0)
    pc, gm = [], []
    # arg L = -180 deg (mod 360): unwrapped phase crosses an odd multiple of pi
    turns = np.floor((phase + math.pi) / (2 * math.pi))
    for k in np.flatnonzero(turns[:-1] != turns[1:]):
        level = (max(turns[k], turns[k + 1])) * 2 * math.pi - math.pi
        t = (level - phase[k]) / (phase[k + 1] - phase[k])
        pc.append(math.exp(logw[k] + t * (logw[k + 1] - logw[k])))
        gm.append(-20.0 / math.log(10.0) * (logmag[k] + t * (logmag[k + 1] - logmag[k])))
    return np.array(gc), np.array(pm), np.array(pc), np.array(gm)


DENSE = np.logspace(-5, 5, 20001)


@pytest.fixture(scope="module")
def dense_L(problem, x):
    return _numpy_return_ratio(problem, x, DENSE)


# -- textbook SISO cases -----------------------------------------------------------------------
def test_textbook_third_order_loop():
    # L = 2/(s+1)^3: arg L = -180 deg at w = sqrt(3) where |L| = 2/8, so GM = 4 (12.04 dB);
    # |L| = 1 at w^2 = 2^(2/3) - 1, PM = 180 - 3 atan(w).
    L = control.tf([2.0], [1.0, 3.0, 3.0, 1.0])
    # The crossovers are roots of L(jw) itself (Brent, xtol 2e-12), not of a spline through the
    # samples (python-control's route, 1e-6 here, 0.3 % on some gain margins of the QTP loops)
    m = siso_margins(L)
    wc = math.sqrt(2.0 ** (2.0 / 3.0) - 1.0)
    assert m["phase_crossover_rad_s"] == pytest.approx(math.sqrt(3.0), rel=1e-11)
    assert m["gain_margin_db"] == pytest.approx(20 * math.log10(4.0), abs=1e-10)
    assert m["gain_crossover_rad_s"] == pytest.approx(wc, rel=1e-11)
    assert m["phase_margin_deg"] == pytest.approx(180.0 - 3.0 * math.degrees(math.atan(wc)), abs=1e-9)
    assert (m["n_gain_crossovers"], m["n_phase_crossovers"]) == (1, 1)
    # same through the state-space route
    ms = siso_margins(control.ss(L))
    for key in ("gain_margin_db", "phase_margin_deg"):
        assert ms[key] == pytest.approx(m[key], abs=1e-6)


def test_textbook_integrator_loop_has_infinite_gain_margin():
    # L = 1/(s(s+1)): |L| = 1 at w^2 = (sqrt5 - 1)/2, PM = 90 - atan(w); the phase never
    # reaches -180 deg, so GM = inf with no crossover (pole at 0 ignored by the grid).
    m = siso_margins(control.tf([1.0], [1.0, 1.0, 0.0]))
    wc = math.sqrt((math.sqrt(5.0) - 1.0) / 2.0)
    assert m["gain_crossover_rad_s"] == pytest.approx(wc, rel=1e-11)
    assert m["phase_margin_deg"] == pytest.approx(90.0 - math.degrees(math.atan(wc)), abs=1e-9)
    assert m["gain_margin_db"] == math.inf and math.isnan(m["phase_crossover_rad_s"])


def test_a_pole_on_the_grid_leaves_out_its_intervals():
    # L = 1/(s^2 + 1) sampled at its pole w = 1: the infinite sample bounds no bracket (|L| = 1
    # at w = 0, off the grid, and at sqrt(2), inside the left-out interval; beyond w = 1, L is
    # real negative throughout, so no sign of arg(-L) changes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = siso_margins(control.tf([1.0], [1.0, 0.0, 1.0]), [0.5, 1.0, 2.0, 3.0])
    assert (m["n_gain_crossovers"], m["n_phase_crossovers"]) == (0, 0)
    assert m["gain_margin_db"] == math.inf and m["phase_margin_deg"] == math.inf


def test_no_gain_crossover_gives_infinite_phase_margin():
    m = siso_margins(control.tf([0.5], [1.0, 1.0]))
    assert m["phase_margin_deg"] == math.inf and math.isnan(m["gain_crossover_rad_s"])
    assert m["n_gain_crossovers"] == 0


def test_frequency_grid_covers_poles():
    w = frequency_grid([0.0, -1e-3, -700.0, -1 + 2j])
    assert w[0] <= 1e-5 and w[-1] >= 7e4
    assert frequency_grid([0.0])[[0, -1]].tolist() == [1e-4, 1e4]


# -- the thesis' CS/FOLQI/min loop --------------------------------------------------------------
def test_table_layout(table):
    assert list(table.columns) == list(MARGIN_COLUMNS)
    assert MARGIN_COLUMNS[:8] == ("input", "output", "gain_crossover_rad_s", "phase_margin_deg",
                                  "phase_crossover_rad_s", "gain_margin_db", "n_gain_crossovers",
                                  "n_phase_crossovers")  # the schema before element loops, kept
    assert table[["input", "output"]].values.tolist() == [[1, 1], [1, 2], [2, 1], [2, 2]]
    assert (table.definition == ELEMENT_LOOP).all()


def test_return_ratio_matches_numpy(problem, x):
    w = np.logspace(-4, 3, 15)
    L = return_ratio(problem, x)
    ref = _numpy_return_ratio(problem, x, w)
    got = np.moveaxis(np.asarray(control.frequency_response(L, w).complex), -1, 0)
    np.testing.assert_allclose(got, ref, rtol=1e-9)


def _check_against_numpy(table, problem, x, factor=1.0):
    for row in table.itertuples():
        i, j = row.input - 1, row.output - 1
        L = _numpy_element_loop(problem, x, i, j, DENSE, factor)
        gc, pm, pc, gm = _numpy_margins(L, DENSE)
        assert row.n_gain_crossovers == len(gc) and row.n_phase_crossovers == len(pc)
        if len(gc):
            exact = _brentq_gain_crossovers(problem, x, i, j, DENSE, L, factor)
            k = int(np.argmin(np.abs(pm)))
            assert row.gain_crossover_rad_s == pytest.approx(exact[k][0], rel=1e-5)
            assert row.phase_margin_deg == pytest.approx(exact[k][1], abs=1e-3)
        else:
            assert row.phase_margin_deg == math.inf and math.isnan(row.gain_crossover_rad_s)
        if len(pc):
            k = int(np.argmin(np.abs(gm)))
            assert row.phase_crossover_rad_s == pytest.approx(pc[k], rel=1e-5)
            assert row.gain_margin_db == pytest.approx(gm[k], abs=1e-3)
        else:
            assert row.gain_margin_db == math.inf and math.isnan(row.phase_crossover_rad_s)


def test_element_loops_match_numpy(problem, x, table):
    _check_against_numpy(table, problem, x)
    w = np.logspace(-4, 3, 15)
    for i in (1, 2):
        for j in (1, 2):
            got = np.asarray(control.frequency_response(element_loop(problem, x, i, j), w).complex).ravel()
            # measured: 1.3e-8 relative near the integrators; cross elements reach 1e-9 at low
            # frequency, differences of terms of about |K_ij| |P| |K| = 350 there, where
            # cancellation leaves 1e-15 to 1.7e-13 absolute by CPU (9 eps times those terms on
            # an AMD EPYC with AVX2 only)
            np.testing.assert_allclose(got, _numpy_element_loop(problem, x, i - 1, j - 1, w), rtol=1e-7, atol=2e-12)


# A stable tuning (min case) whose element loop (1, 2) has a phase crossover: exercises the
# gain-margin path. Found by drawing random points of the box.
PHASE_CROSSING_X = ("Q11=2.0415,Q22=0.0168,Q33=2.1449,Q44=0.0936,R11=3.6753,R22=0.9607,"
                    "Ki1=8.6455,Ki2=5.4605,alpha1=0.6695,alpha2=0.9031")


def test_element_loop_gain_margin_matches_numpy(problem):
    x = problem.parse(PHASE_CROSSING_X)
    assert multivariable_margins(problem, x).stable
    t = loop_margins(problem, x)
    assert t.n_phase_crossovers.tolist() == [0, 1, 0, 0]
    assert t.gain_margin_db[1] > 100.0  # measured 106.5 dB at 2.39 rad/s
    _check_against_numpy(t, problem, x)


def test_closing_an_element_loop_closes_the_whole_loop(problem, x):
    # every element loop, closed with 1 / (1 + L), has the closed-loop poles of the simulated
    # loop, plus the controller's own modes (those of the copy that carries the element)
    ctrl = problem.loop.controller(problem.values(x))
    ref = np.concatenate([np.linalg.eigvals(ctrl.closed_loop_matrix(problem.loop.A, problem.loop.B)),
                          np.linalg.eigvals(ctrl.A)])
    for i in (1, 2):
        for j in (1, 2):
            closed = control.feedback(element_loop(problem, x, i, j), 1, sign=-1)
            np.testing.assert_allclose(np.sort_complex(control.poles(closed)), np.sort_complex(ref),
                                       rtol=1e-6, atol=1e-8)


def test_thesis_loops(table):
    # Thesis Table 5.8 (CS / FOLQI / min): gain margins infinite; pump 1 crosses over at
    # 1.03-1.05 rad/s, pump 2 at 2.23-2.27 rad/s. Measured (element loops): 1.023 rad/s and
    # 20.3 deg, 2.244 rad/s and 21.5 deg; the cross elements' loop gains stay below 1e-3.
    # exact: inf is the margin written where there is no crossover
    assert (table.gain_margin_db == math.inf).all() and (table.open_loop_unstable_poles == 0).all()
    t = table.set_index(["input", "output"])
    assert t.loc[(1, 1), "gain_crossover_rad_s"] == pytest.approx(1.03, rel=0.02)
    assert t.loc[(2, 2), "gain_crossover_rad_s"] == pytest.approx(2.27, rel=0.02)
    assert t.loc[(1, 1), "phase_margin_deg"] == pytest.approx(20.31, abs=0.01)
    assert t.loc[(2, 2), "phase_margin_deg"] == pytest.approx(21.52, abs=0.01)
    for pair in ((1, 2), (2, 1)):
        assert t.loc[pair, "phase_margin_deg"] == math.inf and t.loc[pair, "n_gain_crossovers"] == 0  # exact


def test_cross_loops_are_weak(problem, x):
    for i, j in ((0, 1), (1, 0)):
        assert np.max(np.abs(_numpy_element_loop(problem, x, i, j, DENSE))) < 1e-3


def test_uncertainty_scenario_matches_numpy(problem, x):
    # the -30% plant (linearised at its own operating point; the controller stays nominal)
    _check_against_numpy(loop_margins(problem, x, "-30%"), problem, x, 0.7)


def test_uncertainty_scales_the_return_ratio(problem, x):
    # Scaling every A_i and a_i by f keeps the time constants and divides B by f, so the
    # return ratio at the plant input becomes L / f.
    w = np.logspace(-4, 3, 15)
    L = np.asarray(control.frequency_response(return_ratio(problem, x), w).complex)
    for name, f in (("-30%", 0.7), ("+30%", 1.3)):
        Lf = np.asarray(control.frequency_response(return_ratio(problem, x, name), w).complex)
        np.testing.assert_allclose(Lf, L / f, rtol=1e-8)


def test_element_loop_rejects_bad_indices(problem, x):
    with pytest.raises(ValueError, match="input and output must be 1 or 2"):
        element_loop(problem, x, 0, 1)


def test_multivariable_margins(problem, x, dense_L):
    mm = multivariable_margins(problem, x)
    ctrl = problem.loop.controller(problem.values(x))
    assert mm.stable and mm.max_real_eig == pytest.approx(problem.loop.stability_margin(ctrl))
    w, L = DENSE, dense_L
    sv = np.linalg.svd(np.eye(2) + L, compute_uv=False)[:, -1]
    assert mm.return_difference_min_sv == pytest.approx(sv.min(), rel=1e-3)
    lo, hi = mm.disk_gain_margin_db
    s = mm.return_difference_min_sv
    assert lo == pytest.approx(-20 * math.log10(1 + s)) and hi == pytest.approx(-20 * math.log10(1 - s))
    # loop-at-a-time: pump i's loop broken, the other closed: L_ii - L_io L_oi / (1 + L_oo)
    for row in mm.loop_at_a_time.itertuples():
        i, o = row.input - 1, 2 - row.input
        Li = L[:, i, i] - L[:, i, o] * L[:, o, i] / (1.0 + L[:, o, o])
        gc, pm, pc, _ = _numpy_margins(Li, w)
        k = int(np.argmin(np.abs(pm)))
        assert row.gain_crossover_rad_s == pytest.approx(gc[k], rel=1e-4)
        assert row.phase_margin_deg == pytest.approx(pm[k], abs=1e-2)
        assert row.gain_margin_db == math.inf and len(pc) == 0


def test_unstable_candidate_is_flagged(problem, x):
    v = problem.values(x)
    v.update(Ki1=10.0, Ki2=10.0, alpha1=2.0, alpha2=2.0)
    mm = multivariable_margins(problem, v)
    assert not mm.stable and mm.max_real_eig > 0


def test_return_ratio_sign_matches_the_simulated_loop(problem, x):
    # Closing L with the negative-feedback convention, (I + L)^-1, must give the poles of the
    # loop the simulator runs (ClosedLoop's closed-loop matrix): this pins the sign of L.
    ctrl = problem.loop.controller(problem.values(x))
    ref = np.sort_complex(np.linalg.eigvals(ctrl.closed_loop_matrix(problem.loop.A, problem.loop.B)))
    L = return_ratio(problem, x)
    closed = control.feedback(L, np.eye(2), sign=-1)
    np.testing.assert_allclose(np.sort_complex(control.poles(closed)), ref, rtol=1e-6, atol=1e-9)
    wrong = control.feedback(L, np.eye(2), sign=+1)
    assert not np.allclose(np.sort_complex(control.poles(wrong)), ref, rtol=1e-3)


def test_positive_siso_margins_do_not_make_a_stable_mimo_loop():
    # The minimum-phase gains on the non-minimum-phase plant: both pumps' own loops show
    # positive phase margins and no phase crossover, yet the 2 x 2 loop is unstable (the
    # evaluation says so too). Hence multivariable_margins reports the eigenvalue check.
    prob = heurtune.load_experiment("cs_folqi_qtp").problem("nmp")
    x = prob.parse(THESIS_X)
    t = loop_margins(prob, x)
    diag = t[t.input == t.output]
    assert (diag.phase_margin_deg > 0).all() and (diag.gain_margin_db == math.inf).all()
    mm = multivariable_margins(prob, x)
    assert not mm.stable and mm.max_real_eig > 0
    assert prob.evaluate(x).reason[0] == "unstable"


def test_linear_systems_are_the_loop_python_control_builds(problem, x):
    """prob.linear_systems: the closed loop equals python-control's own interconnection of the
    plant and the controller (positive feedback, du = K w, the controller's signs), its poles
    are the stability check's, and its DC gain from d1 to y1 is 1 - the loop's rejection."""
    sys = problem.linear_systems(x)
    plant, ctrl, cl = sys["plant"], sys["controller"], sys["closed_loop"]
    assert plant.input_labels == ["du1", "du2"] and plant.output_labels == ["w1", "w2", "w3", "w4"]
    assert ctrl.input_labels == plant.output_labels and ctrl.output_labels == plant.input_labels
    fb = control.feedback(plant, ctrl, sign=+1)
    np.testing.assert_allclose(np.sort_complex(cl.poles()), np.sort_complex(fb.poles()), rtol=1e-8, atol=1e-10)
    margin = problem.loop.stability_margin(problem.loop.controller(problem.values(x)))
    assert np.max(cl.poles().real) == pytest.approx(margin, rel=1e-8, abs=1e-12)
    # d1 at a frequency: y1 = (I + P_y K_y ...)^-1 d, compare with the interconnection's response
    s = 0.3j
    P = plant(s)
    K = ctrl(s)
    E = np.zeros((4, 2))
    E[0, 0] = E[1, 1] = 1.0
    w = np.linalg.solve(np.eye(4) - P @ K, E)  # w = P K w + E d
    np.testing.assert_allclose(cl(s)[:2], w[:2], rtol=1e-9)
    for i in (1, 2):
        for j in (1, 2):
            assert sys[f"loop_{i}_{j}"].ninputs == sys[f"loop_{i}_{j}"].noutputs == 1


def test_the_compiled_response_is_the_state_space_response_python_control_evaluates(problem):
    """The margins' sampling (Hessenberg form once, one Hessenberg solve per frequency, compiled)
    against python-control's per-frequency evaluation of the same state space (SLICOT's TB05AD),
    on the four element loops of random candidates of three structures, over each loop's grid.
    Both solve ``(jwI - A) x = B`` backward stably, so each errs by about ``eps cond(jwI - A)
    |C| |x|`` (norms); at the grid's low end the shifted matrix is nearly singular (condition
    1e8 on FOLQI loops), and against a 50-digit evaluation (mpmath) the two err alike there, by
    up to 3e-4 of a cross loop's ``|L|`` of 1e-10. Held to 100 times that bound."""
    from heurtune.objectives.qtp.margins import _frequency_response

    rng = np.random.default_rng(5)
    checked = 0
    for name in ("cs_folqi_qtp", "cs_pid_qtp", "cs_fopid_qtp"):
        prob = heurtune.load_experiment(name).problem("min")
        while checked < 4 * (2 + ("pid" in name) + ("fopid" in name)):  # 2, 1 and 1 candidates
            x = prob.lower + rng.random(prob.dim) * (prob.upper - prob.lower)
            try:
                systems = heurtune.objectives.qtp.margins.linear_systems(prob, x)
            except Exception:  # no controller for this candidate
                continue
            for key in ("loop_1_1", "loop_1_2", "loop_2_1", "loop_2_2"):
                L = systems[key]
                w = frequency_grid(control.poles(L))[::20]  # every 20th sample: the bound's SVDs cost
                shifted = 1j * w[:, None, None] * np.eye(L.nstates) - L.A
                with np.errstate(all="ignore"):
                    mine = _frequency_response(L)(w)
                    theirs = np.asarray(np.squeeze(L(1j * w)), dtype=complex)
                    states = np.linalg.solve(shifted, np.broadcast_to(L.B, (w.size,) + L.B.shape))[:, :, 0]
                bound = (np.finfo(float).eps * np.linalg.cond(shifted) * np.linalg.norm(states, axis=1)
                         * np.linalg.norm(L.C) + np.finfo(float).eps * abs(float(L.D[0, 0])))
                assert_close(np.abs(mine - theirs) / bound, np.zeros(w.size), rtol=0.0, atol=100.0,
                             because="two backward-stable solves: eps cond(jwI - A) |C| |x| each",
                             err_msg=f"{name} {key}")
                checked += 1
    # a transfer function is evaluated by python-control itself
    tf = control.tf([1.0], [1.0, 2.0, 1.0])
    w = np.array([0.1, 1.0, 10.0])
    assert_close(_frequency_response(tf)(w), 1.0 / (1j * w + 1.0) ** 2, rtol=1e-14,
                 because="python-control's evaluation of a second-order transfer function")
