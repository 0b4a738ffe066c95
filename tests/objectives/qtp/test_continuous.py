"""The continuous-time QTP loop (exponential integration) against independent continuous solutions.

References:
- ``reference_qtp.reference_loop``: the FOLQI loop written anew (plant, Oustaloup filter by
  scipy's zpk2ss, LQR by python-control), integrated by Radau at rtol 1e-11;
- :func:`radau_loop` below: any heurtune ``LinearController`` (LADR, LQI, a double integrator)
  closed around ``reference_qtp.plant_rhs`` and integrated by Radau, with the integrals
  (IAE, J) as quadrature states, for the metrics;
- the phi functions against scipy's ``expm`` of the augmented matrix.

Tolerances are those the issue sets for ``tolerance = 0.005``: the largest level error
0.005 cm, J and IAE within 0.05 %, ts within 0.005 s. The references are solved 1,000 times more
tightly, so the bound is the method's error alone.
"""

import math
from dataclasses import replace as dataclasses_replace

import numpy as np
import pytest
import reference_qtp as ref
import scipy.linalg
from numerics import assert_exact, assert_same_bits
from qtp_cases import IOLQI_NMP, THESIS_MIN, THESIS_NMP, WEAK
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import continuous as cont
from heurtune.objectives.qtp import continuous_kernels as ck
from heurtune.objectives.qtp.controllers import ControllerDesignError
from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset

T = 350.0
TOL = 0.005
IDX = {name: i for i, name in enumerate(METRIC_NAMES)}


def plant_dict(case, factor=1.0):
    p = preset(case)
    return dict(A=[x * factor for x in p.A], a=[x * factor for x in p.a], k=list(p.k), gamma=list(p.gamma),
                levels=list(p.levels))


# -- phi functions ---------------------------------------------------------------------------

def phi_by_expm(M, k_max=4):
    """phi_0 .. phi_k_max of a square M from the exponential of [[M, I, 0..], [0, 0, I..], ...]."""
    n = M.shape[0]
    big = np.zeros(((k_max + 1) * n, (k_max + 1) * n))
    big[:n, :n] = M
    for k in range(k_max):
        big[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = np.eye(n)
    E = scipy.linalg.expm(big)
    return [E[:n, :n]] + [E[:n, k * n:(k + 1) * n] for k in range(1, k_max + 1)]


@pytest.mark.parametrize("z", [-1e3, -40.0, -3.0, -1.0, -0.999, -0.3, -1e-7, 0.0, 1e-9, 0.5, 1.0, 2.0])
def test_scalar_phi_functions(z):
    out = np.empty(5)
    ck.phi_scalar(z, out)
    expected = [p[0, 0] for p in phi_by_expm(np.array([[z]]))]
    # Both sides are accurate to a few ulps of the largest term; 1e-13 leaves room for expm.
    np.testing.assert_allclose(out, expected, rtol=1e-13, atol=1e-300)


@pytest.mark.parametrize("h", [0.01, 0.4, 7.0])
def test_matrix_phi_levels_match_expm(h):
    rng = np.random.default_rng(3)
    # A stable, non-normal block with a Jordan pair and a fast mode, like LADR's observer.
    A = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [-3.0, -5.0, -20.0, 0.3], [0.0, 0.0, 0.0, -60.0]])
    A += 0.01 * rng.standard_normal(A.shape)
    tab = np.empty((ck.N_LEVELS, ck.N_PHI, 4, 4))
    ck.phi_matrix_levels(A, h, tab)
    for level in range(ck.N_LEVELS):
        expected = phi_by_expm(A * h / 2.0 ** level)
        for k in range(ck.N_PHI):
            scale = np.abs(expected[k]).max()
            np.testing.assert_allclose(tab[level, k], expected[k], rtol=0, atol=1e-11 * scale)


# -- the loop against the independent FOLQI model ----------------------------------------------

# The FOLQI loops checked against Radau: name -> (case, gains, realisation).
FOLQI_REFERENCES = {"min": ("min", THESIS_MIN, "direct"), "nmp": ("nmp", THESIS_NMP, "direct"),
                    "weak": ("min", WEAK, "direct"),
                    "weak-split": ("min", WEAK, "integer_split")}  # two exact integrators per pump: a dense block


class _References(dict):
    """Radau solutions of the independent FOLQI loop on a 0.05 s grid, each computed once, when
    a test first asks for it (the weakly damped ones take 10 s each and only `make test-long`
    reads them)."""

    def __missing__(self, name):
        case, gains, realisation = FOLQI_REFERENCES[name]
        t = np.arange(0.0, T + 1e-9, 0.05)
        y, u = ref.reference_loop(plant_dict(case), gains, t, realisation=realisation, rtol=1e-11, atol=1e-12)
        self[name] = (t, y, u)
        return self[name]


@pytest.fixture(scope="module")
def folqi_references():
    return _References()


def continuous_run(case, kind, gains, *, realisation="direct", plant_model="qtp", **scenario):
    loop = ClosedLoop(preset(case), kind, realisation=realisation, plant_model=plant_model)
    sc = Scenario(output_dt=0.05, **scenario)
    return loop, loop.run(loop.controller(gains), sc)


# the weakly damped candidate's Radau references take 10 s each: `make test-long`
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.long) if n.startswith("weak") else n
                                  for n in FOLQI_REFERENCES])
def test_levels_within_the_tolerance_of_the_continuous_reference(folqi_references, name):
    case, gains, realisation = FOLQI_REFERENCES[name]
    t, y_ref, u_ref = folqi_references[name]
    _, sim = continuous_run(case, "folqi", gains, realisation=realisation, tolerance=TOL)
    assert not sim.diverged
    np.testing.assert_allclose(sim.t, t, rtol=0, atol=1e-9)
    assert np.abs(sim.y - y_ref).max() <= TOL
    # The voltages carry the controller's high-frequency gain on the same error.
    assert np.abs(sim.u - u_ref).max() <= 20 * TOL


