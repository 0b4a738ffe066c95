"""Standard test problems for optimiser quality checks (vectorised: X is (n, d)).

Shifted so that the optimum is not at the centre of the box (a centre-biased method gets no
free lunch). ``PROBLEMS`` maps a name to ``(fun, lower, upper, f_opt)``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "SHIFT",
    "sphere",
    "rosenbrock",
    "rastrigin",
    "ackley",
    "pressure_vessel",
    "zdt1",
    "dtlz2",
    "ZDT1_HYPERVOLUME",
    "PROBLEMS",
    "BUDGETS",
]

SHIFT = 1.3  # optimum of the shifted functions at x_i = 1.3 (inside [-5, 5])


def sphere(X):
    """Shifted sphere, f* = 0 at x = 1.3.

    Parameters
    ----------
    X : ndarray (n, d)

    Returns
    -------
    ndarray (n,)
    """
    return ((X - SHIFT) ** 2).sum(axis=1)


def rosenbrock(X):
    """Rosenbrock (optimum at x = 1, f* = 0).

    Parameters
    ----------
    X : ndarray (n, d)

    Returns
    -------
    ndarray (n,)
    """
    return (100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2).sum(axis=1)


def rastrigin(X):
    """Shifted Rastrigin, f* = 0 at x = 1.3.

    Parameters
    ----------
    X : ndarray (n, d)

    Returns
    -------
    ndarray (n,)
    """
    Z = X - SHIFT
    return 10.0 * X.shape[1] + (Z * Z - 10.0 * np.cos(2 * np.pi * Z)).sum(axis=1)


def ackley(X):
    """Shifted Ackley, f* = 0 at x = 1.3.

    Parameters
    ----------
    X : ndarray (n, d)

    Returns
    -------
    ndarray (n,)
    """
    Z = X - SHIFT
    d = X.shape[1]
    return (-20.0 * np.exp(-0.2 * np.sqrt((Z * Z).sum(axis=1) / d))
            - np.exp(np.cos(2 * np.pi * Z).sum(axis=1) / d) + 20.0 + math.e)


def pressure_vessel(X):
    """Pressure-vessel design (Kannan & Kramer 1994), continuous form.

    x = (Ts, Th, R, L); minimise cost subject to four inequalities g <= 0. Best known
    continuous optimum f* = 5885.33 at about (0.7782, 0.3846, 40.32, 200).

    Parameters
    ----------
    X : ndarray (n, 4)

    Returns
    -------
    f : ndarray (n,)
    g : ndarray (n, 4)
    """
    x1, x2, x3, x4 = X.T
    f = 0.6224 * x1 * x3 * x4 + 1.7781 * x2 * x3 ** 2 + 3.1661 * x1 ** 2 * x4 + 19.84 * x1 ** 2 * x3
    g = np.column_stack([
        -x1 + 0.0193 * x3,
        -x2 + 0.00954 * x3,
        (-np.pi * x3 ** 2 * x4 - 4.0 / 3.0 * np.pi * x3 ** 3 + 1296000.0) / 1296000.0,
        (x4 - 240.0) / 240.0,
    ])
    return f, g


D = 10
PROBLEMS = {
    "sphere": (sphere, [-5.0] * D, [5.0] * D, 0.0),
    "rosenbrock": (rosenbrock, [-5.0] * D, [10.0] * D, 0.0),
    "rastrigin": (rastrigin, [-5.12] * D, [5.12] * D, 0.0),
    "ackley": (ackley, [-5.0] * D, [5.0] * D, 0.0),
    "pressure_vessel": (pressure_vessel, [0.0625, 0.0625, 10.0, 10.0], [6.1875, 6.1875, 200.0, 200.0], 5885.3327),
}

# Evaluation budgets of the quality table (docs/quality.md) and tests/test_quality.py.
BUDGETS = {"sphere": 10_000, "rosenbrock": 50_000, "rastrigin": 50_000, "ackley": 20_000,
           "pressure_vessel": 20_000}


def zdt1(X):
    """ZDT1 (Zitzler, Deb & Thiele 2000), two objectives on [0, 1]^d: ``f1 = x1``,
    ``f2 = g (1 - sqrt(x1 / g))`` with ``g = 1 + 9 mean(x2..xd)``. The Pareto front is
    ``f2 = 1 - sqrt(f1)``, reached with ``x2..xd = 0``.

    Parameters
    ----------
    X : ndarray (n, d)

    Returns
    -------
    ndarray (n, 2)
    """
    f1 = X[:, 0]
    g = 1.0 + 9.0 * X[:, 1:].mean(axis=1)
    return np.column_stack([f1, g * (1.0 - np.sqrt(f1 / g))])


def dtlz2(X, m: int = 3):
    """DTLZ2 (Deb, Thiele, Laumanns & Zitzler 2002), ``m`` objectives on [0, 1]^d:
    ``f_i = (1 + g) prod_{j < m - i} cos(x_j pi / 2) sin(x_{m-i} pi / 2)`` (no sine for
    ``i = 1``), ``g = sum_{j >= m} (x_j - 1/2)^2``. The Pareto front is the unit sphere's
    positive orthant, reached with ``x_m..x_d = 1/2``.

    Parameters
    ----------
    X : ndarray (n, d)
    m : int
        Objectives.

    Returns
    -------
    ndarray (n, m)
    """
    g = ((X[:, m - 1:] - 0.5) ** 2).sum(axis=1)
    angle = 0.5 * np.pi * X[:, :m - 1]
    F = np.empty((len(X), m))
    for i in range(m):
        f = (1.0 + g) * np.prod(np.cos(angle[:, :m - 1 - i]), axis=1)
        if i > 0:
            f = f * np.sin(angle[:, m - 1 - i])
        F[:, i] = f
    return F


# Hypervolume of ZDT1's Pareto front with respect to (1.1, 1.1): the integral over f1 in [0, 1]
# of 1.1 - (1 - sqrt(f1)), plus the strip f1 in [1, 1.1] of height 1.1.
ZDT1_HYPERVOLUME = 0.1 + 2.0 / 3.0 + 0.11
