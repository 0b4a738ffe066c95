"""The compiled design (objectives/qtp/design_kernels.py) against the numpy code it replaced.

The references below are that code as it was (commit 210f338): numpy's solve and matmul and
scipy's wrappers of LAPACK dgees and dgeev; for the FOLQI's output matrices and the step rule's
spectral radius, the numpy and numba code of commit 789c9ae. The compiled versions call the same
routines in the same order, but through other wrappers (workspace sizes, matrix products of
numba's rather than numpy's), so they are two routes to one number: each comparison holds within
a tolerance taken from the problem's conditioning (docs/testing.md), and the failures (designs
without a stabilising solution, infinite margins) are the same failures.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
import scipy.linalg
import scipy.linalg.lapack
from numerics import assert_close

from heurtune.objectives.qtp import design_kernels
from heurtune.objectives.qtp.controllers import (
    RICCATI_RESIDUAL_TOL,
    ControllerDesignError,
    LinearController,
    lqr_gain,
)
from heurtune.objectives.qtp.loop import ClosedLoop
from heurtune.objectives.qtp.model import linearise, preset
from heurtune.objectives.qtp.structures import decision_names, default_bounds

_DGEES = scipy.linalg.lapack.get_lapack_funcs("gees", dtype=np.float64)
_DGEEV = scipy.linalg.lapack.get_lapack_funcs("geev", dtype=np.float64)


def _numpy_lqr_gain(A, B, Q, R):
    """The Riccati gain as numpy computed it: K, or the failure's reason text."""
    n = A.shape[0]
    try:
        Rinv_Bt = np.linalg.solve(R, B.T)
        H = np.empty((2 * n, 2 * n))
        H[:n, :n] = A
        H[:n, n:] = -B @ Rinv_Bt
        H[n:, :n] = -Q
        H[n:, n:] = -A.T
        _, sdim, _, _, Z, _, info = _DGEES(lambda re, im: re < 0.0, H, compute_v=1, sort_t=1, overwrite_a=1)
        if info != 0:
            return f"info {info}"
        if sdim != n:
            return f"{sdim} stable"
        U11, U21 = Z[:n, :n], Z[n:, :n]
        P = np.linalg.solve(U11.T, U21.T).T
    except np.linalg.LinAlgError:
        return "singular"
    P = 0.5 * (P + P.T)
    K = Rinv_Bt @ P
    residual = A.T @ P + P @ A - P @ B @ K + Q
    scale = np.abs(Q).max() + np.abs(P).max() * (2.0 * np.abs(A).max() + np.abs(B @ K).max())
    if not (np.abs(residual).max() <= RICCATI_RESIDUAL_TOL * scale):
        return "residual"
    return K


def _numpy_margin(A, B, ctrl):
    """The stability margin as numpy computed it: the loop's matrix, then dgeev."""
    M = ctrl.closed_loop_matrix(A, B)
    if not np.isfinite(M).all():
        return math.inf
    wr, _, _, _, info = _DGEEV(M, compute_vl=0, compute_vr=0, overwrite_a=1)
    return math.inf if info != 0 else float(wr.max())


def _schur_basis(A, B, Q, R):
    """The ordered Schur vectors of the Hamiltonian (their leading block U11 is inverted)."""
    H = np.block([[A, -B @ np.linalg.solve(R, B.T)], [-Q, -A.T]])
    return _DGEES(lambda re, im: re < 0.0, H, compute_v=1, sort_t=1)[4]


def _rightmost_condition(M):
    """The condition number ``1 / |y^H x|`` of M's rightmost eigenvalue (unit left and right
    eigenvectors y, x): how much a perturbation of M of norm e can move it, per e."""
    w, vl, vr = scipy.linalg.eig(M, left=True, right=True)
    k = int(np.argmax(w.real))
    y, x = vl[:, k] / np.linalg.norm(vl[:, k]), vr[:, k] / np.linalg.norm(vr[:, k])
    return 1.0 / max(abs(np.vdot(y, x)), 1e-300)


def _compiled_lqr_gain(A, B, Q, R):
    try:
        return lqr_gain(A, B, Q, R)
    except ControllerDesignError as exc:
        return exc.detail


def _augmented(A, B):
    """The LQI's plant with the two integrated errors (the 6-state Riccati problem)."""
    Aa = np.zeros((6, 6))
    Aa[:4, :4] = A
    Aa[4:, :4] = -np.eye(2, 4)
    return Aa, np.vstack([B, np.zeros((2, 2))])


