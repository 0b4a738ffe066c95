"""Compiled parts of a candidate's design: the LQR gain from the Riccati equation, the
closed-loop stability margin and the FOLQI's modal layout and output matrices, each one numba
call instead of some twenty numpy and LAPACK calls from Python (orchestration in
:mod:`heurtune.objectives.qtp.controllers` and :mod:`heurtune.objectives.qtp.loop`); and the
spectral radius that the continuous loop's step rule takes of small matrices.

The arithmetic of the numpy code they replace, the same routines in the same order:

* LAPACK's ``dgees`` (the ordered Schur form) and ``dgeev`` (eigenvalues) are the routines
  ``scipy.linalg.lapack`` wraps, taken from ``scipy.linalg.cython_lapack`` and called with the
  wrapper's arguments (Fortran-ordered copies, the wrapper's default workspace sizes);
  ``zgeev`` (the spectral radius) is the routine numba's ``np.linalg.eigvals`` calls;
* the small solves and products are numba's ``np.linalg.solve`` and ``np.dot``: they call
  ``dgesv`` and ``dgemm`` from scipy's OpenBLAS, numpy's ``solve`` and ``@`` call the same
  routines from numpy's OpenBLAS;
* element-wise arithmetic and the comparisons are IEEE operations in the same order.

The two OpenBLAS builds may pick other kernels on another CPU, so the two routes are held to a
tolerance, not to the bits (docs/testing.md): ``tests/objectives/qtp/test_design_kernels.py``
compares them with the numpy implementation on thousands of weights and controllers, failures
included, the gains within ``64 n eps cond(U11)`` and the margins within ``10 N eps kappa
||M||`` (kappa the rightmost eigenvalue's condition number).
"""

from __future__ import annotations

import llvmlite.binding
import numpy as np
from numba import cfunc, njit, types
from numba.core import cgutils
from numba.extending import get_cython_function_address, intrinsic

__all__ = [
    "riccati_gain",
    "weighted_riccati_gain",
    "loop_margin",
    "spectral_radius",
    "modal_layout",
    "folqi_outputs",
    "SELECT_STABLE",
    "RICCATI_OK",
    "RICCATI_SCHUR_FAILED",
    "RICCATI_STABLE_COUNT",
    "RICCATI_RESIDUAL",
]

# riccati_gain's outcomes (the first of its returned triple)
RICCATI_OK = 0
RICCATI_SCHUR_FAILED = 1  # dgees' info (returned second) is not 0
RICCATI_STABLE_COUNT = 2  # the Hamiltonian has another number of stable eigenvalues (returned second)
RICCATI_RESIDUAL = 3  # the solution's residual is too large

# The LAPACK routines by symbol name, bound to scipy's at import: compiled code that names them
# can be cached (an address would be baked into it, and differs from process to process).
for _name in ("dgees", "dgeev", "zgeev"):
    llvmlite.binding.add_symbol(f"heurtune_{_name}", get_cython_function_address("scipy.linalg.cython_lapack", _name))
_dgees = types.ExternalFunction("heurtune_dgees", types.void(*([types.voidptr] * 15)))
_dgeev = types.ExternalFunction("heurtune_dgeev", types.void(*([types.voidptr] * 14)))
_zgeev = types.ExternalFunction("heurtune_zgeev", types.void(*([types.voidptr] * 14)))


