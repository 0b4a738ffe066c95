"""Public API: load_experiment, Problem.evaluate / simulate / report, failure handling."""

import numpy as np
import pytest
from numerics import assert_close, assert_exact, assert_same_bits

import heurtune
from heurtune.core.problem import FAILED_OBJECTIVE, FAILED_VIOLATION
from heurtune.objectives.qtp.problem import OBJECTIVES

THESIS_MIN = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
                  Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


@pytest.fixture(scope="module")
def problem():
    return heurtune.load_experiment("cs_folqi_qtp").problem("min")


def vector(problem, values):
    return np.array([values[n] for n in problem.names])


def test_problem_shape(problem):
    assert problem.names == ("Q11", "Q22", "Q33", "Q44", "R11", "R22", "Ki1", "Ki2", "alpha1", "alpha2")
    assert_exact(problem.lower, [0.01] * 4 + [0.1] * 2 + [0.1] * 2 + [0.1] * 2)  # the bounds' literals
    assert_exact(problem.upper, [2.5] * 4 + [5.0] * 2 + [10.0] * 2 + [2.0] * 2)
    assert problem.constraint_names == ("Mp1", "Mp2", "ts1", "ts2", "ess1", "ess2")
    assert set(problem.scenarios) == {"nominal", "-30%", "+30%"}


def test_thesis_gains_are_feasible_and_objective_is_effort(problem):
    ev = problem.evaluate(vector(problem, THESIS_MIN))
    assert ev.feasible[0] and ev.reason[0] == ""
    m = dict(zip(ev.metric_names, ev.metrics[0]))
    assert ev.f[0] == pytest.approx(m["J1"] + m["J2"])
    # The additive 1 cm step on the measured level gives Mp = 1 / h0 exactly (thesis Table 4.8).
    assert m["Mp1"] == pytest.approx(100 / 16.47, rel=1e-9)
    assert m["Mp2"] == pytest.approx(100 / 16.71, rel=1e-9)
    # Constraints are normalised by their limits (Mp 10 %, ts 70 s, ess 1 %).
    expected_g = [m["Mp1"] / 10 - 1, m["Mp2"] / 10 - 1, m["ts1"] / 70 - 1, m["ts2"] / 70 - 1,
                  m["ess1"] - 1, m["ess2"] - 1]
    np.testing.assert_allclose(ev.g[0], expected_g, rtol=1e-12)


def test_effort_scales_with_the_square_of_the_uncertainty_factor(problem):
    rep = problem.report(THESIS_MIN)
    # The equilibrium input scales with the factor; the transient part is small (REFERENCE.md 1).
    assert rep.loc["-30%", "J"] / rep.loc["nominal", "J"] == pytest.approx(0.49, rel=0.02)
    assert rep.loc["+30%", "J"] / rep.loc["nominal", "J"] == pytest.approx(1.69, rel=0.02)


def test_batch_evaluation_is_deterministic_and_row_independent(problem):
    rng = np.random.default_rng(0)
    X = problem.lower + rng.random((6, problem.dim)) * (problem.upper - problem.lower)
    a = problem.evaluate(X)
    b = problem.evaluate(X[::-1])
    assert_same_bits(a.f, b.f[::-1], because="shared kernel")
    assert_same_bits(a.g, b.g[::-1], because="shared kernel")
    single = problem.evaluate(X[2])
    assert_same_bits(single.f[0], a.f[2], because="shared kernel")


@pytest.mark.parametrize("change, reason", [
    (dict(alpha1=np.nan), "invalid_parameter"),
    (dict(alpha1=3.0), "invalid_parameter"),     # outside the realisable [0.1, 2]
    (dict(R11=-1.0), "riccati_failed"),           # R must be positive definite
    (dict(alpha1=2.0, alpha2=2.0, Ki1=10.0, Ki2=10.0), "unstable"),
])
def test_failed_candidates_are_flagged_not_raised(problem, change, reason):
    ev = problem.evaluate(vector(problem, dict(THESIS_MIN, **change)))
    assert ev.reason[0] == reason
    assert ev.f[0] == FAILED_OBJECTIVE and np.isfinite(ev.f[0])  # exact: the constant, stored
    assert np.all(ev.g[0] > 0) and np.all(np.isfinite(ev.g[0]))
    assert not ev.feasible[0]


def test_diverging_simulation_is_flagged(problem, monkeypatch):
    """Even if the linear check passed, a run that blows up is a flagged failure."""
    monkeypatch.setattr(problem.loop, "stability_margin", lambda ctrl: -1.0)
    ev = problem.evaluate(vector(problem, dict(THESIS_MIN, alpha1=2.0, alpha2=2.0, Ki1=10.0, Ki2=10.0)))
    assert ev.reason[0] == "diverged" and ev.f[0] == FAILED_OBJECTIVE  # exact: the constant


def test_simulate_returns_trajectories(problem):
    df = problem.simulate(THESIS_MIN, "+30%")
    assert list(df.columns) == ["t", "h1", "h2", "h3", "h4", "y1", "y2", "u1", "u2"]
    assert len(df) == 35001 and df.t.iloc[-1] == pytest.approx(350.0)
    # Before the disturbance the plant rests at its operating point.
    assert df.loc[df.t < 50, "h1"].sub(16.47).abs().max() < 1e-9
    assert (df.y1 - df.h1).iloc[-1] == pytest.approx(1.0)


