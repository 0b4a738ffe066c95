"""The compiled design (objectives/qtp/design_kernels.py) against the numpy code it replaced.

The references below are that code as it was (commit 210f338): numpy's solve and matmul and
scipy's wrappers of LAPACK dgees and dgeev; for the FOLQI's output matrices and the step rule's
spectral radius, the numpy and numba code of commit 789c9ae. The compiled versions call the same routines in the
same order, so the gains, margins and failures must be the same bit for bit; shipped results
depend on it (tests/runner/test_sampled_release.py pins them). A numpy or scipy whose OpenBLAS
rounded otherwise than the other's would fail here first.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
import scipy.linalg.lapack

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
def test_riccati_gain_equals_the_numpy_design_bit_for_bit(case, augmented):
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
            np.testing.assert_array_equal(got, ref)
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
def test_loop_margin_equals_the_numpy_check_bit_for_bit(kind, case, stable):
    """FOLQI, IOLQI, LQI and (non-minimal, reduced by minreal) LADR controllers of random
    candidates of the default bounds, stable and unstable."""
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
        assert loop.stability_margin(ctrl) == ref
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


def test_spectral_radius_equals_numbas_eigvals_bit_for_bit():
    """The same zgeev on the same complex copy: random 4 x 4 matrices of many scales, with real,
    complex and repeated eigenvalues, give the same bits; and the radius numpy finds."""
    rng = np.random.default_rng(5)
    mats = [rng.standard_normal((4, 4)) * 10.0 ** rng.uniform(-4, 3) for _ in range(1500)]
    mats += [np.diag([-1.0, -1.0, -2.0, -2.0]), np.eye(4, k=1) - 0.5 * np.eye(4), np.zeros((4, 4)),
             np.array([[0.0, 1.0, 0, 0], [-1.0, 0.0, 0, 0], [0, 0, 0.0, 2.0], [0, 0, -2.0, 0.0]])]
    for M in mats:
        got = design_kernels.spectral_radius(M)
        assert got == _numba_eigvals_radius(M)
        assert got == pytest.approx(np.max(np.abs(np.linalg.eigvals(M))), rel=1e-12, abs=1e-300)


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
def test_folqi_outputs_equal_the_numpy_arithmetic_bit_for_bit(realisation, pairing):
    """Orders below, at and above 1 (one Oustaloup block, a pure integrator, integer splits)."""
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
                np.testing.assert_array_equal(a, b)
