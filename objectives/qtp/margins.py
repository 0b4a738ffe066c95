"""Frequency-domain stability margins of the linearised QTP loop (thesis Tables 4.11, 5.8-5.10).

The thesis reports, per "loop interaction (input i, output j)", a gain-crossover frequency and
a phase margin read from Bode plots of "the open loop", with infinite gain margins. It does not
say where the loop is broken nor what input and output mean. heurtune's choice, used throughout
this module:

* The loop is broken at the **plant input** (the pump-voltage deviations ``du``). With the
  linearised plant ``P(s) = (sI - A)^-1 B`` (``du -> w``, the four measured deviations
  ``w = dx = [dy1, dy2, dh3, dh4]``) and the controller ``K(s) = C_c (sI - A_c)^-1 B_c + D_c``
  (``w -> du``), the loop is ``du = K w``: the controller output already contains the minus
  signs of the feedback (``-K_lqr dx`` and ``e = -dy``). In the negative-feedback convention
  of Bode and Nyquist margins (closed loop ``(I + L)^-1``) the return ratio at the plant input
  is therefore

      L(s) = -K(s) P(s)        (2 x 2)

* :func:`return_ratio` gives that 2 x 2 ``L``. Its off-diagonal elements are couplings, not
  loops (closing them alone closes nothing), so their "margins" are formal numbers (negative
  phase margins, gain margins below 0 dB). They are not what the thesis tables need.

* **Interaction loop "input i, output j"** (:func:`element_loop`, used by :func:`loop_margins`
  for all four pairs): the loop through the controller's *element* from measured level ``j``
  to pump ``i``, ``k_ij(s) = K(s)[i, j]``, with every other path of controller and plant left
  connected. Breaking the loop at that element's output, the rest of the loop is the plant
  from pump ``i`` to level ``j`` with the remaining controller ``K' = K - k_ij e_i e_j^T`` in
  feedback, so

      L_ij(s) = -k_ij(s) [(I - P(s) K'(s))^-1 P(s)]_{j, i}

  Why this definition: (1) it is a true SISO loop for every pair, and closing it gives back
  exactly the whole closed loop, so its Nyquist plot decides closed-loop stability (with the
  open-loop RHP poles counted in ``open_loop_unstable_poles``) and its gain and phase margins
  are the gain factor and the phase lag that element alone tolerates; (2) for a decentralised
  (diagonal) controller and a diagonal pair it is the classical "loop ``i`` with the other loop
  closed" (equivalent/effective open loop of decentralised control), and it extends that to the
  full state-feedback FOLQI/IOLQI and to the cross paths; (3) the alternative with all other
  paths *open* (``-k_ij P_ji``) drops the state feedback and the other pump, which are always
  present, and its closure is no loop that exists. On the thesis' CS/FOLQI/min gains the pump
  loops (1, 1) and (2, 2) cross over at 1.02 and 2.24 rad/s (thesis Table 5.8: 1.03 and 2.27),
  with phase margins 20.3 and 21.5 deg; the cross elements (1, 2) and (2, 1) are only the
  small state-feedback gains on the other level, and with the integral action of the other
  pump closed their loop gains stay below 1e-3 and their phase never reaches -180 deg: no
  gain or phase crossover, infinite margins, which here means that no phase lag and no gain
  increase of a cross path alone can destabilise the loop. Like all margins they describe a
  *stable* closed loop (check :func:`multivariable_margins` or the evaluation's reason).

:func:`multivariable_margins` adds what does decide stability of the MIMO loop: the largest real
part of the closed-loop eigenvalues, loop-at-a-time margins (one pump's loop broken, the other
closed) and the return-difference (disk-type) margin ``min_w sigma_min(I + L(jw))``.

The frequency response is sampled densely (``POINTS_PER_DECADE`` log-spaced points) over a
range that extends two decades beyond the slowest and the fastest pole of the loop, so both
the Oustaloup filter's slow (~1e-3 rad/s) and fast (~700 rad/s) poles are covered. A crossover
is bracketed where the samples change sign, as python-control's
:func:`control.stability_margins` brackets them, and found by Brent's method on the exact
response ``L(jw)`` rather than on a spline through the samples: exact to 2e-12 rad/s. The
response is SLICOT's TB05AD method (Hessenberg form once, one Hessenberg solve per frequency),
compiled over the whole grid (:mod:`heurtune.objectives.qtp.margins_kernels`) where
python-control calls TB05AD once per frequency from Python (docs/speed_history.md).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from heurtune.objectives.qtp.margins_kernels import hessenberg_response
from heurtune.objectives.qtp.model import linearise, operating_point

__all__ = ["loop_margins", "multivariable_margins", "siso_margins", "return_ratio", "element_loop",
           "frequency_grid", "MultivariableMargins", "MARGIN_COLUMNS", "ELEMENT_LOOP"]

POINTS_PER_DECADE = 200
MARGIN_COLUMNS = ("input", "output", "gain_crossover_rad_s", "phase_margin_deg",
                  "phase_crossover_rad_s", "gain_margin_db", "n_gain_crossovers",
                  "n_phase_crossovers", "open_loop_unstable_poles", "definition")
# value of the ``definition`` column: the loop of one controller element, the rest closed
ELEMENT_LOOP = "element_loop"


def frequency_grid(poles, *, decades_beyond: float = 2.0,
                   points_per_decade: int = POINTS_PER_DECADE) -> np.ndarray:
    """Log-spaced frequencies (rad/s) covering ``poles`` with ``decades_beyond`` to spare.

    Poles at the origin are ignored when choosing the low end; without any non-zero pole the
    grid spans [1e-4, 1e4] rad/s.

    Parameters
    ----------
    poles : array_like of complex
    decades_beyond : float
        Decades added below the slowest and above the fastest non-zero pole magnitude.
    points_per_decade : int

    Returns
    -------
    numpy.ndarray
    """
    mag = np.abs(np.asarray(poles, dtype=complex))
    mag = mag[np.isfinite(mag) & (mag > 1e-12)]
    lo, hi = (mag.min(), mag.max()) if mag.size else (1.0, 1.0)
    lo = math.floor(math.log10(lo) - decades_beyond)
    hi = math.ceil(math.log10(hi) + decades_beyond)
    if mag.size == 0:
        lo, hi = -4, 4
    return np.logspace(lo, hi, int((hi - lo) * points_per_decade) + 1)


def _frequency_response(sys):
    """``w -> L(jw)`` on an array of frequencies for a SISO ``sys``: a state space by the compiled
    Hessenberg evaluation (:mod:`heurtune.objectives.qtp.margins_kernels`, what SLICOT's TB05AD,
    python-control's evaluator, does per frequency from Python), anything else by python-control."""
    import control
    import scipy.linalg

    if not isinstance(sys, control.StateSpace) or sys.nstates == 0:
        return lambda w: np.asarray(np.squeeze(sys(1j * np.asarray(w))), dtype=complex).ravel()
    A = np.asarray(sys.A, dtype=np.float64)
    H, Q = scipy.linalg.hessenberg(A, calc_q=True)
    H = np.ascontiguousarray(H)
    b = np.ascontiguousarray(Q.T @ np.asarray(sys.B, dtype=np.float64)[:, 0])
    c = np.ascontiguousarray(np.asarray(sys.C, dtype=np.float64)[0] @ Q)
    d = float(np.asarray(sys.D, dtype=np.float64)[0, 0])

    def evaluate(w):
        w = np.ascontiguousarray(w, dtype=np.float64)
        out = np.empty(w.size, dtype=np.complex128)
        hessenberg_response(H, b, c, d, w, out)
        return out

    return evaluate


def _crossings(sys, omega) -> tuple:
    """The phase crossovers (L real negative) and gain crossovers (|L| = 1) of a SISO ``sys``.

    The search of python-control's ``stability_margins`` for sampled data: a crossover lies
    between two grid points where ``arg(-L)`` (with ``Re L <= 0`` at the first) or ``|L| - 1``
    changes sign, and Brent's method finds it. Here the root is found on ``L(jw)`` itself,
    evaluated from the state space (:func:`_frequency_response`), not on a spline through the
    samples: exact to the root finder's tolerance (2e-12 rad/s) and faster per loop, the
    sampling included (``benchmarks/bench_qtp_margins.py``).

    Returns
    -------
    (w_phase, gain_margin, w_gain, phase_margin_deg) : numpy.ndarray
        Gain margins as factors ``1 / |L|``; phase margins as python-control defines them.
    """
    from scipy.optimize import brentq

    sampled = _frequency_response(sys)

    def response(w):
        return complex(sampled(np.array([w], dtype=np.float64))[0])

    with np.errstate(all="ignore"):  # a pole on the grid: an infinite sample, no interval there
        values = sampled(omega)
    finite = np.isfinite(values)
    usable = finite[:-1] & finite[1:]
    arg = np.angle(-values)
    at = np.flatnonzero((np.diff(np.sign(arg)) != 0) & usable)
    at = at[values.real[at] <= 0.0]
    w_phase = np.array([brentq(lambda w: np.angle(-response(w)), omega[i], omega[i + 1]) for i in at])
    at = np.flatnonzero((np.diff(np.sign(np.abs(values) - 1.0)) != 0) & usable)
    w_gain = np.array([brentq(lambda w: abs(response(w)) - 1.0, omega[i], omega[i + 1]) for i in at])
    with np.errstate(divide="ignore"):
        gain_margin = np.array([1.0 / abs(response(w)) for w in w_phase])
    phase_margin = np.array([np.remainder(np.angle(response(w), deg=True), 360.0) - 180.0 for w in w_gain])
    return w_phase, gain_margin, w_gain, phase_margin


def siso_margins(sys, omega=None) -> dict:
    """Gain and phase margins of a SISO loop transfer function ``L`` (closed loop ``1/(1+L)``).

    Parameters
    ----------
    sys : control.LTI
        SISO continuous-time system (state space or transfer function).
    omega : array_like, optional
        Frequencies (rad/s) on which the response is sampled; default :func:`frequency_grid`
        of the system's poles. Crossings outside it are not found.

    Returns
    -------
    dict
        ``gain_crossover_rad_s`` and ``phase_margin_deg`` at the gain crossover (|L| = 1) with
        the smallest |phase margin| (python-control's choice; ``NaN`` and ``inf`` when |L|
        never crosses 1); ``phase_crossover_rad_s`` and ``gain_margin_db`` (``20 log10(1/|L|)``)
        at the phase crossover (arg L = -180 deg, L real negative) whose gain margin is
        closest to 0 dB (``NaN`` and ``inf`` without a phase crossover); the numbers of
        crossovers found, ``n_gain_crossovers`` and ``n_phase_crossovers``.
    """
    import control

    if omega is None:
        omega = frequency_grid(control.poles(sys))
    omega = np.asarray(omega, dtype=np.float64)
    wpc, gm, wgc, pm = _crossings(sys, omega)
    out = dict(gain_crossover_rad_s=math.nan, phase_margin_deg=math.inf,
               phase_crossover_rad_s=math.nan, gain_margin_db=math.inf,
               n_gain_crossovers=int(wgc.size), n_phase_crossovers=int(wpc.size))
    if wgc.size:
        k = int(np.argmin(np.abs(pm)))
        out["gain_crossover_rad_s"] = float(wgc[k])
        out["phase_margin_deg"] = float(pm[k])
    finite = np.isfinite(gm) & (gm > 0)
    if np.any(finite):
        idx = np.flatnonzero(finite)
        k = idx[int(np.argmin(np.abs(np.log(gm[idx]))))]
        out["phase_crossover_rad_s"] = float(wpc[k])
        out["gain_margin_db"] = float(20.0 * np.log10(gm[k]))
    return out


def _plant_and_controller(problem, x, scenario):
    """Linearised (possibly perturbed) plant matrices and the controller designed for ``x``."""
    loop = problem.loop
    ctrl = loop.controller(problem.values(x))
    factor = problem.scenario(scenario).uncertainty
    if factor == 1.0:
        A, B = loop.A, loop.B
    else:
        plant = loop.plant.scaled(factor)
        A, B, _ = linearise(plant, operating_point(plant))
    return np.asarray(A), np.asarray(B), ctrl


def linear_systems(problem, x, scenario="nominal") -> dict:
    """The linear systems of a candidate as python-control ``StateSpace`` objects with named
    signals.

    Parameters
    ----------
    problem : heurtune.Problem
    x : array_like or dict
        Tuning values.
    scenario : str or Scenario
        Plant uncertainty factor taken from it (default nominal); the controller is designed on
        the nominal plant, as in every evaluation.

    Returns
    -------
    dict
        - ``"plant"``: the linearisation at the operating point, inputs ``du1, du2`` (V), states
          ``dh1..dh4`` and outputs ``w1..w4`` (cm: the measured deviations, y1, y2, h3, h4);
        - ``"controller"``: inputs ``w1..w4``, outputs ``du1, du2``, states ``z1..``;
        - ``"closed_loop"``: the loop closed with ``du = K w``, inputs ``d1, d2`` (an output
          disturbance added to the measured y1, y2, cm) and outputs ``y1, y2`` (their deviations,
          the disturbance included), ``du1, du2``;
        - ``"loop_i_j"`` for i, j in 1, 2: :func:`element_loop`, the SISO loop through the
          controller's element from level j to pump i, whose margins :func:`loop_margins`
          reports.

    Raises
    ------
    ControllerDesignError
        When the candidate has no controller.
    """
    import control

    A, B, ctrl = _plant_and_controller(problem, x, scenario)
    n, nz = A.shape[0], ctrl.A.shape[0]
    w = [f"w{i}" for i in range(1, 5)]
    du = ["du1", "du2"]
    z = [f"z{i}" for i in range(1, nz + 1)]
    plant = control.ss(A, B, np.eye(n), np.zeros((n, 2)), inputs=du, outputs=w,
                       states=[f"dh{i}" for i in range(1, n + 1)], name="plant")
    controller = control.ss(ctrl.A, ctrl.B, ctrl.C, ctrl.D, inputs=w, outputs=du, states=z, name="controller")
    # closed loop: x' = A x + B (C z + D w), z' = Ac z + Bc w, w = x + E d (E: d onto y1, y2)
    E = np.zeros((n, 2))
    E[0, 0] = E[1, 1] = 1.0
    Acl = np.block([[A + B @ ctrl.D, B @ ctrl.C], [ctrl.B, ctrl.A]])
    Bcl = np.vstack([B @ ctrl.D @ E, ctrl.B @ E])
    Ccl = np.vstack([np.hstack([np.eye(2, n), np.zeros((2, nz))]), np.hstack([ctrl.D, ctrl.C])])
    Dcl = np.vstack([np.eye(2), ctrl.D @ E])
    closed = control.ss(Acl, Bcl, Ccl, Dcl, inputs=["d1", "d2"], outputs=["y1", "y2"] + du,
                        states=[f"dh{i}" for i in range(1, n + 1)] + z, name="closed_loop")
    out = {"plant": plant, "controller": controller, "closed_loop": closed}
    for i in (1, 2):
        for j in (1, 2):
            out[f"loop_{i}_{j}"] = element_loop(problem, x, i, j, scenario)
    return out


def return_ratio(problem, x, scenario="nominal"):
    """Return ratio ``L = -K P`` at the plant input as a 2 x 2 python-control state space.

    Parameters
    ----------
    problem : heurtune.Problem
    x : array_like or dict
        Tuning values (see ``problem.names``).
    scenario : str or Scenario
        Only its ``uncertainty`` factor is used: the plant is linearised at the operating point
        of the scaled plant, the controller is designed on the nominal one (as in simulation).

    Returns
    -------
    control.StateSpace
        Inputs: signals injected at pumps 1, 2; outputs: controller commands for pumps 1, 2.
        ``L[j, i]`` is the "input i, output j" element (python-control indexes output first).
    """
    import control

    A, B, ctrl = _plant_and_controller(problem, x, scenario)
    P = control.ss(A, B, np.eye(4), np.zeros((4, B.shape[1])))
    if ctrl.n_states:
        K = control.ss(ctrl.A, ctrl.B, ctrl.C, ctrl.D)
    else:
        K = control.ss([], [], [], ctrl.D)
    return -K * P


def element_loop(problem, x, input, output, scenario="nominal"):
    """Loop transfer function of the controller element from level ``output`` to pump ``input``.

    The controller ``du = K(s) w`` is split into the SISO element ``k = K[input, output]`` (from
    the measured level ``y_output`` to pump ``input``'s command) and the rest ``K' = K - k e_i
    e_j^T``, which stays connected. Cutting the element's output and injecting ``v`` there, the
    signal returned by the element is ``r = k y_j`` with ``y = (I - P K')^-1 P e_i v``, so in the
    negative-feedback convention of Bode and Nyquist margins (closed loop ``1 / (1 + L)``)

        L_ij(s) = -k(s) [(I - P(s) K'(s))^-1 P(s)]_{j, i}

    Closing it (``v = r``) gives back the whole closed loop, for every pair.

    Parameters
    ----------
    problem : heurtune.Problem
    x : array_like or dict
        Tuning values (see ``problem.names``).
    input, output : int
        Pump (1 or 2) and measured level (1 or 2).
    scenario : str or Scenario
        Plant uncertainty factor taken from it (default nominal), as :func:`return_ratio`.

    Returns
    -------
    control.StateSpace
        SISO, states ``[plant (4), controller (nz), copy of the controller for the element (nz)]``
        (not minimal: the copy's modes not reached by the element are cancelled).

    Raises
    ------
    ValueError
        When ``input`` or ``output`` is not 1 or 2.
    """
    import control

    if input not in (1, 2) or output not in (1, 2):
        raise ValueError(f"input and output must be 1 or 2, got input={input!r}, output={output!r}")
    A, B, ctrl = _plant_and_controller(problem, x, scenario)
    i, j = input - 1, output - 1
    n, m = A.shape[0], B.shape[1]
    nz = ctrl.n_states
    Ac = np.asarray(ctrl.A, dtype=np.float64).reshape(nz, nz)
    Bc = np.asarray(ctrl.B, dtype=np.float64).reshape(nz, n)
    Cc = np.asarray(ctrl.C, dtype=np.float64).reshape(m, nz)
    Dc = np.asarray(ctrl.D, dtype=np.float64)
    ej = np.zeros(n)
    ej[j] = 1.0
    Dr = Dc.copy()
    Dr[i, j] = 0.0  # the rest of the controller, static part
    bi = B[:, i]
    # x' = (A + B Dr) x + B Cc z - b_i (Cc_i z_e) + b_i v;  z' = Ac z + Bc x;
    # z_e' = Ac z_e + Bc_j x_j;  element output r = Cc_i z_e + Dc_ij x_j;  L output -r
    Ael = np.zeros((n + 2 * nz, n + 2 * nz))
    Ael[:n, :n] = A + B @ Dr
    Ael[:n, n:n + nz] = B @ Cc
    Ael[:n, n + nz:] = -np.outer(bi, Cc[i])
    Ael[n:n + nz, :n] = Bc
    Ael[n:n + nz, n:n + nz] = Ac
    Ael[n + nz:, :n] = np.outer(Bc[:, j], ej)
    Ael[n + nz:, n + nz:] = Ac
    Bel = np.concatenate([bi, np.zeros(2 * nz)])[:, None]
    Cel = -np.concatenate([Dc[i, j] * ej, np.zeros(nz), Cc[i]])[None, :]
    return control.ss(Ael, Bel, Cel, np.zeros((1, 1)))


def loop_margins(problem, x, scenario="nominal", omega=None) -> pd.DataFrame:
    """Margins of the four interaction loops "input i, output j" (thesis Tables 4.11, 5.8-5.10).

    The loop of the pair (pump ``i``, level ``j``) is :func:`element_loop`: the controller's
    element from level ``j`` to pump ``i``, with every other path of the controller and plant
    connected (see the module docstring for why). Its gain margin is the factor by which that
    element alone may grow, its phase margin the lag it tolerates, before the closed loop
    becomes unstable (Nyquist, given ``open_loop_unstable_poles``).

    Parameters
    ----------
    problem : heurtune.Problem
    x : array_like or dict
        Tuning values.
    scenario : str or Scenario
        Plant uncertainty factor taken from it (default nominal).
    omega : array_like, optional
        Frequency grid (rad/s); default two decades beyond the loop's slowest and fastest poles.

    Returns
    -------
    pandas.DataFrame
        One row per (input, output) in (1, 1), (1, 2), (2, 1), (2, 2) with the columns
        ``MARGIN_COLUMNS``: ``gain_crossover_rad_s``, ``phase_margin_deg`` (``inf`` and ``NaN``
        crossover when |L| never reaches 1: no phase error of that element alone can
        destabilise the loop), ``phase_crossover_rad_s``, ``gain_margin_db`` (``inf`` and
        ``NaN`` crossover without a phase crossover), the counts of crossovers found,
        ``open_loop_unstable_poles`` (poles of ``L`` with positive real part: the loop with
        that element removed; the margins certify stability only when it is 0) and
        ``definition`` (``"element_loop"``).

    Raises
    ------
    ControllerDesignError
        When the controller cannot be designed for ``x``.
    """
    import control

    rows = []
    for i in (1, 2):
        for j in (1, 2):
            L = element_loop(problem, x, i, j, scenario)
            poles = control.poles(L)
            w = frequency_grid(poles) if omega is None else omega
            row = {"input": i, "output": j}
            row.update(siso_margins(L, w))
            row["open_loop_unstable_poles"] = int(np.sum(poles.real > 1e-9 * max(1.0, np.max(np.abs(poles)))))
            row["definition"] = ELEMENT_LOOP
            rows.append(row)
    return pd.DataFrame(rows, columns=list(MARGIN_COLUMNS))


@dataclasses.dataclass(frozen=True)
class MultivariableMargins:
    """Stability of the 2 x 2 loop broken at the plant input.

    Only ``max_real_eig`` (and ``stable``) decides stability. The frequency-domain numbers are
    robustness margins *of a stable loop*: when ``stable`` is False they are still computed but
    mean nothing (e.g. the thesis' minimum-phase gains on the ``nmp`` plant give positive
    single-loop phase margins and an unstable MIMO loop). The open loop ``L`` is stable for the
    ``direct`` Oustaloup realisation (finite DC gain), so a stable closed loop means
    ``det(I + L(jw))`` does not encircle the origin.

    Attributes
    ----------
    max_real_eig : float
        Largest real part of the closed-loop eigenvalues (linearised plant and controller);
        negative means stable.
    stable : bool
        ``max_real_eig < 0``.
    return_difference_min_sv : float
        ``s = min_w sigma_min(I + L(jw))`` over the grid. If the loop is stable, it stays
        stable under any simultaneous, independent change of the two pump gains within
        ``disk_gain_margin_db`` or of their phases within ``disk_phase_margin_deg``
        (Lehtomaki et al., 1981).
    return_difference_freq : float
        Frequency (rad/s) of that minimum.
    disk_gain_margin_db : (float, float)
        Guaranteed simultaneous gain margins ``20 log10(1/(1+s))`` and ``20 log10(1/(1-s))``
        (upper ``inf`` when ``s >= 1``).
    disk_phase_margin_deg : float
        Guaranteed simultaneous phase margin ``2 arcsin(s/2)`` (deg).
    loop_at_a_time : pandas.DataFrame
        Margins of each pump's loop broken alone with the other pump's loop closed
        (columns ``input`` and those of :func:`siso_margins`): the classical loop-at-a-time
        margins, ``L_ii - L_io L_oi / (1 + L_oo)``.
    """

    max_real_eig: float
    stable: bool
    return_difference_min_sv: float
    return_difference_freq: float
    disk_gain_margin_db: tuple
    disk_phase_margin_deg: float
    loop_at_a_time: pd.DataFrame


def multivariable_margins(problem, x, scenario="nominal", omega=None) -> MultivariableMargins:
    """Closed-loop stability and MIMO margins of the loop broken at the plant input.

    Parameters
    ----------
    problem : heurtune.Problem
    x : array_like or dict
    scenario : str or Scenario
        Plant uncertainty factor taken from it (default nominal).
    omega : array_like, optional
        Frequency grid (rad/s); default as :func:`loop_margins`.

    Returns
    -------
    MultivariableMargins
    """
    import control

    A, B, ctrl = _plant_and_controller(problem, x, scenario)
    Acl = ctrl.closed_loop_matrix(A, B)
    max_eig = float(np.max(np.linalg.eigvals(Acl).real)) if np.all(np.isfinite(Acl)) else math.inf

    L = return_ratio(problem, x, scenario)
    if omega is None:
        omega = frequency_grid(control.poles(L))
    omega = np.asarray(omega, dtype=np.float64)
    resp = np.asarray(control.frequency_response(L, omega).complex)  # (2, 2, n_w)
    F = np.eye(2)[:, :, None] + resp
    sv = np.linalg.svd(np.moveaxis(F, -1, 0), compute_uv=False)[:, -1]
    k = int(np.argmin(sv))
    s = float(sv[k])
    gm_lo = 20.0 * math.log10(1.0 / (1.0 + s))
    gm_hi = 20.0 * math.log10(1.0 / (1.0 - s)) if s < 1.0 else math.inf
    pm = math.degrees(2.0 * math.asin(min(s, 2.0) / 2.0))

    # Loop-at-a-time: pump i's loop broken, pump o's closed (du_o = K_o w).
    nz = ctrl.n_states
    rows = []
    for i in (0, 1):
        o = 1 - i
        Ai = np.block([[A + np.outer(B[:, o], ctrl.D[o]), np.outer(B[:, o], ctrl.C[o])],
                       [ctrl.B, ctrl.A]]) if nz else A + np.outer(B[:, o], ctrl.D[o])
        Bi = np.concatenate([B[:, i], np.zeros(nz)])[:, None]
        Ci = -np.concatenate([ctrl.D[i], ctrl.C[i]])[None, :]
        row = {"input": i + 1}
        row.update(siso_margins(control.ss(Ai, Bi, Ci, 0.0), omega))
        rows.append(row)
    return MultivariableMargins(
        max_real_eig=max_eig, stable=bool(max_eig < 0.0), return_difference_min_sv=s,
        return_difference_freq=float(omega[k]), disk_gain_margin_db=(gm_lo, gm_hi),
        disk_phase_margin_deg=pm, loop_at_a_time=pd.DataFrame(rows),
    )
