"""Bandwidth-optimal PI/PID design for (decoupled) TITO loops: batch loop metrics and Nyquist stability.

The design problem of papers 000/002 of the seeds, per decoupled loop ``h_ii`` (see
:class:`heurtune.objectives.tito.model.Decoupler`)::

    maximise   w_b                      (closed-loop bandwidth)
    subject to Am >= Am_min,  phim >= phim_min,  Mt = max |T(jw)| <= Mt_max,  closed loop stable

Everything here works on exact frequency responses sampled on a grid (delays as ``e^{-jwL}``, no
Pade approximation) and is vectorised over candidates: a batch of ``n`` controllers on ``m``
frequencies is a handful of ``(n, m)`` numpy operations.

Controller structure
--------------------
The decision vector is the parallel gain triple ``(Kp, Ki, Kd)`` of :meth:`PIDController.parallel`.
The controller evaluated is the one :class:`~heurtune.objectives.tito.model.PIDController` realises, i.e.
the series PID with a first-order filter on the *whole* controller::

    C(s) = (Kd s^2 + Kp s + Ki) / (s (1 + Tf s)) = (Kp + Ki/s + Kd s) / (1 + Tf s),   Tf = Td / N

with ``Td`` the smaller series time constant (``Kc = Ki Ti``, ``Td = Kd / Kc``, see
:func:`pid_filter_time`). ``Kd = 0`` gives ``Tf = 0`` and the PI ``Kp + Ki/s`` exactly.

Stability
---------
:func:`nyquist_stable` (SISO, batched) and :func:`mimo_nyquist` (2x2, generalised Nyquist) count
the encirclements of the origin by ``1 + L(jw)`` (``det(I + G D C)``) along the imaginary axis
indented to the right around the integrators at ``s = 0``. Both assume that the open loop has no
pole in the open right half-plane: :class:`~heurtune.objectives.tito.model.TFElement` lags are positive
time constants, :func:`~heurtune.objectives.tito.model.inverted_decoupler` refuses ratios whose
denominator has a right-half-plane zero (so ``h11 = g11 - g12 g21 / g22`` has only stable poles),
and the controller's only other pole ``-1/Tf`` is stable because ``Tf >= 0``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from heurtune.core.errors import ConfigError

from .model import Decoupler, ParallelPID, PIController, PIDController, TITOPlant

__all__ = [
    "BANDWIDTH_LEVEL",
    "RESOLVE_LEVEL",
    "TAIL_LEVEL",
    "UNSTABLE_VIOLATION",
    "LoopMetrics",
    "NyquistVerdict",
    "bandwidth_design_eval",
    "bandwidth_design_values",
    "design_grid",
    "loop_metrics_batch",
    "mimo_nyquist",
    "nyquist_stable",
    "parallel_controller",
    "pi_from_parallel",
    "pid_filter_time",
    "pid_freqresp",
    "pid_from_parallel",
    "tito_closed_loop_stable",
    "unwrapped_phase",
]

TAIL_LEVEL = 0.9
"""Bound of ``|L|`` beyond a sample below which the Nyquist count needs no resolution there."""
BANDWIDTH_LEVEL = 1.0 / math.sqrt(2.0)
"""``|T(j w_b)|`` at the closed-loop bandwidth (-3 dB of the unit static gain)."""

RESOLVE_LEVEL = 0.125
"""Loop magnitude above which the grid must resolve ``L`` for a Nyquist verdict (see :func:`nyquist_stable`)."""

MAX_ANGLE_STEP = 0.5
"""Largest accepted turn ``|arg(L_{k+1} / L_k)|`` (rad) between samples where ``|L| >= RESOLVE_LEVEL``."""

UNSTABLE_VIOLATION = 1.0e3
"""Added to every constraint of an unstable (or unresolved) candidate in :func:`bandwidth_design_eval`."""

G_CLIP = 1.0e6
"""Constraint values are clipped to ``[-G_CLIP, G_CLIP]`` (so infinite margins stay finite)."""

_TWO_PI = 2.0 * math.pi


def _wrap(x: np.ndarray) -> np.ndarray:
    """Wrap angles to ``[-pi, pi]`` (nearest representative; faster than a modulo)."""
    return x - _TWO_PI * np.rint(x * (1.0 / _TWO_PI))


def _grid(w) -> np.ndarray:
    w = np.asarray(w, dtype=np.float64)
    if w.ndim != 1 or w.size < 3:
        raise ConfigError(f"frequency grid: need a 1-D array of at least 3 frequencies, got shape {w.shape}")
    if not (np.all(np.isfinite(w)) and w[0] > 0 and np.all(np.diff(w) > 0)):
        raise ConfigError("frequency grid: frequencies must be finite, > 0 and strictly increasing")
    return w


# --------------------------------------------------------------------------------------------
# Controllers
# --------------------------------------------------------------------------------------------


def _series_kc(Kp, Ki, Kd):
    """Larger-magnitude root ``Kc`` of ``Kc^2 - Kp Kc + Kd Ki = 0`` and the discriminant."""
    disc = Kp * Kp - 4.0 * Kd * Ki
    sgn = np.where(Kp >= 0, 1.0, -1.0)
    return 0.5 * (Kp + sgn * np.sqrt(np.maximum(disc, 0.0))), disc


def pid_filter_time(Kp, Ki, Kd, N=100.0) -> np.ndarray:
    """Filter time constant ``Tf = Td / N`` of the PID with parallel gains ``(Kp, Ki, Kd)``.

    The series form ``Kc (1 + Ti s)(1 + Td s) / (Ti s)`` has ``Ki = Kc/Ti``, ``Kd = Kc Td`` and
    ``Kp = Kc (Ti + Td)/Ti``, so ``Kc`` solves ``Kc^2 - Kp Kc + Kd Ki = 0``. The root of larger
    magnitude is taken (``Ti >= Td``; computed without cancellation) and ``Td = Kd / Kc``; this is
    exactly :func:`pid_from_parallel`'s ``Td`` whenever a real series form with ``Ti > 0``,
    ``Td >= 0`` exists. Outside that set the filter stays defined, finite and stable:
    complex series zeros (``Kp^2 < 4 Kd Ki``) use their natural time constant
    ``Td = sqrt(Kd/Ki)`` (continuous at ``Kp^2 = 4 Kd Ki``), mixed signs use ``|Td|``, and
    ``Kd = 0`` or a zero ``Kc`` (pure D) give ``Tf = 0``.

    Parameters
    ----------
    Kp, Ki, Kd : array_like
        Parallel gains, broadcastable to a common shape.
    N : float
        Filter ratio ``Td / Tf``, finite and > 0.

    Returns
    -------
    numpy.ndarray
        ``Tf >= 0``, finite, of the broadcast shape.
    """
    N = float(N)
    if not (math.isfinite(N) and N > 0):
        raise ConfigError(f"pid: N must be finite and > 0, got {N!r}")
    Kp, Ki, Kd = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (Kp, Ki, Kd)))
    with np.errstate(all="ignore"):
        # Td is invariant to a common scaling of the gains: normalise to avoid overflow.
        big = np.maximum(np.maximum(np.abs(Kp), np.abs(Ki)), np.abs(Kd))
        big = np.where((big > 0) & np.isfinite(big), big, 1.0)
        Kp, Ki, Kd = Kp / big, Ki / big, Kd / big
        Kc, disc = _series_kc(Kp, Ki, Kd)
        scale = np.where(disc >= 0, np.abs(Kc), np.sqrt(np.abs(Kd * Ki)))
        Td = np.abs(Kd) / scale
    Td = np.where((Kd == 0) | ~np.isfinite(Td), 0.0, Td)
    return Td / N


def pid_freqresp(Kp, Ki, Kd, N, w) -> np.ndarray:
    """Batch frequency response ``C(jw) = (Kp + Ki/(jw) + Kd jw) / (1 + jw Tf)``.

    This is the response of :class:`~heurtune.objectives.tito.model.PIDController` (series PID with the
    filter ``1/(1 + Tf s)`` on the whole controller, ``Tf = Td/N``) written with its parallel gains;
    ``Tf`` comes from :func:`pid_filter_time`. With ``Kd = 0`` it is the PI ``Kp + Ki/(jw)``.

    Parameters
    ----------
    Kp, Ki, Kd : array_like, shape (n,) or scalar
        Parallel gains of ``n`` candidates (scalars count as ``n = 1``).
    N : float
        Filter ratio ``Td / Tf`` (> 0).
    w : array_like, shape (m,)
        Frequencies in rad/s, > 0.

    Returns
    -------
    numpy.ndarray, shape (n, m), complex
    """
    Kp, Ki, Kd = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (Kp, Ki, Kd))
    Kp, Ki, Kd = np.broadcast_arrays(Kp, Ki, Kd)
    if Kp.ndim != 1:
        raise ConfigError(f"pid_freqresp: gains must be scalars or 1-D arrays, got shape {Kp.shape}")
    w = np.atleast_1d(np.asarray(w, dtype=np.float64))
    Tf = pid_filter_time(Kp, Ki, Kd, N)
    s = 1j * w[None, :]
    with np.errstate(over="ignore", invalid="ignore"):  # absurd gains may overflow to inf
        return (Kp[:, None] + Ki[:, None] / s + Kd[:, None] * s) / (1.0 + s * Tf[:, None])


def _finite_scalars(label: str, **vals) -> dict:
    out = {}
    for key, v in vals.items():
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise ConfigError(f"{label}: {key} must be a number, got {v!r}") from None
        if not math.isfinite(f):
            raise ConfigError(f"{label}: {key} must be finite, got {v!r}")
        out[key] = f
    return out


def parallel_controller(Kp, Ki, Kd=0.0, N=100.0) -> ParallelPID:
    """The :class:`ParallelPID` of :func:`pid_freqresp`: gains as given, ``Tf`` from
    :func:`pid_filter_time` (0 for a PI). Raises ConfigError for non-finite gains or ``N <= 0``.

    Parameters
    ----------
    Kp, Ki, Kd : float
        Parallel gains.
    N : float
        Derivative filter ratio.

    Returns
    -------
    ParallelPID
    """
    v = _finite_scalars("parallel_controller", Kp=Kp, Ki=Ki, Kd=Kd, N=N)
    Tf = float(pid_filter_time(v["Kp"], v["Ki"], v["Kd"], v["N"]))
    return ParallelPID(Kp=v["Kp"], Ki=v["Ki"], Kd=v["Kd"], Tf=Tf)


def pi_from_parallel(Kp, Ki) -> PIController:
    """The :class:`PIController` ``Kc (1 + 1/(Ti s))`` with parallel gains ``Kp + Ki/s``.

    ``Kc = Kp``, ``Ti = Kp / Ki``; :meth:`PIController.parallel` returns ``(Kp, Ki, 0)``.

    Parameters
    ----------
    Kp, Ki : float
        Parallel gains.

    Returns
    -------
    PIController

    Raises
    ------
    ConfigError
        Non-finite gains, ``Ki = 0`` or ``Kp/Ki <= 0`` (no positive integral time).
    """
    v = _finite_scalars("pi_from_parallel", Kp=Kp, Ki=Ki)
    Kp, Ki = v["Kp"], v["Ki"]
    if Ki == 0 or Kp / Ki <= 0:
        raise ConfigError(f"pi_from_parallel: need Ki != 0 and Kp/Ki > 0 (Ti > 0), got Kp={Kp!r}, Ki={Ki!r}")
    return PIController(Kc=Kp, Ti=Kp / Ki)


def pid_from_parallel(Kp, Ki, Kd, N=100.0) -> PIDController:
    """The :class:`PIDController` with parallel gains ``(Kp, Ki, Kd)`` and filter ``Tf = Td/N``.

    Inverts :meth:`PIDController.parallel`: ``Kc`` is the larger-magnitude root of
    ``Kc^2 - Kp Kc + Kd Ki = 0``, ``Ti = Kc/Ki``, ``Td = Kd/Kc`` (so ``Ti >= Td``), ``Tf = Td/N``.
    Its :meth:`~PIDController.freqresp` equals :func:`pid_freqresp` for the same gains.

    Parameters
    ----------
    Kp, Ki, Kd : float
        Parallel gains.
    N : float
        Derivative filter ratio.

    Returns
    -------
    PIDController

    Raises
    ------
    ConfigError
        Non-finite gains, ``Ki = 0``, ``Kp/Ki <= 0``, ``Kd/Ki < 0`` or ``Kp^2 < 4 Kd Ki`` (complex
        series zeros: no series form with real ``Ti``, ``Td``), or ``N <= 0``.
    """
    v = _finite_scalars("pid_from_parallel", Kp=Kp, Ki=Ki, Kd=Kd, N=N)
    Kp, Ki, Kd, N = v["Kp"], v["Ki"], v["Kd"], v["N"]
    if N <= 0:
        raise ConfigError(f"pid_from_parallel: N must be > 0, got {N!r}")
    if Ki == 0 or Kp / Ki <= 0 or Kd / Ki < 0:
        raise ConfigError(f"pid_from_parallel: need Ki != 0, Kp/Ki > 0 and Kd/Ki >= 0, got "
                          f"Kp={Kp!r}, Ki={Ki!r}, Kd={Kd!r}")
    if Kp * Kp < 4.0 * Kd * Ki:
        raise ConfigError(f"pid_from_parallel: Kp^2 < 4 Kd Ki ({Kp * Kp:.6g} < {4 * Kd * Ki:.6g}): complex "
                          f"zeros, no series PID with real Ti, Td")
    Kc = float(_series_kc(np.float64(Kp), np.float64(Ki), np.float64(Kd))[0])
    Td = Kd / Kc
    return PIDController(Kc=Kc, Ti=Kc / Ki, Td=Td, Tf=Td / N)


# --------------------------------------------------------------------------------------------
# Frequency grid
# --------------------------------------------------------------------------------------------


def _roll_off(P: Callable, w_min: float, mag_floor: float | None, rel_floor: float) -> float:
    """Twice the frequency beyond which ``|P|`` stays below ``mag_floor / 2`` (probed up to ``1e12 w_min``)."""
    wp = np.geomspace(w_min, 1e12 * w_min, 2401)
    mag = np.abs(np.asarray(P(wp), dtype=np.complex128).reshape(wp.size, -1)).max(axis=1)
    floor = float(mag_floor) if mag_floor is not None else rel_floor * float(np.max(mag))
    high = np.nonzero(~(mag < 0.5 * floor))[0]
    if high.size == 0:
        return float(wp[1])
    if high[-1] >= wp.size - 1:
        raise ConfigError(f"design_grid: |P| does not fall below mag_floor/2 = {0.5 * floor:.3g} up to "
                          f"{wp[-1]:.3g} rad/s; give w_max")
    return float(2.0 * wp[high[-1] + 1])


def design_grid(P: Callable, w_min: float, w_max: float | None = None, n: int = 2000, *, mag_floor: float | None = None,
                rel_floor: float = 1e-4) -> np.ndarray:
    """A frequency grid that resolves the phase of a delayed element where the loop gain can matter.

    A plain log grid has a constant step in ``u = ln w``, but a delay ``e^{-jwL}`` turns its phase
    by ``w L du`` per step, which grows without bound with ``w``. Here the ``n`` points are spread
    uniformly in the measure ``dLambda = (1 + rho(u) psi(u)) du`` where

    * ``rho = |d ln P / d ln w|`` is the complex logarithmic rate of ``P`` (phase rate and
      log-magnitude rate together; ``rho = w L`` for a pure delay), by a one-sided difference;
    * ``psi = min(1, r) (1 + log10(max(r, 1)))`` with ``r = |P| / mag_floor`` switches the phase
      requirement off where ``|P|`` is so small that no controller of interest makes ``|L|``
      large, and grows slowly with ``|P|`` so that the crossover region (``|L|`` near 1, far above
      the floor) gets a few times more points than the tail where ``|L|`` is near 1/8.

    Hence every step satisfies ``du <= h`` and, where ``|P| >= mag_floor``,
    ``|d ln P| <= h`` (in particular a phase increment of ``P`` of at most ``h`` radians), with
    ``h = Lambda_total / (n - 1)``. A PI/PID adds at most a few radians of phase per unit of
    ``u``, so the loop's step there is a small multiple of ``h`` (0.01-0.05 near the crossovers
    for the presets with ``n = 2000``). :func:`nyquist_stable` needs ``L`` resolved wherever
    ``|L| >= RESOLVE_LEVEL = 1/8``, so choose ``mag_floor <= 1 / (8 c_max)`` with ``c_max`` the
    largest controller magnitude of interest at high frequency (``|Kp| + |Kd|/Tf`` for the filtered
    PID), and ``w_max`` where ``|P| c_max < 1/8``; candidates with more gain are reported
    unresolved (hence not stable) rather than misjudged.

    Parameters
    ----------
    P : callable
        ``P(w)`` -> complex array of shape ``(m,)`` or ``(m, ...)`` (several responses, e.g. the
        4 elements of a plant: the grid then serves the fastest of them at every frequency).
    w_min, w_max : float
        Grid ends, ``0 < w_min < w_max``. ``w_min`` must lie well below the loop dynamics (phase of
        ``P(j w_min)`` within 0.1 rad of 0 or pi, see :func:`loop_metrics_batch`). ``w_max=None``
        takes twice the frequency beyond which ``|P|`` stays below ``mag_floor / 2`` (probed on a
        log grid up to ``1e12 w_min``), so that ``|L(j w_max)| < 1/8`` for ``|C| <= c_max``.
    n : int
        Number of points (>= 3).
    mag_floor : float, optional
        Absolute magnitude below which the phase of ``P`` need not be resolved; default
        ``rel_floor * max |P|`` over ``[w_min, w_max]``.
    rel_floor : float
        See ``mag_floor``.

    Returns
    -------
    numpy.ndarray, shape (n,)
        Strictly increasing, ``w[0] = w_min``, ``w[-1] = w_max``.
    """
    n = int(n)
    if n < 3:
        raise ConfigError(f"design_grid: n must be >= 3, got {n}")
    if not (math.isfinite(w_min) and w_min > 0):
        raise ConfigError(f"design_grid: w_min must be finite and > 0, got {w_min!r}")
    if w_max is None:
        w_max = _roll_off(P, w_min, mag_floor, rel_floor)
    if not (math.isfinite(w_max) and w_min < w_max):
        raise ConfigError(f"design_grid: need 0 < w_min < w_max, got {w_min!r}, {w_max!r}")
    n_probe = max(8 * n, 8000)
    u = np.linspace(math.log(w_min), math.log(w_max), n_probe)
    wp = np.exp(u)
    delta = 1e-6
    p0 = np.asarray(P(wp), dtype=np.complex128).reshape(n_probe, -1)
    p1 = np.asarray(P(wp * (1.0 + delta)), dtype=np.complex128).reshape(n_probe, -1)
    mag = np.abs(p0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.abs(np.log(p1 / p0)) / math.log1p(delta)
        floor = float(mag_floor) if mag_floor is not None else rel_floor * float(np.max(mag))
        ratio = mag / floor if floor > 0 else np.ones_like(mag)
        psi = np.minimum(1.0, ratio) * (1.0 + np.log10(np.maximum(ratio, 1.0)))
        dens = 1.0 + np.nan_to_num(rate * psi, nan=0.0, posinf=0.0).max(axis=1)
    lam = np.concatenate(([0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(u))))
    ug = np.interp(np.linspace(0.0, lam[-1], n), lam, u)
    w = np.exp(ug)
    w[0], w[-1] = w_min, w_max
    return w


# --------------------------------------------------------------------------------------------
# SISO batch metrics and Nyquist
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LoopMetrics:
    """Per-candidate loop metrics of a batch (every field is an array of shape ``(n,)``).

    Attributes
    ----------
    gain_margin : ndarray
        ``1 / |L(j w_pc)|`` (ratio); ``inf`` without phase crossover.
    phase_margin_deg : ndarray
        ``arg L(j w_gc) + 180`` wrapped to ``[-180, 180]`` degrees; ``inf`` without gain crossover.
    w_gc, w_pc : ndarray
        First gain crossover (``|L|`` falls through 1) and first phase crossover (unwrapped phase
        reaches -180 deg), rad/s; ``nan`` when absent.
    w_b : ndarray
        Closed-loop bandwidth: first frequency where ``|T|`` falls below ``1/sqrt(2)``; 0 when
        ``|T(j w_0)|`` is already below it, ``w[-1]`` (a lower bound) when it never falls below.
    Mt, Ms : ndarray
        Peaks of ``|T| = |L/(1+L)|`` and ``|S| = 1/|1+L|`` over the grid (parabolic refinement).
    stable : ndarray of bool
        Nyquist verdict: resolved, no encirclement, ``1 + L`` never (numerically) zero on the grid.
    n_rhp : ndarray of int
        Closed-loop poles in the right half-plane counted by the winding number (valid if resolved).
    resolved : ndarray of bool
        The samples decide the winding number (see :func:`nyquist_stable`): ``L`` resolved where
        ``|L| >= RESOLVE_LEVEL``, no ambiguous pass near -1, ``|L(j w[-1])| < RESOLVE_LEVEL``.
    """

    gain_margin: np.ndarray
    phase_margin_deg: np.ndarray
    w_gc: np.ndarray
    w_pc: np.ndarray
    w_b: np.ndarray
    Mt: np.ndarray
    Ms: np.ndarray
    stable: np.ndarray
    n_rhp: np.ndarray
    resolved: np.ndarray


def _check_element(Pw: np.ndarray, w: np.ndarray) -> np.ndarray:
    Pw = np.asarray(Pw, dtype=np.complex128)
    if Pw.shape != w.shape:
        raise ConfigError(f"element response: shape {Pw.shape} does not match the grid {w.shape}")
    if not np.all(np.isfinite(Pw)):
        raise ConfigError("element response: must be finite on the grid")
    p0 = Pw[0]
    if p0 == 0 or abs(p0.imag) > 0.1 * abs(p0.real):
        raise ConfigError(
            f"element response at w[0] = {w[0]:.3g} rad/s is {p0:.4g}: not within 0.1 rad of a non-zero "
            f"real static gain; start the grid lower"
        )
    return Pw


def _controllers(Cw, m: int) -> np.ndarray:
    Cw = np.asarray(Cw, dtype=np.complex128)
    if Cw.ndim == 1:
        Cw = Cw[None, :]
    if Cw.ndim != 2 or Cw.shape[1] != m:
        raise ConfigError(f"controller responses: expected shape (n, {m}), got {Cw.shape}")
    return Cw


def _integral_gains(Ki, Cw: np.ndarray, w: np.ndarray) -> np.ndarray:
    if Ki is None:
        # jw C(jw) -> Ki as w -> 0 for the PI/PID structures (relative error O(w0^2)).
        return np.real(1j * w[0] * Cw[:, 0])
    Ki = np.broadcast_to(np.asarray(Ki, dtype=np.float64), (Cw.shape[0],))
    return np.where(np.isfinite(Ki), Ki, 0.0)


def _ambiguous(F: np.ndarray, absF: np.ndarray, dF: np.ndarray, absdF: np.ndarray,
               skip: np.ndarray | None = None) -> np.ndarray:
    """Rows with a step whose chord passes the origin closer than the curve may deviate from it.

    Between samples the path of ``F`` deviates from its chord by about ``|F''| du^2 / 8``, estimated
    by ``|second difference| / 8``; when the chord passes within 1.5 times that of the origin, the
    side on which the true curve passes (hence the winding number) is not decided by the samples.
    """
    n, ms = dF.shape
    near = np.minimum(absF[:, :-1], absF[:, 1:]) <= 2.0 * absdF
    if skip is not None:  # steps on which 1 + L is known to stay in the disc |F - 1| < 0.9
        near &= ~skip
    r, k = np.nonzero(near)
    out = np.zeros(n, dtype=bool)
    if r.size == 0:
        return out
    f0, d = F[r, k], dF[r, k]
    dd = np.maximum(absdF[r, k] ** 2, 1e-300)
    t = np.clip(-(d.conjugate() * f0).real / dd, 0.0, 1.0)
    dist = np.abs(f0 + t * d)
    km, kp = np.maximum(k - 1, 0), np.minimum(k + 1, ms - 1)
    dev = np.maximum(np.abs(d - dF[r, km]), np.abs(dF[r, kp] - d)) / 8.0
    out[r[dist <= 1.5 * dev]] = True
    return out


def _branch_crossings(F: np.ndarray) -> np.ndarray:
    """Net counter-clockwise crossings of the negative real axis by the chords of each row of ``F``.

    The sum of the principal increments ``arg(F_{k+1} / F_k)`` equals
    ``arg F_last - arg F_first + 2 pi * crossings`` (the principal argument jumps by -2 pi exactly
    where a chord crosses the negative real axis counter-clockwise); counting sign changes of
    ``Im F`` is cheaper than an ``arctan2`` per step.
    """
    neg = np.signbit(F.imag)  # -0.0 counts as negative, as in arctan2
    r, k = np.nonzero(neg[:, 1:] != neg[:, :-1])
    f0, f1 = F[r, k], F[r, k + 1]
    dim = f1.imag - f0.imag
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(dim != 0, f0.real - f0.imag * (f1.real - f0.real) / dim, f0.real)
    hit = x < 0
    sign = np.where(neg[r, k + 1], 1.0, -1.0)  # Im from >= 0 to < 0 on the negative side: counter-clockwise
    return np.bincount(r[hit], weights=sign[hit], minlength=F.shape[0])


def _unresolved(L: np.ndarray, absL: np.ndarray, dphase: np.ndarray, F: np.ndarray, absF: np.ndarray,
                safe: np.ndarray | None = None) -> np.ndarray:
    """Rows whose samples do not decide the winding number of ``F = 1 + L`` (see :func:`nyquist_stable`).

    ``safe`` (same shape as ``L``) marks samples whose step to the next sample keeps
    ``|L| < TAIL_LEVEL`` (so ``1 + L`` stays in the disc ``|F - 1| < 0.9``, away from the origin):
    those steps need no resolution and cannot be ambiguous. The last sample is safe when
    ``|L| < TAIL_LEVEL`` holds for all higher frequencies; a grid ending there needs no roll-off
    below 1/8.
    """
    mx = np.maximum(absL[:, :-1], absL[:, 1:])
    bad = (np.abs(dphase) > MAX_ANGLE_STEP) & (mx >= RESOLVE_LEVEL)
    end_ok = absL[:, -1] < RESOLVE_LEVEL
    if safe is not None:
        bad &= ~safe[:, :-1]
        end_ok |= safe[:, -1]
    out = bad.any(axis=1) | ~end_ok | ~np.isfinite(absL.sum(axis=1))
    dF = np.diff(F, axis=1)
    return out | _ambiguous(F, absF, dF, np.abs(dF), None if safe is None else safe[:, :-1])


def _nyquist_core(L: np.ndarray, absL: np.ndarray, dphase: np.ndarray, F: np.ndarray, absF: np.ndarray,
                  ki_dir: np.ndarray, safe: np.ndarray | None = None):
    """Winding count of ``1 + L`` for a batch; ``ki_dir`` is ``sign(Ki P(0))`` (0: no integrator)."""
    argF0, argF1 = np.angle(F[:, 0]), np.angle(F[:, -1])
    integ = ki_dir != 0
    # Limit of arg(1 + L) as w -> 0+: that of Ki P(0) / (jw) with an integrator, else 0 or pi.
    start = np.where(integ, -0.5 * math.pi * ki_dir, np.where(F[:, 0].real >= 0, 0.0, math.pi))
    first = _wrap(argF0 - start)  # (0, w0]: change < pi (element phase < 0.1 rad there)
    inner = argF1 - argF0 + _TWO_PI * _branch_crossings(F)  # = sum of principal increments
    last = -argF1  # w[-1] -> inf: |L| < 1/2 keeps 1 + L in Re > 1/2, ends at arg 1 = 0
    delta_plus = first + inner + last
    # Clockwise D-contour: both half-axes contribute delta_plus, the right indentation -pi.
    wind = -(2.0 * delta_plus - np.where(integ, math.pi, 0.0)) / _TWO_PI
    n_rhp = np.rint(wind)
    n_rhp = np.where(np.isfinite(n_rhp), n_rhp, 0.0)
    resolved = ~_unresolved(L, absL, dphase, F, absF, safe) & (np.abs(wind - n_rhp) < 0.25)
    marginal = (absF <= 1e-12 * (1.0 + absL)).any(axis=1)
    stable = resolved & (n_rhp == 0) & ~marginal
    return stable, n_rhp.astype(np.int64), resolved


def nyquist_stable(Pw, Cw, w, *, Ki=None, tail=None) -> np.ndarray:
    """Closed-loop stability of ``L = P C`` for a batch of controllers by the Nyquist criterion.

    The winding number of ``1 + L(s)`` about the origin is taken along the Nyquist D-contour:
    the imaginary axis, indented to the right around the integrator's pole at ``s = 0``, closed in
    the right half-plane. With no open-loop pole in the open right half-plane (assumption: ``P`` is
    a stable element, e.g. a TFElement or decoupled ``h_ii``; the controller's filter pole is
    stable), the loop is stable iff the winding number is zero. Pieces of the contour:

    * ``w -> 0+``: ``L ~ Ki P(0) / (jw)``, so ``arg(1 + L) -> -pi/2 sign(Ki P(0))`` and the
      indentation ``s = eps e^{j theta}``, ``theta: -pi/2 -> pi/2``, turns ``1 + L`` by exactly
      ``-pi`` (analytically, whatever the sign); without integrator (``Ki = 0``) ``1 + L(0)`` is
      real and the indentation adds nothing. The stretch ``(0, w[0]]`` is taken as the principal
      change, valid because ``P`` has turned less than 0.1 rad there (checked).
    * grid: the change between consecutive samples is the principal value of
      ``arg((1 + L_{k+1}) / (1 + L_k))``. Where ``|L| < 1/2`` on a whole step, ``1 + L`` stays in
      the disc of radius 1/2 about 1 (inside ``Re > 1/2``), so it cannot circle the origin and the
      principal value is exact however fast a delay turns ``L``: such stretches contribute no
      encirclement of -1 and need no resolution. Elsewhere the chord between samples stands for
      the curve, which needs (a) ``|arg(L_{k+1}/L_k)| <= MAX_ANGLE_STEP = 0.5`` rad on every step
      reaching ``|L| >= RESOLVE_LEVEL = 1/8`` (the factor 4 below 1/2 covers the magnitude ripple of
      an element with several delays, e.g. ``g11 - g12 g21/g22``, between samples; a pure change of
      magnitude, as in the integrator region, is a straight chord and needs no limit), and (b) no
      chord passing the origin closer than 1.5 times the curve's estimated deviation from it
      (``|second difference of 1 + L| / 8``): otherwise the samples do not tell on which side of
      -1 the loop passes.
    * ``w[-1] -> inf`` and the closing arc: ``|L(j w[-1])| < 1/8`` is required and ``|L|`` assumed
      to stay below 1/2 beyond the grid (strictly proper element, grid extended past roll-off),
      so ``arg(1 + L)`` returns to 0 within ``(-pi/6, pi/6)``. A loop that does not roll off (a
      biproper element) can instead give ``tail``, a bound of ``|L|`` beyond each sample: where
      ``tail < TAIL_LEVEL = 0.9``, ``1 + L`` stays in the disc of radius 0.9 about 1 for every
      higher frequency (and, the delays being of modulus <= 1 in the right half-plane, on the
      closing arc), so the principal increments there are exact however fast the delay turns
      ``L``, and the rest of the contour changes ``arg(1 + L)`` by exactly
      ``-2 arg(1 + L(j w[-1]))``, which is what the count takes: the grid may end there.

    A candidate failing (a), (b) or the end condition is *unresolved* and reported unstable
    (conservative for design); (b) makes loops within a relative ``~(step)^2`` of a stability
    boundary unresolved rather than misjudged. Checked against the closed-loop poles of Pade
    models (tests): every resolved winding number equals the number of right-half-plane poles.

    Parameters
    ----------
    Pw : array_like, shape (m,)
        Exact element response on ``w``.
    Cw : array_like, shape (n, m) or (m,)
        Controller responses.
    w : array_like, shape (m,)
        Strictly increasing grid, ``w[0] > 0`` low enough that ``P(j w[0])`` is within 0.1 rad of
        its real static gain; see :func:`design_grid`.
    Ki : array_like, shape (n,), optional
        Integral gains (only their sign and whether they are 0 are used). Default: read from the
        lowest frequency as ``Re(j w[0] C(j w[0]))``, exact up to ``O(w[0]^2)`` for PI/PID.
    tail : array_like, shape (n, m), optional
        ``tail[r, k] >= sup of |L_r(jw)|`` over the step ``[w[k], w[k+1]]`` (over ``w >= w[-1]``
        for the last sample), e.g. ``sup over w >= w[k]`` from the element's and the
        controller's high-frequency magnitude bounds.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
    """
    return loop_metrics_batch(Pw, w, Cw, Ki=Ki, tail=tail).stable


class _Triple:
    """Quadratic (Newton form) through three consecutive samples ``j0, j0+1, j0+2`` of each row."""

    def __init__(self, u: np.ndarray, j0: np.ndarray):
        self.rows = np.arange(j0.size)
        self.idx = j0[:, None] + np.arange(3)
        self.j0 = j0
        self.U = u[self.idx]

    def gather(self, y: np.ndarray) -> np.ndarray:
        return np.take_along_axis(y, self.idx, axis=1)

    def coeffs(self, Y: np.ndarray):
        U = self.U
        d1 = (Y[:, 1] - Y[:, 0]) / (U[:, 1] - U[:, 0])
        d2 = (Y[:, 2] - Y[:, 1]) / (U[:, 2] - U[:, 1])
        return Y[:, 0], d1, (d2 - d1) / (U[:, 2] - U[:, 0])

    def value(self, Y: np.ndarray, x: np.ndarray) -> np.ndarray:
        y0, d1, a = self.coeffs(Y)
        U = self.U
        return y0 + d1 * (x - U[:, 0]) + a * (x - U[:, 0]) * (x - U[:, 1])

    def cross(self, Y: np.ndarray, k: np.ndarray, level: float) -> np.ndarray:
        """Root of ``quadratic = level`` in ``[u_k, u_{k+1}]`` (Newton from the linear estimate)."""
        i = k - self.j0
        r = self.rows
        ua, ub = self.U[r, i], self.U[r, i + 1]
        ya, yb = Y[r, i], Y[r, i + 1]
        t = np.clip(np.nan_to_num((level - ya) / (yb - ya)), 0.0, 1.0)
        x_lin = ua + t * (ub - ua)
        y0, d1, a = self.coeffs(Y)
        U0, U1 = self.U[:, 0], self.U[:, 1]

        def resid(x):
            return y0 + d1 * (x - U0) + a * (x - U0) * (x - U1) - level

        x = x_lin
        for _ in range(3):
            dq = d1 + a * (2.0 * x - U0 - U1)
            x = np.clip(np.where(dq != 0, x - resid(x) / dq, x), ua, ub)
        better = np.isfinite(x) & (np.abs(resid(x)) <= np.abs(resid(x_lin)))
        return np.where(better, x, x_lin)

    def peak(self, Y: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Maximum of the quadratic if the sample ``k`` is an interior local maximum, else ``Y`` at ``k``."""
        y0, d1, a = self.coeffs(Y)
        U = self.U
        yk = Y[self.rows, k - self.j0]
        xs = np.clip(0.5 * (U[:, 0] + U[:, 1]) - d1 / (2.0 * a), U[:, 0], U[:, 2])
        pk = y0 + d1 * (xs - U[:, 0]) + a * (xs - U[:, 0]) * (xs - U[:, 1])
        ok = (k == self.j0 + 1) & (a < 0) & np.isfinite(pk)
        return np.where(ok, np.maximum(pk, yk), yk)


