"""The continuous-time TITO closed loop with exact dead times, on a step that divides them.

Every signal path of the loop is linear and time-invariant, so the output of loop ``i`` is a sum
of paths from the errors, each a series of rational parts with one total dead time::

    y_i(t) = sum_{k,j} (g_ik D_kj c_j)(e_j(t - Lg_ik - Ld_kj)) + sum_k g_ik(d_in_k(t - Lg_ik)) + d_out_i

(``c_j`` controller, ``D_kj`` decoupler entry, ``g_ik`` plant element, each with its own state;
the controller's and the decoupler's states are copied into every path that carries them, which
changes nothing in a linear loop). Every plant element is strictly proper with a dead time, so
the error ``e_j = r_j - y_j`` is piecewise smooth, and its breakpoints (set-point and disturbance
steps, and their images through the delays) fall on the step grid when the step ``h`` divides
every dead time and every breakpoint time. Over one step each path's input is then the error of
an earlier step, known in full: the errors are kept as their values at the four Gauss-Lobatto
nodes of every step (a cubic), each path's state is advanced exactly for that cubic input
(matrix exponential of the path with a chain of integrators, Van Loan), and the new step's
errors follow from the outputs at its nodes. The only approximation is the cubic on each step
(a local error of order ``h^4``); fast modes (a derivative filter shorter than ``h``) are
integrated exactly. The decoupler outputs ``u`` and controller outputs ``v`` are recorded the
same way, from paths ``D_kj c_j`` and ``c_j`` driven by the stored errors.

A dead time that is not a multiple of the step (it must not be shorter than the step) puts a
stored step boundary at the same fraction ``theta`` of every step; the path is advanced over the
two sub-steps, each with its own stored cubic as input, so it stays exact (the errors' jumps and
kinks included). The input
disturbance's jump is integrated exactly wherever its delayed image falls. Set-point and
disturbance times must be multiples of the step; no measurement or input noise; linear plants
only. Checked against the method of
steps with ``solve_ivp`` (``tests/tito_dde_reference.py``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.signal

from heurtune.core.errors import ConfigError

from .design import pid_filter_time

__all__ = ["ContinuousTITOLoop"]

# Gauss-Lobatto nodes on [0, 1] (cubic through both ends and two interior points)
NODES = np.array([0.0, 0.5 - 0.5 / math.sqrt(5.0), 0.5 + 0.5 / math.sqrt(5.0), 1.0])
_COMMENSURATE_TOL = 1e-9


def _poly(K, constants):
    p = np.array([float(K)])
    for t in constants:
        p = np.polymul(p, [float(t), 1.0])
    return p


def _ss(num, den):
    """Minimal controllable-form state space of ``num/den`` (``D`` a float)."""
    num = np.trim_zeros(np.atleast_1d(np.asarray(num, float)), "f")
    den = np.trim_zeros(np.atleast_1d(np.asarray(den, float)), "f")
    if den.size == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), float(num[-1] / den[0]) if num.size else 0.0
    A, B, C, D = scipy.signal.tf2ss(num, den)
    return A, B.reshape(-1, 1), C.reshape(1, -1), float(D[0, 0])


def _series(first, second):
    """``second(first(.))`` of two state spaces ``(A, B, C, D)``."""
    A1, B1, C1, D1 = first
    A2, B2, C2, D2 = second
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = A1
    A[n1:, :n1] = B2 @ C1
    A[n1:, n1:] = A2
    B = np.vstack([B1, B2 * D1])
    C = np.hstack([D2 * C1, C2])
    return A, B, C, D1 * D2


def _element(e):
    return _ss(_poly(e.K, e.leads), _poly(1.0, e.lags))


def _ratio(num, den):
    n = np.polymul(_poly(-num.K, num.leads), _poly(1.0, den.lags))
    d = np.polymul(_poly(den.K, den.leads), _poly(1.0, num.lags))
    return _ss(n, d)


def _controller(kp, ki, kd, N):
    tf = float(pid_filter_time(kp, ki, kd, N))
    if kd != 0.0 and tf == 0.0:
        raise ConfigError(f"controller: a derivative gain Kd = {kd!r} needs a filter (Tf = 0)")
    if tf == 0.0:
        return _ss([kp, ki], [1.0, 0.0])
    return _ss([kd, kp, ki], [tf, 1.0, 0.0])


def _lagrange_matrix(points) -> np.ndarray:
    """``P`` with ``P @ values`` the cubic through ``values`` at the nodes, evaluated at ``points``."""
    P = np.empty((len(points), NODES.size))
    for r, tau in enumerate(points):
        for c in range(NODES.size):
            others = [b for i, b in enumerate(NODES) if i != c]
            P[r, c] = np.prod([(tau - b) / (NODES[c] - b) for b in others])
    return P


class _Path:
    """A state space advanced exactly over a step for an input given at the nodes."""

    def __init__(self, system, h: float, shift=0):
        A, B, C, D = system
        self.C, self.D = C.reshape(-1), float(D)
        self._A, self._B, self._h = A, B[:, 0], h
        self.n = A.shape[0]
        self.E, self.H = self._transitions(h, NODES)
        self.split = None
        if not isinstance(shift, int):
            # the delayed window crosses a stored step boundary at theta of every step: two
            # sub-steps, each with one stored cubic as its input (exact, jumps included)
            theta = shift - math.floor(shift)  # where, in every step, the window crosses a stored boundary
            first = [tau / theta for tau in NODES if tau < theta] + [1.0]
            second = [(tau - theta) / (1.0 - theta) for tau in NODES if tau >= theta]
            self.split = dict(
                theta=theta, lag=int(math.ceil(shift)), n_first=len(first) - 1,
                A=self._transitions(theta * h, first), B=self._transitions((1.0 - theta) * h, second),
                # the stored cubic of each sub-step, at that sub-step's nodes
                PA=_lagrange_matrix((1.0 - theta) + theta * NODES), PB=_lagrange_matrix((1.0 - theta) * NODES),
            )

    def _transitions(self, length: float, offsets):
        """``E[i]``, ``H[i]``: the state at ``offsets[i]`` (fractions of a sub-step of ``length``
        seconds) is ``E[i] x + H[i] w`` for a cubic input with values ``w`` at its nodes."""
        n, q = self.n, NODES.size
        # chain of integrators: a0' = a1, ..., input w(tau) = a0(tau) = sum_k alpha_k tau^k / k!
        M = np.zeros((n + q, n + q))
        M[:n, :n] = self._A * length
        M[:n, n] = self._B * length
        for k in range(q - 1):
            M[n + k, n + k + 1] = 1.0
        V = np.array([[tau ** k / math.factorial(k) for k in range(q)] for tau in NODES])
        Vinv = np.linalg.inv(V)
        E = np.empty((len(offsets), n, n))
        H = np.empty((len(offsets), n, q))
        for i, tau in enumerate(offsets):
            F = scipy.linalg.expm(M * tau)
            E[i] = F[:n, :n]
            H[i] = F[:n, n:] @ Vinv
        return E, H

    def step_delayed(self, x: np.ndarray, hist: np.ndarray, k: int, j: int) -> np.ndarray:
        """States at the nodes over step ``k`` for the stored signal ``j`` delayed by a fraction
        of steps: the two sub-steps of :attr:`split`."""
        sp = self.split
        m2 = k - sp["lag"] + 1
        zero = np.zeros(NODES.size)
        wa = sp["PA"] @ hist[m2 - 1, j] if m2 - 1 >= 0 else zero
        wb = sp["PB"] @ hist[m2, j] if m2 >= 0 else zero
        Ea, Ha = sp["A"]
        Eb, Hb = sp["B"]
        xa = np.einsum("inm,m->in", Ea, x) + np.einsum("inq,q->in", Ha, wa)
        xb = np.einsum("inm,m->in", Eb, xa[-1]) + np.einsum("inq,q->in", Hb, wb)
        return np.vstack([xa[:sp["n_first"]], xb])

    def constant(self, x: np.ndarray, tau: float, value: float) -> np.ndarray:
        """State after ``tau`` steps from ``x`` under a constant input (an exponential of its own:
        for the one step of a delayed disturbance whose jump falls inside it)."""
        n = self.n
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = self._A * self._h
        M[:n, n] = self._B * self._h
        F = scipy.linalg.expm(M * tau)
        return F[:n, :n] @ x + F[:n, n] * value

    def step(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """States at the nodes, shape ``(q, n)``, for the state ``x`` at the step's start and the
        input's node values ``w``."""
        return np.einsum("inm,m->in", self.E, x) + np.einsum("inq,q->in", self.H, w)

    def outputs(self, X: np.ndarray, w: np.ndarray) -> np.ndarray:
        return X @ self.C + self.D * w


