"""Exact loop metrics of one controller on a decoupled TITO loop: a grid of its own, then roots.

A decoupled loop element is a sum of delayed rational terms: ``z11 = g11 - g12 g21 / g22`` has
the diagonal element's term and a cross-coupling term whose dead time is ``L12 + L21 - L22``. For
the CSTS that second term carries 163.6 s of dead time at a tenth of the first term's magnitude:
it makes the loop ripple with a period of 2 pi / 163.6 = 0.038 rad/s, and the gain and phase
margins depend on where that ripple is. A grid shared by every candidate of a gain box has to
resolve the loop of the box's largest gains as far as they reach, hundreds of thousands of points
on the CSTS; the shared grid of :meth:`TITOProblem._design_grid` stops at 48,000 and so
under-resolves the ripple where a moderate candidate's margins are decided (paper 001's CSTS GPM
PI read gain margins 3.52 and 3.68 from it, where the exact ones are 2.98 and 2.99).

Here every candidate gets a grid of its own, dense where its own loop needs it, and every
crossing bracketed on that grid is refined by a root finder on the exact frequency response.

The grid
--------
With ``u = ln w`` and the element ``q = sum_j t_j``, the logarithmic rate of each term is bounded
analytically::

    |d ln t_j / du| <= rho_j(w) = w |L_j| + sum_T w |T| / |1 + j w T|

(``L_j`` the term's net dead time, ``T`` every lead and lag of its factors), so
``|d ln L / du| <= R = sum_j |t_j| rho_j / q_low + rho_C`` with ``q_low`` a lower bound of ``|q|``
(``|t_max| - sum of the others``, not below a twentieth of ``E = sum_j |t_j|`` where the terms may
cancel) and ``rho_C`` the controller's bound (2 for a PI, 4 for a filtered PID). Every quantity in
``R`` is a magnitude without delays, smooth in ``u``, so a probe of 200 points per decade
integrates it; the delays enter only through their analytic rates. The grid has two parts:

* from ``w_min`` to the first phase crossover, points uniform in
  ``dLambda = (1 + min(1, E |C| / 1e-6)^4 R) du`` with a step of ``STEP = 0.1`` in ``Lambda``:
  ``ln L`` turns by at most 0.1 rad per step wherever ``|L|`` may exceed 1e-6, so the unwrapped
  phase, and with it the first phase crossover and every gain margin below 1e6, is never
  aliased. The grid is laid out in chunks until the phase reaches -180 deg;
* beyond it, ``dLambda = (1 + min(1, E |C| / 0.4)^4 R) du``: resolved where ``|L|`` may reach
  0.4 (gain crossover, bandwidth, peaks above ``Mt = 1`` or ``Ms = 2`` and the Nyquist count,
  for which ``1 + L`` cannot reach the origin where ``|L| < 1``); the fourth power switches the
  requirement off quickly below 0.4 (a delay's rate grows like ``w`` while ``|L|`` falls like
  ``1/w``, so a first power would keep the density constant up to ``w_max``).

The Nyquist count (:func:`~heurtune.objectives.tito.design.loop_metrics_batch`) is told, step by
step, where ``E |C|`` bounds ``|L|`` below 0.9, so that the coarse steps of the second part need no
resolution there. A candidate whose grid would need more than ``N_MAX`` points (a filtered PID
whose derivative gain keeps ``|L|`` above 0.4 over thousands of turns of a delay, far beyond
every stable design of the presets) is not resolved, hence not stable.

The roots
---------
The first phase crossover (unwrapped phase reaching -180 deg), the first gain crossover (``|L|``
falling through 1) and the bandwidth (``|T|`` falling through ``1/sqrt 2``) are bracketed by two
samples and refined by brentq on the exact response (``xtol`` 1e-12 relative); the margins are
read from the exact response at the roots. The peaks ``Mt`` and ``Ms`` are refined by bounded
Brent between the neighbours of every sample crest within 2 % of the largest. A crossing where
``|L|`` only grazes 1, or ``|T|`` grazes ``1/sqrt 2``, between two samples is not seen (a touch
narrower than a step: on the CSTS the ripple takes ``|T|`` 0.07 % below the level over 0.001
rad/s, and the bandwidth is then the next crossing). Checked in the tests against 10^6
log-spaced points and brentq, on every preset with the printed and GPM controllers, at their
gains and scaled up to instability.
"""

from __future__ import annotations

import cmath
import dataclasses
import functools
import math

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from . import design as tito_design
from .model import TFElement

