"""Oustaloup rational approximation of fractional operators and fractional integrators.

``s^r`` (``-1 < r < 1``) is approximated over ``[wb, wh]`` rad/s by ``2N + 1`` real zero/pole
pairs (thesis eq. 3.4, FOMCON ``oustafod``)::

    s^r ~ wh^r prod_{k=-N..N} (s + z_k) / (s + p_k)
    z_k = wb mu^((k + N + (1 - r)/2) / (2N + 1)),  p_k = wb mu^((k + N + (1 + r)/2) / (2N + 1)),
    mu = wh / wb.

A fractional integrator ``1 / s^alpha`` with ``alpha`` in [0.1, 2] is realised either

* ``direct`` (FOMCON's default, used by the thesis): integer integrators for ``floor(alpha)``
  and the Oustaloup filter of ``s^-(alpha - floor(alpha))``. For ``alpha < 1`` the DC gain is
  finite (``wb^-alpha``), so a small steady-state error remains.
* ``integer_split``: ``floor(alpha) + 1`` exact integrators times the Oustaloup filter of
  ``s^(1 - frac(alpha))``. Integral action is exact: zero steady-state error.

An integer ``alpha`` is realised by exact integrators in both cases (IOLQI is ``alpha = 1``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.oustaloup_kernels import partial_fraction_residues

__all__ = ["oustaloup_zpk", "FractionalIntegrator", "fractional_integrator", "REALISATIONS"]

REALISATIONS = ("direct", "integer_split")
# The largest Oustaloup order a config may ask for: 2N + 1 states per fractional integrator,
# 2 (2N + 1) per FOLQI (82 at 20, beyond the GPU kernel's 64); the thesis uses 5.
MAX_OUSTALOUP_ORDER = 20
_INTEGER_TOL = 1e-12


def oustaloup_zpk(r: float, order: int = 5, band: tuple = (1e-3, 1e3)):
    """Zeros, poles and gain of the Oustaloup approximation of ``s^r``.

    Parameters
    ----------
    r : float
        Fractional order, ``-1 < r < 1``.
    order : int
        ``N``; the filter has ``2N + 1`` zero/pole pairs.
    band : (float, float)
        ``(wb, wh)`` in rad/s, ``0 < wb < wh``.

    Returns
    -------
    zeros, poles : numpy.ndarray, shape (2N+1,)
        Negative real numbers (the filter is ``k prod (s - zeros) / prod (s - poles)``).
    gain : float
        ``wh^r``.
    """
    try:
        wb, wh = (float(v) for v in band)
    except (TypeError, ValueError):
        raise ConfigError(f"oustaloup band must be two numbers (wb, wh), got {band!r}") from None
    if not (0 < wb < wh) or not math.isfinite(wh):
        raise ConfigError(f"oustaloup band must satisfy 0 < wb < wh, got {band!r}")
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ConfigError(f"oustaloup order must be a positive integer, got {order!r}")
    if not -1.0 < r < 1.0:
        raise ConfigError(f"oustaloup order r must lie in (-1, 1), got {r!r}")
    order = int(order)
    mu = wh / wb
    k = np.arange(-order, order + 1, dtype=np.float64)
    m = 2 * order + 1
    zk = wb * mu ** ((k + order + 0.5 * (1.0 - r)) / m)
    pk = wb * mu ** ((k + order + 0.5 * (1.0 + r)) / m)
    return -zk, -pk, wh**r


@dataclasses.dataclass(frozen=True, eq=False)
class FractionalIntegrator:
    """A rational realisation of ``1 / s^alpha``: ``n_integrators`` exact integrators in series
    with ``gain * prod (s - zeros) / (s - poles)`` (empty zeros/poles for integer alpha)."""

    alpha: float
    n_integrators: int
    zeros: np.ndarray
    poles: np.ndarray
    gain: float

    @property
    def order(self) -> int:
        """Number of states of the realisation."""
        return self.n_integrators + len(self.poles)

    def freqresp(self, w: np.ndarray) -> np.ndarray:
        """Complex frequency response at angular frequencies ``w`` (rad/s)."""
        s = 1j * np.asarray(w, dtype=np.float64)
        out = self.gain * np.ones_like(s) / s**self.n_integrators
        for z, p in zip(self.zeros, self.poles):
            out = out * (s - z) / (s - p)
        return out

    def modal(self):
        """Partial fractions ``d + sum_k r_k / (s - p_k)``, or None with two integrators.

        The poles (the filter's and a single integrator's 0) are real and distinct, so the
        residues are ``r_k = gain prod_j (p_k - z_j) / prod_{i != k} (p_k - p_i)``; ``d`` is the
        direct term (``gain`` for a biproper filter, else 0). A double integrator is a Jordan
        block with no such form: use :meth:`state_space`.

        Returns
        -------
        poles, residues : numpy.ndarray, shape (order,)
        d : float
        """
        if self.n_integrators > 1:
            return None
        poles = np.concatenate([self.poles, np.zeros(self.n_integrators)])
        residues = np.empty(poles.size)
        partial_fraction_residues(poles, self.zeros, float(self.gain), residues)
        d = float(self.gain) if len(self.zeros) == len(poles) else 0.0
        return poles, residues, d

    def state_space(self):
        """Cascade state-space realisation ``(A, B, C, D)`` of the integrator.

        The filter sections ``(s - z) / (s - p) = 1 + (p - z) / (s - p)`` come first, then the
        integrators. The state matrix is lower triangular with the poles on its diagonal, so
        the poles are exact whatever their spread; the tests check the realisation against
        :meth:`freqresp` to 1e-9.

        Returns
        -------
        A : numpy.ndarray, shape (n, n)
        B : numpy.ndarray, shape (n,)
        C : numpy.ndarray, shape (n,)
        D : float
        """
        nf = len(self.poles)
        n = nf + self.n_integrators
        A = np.zeros((n, n))
        B = np.zeros(n)
        # Signal entering section i is sig_i = D_in * u + sum_j C_in[j] x_j.
        c_in = np.zeros(n)
        d_in = float(self.gain)
        for i in range(nf):
            p, z = self.poles[i], self.zeros[i]
            # x_i' = p x_i + sig_i ; out_i = (p - z) x_i + sig_i
            A[i, :] = c_in
            A[i, i] = p
            B[i] = d_in
            c_out = c_in.copy()
            c_out[i] += p - z
            c_in = c_out
        for i in range(nf, n):
            # Exact integrator: x_i' = sig_i ; out_i = x_i.
            A[i, :] = c_in
            B[i] = d_in
            c_in = np.zeros(n)
            c_in[i] = 1.0
            d_in = 0.0
        return A, B, c_in, d_in


def fractional_integrator(alpha: float, order: int = 5, band: tuple = (1e-3, 1e3),
                          realisation: str = "direct") -> FractionalIntegrator:
    """Realise ``1 / s^alpha`` for ``alpha`` in [0.1, 2].

    Parameters
    ----------
    alpha : float
        Integration order.
    order, band :
        Oustaloup order ``N`` and band ``(wb, wh)`` in rad/s.
    realisation : {"direct", "integer_split"}
        See the module docstring.

    Returns
    -------
    FractionalIntegrator
    """
    if realisation not in REALISATIONS:
        raise ConfigError(
            f"unknown realisation {realisation!r}; allowed: {', '.join(REALISATIONS)}"
        )
    alpha = float(alpha)
    if not (math.isfinite(alpha) and 0.1 - 1e-12 <= alpha <= 2.0 + 1e-12):
        raise ConfigError(f"alpha must lie in [0.1, 2], got {alpha!r}")
    n_int = math.floor(alpha + _INTEGER_TOL)
    frac = alpha - n_int
    empty = np.zeros(0)
    if abs(frac) <= _INTEGER_TOL:
        return FractionalIntegrator(alpha, n_int, empty, empty, 1.0)
    if realisation == "direct":
        z, p, k = oustaloup_zpk(-frac, order, band)
        return FractionalIntegrator(alpha, n_int, z, p, k)
    z, p, k = oustaloup_zpk(1.0 - frac, order, band)
    return FractionalIntegrator(alpha, n_int + 1, z, p, k)