@intrinsic
def _data(typingctx, arr):
    """The address of an array's data, for a LAPACK argument (the array must stay in use after
    the call: see :func:`_kept`)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(context.make_array(arr)(context, builder, args[0]).data, cgutils.voidptr_t)
    return types.voidptr(arr), codegen


@intrinsic
def _pointer(typingctx, address):
    """An integer address as a pointer (dgees' selection function)."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)
    return types.voidptr(address), codegen


@njit(cache=True)
def _kept(*arrays):
    """A use of ``arrays`` after a LAPACK call that wrote through their addresses (so that numba
    releases none of them before it)."""
    return len(arrays)


@cfunc(types.int32(types.CPointer(types.float64), types.CPointer(types.float64)))
def _left_half_plane(re, im):
    """dgees' selection: the stable eigenvalues (real part < 0) first."""
    return 1 if re[0] < 0.0 else 0


_V, _N, _S = ord("V"), ord("N"), ord("S")
# dgees' selection of the stable eigenvalues, for riccati_gain
SELECT_STABLE = _left_half_plane.address


@njit(cache=True)
def _ordered_schur_vectors(H, select):
    """Schur vectors of ``H`` with the eigenvalues ``select`` (a dgees selection function's
    address) first, as ``scipy.linalg.lapack.dgees(select, H, compute_v=1, sort_t=1)``:
    ``(Z, sdim, info)``."""
    n = H.shape[0]
    a = np.asfortranarray(H)
    vs = np.asfortranarray(np.empty((n, n)))
    wr, wi = np.empty(n), np.empty(n)
    jobvs, sort = np.array([_V], dtype=np.uint8), np.array([_S], dtype=np.uint8)
    size, sdim = np.array([n], dtype=np.int32), np.zeros(1, dtype=np.int32)
    lwork, info = np.array([max(3 * n, 1)], dtype=np.int32), np.zeros(1, dtype=np.int32)
    work = np.empty(max(3 * n, 1))
    bwork = np.empty(n, dtype=np.int32)
    _dgees(_data(jobvs), _data(sort), _pointer(select), _data(size), _data(a), _data(size), _data(sdim), _data(wr),
           _data(wi), _data(vs), _data(size), _data(work), _data(lwork), _data(bwork), _data(info))
    _kept(jobvs, sort, size, a, sdim, wr, wi, work, lwork, bwork, info)
    return vs, sdim[0], info[0]


@njit(cache=True)
def riccati_gain(A, B, Q, R, residual_tol, select):
    """State-feedback gain ``K = R^-1 B^T P`` of the weights ``Q``, ``R`` by the ordered Schur
    form of the Hamiltonian (the method and the checks of
    :func:`~heurtune.objectives.qtp.controllers.lqr_gain`, which reads the outcome).

    Parameters
    ----------
    A : ndarray (n, n)
    B : ndarray (n, m)
    Q : ndarray (n, n)
    R : ndarray (m, m)
    residual_tol : float
        The largest residual accepted, relative to the size of its terms.
    select : int
        The address of the selection function (:data:`SELECT_STABLE`).

    Returns
    -------
    tuple
        ``(outcome, count, K)``: ``RICCATI_OK`` and K; or a failure, with dgees' info
        (``RICCATI_SCHUR_FAILED``) or the number of stable eigenvalues
        (``RICCATI_STABLE_COUNT``) as ``count``. A singular solve raises numpy's LinAlgError.
    """
    n = A.shape[0]
    Rinv_Bt = np.linalg.solve(R, np.ascontiguousarray(B.T))
    H = np.empty((2 * n, 2 * n))
    H[:n, :n] = A
    H[:n, n:] = np.dot(-B, Rinv_Bt)
    H[n:, :n] = -Q
    H[n:, n:] = -A.T
    Z, sdim, info = _ordered_schur_vectors(H, select)
    K = np.empty((B.shape[1], n))
    if info != 0:
        return RICCATI_SCHUR_FAILED, info, K
    if sdim != n:
        return RICCATI_STABLE_COUNT, sdim, K
    P = np.linalg.solve(np.ascontiguousarray(Z[:n, :n].T), np.ascontiguousarray(Z[n:, :n].T)).T
    P = 0.5 * (P + P.T)
    K = np.dot(Rinv_Bt, np.ascontiguousarray(P))
    residual = np.dot(np.ascontiguousarray(A.T), P) + np.dot(P, A) - np.dot(np.dot(P, B), K) + Q
    scale = np.abs(Q).max() + np.abs(P).max() * (2.0 * np.abs(A).max() + np.abs(np.dot(B, K)).max())
    if not (np.abs(residual).max() <= residual_tol * scale):
        return RICCATI_RESIDUAL, 0, K
    return RICCATI_OK, 0, K


@njit(cache=True)
def weighted_riccati_gain(A, B, weights, residual_tol, select):
    """:func:`riccati_gain` of diagonal weights, given as one vector: ``Q = diag(weights[:n])``,
    ``R = diag(weights[n:])`` with ``n`` the states of ``A`` (the same arithmetic: the diagonal
    matrices hold the same values as numpy's ``np.diag`` of them)."""
    n = A.shape[0]
    return riccati_gain(A, B, np.diag(weights[:n]), np.diag(weights[n:]), residual_tol, select)


@njit(cache=True)
def loop_margin(A, B, Ac, Bc, Cc, Dc):
    """Largest real part of the eigenvalues of ``[[A + B Dc, B Cc], [Bc, Ac]]`` (the
    linearised loop of a minimal controller, as
    :func:`~heurtune.objectives.qtp.controllers.loop_state_matrix` assembles it), by LAPACK
    ``dgeev`` as ``scipy.linalg.lapack.dgeev(M, compute_vl=0, compute_vr=0)``; ``inf`` for a
    matrix with a non-finite entry or when dgeev fails."""
    n, nc = A.shape[0], Ac.shape[0]
    N = n + nc
    M = np.empty((N, N))
    M[:n, :n] = A + np.dot(B, Dc)
    if nc:
        M[:n, n:] = np.dot(B, Cc)
        M[n:, :n] = Bc
        M[n:, n:] = Ac
    if not np.isfinite(M).all():
        return np.inf
    a = np.asfortranarray(M)
    wr, wi = np.empty(N), np.empty(N)
    vl, vr = np.empty(1), np.empty(1)
    job = np.array([_N], dtype=np.uint8)
    size, ld = np.array([N], dtype=np.int32), np.ones(1, dtype=np.int32)
    lwork, info = np.array([max(4 * N, 1)], dtype=np.int32), np.zeros(1, dtype=np.int32)
    work = np.empty(max(4 * N, 1))
    _dgeev(_data(job), _data(job), _data(size), _data(a), _data(size), _data(wr), _data(wi), _data(vl), _data(ld),
           _data(vr), _data(ld), _data(work), _data(lwork), _data(info))
    _kept(job, size, a, wr, wi, vl, ld, vr, work, lwork, info)
    if info[0] != 0:
        return np.inf
    return wr.max()


@njit(cache=True)
def spectral_radius(M):
    """Largest modulus of the eigenvalues of a real square matrix (``inf`` when LAPACK fails),
    as ``np.max(np.abs(np.linalg.eigvals(M.astype(np.complex128))))`` in numba computes it: the
    same LAPACK ``zgeev`` on the same complex copy, called once with the minimal workspace.
    Numba's ``eigvals`` first asks for the optimal size; the step rule's 4 x 4 matrices do not
    use it (LAPACK runs its unblocked Hessenberg reduction and QR on them whatever the
    workspace), and the tests check the bits on thousands of them. Meant for such small
    matrices: on large ones a larger workspace selects blocked algorithms, whose rounding
    differs."""
    n = M.shape[0]
    a = np.empty((n, n), dtype=np.complex128).T  # Fortran order
    for r in range(n):
        for c in range(n):
            a[r, c] = M[r, c]
    w = np.empty(n, dtype=np.complex128)
    vl, vr = np.empty(1, dtype=np.complex128), np.empty(1, dtype=np.complex128)
    job = np.array([_N], dtype=np.uint8)
    size, ld = np.array([n], dtype=np.int32), np.ones(1, dtype=np.int32)
    lwork, info = np.array([max(2 * n, 1)], dtype=np.int32), np.zeros(1, dtype=np.int32)
    work = np.empty(max(2 * n, 1), dtype=np.complex128)
    rwork = np.empty(max(2 * n, 1))
    _zgeev(_data(job), _data(job), _data(size), _data(a), _data(size), _data(w), _data(vl), _data(ld), _data(vr),
           _data(ld), _data(work), _data(lwork), _data(rwork), _data(info))
    _kept(job, size, a, w, vl, ld, vr, work, lwork, rwork, info)
    if info[0] != 0:
        return np.inf
    return np.max(np.abs(w))


@njit(cache=True)
def modal_layout(poles1, poles2, err1, err2):
    """The FOLQI matrices that depend on the orders alone when both fractional integrators are
    in partial fractions (:func:`~heurtune.objectives.qtp.controllers._folqi_layout`): pump 1's
    poles, then pump 2's, each state reading its pump's error ``err`` (0 or 1) with weight -1
    (``e = -w``).

    Returns
    -------
    tuple
        ``(A, B, lam, b, col, channel)``: the diagonal state matrix (nz, nz), the input matrix
        (nz, 4), the poles, the input weights (-1), the measured signal each state reads and the
        pump it belongs to (int64).
    """
    n1 = poles1.size
    nz = n1 + poles2.size
    lam = np.empty(nz)
    lam[:n1] = poles1
    lam[n1:] = poles2
    A = np.zeros((nz, nz))
    B = np.zeros((nz, 4))
    b = np.full(nz, -1.0)
    col = np.empty(nz, dtype=np.int64)
    channel = np.empty(nz, dtype=np.int64)
    for i in range(nz):
        A[i, i] = lam[i]
        channel[i] = 0 if i < n1 else 1
        col[i] = err1 if i < n1 else err2
        B[i, col[i]] = -1.0
    return A, B, lam, b, col, channel


@njit(cache=True)
def folqi_outputs(K, ki1, c1, d1, err1, ki2, c2, d2, err2):
    """The FOLQI's output matrices (:func:`~heurtune.objectives.qtp.controllers.folqi_design`):
    ``C`` (2, nz) with pump r's fractional integrator (output weights ``c_r``, direct term
    ``d_r``, reading error ``err_r``) scaled by its gain ``ki_r`` in its own states, pump 1's
    first; and ``D = -K`` less ``ki_r d_r`` on the error each pump integrates. The products and
    differences of the numpy code it replaced, in the same order."""
    n1 = c1.size
    Cc = np.zeros((2, n1 + c2.size))
    Dc = -K
    for i in range(n1):
        Cc[0, i] = ki1 * c1[i]
    for i in range(c2.size):
        Cc[1, n1 + i] = ki2 * c2[i]
    Dc[0, err1] -= ki1 * d1
    Dc[1, err2] -= ki2 * d2
    return Cc, Dc
