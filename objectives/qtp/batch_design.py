"""Controller design of a whole batch of candidates with stacked numpy calls (device ``cpu-batch`` and ``gpu``).

One candidate's design (:func:`heurtune.objectives.qtp.structures.build_controller`, the
stability check, the discretisation) is some forty small numpy and LAPACK calls, about 0.7 ms
of which little is arithmetic. Here each step runs once for the batch on arrays with a leading
candidate axis:

* :func:`lqr_gains`: the Riccati solutions of all candidates from one stacked eigen-decomposition
  of their Hamiltonians (the stable invariant subspace from eigenvectors instead of the ordered
  Schur form of :func:`~heurtune.objectives.qtp.controllers.lqr_gain`); a candidate whose
  solution fails the same residual test is designed again by ``lqr_gain``, so the failures and
  their reasons are the one-candidate path's;
* :func:`folqi_controllers`: FOLQI and IOLQI controllers whose fractional integrators have a
  modal form (the Oustaloup zeros, poles and residues of all candidates at once); others are
  built one by one;
* :func:`stability_margins`: the closed-loop eigenvalues of all candidates of one size in one
  stacked call;
* :func:`discretise_many`: the zero-order-hold discretisation of controllers whose blocks are all
  diagonal and single-input (FOLQI, IOLQI), vectorised; others by ``discretise``.

The discretisation is the same arithmetic element by element (the tests check it bit for bit).
The Riccati gains agree with ``lqr_gain`` to about 1e-13 relative, and the closed-loop
eigenvalues are those of numpy's stacked ``eigvals``, so a batch-designed candidate's metrics
agree with the one-candidate path within the batched device's tolerance, not bit for bit.
"""

from __future__ import annotations

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.controllers import (
    _PUMP_ROWS,
    _SEGMENT_KEYS,
    N_INPUTS,
    N_MEASURED,
    RICCATI_RESIDUAL_TOL,
    ControllerDesignError,
    DiscreteController,
    LinearController,
    _error_of_pump,
    folqi_design,
    loop_state_matrix,
    lqr_gain,
)
from heurtune.objectives.qtp.oustaloup import _INTEGER_TOL

__all__ = ["lqr_gains", "folqi_controllers", "stability_margins", "discretise_many", "design_batch"]


