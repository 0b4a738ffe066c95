"""The optimiser contract: what every registered optimiser must do, as checks that can run on any
of them (the test suite runs them on every registered one; ``python -m heurtune.check_plugin``
on a plugin's).

Each check takes the optimiser's name and small settings and raises ``AssertionError`` with a
one-line reason when the optimiser breaks the contract:

- ``bounds``: every evaluated point lies inside the box;
- ``nan_inf``: NaN and inf objective values are survived, the result is finite and avoids them;
- ``seeds``: the same seed gives the same history (even after the global NumPy RNG is used),
  another seed another history;
- ``budget``: a budget of evaluations is spent exactly (1, 37 and 250 evaluations);
- ``constraints``: a constraint steers the result to the feasible side;
- ``workers``: one and two worker processes give the same history.
"""

from __future__ import annotations

import numpy as np

from heurtune.core.engine import minimize

__all__ = ["CHECKS", "LOWER", "UPPER", "run_checks", "run_named_checks"]

LOWER = np.array([-2.0, -1.0, 0.0, 5.0])
UPPER = np.array([3.0, 1.0, 0.5, 6.0])
HISTORY_COLUMNS = ["epoch", "n_evals", "best_f", "mean_f", "sd_f"]


def sphere(X):
    """The checks' objective: a sphere centred at 0.3 in every variable (inside the box in all
    but the last, whose optimum is at its lower bound)."""
    return ((X - 0.3) ** 2).sum(axis=1)


def nasty(X):
    """The sphere, NaN where x0 > 1 and inf where x1 > 0.5."""
    f = sphere(X)
    f[X[:, 0] > 1.0] = np.nan
    f[X[:, 1] > 0.5] = np.inf
    return f


def _constrained(X):
    """Minimise x0 subject to x0 >= 1 (g = 1 - x0 <= 0): the optimum sits on the constraint."""
    return X[:, 0], (1.0 - X[:, 0])[:, None]


class _Recorder:
    def __init__(self, fun):
        self.fun = fun
        self.seen = []

    def __call__(self, X):
        self.seen.append(np.array(X))
        return self.fun(X)


def check_bounds(name, settings):
    rec = _Recorder(sphere)
    minimize(rec, LOWER, UPPER, name, max_evals=300, seed=1, settings=settings)
    X = np.vstack(rec.seen)
    assert np.all(X >= LOWER) and np.all(X <= UPPER), "evaluated a point outside the box"


def check_nan_inf(name, settings):
    res = minimize(nasty, LOWER, UPPER, name, max_evals=300, seed=2, settings=settings)
    assert np.isfinite(res.f), f"the result is not finite ({res.f})"
    assert np.all(res.x >= LOWER) and np.all(res.x <= UPPER), "the result lies outside the box"
    assert res.x[0] <= 1.0 and res.x[1] <= 0.5, "the result lies where the objective is NaN or inf"


def check_seeds(name, settings):
    kw = dict(max_evals=200, settings=settings)
    a = minimize(sphere, LOWER, UPPER, name, seed=5, **kw)
    np.random.seed(123)  # noqa: NPY002 - the global generator, poked on purpose:
    np.random.random(10)  # noqa: NPY002 - a run seeded by its own generator must not change
    b = minimize(sphere, LOWER, UPPER, name, seed=5, **kw)
    c = minimize(sphere, LOWER, UPPER, name, seed=6, **kw)
    assert a.history[HISTORY_COLUMNS].equals(b.history[HISTORY_COLUMNS]) and np.array_equal(a.x, b.x), \
        "the same seed gave another history (randomness outside self.rng?)"
    assert not a.history[HISTORY_COLUMNS].equals(c.history[HISTORY_COLUMNS]), "another seed gave the same history"


def check_budget(name, settings):
    for budget in (1, 37, 250):
        calls = []

        def counting(X, calls=calls):
            calls.append(len(X))
            return sphere(X)

        res = minimize(counting, LOWER, UPPER, name, max_evals=budget, seed=3, settings=settings)
        assert sum(calls) == res.n_evals == budget, f"budget {budget}: {sum(calls)} evaluations made"
        assert res.stop_reason == "max_evals", f"budget {budget}: stopped for {res.stop_reason!r}"
        assert res.history["n_evals"].iloc[-1] == budget, f"budget {budget}: history ends at another count"


def check_constraints(name, settings):
    res = minimize(_constrained, LOWER, UPPER, name, max_evals=400, seed=4, settings=settings)
    assert res.feasible and res.x[0] >= 1.0, "the result is infeasible"
    assert res.f < 2.5, f"the result is far from the constrained optimum (f = {res.f:.3g}, best 1)"


def check_workers(name, settings):
    kw = dict(max_evals=60, seed=7, settings=settings)
    a = minimize(sphere, LOWER, UPPER, name, n_jobs=1, **kw)
    b = minimize(sphere, LOWER, UPPER, name, n_jobs=2, **kw)
    assert a.history[HISTORY_COLUMNS].equals(b.history[HISTORY_COLUMNS]) and np.array_equal(a.x, b.x), \
        "one and two workers gave different histories"


CHECKS = {"bounds": check_bounds, "nan_inf": check_nan_inf, "seeds": check_seeds, "budget": check_budget,
          "constraints": check_constraints, "workers": check_workers}


def run_named_checks(checks: dict, *args) -> list:
    """``checks`` (name -> function) each called with ``args``: ``[(check, passed, reason),
    ...]``, the reason "" when it passed, the first line of its ``AssertionError`` when it broke
    the contract, and the type and message of any other exception (a crash breaks it too). The
    optimiser, plant-family and controller-structure contracts all report through this.

    Parameters
    ----------
    checks : dict of str to callable
        The checks by name.
    *args
        What each check is called with.

    Returns
    -------
    list of (str, bool, str)
    """
    out = []
    for check, fn in checks.items():
        try:
            fn(*args)
        except AssertionError as exc:
            out.append((check, False, str(exc).splitlines()[0] if str(exc) else "failed"))
        except Exception as exc:  # noqa: BLE001 - a crash breaks the contract too
            out.append((check, False, f"{type(exc).__name__}: {exc}".splitlines()[0]))
        else:
            out.append((check, True, ""))
    return out


def run_checks(name: str, settings=None) -> list:
    """Every check on the optimiser ``name``: ``[(check, passed, reason), ...]`` (reason "" when
    it passed; an exception other than a broken contract counts as a failure with its type).

    Parameters
    ----------
    name : str
        A registered optimiser.
    settings : dict, optional
        Its settings for the checks.

    Returns
    -------
    list of (str, bool, str)
    """
    return run_named_checks(CHECKS, name, settings or {})
