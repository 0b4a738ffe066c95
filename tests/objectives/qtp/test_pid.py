"""The PID and FOPID structures of the QTP: their laws against an independent scipy model, the
step rule of their static feedback, their options, bounds and integral-action check, and the
shipped configs on both CPU devices.

The reference (``tests/reference_qtp.reference_pid_loop``) writes the plant, the operating
point, the PID law (with the derivative filter as ``Kd N (e - x_f)``, another realisation than
heurtune's), the Oustaloup filters (scipy's ``zpk2ss``) and the decoupler anew and integrates
them with DOP853 at rtol 1e-10. Tolerances: the continuous loop's stated ones, 0.005 cm on the
levels and 0.05 % on IAE (measured: 1e-6 to 2e-5 cm and 1e-5 relative).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_qtp as ref

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import continuous
from heurtune.objectives.qtp.controllers import integral_action_obstruction
from heurtune.objectives.qtp.loop import METRIC_NAMES, ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset
from heurtune.objectives.qtp.structures import build_controller, decision_names, default_bounds, structure

PID_MIN = dict(Kp1=3.0, Ki1=0.1, Kd1=1.0, Kp2=2.0, Ki2=0.2, Kd2=0.5)
# a stable anti-diagonal PID on nmp, in the small-gain corner where the sweep finds feasible ones
PID_NMP = dict(Kp1=0.1, Ki1=0.02, Kd1=0.05, Kp2=0.03, Ki2=0.001, Kd2=0.02)
FOPID_MIN = dict(Kp1=2.0, Ki1=0.1, Kd1=0.05, lambda1=0.9, mu1=0.5, Kp2=1.0, Ki2=0.3, Kd2=0.02, lambda2=1.2, mu2=0.7)
HORIZON = 100.0


def plant_dict(case):
    p = preset(case)
    return dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))


@pytest.mark.parametrize("case, kind, pairing, decoupler, gains", [
    ("min", "pid", "diagonal", "none", PID_MIN),
    ("min", "pid", "diagonal", "inverse_dc", PID_MIN),
    ("nmp", "pid", "anti-diagonal", "none", PID_NMP),
    ("min", "fopid", "diagonal", "none", FOPID_MIN),
])
def test_the_loop_matches_an_independent_scipy_model(case, kind, pairing, decoupler, gains):
    loop = ClosedLoop(preset(case), kind, pairing=pairing, decoupler=decoupler)
    ctrl = loop.controller(gains)
    assert loop.stability_margin(ctrl) < 0.0
    t = np.arange(0.0, HORIZON + 1e-9, 0.1)
    y_ref, iae_ref = ref.reference_pid_loop(plant_dict(case), gains, t, kind=kind, pairing=pairing,
                                            decoupler=decoupler)
    sim = loop.run(ctrl, Scenario(horizon=HORIZON, output_dt=0.1))
    m = dict(zip(METRIC_NAMES, sim.metrics))
    assert np.max(np.abs(sim.y - y_ref)) < 0.005
    assert abs(m["IAE1"] + m["IAE2"] - iae_ref.sum()) / iae_ref.sum() < 5e-4


def test_pid_transfer_function_is_kp_ki_kd_with_a_filtered_derivative():
    """Each loop's controller, from its error to its pump, is Kp + Ki/s + Kd s/(1 + s/N)."""
    loop = ClosedLoop(preset("min"), "pid", derivative_filter=7.0)
    c = loop.controller(PID_MIN)
    for pump, err in ((0, 0), (1, 1)):
        kp, ki, kd = (PID_MIN[f"{g}{pump + 1}"] for g in ("Kp", "Ki", "Kd"))
        for w in (0.01, 0.3, 5.0, 40.0):
            s = 1j * w
            K = c.C @ np.linalg.solve(s * np.eye(c.A.shape[0]) - c.A, c.B) + c.D
            # du = K w with w = -e: the element from the error is -K
            assert -K[pump, err] == pytest.approx(kp + ki / s + kd * s / (1 + s / 7.0), rel=1e-12)
            assert K[pump, 1 - err] == 0.0  # exact: a structural zero (zero columns of B and D)


