"""An independent continuous-time reference of the TITO closed loop: its delay differential
equations solved by the method of steps with scipy's ``solve_ivp``, the dense output of earlier
segments serving as the history of the delayed signals.

The loop (deviations from the operating point, at rest for t < 0)::

    e_k = r_k - y_k - n_k,   v_k = c_k(e_k),   u_i = sum_k D_ik(v_k(t - Ld_ik)) + d_in_i + n_in_i,
    y_i = sum_j g_ij(u_j(t - Lg_ij)) + d_out_i

with the measurement noise ``n`` and the input noise ``n_in`` given as samples held over a
period (zero without them)
with every rational part (plant element, decoupler ratio, controller) a continuous state space
of its own (``scipy.signal.tf2ss`` of its polynomials) and every dead time exact. The plant
elements must be strictly proper, so ``v(s)`` needs the states at ``s`` only and ``u(s)`` the
states at ``s`` and ``s - Ld``: no signal is looked up recursively. Segments end at every
breakpoint (set-point and disturbance steps, and those delayed once by each dead time) and are
at most the smallest positive dead time long, so every delayed value lies in a finished segment.

Shares nothing with ``heurtune.objectives.tito.sim`` but the plant's parameters.
"""

from __future__ import annotations

import bisect
import math

import numpy as np
import scipy.signal
from scipy.integrate import solve_ivp

from heurtune.objectives.tito.design import pid_filter_time


def _poly(K, constants):
    """Coefficients (highest power first) of ``K prod(1 + s T)``."""
    p = np.array([float(K)])
    for t in constants:
        p = np.polymul(p, [float(t), 1.0])
    return p


def _ss(num, den):
    A, B, C, D = scipy.signal.tf2ss(num, den)
    return (np.atleast_2d(A).astype(float), np.atleast_2d(B).astype(float).reshape(-1),
            np.atleast_2d(C).astype(float).reshape(-1), float(np.atleast_2d(D)[0, 0]))


def _element(e):
    """``(A, B, C, D, L)`` of a TFElement."""
    return (*_ss(_poly(e.K, e.leads), _poly(1.0, e.lags)), float(e.L))


def _ratio(num, den, extra):
    """``-num/den e^{-extra s}`` of two TFElements (a decoupler entry)."""
    n = np.polymul(_poly(-num.K, num.leads), _poly(1.0, den.lags))
    d = np.polymul(_poly(den.K, den.leads), _poly(1.0, num.lags))
    return (*_ss(n, d), float(num.L - den.L + extra))


def _unit(extra):
    return (np.zeros((0, 0)), np.zeros(0), np.zeros(0), 1.0, float(extra))


def _controller(kp, ki, kd, N):
    tf = float(pid_filter_time(kp, ki, kd, N))
    if kd != 0.0 and tf == 0.0:
        raise ValueError("an unfiltered derivative has no state space")
    if tf == 0.0:
        return (*_ss([kp, ki], [1.0, 0.0]), 0.0)
    return (*_ss([kd, kp, ki], [tf, 1.0, 0.0]), 0.0)