def test_error_is_fourth_order_in_the_step(folqi_references):
    """Halving the step divides the largest level error by about 2^4 (min, thesis gains)."""
    t, y_ref, _ = folqi_references["min"]
    errors = []
    for h in (1.0, 0.5, 0.25):
        _, sim = continuous_run("min", "folqi", THESIS_MIN, step=h)
        errors.append(np.abs(sim.y - y_ref).max())
    ratios = [errors[i] / errors[i + 1] for i in range(2)]
    # measured 33 and 15 (16 is fourth order; the first pair is not yet asymptotic)
    assert all(r > 10.0 for r in ratios), (errors, ratios)


def test_the_step_rule_meets_the_tolerance_at_the_corners_of_the_bounds():
    """Optimisers go to the bounds. At the corners of the thesis bounds (all Q, all R, both Ki
    and both alpha at a bound or alpha = 1), against the same loop at 0.02 s (itself 1e-7 cm
    from Radau), compared on the 0.01 s output grid (a coarser grid misses the peak error just
    after the disturbance): every stable one within the tolerance at the rule's step. The
    corner Q = 2.5, R = 0.1, Ki = 10, alpha = 0.1 is 5.5e-3 cm off at the structure's 0.125 s:
    the plant under its effective static feedback has a spectral radius of 8.5 1/s, so
    ``feedback_step`` halves its step (measured 5.6e-4 cm at 0.0625 s); the other corners keep
    0.125 s (measured worst 2.1e-3 cm)."""
    import itertools

    loop = ClosedLoop(preset("min"), "folqi")
    worst, shortened = 0.0, []
    for Q, R, Ki, a in itertools.product([0.01, 2.5], [0.1, 5.0], [0.1, 10.0], [0.1, 1.0, 2.0]):
        ctrl = loop.controller(dict(Q11=Q, Q22=Q, Q33=Q, Q44=Q, R11=R, R22=R, Ki1=Ki, Ki2=Ki, alpha1=a, alpha2=a))
        if not loop.stability_margin(ctrl) < 0:
            continue
        sc = Scenario(tolerance=TOL, output_dt=0.01)
        fine = loop.run(ctrl, Scenario(step=0.02, output_dt=0.01))
        sim = loop.run(ctrl, sc)
        worst = max(worst, np.abs(sim.h - fine.h).max())
        if loop.step_plan(ctrl, sc).h.max() < 0.125:
            shortened.append((Q, R, Ki, a))
    assert worst <= TOL
    assert shortened == [(2.5, 0.1, 10.0, 0.1)]


def test_folded_feedback_is_the_static_gain_of_the_fast_modes():
    """``folded_feedback(cc, h)`` is D plus the DC gain of the modal states faster than 1/h,
    checked against python-control's ``dcgain`` of those states as a system of their own."""
    import control

    loop = ClosedLoop(preset("min"), "folqi")
    ctrl = loop.controller(THESIS_MIN)
    cc = cont.ContinuousController.from_linear(ctrl)
    for h in (0.0625, 0.125, 1.0):
        fast = np.abs(cc.lam) * h > 1.0
        assert 0 < fast.sum() < cc.lam.size
        B = np.zeros((int(fast.sum()), 4))
        B[np.arange(B.shape[0]), cc.col[fast]] = cc.b[fast]
        dc = control.ss(np.diag(cc.lam[fast]), B, cc.Cm[:, fast], np.zeros((2, 4))).dcgain()
        np.testing.assert_allclose(cont.folded_feedback(cc, h), cc.D + dc, rtol=1e-12, atol=1e-12)
        # the jitted radius of the step rule is the spectral radius of A + B D_h
        rho = np.abs(np.linalg.eigvals(loop.A + loop.B @ cont.folded_feedback(cc, h))).max()
        assert ck.feedback_radius(loop.A, loop.B, cc.D, cc.lam, cc.b, cc.col, cc.Cm, h) == pytest.approx(rho, rel=1e-12)
    bad = cc.D.copy()
    bad[0, 0] = np.nan
    assert ck.feedback_radius(loop.A, loop.B, bad, cc.lam, cc.b, cc.col, cc.Cm, 0.125) == math.inf
    assert cont.feedback_step(loop.A, loop.B, dataclasses_replace(cc, D=bad), 0.125, TOL) == cont.MIN_STEP


def test_step_rule_computes_each_folded_radius_once_with_the_same_result():
    """``step_rule`` keeps each radius by the number of modes folded (the folded set grows with
    h, so its size names it) and skips it where a norm bound decides; its step and adaptive
    range equal those of the rule written out with a fresh radius at every step tried, on
    random candidates of FOLQI, IOLQI and LQI on both plants and at two tolerances, including
    ones whose step is halved, ones whose range is cut, and ones that the bound decides."""
    from heurtune.objectives.qtp.structures import decision_names, default_bounds

    rng = np.random.default_rng(4)
    halved = cut = bounded = 0
    for kind, count in (("folqi", 120), ("iolqi", 40), ("lqi", 40)):
        names, bounds = decision_names(kind), default_bounds(kind)
        for case in ("min", "nmp"):
            loop = ClosedLoop(preset(case), kind)
            for _ in range(count):
                try:
                    cc = cont.ContinuousController.from_linear(
                        loop.controller({n: rng.uniform(*bounds[n]) for n in names}))
                except ControllerDesignError:
                    continue
                for tol in (TOL, 16 * TOL):
                    radius = cont.FEEDBACK_STEP_RADIUS * (tol / cont.REFERENCE_TOLERANCE) ** 0.25

                    def rho(h, loop=loop, cc=cc):
                        return ck.feedback_radius(loop.A, loop.B, cc.D, cc.lam, cc.b, cc.col, cc.Cm, h)

                    h = 0.25
                    while h > cont.MIN_STEP and h * rho(h) > radius:
                        h *= 0.5
                    top = next((j + 1 for j in range(ck.ADAPTIVE_TOP - 1, 0, -1)
                                if h * 2.0 ** j * rho(h * 2.0 ** j) <= cont.ADAPTIVE_STABILITY_RADIUS), 0)
                    halved += h < 0.25
                    cut += 0 < top < ck.ADAPTIVE_TOP
                    M = loop.A + loop.B @ cont.folded_feedback(cc, h)
                    bounded += h * min(np.abs(M).sum(axis=0).max(), np.abs(M).sum(axis=1).max()) < radius
                    assert cont.feedback_step_and_top(loop.A, loop.B, cc, 0.25, tol) == (h, top)
    assert halved > 0 and cut > 0 and bounded > 0