def test_inverse_dc_decoupler_makes_the_dc_gain_diagonal_in_the_pairing():
    for case, pairing in (("min", "diagonal"), ("nmp", "anti-diagonal")):
        loop = ClosedLoop(preset(case), "pid", pairing=pairing, decoupler="inverse_dc")
        gains = dict(Kp1=1.0, Ki1=0.0, Kd1=0.0, Kp2=1.0, Ki2=0.0, Kd2=0.0)
        c = loop.controller(gains)  # static: du = D w, and D = -Dd P with P the pairing's selector
        G0 = -(loop.C @ np.linalg.solve(loop.A, loop.B))
        Dd = -c.D[:, :2] if pairing == "diagonal" else -c.D[:, :2][:, ::-1]
        apparent = G0 @ Dd
        err = (0, 1) if pairing == "diagonal" else (1, 0)
        for r in range(2):
            assert apparent[err[r], r] == pytest.approx(G0[err[r], r], rel=1e-12)
            assert abs(apparent[1 - err[r], r]) < 1e-12


def test_fopid_parts_follow_their_fractional_orders():
    """The integral part is Ki/s^lambda and the derivative part Kd s^mu inside the band."""
    loop = ClosedLoop(preset("min"), "fopid")
    g = dict(FOPID_MIN, Kp1=0.0, Kd1=0.0)
    c = loop.controller(g)
    for w in (0.05, 0.5, 5.0):
        s = 1j * w
        K = c.C @ np.linalg.solve(s * np.eye(c.A.shape[0]) - c.A, c.B) + c.D
        # Oustaloup order 5 over [1e-3, 1e3]: within 1 % in magnitude well inside the band
        assert abs(-K[0, 0]) == pytest.approx(abs(g["Ki1"] / s ** g["lambda1"]), rel=0.01)
    g = dict(FOPID_MIN, Kp1=0.0, Ki1=0.0)
    c = loop.controller(g)
    for w in (0.05, 0.5, 5.0):
        s = 1j * w
        K = c.C @ np.linalg.solve(s * np.eye(c.A.shape[0]) - c.A, c.B) + c.D
        assert abs(-K[0, 0]) == pytest.approx(abs(g["Kd1"] * s ** g["mu1"]), rel=0.01)


def test_the_static_feedback_shortens_the_step():
    """PID's steps follow EXPLICIT_STEP_RADIUS / rho(A + B D); at the default tolerance a
    high-gain candidate (rho near 20 1/s) is within 2e-4 cm of the same loop at a 20x finer step,
    which test_the_loop_matches_an_independent_scipy_model ties to scipy."""
    loop = ClosedLoop(preset("min"), "pid")
    gains = dict(Kp1=10.0, Ki1=1.0, Kd1=2.0, Kp2=10.0, Ki2=1.0, Kd2=2.0)
    c = loop.controller(gains)
    sc = Scenario(horizon=HORIZON, output_dt=0.1)
    rho = np.max(np.abs(np.linalg.eigvals(loop.A + loop.B @ c.D)))
    h = continuous.explicit_step(loop.A, loop.B, c.D, sc.tolerance)
    assert h == pytest.approx(continuous.EXPLICIT_STEP_RADIUS / rho)
    assert loop.step_plan(c, sc).h.max() <= h + 1e-12
    fine = loop.run(c, Scenario(horizon=HORIZON, output_dt=0.1, step=h / 20))
    assert np.max(np.abs(loop.run(c, sc).y - fine.y)) < 2e-4
    # an explicit step is taken as given
    assert loop.step_plan(c, Scenario(horizon=HORIZON, step=0.1)).h.max() == pytest.approx(0.1)


def test_batched_lanes_take_each_candidates_own_step():
    loop = ClosedLoop(preset("min"), "pid")
    ctrls = [loop.controller(PID_MIN), loop.controller(dict(PID_MIN, Kd1=0.0, Kd2=0.0))]
    sc = Scenario(horizon=HORIZON)
    diverged, metrics = loop.run_batch(ctrls, [sc])
    for i, c in enumerate(ctrls):
        one = loop.run(c, sc, record=False)
        assert not diverged[i, 0]
        np.testing.assert_allclose(metrics[i, 0], one.metrics, rtol=1e-12, atol=1e-12)


