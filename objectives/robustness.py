"""Robust-stability analysis: spectral-radius test and the Kharitonov-Hurwitz theorem.

Two independent tools used by the TITO coupled-tank papers (REFERENCE.md section 6, paper 000
sec. IV) to certify a tuned controller. Nothing here knows about a particular plant: the
frequency-domain test works on frequency responses (callables of ``w`` or arrays) and the
polynomial tests work on coefficient arrays.

Frequency domain (multiplicative uncertainty)
    For the loop ``y = G u``, ``u = -K y`` with ``m`` inputs and outputs, the complementary
    sensitivities are ``T_o = G K (I + G K)^-1`` (output side) and ``T_i = K G (I + K G)^-1``
    (input side; equal to ``K (I + G K)^-1 G``, the paper's ``-T_MI`` of eq. 38).
    With multiplicative input uncertainty ``G_p = G (I + W_i Delta_i)`` or output uncertainty
    ``G_p = (I + W_o Delta_o) G``, ``Delta`` diagonal with ``|delta_k| <= 1``, the uncertainty
    sees ``M = -W T``. :func:`spectral_radius_test` returns ``rho(W T(jw))`` (the quantity the
    paper plots, eq. 42-43) and ``sigma_max(W T(jw))`` (the small-gain bound) on the grid.

Polynomials (Kharitonov)
    Every polynomial here is a 1-D coefficient array ordered **highest power first** (the
    ``numpy.polyval`` / ``numpy.roots`` / ``scipy.signal`` convention), also for the interval
    bounds of :func:`kharitonov_polynomials` and the Pade numerator and denominator.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping

import numpy as np

from heurtune.core.errors import ConfigError

__all__ = [
    "KharitonovResult",
    "SpectralRadiusResult",
    "complementary_sensitivity",
    "frequency_response",
    "hurwitz_determinants",
    "hurwitz_matrix",
    "interval_characteristic_polynomial",
    "is_hurwitz",
    "kharitonov_polynomials",
    "kharitonov_test",
    "max_singular_value",
    "pade",
    "spectral_radius",
    "spectral_radius_test",
]

_MAX_BOX_PARAMS = 16


# ----------------------------------------------------------------------------------------------
# Frequency-domain test
# ----------------------------------------------------------------------------------------------


def _grid(w) -> np.ndarray:
    try:
        arr = np.asarray(w, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"w must be an array of frequencies, got {w!r}") from None
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ConfigError("w must be a non-empty array of finite frequencies >= 0")
    return arr


def _as_stack(arr: np.ndarray, n: int, name: str) -> np.ndarray | None:
    """Shape an evaluated response as (n, m, m); None when the layout is not recognised."""
    if arr.ndim == 0:
        return np.broadcast_to(arr.reshape(1, 1, 1), (n, 1, 1))
    if arr.ndim == 1 and arr.shape[0] == n:
        return arr.reshape(n, 1, 1)
    if arr.ndim == 2 and arr.shape[0] == arr.shape[1]:
        return np.broadcast_to(arr, (n,) + arr.shape)
    if arr.ndim == 3:
        if arr.shape[0] == n and arr.shape[1] == arr.shape[2]:
            return arr
        if arr.shape[-1] == n and arr.shape[0] == arr.shape[1]:
            return np.moveaxis(arr, -1, 0)
    return None


def frequency_response(F, w) -> np.ndarray:
    """Evaluate a (matrix) frequency response on a grid as a complex ``(n, m, m)`` array.

    Parameters
    ----------
    F : callable or array_like
        Either a callable of the frequency ``w`` (rad/s) returning ``F(jw)``, or the values.
        Accepted layouts: a scalar (constant SISO gain), ``(n,)`` (SISO on the grid), ``(m, m)``
        (constant matrix), ``(n, m, m)`` or ``(m, m, n)``. A callable is first called with the
        whole grid; if that fails or returns an unrecognised layout it is called per frequency.
    w : array_like
        Frequencies in rad/s, shape ``(n,)``, finite and non-negative.

    Returns
    -------
    numpy.ndarray
        Complex array of shape ``(n, m, m)``.

    Raises
    ------
    ConfigError
        If the layout cannot be matched to the grid or contains non-finite values.
    """
    w = _grid(w)
    n = w.size
    out = None
    if callable(F):
        try:
            out = _as_stack(np.asarray(F(w), dtype=complex), n, "F")
        except Exception:  # noqa: BLE001 - scalar-only callables are retried per frequency
            out = None
        if out is None:
            try:
                vals = [np.asarray(F(float(wk)), dtype=complex) for wk in w]
                out = _as_stack(np.stack(vals), n, "F")
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"frequency response callable failed on the grid: {exc}") from None
    else:
        try:
            out = _as_stack(np.asarray(F, dtype=complex), n, "F")
        except (TypeError, ValueError):
            raise ConfigError(f"frequency response must be numeric, got {type(F).__name__}") from None
    if out is None:
        raise ConfigError(f"frequency response layout not understood for a grid of {n} frequencies")
    out = np.array(out, dtype=complex)
    if not np.all(np.isfinite(out)):
        raise ConfigError("frequency response contains non-finite values")
    return out


def _weight(weight, n: int, m: int, name: str) -> np.ndarray:
    """Weight as a per-frequency diagonal, shape (n, m)."""
    if callable(weight):
        raise ConfigError(f"{name} must be a number or an array, evaluate callables on the grid first")
    try:
        arr = np.asarray(weight, dtype=complex)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be numeric, got {weight!r}") from None
    if arr.ndim == 0:
        arr = np.full((n, m), arr)
    elif arr.ndim == 1 and arr.shape[0] == n:
        arr = np.repeat(arr[:, None], m, axis=1)
    elif arr.ndim == 2 and arr.shape == (n, m):
        arr = arr.copy()
    else:
        raise ConfigError(f"{name} must be a scalar, shape ({n},) or ({n}, {m}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} contains non-finite values")
    return arr


def complementary_sensitivity(Gw: np.ndarray, Kw: np.ndarray, side: str = "output") -> np.ndarray:
    """Complementary sensitivity of the loop at every grid frequency.

    Parameters
    ----------
    Gw, Kw : numpy.ndarray
        Plant and controller responses, shape ``(n, m, m)`` (see :func:`frequency_response`).
    side : {"output", "input"}
        ``"output"``: ``T_o = G K (I + G K)^-1``; ``"input"``: ``T_i = K G (I + K G)^-1``.

    Returns
    -------
    numpy.ndarray
        Shape ``(n, m, m)``. Frequencies where ``I + L`` is singular (a closed-loop pole on the
        imaginary axis) are filled with ``inf``.
    """
    if side == "output":
        L = Gw @ Kw
    elif side == "input":
        L = Kw @ Gw
    else:
        raise ConfigError(f"side must be 'output' or 'input', got {side!r}")
    eye = np.eye(L.shape[-1])
    A = eye + L
    # T = L (I + L)^-1 = I - (I + L)^-1
    out = np.empty_like(L)
    cond = np.linalg.cond(A)
    ok = np.isfinite(cond) & (cond < 1e14)
    if np.any(ok):
        out[ok] = eye - np.linalg.inv(A[ok])
    out[~ok] = np.inf
    return out


def spectral_radius(M) -> np.ndarray:
    """Spectral radius ``max_k |lambda_k(M)|`` of a matrix or a stack of matrices.

    Parameters
    ----------
    M : array_like
        Shape ``(..., m, m)``.

    Returns
    -------
    numpy.ndarray or float
        Shape ``M.shape[:-2]``; entries are ``inf`` where ``M`` is not finite.
    """
    M = np.asarray(M, dtype=complex)
    if M.ndim < 2 or M.shape[-1] != M.shape[-2]:
        raise ConfigError(f"spectral_radius needs square matrices, got shape {M.shape}")
    finite = np.all(np.isfinite(M), axis=(-2, -1))
    out = np.full(M.shape[:-2], np.inf)
    if np.any(finite):
        out[finite] = np.max(np.abs(np.linalg.eigvals(M[finite])), axis=-1)
    return out[()] if out.ndim == 0 else out


def max_singular_value(M) -> np.ndarray:
    """Largest singular value of a matrix or stack of matrices (``inf`` where not finite).

    Parameters
    ----------
    M : array_like (..., m, n)

    Returns
    -------
    ndarray
        One value per matrix.
    """
    M = np.asarray(M, dtype=complex)
    if M.ndim < 2:
        raise ConfigError(f"max_singular_value needs matrices, got shape {M.shape}")
    finite = np.all(np.isfinite(M), axis=(-2, -1))
    out = np.full(M.shape[:-2], np.inf)
    if np.any(finite):
        out[finite] = np.linalg.svd(M[finite], compute_uv=False)[..., 0]
    return out[()] if out.ndim == 0 else out


@dataclasses.dataclass(frozen=True)
class SpectralRadiusResult:
    """Outcome of :func:`spectral_radius_test` on a frequency grid.

    Attributes
    ----------
    w : numpy.ndarray
        The frequency grid (rad/s).
    rho_input, rho_output : numpy.ndarray
        ``rho(W_i T_i(jw))`` and ``rho(W_o T_o(jw))`` on the grid (paper eq. 42-43).
    sigma_input, sigma_output : numpy.ndarray
        ``sigma_max(W_i T_i(jw))`` and ``sigma_max(W_o T_o(jw))`` (small-gain bound).
    rho_input_peak, rho_output_peak, sigma_input_peak, sigma_output_peak : float
        Maxima over the grid.
    rho_input_peak_w, rho_output_peak_w, sigma_input_peak_w, sigma_output_peak_w : float
        Frequencies of those maxima.
    input_stable, output_stable : bool
        ``rho < 1`` at every grid frequency, for the input / output uncertainty.
    robustly_stable : bool
        The verdict: ``input_stable and output_stable`` (the paper's spectral-radius criterion).
    sigma_robustly_stable : bool
        ``sigma_max < 1`` at every grid frequency for both sides (sufficient small-gain test).
    """

    w: np.ndarray
    rho_input: np.ndarray
    rho_output: np.ndarray
    sigma_input: np.ndarray
    sigma_output: np.ndarray
    rho_input_peak: float
    rho_input_peak_w: float
    rho_output_peak: float
    rho_output_peak_w: float
    sigma_input_peak: float
    sigma_input_peak_w: float
    sigma_output_peak: float
    sigma_output_peak_w: float
    input_stable: bool
    output_stable: bool
    robustly_stable: bool
    sigma_robustly_stable: bool


def _peak(w: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    k = int(np.argmax(values))
    return float(values[k]), float(w[k])


def spectral_radius_test(G, K, w, weight=1.0, *, weight_input=None, weight_output=None) -> SpectralRadiusResult:
    """Robust stability under multiplicative input and output uncertainty on a frequency grid.

    Computes, at every grid frequency, the spectral radius and the largest singular value of the
    weighted complementary sensitivities ``W_i T_i`` and ``W_o T_o`` with
    ``T_i = K G (I + K G)^-1`` and ``T_o = G K (I + G K)^-1``.

    **Verdict.** ``robustly_stable`` is the criterion of paper 000 (eq. 42-43, after its ref.
    [50]): ``rho(W T(jw)) < 1`` for all grid frequencies, on both sides. This is what the papers
    plot and report, so it is the verdict used to reproduce them. Be aware of what it certifies:
    for a diagonal complex ``Delta`` with ``|delta_k| <= 1`` the structured singular value obeys
    ``rho(M) <= mu(M) <= sigma_max(M)``, so ``rho < 1`` is *necessary* for robust stability and
    is exact only for a repeated scalar perturbation ``Delta = delta I`` (the same relative error
    in every channel). The standard *sufficient* small-gain condition ``sigma_max(W T) < 1``
    (any complex ``Delta``, even full, with ``||Delta|| <= 1``) is returned as
    ``sigma_robustly_stable``. For SISO loops and for decoupled (diagonal) loops with a scalar
    weight the two coincide. Both assume the nominal closed loop is stable (not checked here)
    and are only as good as the grid (inter-grid peaks are missed).

    Parameters
    ----------
    G, K : callable or array_like
        Plant and controller frequency responses, see :func:`frequency_response` (e.g.
        ``lambda w: np.array([[g11(1j*w), ...], ...])``; evaluate delays exactly as
        ``np.exp(-1j*w*L)``). Both must have the same size ``m``.
    w : array_like
        Frequency grid in rad/s, shape ``(n,)``.
    weight : float or array_like
        Uncertainty weight ``|W(jw)|`` used for both sides unless overridden: a scalar (e.g. 0.3
        for 30 % uncertainty), a per-frequency array ``(n,)`` or per-frequency per-channel
        ``(n, m)`` (a diagonal weight).
    weight_input, weight_output : float or array_like, optional
        Side-specific weights, same layouts as ``weight``.

    Returns
    -------
    SpectralRadiusResult

    Raises
    ------
    ConfigError
        On malformed responses, grids or weights.
    """
    w = _grid(w)
    Gw = frequency_response(G, w)
    Kw = frequency_response(K, w)
    if Gw.shape != Kw.shape:
        raise ConfigError(f"plant and controller sizes differ: {Gw.shape[1:]} vs {Kw.shape[1:]}")
    n, m = Gw.shape[0], Gw.shape[1]
    Wi = _weight(weight if weight_input is None else weight_input, n, m, "weight_input")
    Wo = _weight(weight if weight_output is None else weight_output, n, m, "weight_output")
    Ti = complementary_sensitivity(Gw, Kw, "input")
    To = complementary_sensitivity(Gw, Kw, "output")
    with np.errstate(invalid="ignore"):  # inf rows (singular I + L) stay non-finite -> rho = inf
        Mi = Wi[:, :, None] * Ti  # diag(W) @ T
        Mo = Wo[:, :, None] * To
    rho_i, rho_o = spectral_radius(Mi), spectral_radius(Mo)
    sig_i, sig_o = max_singular_value(Mi), max_singular_value(Mo)
    pi, po = _peak(w, rho_i), _peak(w, rho_o)
    si, so = _peak(w, sig_i), _peak(w, sig_o)
    in_ok, out_ok = bool(np.all(rho_i < 1.0)), bool(np.all(rho_o < 1.0))
    return SpectralRadiusResult(
        w=w, rho_input=rho_i, rho_output=rho_o, sigma_input=sig_i, sigma_output=sig_o,
        rho_input_peak=pi[0], rho_input_peak_w=pi[1], rho_output_peak=po[0], rho_output_peak_w=po[1],
        sigma_input_peak=si[0], sigma_input_peak_w=si[1],
        sigma_output_peak=so[0], sigma_output_peak_w=so[1],
        input_stable=in_ok, output_stable=out_ok, robustly_stable=in_ok and out_ok,
        sigma_robustly_stable=bool(np.all(sig_i < 1.0) and np.all(sig_o < 1.0)),
    )


# ----------------------------------------------------------------------------------------------
# Hurwitz and Kharitonov
# ----------------------------------------------------------------------------------------------


def _coeffs(coeffs, name: str = "coeffs") -> np.ndarray:
    """Validated real coefficients, highest power first, normalised to a positive leading term."""
    try:
        a = np.asarray(coeffs, dtype=float).reshape(-1) if not np.iscomplexobj(coeffs) else None
    except (TypeError, ValueError):
        a = None
    if a is None:
        raise ConfigError(f"{name} must be real numbers (highest power first), got {coeffs!r}")
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} must be a non-empty array of finite numbers")
    if a[0] == 0.0:
        raise ConfigError(f"{name}: leading coefficient must be non-zero (highest power first), got {a.tolist()}")
    return a if a[0] > 0 else -a


def hurwitz_matrix(coeffs) -> np.ndarray:
    """Hurwitz matrix of ``p(s) = a_0 s^n + a_1 s^(n-1) + ... + a_n``.

    Parameters
    ----------
    coeffs : array_like
        ``[a_0, a_1, ..., a_n]``, highest power first, ``a_0 != 0``. A negative leading
        coefficient is handled by multiplying ``p`` by -1 (same roots), so that ``a_0 > 0``.

    Returns
    -------
    numpy.ndarray
        The ``n x n`` matrix with ``H[i, j] = a_(2j - i + 1)`` (0-based ``i, j``; zero outside
        ``0..n``): first row ``a_1, a_3, a_5, ...``, second ``a_0, a_2, a_4, ...``, then the
        same two rows shifted right by one column at a time. Empty ``(0, 0)`` for a constant.
    """
    a = _coeffs(coeffs)
    n = a.size - 1
    H = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            k = 2 * j - i + 1
            if 0 <= k <= n:
                H[i, j] = a[k]
    return H


def hurwitz_determinants(coeffs) -> np.ndarray:
    """Leading principal minors ``Delta_1 .. Delta_n`` of the Hurwitz matrix.

    ``Delta_1 = a_1``, ``Delta_2 = a_1 a_2 - a_0 a_3``, ..., ``Delta_n = a_n Delta_(n-1)``
    (see :func:`hurwitz_matrix` for the convention; ``a_0 > 0`` after normalisation). The pivots
    of the paper's "row-reduced Hurwitz matrix" are ``Delta_k / Delta_(k-1)``, so a sign change
    on its diagonal is the same event as a non-positive minor here.

    Parameters
    ----------
    coeffs : array_like
        Coefficients, highest power first.

    Returns
    -------
    numpy.ndarray
        Shape ``(n,)``.
    """
    H = hurwitz_matrix(coeffs)
    n = H.shape[0]
    return np.array([np.linalg.det(H[:k, :k]) for k in range(1, n + 1)], dtype=float)


def is_hurwitz(coeffs, tol: float = 0.0) -> bool:
    """Whether all roots of the polynomial lie in the open left half plane.

    Uses the Hurwitz criterion: with ``a_0 > 0`` the polynomial is Hurwitz iff every leading
    principal minor of the Hurwitz matrix is positive (``> tol``). A constant is Hurwitz.

    Parameters
    ----------
    coeffs : array_like
        Coefficients, highest power first.
    tol : float
        Minors must exceed this (default 0, strict positivity); raise it to reject near-boundary
        cases where rounding decides.

    Returns
    -------
    bool
    """
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol >= 0):
        raise ConfigError(f"tol must be a finite number >= 0, got {tol!r}")
    return bool(np.all(hurwitz_determinants(coeffs) > tol))


def _bounds(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    try:
        lo = np.asarray(lower, dtype=float).reshape(-1)
        hi = np.asarray(upper, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError("interval polynomial bounds must be arrays of real numbers") from None
    if lo.size == 0 or lo.shape != hi.shape:
        raise ConfigError(f"lower and upper must be non-empty and of equal length, got {lo.size} and {hi.size}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ConfigError("interval polynomial bounds must be finite")
    if np.any(lo > hi):
        raise ConfigError(f"lower must not exceed upper, got lower={lo.tolist()} upper={hi.tolist()}")
    if lo[0] <= 0.0 <= hi[0]:
        raise ConfigError(f"leading coefficient interval [{lo[0]:g}, {hi[0]:g}] contains 0: degree must not drop")
    if hi[0] < 0.0:  # multiply the whole family by -1 (same roots)
        lo, hi = -hi, -lo
    return lo, hi


# Sign patterns in increasing powers (s^0, s^1, s^2, ...), period 4; True = upper bound.
_PATTERNS = (
    (False, False, True, True),  # K1: l l u u
    (True, True, False, False),  # K2: u u l l
    (False, True, True, False),  # K3: l u u l
    (True, False, False, True),  # K4: u l l u
)


def kharitonov_polynomials(lower, upper) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The four Kharitonov polynomials of an interval polynomial.

    The family is ``p(s) = sum_k c_k s^k`` with ``lower[k] <= c_k <= upper[k]`` independently.

    Parameters
    ----------
    lower, upper : array_like
        Coefficient bounds, **highest power first** (same convention as :func:`hurwitz_matrix`
        and ``numpy.roots``). The leading interval must not contain 0; a negative leading
        interval is handled by negating the family.

    Returns
    -------
    tuple of 4 numpy.ndarray
        ``(K1, K2, K3, K4)``, highest power first. In increasing powers ``c_0, c_1, c_2, c_3,
        ...`` (l = lower, u = upper, pattern repeating every 4):
        K1 = l l u u, K2 = u u l l, K3 = l u u l, K4 = u l l u.
        Paper 000 (eq. 32-35) numbers them K1, K3, K4, K2 of this list.
    """
    lo, hi = _bounds(lower, upper)
    lo_inc, hi_inc = lo[::-1], hi[::-1]
    out = []
    for pat in _PATTERNS:
        use_hi = np.array([pat[k % 4] for k in range(lo_inc.size)])
        out.append(np.where(use_hi, hi_inc, lo_inc)[::-1].copy())
    return tuple(out)


@dataclasses.dataclass(frozen=True)
class KharitonovResult:
    """Outcome of :func:`kharitonov_test`.

    Attributes
    ----------
    lower, upper : numpy.ndarray
        The coefficient bounds used (highest power first, leading interval positive).
    polynomials : tuple of 4 numpy.ndarray
        K1..K4 (see :func:`kharitonov_polynomials`), highest power first.
    determinants : tuple of 4 numpy.ndarray
        Hurwitz determinants of each polynomial.
    hurwitz : tuple of 4 bool
        Whether each polynomial is Hurwitz.
    robustly_stable : bool
        True iff all four are Hurwitz (then every member of the interval family is).
    """

    lower: np.ndarray
    upper: np.ndarray
    polynomials: tuple
    determinants: tuple
    hurwitz: tuple
    robustly_stable: bool


def kharitonov_test(lower, upper, tol: float = 0.0) -> KharitonovResult:
    """Kharitonov's theorem: an interval polynomial family is Hurwitz iff its four K-polynomials are.

    Parameters
    ----------
    lower, upper : array_like
        Coefficient bounds, highest power first (see :func:`kharitonov_polynomials`).
    tol : float
        Passed to :func:`is_hurwitz`.

    Returns
    -------
    KharitonovResult
    """
    lo, hi = _bounds(lower, upper)
    polys = kharitonov_polynomials(lo, hi)
    dets = tuple(hurwitz_determinants(p) for p in polys)
    ok = tuple(is_hurwitz(p, tol) for p in polys)
    return KharitonovResult(lower=lo, upper=hi, polynomials=polys, determinants=dets, hurwitz=ok,
                            robustly_stable=all(ok))


def pade(L: float, order: int, num_order: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pade approximation of the delay ``e^(-L s)``.

    ``[p/q]`` approximant with ``q = order`` and ``p = num_order`` (default ``order``)::

        N(s) = sum_k  (p+q-k)! p! / ((p+q)! k! (p-k)!) (-L s)^k,   k = 0..p
        D(s) = sum_k  (p+q-k)! q! / ((p+q)! k! (q-k)!) ( L s)^k,   k = 0..q

    so order 1 is ``(1 - L s/2) / (1 + L s/2)``; ``N(0) = D(0) = 1``.

    Parameters
    ----------
    L : float
        Delay, ``>= 0``. ``L = 0`` returns ``([1.], [1.])``.
    order : int
        Denominator degree ``q >= 0``.
    num_order : int, optional
        Numerator degree ``p >= 0``; defaults to ``order`` (diagonal, all-pass approximant).

    Returns
    -------
    num, den : numpy.ndarray
        Coefficients, highest power first (``numpy.polyval`` / ``scipy.signal`` convention).
    """
    if isinstance(L, bool) or not isinstance(L, (int, float, np.floating, np.integer)) or not math.isfinite(L) or L < 0:
        raise ConfigError(f"delay L must be a finite number >= 0, got {L!r}")
    p = order if num_order is None else num_order
    for key, v in (("order", order), ("num_order", p)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ConfigError(f"{key} must be an integer >= 0, got {v!r}")
    q = int(order)
    p = int(p)
    if L == 0:
        return np.array([1.0]), np.array([1.0])
    f = math.factorial
    num = [f(p + q - k) * f(p) / (f(p + q) * f(k) * f(p - k)) * (-L) ** k for k in range(p + 1)]
    den = [f(p + q - k) * f(q) / (f(p + q) * f(k) * f(q - k)) * L ** k for k in range(q + 1)]
    return np.array(num[::-1], dtype=float), np.array(den[::-1], dtype=float)


def interval_characteristic_polynomial(
    poly: Callable[[dict], object], box: Mapping[str, tuple]
) -> tuple[np.ndarray, np.ndarray]:
    """Coefficient bounds of a parametrised characteristic polynomial over a parameter box.

    Evaluates ``poly(params)`` at all ``2^k`` vertices of the box and takes the element-wise
    minimum and maximum of the coefficients. This is exact when every coefficient is multilinear
    (affine in each parameter separately, e.g. ``K kp``, ``T L``), because such a function attains
    its extremes at vertices; for other dependences (``L^2``, ``1/T``, ...) the bounds may be too
    narrow and the subsequent verdict is not guaranteed. Feed the result to
    :func:`kharitonov_test`. Note that Kharitonov then treats the coefficients as independent, so
    for a dependent family a pass is sufficient (conservative) and a fail is inconclusive.

    Parameters
    ----------
    poly : callable
        ``poly(params) -> coefficients`` (highest power first), ``params`` a dict name -> value
        (e.g. built with ``numpy.polymul`` / ``numpy.polyadd`` and :func:`pade` for delays).
        Vertex results of different lengths are left-padded with zeros.
    box : mapping
        ``name -> (lo, hi)`` with ``lo <= hi``; at most 16 parameters. A degenerate interval
        ``(v, v)`` fixes a parameter.

    Returns
    -------
    lower, upper : numpy.ndarray
        Coefficient bounds, highest power first.
    """
    if not callable(poly):
        raise ConfigError(f"poly must be a callable params -> coefficients, got {type(poly).__name__}")
    if not isinstance(box, Mapping) or not box:
        raise ConfigError("box must be a non-empty mapping name -> (lo, hi)")
    if len(box) > _MAX_BOX_PARAMS:
        raise ConfigError(f"box has {len(box)} parameters, at most {_MAX_BOX_PARAMS} allowed (2^k vertices)")
    names, ranges = [], []
    for name, rng in box.items():
        try:
            lo, hi = (float(v) for v in rng)
        except (TypeError, ValueError):
            raise ConfigError(f"box['{name}'] must be a pair (lo, hi), got {rng!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
            raise ConfigError(f"box['{name}'] must be finite with lo <= hi, got ({lo:g}, {hi:g})")
        names.append(name)
        ranges.append((lo, hi) if lo < hi else (lo,))
    vals = []
    for vertex in itertools.product(*ranges):
        c = np.asarray(poly(dict(zip(names, vertex))), dtype=float).reshape(-1)
        if c.size == 0 or not np.all(np.isfinite(c)):
            raise ConfigError(f"poly returned empty or non-finite coefficients at {dict(zip(names, vertex))}")
        vals.append(c)
    size = max(c.size for c in vals)
    stack = np.array([np.concatenate([np.zeros(size - c.size), c]) for c in vals])
    return stack.min(axis=0), stack.max(axis=0)