def unwrapped_phase(L: np.ndarray, *, with_steps: bool = False):
    """Phase of each row of ``L`` unwrapped along the grid: the principal value at the first
    sample plus the principal increments ``arg(L_{k+1} / L_k)``.

    Parameters
    ----------
    L : numpy.ndarray, shape (n, m), complex
        Loop responses of ``n`` candidates on ``m`` frequencies.
    with_steps : bool
        Also return the increments.

    Returns
    -------
    phase : numpy.ndarray, shape (n, m)
    steps : numpy.ndarray, shape (n, m - 1)
        Only with ``with_steps=True``.
    """
    phase = np.empty(L.shape)
    phase[:, 0] = 0.0
    dphase = np.angle(L[:, 1:] * np.conj(L[:, :-1]))
    np.cumsum(dphase, axis=1, out=phase[:, 1:])
    phase += np.angle(L[:, :1])
    return (phase, dphase) if with_steps else phase


def _triple(u: np.ndarray, k: np.ndarray) -> _Triple:
    """Three consecutive samples containing the step ``k -> k+1`` (centred on ``k`` when possible)."""
    j0 = np.clip(k - 1, 0, u.size - 3)
    return _Triple(u, j0)


def _first(cond: np.ndarray):
    """Whether each row has a True and the index of the first one."""
    return cond.any(axis=1), np.argmax(cond, axis=1)