def test_feedback_step_keeps_the_step_of_ordinary_candidates_and_halves_it_for_a_fast_plant():
    """The thesis gains keep the structure's step (so their plan, and every result made with
    it, is unchanged); a fast feedback halves it until ``h rho <= 0.75``; a looser tolerance
    scales the radius by its fourth root; ``step`` given in the scenario is used as given."""
    loop = ClosedLoop(preset("min"), "folqi")
    sc = Scenario(tolerance=TOL)
    thesis = loop.controller(THESIS_MIN)
    plan = loop.step_plan(thesis, sc)
    assert_exact(plan.h, sc.step_plan("folqi").h)  # the structure's step, unchanged
    corner = loop.controller(dict(Q11=2.5, Q22=2.5, Q33=2.5, Q44=2.5, R11=0.1, R22=0.1, Ki1=10.0, Ki2=10.0,
                                  alpha1=0.1, alpha2=0.1))
    cc = cont.ContinuousController.from_linear(corner)
    h = cont.feedback_step(loop.A, loop.B, cc, 0.125, TOL)
    assert h == 0.0625
    rho = np.abs(np.linalg.eigvals(loop.A + loop.B @ cont.folded_feedback(cc, h))).max()
    assert h * rho <= cont.FEEDBACK_STEP_RADIUS < 2 * h * np.abs(
        np.linalg.eigvals(loop.A + loop.B @ cont.folded_feedback(cc, 2 * h))).max()
    assert loop.step_plan(corner, sc).h.max() == pytest.approx(0.0625)
    # the -30 % plant (areas x 0.7) is faster under the same feedback
    assert loop.step_plan(corner, Scenario(tolerance=TOL, uncertainty=0.7)).h.max() <= 0.0625
    assert loop.step_plan(corner, Scenario(step=0.125)).h.max() == pytest.approx(0.125)
    assert cont.feedback_step(loop.A, loop.B, cc, 0.125, 16 * TOL) >= h


def _steps_taken(loop, ctrl, sc):
    """Steps the continuous kernel takes (accepted ones) for ``ctrl`` under ``sc``."""
    cc = cont.ContinuousController.from_linear(ctrl)
    plan = loop.step_plan(ctrl, sc, cc)
    empty2, empty4 = np.empty((0, 2)), np.empty((0, 4))
    _, n = ck.simulate_continuous(loop._scenario_table(sc), loop._level_per_state, loop._state_op(), loop.op.h,
                                  cc.lam, cc.b, cc.col, cc.Cm, cc.Aq, cc.Bq, cc.Cq, cc.D, cc.channel, plan.table, 3.0,
                                  np.empty(len(METRIC_NAMES)), 0.01, empty2, empty2, empty4)
    return plan, n


def test_adaptive_pairs_lengthen_the_steps_where_the_loop_is_quiet(folqi_references):
    """Under ``tolerance`` FOLQI takes pairs of steps above the rule's step where step doubling
    finds them within the local tolerance: the thesis gains settle after the disturbance and
    take 494 steps instead of 2,804, with the levels as close to Radau as at the rule's step
    (measured 4.8e-5 cm both). An explicit ``step`` keeps every step at it."""
    t, y_ref, _ = folqi_references["min"]
    loop = ClosedLoop(preset("min"), "folqi")
    thesis = loop.controller(THESIS_MIN)
    sc = Scenario(tolerance=TOL, output_dt=0.05)
    plan, n = _steps_taken(loop, thesis, sc)
    assert plan.top == ck.ADAPTIVE_TOP and plan.local_tol == pytest.approx(cont.ADAPTIVE_LOCAL_FRACTION * TOL)
    assert n < plan.n_steps / 4
    fixed = Scenario(step=float(plan.h.max()), output_dt=0.05)
    plan_fixed, n_fixed = _steps_taken(loop, thesis, fixed)
    assert plan_fixed.top == 0 and plan_fixed.local_tol == 0.0 and n_fixed == plan_fixed.n_steps == plan.n_steps
    err_adaptive = np.abs(loop.run(thesis, sc).y - y_ref).max()
    err_fixed = np.abs(loop.run(thesis, fixed).y - y_ref).max()
    assert err_adaptive <= max(2.0 * err_fixed, 1e-4)


def test_adaptive_range_keeps_the_explicit_part_stable():
    """Pairs go up to ``h 2^(top - 1)``, the largest of ``2h, 4h, 8h`` at which the plant under
    the effective static feedback keeps ``step rho <= ADAPTIVE_STABILITY_RADIUS``: 8h (1 s)
    for the thesis gains, 2h for the weakly damped candidate (rho 3.6 1/s at 0.5 s) and for the
    corner whose step the rule halved (2h = 0.125 s); the weakly damped candidate still takes
    most steps at the rule's step, which its oscillation needs (at least half of the plan)."""
    loop = ClosedLoop(preset("min"), "folqi")
    sc = Scenario(tolerance=TOL)
    corner = dict(Q11=2.5, Q22=2.5, Q33=2.5, Q44=2.5, R11=0.1, R22=0.1, Ki1=10.0, Ki2=10.0, alpha1=0.1, alpha2=0.1)
    tops = {}
    for name, gains in (("thesis", THESIS_MIN), ("weak", WEAK), ("corner", corner)):
        ctrl = loop.controller(gains)
        cc = cont.ContinuousController.from_linear(ctrl)
        plan = loop.step_plan(ctrl, sc, cc)
        h, top = float(plan.h.max()), plan.top
        tops[name] = top
        assert cont.adaptive_top(loop.A, loop.B, cc, h) == top
        if top:
            hj = h * 2.0 ** (top - 1)
            assert hj * ck.feedback_radius(loop.A, loop.B, cc.D, cc.lam, cc.b, cc.col, cc.Cm, hj) <= 1.5
        if top < ck.ADAPTIVE_TOP:
            hj = h * 2.0 ** max(top, 1)
            assert hj * ck.feedback_radius(loop.A, loop.B, cc.D, cc.lam, cc.b, cc.col, cc.Cm, hj) > 1.5
        if name == "weak":
            assert _steps_taken(loop, ctrl, sc)[1] > plan.n_steps / 2
    assert tops == {"thesis": ck.ADAPTIVE_TOP, "weak": 2, "corner": 2}


