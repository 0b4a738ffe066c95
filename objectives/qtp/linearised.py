"""The linearised integrator of the continuous-time QTP loop (``scenario.integrator = "linearised"``).

The Python side of :mod:`heurtune.objectives.qtp.linearised_kernels`: the loop matrix of a
controller under a scenario's plant and its real modal form (built once per controller and
plant), the step rule of a scenario's tolerance, and one simulation. The switching integrator
(:mod:`heurtune.objectives.qtp.continuous`) stays the default: it follows saturation and level
limits, which this one does not. docs/model.md, "The linearised integrator", gives the method,
its rule and its validation.
"""

from __future__ import annotations

import dataclasses
import threading
import warnings

import numpy as np

from heurtune.objectives.qtp import continuous as _continuous
from heurtune.objectives.qtp import linearised_kernels as _lk
from heurtune.objectives.qtp.kernels import P_COEF, P_UOP

# The step rule (linearised_kernels._step_level): steps h_top 2^-l with h_top = H_TOP (or the
# scenario's explicit step), the longest at which every mode is resolved, |lambda| h <= kappa,
# or light: its transient a_j (cm in the level errors, V in the voltages) such that a_j h <=
# FLOOR_FRACTION x tolerance x 1 s. At the default tolerance (0.005 cm): kappa = 0.35, a floor of
# 2.5e-4 cm s. Simpson's rule on a resolved oscillation errs by about (h |lambda|)^4 / 2880, and
# ISE's squared error oscillates at twice the frequency: kappa = 0.5 left 7.5e-4 in an LQI's ISE
# and 1.6e-4 in its IAE, 0.35 leaves at most 4e-5 in IAE on 8 random stable candidates of each
# structure and case. kappa scales with tolerance^(1/4) as the switching integrator's step does,
# at most 1. h_top = 2 s was tried: 5e-3 in IAE on a 2-DOF PI whose tank runs dry. Validated in
# tests/objectives/qtp/test_linearised.py and benchmarks/linearised_lane.py.
H_TOP = 1.0
KAPPA_AT_REFERENCE = 0.35
FLOOR_FRACTION = 0.05


@dataclasses.dataclass(frozen=True, eq=False)
class LinearisedForm:
    """A controller's loop under one plant in the kernel's real modal form
    (:func:`~heurtune.objectives.qtp.linearised_kernels.modal_form`), with the controller's
    input matrices and reference path in the loop matrix's coordinates.

    Attributes
    ----------
    ok : bool
        False where LAPACK failed or the basis is conditioned worse than ``COND_LIMIT``.
    lam_r, lam_i, n_real, V6, W, Tinv, gain :
        The modal form.
    Bc : (nc, 4); Dc : (2, 4); Br : (nc, 2); Dr : (2, 2)
    """

    ok: bool
    lam_r: np.ndarray
    lam_i: np.ndarray
    n_real: int
    V6: np.ndarray
    W: np.ndarray
    Tinv: np.ndarray
    gain: np.ndarray
    Bc: np.ndarray
    Dc: np.ndarray
    Br: np.ndarray
    Dr: np.ndarray

    @property
    def kernel_args(self) -> tuple:
        """The lane's arguments from ``lam_r`` to ``Dr``, in its order."""
        return (self.lam_r, self.lam_i, self.n_real, self.V6, self.W, self.Tinv, self.gain, self.Bc, self.Dc,
                self.Br, self.Dr)


def controller_matrices(ctrl) -> tuple:
    """``(Ac, Bc, Cc, Dc, Br, Dr)`` of the loop matrix: the minimal realisation of a controller
    that does not read the reference (``Br``, ``Dr`` zero), the full one of one that does (its
    reference path acts on states the measured signals may not reach), whose ``Br``, ``Dr`` are
    then :meth:`LinearController.reference_feed`'s (the kernels measure the levels from the
    set-points). Kept on the controller.

    Parameters
    ----------
    ctrl : LinearController

    Returns
    -------
    tuple of C-contiguous float64 arrays
    """
    cached = ctrl.__dict__.get("_linearised_matrices")
    if cached is not None:
        return cached
    if ctrl.reads_reference:  # the kernels measure from the set-points: B w + Br r = B w_k + Be r
        Ac, Bc, Cc, Dc = ctrl.A, ctrl.B, ctrl.C, ctrl.D
        Br, Dr = ctrl.reference_feed()
    else:
        Ac, Bc, Cc, Dc = ctrl.minimal_realisation()
        Br, Dr = np.zeros((Ac.shape[0], 2)), np.zeros((2, 2))
    # writeable, as the kernels' types are: a frozen design's matrices (FOLQI's) and a fresh
    # realisation's (the 2-DOF PI's) would otherwise compile two copies of each kernel
    out = tuple(np.require(a, np.float64, ("C", "W")) for a in (Ac, Bc, Cc, Dc, Br, Dr))
    object.__setattr__(ctrl, "_linearised_matrices", out)
    return out


