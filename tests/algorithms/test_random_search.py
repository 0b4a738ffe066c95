"""Random search: uniform draws in the box, n per generation, reproducible from the seed."""

import numpy as np
from numerics import assert_same_bits

import heurtune


def test_draws_uniformly_in_the_box_n_per_generation():
    seen = []

    def fun(X):
        seen.append(np.array(X))
        return (X ** 2).sum(axis=1)

    lo, hi = np.array([-1.0, 2.0]), np.array([3.0, 5.0])
    res = heurtune.minimize(fun, lo, hi, "random_search", max_evals=400, seed=3, settings={"n": 20})
    X = np.vstack(seen)
    assert res.n_evals == 400 and all(len(batch) == 20 for batch in seen)
    assert np.all(X >= lo) and np.all(X <= hi)
    # uniform: each coordinate's mean and spread within a few standard errors of the box's
    mid, width = (lo + hi) / 2, hi - lo
    assert np.all(np.abs(X.mean(axis=0) - mid) < 4 * width / np.sqrt(12 * len(X)))
    assert res.f == (X ** 2).sum(axis=1).min()
    again = heurtune.minimize(fun, lo, hi, "random_search", max_evals=400, seed=3, settings={"n": 20})
    assert_same_bits([again.f, *again.x], [res.f, *res.x], because="same seed")