def test_names_bounds_and_options():
    assert decision_names("pid") == ("Kp1", "Ki1", "Kd1", "Kp2", "Ki2", "Kd2")
    assert decision_names("fopid") == ("Kp1", "Ki1", "Kd1", "lambda1", "mu1", "Kp2", "Ki2", "Kd2", "lambda2", "mu2")
    assert default_bounds("pid")["Kd2"] == (0.0, 2.0)
    assert default_bounds("fopid")["mu1"] == (0.1, 0.9)
    s = structure("pid")
    assert s.paired and s.default_options() == {"derivative_filter": 10.0, "decoupler": "none"}
    A, B, C = ClosedLoop(preset("min"), "pid").plant_linearisation
    with pytest.raises(ConfigError, match="controller type 'pid' has no option 'oustaloup_order'; allowed: "
                                          "decoupler, derivative_filter, pairing"):
        build_controller("pid", PID_MIN, A, B, C, oustaloup_order=5)


@pytest.mark.parametrize(
    "text, message",
    [
        ('[controller]\ntype = "pid"\nderivative_filter = 0\n', "controller.derivative_filter"),
        (
            '[controller]\ntype = "pid"\ndecoupler = "full"\n',
            "controller.decoupler: got 'full'; allowed: none, inverse_dc",
        ),
        (
            '[controller]\ntype = "pid"\n[problem.bounds]\nKp1 = [-1.0, 1.0]\n',
            "problem.bounds.Kp1: the lower bound must be >= 0",
        ),
    ],
)
def test_bad_pid_configs_get_one_line_errors(tmp_path, text, message):
    path = tmp_path / "exp.toml"
    path.write_text('extends = "cs_pid_qtp"\n' + text)
    with pytest.raises(ConfigError) as exc:
        heurtune.load_experiment(str(path))
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_another_structures_option_is_ignored_with_a_warning(tmp_path, capsys):
    path = tmp_path / "exp.toml"
    path.write_text('extends = "cs_pid_qtp"\n[controller]\ntype = "folqi"\n')
    heurtune.load_experiment(str(path))
    err = capsys.readouterr().err
    assert "controller.derivative_filter, controller.decoupler not read by folqi" in err


def test_integral_action_check_accounts_for_the_decoupler():
    """On nmp (det G(0) < 0) diagonal PIDs with positive Ki cannot be stable; the inverse-DC
    decoupler, whose determinant has the sign of det G(0), makes the diagonal pairing possible."""
    loop = ClosedLoop(preset("nmp"), "pid")
    A, B, C = loop.plant_linearisation
    assert integral_action_obstruction("pid", "diagonal", A, B, C, ((1e-4, 1.0), (1e-4, 1.0)))
    assert integral_action_obstruction("pid", "anti-diagonal", A, B, C, ((1e-4, 1.0), (1e-4, 1.0))) is None
    dec = ClosedLoop(preset("nmp"), "pid", decoupler="inverse_dc")
    sign = dec.structure.extras["gain_sign"](dec.plant_linearisation, dec.options)
    assert sign == -1
    assert integral_action_obstruction("pid", "diagonal", A, B, C, ((1e-4, 1.0), (1e-4, 1.0)), gain_sign=sign) is None


@pytest.mark.parametrize("name", ["cs_pid_qtp", "cs_fopid_qtp"])
@pytest.mark.parametrize("device", ["cpu", "cpu-batch"])
def test_shipped_configs_run_on_both_cpu_devices_and_write_margins(tmp_path, name, device):
    import pandas as pd

    from heurtune.runner.experiment import run_experiment

    with open("/dev/null", "w") as quiet:
        out = run_experiment(name, smoke=True, seed=7, out=tmp_path / name, figures=False, device=device,
                             progress_stream=quiet)
    runs = pd.read_parquet(out / "runs.parquet")
    assert set(runs.case) == {"min", "nmp"}
    margins = pd.read_parquet(out / "margins.parquet")
    assert len(margins) > 0 and np.isfinite(margins.filter(like="margin").to_numpy(dtype=float)).any()
