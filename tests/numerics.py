"""How the tests compare numbers: the testing rule of docs/testing.md as three assertions.

Every numerical comparison in ``tests/`` goes through one of these, so each says which class of
the rule it is in and why:

``assert_same_bits(actual, expected, because=...)``
    Bit for bit, where both sides run the same instruction stream by design. ``because`` names
    the design (a key of :data:`SAME_STREAM`); a comparison that is not in one of these classes
    belongs under :func:`assert_close`.
``assert_exact(actual, expected)``
    No floating-point rounding stands between the two sides: integers, booleans, strings,
    literals stored and read back, values copied, reordered or shifted by whole samples, sums
    of small integers. The function cannot check that claim; its name states it for a reviewer.
``assert_close(actual, expected, rtol=..., atol=..., because=...)``
    Within a stated tolerance: everything else (a compiled kernel against the numpy code it
    replaced, one LAPACK route against another, a file written on another CPU or by an earlier
    release, a solver against an independent reference). ``because`` says where the tolerance
    comes from (the problem's conditioning, the solver's tolerance), never what one CPU gave.

NaN equals NaN in all three (a diverged candidate's NaN metric is a value like any other);
signed zeros are compared as values (``-0.0 == 0.0``) except by :func:`assert_same_bits` on
arrays with ``signed_zeros=True``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

# The designs under which two computations are the same instruction stream on any CPU: the
# same compiled code on the same inputs, in the same order. Each key is what a test passes as
# ``because``; the value is the docs/testing.md wording.
SAME_STREAM = {
    "same seed": "the same seed twice: the same code on the same inputs",
    "workers": "1 and several worker processes, loky or Dask: each run is computed whole by one process",
    "resume": "a run resumed after an interrupt or a kill: finished runs are read back, the rest computed anew",
    "lockstep": "runs gathered into lockstep batches: each candidate still evaluated by the same kernel",
    "shared kernel": "batched lanes, several scenarios in one call, or a lane's neighbours: the same compiled "
                     "per-lane function on the same inputs",
    "numba cache": "a kernel loaded from numba's cache against the same kernel freshly compiled on this CPU",
    "same code": "the same function called twice, or through two entry points that share its arithmetic",
}


def _values(x):
    if isinstance(x, pd.DataFrame | pd.Series):
        return x
    return np.asarray(x)


def _equal_tables(a, b, label) -> bool:
    """Compare two frames or series exactly (check_exact=True); False when they are arrays."""
    if isinstance(a, pd.DataFrame):
        pd.testing.assert_frame_equal(a, b, check_exact=True, obj=f"frame {label}")
    elif isinstance(a, pd.Series):
        pd.testing.assert_series_equal(a, b, check_exact=True, obj=f"series {label}")
    else:
        return False
    return True


def assert_same_bits(actual, expected, *, because, signed_zeros=False, err_msg=""):
    """Assert two results are equal bit for bit, as the same instruction stream must give.

    Parameters
    ----------
    actual, expected : array_like, DataFrame or Series
        The two results. Frames and series are compared with ``check_exact=True``.
    because : str
        Why the two are one instruction stream: a key of :data:`SAME_STREAM`.
    signed_zeros : bool, optional
        Also tell ``-0.0`` from ``0.0`` (arrays only).
    err_msg : str, optional
        Added to the failure message.
    """
    if because not in SAME_STREAM:
        raise ValueError(f"assert_same_bits: because={because!r} is not a same-stream design; allowed: "
                         f"{', '.join(sorted(SAME_STREAM))} (otherwise use assert_close with a stated tolerance)")
    a, b = _values(actual), _values(expected)
    if _equal_tables(a, b, f"({because}) {err_msg}"):
        return
    np.testing.assert_array_equal(a, b, err_msg=f"not bit for bit ({because}) {err_msg}", strict=False)
    if signed_zeros:
        np.testing.assert_array_equal(np.signbit(a), np.signbit(b),
                                      err_msg=f"signed zeros differ ({because}) {err_msg}")


def assert_exact(actual, expected, *, err_msg=""):
    """Assert two values are equal where no rounding stands between them.

    For integers, booleans, strings, literals stored and read back, and values copied,
    reordered or shifted by whole samples.

    Parameters
    ----------
    actual, expected : array_like, DataFrame or Series
        The two values. Frames and series are compared with ``check_exact=True``.
    err_msg : str, optional
        Added to the failure message.
    """
    a, b = _values(actual), _values(expected)
    if not _equal_tables(a, b, err_msg):
        np.testing.assert_array_equal(a, b, err_msg=err_msg)


def assert_close(actual, expected, *, rtol, atol=0.0, because, err_msg=""):
    """Assert two results agree within a stated tolerance.

    Parameters
    ----------
    actual, expected : array_like, DataFrame or Series
        The two results; NaN in the same places counts as equal. Frames and series: their float
        columns within the tolerance, every other column exactly.
    rtol, atol : float
        Relative and absolute tolerance (``|a - b| <= atol + rtol |b|``).
    because : str
        Where the tolerance comes from: the conditioning of the problem, the solvers'
        tolerances. Required, and shown on failure.
    err_msg : str, optional
        Added to the failure message.
    """
    if not because or not isinstance(because, str):
        raise ValueError("assert_close: say where the tolerance comes from (because=...)")
    a, b = _values(actual), _values(expected)
    if isinstance(a, pd.DataFrame):
        pd.testing.assert_frame_equal(a, b, check_exact=False, rtol=rtol, atol=atol, obj=f"frame ({because}) {err_msg}")
        return
    if isinstance(a, pd.Series):
        pd.testing.assert_series_equal(a, b, check_exact=False, rtol=rtol, atol=atol,
                                       obj=f"series ({because}) {err_msg}")
        return
    np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, equal_nan=True, err_msg=f"({because}) {err_msg}")