def test_adaptive_pairs_keep_ts_within_its_target_where_the_error_leaves_its_band():
    """No pair is taken across a settling-band crossing, so ts is located between the rule's
    steps. The worst of 600 random LQI candidates on nmp (``benchmarks/step_rule.py``): ts within
    5e-3 s of the loop at 0.02 s (measured 4.5e-3 s; the worst of the same 600 was 1.7e-2 s
    before pairs stopped at a crossing), its levels within the tolerance."""
    import heurtune

    prob = heurtune.load_experiment("cs_lqi_qtp").problem("nmp")
    loop, sc = prob.loop, prob.scenario(prob.tuning_scenario)
    x = np.array([2.5, 2.08249, 1.603759, 2.5, 0.0001, 5.095053, 2.071011, 5.0])
    ctrl, reason, _ = prob._design(x)
    assert reason == ""
    fine = loop.run(ctrl, dataclasses_replace(sc, tolerance=None, step=0.02, output_dt=0.01))
    sim = loop.run(ctrl, dataclasses_replace(sc, output_dt=0.01))
    assert sim.steps < loop.step_plan(ctrl, sc).n_steps / 2  # pairs were taken
    ts = [IDX["ts1"], IDX["ts2"]]
    assert np.abs(sim.metrics[ts] - fine.metrics[ts]).max() <= 5e-3
    assert np.abs(sim.h - fine.h).max() <= TOL


def test_sampled_loop_is_first_order_and_far_less_accurate(folqi_references):
    """Why the continuous loop: the sampled loop's error at the default dt is 5x the
    continuous loop's tolerance, at 30x the steps."""
    t, y_ref, _ = folqi_references["min"]
    loop = ClosedLoop(preset("min"), "folqi")
    sampled = loop.run(loop.controller(THESIS_MIN), Scenario(dt=0.01))
    err_sampled = np.abs(sampled.y[::5] - y_ref).max()
    _, sim = continuous_run("min", "folqi", THESIS_MIN, tolerance=TOL)
    assert err_sampled > 3 * TOL > 3 * np.abs(sim.y - y_ref).max()


# -- any controller, the metrics, the bond graph: against radau_loop --------------------------

def radau_loop(loop, ctrl, *, d=(1.0, 1.0), t_d=50.0, horizon=T, factor=1.0):
    """Independent continuous loop: ``reference_qtp.plant_rhs`` closed by the controller's own
    (A, B, C, D), integrated by Radau with IAE_i and J_j as quadrature states.

    Returns the dense solution of each piece, the operating levels and voltages, and the
    integrals at the end."""
    P = plant_dict(loop.plant.name if loop.plant.name in ("min", "nmp") else "min", factor)
    h0, _ = ref.equilibrium(plant_dict(loop.plant.name))
    _, u0 = ref.equilibrium(P)
    A, B, C, D = ctrl.A, ctrl.B, ctrl.C, ctrl.D
    nz = A.shape[0]

    def parts(s, dist):
        h, z = s[:4], s[4:4 + nz]
        w = h - h0
        w[:2] += dist
        u = u0 + C @ z + D @ w
        return h, z, w, u

    def rhs(t, s, dist):
        h, z, w, u = parts(s, dist)
        return np.concatenate([ref.plant_rhs(h, u, P), A @ z + B @ w, np.abs(w[:2]), u * u])

    s0 = np.concatenate([h0, np.zeros(nz), np.zeros(4)])
    pieces = []
    for t0, t1, dist in [(0.0, t_d, np.zeros(2)), (t_d, horizon, np.asarray(d, dtype=float))]:
        sol = solve_ivp(rhs, (t0, t1), s0, method="Radau", args=(dist,), rtol=1e-11, atol=1e-12, dense_output=True)
        assert sol.success
        pieces.append((t0, t1, dist, sol))
        s0 = sol.y[:, -1]
    return pieces, h0, u0, s0[-4:], parts


def reference_metrics(pieces, h0, integrals, parts, band_pct=3.0):
    """Mp, ts (last exit from the band, by brentq on the dense solution), IAE and J."""
    t0, t1, dist, sol = pieces[1]
    out = {}
    grid = np.linspace(t0, t1, 700_001)
    Y = sol.sol(grid)
    for i in range(2):
        e = np.abs(Y[i] - h0[i] + dist[i])
        k = int(np.argmax(e))
        out[f"Mp{i + 1}"] = e[k] / h0[i] * 100.0
        band = band_pct / 100.0 * h0[i]
        outside = np.flatnonzero(e > band)
        if outside.size == 0:
            out[f"ts{i + 1}"] = 0.0
        else:
            j = outside[-1]
            f = lambda t: abs(sol.sol(t)[i] - h0[i] + dist[i]) - band  # noqa: B023, E731
            out[f"ts{i + 1}"] = brentq(f, grid[j], grid[j + 1], xtol=1e-12) - t0
        out[f"IAE{i + 1}"] = integrals[i]
        out[f"J{i + 1}"] = integrals[2 + i]
    return out


CONTROLLERS = {
    "folqi-min": ("min", "folqi", THESIS_MIN, {}),
    "folqi-weak": ("min", "folqi", WEAK, {}),
    "iolqi-nmp": ("nmp", "iolqi", IOLQI_NMP, {}),
    "lqi-min": ("min", "lqi", dict(Q11=1.0, Q22=1.0, Q33=0.5, Q44=0.5, Qi1=0.05, Qi2=0.05, R11=1.0, R22=1.0), {}),
}
# The scenario each case is checked under, and the relative IAE bound it meets there. The weakly
# damped candidate oscillates for the whole 300 s: its level error of 3e-4 cm at tolerance
# 0.005 (step 0.125 s) adds up to 0.11 % of its IAE, so it meets the 0.05 % target only at a
# tolerance 16 times tighter (step 0.0625 s, measured 0.007 %). The step rule is per problem,
# not yet per candidate (docs/model.md, "Step rule").
SCENARIOS = {"folqi-weak": (dict(tolerance=TOL / 16), 5e-4)}