class DDELoop:
    """The reference loop of a plant, decoupler (case 1 or 2, or None) and PI/PID gains.

    Parameters
    ----------
    plant : TITOPlant
    decoupler : Decoupler or None
    gains : ((Kp, Ki, Kd), (Kp, Ki, Kd))
    N : float
        Derivative filter ratio (``Tf = Td / N``, as the tuning problems).
    scenario : TITOScenario
        Set-points, disturbances and horizon (its ``dt`` and noise are not used).
    noise, input_noise : array_like, shape (m, 2), optional
        Measurement and input noise: sample ``k`` held over ``[k hold, (k + 1) hold)``.
    hold : float, optional
        Their hold period (needed with either).
    """

    def __init__(self, plant, decoupler, gains, N, scenario, noise=None, input_noise=None, hold=None):
        g = {(i, j): _element(plant.element(i + 1, j + 1)) for i in range(2) for j in range(2)}
        for (i, j), blk in g.items():
            if abs(blk[3]) > 0 or blk[4] <= 0:
                raise ValueError(f"plant element g{i + 1}{j + 1} must be strictly proper with a dead time")
        if decoupler is None:
            d = {(0, 0): _unit(0.0), (1, 1): _unit(0.0), (0, 1): None, (1, 0): None}
        else:
            p, (c1, c2) = plant, decoupler.column_delays
            if decoupler.case == 1:
                d = {(0, 0): _unit(c1), (1, 0): _ratio(p.g21, p.g22, c1), (0, 1): _ratio(p.g12, p.g11, c2),
                     (1, 1): _unit(c2)}
            else:
                d = {(0, 0): _ratio(p.g22, p.g21, c1), (1, 0): _unit(c1), (0, 1): _unit(c2),
                     (1, 1): _ratio(p.g11, p.g12, c2)}
        c = {k: _controller(*gains[k], N) for k in range(2)}
        self.blocks = {("c", k): c[k] for k in range(2)}
        self.blocks.update({("d",) + key: blk for key, blk in d.items() if blk is not None})
        self.blocks.update({("g",) + key: blk for key, blk in g.items()})
        self.slices, n = {}, 0
        for key, blk in self.blocks.items():
            self.slices[key] = slice(n, n + blk[0].shape[0])
            n += blk[0].shape[0]
        self.n = n
        self.sc = scenario
        self.hold = hold
        self.noise = None if noise is None else np.asarray(noise, float)
        self.input_noise = None if input_noise is None else np.asarray(input_noise, float)
        self.segments = []  # (a, b, dense solution)
        self._starts = []
        delays = sorted({blk[4] for blk in self.blocks.values() if blk[4] > 0})
        self.h = min(delays)
        jumps = [0.0] + [t for steps in scenario.setpoints for t, _ in steps]
        jumps += [scenario.input_disturbance[0], scenario.output_disturbance[0]]
        held = [a for a in (self.noise, self.input_noise) if a is not None]
        if held:
            jumps += [k * float(hold) for k in range(max(len(a) for a in held))]
        paths = sorted(set(delays) | {a + b for a in delays for b in delays})
        marks = {t + L for t in jumps for L in [0.0] + paths}
        self.marks = sorted(t for t in marks if 0.0 <= t < scenario.horizon)

    # -- piecewise-constant inputs ------------------------------------------------------------------
    def _r(self, t):
        out = np.zeros(2)
        for k, steps in enumerate(self.sc.setpoints):
            for ts, val in steps:
                if t >= ts:
                    out[k] = val
        return out

    def _dist(self, which, t):
        ts, mag = getattr(self.sc, which)
        return np.asarray(mag, float) if t >= ts else np.zeros(2)

    def _held(self, samples, t):
        if samples is None or t < 0.0:
            return np.zeros(2)
        return samples[min(int(math.floor(t / self.hold + 1e-9)), len(samples) - 1)]

    # -- signals from states -------------------------------------------------------------------------
    def _state(self, s):
        if s < 0.0:
            return np.zeros(self.n)
        if s >= self._t0:  # the start of the segment being integrated (a delay equal to its length)
            return self._x0
        k = bisect.bisect_right(self._starts, s) - 1
        a, b, sol = self.segments[max(k, 0)]
        return sol(min(max(s, a), b))

    def _part(self, key, x):
        blk = self.blocks[key]
        return float(blk[2] @ x[self.slices[key]]) if blk[0].size else 0.0

    def _y(self, x, t):
        y = self._dist("output_disturbance", t).copy()
        for i in range(2):
            for j in range(2):
                y[i] += self._part(("g", i, j), x)
        return y

    def _v(self, x, t):
        e = self._r(t) - self._y(x, t) - self._held(self.noise, t)
        return np.array([self._part(("c", k), x) + self.blocks[("c", k)][3] * e[k] for k in range(2)]), e

    def _u(self, x, t, v_at):
        u = self._dist("input_disturbance", t) + self._held(self.input_noise, t)
        for i in range(2):
            for k in range(2):
                key = ("d", i, k)
                if key in self.blocks:
                    u[i] += self._part(key, x) + self.blocks[key][3] * v_at(k, t - self.blocks[key][4])
        return u

    def _v_past(self, k, s):
        return 0.0 if s < 0.0 else self._v(self._state(s), s)[0][k]

    def _u_past(self, j, s):
        if s < 0.0:
            return 0.0
        return self._u(self._state(s), s, self._v_past)[j]

    def _rhs(self, t, x, tm):
        dx = np.empty(self.n)
        v, e = self._v(x, tm)
        for key, blk in self.blocks.items():
            A, B = blk[0], blk[1]
            if not A.size:
                continue
            if key[0] == "c":
                w = e[key[1]]
            elif key[0] == "d":
                L = blk[4]
                w = v[key[2]] if L == 0.0 else self._v_past(key[2], t - L)
            else:
                w = self._u_past(key[2], t - blk[4])
            sl = self.slices[key]
            dx[sl] = A @ x[sl] + B * w
        return dx

    def solve(self, rtol=1e-10, atol=1e-12, method="Radau"):
        """Integrate over the horizon; returns self."""
        x = np.zeros(self.n)
        T = float(self.sc.horizon)
        edges = sorted(set(self.marks) | {T})
        t = 0.0
        self._t0, self._x0 = 0.0, x
        for stop in edges[1:] + [T]:
            while t < stop - 1e-12:
                b = min(stop, t + self.h)
                # the piecewise-constant inputs of the segment are those of its midpoint
                tm = 0.5 * (t + b)

                def fun(s, y, tm=tm):
                    return self._rhs(s, y, tm)

                sol = solve_ivp(fun, (t, b), x, method=method, rtol=rtol, atol=atol, dense_output=True)
                if not sol.success:
                    raise RuntimeError(sol.message)
                self.segments.append((t, b, sol.sol))
                self._starts.append(t)
                x = sol.y[:, -1]
                t = b
                self._t0, self._x0 = t, x
        self._t0 = math.inf
        return self

    def outputs(self, times):
        """``y`` at ``times`` (after :meth:`solve`), shape ``(len(times), 2)``; left limits at jumps
        of the output disturbance are not distinguished (the value from the right)."""
        return np.array([self._y(self._state(s), s) for s in times])

    def error_integrals(self, step=0.01):
        """Per loop ``(IAE, ISE, ITAE)`` of ``e = r - y`` over the horizon (after :meth:`solve`):
        the trapezoid rule on a grid of about ``step`` s in each piece between the set-point
        steps and the output disturbance, whose jumps it must not straddle (each piece is
        evaluated just inside its ends). Shape ``(2, 3)``."""
        T = float(self.sc.horizon)
        cuts = {0.0, T, float(self.sc.output_disturbance[0])}
        cuts |= {float(t) for steps in self.sc.setpoints for t, _ in steps}
        cuts = sorted(c for c in cuts if 0.0 <= c <= T)
        out = np.zeros((2, 3))
        for a, b in zip(cuts[:-1], cuts[1:]):
            t = np.linspace(a, b, max(2, int(round((b - a) / step)) + 1))
            inside = t.copy()
            inside[0] += 1e-9 * max(1.0, b)
            inside[-1] -= 1e-9 * max(1.0, b)
            r = np.array([[sum(v for ts, v in steps if ts <= s) for steps in self.sc.setpoints] for s in inside])
            e = r - self.outputs(inside)
            for i in range(2):
                ae = np.abs(e[:, i])
                out[i] += [np.trapezoid(ae, t), np.trapezoid(e[:, i] ** 2, t), np.trapezoid(t * ae, t)]
        return out

    def inputs(self, times):
        """``u`` (decoupler output plus input disturbance) at ``times``."""
        return np.array([self._u(self._state(s), s, self._v_past) for s in times])