def loop_metrics_batch(Pw, w, Cw, *, Ki=None, tail=None) -> LoopMetrics:
    """Margins, crossovers, bandwidth, peaks and Nyquist stability of ``L = P C`` for a batch.

    Definitions (``L = P C``, ``T = L/(1 + L)``, ``S = 1/(1 + L)``, ``u = ln w``):

    * phase crossover ``w_pc``: first frequency where the phase of ``L``, unwrapped continuously
      from its principal value at ``w[0]``, reaches -180 deg (as :func:`tito.exact_margins`; none if
      it is already there at ``w[0]``); ``gain_margin = 1/|L(j w_pc)|``.
    * gain crossover ``w_gc``: first frequency where ``|L|`` falls from > 1 to <= 1;
      ``phase_margin_deg = arg L(j w_gc) + 180`` wrapped to ``[-180, 180]``.
    * bandwidth ``w_b``: first frequency where ``|T|`` falls below ``1/sqrt(2)`` (``|T(0)| = 1`` with
      integral action, so this is the -3 dB frequency); 0 if ``|T(j w[0])| < 1/sqrt(2)``; ``w[-1]``
      (censored) if ``|T|`` never falls below it on the grid.
    * ``Mt = max |T|``, ``Ms = max |S|`` on the grid, refined by a parabola in ``u`` through the
      largest sample of ``ln|T|`` (``ln|S|``) and its neighbours.

    Each crossing is bracketed by two samples and refined on the quadratic (in ``u``) through those
    and a neighbouring sample (three Newton steps, falling back to linear interpolation); margins
    are read from the same quadratics of ``ln|L|`` and the unwrapped phase, and the peaks from the
    parabola through the largest sample and its neighbours. The error is ``O(h^3)`` for a step
    ``h`` in ``u``. Measured against brentq/``minimize_scalar`` on the exact response with
    :func:`design_grid` grids of 2000 points (PI at 0.5, 1, 1.5 times a GPM design and a filtered
    PID, both loops of each preset): relative errors of GM, ``w_gc``, ``w_pc`` below 4e-6, of ``w_b``
    below 2e-5, of ``Mt``, ``Ms`` below 4e-5 and PM within 5e-4 deg for ccts, qts and two_tank; for
    wood_berry's ``h11``, whose two delayed terms of similar size make the loop ripple, GM 1.5e-4,
    ``w_pc`` 4e-5, ``Mt`` 3e-4, PM 1e-3 deg (about 8 times smaller with 4000 points). A crossing
    where ``|L|`` barely touches 1 (e.g. a ripple grazing the unit circle) is ill-conditioned and
    located less accurately.

    Parameters
    ----------
    Pw : array_like, shape (m,)
        Exact frequency response of the SISO loop element on ``w`` (e.g. ``Decoupler.z11(w)``).
    w : array_like, shape (m,)
        Strictly increasing frequencies (rad/s), ``w[0] > 0``; see :func:`design_grid`.
    Cw : array_like, shape (n, m) or (m,)
        Controller responses of ``n`` candidates (e.g. :func:`pid_freqresp`).
    Ki : array_like, shape (n,), optional
        Integral gains for the Nyquist count (see :func:`nyquist_stable`).
    tail : array_like, shape (n, m), optional
        Bounds of ``|L|`` beyond each sample for the Nyquist count (see :func:`nyquist_stable`).

    Returns
    -------
    LoopMetrics

    Raises
    ------
    ConfigError
        Malformed shapes, non-finite ``Pw``, or a grid starting too high (``P(j w[0])`` not within
        0.1 rad of a non-zero real static gain).
    """
    w = _grid(w)
    Pw = _check_element(Pw, w)
    Cw = _controllers(Cw, w.size)
    u = np.log(w)
    ki = _integral_gains(Ki, Cw, w)
    ki_dir = np.sign(ki) * np.sign(Pw[0].real)

    with np.errstate(all="ignore"):
        L = Pw[None, :] * Cw
        absL = np.abs(L)
        F = 1.0 + L
        absF = np.abs(F)
        absT = absL / absF

        phase, dphase = unwrapped_phase(L, with_steps=True)

        # Phase crossover: first sample at or below -pi, bracketed by the previous one.
        has_pc, kb = _first(phase <= -math.pi)
        has_pc &= kb > 0
        k = np.maximum(kb - 1, 0)
        tri = _triple(u, k)
        u_pc = tri.cross(tri.gather(phase), k, -math.pi)
        ln_pc = tri.value(np.log(tri.gather(absL)), u_pc)
        gm = np.where(has_pc, np.exp(-ln_pc), np.inf)
        w_pc = np.where(has_pc, np.exp(u_pc), np.nan)

        # Gain crossover: |L| falls from > 1 to <= 1.
        above = absL > 1.0
        has_gc, k = _first(above[:, :-1] & ~above[:, 1:])
        tri = _triple(u, k)
        u_gc = tri.cross(np.log(tri.gather(absL)), k, 0.0)
        ph = tri.value(tri.gather(phase), u_gc)
        pm = np.where(has_gc, np.degrees(_wrap(ph + math.pi)), np.inf)
        w_gc = np.where(has_gc, np.exp(u_gc), np.nan)

        # Bandwidth: |T| falls below 1/sqrt(2).
        c = BANDWIDTH_LEVEL
        above = absT >= c
        has_b, k = _first(above[:, :-1] & ~above[:, 1:])
        tri = _triple(u, k)
        u_b = tri.cross(np.log(tri.gather(absT)), k, math.log(c))
        w_b = np.where(absT[:, 0] < c, 0.0, np.where(has_b, np.exp(u_b), w[-1]))

        # Peaks of |T| and |S| = 1/|1 + L|, refined on ln|T| and -ln|1 + L|.
        k = np.argmax(absT, axis=1)  # a NaN row gives NaN peaks
        tri = _triple(u, k)
        Mt = np.exp(tri.peak(np.log(tri.gather(absT)), k))
        k = np.argmin(absF, axis=1)
        tri = _triple(u, k)
        Ms = np.exp(tri.peak(-np.log(tri.gather(absF)), k))

        safe = None
        if tail is not None:
            tail = np.asarray(tail, dtype=np.float64)
            if tail.shape != L.shape:
                raise ConfigError(f"tail must have shape {L.shape}, got {tail.shape}")
            safe = tail < TAIL_LEVEL
        stable, n_rhp, resolved = _nyquist_core(L, absL, dphase, F, absF, ki_dir, safe)
    return LoopMetrics(gain_margin=gm, phase_margin_deg=pm, w_gc=w_gc, w_pc=w_pc, w_b=w_b, Mt=Mt, Ms=Ms,
                       stable=stable, n_rhp=n_rhp, resolved=resolved)