@pytest.fixture(scope="module")
def ladr_gains():
    """Thesis Table 4.7's LADR of the minimum-phase plant (observer blocks: dense, complex)."""
    from heurtune.objectives.qtp.structures import decision_names
    from heurtune.objectives.qtp.thesis.printed import printed_row

    row = printed_row("4.7", "min-ladr")
    return {n: float(row[n]) for n in decision_names("ladr")}


# the weakly damped FOLQI and the LADR take Radau 10-20 s each (tens of thousands of steps at
# rtol 1e-11): `make test-long` (docs/testing.md, "Two tiers")
LONG = ("folqi-weak", "ladr-min")


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.long) if name in LONG else name
                                  for name in [*CONTROLLERS, "ladr-min"]])
def test_metrics_within_the_targets_of_the_continuous_reference(name, ladr_gains):
    case, kind, gains, options = CONTROLLERS[name] if name != "ladr-min" else ("min", "ladr", ladr_gains, {})
    loop = ClosedLoop(preset(case), kind, **options)
    ctrl = loop.controller(gains)
    pieces, h0, _, integrals, parts = radau_loop(loop, ctrl)
    expected = reference_metrics(pieces, h0, integrals, parts)
    keys, iae_rel = SCENARIOS.get(name, (dict(tolerance=TOL), 5e-4))
    sim = loop.run(ctrl, Scenario(**keys), record=False)
    assert not sim.diverged
    m = dict(zip(METRIC_NAMES, sim.metrics))
    for i in (1, 2):
        assert m[f"J{i}"] == pytest.approx(expected[f"J{i}"], rel=5e-4), name
        assert m[f"IAE{i}"] == pytest.approx(expected[f"IAE{i}"], rel=iae_rel), name
        assert abs(m[f"ts{i}"] - expected[f"ts{i}"]) <= 0.005, name
        # Mp: the jump at t_d or a refined maximum; 0.005 cm on a 1 cm deviation
        assert m[f"Mp{i}"] == pytest.approx(expected[f"Mp{i}"], abs=0.005 / h0[i - 1] * 100), name
    # the levels of the dense output against the reference, at the default tolerance
    rec = loop.run(ctrl, Scenario(tolerance=TOL, output_dt=0.5))
    for t0, t1, _, sol in pieces:
        mask = (rec.t >= t0) & (rec.t < t1)
        assert np.abs(rec.h[mask] - sol.sol(rec.t[mask])[:4].T).max() <= TOL, name


def test_bond_graph_model_follows_the_level_model():
    """The pressure formulation simulates the same loop: levels agree to the tolerance."""
    loop_h = ClosedLoop(preset("min"), "folqi")
    loop_p = ClosedLoop(preset("min"), "folqi", plant_model="qtp_bond_graph")
    ctrl = loop_h.controller(THESIS_MIN)
    pieces, _, _, _, _ = radau_loop(loop_h, ctrl)
    sc = Scenario(tolerance=TOL, output_dt=0.5)
    sim_p = loop_p.run(ctrl, sc)
    assert sim_p.P is not None
    for t0, t1, _, sol in pieces:
        mask = (sim_p.t >= t0) & (sim_p.t < t1)
        assert np.abs(sim_p.h[mask] - sol.sol(sim_p.t[mask])[:4].T).max() <= TOL
    np.testing.assert_allclose(sim_p.metrics, loop_h.run(ctrl, sc, record=False).metrics, rtol=1e-9)


def test_uncertainty_and_input_disturbance_segments():
    """A +30 % plant and an input step at 120 s (a third segment, graded): levels within the
    tolerance of Radau on the same loop."""
    loop = ClosedLoop(preset("min"), "folqi")
    ctrl = loop.controller(THESIS_MIN)
    sc = Scenario(tolerance=TOL, output_dt=0.25, uncertainty=1.3, input_disturbance=(0.3, -0.2),
                  input_disturbance_time=120.0)
    sim = loop.run(ctrl, sc)
    P = plant_dict("min", 1.3)
    h0, _ = ref.equilibrium(plant_dict("min"))
    _, u0 = ref.equilibrium(P)
    A, B, C, D = ctrl.A, ctrl.B, ctrl.C, ctrl.D

    def rhs(t, s, d, ui):
        h, z = s[:4], s[4:]
        w = h - h0
        w[:2] += d
        u = u0 + C @ z + D @ w
        return np.concatenate([ref.plant_rhs(h, u + ui, P), A @ z + B @ w])

    s0 = np.concatenate([h0, np.zeros(A.shape[0])])
    worst = 0.0
    for t0, t1, d, ui in [(0, 50, (0, 0), (0, 0)), (50, 120, (1, 1), (0, 0)), (120, T, (1, 1), (0.3, -0.2))]:
        sol = solve_ivp(rhs, (t0, t1), s0, method="Radau", args=(np.array(d, float), np.array(ui, float)),
                        rtol=1e-11, atol=1e-12, dense_output=True)
        mask = (sim.t >= t0) & (sim.t < t1)
        worst = max(worst, np.abs(sim.h[mask] - sol.sol(sim.t[mask])[:4].T).max())
        s0 = sol.y[:, -1]
    assert worst <= TOL


# -- switches: saturation with anti-windup, tanks that overflow or run dry -----------------------

def projected_reference(P, K, H, U, d, t_d, horizon, t_eval):
    """Continuous proportional control ``u = clip(u0 - K (y - y0))`` of the plant of
    reference_qtp with tanks of heights ``H``, by DOP853 at rtol 1e-11: a level's slope is 0
    when it sits at the floor and falls or at its rim and rises. Nothing from heurtune."""
    h0, u0 = ref.equilibrium(P)
    Hn = np.asarray(H, dtype=float)

    def rhs(t, h, dist):
        u = np.clip(u0 - K * (h[:2] + dist - h0[:2]), *U)
        dh = ref.plant_rhs(h, u, P)
        dh[(h <= 0.0) & (dh < 0.0)] = 0.0
        dh[(h >= Hn) & (dh > 0.0)] = 0.0
        return dh

    out = np.empty((len(t_eval), 4))
    h = h0.copy()
    for t0, t1, dist in [(0.0, t_d, np.zeros(2)), (t_d, horizon, np.asarray(d, dtype=float))]:
        mask = (t_eval >= t0) & ((t_eval < t1) if t1 < horizon else (t_eval <= t1))
        sol = solve_ivp(rhs, (t0, t1), h, args=(dist,), method="DOP853", rtol=1e-11, atol=1e-12, dense_output=True)
        assert sol.success
        out[mask] = sol.sol(t_eval[mask]).T
        h = np.clip(sol.y[:, -1], 0.0, Hn)
    return out


