"""The continuous-time TITO closed loop with exact dead times: on a fixed step, or to a tolerance.

Every signal path of the loop is linear and time-invariant, so the output of loop ``i`` is a sum
of routes from the errors, each a series of rational parts with one total dead time::

    y_i(t) = sum_{k,j} (g_ik D_kj c_j)(e_j(t - Lg_ik - Ld_kj)) + sum_k g_ik(d_in_k(t - Lg_ik)) + d_out_i

(``c_j`` controller, ``D_kj`` decoupler entry, ``g_ik`` plant element, each with its own state;
the controller's and the decoupler's states are copied into every route that carries them,
which changes nothing in a linear loop). Every plant element is strictly proper with a dead
time, so the error ``e_j = r_j - y_j`` is piecewise smooth, and its breakpoints (set-point and
disturbance steps, and their images through the delays) fall on the step grid when the step
``h`` divides every dead time and every breakpoint time. Over one step each route's input is
then the error of an earlier step, known in full: the errors are kept as their values at the
four Gauss-Lobatto nodes of every step (a cubic), each route's state is advanced exactly for
that cubic input (matrix exponential of the route with a chain of integrators, Van Loan), and
the new step's errors follow from the outputs at its nodes. Per route, the outputs at the nodes
and the end state are one precomputed affine map of the start state and the stored node values
(:class:`_Path`). The only approximation is the cubic on each step (a local error of order
``h^4``); fast modes (a derivative filter shorter than ``h``) are integrated exactly. The
decoupler outputs ``u`` and controller outputs ``v`` are recorded the same way, from routes
``D_kj c_j`` and ``c_j`` driven by the stored errors.

A PI route is one path whatever the gains (:class:`_PIPath`: the routes through the bases 1 and
``1/s`` share their states, and their gain-weighted sum is the state of one path whose matrices
are ``F + Kp A + Ki B``), built once per step and scenario. The two routes that an inverted
decoupler makes cancel (``e_j`` into ``y_i``, ``i != j``, on the plant it inverts) are left out.

A dead time that is not a multiple of the step (into the outputs it must not be shorter than
the step) puts a stored step boundary at the same fraction ``theta`` of every step; the route is
advanced over the two sub-steps, each with its own stored cubic as input, so a jump of the
delayed signal (the input disturbance, a set-point step) is integrated exactly. The breakpoints
it creates in the errors then fall inside steps, where the cubics smooth their kinks: second
order in ``h``. With a derivative in the controllers the order is about 2 as well (the
derivative acts on the cubics' slope jumps at the step boundaries). Set-point and disturbance
times must be multiples of the step; linear plants only.

:class:`ContinuousTITOSimulator` runs a scenario's loop to ``scenario.tolerance`` (the step
ladder of :func:`coarsest_step`, each run checked against the run at twice its step) or on its
fixed step ``dt``; :class:`ErrorCubics` integrates a run's errors exactly.

Noise is a zero-order-held signal at the sample time ``dt``, a whole number of steps: the
sampled loop's draws (the same generators, variance ``P / dt`` per sample), sample ``k`` held
over ``[k dt, (k + 1) dt)``. The measurement noise enters the errors (``e = r - y - n``) and the
input noise the plant inputs beside the input disturbance; both jump only at step boundaries,
where the stored cubics already break, so the loop stays exact for them. The outputs ``y`` are
the plant's, the measurement ``ym = y + n``. Checked against the method of steps with
``solve_ivp`` (``tests/tito_dde_reference.py``, ``tests/objectives/tito/test_continuous_tito.py``).
"""

from __future__ import annotations

import functools
import math
from fractions import Fraction

import numpy as np
import scipy.signal

from heurtune.core.errors import ConfigError

from . import continuous_kernels as kern
from .design import parallel_controller
from .model import ParallelPID, PIController
from .sim import _poly, controller_tf, input_noise, measurement_noise, vary_plant

__all__ = ["DEFAULT_TOLERANCE", "ContinuousRun", "ContinuousTITOLoop", "ContinuousTITOSimulator", "ErrorCubics",
           "PlantSide", "check_continuous_plant", "coarsest_step"]

# Gauss-Lobatto nodes on [0, 1] (cubic through both ends and two interior points)
NODES = np.array([0.0, 0.5 - 0.5 / math.sqrt(5.0), 0.5 + 0.5 / math.sqrt(5.0), 1.0])
_COMMENSURATE_TOL = 1e-9
# node values -> the coefficients a_k of w(tau) = sum a_k tau^k / k! (the chain of integrators'
# initial state in a path's transition matrices)
_FROM_NODES = np.linalg.inv(np.array([[tau ** k / math.factorial(k) for k in range(NODES.size)] for tau in NODES]))
SIGNAL_LIMIT = 1.0e12
# the continuous loop's default tolerance on the outputs (a config without sample_time or
# tolerance): 0.1 % of the presets' unit set-point steps
DEFAULT_TOLERANCE = 1e-3