# --------------------------------------------------------------------------------------------
# MIMO: generalised Nyquist on det(I + G D C)
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class NyquistVerdict:
    """Result of :func:`mimo_nyquist`.

    Attributes
    ----------
    stable : bool
        Resolved and no encirclement of the origin by ``det(I + G D C)``.
    n_rhp : int
        Closed-loop right-half-plane poles given by the winding number (meaningful if resolved).
    resolved : bool
        Grid adequate (see :func:`mimo_nyquist`) and a low-frequency asymptote was found.
    n_integrators : int
        Order of the pole of ``det(I + G D C)`` at ``s = 0`` found from its low-frequency slope.
    """

    stable: bool
    n_rhp: int
    resolved: bool
    n_integrators: int


def _mimo_loop(plant: TITOPlant, decoupler: Decoupler | None, controllers, w: np.ndarray) -> np.ndarray:
    M = plant.freqresp(w)
    if decoupler is not None:
        M = M @ decoupler.freqresp(w)
    c = np.stack([np.asarray(ci.freqresp(w), dtype=np.complex128) for ci in controllers], axis=1)
    return M * c[:, None, :]


def mimo_nyquist(plant: TITOPlant, decoupler: Decoupler | None, controllers, w) -> NyquistVerdict:
    """Generalised Nyquist test of the decentralised loop ``u = C (r - y)``, ``y = G D u``.

    Counts the encirclements of the origin by ``F(jw) = det(I + M(jw))``, ``M = G D C`` with
    ``C = diag(c1, c2)``, along the D-contour indented to the right around ``s = 0``. All open-loop
    poles are in the open left half-plane or at ``s = 0`` (stable elements and decoupler, see the
    module notes; the controllers' integrators), so the closed loop is stable iff the winding
    number is zero. ``F = 1 + Q`` with ``Q = tr M + det M``, and ``Q`` takes the part of ``L`` in
    :func:`nyquist_stable`: where ``|Q| < 1/2`` the samples of ``F`` stay in the disc of radius 1/2
    about 1 and cannot circle the origin; elsewhere the same resolution and ambiguity checks apply.

    Low frequencies are handled without assuming how many integrators act: ``F`` is evaluated
    decade by decade below ``w[0]`` until it follows ``c0 / (jw)^p`` (slope of ``log|F|`` within
    0.01 of an integer ``p`` in {0, 1, 2} and phase constant within 1e-3 rad over a decade); that
    stretch is added to the grid and the indentation contributes ``-p pi``. A singular static gain
    (``det(G(0) D(0)) = 0``) therefore gives a lower ``p`` instead of a wrong count.

    Parameters
    ----------
    plant : TITOPlant
    decoupler : Decoupler or None
        ``None`` means ``D = I`` (plain decentralised control).
    controllers : pair
        Two objects with a vectorised ``freqresp(w)`` (:class:`PIController`, :class:`PIDController`).
    w : array_like, shape (m,)
        Strictly increasing grid (rad/s) that resolves ``Q`` wherever ``|Q| >= 1/8`` and ends where
        ``|Q| < 1/8``, e.g. :func:`design_grid` on the four elements of ``G D`` (``P(w)`` returning
        ``(G(w) @ D(w)).reshape(-1, 4)``) with ``mag_floor = 1/(8 c_max)``.

    Returns
    -------
    NyquistVerdict
    """
    w = _grid(w)
    if len(controllers) != 2:
        raise ConfigError("mimo_nyquist: controllers must be a pair (c1, c2)")

    def det_parts(ww):
        M = _mimo_loop(plant, decoupler, controllers, ww)
        tr = M[:, 0, 0] + M[:, 1, 1]
        dt = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
        return tr, dt

    # Low-frequency asymptote F ~ c0 (jw)^-p: decades w[0] 10^-j, j = 0..16.
    wd = w[0] * 10.0 ** -np.arange(17.0)
    tr, dt = det_parts(wd)
    Fd = 1.0 + tr + dt
    with np.errstate(all="ignore"):
        slope = np.log10(np.abs(Fd[1:]) / np.abs(Fd[:-1]))
        dphase = np.abs(np.angle(Fd[1:] / Fd[:-1]))
    p_int = np.rint(slope)
    ok = (np.abs(slope - p_int) < 0.01) & (dphase < 1e-3) & (p_int >= 0) & (p_int <= 2)
    if not ok.any():
        return NyquistVerdict(False, 0, False, -1)
    j = int(np.argmax(ok))
    p = int(p_int[j])
    w_t = wd[j]
    if j > 0:
        n_pre = math.ceil(math.log(w[0] / w_t) / 0.02) + 1
        w_all = np.concatenate((np.geomspace(w_t, w[0], n_pre)[:-1], w))
    else:
        w_all = w
    tr, dt = det_parts(w_all)
    Q = (tr + dt)[None, :]  # F = 1 + Q plays the part of 1 + L
    F = 1.0 + Q
    absQ, absF = np.abs(Q), np.abs(F)
    argF = np.angle(F[0])
    # arg F(0+) equals arg F(w_t) to 1e-3 rad; continue along the grid, then to arg 1 = 0 at infinity.
    delta_plus = argF[-1] - argF[0] + _TWO_PI * _branch_crossings(F)[0] - argF[-1]
    wind = -(2.0 * delta_plus - p * math.pi) / _TWO_PI
    n_rhp = int(np.rint(wind)) if np.isfinite(wind) else 0
    dphase = np.angle(Q[:, 1:] * np.conj(Q[:, :-1]))
    resolved = bool(not _unresolved(Q, absQ, dphase, F, absF)[0] and abs(wind - n_rhp) < 0.25)
    marginal = bool((absF <= 1e-12 * (1.0 + absQ)).any())
    return NyquistVerdict(resolved and n_rhp == 0 and not marginal, n_rhp, resolved, p)