__all__ = ["MARGIN_LEVEL", "N_MAX", "STEP", "TAIL_RESOLVE_LEVEL", "LoopTerm", "candidate_grid",
           "candidate_loop_metrics"]

STEP = 0.1
"""Largest turn of ``ln L`` (rad) between consecutive samples where the grid resolves ``L``."""
N_MAX = 1 << 16
"""A candidate whose grid would need more points is not resolved (reported not stable)."""
MARGIN_LEVEL = 1e-6
"""Up to the first phase crossover the grid resolves ``L`` where ``|L| >= 1e-6``: every gain margin
below 1e6 is exact (a loop with no controller, ``C = 0``, needs no points)."""
TAIL_RESOLVE_LEVEL = 0.4
"""Beyond the first phase crossover the grid resolves ``L`` where ``|L| >= 0.4``: enough for the gain
crossover, the bandwidth (``|T| = 1/sqrt 2`` needs ``|L| >= 0.41``), peaks above ``Mt = 1`` and
``Ms = 2`` (both need ``|L| > 1/2``) and the Nyquist count (``1 + L`` cannot reach the origin where
``|L| < 1``)."""
PROBES_PER_DECADE = 200
FIRST_CHUNK = 512
_CANCEL_FLOOR = 0.05  # q_low is at least this fraction of the envelope where the terms may cancel
_XTOL = 1e-12


@dataclasses.dataclass(frozen=True)
class LoopTerm:
    """One term ``prod(num) / prod(den) e^{-extra_delay s}`` of a loop element.

    Parameters
    ----------
    num, den : tuple of TFElement
        Factors multiplied and divided (each with its own dead time).
    sign : float
        +1 or -1 (the decoupled element subtracts its cross-coupling term).
    extra_delay : float
        A dead time on the whole term (the decoupler's column delay), >= 0.
    """

    num: tuple
    den: tuple = ()
    sign: float = 1.0
    extra_delay: float = 0.0

    def __post_init__(self):
        for e in self.num + self.den:
            if not isinstance(e, TFElement):
                raise TypeError(f"LoopTerm factors must be TFElement, got {type(e).__name__}")

    @property
    def delay(self) -> float:
        """Net dead time of the term (s)."""
        return sum(e.L for e in self.num) - sum(e.L for e in self.den) + self.extra_delay

    @property
    def time_constants(self) -> tuple:
        """``|T|`` of every lead and lag of every factor (zeros left out)."""
        return tuple(abs(t) for e in self.num + self.den for t in e.leads + e.lags if t != 0.0)

    def magnitude(self, w: np.ndarray) -> np.ndarray:
        """``|t(j w)|`` (delays do not change magnitudes)."""
        out = np.ones(w.shape)
        for e in self.num:
            out *= np.abs(e.rational(w))
        for e in self.den:
            out /= np.abs(e.rational(w))
        return out

    def rate(self, w: np.ndarray) -> np.ndarray:
        """Bound of ``|d ln t / d ln w|``: ``w |L| + sum_T w T / |1 + j w T|``."""
        out = w * abs(self.delay)
        for t in self.time_constants:
            out = out + w * t / np.sqrt(1.0 + (w * t) ** 2)
        return out

    def response(self, w: np.ndarray) -> np.ndarray:
        """Exact ``t(j w)``."""
        out = np.full(w.shape, self.sign, dtype=np.complex128)
        for e in self.num:
            out *= e.freqresp(w)
        for e in self.den:
            out /= e.freqresp(w)
        if self.extra_delay:
            out *= np.exp(-1j * w * self.extra_delay)
        return out


def _element(terms, w: np.ndarray) -> np.ndarray:
    return sum(t.response(w) for t in terms)


@dataclasses.dataclass
class _Probe:
    """Smooth, delay-free magnitudes of the loop on a probe grid in ``u = ln w``."""

    u: np.ndarray
    env: np.ndarray  # sum_j |t_j|, an upper envelope of |q|
    rate: np.ndarray  # bound of |d ln L / du|: sum_j |t_j| rho_j / q_low + rho_C
    c_mag: np.ndarray

    def measure(self, level: float) -> np.ndarray:
        """Cumulative ``Lambda(u)`` of the grid measure that resolves ``L`` where ``|L| >= level``."""
        with np.errstate(all="ignore"):
            weight = np.minimum(1.0, self.env * self.c_mag / level) ** 4 * self.rate
        dens = 1.0 + np.nan_to_num(weight, nan=0.0, posinf=1e300)
        return np.concatenate(([0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(self.u))))