def test_saturation_and_overflow_located_inside_steps_match_an_independent_model():
    """A static gain and a large measured-level step (-3, +15) cm on the `min` plant with low
    tanks: pump 1 runs at 10 V and pump 2 at 0 V, tanks 1 and 4 overflow, tank 3 runs dry. Each
    switch is located inside its step; the sampled loop, which clips at step ends, is 6.6e-3 cm
    off at dt = 0.05 s (tests/objectives/qtp/test_physical_limits.py)."""
    from heurtune.objectives.qtp.controllers import LinearController
    from heurtune.objectives.qtp.model import QTPParams

    base = preset("min")
    H, U, K = (18.0, 18.0, 10.0, 9.0), (0.0, 10.0), 3.0
    plant = QTPParams(A=base.A, a=base.a, k=base.k, gamma=base.gamma, levels=base.levels, height=H, u_range=U,
                      name="low")
    D = np.zeros((2, 4))
    D[0, 0] = D[1, 1] = -K
    ctrl = LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ())
    d = (-3.0, 15.0)
    sc = Scenario(horizon=40.0, disturbance_time=5.0, output_disturbance=d, limits="physical",
                  tolerance=TOL, output_dt=0.05)
    sim = ClosedLoop(plant, "iolqi").run(ctrl, sc)
    h_ref = projected_reference(plant_dict("min"), K, H, U, d, 5.0, 40.0, sim.t)
    # the limits are active: two rims and an empty tank
    assert (h_ref[:, 0] >= 18.0 - 1e-9).sum() > 100 and (h_ref[:, 2] <= 1e-9).sum() > 100
    assert np.abs(sim.h - h_ref).max() <= 0.1 * TOL  # measured 6.9e-5 cm
    assert sim.metrics[[METRIC_NAMES.index(k) for k in ("hmin", "hmax", "umin", "umax")]].tolist() == [0, 18, 0, 10]
    assert (sim.h >= 0.0).all() and (sim.h <= np.array(H)).all()
    assert (sim.u >= 0.0).all() and (sim.u <= 10.0).all()


@pytest.mark.parametrize("case, gains, keys", [
    # thesis gains, narrow pump range: both pumps saturate at 2.2 V and slide along it
    ("min", THESIS_MIN, dict(saturation=(2.2, 3.0))),
    ("min", THESIS_MIN, dict(saturation=(2.2, 3.0), output_disturbance=(3.0, -2.0))),
    # the README's best nmp FOLQI design asks for -3.7 V: with the physical limits pump 2 sits at 0 V
    ("nmp", dict(Q11=0.01, Q22=1.783, Q33=1.318, Q44=0.01, R11=0.1, R22=0.4171, Ki1=0.1, Ki2=10.0,
                 alpha1=0.1358, alpha2=0.1807), dict(limits="physical")),
])
def test_anti_windup_converges_to_the_sampled_loop_at_a_fine_step(case, gains, keys):
    """Conditional integration (a saturated pump's controller states held) in continuous time
    slides along the limit, a Filippov solution that no ODE solver resolves; the sampled loop
    chatters towards the same solution as dt -> 0. Against the sampled loop at dt = 0.0005 s
    (itself about 1e-4 cm off: first order, 1.8e-3 cm at dt = 0.01 s) the continuous loop at
    tolerance 0.005 is within a fifth of the tolerance (measured 1.0e-4, 2.8e-5 and 5.6e-4 cm,
    with the sliding pump pinned at its limit; the sampled loop at dt = 0.01 s: 1.8e-3, 0.8e-3
    and 2.4e-3 cm), and J within 0.05 % (measured 4e-7). Sliding phases are simulated at h/16
    and are first order in the controller states (docs/model.md)."""
    loop = ClosedLoop(preset(case), "folqi")
    ctrl = loop.controller(gains)
    fine = loop.run(ctrl, Scenario(dt=0.0005, **keys))
    sim = loop.run(ctrl, Scenario(tolerance=TOL, output_dt=0.1, **keys))
    assert not sim.diverged
    assert np.abs(sim.h - fine.h[::200]).max() <= 0.2 * TOL
    m, mf = dict(zip(METRIC_NAMES, sim.metrics)), dict(zip(METRIC_NAMES, fine.metrics))
    assert m["J1"] + m["J2"] == pytest.approx(mf["J1"] + mf["J2"], rel=5e-4)
    lo, hi = keys.get("saturation", (0.0, 10.0))
    assert lo <= m["umin"] and m["umax"] <= hi and m["umin"] == lo


# -- plan, records, divergence, errors ----------------------------------------------------------

def test_step_plan_starts_a_graded_segment_at_each_discontinuity():
    plan = Scenario(tolerance=TOL, input_disturbance=(0.1, 0.0), input_disturbance_time=200.0).step_plan("folqi")
    np.testing.assert_allclose(plan.t0, [0.0, 50.0, 200.0])
    assert plan.graded.tolist() == [False, True, True] and plan.post.tolist() == [False, True, True]
    np.testing.assert_allclose(plan.h * plan.steps, [50.0, 150.0, 150.0])
    assert np.all(plan.h <= cont.step_for_tolerance(TOL, "folqi") + 1e-12)
    # no disturbance: one segment
    assert Scenario(tolerance=TOL, output_disturbance=(0.0, 0.0)).step_plan().t0.tolist() == [0.0]


def test_step_rule_is_fourth_root_of_the_tolerance():
    assert cont.step_for_tolerance(0.005, "folqi") == pytest.approx(0.125)
    assert cont.step_for_tolerance(0.005 * 16, "folqi") == pytest.approx(0.25)
    assert cont.step_for_tolerance(0.005, "ladr") == pytest.approx(0.05)
    assert cont.step_for_tolerance(0.005) == pytest.approx(0.05)  # unknown type: the smallest
    assert cont.step_for_tolerance(1e9, "folqi") == cont.MAX_STEP


