"""The parameter tables of the QTP loop kernels: a scenario's table ``P`` (kernels.scenario_table)
and a step plan's segment table (continuous.StepPlan.table).

Every kernel of the loop (one candidate, several scenarios, batched lanes, the continuous loop
and its lanes, the CUDA kernels) reads a scenario's numbers from one table with one row layout,
instead of a dozen separate arguments. These tests check that each row holds what its name says,
that the kernels take the tables (and not the old separate arguments), and that a kernel called
with a hand-built table gives what ``ClosedLoop.run`` gives, bit for bit (the same kernel on the
same numbers). The results of the shipped experiments are pinned elsewhere
(tests/runner/test_sampled_release.py, within the tolerances of docs/testing.md).
"""

import inspect

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits

from heurtune.objectives.qtp import continuous_kernels, kernels
from heurtune.objectives.qtp.continuous import plan_steps
from heurtune.objectives.qtp.controllers import LinearController
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset


def test_scenario_table_rows_hold_what_their_names_say():
    c = np.arange(10.0) + 1.0
    P = kernels.scenario_table(c, (3.1, 3.2), True, -1.0, 9.0, False, (20.0, 21.0, 22.0, 23.0), (0.5, -0.5), 700,
                               (0.1, 0.2), 900, 7.0, 350.0)
    assert P.shape == (kernels.NP,)
    # exact: literals stored into the table and read back
    assert_exact(P[kernels.P_COEF:kernels.P_COEF + 10], c)
    assert_exact(P[kernels.P_UOP:kernels.P_UOP + 2], (3.1, 3.2))
    assert (P[kernels.P_UMIN], P[kernels.P_UMAX], P[kernels.P_SAT], P[kernels.P_CLIP]) == (-1.0, 9.0, 1.0, 0.0)
    assert_exact(P[kernels.P_OUT:kernels.P_OUT + 2], (0.5, -0.5))
    assert_exact(P[kernels.P_IN:kernels.P_IN + 2], (0.1, 0.2))
    assert (P[kernels.P_I_OUT], P[kernels.P_I_IN]) == (700.0, 900.0)
    assert_exact(P[kernels.P_HMAX:kernels.P_HMAX + 4], (20.0, 21.0, 22.0, 23.0))
    assert (P[kernels.P_T_DIST], P[kernels.P_HORIZON]) == (7.0, 350.0)
    # every row is written: the rows tile the table without gaps or overlaps
    rows = sorted([(kernels.P_COEF, 10), (kernels.P_UOP, 2), (kernels.P_UMIN, 1), (kernels.P_UMAX, 1),
                   (kernels.P_SAT, 1), (kernels.P_CLIP, 1), (kernels.P_OUT, 2), (kernels.P_IN, 2),
                   (kernels.P_I_OUT, 1), (kernels.P_I_IN, 1), (kernels.P_HMAX, 4), (kernels.P_T_DIST, 1),
                   (kernels.P_HORIZON, 1)])
    assert [r for r, _ in rows] == list(np.cumsum([0] + [n for _, n in rows[:-1]]))
    assert sum(n for _, n in rows) == kernels.NP


def test_step_plan_table_columns_follow_the_plan():
    plan = plan_steps(100.0, 0.125, (1.0, -2.0), 30.0, (0.3, 0.4), 60.0)
    seg = plan.table
    ck = continuous_kernels
    assert seg.shape == (3, ck.N_SEG)
    # exact: the plan's own numbers and literals, stored into the table
    assert_exact(seg[:, ck.SEG_T0], plan.t0)
    assert_exact(seg[:, ck.SEG_H], plan.h)
    assert_exact(seg[:, ck.SEG_STEPS], plan.steps)
    assert_exact(seg[:, ck.SEG_GRADED], [0.0, 1.0, 1.0])
    assert_exact(seg[:, ck.SEG_DIST:ck.SEG_DIST + 2], [[0, 0], [1, -2], [1, -2]])
    assert_exact(seg[:, ck.SEG_UIN:ck.SEG_UIN + 2], [[0, 0], [0, 0], [0.3, 0.4]])
    assert_exact(seg[:, ck.SEG_POST], [0.0, 1.0, 1.0])
    assert plan.table is seg  # built once per plan