@pytest.mark.parametrize("case, augmented", [("min", False), ("nmp", False), ("nmp", True), ("P+", True)])
def test_riccati_gain_agrees_with_the_numpy_design_within_its_conditioning(case, augmented):
    """The Schur method's gain is ``R^-1 B^T U21 U11^-1``: rounding in the Schur basis is
    amplified by the condition number of U11 (up to 5e7 on these random weights, 2e3 without
    the integrators), so the two routes agree to ``64 n eps cond(U11)`` normwise (measured: at
    most 6 eps cond(U11), 6e-11 relative on the worst draw)."""
    A, B, _ = linearise(preset(case))
    if augmented:
        A, B = _augmented(A, B)
    n, m = B.shape
    rng = np.random.default_rng(11)
    failures = 0
    for i in range(400):
        Q = np.diag(10.0 ** rng.uniform(-6, 3, n))
        R = np.diag(10.0 ** rng.uniform(-4, 3, m))
        if i % 5 == 0:
            Q[(i // 5) % n, (i // 5) % n] = 0.0  # unweighted states: the limits of detectability
        ref, got = _numpy_lqr_gain(A, B, Q, R), _compiled_lqr_gain(A, B, Q, R)
        if isinstance(ref, str):
            failures += 1
            assert isinstance(got, str), (i, ref)
        else:
            assert not isinstance(got, str), (i, got)
            cond = np.linalg.cond(_schur_basis(A, B, Q, R)[:n, :n])
            rtol = 64 * n * np.finfo(float).eps * cond
            assert_close(got, ref, rtol=0.0, atol=rtol * np.abs(ref).max(), err_msg=f"draw {i}",
                         because=f"64 n eps cond(U11) normwise, cond(U11) = {cond:.1e}")
    if augmented:  # unweighted integrators: some designs fail, on both sides
        assert failures >= 1


@pytest.mark.parametrize("A, B, Q, ref_kind", [
    # the unstable mode is uncontrollable: no stabilising solution (a singular U11)
    (np.array([[1.0, 0.0], [0.0, -1.0]]), np.array([[0.0], [1.0]]), np.eye(2), "singular"),
    # an uncontrollable, unweighted integrator: Hamiltonian eigenvalues at 0, fewer than n stable
    (np.array([[0.0, 0.0], [0.0, -1.0]]), np.array([[0.0], [1.0]]), np.diag([0.0, 1.0]), "stable"),
])
def test_riccati_failures_are_the_numpy_designs(A, B, Q, ref_kind):
    ref = _numpy_lqr_gain(A, B, Q, np.eye(1))
    assert isinstance(ref, str) and ref_kind in ref
    with pytest.raises(ControllerDesignError) as info:
        lqr_gain(A, B, Q, np.eye(1))
    assert info.value.reason == "riccati_failed"
    if ref_kind == "stable":
        assert info.value.detail == "1 stable Hamiltonian eigenvalues, need 2"


@pytest.mark.parametrize("kind, case, stable", [
    ("folqi", "min", {True, False}), ("folqi", "nmp", {True, False}), ("ladr", "min", {True, False}),
    ("ladr", "nmp", {True, False}),
    ("iolqi", "nmp", {False}),  # exact integrators cannot stabilise nmp (docs/thesis.md)
    ("lqi", "min", {True}),
])
def test_loop_margin_agrees_with_the_numpy_check_within_its_conditioning(kind, case, stable):
    """FOLQI, IOLQI, LQI and (non-minimal, reduced by minreal) LADR controllers of random
    candidates of the default bounds, stable and unstable. Two dgeev calls on matrices that may
    differ in their last bits (numba's products against numpy's) give rightmost real parts
    within ``kappa * eps * ||M||`` (kappa the eigenvalue's condition number) times dgeev's
    backward-error factor, a small multiple of N: the test allows ``10 N eps kappa ||M||``, and
    the verdict (stable or not) must be the same wherever the margin is larger than that."""
    loop = ClosedLoop(preset(case), kind)
    names = decision_names(kind)
    bounds = default_bounds(kind)
    rng = np.random.default_rng(3)
    margins = []
    for _ in range(120):
        try:
            ctrl = loop.controller({n: rng.uniform(*bounds[n]) for n in names})
        except ControllerDesignError:
            continue
        ref = _numpy_margin(loop.A, loop.B, ctrl)
        got = loop.stability_margin(ctrl)
        M = ctrl.closed_loop_matrix(loop.A, loop.B)
        kappa = _rightmost_condition(M)
        atol = 10 * M.shape[0] * np.finfo(float).eps * kappa * np.linalg.norm(M, 2)
        assert_close(got, ref, rtol=0.0, atol=atol, because=f"10 N eps kappa ||M||, kappa = {kappa:.1e}")
        if abs(ref) > atol:
            assert (got < 0.0) == (ref < 0.0)
        margins.append(ref)
    assert len(margins) >= 100 and {m < 0.0 for m in margins} == stable


def test_loop_margin_of_a_non_finite_controller_is_infinite():
    loop = ClosedLoop(preset("min"), "lqi")
    D = np.full((2, 4), np.nan)
    ctrl = LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ())
    assert loop.stability_margin(ctrl) == math.inf == _numpy_margin(loop.A, loop.B, ctrl)


def test_compiled_design_kernels_are_cached():
    """The LAPACK routines are named by symbol, not address, so the kernels can be cached."""
    for kernel in (design_kernels.riccati_gain, design_kernels.weighted_riccati_gain, design_kernels.loop_margin,
                   design_kernels.spectral_radius, design_kernels.modal_layout, design_kernels.folqi_outputs):
        assert kernel._cache.__class__.__name__ == "FunctionCache"


@numba.njit(cache=False)
def _numba_eigvals_radius(M):
    """The spectral radius as the step rule computed it before :func:`spectral_radius`."""
    return np.max(np.abs(np.linalg.eigvals(M.astype(np.complex128))))


def test_spectral_radius_agrees_with_numbas_eigvals_and_numpy():
    """zgeev called by symbol against numba's eigvals (zgeev through numba's own wrapper) and
    numpy's (dgeev): random 4 x 4 matrices of many scales, with real, complex and repeated
    eigenvalues. The radius is the largest |lambda|; for these draws it moves by at most
    ``eps kappa ||M||`` with kappa below about 1e2 (the repeated eigenvalues are exact on
    their triangular or block-diagonal matrices), so 1e-12 relative holds with room."""
    rng = np.random.default_rng(5)
    mats = [rng.standard_normal((4, 4)) * 10.0 ** rng.uniform(-4, 3) for _ in range(1500)]
    mats += [np.diag([-1.0, -1.0, -2.0, -2.0]), np.eye(4, k=1) - 0.5 * np.eye(4), np.zeros((4, 4)),
             np.array([[0.0, 1.0, 0, 0], [-1.0, 0.0, 0, 0], [0, 0, 0.0, 2.0], [0, 0, -2.0, 0.0]])]
    for M in mats:
        got = design_kernels.spectral_radius(M)
        assert_close(got, _numba_eigvals_radius(M), rtol=1e-12, because="eps kappa ||M|| with kappa < 1e2")
        assert_close(got, np.max(np.abs(np.linalg.eigvals(M))), rtol=1e-12, atol=1e-300,
                     because="eps kappa ||M|| with kappa < 1e2")


def _numpy_folqi_outputs(K, ki, outputs):
    """The FOLQI's output matrices as folqi_design computed them in numpy."""
    Cc = np.zeros((2, outputs[-1][4]))
    Dc = -K
    for ch, (cf, df, err, start, stop) in enumerate(outputs):
        Cc[ch, start:stop] = ki[ch] * cf
        Dc[ch, err] -= ki[ch] * df
    return Cc, Dc


@pytest.mark.parametrize("realisation", ["direct", "integer_split"])
@pytest.mark.parametrize("pairing", ["diagonal", "anti-diagonal"])
def test_folqi_outputs_agree_with_the_numpy_arithmetic(realisation, pairing):
    """Orders below, at and above 1 (one Oustaloup block, a pure integrator, integer splits).
    Each entry is one product, or one product subtracted from a gain: at most two roundings, so
    the two sides agree to ``2 eps`` of the larger operand."""
    from heurtune.objectives.qtp.controllers import _folqi_layout

    rng = np.random.default_rng(8)
    for alphas in [(0.9814, 0.8437), (1.0, 1.0), (1.5, 0.3), (1.9, 1.2), (0.1, 2.0)]:
        layout = _folqi_layout(alphas, 5, (1e-3, 1e3), realisation, pairing)
        for _ in range(20):
            K = rng.standard_normal((2, 4)) * 10.0 ** rng.uniform(-3, 2)
            ki = tuple(10.0 ** rng.uniform(-2, 1, 2))
            (c1, d1, e1, _, _), (c2, d2, e2, _, _) = layout.outputs
            got = design_kernels.folqi_outputs(K, ki[0], c1, d1, e1, ki[1], c2, d2, e2)
            for a, b in zip(got, _numpy_folqi_outputs(K, ki, layout.outputs)):
                scale = max(np.abs(K).max(), max(ki) * max(np.abs(c1).max(), np.abs(c2).max(), abs(d1), abs(d2)))
                assert_close(a, b, rtol=0.0, atol=2 * np.finfo(float).eps * scale,
                             because="one product and one subtraction per entry: 2 eps of the operands")