@functools.lru_cache(maxsize=64)
def _term_probe(terms: tuple, w_min: float, w_max: float):
    """``(u, E, R_q)`` of the element on the probe grid: the envelope ``sum_j |t_j|`` and the rate
    bound ``sum_j |t_j| rho_j / q_low`` (the same for every controller; read-only)."""
    decades = math.log10(w_max / w_min)
    u = np.linspace(math.log(w_min), math.log(w_max), max(int(PROBES_PER_DECADE * decades), 64))
    w = np.exp(u)
    mags = np.array([t.magnitude(w) for t in terms])
    env = mags.sum(axis=0)
    q_low = np.maximum(2.0 * mags.max(axis=0) - env, _CANCEL_FLOOR * env)
    rates = np.array([t.rate(w) for t in terms])
    with np.errstate(all="ignore"):
        rate = (mags * rates).sum(axis=0) / q_low
    for array in (u, env, rate):
        array.flags.writeable = False
    return u, env, rate


def _probe(terms, gains, N: float, w_min: float, w_max: float) -> _Probe:
    kp, ki, kd = gains
    u, env, rate = _term_probe(tuple(terms), float(w_min), float(w_max))
    c_mag = np.abs(tito_design.pid_freqresp(kp, ki, kd, N, np.exp(u))[0])
    return _Probe(u=u, env=env, rate=rate + _controller_rate(kd), c_mag=c_mag)


def _controller_rate(kd: float) -> float:
    """Bound of ``|d ln C / d ln w|``: one per pole and zero (PI: integrator and zero; filtered PID:
    two of each)."""
    return 4.0 if kd != 0.0 else 2.0


def _points(lam: np.ndarray, u: np.ndarray, a: float, b: float, step: float) -> np.ndarray:
    """Points ``u`` from ``lam = a`` to ``lam = b`` spaced ``<= step`` in ``lam`` (both ends included)."""
    n = max(2, int(math.ceil((b - a) / step)) + 1)
    return np.interp(np.linspace(a, b, n), lam, u)


def candidate_grid(terms, gains, N: float, w_min: float, w_max: float, *, step: float = STEP,
                   n_max: int | None = None):
    """The frequency grid of one controller on the element ``sum(terms)`` (see the module docstring).

    From ``w_min`` up to the first phase crossover the grid resolves ``L`` wherever
    ``|L| >= MARGIN_LEVEL`` (the gain margin is decided there); beyond it, wherever
    ``|L| >= TAIL_RESOLVE_LEVEL`` (gain crossover, bandwidth, peaks above ``Mt = 1`` and ``Ms = 2``,
    and the Nyquist count, which needs no resolution where ``|L| < 0.9``).

    Parameters
    ----------
    terms : sequence of LoopTerm
    gains : (Kp, Ki, Kd)
        Parallel gains of the controller (:func:`~heurtune.objectives.tito.design.pid_freqresp`).
    N : float
        Derivative filter ratio.
    w_min, w_max : float
        Grid ends (rad/s), ``0 < w_min < w_max``.
    step, n_max : float, int
        See :data:`STEP`, :data:`N_MAX` (its value at the call, by default).

    Returns
    -------
    tuple or None
        ``(w, q(jw), C(jw))`` on the grid (``w`` strictly increasing from ``w_min`` to ``w_max``);
        None when the loop would need more than ``n_max`` points.
    """
    kp, ki, kd = (float(v) for v in gains)
    n_max = N_MAX if n_max is None else int(n_max)
    probe = _probe(terms, (kp, ki, kd), N, w_min, w_max)
    lam1 = probe.measure(MARGIN_LEVEL)
    lam2 = probe.measure(TAIL_RESOLVE_LEVEL)
    # the first measure is at least the second everywhere, so whatever the cut the grid has at
    # least lam2[-1] / step points: a loop wider than n_max is known before any is laid out
    if not (np.isfinite(lam1[-1]) and lam2[-1] / step < n_max):
        return None
    pieces_u, pieces_q, pieces_c = [], [], []
    count, pos, phase_end, L_end = 0, 0.0, None, None
    cut = None
    chunk = FIRST_CHUNK
    while pos < lam1[-1]:
        # march through the finely resolved measure, a chunk at a time, to the first phase crossover
        end = min(lam1[-1], pos + chunk * step)
        chunk *= 4
        uc = _points(lam1, probe.u, pos, end, step)
        if pieces_u:
            uc = uc[1:]
        wc = np.exp(uc)
        qc = _element(terms, wc)
        cc = tito_design.pid_freqresp(kp, ki, kd, N, wc)[0]
        Lc = qc * cc
        if L_end is None:
            phase = tito_design.unwrapped_phase(Lc[None, :])[0]
        else:
            phase = phase_end + np.cumsum(np.angle(Lc * np.conj(np.concatenate(([L_end], Lc[:-1])))))
        below = np.flatnonzero(phase <= -math.pi)
        if below.size:
            k = int(below[0]) + 1
            uc, qc, cc = uc[:k], qc[:k], cc[:k]
            cut = uc[-1]
        pieces_u.append(uc)
        pieces_q.append(qc)
        pieces_c.append(cc)
        count += uc.size
        if count > n_max:
            return None
        if cut is not None:
            break
        pos, phase_end, L_end = end, phase[-1], Lc[-1]
    if cut is not None and cut < probe.u[-1]:
        a = float(np.interp(cut, probe.u, lam2))
        if int(math.ceil((lam2[-1] - a) / step)) + count > n_max:
            return None
        u2 = _points(lam2, probe.u, a, lam2[-1], step)[1:]
        w2 = np.exp(u2)
        pieces_u.append(u2)
        pieces_q.append(_element(terms, w2))
        pieces_c.append(tito_design.pid_freqresp(kp, ki, kd, N, w2)[0])
    u = np.concatenate(pieces_u)
    keep = np.concatenate(([True], np.diff(u) > 0))  # interpolation may repeat a point
    w = np.exp(u[keep])
    q = np.concatenate(pieces_q)[keep]
    c = np.concatenate(pieces_c)[keep]
    w[0], w[-1] = w_min, w_max
    return w, q, c