def tito_closed_loop_stable(plant: TITOPlant, decoupler: Decoupler | None, controllers, w) -> bool:
    """True when the decentralised TITO loop is stable by the generalised Nyquist criterion.

    Shorthand for ``mimo_nyquist(plant, decoupler, controllers, w).stable``; an unresolved grid
    counts as unstable. With a decoupler, ``G D = diag(h11, h22)`` and the verdict equals the
    conjunction of the two SISO verdicts of :func:`nyquist_stable` on ``Decoupler.z11/z22``.

    Parameters
    ----------
    plant : TITOPlant
    decoupler : Decoupler or None
        ``None`` for ``D = I``.
    controllers : pair of PIController / PIDController
    w : array_like, shape (m,)
        Frequency grid (see :func:`mimo_nyquist`).

    Returns
    -------
    bool
    """
    return mimo_nyquist(plant, decoupler, controllers, w).stable


# --------------------------------------------------------------------------------------------
# Design evaluator
# --------------------------------------------------------------------------------------------


def bandwidth_design_eval(Pw, w, X, kind, N, Am_min, phim_min_deg, Mt_max, *, return_metrics=False, tail=None):
    """Objective and constraints of the bandwidth-optimal PI/PID design of one loop, for a batch.

    For each candidate row of ``X`` the controller :func:`pid_freqresp` is closed around the
    element ``Pw`` and :func:`loop_metrics_batch` evaluated. Returns

    * ``f = -w_b`` (minimising ``f`` maximises the closed-loop bandwidth); ``f = 0`` for candidates
      that are not stable;
    * ``g`` of shape ``(n, 3)``, feasible when ``g <= 0``::

          g[:, 0] = 1 - Am / Am_min             (gain margin >= Am_min)
          g[:, 1] = 1 - phim / phim_min_deg      (phase margin >= phim_min_deg, degrees)
          g[:, 2] = Mt / Mt_max - 1              (closed-loop peak max|T| <= Mt_max)

      clipped to ``[-G_CLIP, G_CLIP]`` (an infinite margin gives ``-G_CLIP``); for a candidate that
      is not stable (Nyquist, including unresolved grids and non-finite gains) every entry is
      replaced by ``max(g, 0) + UNSTABLE_VIOLATION``, so it is infeasible with a finite violation;
    * ``stable``, bool of shape ``(n,)``.

    Never raises for any gains and never returns NaN.

    Parameters
    ----------
    Pw : array_like, shape (m,)
        Exact response of the loop element on ``w`` (e.g. ``Decoupler.z11(w)``).
    w : array_like, shape (m,)
        Grid (see :func:`design_grid`).
    X : array_like, shape (n, 2) or (n, 3)
        ``[Kp, Ki]`` rows for ``kind="pi"``, ``[Kp, Ki, Kd]`` for ``kind="pid"``.
    kind : {"pi", "pid"}
    N : float
        PID filter ratio ``Td/Tf`` (unused for PI).
    Am_min, phim_min_deg, Mt_max : float
        Specifications (> 0; ``phim_min_deg`` in degrees).
    return_metrics : bool
        Also return the loop metrics.
    tail : array_like, shape (n, m), optional
        Passed to :func:`loop_metrics_batch` (bounds of ``|L|`` beyond each sample, for loops
        that do not roll off).

    Returns
    -------
    f : numpy.ndarray, shape (n,)
    g : numpy.ndarray, shape (n, 3)
    stable : numpy.ndarray of bool, shape (n,)
    metrics : LoopMetrics
        Only with ``return_metrics=True``: the loop metrics the verdicts come from.
    """
    if kind not in ("pi", "pid"):
        raise ConfigError(f"bandwidth_design_eval: kind must be 'pi' or 'pid', got {kind!r}")
    spec = _finite_scalars("bandwidth_design_eval", Am_min=Am_min, phim_min_deg=phim_min_deg, Mt_max=Mt_max)
    if min(spec.values()) <= 0:
        raise ConfigError(f"bandwidth_design_eval: Am_min, phim_min_deg, Mt_max must be > 0, got {spec}")
    d = 2 if kind == "pi" else 3
    X = np.asarray(X, dtype=np.float64)
    if X.ndim == 1:
        X = X[None, :]
    if X.ndim != 2 or X.shape[1] != d:
        raise ConfigError(f"bandwidth_design_eval: X must have shape (n, {d}) for kind={kind!r}, got {X.shape}")
    w = _grid(w)
    finite = np.isfinite(X).all(axis=1)
    Xs = np.where(finite[:, None], X, 0.0)
    Kd = Xs[:, 2] if d == 3 else np.zeros(X.shape[0])
    Cw = pid_freqresp(Xs[:, 0], Xs[:, 1], Kd, N if d == 3 else 1.0, w)
    m = loop_metrics_batch(Pw, w, Cw, Ki=Xs[:, 1], tail=tail)
    f, g, stable = bandwidth_design_values(m, finite, **spec)
    if return_metrics:
        return f, g, stable, m
    return f, g, stable