def test_recorded_and_unrecorded_runs_have_the_same_metrics():
    loop = ClosedLoop(preset("nmp"), "folqi")
    ctrl = loop.controller(THESIS_NMP)
    sc = Scenario(tolerance=TOL)
    a = loop.run(ctrl, sc)
    b = loop.run(ctrl, sc, record=False)
    # one compiled lane; an unrecorded run hands it record arrays of no rows
    assert_same_bits(a.metrics, b.metrics, because="shared kernel")
    assert a.y.shape == (35001, 2) and a.t[-1] == T
    assert_same_bits(loop.metrics(a, sc, 3.0), a.metrics, because="same code")
    # the record at t_d is the right limit: the measured step is in it
    k = int(round(50.0 / 0.01))
    assert a.y[k, 0] - a.h[k, 0] == pytest.approx(1.0)
    assert a.y[k - 1, 0] == pytest.approx(a.h[k - 1, 0])


def test_a_diverging_candidate_is_flagged_finite_and_infeasible():
    """The weak candidate at a 1 s step: the explicit part is unstable. The run is flagged, its
    metrics NaN, and the problem reports a failed, infeasible evaluation."""
    loop = ClosedLoop(preset("min"), "folqi")
    sim = loop.run(loop.controller(WEAK), Scenario(step=1.0))
    assert sim.diverged and np.isnan(sim.metrics).all()
    assert np.isnan(sim.y[-1]).all() and np.isfinite(sim.y[0]).all()
    import heurtune

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    x = np.array([WEAK[n] for n in prob.names])
    ev = prob.evaluate(x, Scenario(step=1.0))
    assert not ev.feasible[0] and ev.reason[0] == "diverged" and np.isfinite(ev.f[0])


def test_problem_evaluates_continuous_scenarios_on_every_device():
    import heurtune

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    X = np.array([[THESIS_MIN[n] for n in prob.names], [WEAK[n] for n in prob.names]])
    sc = Scenario(tolerance=TOL)
    cpu = prob.evaluate(X, sc)
    prob.set_device("cpu-batch")
    batch = prob.evaluate(X, sc)
    # The batched design (batch_design) rounds differently from the one-by-one design; the
    # simulation is the same kernel. The objective agrees to 1e-12; small metrics (ess of
    # 1e-3 %) carry that rounding relatively larger (measured 2e-11).
    np.testing.assert_allclose(cpu.f, batch.f, rtol=1e-12)
    np.testing.assert_allclose(cpu.metrics, batch.metrics, rtol=1e-9)


@pytest.mark.parametrize("kwargs, message", [
    (dict(tolerance=0.0), r"scenario.tolerance \(the largest level error in cm\) must be a finite number > 0, got 0.0"),
    (dict(tolerance=-1.0), r"scenario.tolerance .* must be a finite number > 0, got -1.0"),
    (dict(tolerance=math.inf), r"scenario.tolerance .* must be a finite number > 0, got inf"),
    (dict(tolerance=math.nan), r"scenario.tolerance .* must be a finite number > 0, got nan"),
    (dict(tolerance=TOL, output_dt=0.0), r"scenario.output_dt .* must be a finite number > 0, got 0.0"),
    (dict(step=-0.1), r"scenario.step .* must be a finite number > 0, got -0.1"),
    (dict(step=400.0), r"scenario.step must not exceed scenario.horizon \(350.0\), got 400.0"),
    (dict(tolerance=TOL, output_dt=0.3), r"scenario.horizon \(350.0\) must be a whole number of scenario.output_dt"),
    (dict(tolerance=1e-30), r"scenario.tolerance = 1e-30 is below what the loop can meet"),
    (dict(tolerance=TOL, step=0.1), r"scenario.tolerance and scenario.step both set"),
    (dict(tolerance=TOL, noise_sd=0.1), r"scenario.noise_sd > 0 needs a digital controller"),
    (dict(noise_sd=0.1), r"scenario.noise_sd > 0 needs a digital controller: .* give controller.sample_time"),
    (dict(dt=0.01, tolerance=TOL), r"scenario.dt \(the sampled loop's sample period\) and scenario.tolerance"),
    (dict(dt=0.01, step=0.1), r"scenario.dt .* and scenario.step .* both set"),
    (dict(dt=0.0), r"scenario.dt \(the sample period in s\) must be > 0, got 0.0"),
    (dict(dt=-0.01), r"scenario.dt \(the sample period in s\) must be > 0, got -0.01"),
    (dict(dt=400.0), r"scenario.dt \(400.0\) must not exceed scenario.horizon \(350.0\)"),
])
def test_bad_continuous_keys_get_one_line_errors(kwargs, message):
    with pytest.raises(ConfigError, match=message) as exc:
        Scenario(**kwargs)
    assert "\n" not in str(exc.value)


def test_step_budget_is_stated():
    """A tolerance that cannot be met within the budget of steps is refused, naming it (the
    budget check uses the smallest step of any controller type)."""
    with pytest.raises(ConfigError, match=r"more than the budget of 10,000,000; raise scenario.tolerance"):
        Scenario(horizon=35000.0, disturbance_time=50.0, tolerance=1e-9)