def _root(fun, a: float, b: float, guess: float) -> float:
    """Root of ``fun`` in the bracket ``[a, b]`` (``fun(a) > 0 >= fun(b)`` on the grid's samples);
    ``guess`` (the grid's estimate) where rounding in the exact response closes the bracket."""
    fa, fb = fun(a), fun(b)
    if fb == 0.0:
        return b
    if not (fa > 0.0 > fb):
        return guess
    return brentq(fun, a, b, xtol=_XTOL * a, rtol=4.0 * np.finfo(float).eps, maxiter=200)


def candidate_loop_metrics(terms, gains, N: float, w_min: float, w_max: float, *, tail=None,
                           n_max: int | None = None) -> tito_design.LoopMetrics | None:
    """Loop metrics of one controller, its crossings and peaks exact (see the module docstring).

    Parameters
    ----------
    terms : sequence of LoopTerm
        The loop element ``q = sum(terms)``.
    gains : (Kp, Ki, Kd)
        Finite parallel gains.
    N : float
        Derivative filter ratio.
    w_min, w_max : float
        Grid ends, as for :func:`~heurtune.objectives.tito.design.loop_metrics_batch`.
    tail : callable, optional
        ``tail(w)`` -> bound of ``|L|`` beyond each frequency (for loops that do not roll off).
    n_max : int
        See :func:`candidate_grid`.

    Returns
    -------
    LoopMetrics or None
        Arrays of shape ``(1,)``; None when the grid would need more than ``n_max`` points.
    """
    kp, ki, kd = (float(v) for v in gains)
    grid = candidate_grid(terms, (kp, ki, kd), N, w_min, w_max, n_max=n_max)
    if grid is None:
        return None
    w, q, c = grid
    loop = _ScalarLoop(terms, kp, ki, kd, N)
    L = q * c
    m = tito_design.loop_metrics_batch(q, w, c[None, :], Ki=[ki], tail=_step_bounds(terms, kd, w, c, tail)[None, :])
    out = {f.name: np.array(getattr(m, f.name), copy=True) for f in dataclasses.fields(m)}
    with np.errstate(all="ignore"):
        if np.isfinite(m.w_pc[0]):
            phase = tito_design.unwrapped_phase(L[None, :])[0]
            k = int(np.argmax(phase <= -math.pi)) - 1
            Lk, pk = L[k], phase[k]

            def pc(x):
                return pk + cmath.phase(loop(x) / Lk) + math.pi

            x = _root(pc, w[k], w[k + 1], m.w_pc[0])
            out["w_pc"][0] = x
            out["gain_margin"][0] = 1.0 / abs(loop(x))
        absL = np.abs(L)
        if np.isfinite(m.w_gc[0]):
            k = int(np.argmax((absL[:-1] > 1.0) & ~(absL[1:] > 1.0)))

            def gc(x):
                return math.log(abs(loop(x)))

            x = _root(gc, w[k], w[k + 1], m.w_gc[0])
            out["w_gc"][0] = x
            out["phase_margin_deg"][0] = math.degrees(math.remainder(cmath.phase(loop(x)) + math.pi,
                                                                     2.0 * math.pi))
        absF = np.abs(1.0 + L)
        absT = absL / absF
        if 0.0 < m.w_b[0] < w[-1]:
            c0 = tito_design.BANDWIDTH_LEVEL
            k = int(np.argmax((absT[:-1] >= c0) & ~(absT[1:] >= c0)))

            def bw(x):
                lx = loop(x)
                return math.log(abs(lx / (1.0 + lx)) / c0)

            out["w_b"][0] = _root(bw, w[k], w[k + 1], m.w_b[0])
        if np.isfinite(m.Mt[0]):
            out["Mt"][0] = _peak(loop.complementary, w, absT)
        if np.isfinite(m.Ms[0]):
            out["Ms"][0] = _peak(loop.sensitivity, w, 1.0 / absF)
    return tito_design.LoopMetrics(**out)


