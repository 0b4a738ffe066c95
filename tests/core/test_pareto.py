"""Pareto tools (heurtune.core.pareto) on hand-made fronts."""

import numpy as np
import pytest
from numerics import assert_exact

from heurtune.core.pareto import asf_choice, constrained_ranks, crowding_distance, hypervolume, update_front

F = np.array([[1.0, 4.0], [2.0, 2.0], [4.0, 1.0], [3.0, 3.0], [5.0, 5.0], [2.0, 2.0]])


def test_constrained_ranks_put_feasible_fronts_first_then_violations():
    v = np.array([0, 0, 0, 0, 0, 0.0])
    assert_exact(constrained_ranks(F, v), [0, 0, 0, 1, 2, 0])
    v = np.array([0, 0.5, 0, 0, 0.2, 0.5])  # (2, 2) now infeasible: (3, 3) joins the first front
    assert_exact(constrained_ranks(F, v), [0, 2, 0, 0, 1, 2])
    assert_exact(constrained_ranks(F, np.full(6, 1.0)), np.zeros(6))


def test_crowding_distance_by_hand():
    front = np.array([[1.0, 4.0], [2.0, 2.0], [4.0, 1.0], [1.5, 3.0]])
    d = crowding_distance(front)
    # sorted by f1: 1, 1.5, 2, 4 (span 3); by f2: 1, 2, 3, 4 (span 3)
    assert d[0] == np.inf and d[2] == np.inf  # exact: the extremes get the literal inf
    assert d[3] == pytest.approx((2 - 1) / 3 + (4 - 2) / 3)
    assert d[1] == pytest.approx((4 - 1.5) / 3 + (3 - 1) / 3)
    assert np.all(crowding_distance(front[:2]) == np.inf)  # exact: both are extremes


def test_hypervolume_of_known_fronts():
    assert hypervolume(F[:3], [5, 5]) == pytest.approx(11.0)  # 1x1 + 2x3 + 1x4
    assert hypervolume([[0.0, 0.0]], [1.0, 1.0]) == pytest.approx(1.0)
    assert hypervolume([[6.0, 0.0]], [5.0, 5.0]) == 0.0  # outside the reference box (exact: nothing added)
    cube = hypervolume([[0.5, 0.5, 0.5]], [1, 1, 1])
    assert cube == pytest.approx(0.125)


def test_front_keeps_feasible_nondominated_points_once():
    X = np.arange(6.0)[:, None]
    v = np.array([0, 0, 0, 0, 0, 0.0])
    fx, ff, fv, _ = update_front(None, X, F, v, np.zeros((6, 0)))
    # exact below: the front holds copies of the candidates and their values
    assert sorted(fx.ravel().tolist()) == [0.0, 1.0, 2.0]  # the duplicate (2, 2) kept once
    # new points: one dominating (2, 2), one infeasible
    fx, ff, fv, _ = update_front((fx, ff, fv, np.zeros((3, 0))), np.array([[6.0], [7.0]]),
                                 np.array([[1.5, 1.5], [0.0, 0.0]]), np.array([0.0, 1.0]), np.zeros((2, 0)))
    assert sorted(fx.ravel().tolist()) == [0.0, 2.0, 6.0]
    # nothing feasible yet: the least violating candidate
    fx, _, fv, _ = update_front(None, X[:3], F[:3], np.array([0.3, 0.1, 0.2]), np.zeros((3, 0)))
    assert fx.ravel().tolist() == [1.0] and fv.tolist() == [0.1]


def test_asf_picks_the_balanced_point_and_follows_weights():
    front = np.array([[0.0, 10.0], [1.0, 2.0], [4.0, 1.0], [10.0, 0.0]])
    assert asf_choice(front) == 1
    assert asf_choice(front, weights=[1.0, 10.0]) == 2
    assert asf_choice(front, weights=[20.0, 1.0]) == 0
    assert asf_choice(front[:1]) == 0
