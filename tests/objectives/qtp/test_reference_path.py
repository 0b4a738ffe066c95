"""The reference path of the QTP: set-point steps, structures that read the reference (the
shipped ``pi2dof``), the servo and regulatory windows.

The 2-DOF PI loop is checked against ``tests/reference_qtp.reference_pi2dof_loop``, the plant,
the operating point and the control law written anew and integrated with DOP853 at rtol 1e-10.
Tolerances: the continuous loop's stated ones, 0.005 cm on the levels and 0.05 % on IAE (as
for the PID, tests/objectives/qtp/test_pid.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_qtp as ref
from numerics import assert_exact

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.core.families import make_experiment
from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset
from heurtune.runner.config import load_config

PI2DOF = dict(Kp1=3.0, Ki1=0.05, b1=0.4, Kp2=2.0, Ki2=0.08, b2=0.7)
# the loop settles in the servo window, and the set-points step before the levels do
SERVO = dict(setpoint_step=(1.0, -0.5), setpoint_time=10.0, output_disturbance=(1.0, 1.0), disturbance_time=150.0)
HORIZON = 250.0


def plant_dict(case):
    p = preset(case)
    return dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))


def metrics_of(sim):
    return dict(zip(METRIC_NAMES, sim.metrics))


def test_the_2dof_pi_matches_an_independent_scipy_model():
    loop = ClosedLoop(preset("min"), "pi2dof")
    ctrl = loop.controller(PI2DOF)
    assert loop.stability_margin(ctrl) < 0.0
    t = np.arange(0.0, HORIZON + 1e-9, 0.1)
    y_ref, iae_ref, _ = ref.reference_pi2dof_loop(plant_dict("min"), PI2DOF, t, r=SERVO["setpoint_step"],
                                                 t_r=SERVO["setpoint_time"], d=SERVO["output_disturbance"],
                                                 t_d=SERVO["disturbance_time"])
    sim = loop.run(ctrl, Scenario(horizon=HORIZON, output_dt=0.1, **SERVO))
    m = metrics_of(sim)
    assert np.max(np.abs(sim.y - y_ref)) < 0.005  # the measured levels, set-points not subtracted
    for i in (0, 1):
        assert abs(m[f"IAE{i + 1}"] - iae_ref[i]) / iae_ref[i] < 5e-4


def test_the_windows_integrate_apart_and_add_up():
    config = load_config("pi2dof_qtp")
    config["scenario"].update(horizon=HORIZON, limits="none", uncertainty={"nominal": 1.0},
                              **{k: list(v) if isinstance(v, tuple) else v for k, v in SERVO.items()})
    prob = make_experiment(config).problem("min")
    x = np.array([PI2DOF[n] for n in prob.names])
    row = prob.report(x).loc["nominal"]
    t = np.arange(0.0, HORIZON + 1e-9, 0.1)
    _, _, iae_at = ref.reference_pi2dof_loop(plant_dict("min"), PI2DOF, t, r=SERVO["setpoint_step"],
                                            t_r=SERVO["setpoint_time"], d=SERVO["output_disturbance"],
                                            t_d=SERVO["disturbance_time"])
    t_d = SERVO["disturbance_time"]
    for i in (1, 2):
        servo, regulatory = row[f"IAE_servo{i}"], row[f"IAE_regulatory{i}"]
        assert servo + regulatory == pytest.approx(row[f"IAE{i}"], rel=1e-12)
        assert row[f"ISE_servo{i}"] + row[f"ISE_regulatory{i}"] == pytest.approx(row[f"ISE{i}"], rel=1e-12)
        assert servo == pytest.approx(iae_at[t_d][i - 1] - iae_at[SERVO["setpoint_time"]][i - 1], rel=5e-4)
        assert regulatory == pytest.approx(iae_at[HORIZON][i - 1] - iae_at[t_d][i - 1], rel=5e-4)
    # ITAE counts from each window's start: the regulatory one is not inflated by its 150 s
    assert row["ITAE_regulatory1"] < t_d * row["IAE_regulatory1"]


def test_set_point_weights_change_the_servo_response_alone():
    """b moves the set-point IAE, not the loop's poles (nor, for a settled loop, the response
    to the later disturbance)."""
    loop = ClosedLoop(preset("min"), "pi2dof")
    sc = Scenario(horizon=HORIZON, **SERVO)
    iae, poles = [], []
    for b in (0.0, 0.5, 1.0):
        ctrl = loop.controller({**PI2DOF, "b1": b, "b2": b})
        iae.append(metrics_of(loop.run(ctrl, sc, record=False))["IAE1"])
        poles.append(loop.stability_margin(ctrl))
    assert len(set(np.round(iae, 6))) == 3
    assert poles[0] == poles[1] == poles[2]


def test_a_one_dof_loop_sees_a_set_point_step_as_the_opposite_level_step():
    """For a structure that does not read the reference, a set-point step s is the measured-
    level step -s: the same true levels and the same error integrals; the records keep the
    measured levels."""
    loop = ClosedLoop(preset("min"), "pid")
    ctrl = loop.controller(dict(Kp1=3.0, Ki1=0.1, Kd1=1.0, Kp2=2.0, Ki2=0.2, Kd2=0.5))
    a = loop.run(ctrl, Scenario(horizon=100.0, output_disturbance=(0.0, 0.0), setpoint_step=(1.0, 0.5),
                                setpoint_time=20.0))
    b = loop.run(ctrl, Scenario(horizon=100.0, output_disturbance=(-1.0, -0.5), disturbance_time=20.0))
    np.testing.assert_allclose(a.h, b.h, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.metrics, b.metrics, rtol=1e-12, atol=0)
    np.testing.assert_allclose(a.y, a.h[:, :2], rtol=0, atol=1e-12)  # no output disturbance here


def test_a_2dof_pi_with_unit_weights_is_the_pi():
    loop2, loop1 = ClosedLoop(preset("min"), "pi2dof"), ClosedLoop(preset("min"), "pid")
    gains = dict(Kp1=3.0, Ki1=0.05, Kp2=2.0, Ki2=0.08)
    sc = Scenario(horizon=HORIZON, **SERVO)
    a = loop2.run(loop2.controller({**gains, "b1": 1.0, "b2": 1.0}), sc)
    b = loop1.run(loop1.controller({**gains, "Kd1": 0.0, "Kd2": 0.0}), sc)
    assert np.max(np.abs(a.h - b.h)) < 1e-6
    np.testing.assert_allclose(a.metrics, b.metrics, rtol=1e-6)


def test_the_batched_path_gives_the_one_candidate_numbers():
    prob = heurtune.load_experiment("pi2dof_qtp").problem("min")
    rng = np.random.default_rng(3)
    X = prob.lower + rng.random((6, prob.dim)) * (prob.upper - prob.lower)
    one = prob.evaluate(X)
    prob.set_device("cpu-batch")
    many = prob.evaluate(X)
    assert_exact(one.reason, many.reason)
    ok = one.reason == ""
    assert ok.any()
    np.testing.assert_allclose(many.metrics[ok], one.metrics[ok], rtol=1e-9)


@pytest.mark.parametrize("changes, message", [
    (dict(dt=0.01, setpoint_step=(1.0, 0.0)), "scenario.setpoint_step needs the continuous-time loop"),
    (dict(setpoint_step=(1.0, 0.0), setpoint_time=400.0), "scenario.setpoint_time must lie in [0, horizon]"),
    (dict(setpoint_step=(1.0,)), "scenario.setpoint_step must be two numbers"),
])
def test_bad_set_point_steps_are_one_line_errors(changes, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        Scenario(**changes)


def test_the_windows_and_the_cut_scenario():
    sc = Scenario(horizon=HORIZON, **SERVO)
    assert sc.windows == {"servo": (10.0, 150.0), "regulatory": (150.0, HORIZON)}
    assert Scenario(horizon=100.0, setpoint_step=(1.0, 0.0), output_disturbance=(0.0, 0.0)).windows == {
        "servo": (0.0, 100.0)}
    assert Scenario().windows == {}
    cut = sc.cut(150.0)
    assert cut.horizon == 150.0 and cut.output_disturbance == (0.0, 0.0) and cut.setpoint_step == (1.0, -0.5)
    # the thesis' scenario keeps its event time and its problem id
    assert Scenario().event_time == 50.0


def test_without_a_set_point_step_the_weights_are_dead_variables():
    from heurtune.core.dead_variables import dead_variables

    config = load_config("pi2dof_qtp")
    config["scenario"]["setpoint_step"] = [0.0, 0.0]
    prob = make_experiment(config).problem("min")
    assert set(dead_variables(prob)) == {"b1", "b2"}
    assert dead_variables(heurtune.load_experiment("pi2dof_qtp").problem("min")) == []