class _ScalarLoop:
    """``L(j w)`` at one frequency in Python complex arithmetic (the root finders call it a few
    dozen times per crossing; numpy's per-call overhead would dominate)."""

    def __init__(self, terms, kp: float, ki: float, kd: float, N: float):
        self.terms = []
        for t in terms:
            gain = t.sign * math.prod(e.K for e in t.num) / math.prod(e.K for e in t.den)
            zeros = [T for e in t.num for T in e.leads] + [T for e in t.den for T in e.lags]
            poles = [T for e in t.num for T in e.lags] + [T for e in t.den for T in e.leads]
            self.terms.append((gain, zeros, poles, t.delay))
        self.gains = (kp, ki, kd, float(tito_design.pid_filter_time(kp, ki, kd, N)))

    def __call__(self, w: float) -> complex:
        s = 1j * float(w)
        q = 0j
        for gain, zeros, poles, delay in self.terms:
            v = complex(gain)
            for T in zeros:
                v *= 1.0 + s * T
            for T in poles:
                v /= 1.0 + s * T
            q += v * cmath.exp(-s * delay)
        kp, ki, kd, tf = self.gains
        return q * (kp + ki / s + kd * s) / (1.0 + s * tf)

    def complementary(self, w: float) -> float:
        """``|T| = |L / (1 + L)|``."""
        lw = self(w)
        return abs(lw / (1.0 + lw))

    def sensitivity(self, w: float) -> float:
        """``|S| = 1 / |1 + L|``."""
        return 1.0 / abs(1.0 + self(w))


def _step_bounds(terms, kd: float, w: np.ndarray, c: np.ndarray, tail) -> np.ndarray:
    """Per sample a bound of ``|L|`` over the step to the next sample (beyond ``w[-1]`` for the
    last one): the envelope ``sum_j |t_j| |C|`` at the larger end, times ``exp(M du / 2)`` with
    ``M`` the largest log-magnitude rate of a term plus the controller's (one per time
    constant); ``tail(w)`` (a bound beyond each sample) where it is smaller."""
    u, env_probe, _ = _term_probe(tuple(terms), float(w[0]), float(w[-1]))
    # the envelope interpolated in log from the probe (a smooth magnitude, 200 points per
    # decade: relative error below 1e-4, covered by the 1 % added)
    env = 1.01 * np.exp(np.interp(np.log(w), u, np.log(env_probe))) * np.abs(c)
    rate = max(len(t.time_constants) for t in terms) + _controller_rate(kd)
    du = np.diff(np.log(w))
    out = np.full(w.size, np.inf)
    out[:-1] = np.maximum(env[:-1], env[1:]) * np.exp(0.5 * rate * du)
    if tail is not None:
        out = np.minimum(out, tail(w))
    return np.nan_to_num(out, nan=np.inf)


def _peak(fun, w: np.ndarray, values: np.ndarray) -> float:
    """Maximum of ``fun``: bounded Brent between the neighbours of every local maximum of the samples
    within 2 % of the largest (a ripple puts crests of nearly equal height side by side, and the
    largest sample need not lie beside the highest crest; a crest's top is within about
    ``STEP^2 / 2`` of its samples); at most the 4 highest are refined."""
    v = np.nan_to_num(values, nan=-np.inf)
    best = float(v.max())
    inner = np.flatnonzero((v[1:-1] >= v[:-2]) & (v[1:-1] >= v[2:]) & (v[1:-1] >= 0.98 * best)) + 1
    for k in inner[np.argsort(v[inner])[::-1][:4]]:
        res = minimize_scalar(lambda x: -fun(x), bounds=(w[k - 1], w[k + 1]), method="bounded",
                              options={"xatol": _XTOL * w[k]})
        if np.isfinite(res.fun):
            best = max(best, -float(res.fun))
    return best