def test_evaluate_rejects_wrong_shapes(problem):
    with pytest.raises(heurtune.ConfigError, match="shape"):
        problem.evaluate(np.zeros((2, 3)))


def test_values_parse_and_bounds(problem):
    x = problem.parse(",".join(f"{k}={v}" for k, v in THESIS_MIN.items()))
    assert_exact(x, vector(problem, THESIS_MIN))  # the literals, printed and parsed back
    with pytest.raises(heurtune.ConfigError, match="outside its bounds"):
        problem.parse(",".join(f"{k}={v}" for k, v in dict(THESIS_MIN, Ki1=11).items()))
    with pytest.raises(heurtune.ConfigError, match="unknown variable 'Q55'"):
        problem.values(dict(THESIS_MIN, Q55=1.0))


@pytest.mark.parametrize("name", ["cs_folqi_qtp"])
def test_both_cases_load(name):
    exp = heurtune.load_experiment(name)
    for case in exp.cases:
        p = exp.problem(case)
        assert p.evaluate((p.lower + p.upper) / 2).f.shape == (1,)


def test_unstable_candidates_get_graded_violations(problem):
    """The less unstable of two unstable designs has the smaller violation."""
    mild = dict(THESIS_MIN, alpha1=2.0, alpha2=2.0, Ki1=1.0, Ki2=1.0)
    wild = dict(THESIS_MIN, alpha1=2.0, alpha2=2.0, Ki1=10.0, Ki2=10.0)
    ev = problem.evaluate(np.vstack([vector(problem, mild), vector(problem, wild)]))
    assert list(ev.reason) == ["unstable", "unstable"]
    assert FAILED_VIOLATION < ev.g[0, 0] < ev.g[1, 0]


@pytest.mark.parametrize("extra", [
    dict(),
    dict(noise_sd=0.05, noise_seed=3, input_disturbance=(0.3, -0.2), input_disturbance_time=120.0),
    dict(saturation=(0.0, 3.6), horizon=200.0, disturbance_time=51.2),  # t_d on a block edge (5120 = 20 x 256)
])
def test_in_loop_metrics_equal_those_of_the_recorded_trajectory(problem, extra):
    """The kernel folds its metrics from a buffer as it runs; loop_metrics recomputes them from
    the recorded y and u. Same samples, sums grouped alike: equal to 1e-12 relative."""
    from heurtune.objectives.qtp.loop import Scenario

    sc = Scenario(dt=0.01, **extra)  # the sampled loop: its metrics are sums over the samples
    loop = problem.loop
    ctrl = loop.controller(THESIS_MIN)
    lean = loop.run(ctrl, sc, record=False)
    full = loop.run(ctrl, sc)
    np.testing.assert_allclose(lean.metrics, loop.metrics(full, sc, 3.0), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("objective", ["effort", "iae"])
def test_bookkeeping_of_simulated_candidates_equals_the_general_path(problem, objective, monkeypatch, tmp_path):
    """When every candidate was simulated, ``evaluate_scenarios`` skips the masks of failed
    candidates (``_simulated_evaluations``): the same objective, constraints and feasibility,
    bit for bit, for one candidate and for batches, under one scenario and several."""
    if objective != "effort":
        path = tmp_path / "iae.toml"
        path.write_text(f'extends = "cs_folqi_qtp"\n[problem]\nobjective = "{objective}"\n')
        problem = heurtune.load_experiment(str(path)).problem("min")
    rng = np.random.default_rng(4)
    x = vector(problem, THESIS_MIN)
    X = x * (1.0 + 0.05 * rng.standard_normal((4, problem.dim)))
    calls = [(x, ["nominal"]), (X, ["nominal"]), (X, ["nominal", "-30%", "+30%"])]
    fast = [problem.evaluate_scenarios(*call) for call in calls]
    assert all((ev.reason == "").all() for evs in fast for ev in evs)
    monkeypatch.setattr(problem, "_plain_bookkeeping", lambda: False)
    for evs, call in zip(fast, calls):
        for a, b in zip(evs, problem.evaluate_scenarios(*call)):
            for field in ("f", "g", "feasible", "metrics", "reason"):
                got, ref = getattr(a, field), getattr(b, field)
                assert got.dtype == ref.dtype and got.shape == ref.shape
                assert_same_bits(got, ref, because="same code", err_msg=field)  # the same numbers, other masks
            assert a.F is b.F is None and a.objective_names == b.objective_names == ()


@pytest.mark.parametrize("objective", sorted(OBJECTIVES))
def test_each_named_objective_is_the_sum_of_its_two_metrics(objective, tmp_path):
    path = tmp_path / f"{objective}.toml"
    path.write_text(f'extends = "cs_folqi_qtp"\n[problem]\nobjective = "{objective}"\n')
    prob = heurtune.load_experiment(str(path)).problem("min")
    ev = prob.evaluate(vector(prob, THESIS_MIN))
    m = dict(zip(ev.metric_names, ev.metrics[0]))
    first, second = OBJECTIVES[objective]
    assert np.isfinite(ev.f[0]) and ev.f[0] > 0
    assert_close(ev.f[0], m[first] + m[second], rtol=1e-12, because="the same two metrics, summed")