OLD_SCENARIO_ARGUMENTS = {"c", "u_op", "out_dist", "in_dist", "i_out_dist", "i_in_dist", "saturate", "u_min",
                          "u_max", "clip", "clip_levels", "h_max", "t_dist", "horizon", "seg_t0", "seg_h",
                          "seg_steps", "seg_graded", "seg_dist", "seg_uin", "seg_post"}


@pytest.mark.parametrize("kernel", [kernels.simulate_loop, kernels.sampled_lane, kernels.simulate_scenarios,
                                    kernels.simulate_lanes, continuous_kernels.simulate_continuous,
                                    continuous_kernels.continuous_lane])
def test_kernels_take_the_tables(kernel):
    names = list(inspect.signature(getattr(kernel, "py_func", kernel)).parameters)
    assert names[0] == "P"
    assert not OLD_SCENARIO_ARGUMENTS & set(names)
    assert len(names) <= 23


def _static_controller():
    """A stable decentralised proportional controller with one modal state per pump."""
    A = np.diag([-0.5, -0.5])
    B = np.zeros((2, 4))
    B[0, 0] = B[1, 1] = 1.0
    C = -0.05 * np.eye(2)
    D = np.zeros((2, 4))
    D[0, 0] = D[1, 1] = -0.8
    return LinearController(A, B, C, D, ((0, 1), (1, 2)), (0, 1))


@pytest.mark.parametrize("sampled", [True, False])
def test_a_hand_built_table_gives_what_the_loop_gives(sampled):
    loop = ClosedLoop(preset("min"), "iolqi")
    ctrl = _static_controller()
    options = dict(horizon=60.0, disturbance_time=10.0, output_disturbance=(1.0, -1.0), input_disturbance=(0.2, 0.1),
                   input_disturbance_time=30.0, saturation=(0.0, 4.5))
    sc = Scenario(dt=0.01, **options) if sampled else Scenario(**options)
    ref = loop.run(ctrl, sc, record=False).metrics
    coef, u_op = loop._perturbed(1.0)
    out = np.empty(kernels.N_METRICS)
    if sampled:
        P = kernels.scenario_table(coef, u_op, True, 0.0, 4.5, False, np.zeros(4), (1.0, -1.0), 1000, (0.2, 0.1),
                                   3000, 10.0, 60.0)
        dc = ctrl.discretise(0.01)
        kernels.simulate_loop(P, 1.0, loop.op.h, loop.op.h, dc.ad, dc.bd, dc.state_input, dc.Ad, dc.Bd, dc.Cc, dc.Dc,
                              dc.state_channel, dc.segments, 0.01, 6000, np.empty((0, 4)), 3.0, out,
                              np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 4)))
    else:
        from heurtune.objectives.qtp.continuous import ContinuousController

        P = kernels.scenario_table(coef, u_op, True, 0.0, 4.5, False, np.zeros(4), (1.0, -1.0), -1, (0.2, 0.1), -1,
                                   10.0, 60.0)
        cc = ContinuousController.from_linear(ctrl)
        plan = loop.step_plan(ctrl, sc, cc)
        continuous_kernels.simulate_continuous(P, 1.0, loop.op.h, loop.op.h, cc.lam, cc.b, cc.col, cc.Cm, cc.Aq,
                                               cc.Bq, cc.Cq, cc.D, cc.channel, plan.table, 3.0, out, 0.01,
                                               np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 4)))
    assert np.all(np.isfinite(ref))
    # the kernel ClosedLoop.run calls, on the numbers it builds its table from
    assert_same_bits(out, ref, because="same code")
