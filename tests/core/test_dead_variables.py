"""heurtune.core.dead_variables: a variable that changes nothing a problem reports is named."""

import types

import numpy as np

from heurtune.core.dead_variables import dead_variables


class Fake:
    """f = x0^2 + x2, x1 read nowhere, x3 fixed by its bounds; candidates with x0 > 0.9 rejected."""

    names = ("x0", "x1", "x2", "x3")
    lower = np.array([0.0, 0.0, 0.0, 2.0])
    upper = np.array([1.0, 1.0, 1.0, 2.0])

    def __init__(self):
        self.calls = 0

    def evaluate(self, X):
        self.calls += len(X)
        X = np.atleast_2d(X)
        f = X[:, 0] ** 2 + X[:, 2]
        reason = np.where(X[:, 0] > 0.9, "unstable", "")
        return types.SimpleNamespace(f=f, g=np.zeros((len(X), 1)), reason=reason)


def test_the_unread_variable_is_named_and_a_fixed_one_is_not():
    prob = Fake()
    assert dead_variables(prob) == ["x1"]
    assert prob.calls <= 8 + 2 + 2 * 4  # the draws, the base points, one move per variable and point


def test_nothing_is_said_when_nothing_was_simulated():
    prob = Fake()
    prob.evaluate = lambda X: types.SimpleNamespace(f=np.full(len(X), np.inf), g=np.zeros((len(X), 1)),
                                                    reason=np.full(len(X), "unstable"))
    assert dead_variables(prob) == []