def _ss(num, den):
    """Minimal controllable-form state space of ``num/den`` (``D`` a float)."""
    num = np.trim_zeros(np.atleast_1d(np.asarray(num, float)), "f")
    den = np.trim_zeros(np.atleast_1d(np.asarray(den, float)), "f")
    if den.size == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), float(num[-1] / den[0]) if num.size else 0.0
    A, B, C, D = scipy.signal.tf2ss(num, den)
    return A, B.reshape(-1, 1), C.reshape(1, -1), float(D[0, 0])


def _controller_ss(num, den):
    """:func:`_ss` of a controller, remembered for the candidate's other steps of the ladder
    (fresh copies: the callers own their arrays)."""
    A, B, C, D = _controller_ss_cached(tuple(np.asarray(num, float).ravel()), tuple(np.asarray(den, float).ravel()))
    return A.copy(), B.copy(), C.copy(), D


@functools.lru_cache(maxsize=64)
def _controller_ss_cached(num: tuple, den: tuple):
    return _ss(num, den)


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
    return _lagrange_cached(tuple(float(p) for p in points)).copy()


@functools.lru_cache(maxsize=4096)
def _lagrange_cached(points: tuple) -> np.ndarray:
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


def _shift(value: float, h: float, what: str, shortest: float = 1.0):
    """A dead time in steps: an int where it is a multiple of ``h``, else a float (at least
    ``shortest`` steps: 1 for a path into the outputs, which must read finished steps only)."""
    k = round(value / h)
    if abs(k * h - value) <= _COMMENSURATE_TOL * max(1.0, abs(value)):
        return int(k)
    if value < shortest * h:
        raise ConfigError(f"continuous loop: {what} = {value!r} s is shorter than the step {h!r} s")
    return value / h


def _noisy(scenario) -> bool:
    return max(scenario.noise_power) > 0 or scenario.has_input_noise


def _multiple(value: float, h: float, what: str) -> int:
    k = round(value / h)
    if abs(k * h - value) > _COMMENSURATE_TOL * max(1.0, abs(value)):
        raise ConfigError(f"continuous loop: {what} = {value!r} s is not a multiple of the step {h!r} s")
    return int(k)


def _freqresp(system, w):
    A, B, C, D = system
    n = A.shape[0]
    if n == 0:
        return np.full(w.size, D, complex)
    X = np.linalg.solve(1j * w[:, None, None] * np.eye(n) - A, np.broadcast_to(B, (w.size, n, 1)))
    return X[:, :, 0] @ C.reshape(-1) + D


def _cancel(first, second) -> bool:
    """Whether two routes ``(system, dead time)`` into one output from one error sum to zero:
    the same dead time and opposite frequency responses (to 1e-9 of their size) on a grid from
    1e-5 to 1e3 rad/s."""
    (s1, L1), (s2, L2) = first, second
    if abs(L1 - L2) > _COMMENSURATE_TOL * max(1.0, abs(L1)):
        return False
    w = np.geomspace(1e-5, 1e3, 17)
    h1, h2 = _freqresp(s1, w), _freqresp(s2, w)
    return bool(np.all(np.abs(h1 + h2) <= 1e-9 * (np.abs(h1) + np.abs(h2))))


def check_continuous_plant(plant) -> None:
    """Raise a one-line ConfigError unless every element of ``plant`` is strictly proper with a
    dead time > 0, as the continuous loop needs (a direct feedthrough would put the jumps of the
    delayed errors inside the steps)."""
    for i in (1, 2):
        for k in (1, 2):
            e = plant.element(i, k)
            if len(e.leads) >= len(e.lags) or not e.L > 0:
                what = "biproper" if len(e.leads) >= len(e.lags) else f"without dead time (L = {e.L!r})"
                raise ConfigError(f"the continuous loop needs every plant element strictly proper with a dead time "
                                  f"> 0; g{i}{k} is {what}")


