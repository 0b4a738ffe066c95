"""The continuous-time QTP closed loop: controller in modal form, step plan, simulation.

The Python side of :mod:`heurtune.objectives.qtp.continuous_kernels`: it puts a
:class:`~heurtune.objectives.qtp.controllers.LinearController` in the form the kernel takes
(modal states ``z_i' = lam_i z_i + b_i w_col`` and dense blocks), and plans the step grid of a
scenario: a segment starts at t = 0 and at every discontinuity (the output and input
disturbance times), its first step after a discontinuity is graded (h/16, h/16, h/8, h/4, h/2)
and the rest are equal steps of at most ``h``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.core.structures import get_structure, structures_of

# The step rule: the step that keeps the largest level error under ``tolerance`` cm. The
# method is fourth order, so the error scales as h^4: h = step_at_reference(kind) (tolerance /
# REFERENCE_TOLERANCE)^(1/4), within [MIN_STEP, MAX_STEP]. The constants are validated in
# tests/objectives/qtp/test_continuous.py and benchmarks/work_precision.py (docs/model.md):
# at 0.125 s the thesis' FOLQI gains and the weakly damped candidate are 3e-4 cm or better off.
# LADR's extended-state observers couple fast modes (-250 and -660 rad/s in closed loop for
# Table 4.7) through the plant, which the explicit part sees: 0.08 s is 1.8e-4 cm off, 0.1 s
# 0.03 cm; its reference step is 0.05 s (4.6e-5 cm).
REFERENCE_TOLERANCE = 0.005
# The tolerance of a scenario that sets none of dt, tolerance, step: the continuous loop is the
# default, to 0.005 cm on the levels.
DEFAULT_TOLERANCE = 0.005
# Each controller structure declares its step at the reference tolerance
# (``extras["step_at_reference"]``, heurtune.objectives.qtp.structures): 0.125 s for FOLQI, IOLQI,
# LQI, PID and FOPID, 0.05 s for LADR. A type that declares none gets the smallest registered.
DEFAULT_STEP_AT_REFERENCE = 0.05
# A structure with ``extras["explicit_step"]`` (PID, FOPID: a static feedback that can be large)
# also keeps h |lambda| <= EXPLICIT_STEP_RADIUS (tolerance / REFERENCE_TOLERANCE)^(1/4) for the
# eigenvalues lambda of the plant under that static feedback, A + B D, which the explicit
# part of the method integrates (see explicit_step; validated in test_pid.py).
EXPLICIT_STEP_RADIUS = 0.5
# A structure with ``extras["feedback_step"]`` (FOLQI, IOLQI, LQI) keeps its declared step unless
# the plant under its effective static feedback is fast: h rho(A + B D_h) <= FEEDBACK_STEP_RADIUS
# (tolerance / REFERENCE_TOLERANCE)^(1/4), where D_h adds to D the static gain of every modal
# state faster than 1/h (those the method integrates exactly, but whose push on the levels the
# explicit part sees as a static feedback). The step is halved until it holds (see
# feedback_step; benchmarks/step_rule.py measures it). At 0.125 s it shortens only candidates with
# rho > 6 1/s, such as the corner Q = 2.5, R = 0.1, Ki = 10, alpha = 0.1 (rho 8.5, 5.5e-3 cm off at
# 0.125 s); every other candidate keeps its step, bit for bit.
FEEDBACK_STEP_RADIUS = 0.75
MAX_STEP = 1.0
# Adaptive steps above the rule's step (FOLQI, IOLQI, LQI, the structures that declare
# ``feedback_step``, under ``tolerance``): pairs of steps up to 2^(top - 1) times the rule's step
# (at most 8 times, ADAPTIVE_TOP in the kernels), each checked by step doubling against a local
# tolerance of ADAPTIVE_LOCAL_FRACTION times the tolerance, or ADAPTIVE_RELATIVE times the
# largest measured deviation where that is smaller, per ADAPTIVE_PERIOD seconds of step. A step
# h is only tried where h rho(A + B D_h) <= ADAPTIVE_STABILITY_RADIUS (the explicit part stays
# stable). Validated in benchmarks/step_rule.py and tests/objectives/qtp/test_continuous.py
# (docs/model.md, "Adaptive steps").
ADAPTIVE_LOCAL_FRACTION = 0.1
ADAPTIVE_RELATIVE = 1e-3
ADAPTIVE_PERIOD = 10.0
ADAPTIVE_STABILITY_RADIUS = 1.5
MIN_STEP = 1e-4
# A scenario whose step rule needs more steps than this over its horizon is refused.
MAX_STEPS = 10_000_000


# The dense part of a controller without dense blocks: Aq, Bq, Cq with no states, shared (there
# is nothing to write in them).
_NO_DENSE = (np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)))


@dataclasses.dataclass(frozen=True, eq=False)
class ContinuousController:
    """A controller as the continuous kernel takes it (see ``simulate_continuous``).

    Attributes
    ----------
    lam, b : (nd,) modal eigenvalues and input gains; col : (nd,) int64 the measured signal of
        each mode; Cm : (2, nd) their output weights
    Aq : (nq, nq), Bq : (nq, 4), Cq : (2, nq): the dense blocks, block diagonal
    D : (2, 4) static feedback
    channel : (nd + nq,) int64, the pump each state belongs to (its anti-windup channel)
    """

    lam: np.ndarray
    b: np.ndarray
    col: np.ndarray
    Cm: np.ndarray
    Aq: np.ndarray
    Bq: np.ndarray
    Cq: np.ndarray
    D: np.ndarray
    channel: np.ndarray

    @classmethod
    def from_linear(cls, ctrl) -> ContinuousController:
        """Modal form of a :class:`LinearController` (:meth:`LinearController.modal_blocks`),
        built once per controller (kept on it: a controller is immutable, and each scenario
        it runs under reads the same form)."""
        cached = ctrl.__dict__.get("_continuous_form")
        if cached is not None:
            return cached
        form = cls._build(ctrl)
        object.__setattr__(ctrl, "_continuous_form", form)
        return form

    @classmethod
    def _build(cls, ctrl) -> ContinuousController:
        D = np.ascontiguousarray(ctrl.D, dtype=np.float64)
        if ctrl.modal_arrays is not None and not ctrl.reads_reference:  # every block modal, concatenated
            # writeable, as the kernels' types are: the design's own (shared by the controllers
            # of one layout, never written), else copies
            lam, b, col, channel = (arr if arr.flags.writeable else arr.copy() for arr in ctrl.modal_arrays)
            return cls(lam=lam, b=b, col=col, Cm=np.ascontiguousarray(ctrl.C), D=D, channel=channel,
                       Aq=_NO_DENSE[0], Bq=_NO_DENSE[1], Cq=_NO_DENSE[2])
        parts, extra = ctrl.modal_blocks(), ()
        if ctrl.reads_reference:
            parts, extra = cls._reference_block(ctrl, parts)
        lam, b, col, Cm, dense, ch_m, ch_q = [], [], [], [], [], [], []

        def real(x):
            return x if x.dtype.kind == "f" else np.real(x)

        for part in parts:
            if part[0] == "modal":
                _, l_, b_, C_, c_, ch = part
                lam.append(real(l_))
                b.append(real(b_))
                Cm.append(real(C_))
                col.append(np.full(len(l_), c_, dtype=np.int64))
                ch_m.append(np.full(len(l_), ch, dtype=np.int64))
            else:
                dense.append(part[1:4])
                ch_q.append(np.full(part[1].shape[0], part[4], dtype=np.int64))
        for A, B, C, channels in extra:  # a dense block whose states have channels of their own
            dense.append((A, B, C))
            ch_q.append(channels)

        def cat(xs, empty):
            return np.ascontiguousarray(np.concatenate(xs)) if xs else empty

        return cls(lam=cat(lam, np.zeros(0)), b=cat(b, np.zeros(0)), col=cat(col, np.zeros(0, dtype=np.int64)),
                   Cm=np.ascontiguousarray(np.hstack(Cm)) if Cm else np.zeros((2, 0)), D=D,
                   channel=np.concatenate(ch_m + ch_q) if ch_m or ch_q else np.zeros(0, dtype=np.int64),
                   **cls._dense_part(dense))

    @staticmethod
    def _reference_block(ctrl, parts) -> tuple:
        """The form of a controller that reads the reference: ``(parts, [(A, B, C, channels)])``,
        the :meth:`LinearController.modal_blocks` parts of the blocks the reference does not drive
        and one dense block holding the others (rows of ``Be`` not zero,
        :meth:`LinearController.reference_feed`) in their own coordinates, beside two reference
        states ``rho`` (channels ``REF_CHANNEL``, ``REF_CHANNEL + 1``) that hold the set-point
        deviations: ``z' = A z + B w_k + Be rho``, and ``rho`` drives the pumps by ``De``. The
        kernel sets ``rho`` at each segment start."""
        from heurtune.objectives.qtp.continuous_kernels import REF_CHANNEL

        Be, De = ctrl.reference_feed()
        keep, driven = [], []
        for part, (start, stop), ch in zip(parts, ctrl.blocks, ctrl.block_channel, strict=True):
            if np.any(Be[start:stop] != 0.0):
                driven.append((start, stop, ch))
            else:
                keep.append(part)
        m = sum(stop - start for start, stop, _ in driven)
        A, B, C = np.zeros((m + 2, m + 2)), np.zeros((m + 2, 4)), np.zeros((2, m + 2))
        channels, k = [], 0
        for start, stop, ch in driven:
            n = stop - start
            A[k:k + n, k:k + n] = ctrl.A[start:stop, start:stop]
            A[k:k + n, m:] = Be[start:stop]
            B[k:k + n] = ctrl.B[start:stop]
            C[:, k:k + n] = ctrl.C[:, start:stop]
            channels += [ch] * n
            k += n
        C[:, m:] = De
        channels += [REF_CHANNEL, REF_CHANNEL + 1]
        return keep, [(A, B, C, np.array(channels, dtype=np.int64))]

    @staticmethod
    def _dense_part(dense: list) -> dict:
        """``Aq``, ``Bq``, ``Cq`` of the dense blocks ``[(A, B, C), ...]``, block diagonal in
        their order (empty arrays of the kernels' shapes when there are none)."""
        nq = sum(d[0].shape[0] for d in dense)
        Aq, Bq, Cq = np.zeros((nq, nq)), np.zeros((nq, 4)), np.zeros((2, nq))
        k = 0
        for A, B, C in dense:
            m = A.shape[0]
            Aq[k:k + m, k:k + m] = A
            Bq[k:k + m] = B
            Cq[:, k:k + m] = C
            k += m
        return dict(Aq=Aq, Bq=Bq, Cq=Cq)


def step_at_reference(kind: str | None) -> float:
    """The step a controller type declares at the reference tolerance (None, or a type that
    declares none: the smallest any registered type declares).

    Parameters
    ----------
    kind : str or None
        A controller type.

    Returns
    -------
    float
    """
    try:  # the per-evaluation path: one lookup
        declared = get_structure("qtp", kind).extras.get("step_at_reference")
    except ConfigError:  # None, or a type not registered
        declared = None
    if declared is not None:
        return float(declared)
    steps = [s.extras["step_at_reference"] for s in structures_of("qtp") if "step_at_reference" in s.extras]
    return float(min(steps, default=DEFAULT_STEP_AT_REFERENCE))


def step_for_tolerance(tolerance: float, kind: str | None = None) -> float:
    """The step of the continuous loop for a largest level error of ``tolerance`` cm under a
    controller of type ``kind`` (None: the smallest of the known types' steps).

    Parameters
    ----------
    tolerance : float
    kind : str, optional

    Returns
    -------
    float
        Within [MIN_STEP, MAX_STEP].
    """
    h = step_at_reference(kind) * (tolerance / REFERENCE_TOLERANCE) ** 0.25
    return float(min(max(h, MIN_STEP), MAX_STEP))


def explicit_step(A: np.ndarray, B: np.ndarray, D: np.ndarray, tolerance: float) -> float:
    """The longest step the explicit part allows a controller whose static feedback is ``D``
    (2, 4): ``EXPLICIT_STEP_RADIUS (tolerance / REFERENCE_TOLERANCE)^(1/4) / rho``, ``rho`` the
    spectral radius of ``A + B D`` (the linearised plant under that feedback, whose fast modes
    the method does not integrate exactly), within [MIN_STEP, MAX_STEP].

    Parameters
    ----------
    A : ndarray (4, 4)
    B : ndarray (4, 2)
        The plant linearisation.
    D : ndarray (2, 4)
    tolerance : float
        The largest level error in cm.

    Returns
    -------
    float
    """
    rho = float(np.max(np.abs(np.linalg.eigvals(A + B @ D))))
    if not math.isfinite(rho):
        return MIN_STEP
    h = EXPLICIT_STEP_RADIUS * (tolerance / REFERENCE_TOLERANCE) ** 0.25 / max(rho, 1e-12)
    return float(min(max(h, MIN_STEP), MAX_STEP))


def folded_feedback(cc: ContinuousController, h: float) -> np.ndarray:
    """The static feedback (2, 4) that the explicit part of a step ``h`` sees: ``D`` plus, for
    every modal state with ``|lam| h > 1``, its static gain ``-C_i b_i / lam_i`` on the signal it
    reads. Dense blocks are left out.

    Parameters
    ----------
    cc : ContinuousController
    h : float
        The step.

    Returns
    -------
    ndarray (2, 4)
    """
    D = np.array(cc.D, dtype=np.float64)
    fast = np.flatnonzero(np.abs(cc.lam) * h > 1.0)
    if fast.size:
        gain = -cc.Cm[:, fast] * (cc.b[fast] / cc.lam[fast])
        for j, col in enumerate(cc.col[fast]):
            D[:, col] += gain[:, j]
    return D


def feedback_step(A: np.ndarray, B: np.ndarray, cc: ContinuousController, h_max: float,
                  tolerance: float) -> float:
    """The step of a controller whose effective static feedback may make the plant fast.

    Parameters
    ----------
    A : (4, 4) ndarray
        The linearised plant of the scenario.
    B : (4, 2) ndarray
        Its input matrix (the nominal one divided by the scenario's uncertainty factor, which
        scales the tank areas).
    cc : ContinuousController
    h_max : float
        The structure's step for ``tolerance`` (:func:`step_for_tolerance`).
    tolerance : float
        The largest level error in cm.

    Returns
    -------
    float
        ``h_max`` if ``h_max rho(A + B D_h) <= FEEDBACK_STEP_RADIUS (tolerance /
        REFERENCE_TOLERANCE)^(1/4)`` (``D_h``: :func:`folded_feedback`), else ``h_max`` halved
        until it holds; at least :data:`MIN_STEP`.
    """
    return feedback_step_and_top(A, B, cc, h_max, tolerance)[0]


def adaptive_top(A: np.ndarray, B: np.ndarray, cc: ContinuousController, h: float) -> int:
    """How far above the rule's step ``h`` the adaptive pairs may go: ``top`` such that the
    largest step tried is ``h 2^(top - 1)``, the largest ``h 2^j`` (j = 1..3) with
    ``h 2^j rho(A + B D_(h 2^j)) <= ADAPTIVE_STABILITY_RADIUS``; 0 (no pairs) if none.

    Parameters
    ----------
    A : (4, 4) ndarray
        The linearised plant of the scenario.
    B : (4, 2) ndarray
        Its input matrix (divided by the scenario's uncertainty factor).
    cc : ContinuousController
    h : float
        The rule's step (:func:`feedback_step`).

    Returns
    -------
    int
        0, or 2 .. ADAPTIVE_TOP of the kernels.
    """
    from heurtune.objectives.qtp import continuous_kernels as ck

    A, B = np.ascontiguousarray(A, dtype=np.float64), np.ascontiguousarray(B, dtype=np.float64)
    # the rule at radius inf keeps h; the range above it is what is left
    return int(ck.step_rule(A, B, cc.D, cc.lam, cc.b, cc.col, cc.Cm, float(h), math.inf, 0.0,
                            ADAPTIVE_STABILITY_RADIUS, ck.ADAPTIVE_TOP)[1])


def feedback_step_and_top(A: np.ndarray, B: np.ndarray, cc: ContinuousController, h_max: float,
                          tolerance: float) -> tuple:
    """:func:`feedback_step` and :func:`adaptive_top` at its step, in one compiled call.

    Parameters
    ----------
    A, B, cc, h_max, tolerance :
        As :func:`feedback_step`.

    Returns
    -------
    (float, int)
    """
    A, B = np.ascontiguousarray(A, dtype=np.float64), np.ascontiguousarray(B, dtype=np.float64)
    return feedback_rule(A, B, cc, float(h_max), feedback_radius(tolerance))


def feedback_radius(tolerance: float) -> float:
    """The largest ``h rho(A + B D_h)`` that :func:`feedback_step` accepts at ``tolerance`` cm:
    ``FEEDBACK_STEP_RADIUS (tolerance / REFERENCE_TOLERANCE)^(1/4)``.

    Parameters
    ----------
    tolerance : float

    Returns
    -------
    float
    """
    return FEEDBACK_STEP_RADIUS * (tolerance / REFERENCE_TOLERANCE) ** 0.25


def feedback_rule(A: np.ndarray, B: np.ndarray, cc: ContinuousController, h_max: float, radius: float) -> tuple:
    """:func:`feedback_step_and_top` with the radius of its tolerance given, as a loop that keeps
    its inputs per scenario calls it.

    Parameters
    ----------
    A : (4, 4) ndarray
        The linearised plant, C-contiguous float64.
    B : (4, 2) ndarray
        The scenario's input matrix, C-contiguous float64.
    cc : ContinuousController
    h_max : float
        The structure's step for the tolerance (:func:`step_for_tolerance`).
    radius : float
        :func:`feedback_radius` of the tolerance.

    Returns
    -------
    (float, int)
    """
    from heurtune.objectives.qtp import continuous_kernels as ck

    h, top = ck.step_rule(A, B, cc.D, cc.lam, cc.b, cc.col, cc.Cm, h_max, radius, MIN_STEP,
                          ADAPTIVE_STABILITY_RADIUS, ck.ADAPTIVE_TOP)
    return float(h), int(top)


@dataclasses.dataclass(frozen=True)
class StepPlan:
    """The segments of a continuous simulation (arrays as ``simulate_continuous`` takes them).

    ``local_tol`` > 0 lets the kernel take adaptive pairs of steps up to ``2^(top - 1)`` times
    ``h`` (tolerance of a pair: ``local_tol``, or ``local_rel`` times the largest measured
    deviation where smaller, per ``local_per`` seconds of step); 0 keeps every step at ``h``.
    ``n_steps`` counts the steps of the plan at ``h``, without pairs (or switches)."""

    t0: np.ndarray
    h: np.ndarray
    steps: np.ndarray
    graded: np.ndarray
    dist: np.ndarray
    uin: np.ndarray
    post: np.ndarray
    local_tol: float = 0.0
    top: int = 0
    local_rel: float = 0.0
    local_per: float = 0.0
    ref: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        """Steps the plan takes (graded ones counted one by one)."""
        return int(self.steps.sum() + 4 * self.graded.sum())

    @functools.cached_property
    def table(self) -> np.ndarray:
        """The segment table ``seg`` (S, N_SEG) of the continuous kernels, columns ``SEG_*`` of
        :mod:`~heurtune.objectives.qtp.continuous_kernels` (flags as 1.0 or 0.0)."""
        from heurtune.objectives.qtp import continuous_kernels as ck

        seg = np.empty((self.t0.size, ck.N_SEG))
        seg[:, ck.SEG_T0], seg[:, ck.SEG_H], seg[:, ck.SEG_STEPS] = self.t0, self.h, self.steps
        seg[:, ck.SEG_GRADED], seg[:, ck.SEG_POST] = self.graded, self.post
        seg[:, ck.SEG_DIST:ck.SEG_DIST + 2], seg[:, ck.SEG_UIN:ck.SEG_UIN + 2] = self.dist, self.uin
        seg[:, ck.SEG_LOCAL_TOL], seg[:, ck.SEG_TOP] = self.local_tol, self.top
        seg[:, ck.SEG_LOCAL_REL], seg[:, ck.SEG_LOCAL_PER] = self.local_rel, self.local_per
        seg[:, ck.SEG_REF:ck.SEG_REF + 2] = 0.0 if self.ref is None else self.ref
        return seg


def first_event_time(output_disturbance, disturbance_time: float, setpoint_step, setpoint_time: float) -> float:
    """The time overshoot and settling count from: the earlier of the measured-level step and
    the set-point step among those that are not zero; the output disturbance time when neither
    is (the thesis' scenarios: its 50 s).

    Parameters
    ----------
    output_disturbance : array_like (2,)
    disturbance_time : float
    setpoint_step : array_like (2,)
    setpoint_time : float

    Returns
    -------
    float
    """
    times = [float(t) for t, d in ((disturbance_time, output_disturbance), (setpoint_time, setpoint_step))
             if np.any(np.asarray(d, dtype=np.float64) != 0)]
    return min(times) if times else float(disturbance_time)


def plan_steps(horizon: float, step: float, output_disturbance, disturbance_time: float,
               input_disturbance, input_disturbance_time: float, local_tol: float = 0.0, top: int = 0,
               local_rel: float = 0.0, local_per: float = 0.0, setpoint_step=(0.0, 0.0),
               setpoint_time: float = 0.0) -> StepPlan:
    """Segments between the discontinuities of a scenario, each in equal steps of at most ``step``.

    A breakpoint is a disturbance or set-point time inside (0, horizon) whose step is not zero.
    Each segment after a breakpoint grades its first step.

    Parameters
    ----------
    horizon : float
    step : float
        The longest step.
    output_disturbance : array_like (2,)
    disturbance_time : float
    input_disturbance : array_like (2,)
    input_disturbance_time : float
    local_tol, top, local_rel, local_per : optional
        Adaptive pairs above ``step`` (:data:`ADAPTIVE_LOCAL_FRACTION` and the constants
        beside it; ``local_tol`` 0, the default, keeps every step at ``step``).
    setpoint_step : array_like (2,), optional
        The set-points' step in cm. The kernels' measured deviations are taken from the
        set-points, so it enters each segment's output disturbance with the opposite sign, and
        the segment's reference (``SEG_REF``) holds it for a structure that reads it.
    setpoint_time : float, optional

    Returns
    -------
    StepPlan
    """
    d_out = np.asarray(output_disturbance, dtype=np.float64)
    d_in = np.asarray(input_disturbance, dtype=np.float64)
    d_ref = np.asarray(setpoint_step, dtype=np.float64)
    breaks = {0.0, float(horizon)}
    for t_event, d in ((disturbance_time, d_out), (setpoint_time, d_ref), (input_disturbance_time, d_in)):
        if np.any(d != 0) and 0.0 < t_event < horizon:
            breaks.add(float(t_event))
    t_post = first_event_time(d_out, disturbance_time, d_ref, setpoint_time)
    edges = sorted(breaks)
    t0, h, steps, graded, dist, uin, post, ref = [], [], [], [], [], [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        n = max(1, math.ceil((b - a) / step - 1e-9))
        t0.append(a)
        h.append((b - a) / n)
        steps.append(n)
        graded.append(a > 0.0)
        r = d_ref if a >= setpoint_time else np.zeros(2)
        d = d_out if a >= disturbance_time else np.zeros(2)
        dist.append(d - r if r.any() else d)
        uin.append(d_in if a >= input_disturbance_time else np.zeros(2))
        post.append(a >= t_post)
        ref.append(r)
    return StepPlan(np.array(t0), np.array(h), np.array(steps, dtype=np.int64), np.array(graded, dtype=np.bool_),
                    np.array(dist), np.array(uin), np.array(post, dtype=np.bool_), float(local_tol), int(top),
                    float(local_rel), float(local_per), np.array(ref))


def pack_lanes(controllers, plans, tables) -> dict:
    """The inputs of :func:`~heurtune.objectives.qtp.continuous_kernels.simulate_continuous_lanes`
    for lanes ``k`` of controller ``controllers[k]`` under step plan ``plans[k]``.

    Parameters
    ----------
    controllers : sequence of ContinuousController
        All with the same numbers of modal and dense states.
    plans : sequence of StepPlan
        Their segment tables are padded here to the longest (``n_seg`` says how many segments
        a lane uses).
    tables : sequence of ndarray
        Per lane the scenario's parameter table (``kernels.scenario_table``, (NP,)).

    Returns
    -------
    dict
        Arrays by the names of ``continuous_kernels.LANE_FIELDS``, lanes on the first axis.
    """
    from heurtune.objectives.qtp.continuous_kernels import LANE_FIELDS, N_SEG

    L = len(controllers)
    seg = np.zeros((L, max(p.t0.size for p in plans), N_SEG))
    for k, p in enumerate(plans):
        seg[k, :p.t0.size] = p.table

    def stacked(name, dtype=np.float64):
        return np.ascontiguousarray(np.stack([np.asarray(getattr(c, name), dtype=dtype) for c in controllers]))

    out = dict(
        P=np.ascontiguousarray(np.stack(tables)),
        lam=stacked("lam"), bm=stacked("b"), mi=stacked("col", np.int64), Cm=stacked("Cm"), Aq=stacked("Aq"),
        Bq=stacked("Bq"), Cq=stacked("Cq"), Dc=stacked("D"), channel=stacked("channel", np.int64),
        seg=seg, n_seg=np.array([p.t0.size for p in plans], dtype=np.int64))
    return {name: out[name] for name in LANE_FIELDS}
