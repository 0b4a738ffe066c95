"""Compiled frequency response of a SISO state space on many frequencies (the margins' sampling).

``C (j w I - A)^-1 B + D`` is evaluated as SLICOT's ``TB05AD`` does, which python-control calls
once per frequency from Python: ``A`` reduced once to upper Hessenberg form ``H = Q^T A Q``
(:func:`scipy.linalg.hessenberg`, orchestration in :mod:`heurtune.objectives.qtp.margins`), then
per frequency one solve of the Hessenberg system ``(j w I - H) x = Q^T B`` by Gaussian elimination
with partial pivoting (only the subdiagonal to eliminate, ``O(n^2)``) and ``C Q x + D``. A
frequency at a pole gives an infinite or NaN value (IEEE division), as the sampled response does.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def hessenberg_response(H, b, c, d, omega, out):
    """``out[k] = c . (j omega[k] I - H)^-1 b + d`` for an upper Hessenberg ``H``.

    Parameters
    ----------
    H : ndarray (n, n) float64
        Upper Hessenberg (entries below the subdiagonal are not read).
    b, c : ndarray (n,) float64
        ``Q^T B`` and ``C Q``.
    d : float
    omega : ndarray (m,) float64
        Frequencies (rad/s).
    out : ndarray (m,) complex128
        Written.
    """
    n = H.shape[0]
    M = np.empty((n, n), dtype=np.complex128)
    x = np.empty(n, dtype=np.complex128)
    for k in range(omega.size):
        s = 1j * omega[k]
        for i in range(n):
            x[i] = b[i]
            for j in range(n):
                M[i, j] = -H[i, j]
            M[i, i] += s
        # eliminate the subdiagonal, row i + 1 against row i (swapped first where larger)
        for i in range(n - 1):
            if abs(M[i + 1, i]) > abs(M[i, i]):
                for j in range(i, n):
                    t = M[i, j]
                    M[i, j] = M[i + 1, j]
                    M[i + 1, j] = t
                t = x[i]
                x[i] = x[i + 1]
                x[i + 1] = t
            f = M[i + 1, i] / M[i, i]
            for j in range(i + 1, n):
                M[i + 1, j] -= f * M[i, j]
            x[i + 1] -= f * x[i]
        acc = 0j
        for i in range(n - 1, -1, -1):
            v = x[i]
            for j in range(i + 1, n):
                v -= M[i, j] * x[j]
            x[i] = v / M[i, i]
            acc += c[i] * x[i]
        out[k] = acc + d