# barycentric weights of the cubic through the nodes
_BARY = np.array([1.0 / np.prod([a - b for b in NODES if b != a]) for a in NODES])


def _cubic_at(values: np.ndarray, tau: float) -> float:
    """The cubic through ``values`` at the nodes, evaluated at ``tau`` in [0, 1]."""
    d = tau - NODES
    hit = np.flatnonzero(d == 0.0)
    if hit.size:
        return float(values[hit[0]])
    w = _BARY / d
    return float(w @ values / w.sum())


def _shift(value: float, h: float, what: str):
    """A dead time in steps: an int where it is a multiple of ``h``, else a float (>= 1)."""
    k = round(value / h)
    if abs(k * h - value) <= _COMMENSURATE_TOL * max(1.0, abs(value)):
        return int(k)
    if value < h:
        raise ConfigError(f"continuous loop: {what} = {value!r} s is shorter than the step {h!r} s")
    return value / h


def _delayed(hist: np.ndarray, k: int, j: int, shift) -> np.ndarray:
    """Node values over step ``k`` of the stored signal ``j`` delayed by ``shift`` steps (zero
    before t = 0): a stored step where the shift is whole, else the stored cubics at the shifted
    nodes (``shift >= 1``, so they lie in finished steps)."""
    if isinstance(shift, int):
        return hist[k - shift, j] if k - shift >= 0 else np.zeros(NODES.size)
    out = np.zeros(NODES.size)
    for i, si in enumerate(k + NODES - shift):
        if si >= 0.0:
            m = int(math.floor(si))
            out[i] = _cubic_at(hist[m, j], si - m)
    return out