def linearised_form(ctrl, table: np.ndarray, x_op: np.ndarray, level_per_state: float) -> LinearisedForm:
    """The modal form of ``ctrl``'s loop on the plant of scenario table ``table``.

    Parameters
    ----------
    ctrl : LinearController
    table : (NP,) ndarray
        The scenario's parameter table (plant coefficients, operating voltages).
    x_op : (4,) ndarray
        The operating state.
    level_per_state : float

    Returns
    -------
    LinearisedForm
    """
    Ac, Bc, Cc, Dc, Br, Dr = controller_matrices(ctrl)
    coef = np.ascontiguousarray(table[P_COEF:P_COEF + 10])
    u_op = np.ascontiguousarray(table[P_UOP:P_UOP + 2])
    L = _lk.loop_matrix(coef, u_op, x_op, float(level_per_state), Ac, Bc, Cc, Dc)
    ok, lam_r, lam_i, n_real, V6, W, Tinv, gain = _lk.modal_form(L, float(level_per_state), Cc, Dc)
    return LinearisedForm(bool(ok), lam_r, lam_i, int(n_real), V6, W, Tinv, gain, Bc, Dc, Br, Dr)


def step_rule(scenario) -> tuple:
    """``(h_top, kappa, amp_floor)`` of a scenario (see :data:`H_TOP`).

    Parameters
    ----------
    scenario : Scenario
        A continuous-time scenario: ``tolerance`` (cm) sets kappa and the floor; an explicit
        ``step`` (s) is ``h_top``, with the default tolerance's kappa and floor.

    Returns
    -------
    (float, float, float)
    """
    tol = _continuous.DEFAULT_TOLERANCE if scenario.tolerance is None else float(scenario.tolerance)
    ratio = (tol / _continuous.REFERENCE_TOLERANCE) ** 0.25
    h_top = H_TOP if scenario.step is None else float(scenario.step)
    return h_top, min(KAPPA_AT_REFERENCE * ratio, 1.0), FLOOR_FRACTION * tol


_LOCAL = threading.local()


def _workspace(n: int) -> tuple:
    """This thread's working arrays of the lane for ``n`` states."""
    cache = getattr(_LOCAL, "work", None)
    if cache is None:
        cache = _LOCAL.work = {}
    work = cache.get(n)
    if work is None:
        work = cache[n] = _lk.workspace(n)
    return work


_warned_fallback = False


def warn_fallback() -> None:
    """Say once per process that a candidate runs on the switching integrator instead (its basis
    is ill-conditioned)."""
    global _warned_fallback
    if not _warned_fallback:
        _warned_fallback = True
        warnings.warn("scenario.integrator = 'linearised': a candidate's loop matrix has an eigenvector basis "
                      f"conditioned worse than {_lk.COND_LIMIT:g}; such candidates run on the switching integrator "
                      "(said once per process)", RuntimeWarning, stacklevel=3)


def simulate(form: LinearisedForm, table, level_per_state, x_op, h_op, plan, band_pct: float, rule: tuple,
             metrics: np.ndarray, out_dt: float, y_rec, u_rec, h_rec):
    """One run of the linearised lane (:func:`~heurtune.objectives.qtp.linearised_kernels.linearised_lane`).

    Parameters
    ----------
    form : LinearisedForm
        With ``ok`` True (the caller runs the switching integrator otherwise).
    table, level_per_state, x_op, h_op :
        The scenario's table, the level per unit of state, the operating state and levels.
    plan : StepPlan
        The scenario's segments (their steps are not read).
    band_pct : float
    rule : (h_top, kappa, amp_floor)
        :func:`step_rule`.
    metrics : (N_METRICS,) ndarray, output
    out_dt : float; y_rec, u_rec : (M, 2); h_rec : (M, 4)
        The records on the grid ``i out_dt`` (0 rows: none).

    Returns
    -------
    (status, steps)
    """
    status, steps = _lk.linearised_lane(
        table, float(level_per_state), x_op, h_op, *form.kernel_args, plan.table, plan.t0.size, float(band_pct),
        *rule, metrics, float(out_dt), y_rec, u_rec, h_rec, _workspace(form.lam_r.size))
    return int(status), int(steps)