class _Path:
    """The precomputed matrices of one path: a state space driven by a stored signal delayed by
    ``shift`` steps (an int: one stored step; a float: two sub-steps, each with its own stored
    step as input).

    Over a step the path needs its outputs at the step's nodes and its state at the end, both
    affine in its state ``x`` at the start and the node values ``h1``, ``h2`` of the stored
    steps it reads (``k - lag`` and ``k - lag + 1``; ``h2`` only where the window is split)::

        out[i] = Ox[i] x + O1[i] h1 + O2[i] h2        x_end = Sx x + S1 h1 + S2 h2

    so a step costs ``(q + n) (n + q)`` multiply-adds (``n + 2 q`` where split), whatever the
    path's stiffness: the matrices are exact (matrix exponentials) for a cubic input.
    """

    def __init__(self, system, h: float, shift, target: int, out: int, src: int):
        A, B, C, D = system
        C, D = C.reshape(-1), float(D)
        self._A, self._B = np.ascontiguousarray(A, float), np.ascontiguousarray(B[:, 0], float)
        n, q = A.shape[0], NODES.size
        self.n = n
        self.target, self.out, self.src = target, out, src
        self.split = not isinstance(shift, int)
        self.O2, self.S2 = np.zeros((q, q)), np.zeros((n, q))
        if not self.split:
            self.lag = int(shift)
            E, H = self._transitions(h, NODES)
            self.Ox = np.einsum("r,irc->ic", C, E)
            self.O1 = np.einsum("r,irc->ic", C, H) + D * np.eye(q)
            self.Sx, self.S1 = E[-1], H[-1]
            return
        # the delayed window crosses a stored step boundary at the same fraction theta of every
        # step: two sub-steps, each with one stored cubic as its input (exact, jumps included)
        theta = shift - math.floor(shift)
        first = [tau / theta for tau in NODES if tau < theta] + [1.0]
        second = [(tau - theta) / (1.0 - theta) for tau in NODES if tau >= theta]
        self.lag, nf = int(math.ceil(shift)), len(first) - 1
        EA, HA = self._transitions(theta * h, first)
        EB, HB = self._transitions((1.0 - theta) * h, second)
        # each sub-step's stored cubic at that sub-step's nodes, and the input at the step's nodes
        PA = _lagrange_matrix((1.0 - theta) + theta * NODES)
        PB = _lagrange_matrix((1.0 - theta) * NODES)
        before = NODES < theta
        QA = np.where(before[:, None], _lagrange_matrix(np.clip((1.0 - theta) + NODES, 0.0, 1.0)), 0.0)
        QB = np.where(before[:, None], 0.0, _lagrange_matrix(np.clip(NODES - theta, 0.0, 1.0)))
        # x_mid = Mx x + M1 h1 at the sub-steps' junction
        Mx, M1 = EA[nf], HA[nf] @ PA
        self.Ox, self.O1, self.O2 = np.empty((q, n)), D * QA, D * QB
        for i in range(nf):
            self.Ox[i] = C @ EA[i]
            self.O1[i] += C @ HA[i] @ PA
        for i in range(nf, q):
            j = i - nf
            self.Ox[i] = C @ EB[j] @ Mx
            self.O1[i] += C @ EB[j] @ M1
            self.O2[i] += C @ HB[j] @ PB
        self.Sx, self.S1, self.S2 = EB[-1] @ Mx, EB[-1] @ M1, HB[-1] @ PB

    def _transitions(self, length: float, offsets):
        """``E[i]``, ``H[i]``: the state at ``offsets[i]`` (fractions of a sub-step of ``length``
        seconds) is ``E[i] x + H[i] w`` for a cubic input with values ``w`` at its nodes
        (:func:`continuous_kernels.transitions`)."""
        return kern.transitions(self._A, self._B, float(length), np.asarray(offsets, float), _FROM_NODES)


_MATRICES = ("Ox", "O1", "O2", "Sx", "S1", "S2")


class _PIPath:
    """The two paths of one signal route under a PI ``Kp + Ki/s``: ``a`` through the basis 1 and
    ``b`` through the basis ``1/s`` (its state ``[z, x]``: the integral ``z`` of the source and
    the route's own states ``x``, those of ``a``). Their weighted sum ``Kp a + Ki b`` is one path
    with state ``[z, Kp x_a + Ki x_b]``, whose matrices are ``F + Kp A + Ki B`` (:meth:`parts`):
    one path per route whatever the gains, built once."""

    def __init__(self, a: _Path, b: _Path, loop: int):
        if b.n != a.n + 1 or (a.split, a.lag, a.target, a.out, a.src) != (b.split, b.lag, b.target, b.out, b.src):
            raise ValueError("a PI route's two paths must share their route, with one more state in b")
        self.a, self.b, self.loop = a, b, loop
        self.n, self.split, self.lag, self.target, self.out, self.src = b.n, b.split, b.lag, b.target, b.out, b.src

    def parts(self):
        """``(F, A, B)``: dicts of the matrices in ``b``'s state layout."""
        a, b, n = self.a, self.b, self.n
        F = {k: np.zeros_like(getattr(b, k)) for k in _MATRICES}
        A = {k: np.zeros_like(getattr(b, k)) for k in _MATRICES}
        B = {k: np.zeros_like(getattr(b, k)) for k in _MATRICES}
        # outputs: C x (x = Kp x_a + Ki x_b, x_a's rows), Ki times b's integral column, inputs by gain
        F["Ox"][:, 1:] = a.Ox
        B["Ox"][:, 0] = b.Ox[:, 0]
        for k in ("O1", "O2"):
            A[k][:] = getattr(a, k)
            B[k][:] = getattr(b, k)
        # states: z as in b (gain-free); x by its own transition, fed by Ki z and the inputs by gain
        F["Sx"][0] = b.Sx[0]
        F["Sx"][1:, 1:] = a.Sx
        B["Sx"][1:n, 0] = b.Sx[1:n, 0]
        for k in ("S1", "S2"):
            F[k][0] = getattr(b, k)[0]
            A[k][1:] = getattr(a, k)
            B[k][1:] = getattr(b, k)[1:]
        return F, A, B


