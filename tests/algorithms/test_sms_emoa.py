"""SMS-EMOA (algorithms/sms_emoa.py): the reduction step on hand-made pools and the whole
method on ZDT1."""

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.algorithms.sms_emoa import contributions, reduce_one, reduce_to
from heurtune.core.testfunctions import ZDT1_HYPERVOLUME, zdt1


def test_contributions_by_hand():
    F = np.array([[0.0, 4.0], [1.0, 2.0], [2.0, 1.5], [4.0, 0.0]])
    c = contributions(F)
    assert c[0] == c[3] == np.inf  # the extremes are kept (exact: the literal inf)
    # exclusive boxes: (1, 2) up to its neighbours: (2 - 1) x (4 - 2); (2, 1.5): (4 - 2) x (2 - 1.5)
    assert c[1] == pytest.approx(2.0) and c[2] == pytest.approx(1.0)


def test_reduction_drops_the_least_contributor_of_the_worst_front():
    F = np.array([[0.0, 4.0], [1.0, 2.0], [2.0, 1.5], [4.0, 0.0], [3.0, 3.0]])
    v = np.zeros(5)
    assert reduce_one(F, v) == 4  # alone in the second front
    assert reduce_one(F[:4], v[:4]) == 2  # the smallest exclusive contribution
    v = np.array([0, 0, 0, 0.5, 0.2])
    assert reduce_one(F, v) == 3  # infeasible fronts go by violation, the largest first


def test_a_generation_keeps_whole_fronts_then_drops_least_contributors_one_at_a_time():
    F = np.array([[0.0, 4.0], [1.0, 2.0], [2.0, 1.5], [4.0, 0.0], [3.0, 3.0]])
    v = np.zeros(5)
    assert_exact(reduce_to(F, v, 4), [0, 1, 2, 3])  # the first front fits
    assert_exact(reduce_to(F, v, 3), [0, 1, 3])  # as reduce_one on it
    # two removals, recomputed: after (2, 1.5) goes, (1, 2) is the only finite contributor
    assert_exact(reduce_to(F, v, 2), [0, 3])
    v = np.array([0, 0, 0, 0.5, 0.2])
    assert_exact(reduce_to(F, v, 4), [0, 1, 2, 4])  # the smaller violation stays


def test_batch_offspring_evaluate_a_generation_at_once_and_reach_the_front():
    batches = []

    def counted(X):
        batches.append(len(X))
        return zdt1(X)

    res = heurtune.minimize(counted, np.zeros(6), np.ones(6), "sms_emoa", max_epochs=120, seed=3,
                            settings=dict(n=30, offspring=30), reference_point=[1.1, 1.1])
    assert batches == [30] * 121 and res.n_evals == 30 * 121 and res.n_epochs == 120
    assert -res.f > 0.98 * ZDT1_HYPERVOLUME  # measured 0.998 of it with this seed
    with pytest.raises(heurtune.ConfigError, match="offspring must be >= 1"):
        heurtune.minimize(zdt1, np.zeros(3), np.ones(3), "sms_emoa", max_epochs=1, settings=dict(offspring=0),
                          reference_point=[1.1, 1.1])


def test_zdt1_front_and_hypervolume():
    res = heurtune.minimize(zdt1, np.zeros(6), np.ones(6), "sms_emoa", max_epochs=120, seed=3,
                            settings=dict(n=30), reference_point=[1.1, 1.1])
    # within 2 % of the front's exact hypervolume (measured 0.44 % short with this seed)
    assert -res.f > 0.98 * ZDT1_HYPERVOLUME
    assert res.n_evals == 30 * 121


def test_same_seed_same_front():
    kw = dict(max_epochs=5, seed=2, settings=dict(n=8), reference_point=[1.1, 1.1])
    a = heurtune.minimize(zdt1, np.zeros(4), np.ones(4), "sms_emoa", **kw)
    b = heurtune.minimize(zdt1, np.zeros(4), np.ones(4), "sms_emoa", n_jobs=2, **kw)
    assert_same_bits(a.front["F"], b.front["F"], because="workers")  # one and two worker processes


def test_dtlz2_puts_its_pareto_set_on_the_unit_sphere():
    """DTLZ2 (heurtune.core.testfunctions, used by benchmarks/bench_sms_emoa.py): with x_3..x_d
    at 1/2 the objectives lie on the unit sphere to rounding (checked also against pymoo's, which agreed
    to the last bit on the CPU where this was written); away from it they lie outside."""
    from heurtune.core.testfunctions import dtlz2

    X = np.random.default_rng(0).random((20, 12))
    X[:, 2:] = 0.5
    np.testing.assert_allclose((dtlz2(X) ** 2).sum(axis=1), 1.0, rtol=1e-14)
    X[:, 5] = 0.9
    assert np.all((dtlz2(X) ** 2).sum(axis=1) > 1.0)