def _multiple(value: float, h: float, what: str) -> int:
    k = round(value / h)
    if abs(k * h - value) > _COMMENSURATE_TOL * max(1.0, abs(value)):
        raise ConfigError(f"continuous loop: {what} = {value!r} s is not a multiple of the step {h!r} s")
    return int(k)


class ContinuousTITOLoop:
    """The continuous closed loop of a plant, a decoupler and decentralised PI/PID controllers.

    Parameters
    ----------
    plant : TITOPlant
        Every element strictly proper, with a dead time > 0.
    decoupler : Decoupler or None
    gains : ((Kp, Ki, Kd), (Kp, Ki, Kd))
        Parallel gains of the two controllers (``C = (Kp + Ki/s + Kd s) / (1 + Tf s)``).
    N : float
        Derivative filter ratio, ``Tf = Td / N``.
    scenario : TITOScenario
        Set-points, disturbances and horizon; its ``dt`` is the step ``h`` and the output
        sample time. Noise is not supported.
    """

    def __init__(self, plant, decoupler, gains, N, scenario):
        h = float(scenario.dt)
        if max(scenario.noise_power) > 0 or scenario.has_input_noise:
            raise ConfigError("continuous loop: noise is not supported yet; set noise_power = 0")
        self.h, self.sc = h, scenario
        c = [_controller(*map(float, gains[k]), N) for k in range(2)]
        if decoupler is None:
            D = {(0, 0): (_ss([1.0], [1.0]), 0.0), (1, 1): (_ss([1.0], [1.0]), 0.0)}
        else:
            p, (c1, c2) = plant, decoupler.column_delays
            if decoupler.case == 1:
                D = {(0, 0): (_ss([1.0], [1.0]), c1), (1, 1): (_ss([1.0], [1.0]), c2),
                     (1, 0): (_ratio(p.g21, p.g22), p.g21.L - p.g22.L + c1),
                     (0, 1): (_ratio(p.g12, p.g11), p.g12.L - p.g11.L + c2)}
            else:
                D = {(1, 0): (_ss([1.0], [1.0]), c1), (0, 1): (_ss([1.0], [1.0]), c2),
                     (0, 0): (_ratio(p.g22, p.g21), p.g22.L - p.g21.L + c1),
                     (1, 1): (_ratio(p.g11, p.g12), p.g11.L - p.g12.L + c2)}
        G = {}
        for i in range(2):
            for k in range(2):
                e = plant.element(i + 1, k + 1)
                sys_g = _element(e)
                if sys_g[3] != 0.0 or e.L <= 0.0:
                    raise ConfigError(f"continuous loop: plant element g{i + 1}{k + 1} must be strictly proper "
                                      "with a dead time > 0")
                G[(i, k)] = (sys_g, _shift(e.L, h, f"the dead time of g{i + 1}{k + 1}"))
        # paths from e_j to y_i, from d_in_k to y_i, from e_j to u_k and to v_j
        self.y_paths, self.d_paths, self.u_paths, self.v_paths = [], [], [], []
        for (k, j), (sys_d, Ld) in D.items():
            nd = _shift(Ld, h, "a decoupler dead time") if Ld > 0 else 0
            dc = _series(c[j], sys_d)
            self.u_paths.append((k, j, nd, _Path(dc, h, nd)))
            for i in range(2):
                sys_g, ng = G[(i, k)]
                total = ng + nd
                if not isinstance(total, int):
                    total = _shift((ng + nd) * h, h, "a path's dead time")
                self.y_paths.append((i, j, total, _Path(_series(dc, sys_g), h, total)))
        for (i, k), (sys_g, ng) in G.items():
            self.d_paths.append((i, k, ng, _Path(sys_g, h)))
        for j in range(2):
            self.v_paths.append((j, _Path(c[j], h)))
        self.n = _multiple(scenario.horizon, h, "the horizon")
        for steps in scenario.setpoints:
            for t, _ in steps:
                _multiple(t, h, "a set-point step time")
        _multiple(scenario.input_disturbance[0], h, "the input disturbance time")
        _multiple(scenario.output_disturbance[0], h, "the output disturbance time")

    def _piecewise(self, t_mid: float):
        """Set-points and disturbances on the step whose midpoint is ``t_mid`` (constant there)."""
        r = np.zeros(2)
        for k, steps in enumerate(self.sc.setpoints):
            for ts, val in steps:
                if t_mid >= ts:
                    r[k] = val
        t_in, d_in = self.sc.input_disturbance
        t_out, d_out = self.sc.output_disturbance
        return r, lambda s: np.asarray(d_in, float) if s >= t_in else np.zeros(2), \
            (np.asarray(d_out, float) if t_mid >= t_out else np.zeros(2))

    @staticmethod
    def _advance(path, x, hist, k, j, shift):
        if path.split is None:
            return path.step(x, _delayed(hist, k, j, shift))
        return path.step_delayed(x, hist, k, j)

    def _disturbance_step(self, path, x, k, kk, shift, d_in_at):
        """Node states over step ``k`` of a plant element driven by the input disturbance
        delayed by ``shift`` steps; exact also where the delayed jump falls inside the step."""
        h = self.h
        jump = self.sc.input_disturbance[0] / h + shift  # where the delayed jump falls, in steps
        if k < jump < k + 1:
            before = d_in_at((k + 0.5 * (jump - k) - shift) * h)[kk]
            after = d_in_at((jump + 0.5 * (k + 1 - jump) - shift) * h)[kk]
            theta = jump - k
            x_theta = path.constant(x, theta, before)
            return np.array([path.constant(x, tau, before) if tau < theta else
                             path.constant(x_theta, tau - theta, after) for tau in NODES])
        return path.step(x, np.full(NODES.size, d_in_at((k + 0.5 - shift) * h)[kk]))

    def run(self):
        """Simulate the scenario.

        Returns
        -------
        t : numpy.ndarray, shape (n + 1,)
            The step boundaries ``0, h, ..., horizon``.
        y, u, v : numpy.ndarray, shape (n + 1, 2)
            Outputs (with the output disturbance), decoupler outputs (before the input
            disturbance) and controller outputs at ``t`` (from the right at a step).
        """
        h, n, q = self.h, self.n, NODES.size
        e_hist = np.zeros((n + 1, 2, q))  # error node values of step k (k = n: unused)
        states = {id(p): np.zeros(p.n) for *_, p in self.y_paths + self.d_paths + self.u_paths}
        states.update({id(p): np.zeros(p.n) for _, p in self.v_paths})
        y_out = np.zeros((n + 1, 2))
        u_out = np.zeros((n + 1, 2))
        v_out = np.zeros((n + 1, 2))
        for k in range(n):
            t0 = k * h
            r, d_in_at, d_out = self._piecewise(t0 + 0.5 * h)
            y = np.tile(d_out[:, None], (1, q))
            for i, j, nd, path in self.y_paths:
                X = self._advance(path, states[id(path)], e_hist, k, j, nd)
                y[i] += X @ path.C  # strictly proper paths
                states[id(path)] = X[-1]
            for i, kk, nd, path in self.d_paths:
                X = self._disturbance_step(path, states[id(path)], k, kk, nd, d_in_at)
                y[i] += X @ path.C
                states[id(path)] = X[-1]
            e_hist[k] = r[:, None] - y
            u = np.zeros((2, q))
            for kk, j, nd, path in self.u_paths:
                X = self._advance(path, states[id(path)], e_hist, k, j, nd)
                u[kk] += path.outputs(X, _delayed(e_hist, k, j, nd))
                states[id(path)] = X[-1]
            v = np.zeros((2, q))
            for j, path in self.v_paths:
                X = path.step(states[id(path)], e_hist[k, j])
                v[j] = path.outputs(X, e_hist[k, j])
                states[id(path)] = X[-1]
            y_out[k], u_out[k], v_out[k] = y[:, 0], u[:, 0], v[:, 0]
            if k == n - 1:
                y_out[n], u_out[n], v_out[n] = y[:, -1], u[:, -1], v[:, -1]
        return np.arange(n + 1) * h, y_out, u_out, v_out
