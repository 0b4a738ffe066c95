"""Tuned variables that change nothing: a structure that does not read them, or a scenario that
does not exercise them (a set-point weight without a set-point step).

:func:`dead_variables` moves each variable of a few simulated candidates towards the far end of
its bounds and compares what the problem reports (every metric where the problem gives them,
else the objectives and constraint values). A variable whose move changes nothing at any of the
candidates is dead: the optimiser searches a dimension that does not exist. The experiment
runner warns about them before the runs (one line per case; not in a ``--smoke`` run, nor where
the check's evaluations would take over 10 s); ``check_plugin``'s structure contract checks the
QTP's structures the same way.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dead_variables"]


def _signature(ev) -> np.ndarray:
    """What an evaluation reports, one row per candidate (NaN kept)."""
    parts = []
    for name in ("metrics", "F", "f", "g"):
        value = getattr(ev, name, None)
        if value is not None:
            arr = np.asarray(value, dtype=float)
            parts.append(arr.reshape(arr.shape[0], -1))
    return np.hstack(parts)


def dead_variables(prob, *, draws: int = 8, points: int = 2, seed: int = 0) -> list:
    """The names of the problem's variables that change nothing it reports.

    Parameters
    ----------
    prob : TuningProblem
        Anything with ``names``, ``lower``, ``upper`` and ``evaluate(X)`` (an Evaluation with
        ``f`` and ``g``, and ``metrics``, ``F``, ``reason`` where it has them).
    draws : int
        Candidates drawn uniformly in the box; the first ``points`` of them that the problem
        simulates (``reason == ""``, or a finite objective) are the ones moved.
    points : int
    seed : int

    Returns
    -------
    list of str
        Empty when every variable changes something, or when no drawn candidate was simulated
        (nothing to compare). A variable whose bounds are equal is not searched and not listed.
    """
    lo, hi = np.asarray(prob.lower, float), np.asarray(prob.upper, float)
    rng = np.random.default_rng(seed)
    X = lo + (hi - lo) * rng.random((draws, lo.size))
    ev = prob.evaluate(X)
    reason = getattr(ev, "reason", None)
    ok = (np.asarray(reason) == "") if reason is not None else np.isfinite(np.asarray(ev.f, float))
    base = X[ok][:points]
    if len(base) == 0:
        return []
    before = _signature(prob.evaluate(base))
    alive = hi <= lo  # a variable fixed by its bounds is not searched: nothing to warn about
    for k in range(len(base)):
        todo = np.flatnonzero(~alive)
        if todo.size == 0:
            break
        Y = np.repeat(base[k:k + 1], todo.size, axis=0)
        for row, i in enumerate(todo):
            far = lo[i] if base[k, i] - lo[i] > hi[i] - base[k, i] else hi[i]
            Y[row, i] = base[k, i] + 0.75 * (far - base[k, i])
        after = _signature(prob.evaluate(Y))
        same = np.all((after == before[k]) | (np.isnan(after) & np.isnan(before[k])), axis=1)
        alive[todo[~same]] = True
    return [str(n) for n, a in zip(prob.names, alive) if not a]