def lqr_gains(A: np.ndarray, B: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """State-feedback gains of diagonal weights ``Q = diag(q[i])``, ``R = diag(r[i])``.

    Parameters
    ----------
    A : (n, n); B : (n, m)
    q : (k, n); r : (k, m) positive weights

    Returns
    -------
    (k, m, n) ndarray
        ``K_i = R_i^-1 B^T P_i``; NaN for a candidate whose stacked solution is not accepted
        (then :func:`~heurtune.objectives.qtp.controllers.lqr_gain` decides).
    """
    k, n = q.shape
    m = B.shape[1]
    Rinv_Bt = B.T[None, :, :] / r[:, :, None]  # (k, m, n)
    H = np.empty((k, 2 * n, 2 * n))
    H[:, :n, :n] = A
    H[:, :n, n:] = -B[None, :, :] @ Rinv_Bt
    H[:, n:, :n] = 0.0
    H[:, n:, :n][:, np.arange(n), np.arange(n)] = -q
    H[:, n:, n:] = -A.T
    K = np.full((k, m, n), np.nan)
    with np.errstate(all="ignore"):
        w, V = np.linalg.eig(H)
        stable = w.real < 0.0
        good = stable.sum(axis=1) == n
        if not good.any():
            return K
        idx = np.argsort(~stable[good], axis=1, kind="stable")[:, :n]  # the stable ones first
        # complex whatever the batch: numpy's eig returns real vectors when every eigenvalue of the
        # stack is real, and a real solve rounds otherwise than a complex one, so a candidate's
        # gains would depend on the candidates beside it
        U = np.take_along_axis(V[good], idx[:, None, :], axis=2).astype(np.complex128, copy=False)
        U11, U21 = U[:, :n, :], U[:, n:, :]
        try:
            P = np.linalg.solve(np.swapaxes(U11, 1, 2), np.swapaxes(U21, 1, 2))
        except np.linalg.LinAlgError:  # a singular U11 somewhere: leave the batch to lqr_gain
            return K
        P = np.swapaxes(P, 1, 2).real
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
        Kg = Rinv_Bt[good] @ P
        residual = np.swapaxes(A, 0, 1)[None] @ P + P @ A[None] - P @ B[None] @ Kg
        residual[:, np.arange(n), np.arange(n)] += q[good]
        BK = B[None] @ Kg
        scale = q[good].max(axis=1) + np.abs(P).max(axis=(1, 2)) * (2.0 * np.abs(A).max() + np.abs(BK).max(axis=(1, 2)))
        ok = np.abs(residual).max(axis=(1, 2)) <= RICCATI_RESIDUAL_TOL * scale
    rows = np.flatnonzero(good)
    K[rows[ok]] = Kg[ok]
    return K


def _layout(alpha: np.ndarray, realisation: str):
    """Per alpha, the integrator count and whether alpha is an integer (no Oustaloup filter), as
    :func:`~heurtune.objectives.qtp.oustaloup.fractional_integrator` realises it."""
    n_int = np.floor(alpha + _INTEGER_TOL)
    integer = np.abs(alpha - n_int) <= _INTEGER_TOL
    if realisation != "direct":
        n_int = np.where(integer, n_int, n_int + 1)
    return n_int.astype(np.int64), integer


def _modal_integrators(alpha: np.ndarray, n_int: int, integer: bool, order: int, band, realisation: str):
    """Poles, residues and direct terms ``(poles (k, s), residues (k, s), d (k,))`` of
    ``1 / s^alpha`` for alphas of one layout with at most one integrator (the partial fractions
    of :meth:`~heurtune.objectives.qtp.oustaloup.FractionalIntegrator.modal`)."""
    k = alpha.size
    if integer:
        return np.zeros((k, n_int)), np.ones((k, n_int)), np.zeros(k)  # 1/s, or nothing for alpha = 0
    frac = alpha - np.floor(alpha + _INTEGER_TOL)
    r = -frac if realisation == "direct" else 1.0 - frac
    wb, wh = (float(v) for v in band)
    mu = wh / wb
    j = np.arange(-order, order + 1, dtype=np.float64)
    m = 2 * order + 1
    zeros = -(wb * mu ** ((j[None, :] + order + 0.5 * (1.0 - r[:, None])) / m))
    poles = -(wb * mu ** ((j[None, :] + order + 0.5 * (1.0 + r[:, None])) / m))
    gain = wh ** r
    poles = np.concatenate([poles, np.zeros((k, n_int))], axis=1)
    diff = poles[:, :, None] - poles[:, None, :]
    diff[:, np.arange(poles.shape[1]), np.arange(poles.shape[1])] = 1.0
    residues = gain[:, None] * np.prod(poles[:, :, None] - zeros[:, None, :], axis=2) / np.prod(diff, axis=2)
    d = gain if zeros.shape[1] == poles.shape[1] else np.zeros(k)
    return poles, residues, d


def folqi_controllers(kind: str, values: np.ndarray, names, A, B, *, oustaloup_order=5, band=(1e-3, 1e3),
                      realisation="direct", pairing="diagonal") -> list:
    """FOLQI or IOLQI controllers of ``values`` (k, d) named ``names``; each entry a
    LinearController or the ControllerDesignError of that candidate (as
    :func:`~heurtune.objectives.qtp.controllers.folqi_design` raises it). Candidates whose
    integrators share a modal layout are
    built together; the others (two integrators, alpha out of range, non-positive weights) one
    by one.

    Parameters
    ----------
    kind : {"folqi", "iolqi"}
    values : ndarray (k, d)
        The candidates.
    names : sequence of str
        Their variables, in column order.
    A, B : ndarray
        The plant linearisation.
    oustaloup_order, band, realisation, pairing
        FOLQI's options (``[controller]``).

    Returns
    -------
    list
        Per candidate, a LinearController or its ControllerDesignError.
    """
    col = {name: i for i, name in enumerate(names)}
    k = values.shape[0]
    q = values[:, [col[n] for n in ("Q11", "Q22", "Q33", "Q44")]]
    r = values[:, [col["R11"], col["R22"]]]
    ki = values[:, [col["Ki1"], col["Ki2"]]]
    alphas = values[:, [col["alpha1"], col["alpha2"]]] if kind == "folqi" else np.ones((k, 2))
    (n1, int1), (n2, int2) = (_layout(alphas[:, ch], realisation) for ch in (0, 1))
    vector = (np.all((alphas >= 0.1 - 1e-12) & (alphas <= 2.0 + 1e-12), axis=1)  # fractional_integrator's range
              & (n1 <= 1) & (n2 <= 1) & np.all(q > 0, axis=1) & np.all(r > 0, axis=1))
    out = [None] * k
    for i in np.flatnonzero(~vector):
        out[i] = _one(kind, dict(zip(names, values[i].tolist())), A, B, oustaloup_order, band, realisation, pairing)
    rows = np.flatnonzero(vector)
    K = lqr_gains(A, B, q[rows], r[rows])
    gains = dict(zip(rows.tolist(), K))
    groups = {}
    for i in rows:
        groups.setdefault((n1[i], int1[i], n2[i], int2[i]), []).append(i)
    for (a1, i1, a2, i2), members in groups.items():
        modal = [_modal_integrators(alphas[members, 0], a1, i1, oustaloup_order, band, realisation),
                 _modal_integrators(alphas[members, 1], a2, i2, oustaloup_order, band, realisation)]
        gain = np.stack([gains[i] for i in members])
        designed = []
        for j, i in enumerate(members):
            if np.isnan(gain[j, 0, 0]):  # the stacked Riccati solution was not accepted
                try:
                    gain[j] = lqr_gain(A, B, np.diag(q[i]), np.diag(r[i]))
                except ControllerDesignError as exc:
                    out[i] = exc
                    continue
            designed.append(j)
        _modal_controllers(out, [members[j] for j in designed], [(p[designed], c[designed], d[designed])
                                                                  for p, c, d in modal],
                           gain[designed], ki[members][designed], pairing)
    return out


def _modal_controllers(out: list, rows: list, modal: list, gain: np.ndarray, ki: np.ndarray, pairing: str) -> None:
    """The FOLQI or IOLQI controllers (into ``out[rows]``) of candidates whose two integrators are in
    partial fractions of one layout: ``modal`` per pump ``(poles, residues, d)`` with a row per
    candidate, ``gain`` their LQR gains (k, 2, 4), ``ki`` their integral gains (k, 2). The
    matrices of all of them are written at once, by the element-wise arithmetic of
    :func:`~heurtune.objectives.qtp.controllers.folqi_design`, and each controller carries its
    modal form as that design's does (so the continuous loop reads it without deriving it)."""
    k = len(rows)
    if k == 0:
        return
    sizes = [p.shape[1] for p, _, _ in modal]
    nz = sum(sizes)
    blocks = ((0, sizes[0]), (sizes[0], nz))
    errs = [_error_of_pump(pairing, ch) for ch in range(N_INPUTS)]
    lam = np.concatenate([p for p, _, _ in modal], axis=1)
    Ac = np.zeros((k, nz, nz))
    Ac[:, np.arange(nz), np.arange(nz)] = lam
    Bc = np.zeros((k, nz, N_MEASURED))
    Cc = np.zeros((k, N_INPUTS, nz))
    Dc = -gain
    for ch, ((start, stop), (_, residues, d), err) in enumerate(zip(blocks, modal, errs)):
        Bc[:, start:stop, err] = -1.0
        Cc[:, ch, start:stop] = ki[:, ch, None] * residues
        Dc[:, ch, err] -= ki[:, ch] * d
    b = np.full(nz, -1.0)
    col = np.repeat(np.array(errs, dtype=np.int64), sizes)
    channel = np.repeat(np.arange(N_INPUTS, dtype=np.int64), sizes)
    for arr in (Ac, Bc, lam, b, col, channel):  # read-only, as the one-candidate design's
        arr.flags.writeable = False
    for j, i in enumerate(rows):
        parts = tuple(("modal", lam[j, start:stop], Bc[j, start:stop, err], Cc[j, :, start:stop], err, ch)
                      for ch, ((start, stop), err) in enumerate(zip(blocks, errs)))
        out[i] = LinearController(Ac[j], Bc[j], Cc[j], Dc[j], blocks, (0, 1), modal=parts,
                                  modal_arrays=(lam[j], b, col, channel))


def _one(kind, values, A, B, order, band, realisation, pairing):
    """One FOLQI or IOLQI design, its error returned instead of raised (a ConfigError of a
    candidate's values as ``invalid_parameter``, as :meth:`Problem._design` counts it)."""
    alphas = (values["alpha1"], values["alpha2"]) if kind == "folqi" else (1.0, 1.0)
    return _returned(lambda: folqi_design(values, A, B, alphas, order, band, realisation, pairing))


def _returned(design):
    """``design()``, or its ControllerDesignError returned (a ConfigError as
    ``invalid_parameter``)."""
    try:
        return design()
    except ControllerDesignError as exc:
        return exc
    except ConfigError:
        return ControllerDesignError("invalid_parameter")


def stability_margins(loop, ctrls) -> np.ndarray:
    """Largest real part of each controller's linearised closed-loop eigenvalues (as
    :meth:`ClosedLoop.stability_margin`), minimal controllers of one size in one stacked call.

    Parameters
    ----------
    loop : ClosedLoop
    ctrls : sequence of LinearController

    Returns
    -------
    ndarray
        One margin per controller (negative: stable).
    """
    out = np.empty(len(ctrls))
    by_size = {}
    for i, ctrl in enumerate(ctrls):
        if ctrl.minimal:
            by_size.setdefault(ctrl.n_states, []).append(i)
        else:
            out[i] = loop.stability_margin(ctrl)
    for members in by_size.values():
        M = _closed_loop_matrices(loop.A, loop.B, [ctrls[i] for i in members])
        finite = np.isfinite(M).all(axis=(1, 2))
        margins = np.full(len(members), np.inf)
        if finite.any():
            try:
                margins[finite] = np.linalg.eigvals(M[finite]).real.max(axis=1)
            except np.linalg.LinAlgError:  # leave the stack to the one-candidate check
                margins[finite] = [loop.stability_margin(ctrls[members[j]]) for j in np.flatnonzero(finite)]
        out[members] = margins
    return out


def _closed_loop_matrices(A: np.ndarray, B: np.ndarray, ctrls) -> np.ndarray:
    """``np.stack([c.closed_loop_matrix(A, B) for c in ctrls])`` for minimal controllers of one
    size, assembled for the stack at once by :func:`~heurtune.objectives.qtp.controllers.loop_state_matrix`."""
    return loop_state_matrix(A, B, *(np.stack([getattr(c, name) for c in ctrls]) for name in "ABCD"))


def _modal_pattern(ctrl) -> tuple | None:
    """The layout of a controller whose blocks are all diagonal and read one measured signal,
    or None (then it is discretised on its own)."""
    if not ctrl.blocks:
        return None
    cols = []
    for start, stop in ctrl.blocks:
        A = ctrl.A[start:stop, start:stop]
        c = np.flatnonzero(ctrl.B[start:stop].any(axis=0))
        if len(c) != 1 or np.count_nonzero(A) != np.count_nonzero(A.diagonal()):
            return None
        cols.append(int(c[0]))
    return ctrl.blocks, ctrl.block_channel, tuple(cols)


def discretise_many(ctrls, dt: float) -> list:
    """``[ctrl.discretise(dt) for ctrl in ctrls]``, the modal ones of one layout in one pass
    (the same element-wise arithmetic as :meth:`LinearController.discretise`).

    Parameters
    ----------
    ctrls : sequence of LinearController
    dt : float
        The sample period.

    Returns
    -------
    list of DiscreteController
    """
    out = [None] * len(ctrls)
    groups = {}
    for i, ctrl in enumerate(ctrls):
        pattern = _modal_pattern(ctrl)
        if pattern is None:
            out[i] = ctrl.discretise(dt)
        else:
            groups.setdefault(pattern, []).append(i)
    for (blocks, channels, cols), members in groups.items():
        lam = np.stack([ctrls[i].A.diagonal() for i in members])
        b = np.stack([np.concatenate([ctrls[i].B[s:e, c] for (s, e), c in zip(blocks, cols)]) for i in members])
        C = np.stack([ctrls[i].C for i in members])
        col = np.concatenate([np.full(e - s, c, dtype=np.int64) for (s, e), c in zip(blocks, cols)])
        chan = np.concatenate([np.full(e - s, ch, dtype=np.int64) for (s, e), ch in zip(blocks, channels)])
        x = lam * dt
        zero = x == 0.0
        phi = np.where(zero, dt, np.expm1(x) / np.where(zero, 1.0, lam))
        a, b = np.exp(x), phi * b
        c0, c1 = C[:, 0, :], C[:, 1, :]
        unit0 = (col == 0) & (c1 == 0.0) & (c0 != 0.0)
        unit1 = (col == 1) & (c0 == 0.0) & (c1 != 0.0)
        b = np.where(unit0, b * c0, np.where(unit1, b * c1, b))
        key = np.where(unit0, 0, np.where(unit1, 1, 2))
        C = np.where((unit0 | unit1)[:, None, :], unit1[:, None, :] == _PUMP_ROWS[None], C)
        for j, i in enumerate(members):
            perm = np.argsort(key[j], kind="stable")
            out[i] = DiscreteController(ad=a[j, perm], bd=b[j, perm], state_input=col[perm], Ad=np.zeros((0, 0)),
                                        Bd=np.zeros((0, N_MEASURED)), Cc=np.ascontiguousarray(C[j][:, perm]),
                                        Dc=np.ascontiguousarray(ctrls[i].D), state_channel=chan[perm],
                                        segments=np.searchsorted(key[j, perm], _SEGMENT_KEYS), dt=dt)
    return out


def design_batch(loop, names, X) -> tuple:
    """Design and check every candidate of ``X`` (k, d) for ``loop``: the controllers (None
    where there is none), the reasons ("" when designed and stable) and the margins (for the
    unstable ones), as :meth:`heurtune.objectives.qtp.problem.Problem._design` gives them one
    by one. Candidates with non-finite values get ``invalid_parameter``.

    Parameters
    ----------
    loop : ClosedLoop
    names : sequence of str
        The variables, in column order.
    X : ndarray (k, d)

    Returns
    -------
    tuple
        ``(controllers, reasons, margins)``, one entry per candidate.
    """
    k = X.shape[0]
    ctrls = [None] * k
    reasons = np.full(k, "", dtype=object)
    margins = np.zeros(k)
    finite = np.all(np.isfinite(X), axis=1)
    reasons[~finite] = "invalid_parameter"
    rows = np.flatnonzero(finite)
    batched = loop.structure.batch_design
    if batched is not None:
        built = batched(X[rows], names, loop.plant_linearisation, loop.options)
    else:  # one by one, as Problem._design does
        built = [_returned(lambda i=i: loop.controller(dict(zip(names, X[i].tolist())))) for i in rows]
    designed = []
    for i, c in zip(rows, built):
        if isinstance(c, ControllerDesignError):
            reasons[i] = c.reason
        else:
            designed.append((i, c))
    if designed:
        m = stability_margins(loop, [c for _, c in designed])
        for (i, c), mi in zip(designed, m):
            if mi < 0.0:
                ctrls[i] = c
            else:
                reasons[i], margins[i] = "unstable", mi
    return ctrls, reasons, margins