def _stack(paths):
    """The paths' matrices as the zero-padded arrays of :func:`continuous_kernels.run_loop`,
    ordered by target (outputs, decoupler outputs, controller outputs): ``bounds[s]`` to
    ``bounds[s + 1]`` are the paths of stage ``s``. ``arrays`` holds the gain-free parts,
    ``by_kp`` and ``by_ki`` the parts that a PI route's gains scale (zeros elsewhere), ``loop``
    the controller whose gains scale each path (-1: none)."""
    order = sorted(range(len(paths)), key=lambda k: paths[k].target)
    paths = [paths[k] for k in order]
    P, q = len(paths), NODES.size
    nm = max(1, max(p.n for p in paths))

    def ints(name):
        return np.array([getattr(p, name) for p in paths], np.int64)

    def zeros():
        return dict(Ox=np.zeros((P, q, nm)), O1=np.zeros((P, q, q)), O2=np.zeros((P, q, q)),
                    Sx=np.zeros((P, nm, nm)), S1=np.zeros((P, nm, q)), S2=np.zeros((P, nm, q)))

    arrays = dict(out=ints("out"), src=ints("src"), split=ints("split"), lag=ints("lag"), nst=ints("n"),
                  bounds=np.searchsorted(ints("target"), np.arange(4)).astype(np.int64), **zeros())
    by_kp, by_ki = zeros(), zeros()
    loop = np.full(P, -1, np.int64)
    for k, p in enumerate(paths):
        n = p.n
        if isinstance(p, _PIPath):
            parts = p.parts()
            loop[k] = p.loop
        else:
            parts = ({m: getattr(p, m) for m in _MATRICES}, None, None)
        for target, part in zip((arrays, by_kp, by_ki), parts):
            if part is None:
                continue
            target["Ox"][k, :, :n] = part["Ox"]
            target["O1"][k] = part["O1"]
            target["O2"][k] = part["O2"]
            target["Sx"][k, :n, :n] = part["Sx"]
            target["S1"][k, :n] = part["S1"]
            target["S2"][k, :n] = part["S2"]
    return arrays, by_kp, by_ki, loop, nm, np.array(order, np.int64)


