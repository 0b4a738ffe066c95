"""Whether two sets of results agree within the tolerances of shipped numbers.

Results made on another CPU, by another code path or by an earlier release are compared within
stated tolerances, never bit for bit (docs/testing.md): 1e-9 relative on objectives, integral
metrics, violations and gains; absolute on levels, overshoots and steady-state errors (ess, a
difference of nearly equal levels, to 1e-10 % of the level), on settling times (1e-8 s) and on
pump voltages (1e-8 V, which follow the gains of poorly conditioned Riccati designs); exactly on
ids, seeds, counts, statuses and texts. ``tests/runner/test_sampled_release.py`` and
``benchmarks/smoke_side_by_side.py`` compare with these functions.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd

__all__ = ["RTOL", "ABSOLUTE", "field_tolerance", "values_agree", "frame_differences", "text_differences"]

RTOL = 1e-9
# metric (a column name without its scenario and loop number) -> absolute tolerance
ABSOLUTE = {
    "ess": 1e-10,  # % of the operating level: a difference of nearly equal levels
    "hmin": 1e-9,  # cm
    "hmax": 1e-9,
    "Mp": 1e-9,  # % of the step
    "ts": 1e-8,  # s: a crossing of the band, interpolated where the level may be flat
    "umin": 1e-8,  # V
    "umax": 1e-8,
}


def field_tolerance(name: str) -> tuple[float, float]:
    """The (relative, absolute) tolerance of a float result named ``name``.

    Parameters
    ----------
    name : str
        A column of a results file, such as ``"J@nominal"``, ``"ess1@+30%"`` or ``"Q11"``.

    Returns
    -------
    tuple of float
        ``(0, ABSOLUTE[metric])`` for the metrics of :data:`ABSOLUTE`, ``(RTOL, 0)`` otherwise.
    """
    metric = str(name).split("@")[0].rstrip("0123456789")
    if metric in ABSOLUTE:
        return 0.0, ABSOLUTE[metric]
    return RTOL, 0.0


def values_agree(a, b, name: str = "") -> bool:
    """Whether two values of the field ``name`` agree: floats within :func:`field_tolerance`
    (NaN with NaN, infinities with themselves), anything else exactly.

    Parameters
    ----------
    a, b : object
        The two values.
    name : str, optional
        The field they are values of.

    Returns
    -------
    bool
    """
    if isinstance(a, float | np.floating) or isinstance(b, float | np.floating):
        if a is None or b is None:
            return a is b
        a, b = float(a), float(b)
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        rtol, atol = field_tolerance(name)
        return math.isclose(a, b, rel_tol=rtol, abs_tol=atol)
    return a == b


def _column_difference(name, x: pd.Series, y: pd.Series) -> str | None:
    if pd.api.types.is_float_dtype(x.dtype) and pd.api.types.is_float_dtype(y.dtype):
        a, b = x.to_numpy(float), y.to_numpy(float)
        rtol, atol = field_tolerance(name)
        same_nan = np.isnan(a) == np.isnan(b)
        with np.errstate(invalid="ignore"):
            close = np.isclose(a, b, rtol=rtol, atol=atol, equal_nan=True) | (a == b)
        bad = ~(close & same_nan)
        if not bad.any():
            return None
        i = int(np.flatnonzero(bad)[0])
        return (f"{int(bad.sum())} of {len(a)} values beyond rtol {rtol:g}, atol {atol:g} "
                f"(row {i}: {a[i]!r} vs {b[i]!r})")
    if x.dtype == object and y.dtype == object:  # lists or arrays in cells: element by element
        for i, (u, v) in enumerate(zip(x, y)):
            if isinstance(u, np.ndarray | list) or isinstance(v, np.ndarray | list):
                u, v = np.asarray(u), np.asarray(v)
                if u.shape != v.shape or not all(values_agree(p, q, name) for p, q in zip(u.ravel(), v.ravel())):
                    return f"row {i}: {u!r} vs {v!r}"
            elif not values_agree(u, v, name):
                return f"row {i}: {u!r} vs {v!r}"
        return None
    if not x.equals(y):
        i = int(np.flatnonzero(x.to_numpy() != y.to_numpy())[0]) if len(x) else 0
        return f"differs (row {i}: {x.iloc[i]!r} vs {y.iloc[i]!r})" if len(x) else "differs"
    return None


def frame_differences(x: pd.DataFrame, y: pd.DataFrame) -> list[str]:
    """Where two result frames disagree: one line per column beyond its tolerance.

    Parameters
    ----------
    x, y : DataFrame
        The two frames, rows in the same order.

    Returns
    -------
    list of str
        Empty when the frames have the same columns and rows, every float column within
        :func:`field_tolerance` and every other column equal.
    """
    if list(x.columns) != list(y.columns):
        return [f"columns differ: {sorted(set(x.columns) ^ set(y.columns))}"]
    if len(x) != len(y):
        return [f"{len(x)} rows against {len(y)}"]
    out = []
    for col in x.columns:
        line = _column_difference(col, x[col].reset_index(drop=True), y[col].reset_index(drop=True))
        if line:
            out.append(f"{col}: {line}")
    return out


_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _last_place(token: str) -> float:
    """One unit in the last printed place of a number as written."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    return 10.0 ** (int(exponent or 0) - decimals)


def text_differences(a: str, b: str) -> list[str]:
    """Where two written tables or reports disagree: the same text, and numbers within 1e-9
    relative or one unit in their last printed place (a value within tolerance may round to
    the other side of a printed digit).

    Parameters
    ----------
    a, b : str
        The two texts.

    Returns
    -------
    list of str
        Empty when they agree; else the first differing line of each kind.
    """
    if a == b:
        return []
    ta, tb = _NUMBER.split(a), _NUMBER.split(b)
    if ta != tb:
        return ["the text around the numbers differs"]
    for p, q in zip(_NUMBER.findall(a), _NUMBER.findall(b)):
        if p == q:
            continue
        u, v = float(p), float(q)
        if not math.isclose(u, v, rel_tol=RTOL) and abs(u - v) > 1.0001 * max(_last_place(p), _last_place(q)):
            return [f"{p} against {q}"]
    return []