def bandwidth_design_values(m: LoopMetrics, finite: np.ndarray, Am_min: float, phim_min_deg: float,
                            Mt_max: float):
    """``(f, g, stable)`` of :func:`bandwidth_design_eval` from loop metrics already computed.

    Parameters
    ----------
    m : LoopMetrics
        Metrics of ``n`` candidates (for instance exact ones from
        :func:`heurtune.objectives.tito.margins.candidate_loop_metrics`).
    finite : numpy.ndarray of bool, shape (n,)
        Whether each candidate's gains are finite.
    Am_min, phim_min_deg, Mt_max : float
        Specifications, > 0 (see :func:`bandwidth_design_eval`).

    Returns
    -------
    f, g, stable
        As :func:`bandwidth_design_eval`.
    """
    with np.errstate(all="ignore"):
        g = np.stack([1.0 - m.gain_margin / Am_min,
                      1.0 - m.phase_margin_deg / phim_min_deg,
                      m.Mt / Mt_max - 1.0], axis=1)
    g = np.clip(np.nan_to_num(g, nan=G_CLIP, posinf=G_CLIP, neginf=-G_CLIP), -G_CLIP, G_CLIP)
    stable = m.stable & finite
    g = np.where(stable[:, None], g, np.minimum(np.maximum(g, 0.0) + UNSTABLE_VIOLATION, G_CLIP))
    f = np.where(stable, -np.nan_to_num(m.w_b, nan=0.0, posinf=0.0), 0.0) + 0.0  # no -0.0
    return f, g, stable