class PlantSide:
    """What every loop of one plant, decoupler and step ``h`` shares whatever its controllers:
    the decoupler's and plant's routes from each error (their rational parts and dead times in
    steps, the pairs that an inverted decoupler cancels left out) and the paths of the input
    disturbances, which no controller is on. :class:`ContinuousTITOSimulator` keeps one per step
    of its ladder, so that a candidate builds only its controllers' paths.

    Parameters
    ----------
    plant : TITOPlant
        Every element strictly proper, with a dead time > 0.
    decoupler : Decoupler or None
    h : float
        The step (s).

    Attributes
    ----------
    decoupler_routes : list of (k, j, system, shift)
        From the error ``e_j`` to the decoupler output ``u_k`` (before the controller ``c_j``).
    output_routes : list of (i, j, system, shift)
        From ``e_j`` to the output ``y_i`` through ``D_kj`` and ``g_ik`` (before ``c_j``).
    disturbance_paths : list of _Path
        From the input disturbance ``d_in_k`` to ``y_i`` through ``g_ik``.
    """

    def __init__(self, plant, decoupler, h: float):
        self.h = h = float(h)
        self.unit = unit = _ss([1.0], [1.0])
        self.integrator = _ss([1.0], [1.0, 0.0])
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
        check_continuous_plant(plant)
        G = {}
        for i in range(2):
            for k in range(2):
                e = plant.element(i + 1, k + 1)
                G[(i, k)] = (_element(e), _shift(e.L, h, f"the dead time of g{i + 1}{k + 1}"), e.L)
        # e_j -> u_k through D_kj; e_j -> y_i through D_kj, g_ik; d_in_k -> y_i through g_ik
        self.decoupler_routes, to_y = [], {}
        for (k, j), (sys_d, Ld) in D.items():
            # the decoupler outputs follow the step's own errors: any delay will do
            self.decoupler_routes.append((k, j, sys_d, _shift(Ld, h, "a decoupler dead time", 0.0)))
            for i in range(2):
                sys_g, _, Lg = G[(i, k)]
                to_y.setdefault((i, j), []).append((_series(sys_d, sys_g), Lg + Ld))
        self.output_routes = []
        for (i, j), routes in to_y.items():
            # the decoupler's purpose: y_i's two routes from e_j (i != j) cancel on the plant it
            # inverts (same dead time, opposite rational parts); both are left out then
            if len(routes) == 2 and _cancel(*routes):
                continue
            self.output_routes += [(i, j, system, _shift(L, h, "a path's dead time")) for system, L in routes]
        self.disturbance_paths = [_Path(sys_g, h, ng, kern.TARGET_Y, i, 2 + k) for (i, k), (sys_g, ng, _) in G.items()]


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
        Set-points, disturbances, noise and horizon; its ``dt`` is the noise's hold period (and
        the step when ``step`` is not given). ``tolerance`` is not read here.
    step : float, optional
        The step ``h`` (s), also the output sample time: no longer than the shortest dead time
        into the outputs, dividing the horizon, the set-point and disturbance times and (with
        noise) ``dt``; one-line ConfigError otherwise.
    signals : {"yuv", "y"}
        ``"y"``: a loop of other than PI controllers builds the paths into the outputs alone;
        :meth:`complete` adds those into ``u`` and ``v`` when asked for them.
    plant_side : PlantSide, optional
        The plant's side of the routes for this step, shared between loops (built here if not
        given).
    inputs : tuple, optional
        The scenario's signals on this step, :attr:`inputs` of another loop of the same
        scenario and step (made here if not given; they do not depend on the controllers).

    Attributes
    ----------
    inputs : tuple
        ``(r, dout, hist, noise)``: set-points less the measurement noise and output
        disturbances per step, the history holding the input disturbances and input noise at
        the nodes, the measurement noise at the step boundaries (read only).
    """

    @classmethod
    def from_gains(cls, plant, decoupler, gains, N, scenario, step=None):
        """The loop of two parallel PID gain triples ``(Kp, Ki, Kd)`` with ``Tf = Td / N`` (the
        tuning problems' controllers)."""
        return cls(plant, decoupler, tuple(parallel_controller(*map(float, g), N) for g in gains), scenario, step)

    def __init__(self, plant, decoupler, controllers, scenario, step=None, *, signals="yuv", plant_side=None,
                 inputs=None):
        h = float(scenario.dt if step is None else step)
        self.h, self.sc = h, scenario
        # the noise is held over scenario.dt: a whole number of steps
        self._hold = _multiple(float(scenario.dt), h, "the noise sample time (dt)") if _noisy(scenario) else 1
        self.pi = _pi_gains(controllers) is not None
        if plant_side is None:
            plant_side = PlantSide(plant, decoupler, h)
        elif plant_side.h != h:
            raise ValueError(f"plant_side was built for the step {plant_side.h!r} s, not {h!r} s")
        self._side, self._controllers = plant_side, controllers
        # a PI loop is built once and reused (run(controllers)): all its paths; another loop only
        # the outputs' when asked for "y" (complete() adds the others to the step that is kept)
        self._y_paths = self._routes("y")
        paths = self._y_paths if signals == "y" and not self.pi else self._y_paths + self._routes("uv")
        self._restack(paths)
        self._gains = None if not self.pi else np.array(_pi_gains(controllers))
        self.n = _multiple(scenario.horizon, h, "the horizon")
        for steps in scenario.setpoints:
            for t, _ in steps:
                _multiple(t, h, "a set-point step time")
        _multiple(scenario.input_disturbance[0], h, "the input disturbance time")
        _multiple(scenario.output_disturbance[0], h, "the output disturbance time")
        self.inputs = self._signals() if inputs is None else inputs
        self.noise = self.inputs[3]

    def _restack(self, paths) -> None:
        self._arrays, self._by_kp, self._by_ki, self._loop_of, self._nmax, order = _stack(paths)
        self.paths = [paths[k] for k in order]

    def _routes(self, targets: str) -> list:
        """The paths into ``targets`` (``"y"``: the outputs, from the errors and the input
        disturbances; ``"uv"``: the decoupler and controller outputs), the controllers' in series
        with the plant side's routes."""
        side, h, controllers = self._side, self.h, self._controllers
        if self.pi:
            def route(system, shift, target, out, j):
                # a PI is Kp + Ki/s: built from the bases 1 and 1/s once; a new PI only recombines
                # the two (run(controllers))
                return _PIPath(_Path(_series(side.unit, system), h, shift, target, out, j),
                               _Path(_series(side.integrator, system), h, shift, target, out, j), j)
        else:
            own = [_controller_ss(*controller_tf(c, j + 1)) for j, c in enumerate(controllers)]

            def route(system, shift, target, out, j):
                return _Path(_series(own[j], system), h, shift, target, out, j)
        if targets == "y":
            return [route(system, shift, kern.TARGET_Y, i, j) for i, j, system, shift in side.output_routes] \
                + side.disturbance_paths
        return [route(system, shift, kern.TARGET_U, k, j) for k, j, system, shift in side.decoupler_routes] \
            + [route(side.unit, 0, kern.TARGET_V, j, j) for j in range(2)]

    def _combined(self, gains) -> dict:
        """The PI routes' matrices for ``gains`` (rows ``(Kp, Ki)`` per loop): ``F + Kp A + Ki B``."""
        has = self._loop_of >= 0
        kp = np.where(has, gains[np.maximum(self._loop_of, 0), 0], 0.0)
        ki = np.where(has, gains[np.maximum(self._loop_of, 0), 1], 0.0)
        out = {}
        for m in _MATRICES:
            out[m] = np.empty_like(self._arrays[m])
            kern.combine(self._arrays[m], self._by_kp[m], self._by_ki[m], kp, ki, out[m])
        return out

    def _signals(self):
        """:attr:`inputs` of this loop's scenario and step."""
        n, h, sc = self.n, self.h, self.sc
        mid = (np.arange(n) + 0.5) * h
        r = np.zeros((n, 2))
        for k, steps in enumerate(sc.setpoints):
            for ts, val in steps:
                r[mid >= ts, k] = val
        hold = np.arange(n + 1) // self._hold  # the noise sample over each step (and at the end)
        noise = np.zeros((n + 1, 2))
        if max(sc.noise_power) > 0:  # e = r - (y + n): the noise held over the step
            noise = measurement_noise(sc)[hold]
            r -= noise[:n]
        hold = hold[:n]
        t_out, d_out = sc.output_disturbance
        dout = np.where((mid >= t_out)[:, None], np.asarray(d_out, float)[None, :], 0.0)
        hist = np.zeros((n + 1, 4, NODES.size))
        t_in, d_in = sc.input_disturbance
        hist[:n, 2:, :] = np.where((mid >= t_in)[:, None, None], np.asarray(d_in, float)[None, :, None], 0.0)
        if sc.has_input_noise:
            hist[:n, 2:, :] += input_noise(sc)[hold, :, None]
        return r, dout, hist, noise

    def run(self, controllers=None, signals="yuv"):
        """Simulate the scenario.

        Parameters
        ----------
        controllers : pair, optional
            Other PI controllers for a loop built from PI controllers (its paths are linear in
            the gains, so nothing is rebuilt); default: the loop's own.
        signals : {"yuv", "yu", "y"}
            Which signals to compute; the others are returned as zeros (the outputs need
            neither ``u`` nor ``v``: skipping them saves their paths; :meth:`complete` adds
            them later).

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
        r, dout, hist, _ = self.inputs
        hist = hist.copy()
        y, u, v = (np.zeros((n + 1, 2)) for _ in range(3))
        a = self._arrays
        if self.pi:
            gains = self._gains
            if controllers is not None:
                pairs = _pi_gains(controllers)
                if pairs is None:
                    raise ConfigError("continuous loop: a loop built for PI controllers runs PI controllers only")
                gains = np.array(pairs)
            a = dict(a, **self._combined(gains))
        elif controllers is not None:
            raise ConfigError("continuous loop: only a loop built for PI controllers takes others")
        self._last = (a, r, dout, hist, y, u, v)
        self._stages(0, len(signals))
        # r - y at every step's nodes (the stored errors carry the measurement noise)
        self.errors = hist[:n, :2] + self.noise[:n, :, None]
        return np.arange(n + 1) * self.h, y, u, v

    def complete(self, signals="uv"):
        """Add ``u`` (and ``v``) to the last :meth:`run` of ``signals = "y"``: their paths read
        the errors that run stored. Returns ``(t, y, u, v)`` as :meth:`run`."""
        if signals and len(self.paths) == len(self._y_paths):  # built for the outputs alone
            self._restack(self._y_paths + self._routes("uv"))
            self._last = (self._arrays,) + self._last[1:]
        if signals:
            self._stages(1 if "u" in signals else 2, 3 if "v" in signals else 2)
        _, _, _, _, y, u, v = self._last
        return np.arange(self.n + 1) * self.h, y, u, v

    def _stages(self, first: int, last: int) -> None:
        n = self.n
        a, r, dout, hist, y, u, v = self._last
        x = np.zeros((len(self.paths), self._nmax))
        done = kern.run_loop(n, hist, r, dout, a["bounds"], a["out"], a["src"], a["split"], a["lag"], a["nst"],
                             a["Ox"], a["O1"], a["O2"], a["Sx"], a["S1"], a["S2"], x, y, u, v,
                             SIGNAL_LIMIT, first, last)
        if done < n:  # left the signal limit in step `done`: the rest is not computed
            for arr in (y, u, v):
                arr[done:] = np.nan
            hist[done:, :2] = np.nan


# the monomial coefficients of the cubic through the values at NODES
_TO_MONOMIAL = np.linalg.inv(np.vander(NODES, NODES.size, increasing=True))


class ErrorCubics:
    """The errors ``r - y`` of a continuous run as one cubic per step and loop, with exact
    integrals (their sign changes located to machine precision).

    Parameters
    ----------
    errors : numpy.ndarray, shape (n, 2, 4)
        Errors at the Gauss-Lobatto nodes of each step.
    h : float
        The step (s).
    """

    def __init__(self, errors, h: float):
        self.h = float(h)
        self.n = errors.shape[0]
        self.coef = [np.ascontiguousarray(errors[:, i, :] @ _TO_MONOMIAL.T) for i in range(2)]
        # per loop, the running sums over whole steps of int |e|, int t |e|, int e^2 (row k: steps < k)
        self._sums = []
        for c in self.coef:
            table = kern.step_table(c, self.h) if self.n else np.zeros((0, 3))
            self._sums.append(np.vstack([np.zeros((1, 3)), np.cumsum(table, axis=0)]))

    def _span(self, t0: float, t1: float):
        """``(k0, a0, k1, b1)``: the window ``[t0, t1]`` as steps and fractions (clipped)."""
        T = self.n * self.h
        t0, t1 = min(max(t0, 0.0), T), min(max(t1, 0.0), T)
        k0 = min(int(math.floor(t0 / self.h + 1e-9)), self.n - 1)
        k1 = min(max(int(math.ceil(t1 / self.h - 1e-9)) - 1, k0), self.n - 1)
        return k0, t0 / self.h - k0, k1, t1 / self.h - k1

    def _partial(self, loop: int, k: int, a: float, b: float) -> np.ndarray:
        """``int |e|``, ``int t |e|`` (``t`` from 0) and ``int e^2`` over fractions ``[a, b]`` of step ``k``."""
        if b <= a:
            return np.zeros(3)
        s0, s1, s2 = kern.step_integrals(self.coef[loop][k], a, b)
        return self.h * np.array([s0, k * self.h * s0 + self.h * s1, s2])

    def integrals(self, loop: int, t0: float = 0.0, t1: float = math.inf):
        """``(IAE, ISE, ITAE)`` of loop ``loop`` (0 or 1) over ``[t0, t1]``, with ``t`` counted
        from ``t0`` in the ITAE."""
        k0, a0, k1, b1 = self._span(t0, t1)
        sums = self._sums[loop]
        if k0 == k1:
            tot = self._partial(loop, k0, a0, b1)
        else:  # the first and last steps in part, those between whole
            tot = self._partial(loop, k0, a0, 1.0) + (sums[k1] - sums[k0 + 1]) + self._partial(loop, k1, 0.0, b1)
        iae, tae, ise = tot
        return float(iae), float(ise), float(tae - (k0 + a0) * self.h * iae)

    def settling_time(self, loop: int, band: float, t0: float = 0.0, t1: float = math.inf) -> float:
        """Time from ``t0`` to the last instant at which ``|e| > band`` in ``[t0, t1]`` (0 if
        never; ``inf`` if still outside at ``t1``)."""
        k0, a0, k1, b1 = self._span(t0, t1)
        k, tau = kern.last_exit(self.coef[loop], k0, a0, k1, b1, band)
        if k < 0:
            return 0.0
        if k == k1 and tau >= b1:
            return math.inf
        return (k + tau) * self.h - (k0 + a0) * self.h


class ContinuousRun:
    """One run of :class:`ContinuousTITOSimulator`: ``status``, the grid ``t`` (step boundaries),
    set-points ``r``, outputs ``y``, measurements ``ym``, decoupler and controller outputs ``u``,
    ``v`` at ``t`` (from the right at a step), the error cubics ``errors`` (:class:`ErrorCubics`),
    the ``step`` and the ``error_estimate`` (largest output difference from the run at twice the
    step; NaN on a fixed step)."""

    __slots__ = ("status", "t", "r", "y", "ym", "u", "v", "errors", "step", "error_estimate")

    def __init__(self, **kw):
        for key, val in kw.items():
            setattr(self, key, val)


def _gcd(values) -> float:
    """The largest step that divides every value (each read as a fraction with a denominator of
    at most 10^6)."""
    g = Fraction(0)
    for v in values:
        f = Fraction(v).limit_denominator(10 ** 6)
        g = Fraction(math.gcd(g.numerator * f.denominator, f.numerator * g.denominator), g.denominator * f.denominator)
    return float(g)


def coarsest_step(plant, scenario) -> float:
    """The coarsest step of the continuous loop's step ladder under ``scenario``: it divides the
    horizon, every set-point and disturbance time and (with noise) the noise sample time ``dt``,
    and is no longer than the shortest dead time into the outputs (a plant element's, which
    every output path carries)."""
    times = [scenario.horizon, scenario.input_disturbance[0], scenario.output_disturbance[0]]
    times += [t for steps in scenario.setpoints for t, _ in steps]
    if _noisy(scenario):
        times.append(scenario.dt)
    g = _gcd([t for t in times if t > 0])
    shortest = min(plant.element(i, j).L for i in (1, 2) for j in (1, 2))
    if not shortest > 0:
        raise ConfigError("continuous loop: every plant element needs a dead time > 0")
    return g / math.ceil(g / shortest - 1e-9)


class ContinuousTITOSimulator:
    """The continuous loop behind the interface of :class:`~heurtune.objectives.tito.sim.TITOSimulator`
    (what ``[scenario] loop = "continuous"`` selects).

    With ``scenario.tolerance`` set, each run chooses its step: the ladder ``h0, h0/2, h0/4, ...``
    from :func:`coarsest_step`; a run at ``h`` is kept when its outputs differ from the run at
    ``2 h`` by at most ``tolerance * max(1, max |y|)``, else the step is halved, down to
    ``h0 / 2**MAX_HALVINGS`` (kept there whatever the difference, which its record gives). The
    difference is an estimate, not a bound: on random stable candidates of the CCTS and CSTS
    the kept run's error was 0.1 to 0.8 of it (docs/tito.md, "Which loop"). Without a
    tolerance the step is ``scenario.dt``.

    Parameters
    ----------
    plant : TITOPlant
        Nominal plant (``scenario.variation`` is applied to it).
    decoupler : Decoupler or None
    scenario : TITOScenario
    controller_outputs : bool
        Whether runs compute the controller outputs ``v`` (default True; zeros otherwise).

    Attributes
    ----------
    plant : TITOPlant
        The simulated (varied) plant.
    """

    MAX_HALVINGS = 8

    def __init__(self, plant, decoupler, scenario, controller_outputs=True):
        self.scenario = scenario
        self._signals = "yuv" if controller_outputs else "yu"
        self.plant = vary_plant(plant, scenario.variation, scenario.vary) if scenario.variation else plant
        self.decoupler = decoupler
        self.tolerance = getattr(scenario, "tolerance", None)
        if self.tolerance is None:
            self.steps = (float(scenario.dt),)
        else:
            h0 = coarsest_step(self.plant, scenario)
            self.steps = tuple(h0 / 2 ** j for j in range(self.MAX_HALVINGS + 1))
        self._pi_loops, self._sides, self._inputs = {}, {}, {}

    def _loop(self, controllers, level: int, signals: str):
        h = self.steps[level]
        if level not in self._sides:  # the plant's side of the loop, once per step
            self._sides[level] = PlantSide(self.plant, self.decoupler, h)
        side = self._sides[level]
        if _pi_gains(controllers) is not None:
            if level not in self._pi_loops:  # built once per step: a new PI only recombines its routes
                self._pi_loops[level] = ContinuousTITOLoop(self.plant, self.decoupler, controllers, self.scenario, h,
                                                           plant_side=side, inputs=self._inputs.get(level))
                self._inputs[level] = self._pi_loops[level].inputs
            loop = self._pi_loops[level]
            return loop, loop.run(controllers, signals)
        loop = ContinuousTITOLoop(self.plant, self.decoupler, controllers, self.scenario, h, signals=signals,
                                  plant_side=side, inputs=self._inputs.get(level))
        self._inputs[level] = loop.inputs
        return loop, loop.run(None, signals)

    def _record(self, loop, t, y, u, v, estimate):
        sc = self.scenario
        r = np.zeros((t.size, 2))
        for k, steps in enumerate(sc.setpoints):
            for ts, val in steps:
                r[t >= ts - 1e-9, k] = val
        noise = loop.noise
        status = "ok" if np.isfinite(y).all() and np.isfinite(u).all() else "diverged"
        return ContinuousRun(status=status, t=t, r=r, y=y, ym=y + noise, u=u, v=v,
                             errors=ErrorCubics(loop.errors, loop.h), step=loop.h, error_estimate=estimate)

    def run(self, controllers) -> ContinuousRun:
        """Run the loop for ``controllers`` (to the tolerance where the scenario sets one).

        Returns
        -------
        ContinuousRun
            ``status`` is ``"ok"``, or ``"diverged"`` where a signal leaves 1e12 or stops being
            finite (the signals are NaN from there on).
        """
        if self.tolerance is None:
            loop, (t, y, u, v) = self._loop(controllers, 0, self._signals)
            return self._record(loop, t, y, u, v, math.nan)
        # the outputs alone until a step is kept; its u (and v) then, from its stored errors
        _, (_, coarse, _, _) = self._loop(controllers, 0, "y")
        for level in range(1, len(self.steps)):
            loop, (t, y, u, v) = self._loop(controllers, level, "y")
            if not np.isfinite(y).all():  # diverged at the finer step: so it is
                return self._record(loop, *loop.complete(self._signals[1:]), math.nan)
            diff = np.abs(y[::2] - coarse)
            estimate = float(diff.max()) if np.isfinite(diff).all() else math.inf
            if estimate <= self.tolerance * max(1.0, float(np.abs(y).max())) or level == len(self.steps) - 1:
                return self._record(loop, *loop.complete(self._signals[1:]), estimate)
            coarse = y

    def arrays(self, controllers):
        """``(status, y, ym, u, v)`` of :meth:`run`, as :meth:`TITOSimulator.arrays` returns them."""
        res = self.run(controllers)
        return res.status, res.y, res.ym, res.u, res.v
