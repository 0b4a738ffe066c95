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
two sub-steps, each with its own stored cubic as input, so a jump of the delayed signal (the
input disturbance, a set-point step) is integrated exactly. The breakpoints it creates in the
errors then fall inside steps, where the cubics smooth their kinks: second order in ``h``. With a
derivative in the controllers the order is about 2 as well (the derivative acts on the cubics'
slope jumps at the step boundaries). Set-point and disturbance times must be multiples of the
step; linear plants only.

Noise is a zero-order-held signal on the step: the sampled loop's draws (the same generators,
variance ``P / dt`` per sample), sample ``k`` held over ``[k h, (k + 1) h)``. The measurement
noise enters the errors (``e = r - y - n``) and the input noise the plant inputs beside the
input disturbance; both are constant within a step and jump at its boundaries, where the stored
cubics already break, so the loop stays exact for them. The outputs ``y`` are the plant's, the
measurement ``ym = y + n``. Checked against the method of steps with ``solve_ivp``
(``tests/tito_dde_reference.py``, ``tests/objectives/tito/test_continuous_tito.py``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.signal

from heurtune.core.errors import ConfigError

from . import continuous_kernels as kern
from .design import parallel_controller
from .model import ParallelPID, PIController
from .sim import _poly, controller_tf, input_noise, measurement_noise, vary_plant

__all__ = ["ContinuousTITOLoop", "ContinuousTITOSimulator"]

# Gauss-Lobatto nodes on [0, 1] (cubic through both ends and two interior points)
NODES = np.array([0.0, 0.5 - 0.5 / math.sqrt(5.0), 0.5 + 0.5 / math.sqrt(5.0), 1.0])
_COMMENSURATE_TOL = 1e-9
SIGNAL_LIMIT = 1.0e12


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


def _lagrange_matrix(points) -> np.ndarray:
    """``P`` with ``P @ values`` the cubic through ``values`` at the nodes, evaluated at ``points``."""
    P = np.empty((len(points), NODES.size))
    for r, tau in enumerate(points):
        for c in range(NODES.size):
            others = [b for i, b in enumerate(NODES) if i != c]
            P[r, c] = np.prod([(tau - b) / (NODES[c] - b) for b in others])
    return P


def _pi_gains(controllers):
    """``((Kp1, Ki1), (Kp2, Ki2))`` where both controllers are PIs (a ParallelPID without
    derivative and filter, or a PIController), else None."""
    out = []
    for c in controllers:
        if isinstance(c, ParallelPID) and c.Kd == 0.0 and c.Tf == 0.0:
            out.append((float(c.Kp), float(c.Ki)))
        elif isinstance(c, PIController):
            out.append((float(c.Kc), float(c.Kc) / float(c.Ti)))
        else:
            return None
    if not all(math.isfinite(v) for pair in out for v in pair):
        return None
    return tuple(out)


def _shift(value: float, h: float, what: str):
    """A dead time in steps: an int where it is a multiple of ``h``, else a float (>= 1)."""
    k = round(value / h)
    if abs(k * h - value) <= _COMMENSURATE_TOL * max(1.0, abs(value)):
        return int(k)
    if value < h:
        raise ConfigError(f"continuous loop: {what} = {value!r} s is shorter than the step {h!r} s")
    return value / h


def _multiple(value: float, h: float, what: str) -> int:
    k = round(value / h)
    if abs(k * h - value) > _COMMENSURATE_TOL * max(1.0, abs(value)):
        raise ConfigError(f"continuous loop: {what} = {value!r} s is not a multiple of the step {h!r} s")
    return int(k)


class _Path:
    """The precomputed matrices of one path: a state space driven by a stored signal delayed by
    ``shift`` steps (an int: the stored step itself; a float: two sub-steps)."""

    def __init__(self, system, h: float, shift, target: int, out: int, src: int):
        A, B, C, D = system
        self.C, self.D = C.reshape(-1), float(D)
        self._A, self._B = A, B[:, 0]
        self.n = A.shape[0]
        self.target, self.out, self.src = target, out, src
        self.split = not isinstance(shift, int)
        if not self.split:
            self.shift, self.lag, self.nfirst = int(shift), 0, 0
            self.E, self.H = self._transitions(h, NODES)
            return
        # the delayed window crosses a stored step boundary at the same fraction theta of every
        # step: two sub-steps, each with one stored cubic as its input (exact, jumps included)
        theta = shift - math.floor(shift)
        first = [tau / theta for tau in NODES if tau < theta] + [1.0]
        second = [(tau - theta) / (1.0 - theta) for tau in NODES if tau >= theta]
        self.shift, self.lag, self.nfirst = 0, int(math.ceil(shift)), len(first) - 1
        self.EA, self.HA = self._transitions(theta * h, first)
        self.EB, self.HB = self._transitions((1.0 - theta) * h, second)
        # each sub-step's stored cubic at that sub-step's nodes, and the input at the step's nodes
        self.PA = _lagrange_matrix((1.0 - theta) + theta * NODES)
        self.PB = _lagrange_matrix((1.0 - theta) * NODES)
        before = NODES < theta
        self.QA = np.where(before[:, None], _lagrange_matrix(np.clip((1.0 - theta) + NODES, 0.0, 1.0)), 0.0)
        self.QB = np.where(before[:, None], 0.0, _lagrange_matrix(np.clip(NODES - theta, 0.0, 1.0)))

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


def _stack(paths):
    """The paths' matrices as the zero-padded arrays of :func:`continuous_kernels.run_loop`."""
    P, q = len(paths), NODES.size
    nm = max(1, max(p.n for p in paths))

    def ints(name):
        return np.array([getattr(p, name) for p in paths], np.int64)

    arrays = dict(
        target=ints("target"), out=ints("out"), src=ints("src"), split=ints("split"), shift=ints("shift"),
        lag=ints("lag"), nfirst=ints("nfirst"), nst=ints("n"),
        E=np.zeros((P, q, nm, nm)), H=np.zeros((P, q, nm, q)), EA=np.zeros((P, q + 1, nm, nm)),
        HA=np.zeros((P, q + 1, nm, q)), EB=np.zeros((P, q, nm, nm)), HB=np.zeros((P, q, nm, q)),
        PA=np.zeros((P, q, q)), PB=np.zeros((P, q, q)), QA=np.zeros((P, q, q)), QB=np.zeros((P, q, q)),
        C=np.zeros((P, nm)), D=np.array([p.D for p in paths]),
    )
    for k, p in enumerate(paths):
        n = p.n
        arrays["C"][k, :n] = p.C
        if p.split:
            arrays["EA"][k, :p.EA.shape[0], :n, :n] = p.EA
            arrays["HA"][k, :p.HA.shape[0], :n] = p.HA
            arrays["EB"][k, :p.EB.shape[0], :n, :n] = p.EB
            arrays["HB"][k, :p.HB.shape[0], :n] = p.HB
            for key in ("PA", "PB", "QA", "QB"):
                arrays[key][k] = getattr(p, key)
        else:
            arrays["E"][k, :, :n, :n] = p.E
            arrays["H"][k, :, :n] = p.H
    return arrays, nm


class ContinuousTITOLoop:
    """The continuous closed loop of a plant, a decoupler and decentralised PI/PID controllers.

    Parameters
    ----------
    plant : TITOPlant
        Every element strictly proper, with a dead time > 0 (``scenario.variation`` is not
        applied here; :class:`ContinuousTITOSimulator` does).
    decoupler : Decoupler or None
    controllers : pair
        ``PIController``, ``PIDController`` or ``ParallelPID`` (a derivative needs its filter).
    scenario : TITOScenario
        Set-points, disturbances, noise and horizon; its ``dt`` is the step ``h``, the output
        sample time and the noise's hold period.
    """

    @classmethod
    def from_gains(cls, plant, decoupler, gains, N, scenario):
        """The loop of two parallel PID gain triples ``(Kp, Ki, Kd)`` with ``Tf = Td / N`` (the
        tuning problems' controllers)."""
        return cls(plant, decoupler, tuple(parallel_controller(*map(float, g), N) for g in gains), scenario)

    def __init__(self, plant, decoupler, controllers, scenario):
        h = float(scenario.dt)
        self.h, self.sc = h, scenario
        unit = _ss([1.0], [1.0])
        self.pi = _pi_gains(controllers) is not None
        if self.pi:
            # a PI is Kp + Ki/s: every path is linear in the gains, so the loop is built from the
            # bases 1 and 1/s once, and a new PI only rescales the paths' outputs (run(controllers))
            integrator = _ss([1.0], [1.0, 0.0])
            bases = [[(unit, 2 * j), (integrator, 2 * j + 1)] for j in range(2)]
        else:
            bases = [[(_ss(*controller_tf(controllers[j], j + 1)), -1)] for j in range(2)]
        if decoupler is None:
            D = {(0, 0): (unit, 0.0), (1, 1): (unit, 0.0)}
        else:
            p, (c1, c2) = plant, decoupler.column_delays
            if decoupler.case == 1:
                D = {(0, 0): (unit, c1), (1, 1): (unit, c2),
                     (1, 0): (_ratio(p.g21, p.g22), p.g21.L - p.g22.L + c1),
                     (0, 1): (_ratio(p.g12, p.g11), p.g12.L - p.g11.L + c2)}
            else:
                D = {(1, 0): (unit, c1), (0, 1): (unit, c2),
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
                G[(i, k)] = (sys_g, _shift(e.L, h, f"the dead time of g{i + 1}{k + 1}"), e.L)
        # paths: e_j -> y_i through c_j, D_kj, g_ik; d_in_k -> y_i through g_ik; e_j -> u_k; e_j -> v_j
        paths, weights = [], []  # weights: which gain scales a path's output (-1: none)
        for (k, j), (sys_d, Ld) in D.items():
            for basis, weight in bases[j]:
                dc = _series(basis, sys_d)
                paths.append(_Path(dc, h, _shift(Ld, h, "a decoupler dead time") if Ld > 0 else 0,
                                   kern.TARGET_U, k, j))
                weights.append(weight)
                for i in range(2):
                    sys_g, _, Lg = G[(i, k)]
                    paths.append(_Path(_series(dc, sys_g), h, _shift(Lg + Ld, h, "a path's dead time"),
                                       kern.TARGET_Y, i, j))
                    weights.append(weight)
        for (i, k), (sys_g, ng, _) in G.items():
            paths.append(_Path(sys_g, h, ng, kern.TARGET_Y, i, 2 + k))
            weights.append(-1)
        for j in range(2):
            for basis, weight in bases[j]:
                paths.append(_Path(basis, h, 0, kern.TARGET_V, j, j))
                weights.append(weight)
        self.paths = paths
        self._weights = np.array(weights, dtype=np.int64)
        self._arrays, self._nmax = _stack(paths)
        self._gains = None if not self.pi else np.array([g for pair in _pi_gains(controllers) for g in pair])
        self.n = _multiple(scenario.horizon, h, "the horizon")
        for steps in scenario.setpoints:
            for t, _ in steps:
                _multiple(t, h, "a set-point step time")
        _multiple(scenario.input_disturbance[0], h, "the input disturbance time")
        _multiple(scenario.output_disturbance[0], h, "the output disturbance time")

    def _signals(self):
        """Set-points less the measurement noise and output disturbances per step, and the
        history holding the input disturbances and input noise at their nodes."""
        n, h, sc = self.n, self.h, self.sc
        mid = (np.arange(n) + 0.5) * h
        r = np.zeros((n, 2))
        for k, steps in enumerate(sc.setpoints):
            for ts, val in steps:
                r[mid >= ts, k] = val
        if max(sc.noise_power) > 0:  # e = r - (y + n): the noise of step k held over it
            r -= measurement_noise(sc)[:n]
        t_out, d_out = sc.output_disturbance
        dout = np.where((mid >= t_out)[:, None], np.asarray(d_out, float)[None, :], 0.0)
        hist = np.zeros((n + 1, 4, NODES.size))
        t_in, d_in = sc.input_disturbance
        hist[:n, 2:, :] = np.where((mid >= t_in)[:, None, None], np.asarray(d_in, float)[None, :, None], 0.0)
        if sc.has_input_noise:
            hist[:n, 2:, :] += input_noise(sc)[:n, :, None]
        return r, dout, hist

    def run(self, controllers=None):
        """Simulate the scenario.

        Parameters
        ----------
        controllers : pair, optional
            Other PI controllers for a loop built from PI controllers (its paths are linear in
            the gains, so nothing is rebuilt); default: the loop's own.

        Returns
        -------
        t : numpy.ndarray, shape (n + 1,)
            The step boundaries ``0, h, ..., horizon``.
        y, u, v : numpy.ndarray, shape (n + 1, 2)
            Outputs (with the output disturbance, without the measurement noise), decoupler
            outputs (before the input disturbance and noise) and controller outputs at ``t``
            (from the right at a step).
        """
        n = self.n
        r, dout, hist = self._signals()
        y, u, v = (np.zeros((n + 1, 2)) for _ in range(3))
        x = np.zeros((len(self.paths), self._nmax))
        a = self._arrays
        C, D = a["C"], a["D"]
        if self.pi:
            gains = self._gains
            if controllers is not None:
                pairs = _pi_gains(controllers)
                if pairs is None:
                    raise ConfigError("continuous loop: a loop built for PI controllers runs PI controllers only")
                gains = np.array([g for pair in pairs for g in pair])
            scale = np.where(self._weights >= 0, gains[np.maximum(self._weights, 0)], 1.0)
            C, D = C * scale[:, None], D * scale
        elif controllers is not None:
            raise ConfigError("continuous loop: only a loop built for PI controllers takes others")
        kern.run_loop(n, hist, r, dout, a["target"], a["out"], a["src"], a["split"], a["shift"], a["lag"],
                      a["nfirst"], a["nst"], a["E"], a["H"], a["EA"], a["HA"], a["EB"], a["HB"], a["PA"], a["PB"],
                      a["QA"], a["QB"], C, D, x, y, u, v)
        return np.arange(n + 1) * self.h, y, u, v


class ContinuousTITOSimulator:
    """The continuous loop behind the interface of :class:`~heurtune.objectives.tito.sim.TITOSimulator`
    (what ``[scenario] loop = "continuous"`` selects).

    Parameters
    ----------
    plant : TITOPlant
        Nominal plant (``scenario.variation`` is applied to it).
    decoupler : Decoupler or None
    scenario : TITOScenario

    Attributes
    ----------
    t, r : numpy.ndarray
        Step boundaries and set-points there.
    plant : TITOPlant
        The simulated (varied) plant.
    noise : numpy.ndarray, shape (n + 1, 2)
        Measurement noise, sample ``k`` held over the step from ``t[k]`` (zeros without).
    """

    def __init__(self, plant, decoupler, scenario):
        self.scenario = scenario
        self.noise = measurement_noise(scenario)
        self.plant = vary_plant(plant, scenario.variation, scenario.vary) if scenario.variation else plant
        self.decoupler = decoupler
        self._pi_loop = None
        self.t = scenario.time()
        self.r = np.zeros((self.t.size, 2))
        for k, steps in enumerate(scenario.setpoints):
            for ts, val in steps:
                self.r[self.t >= ts - 1e-9, k] = val

    def arrays(self, controllers):
        """Run the loop for ``controllers``.

        Returns
        -------
        status : str
            ``"ok"``, or ``"diverged"`` where a signal leaves 1e12 or stops being finite.
        y, ym, u, v : numpy.ndarray, shape (n + 1, 2)
            As :meth:`TITOSimulator.arrays`: ``ym = y + noise``, the measurement at ``t`` (from the
            right at a step).
        """
        if _pi_gains(controllers) is not None:
            if self._pi_loop is None:  # built once: a PI only rescales the paths
                self._pi_loop = ContinuousTITOLoop(self.plant, self.decoupler, controllers, self.scenario)
            _, y, u, v = self._pi_loop.run(controllers)
        else:
            _, y, u, v = ContinuousTITOLoop(self.plant, self.decoupler, controllers, self.scenario).run()
        big = np.abs(y).sum(axis=1) + np.abs(u).sum(axis=1)
        bad = ~(big < SIGNAL_LIMIT)
        if bad.any():
            k = int(np.argmax(bad))
            for a in (y, u, v):
                a[k:] = np.nan
            return "diverged", y, y + self.noise, u, v
        return "ok", y, y + self.noise, u, v