def test_cli_refuses_a_bad_tolerance_with_exit_code_2(tmp_path, capsys):
    from heurtune.runner.experiment import run

    cfg = tmp_path / "exp.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\n[scenario]\ntolerance = -1.0\n')
    assert run([str(cfg), "--smoke", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "scenario.tolerance" in err and not (tmp_path / "out").exists()


# -- the digital controller: [controller] sample_time ------------------------------------------

def config_experiment(tmp_path, text):
    import heurtune

    cfg = tmp_path / "exp.toml"
    cfg.write_text(text)
    return heurtune.load_experiment(str(cfg))


# problem_id of cs_folqi_qtp's cases in heurtune before the continuous loop became the default
# (commit e1bb82f, where the config said [scenario] dt = 0.01)
SAMPLED_RELEASE_IDS = {"min": "b82a33e350f3", "nmp": "ed3cb6596bba"}


def test_sample_time_is_the_sampled_loop_of_an_old_dt(tmp_path, capsys):
    """``sample_time = 0.01`` is the sampled loop of earlier versions: same problem, same id as
    that release, same numbers as an old config's ``[scenario] dt = 0.01``, which is read as
    ``sample_time`` with a warning naming both keys."""
    from heurtune.runner.experiment import problem_id

    old = config_experiment(tmp_path, 'extends = "cs_folqi_qtp"\n[scenario]\ndt = 0.01\n')
    warning = capsys.readouterr().err
    assert warning.count("\n") == 1 and "scenario.dt = 0.01 is read as controller.sample_time = 0.01" in warning
    digital = config_experiment(tmp_path, 'extends = "cs_folqi_qtp"\n[controller]\nsample_time = 0.01\n')
    assert capsys.readouterr().err == ""
    rng = np.random.default_rng(5)
    for case in old.cases:
        assert problem_id(digital, case) == problem_id(old, case) == SAMPLED_RELEASE_IDS[case]
        a, b = old.problem(case), digital.problem(case)
        assert a.identity() == b.identity()
        X = a.lower + rng.random((6, a.dim)) * (a.upper - a.lower)
        ea, eb = a.evaluate(X), b.evaluate(X)
        # one problem, read from two spellings of the config
        assert_same_bits(ea.f, eb.f, because="same code")
        assert_same_bits(ea.metrics, eb.metrics, because="same code")


def test_a_long_sample_period_steps_the_plant_between_samples():
    """A digital controller at 0.1 s (slower ones destabilise the thesis gains: at 0.2 s a
    level reaches 138 cm, at 0.5 s the loop diverges): the voltages are held for 0.1 s and the
    plant is stepped twice by RK4 in between. Against the same sampled controller with the
    plant solved by DOP853 at rtol 1e-11 between samples, the levels agree to 1e-9 cm (this
    plant is slow: one RK4 step of 0.1 s would be 1.3e-10 cm off too; the substeps matter for
    longer periods and faster plants, and a wrong substep would be far off)."""
    loop = ClosedLoop(preset("min"), "folqi")
    ctrl = loop.controller(THESIS_MIN)
    sc = Scenario(horizon=100.0, dt=0.1)
    assert sc.plant_substeps == 2 and Scenario(dt=0.05).plant_substeps == 1
    sim = loop.run(ctrl, sc)
    dc = ctrl.discretise(0.1)
    P = plant_dict("min")
    h0, u0 = ref.equilibrium(P)
    h, z = h0.copy(), np.zeros(dc.n_states)
    worst = 0.0
    for k in range(sc.n_steps + 1):
        worst = max(worst, np.abs(h - sim.h[k]).max())
        w = h - h0
        if k >= sc.disturbance_index:
            w[:2] += 1.0
        u = u0 + dc.Cc @ z + dc.Dc @ w
        if k == sc.n_steps:
            break
        z = dc.step(z, w)
        sol = solve_ivp(lambda t, x, v: ref.plant_rhs(x, v, P), (0.0, 0.1), h, args=(u,), method="DOP853",
                        rtol=1e-11, atol=1e-12)
        h = sol.y[:, -1]
    assert worst < 1e-9


@pytest.mark.parametrize("text, message", [
    ("[controller]\nsample_time = 0.0\n", r"controller.sample_time must be a finite number > 0 \(s\), got 0.0"),
    ("[controller]\nsample_time = nan\n", r"controller.sample_time: expected a number, got nan"),  # the schema
    ("[controller]\nsample_time = -0.01\n", r"controller.sample_time must be a finite number > 0 \(s\), got -0.01"),
    ("[controller]\nsample_time = 0.01\n[scenario]\ntolerance = 0.005\n",
     r"controller.sample_time and scenario.tolerance both set"),
    ("[controller]\nsample_time = 0.02\n[scenario]\ndt = 0.01\n",
     r"controller.sample_time \(0.02\) and scenario.dt \(0.01\) both set"),
    ("[controller]\nsample_time = 0.3\n[scenario]\ndt = 0.3\n",
     r"controller.sample_time \(0.3\) must divide scenario.horizon \(350\)"),
    ("[controller]\nsample_time = 400.0\n[scenario]\ndt = 400.0\n",
     r"controller.sample_time \(400.0\) must not exceed scenario.horizon"),
])
def test_bad_sample_times_get_one_line_errors(tmp_path, text, message):
    with pytest.raises(ConfigError, match=message) as exc:
        config_experiment(tmp_path, 'extends = "cs_folqi_qtp"\n' + text)
    assert "\n" not in str(exc.value)


def test_an_experiment_runs_the_continuous_loop_end_to_end(tmp_path, capsys):
    """A config that sets [scenario] tolerance runs, resumes and is a problem of its own (its
    own problem_id, so that its runs never mix with the sampled loop's)."""
    import pandas as pd

    from heurtune.runner.experiment import run

    cfg = tmp_path / "cont.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\n[plant]\ncases = ["min"]\n[scenario]\ntolerance = 0.005\n')
    out = tmp_path / "out"
    args = [str(cfg), "--smoke", "--runs", "1", "--max-epochs", "1", "--no-figures", "--out", str(out)]
    assert run(args) == 0
    runs = pd.read_parquet(out / "runs.parquet")
    assert len(runs) == 1 and runs.status.iloc[0] == "feasible" and np.isfinite(runs["J@nominal"].iloc[0])
    import heurtune
    from heurtune.runner.experiment import problem_id

    sampled = config_experiment(tmp_path, 'extends = "cs_folqi_qtp"\n[controller]\nsample_time = 0.01\n')
    assert runs.problem_id.iloc[0] != problem_id(sampled, "min")
    assert runs.problem_id.iloc[0] == problem_id(heurtune.load_experiment("cs_folqi_qtp"), "min")  # the default
    assert run(args) == 0  # resumes: nothing to redo
    assert pd.read_parquet(out / "runs.parquet").equals(runs)
    assert "1 of 1 runs" not in capsys.readouterr().out.split("\n")[-3:]


def test_problem_id_of_sampled_scenarios_is_unchanged(tmp_path):
    """The new keys enter a problem's identity only when set, so earlier results keep their ids."""
    prob = config_experiment(tmp_path, 'extends = "cs_folqi_qtp"\n[controller]\nsample_time = 0.01\n').problem("min")
    scenario = prob.identity()["scenario"]
    assert not {"tolerance", "step", "output_dt"} & set(scenario) and scenario["dt"] == 0.01
