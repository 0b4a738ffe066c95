"""Numba kernel of the continuous TITO loop (``heurtune.objectives.tito.continuous``).

Arrays in, arrays out; everything a step needs is precomputed by the caller. Signals are stored
per step as their values at the ``q`` Gauss-Lobatto nodes, in ``hist[step, signal, node]`` with
signals 0, 1 the errors ``e_1, e_2`` and 2, 3 the input disturbances. A path ``p`` is a state
space of ``nst[p]`` states driven by signal ``src[p]``: over step ``k`` it reads the stored step
``k - lag[p]`` (``h1``) and, where its delayed window is split (``split[p] = 1``), also step
``k - lag[p] + 1`` (``h2``). Its outputs at the step's nodes and its state at the step's end are
``Ox x + O1 h1 + O2 h2`` and ``Sx x + S1 h1 + S2 h2``. Paths are ordered by stage: ``bounds[0]``
to ``bounds[1]`` add to the outputs ``y``, then (once the step's errors are known) to the
decoupler outputs ``u``, then to the controller outputs ``v``, each at index ``out[p]``.
"""

import math

import numpy as np
from numba import njit

TARGET_Y = 0
TARGET_U = 1
TARGET_V = 2
# nodes per step (a cubic): a constant, so that the compiler unrolls the loops over them
Q = 4


@njit(cache=True, inline="always")
def _affine_row(X, Y, Z, p, r, n, x, hist, s, m1, m2, two):
    """Row ``r`` of path ``p``'s affine map: ``X[p, r] x + Y[p, r] h1 + Z[p, r] h2`` (``h1``,
    ``h2`` the stored steps ``m1``, ``m2`` of signal ``s``; ``h2`` only where ``two``)."""
    a = 0.0
    for j in range(n):
        a += X[p, r, j] * x[p, j]
    if m1 >= 0:
        for j in range(Q):
            a += Y[p, r, j] * hist[m1, s, j]
    if two and m2 >= 0:
        for j in range(Q):
            a += Z[p, r, j] * hist[m2, s, j]
    return a


@njit(cache=True, inline="always")
def _path_step(p, k, hist, src, split, lag, nst, Ox, O1, O2, Sx, S1, S2, x, xn, acc):
    """Add path ``p``'s outputs over step ``k`` to ``acc`` and advance its state ``x[p]`` to the
    step's end."""
    n = nst[p]
    s = src[p]
    m1 = k - lag[p]
    two = split[p] == 1
    for i in range(Q):
        acc[i] += _affine_row(Ox, O1, O2, p, i, n, x, hist, s, m1, m1 + 1, two)
    for r in range(n):
        xn[r] = _affine_row(Sx, S1, S2, p, r, n, x, hist, s, m1, m1 + 1, two)
    for r in range(n):
        x[p, r] = xn[r]


# Pade(13) coefficients and the norm bound below which it needs no scaling (Higham 2005,
# "The scaling and squaring method for the matrix exponential revisited", Table 2.3)
_PADE13 = np.array([64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
                    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
                    40840800.0, 960960.0, 16380.0, 182.0, 1.0])
_THETA13 = 5.371920351148152


@njit(cache=True)
def expm(M):
    """``exp(M)`` by scaling and squaring with the [13/13] Pade approximant (double precision
    for every norm, Higham 2005): the path matrices of the continuous loop, whose stiff
    filters make scipy's general routine slow on these small matrices."""
    n = M.shape[0]
    norm = np.max(np.sum(np.abs(M), axis=0))  # the 1-norm
    s = 0
    if norm > _THETA13:
        s = int(np.ceil(np.log2(norm / _THETA13)))
    A = M / 2.0 ** s
    b = _PADE13
    eye = np.eye(n)
    A2 = A @ A
    A4 = A2 @ A2
    A6 = A4 @ A2
    U = A @ (A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2) + b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * eye)
    V = A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2) + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * eye
    R = np.ascontiguousarray(np.linalg.solve(V - U, V + U))
    for _ in range(s):
        R = R @ R
    return R


# the range of scaling factors balance() keeps to (LAPACK's: the safe minimum over the precision)
_SAFE_MIN = 2.0 ** -1022 / 2.0 ** -52
_SAFE_MAX = 1.0 / _SAFE_MIN


@njit(cache=True)
def balance(M):
    """``(Mb, scale)`` with ``M = diag(scale) Mb diag(scale)^-1``, ``scale`` powers of 2 (so the
    similarity is exact): the scaling that LAPACK's ``gebal`` makes without permuting (each
    row and column brought near the same 2-norm, repeated until no factor changes a sum of the
    two norms by 5 %). Compiled so that a route's matrices cost no Python calls; checked against
    scipy's ``matrix_balance`` in the tests."""
    n = M.shape[0]
    A = M.copy()
    scale = np.ones(n)
    lo, hi = _SAFE_MIN * 2.0, _SAFE_MAX / 2.0
    changed = True
    while changed:
        changed = False
        for i in range(n):
            c = 0.0
            r = 0.0
            ca = 0.0
            ra = 0.0
            for j in range(n):
                c += A[j, i] * A[j, i]
                r += A[i, j] * A[i, j]
                ca = max(ca, abs(A[j, i]))
                ra = max(ra, abs(A[i, j]))
            c = math.sqrt(c)
            r = math.sqrt(r)
            if c == 0.0 or r == 0.0:
                continue
            if not math.isfinite(c + ca + r + ra):
                return M.copy(), np.ones(n)
            total = c + r
            f = 1.0
            g = r / 2.0
            while c < g and max(f, c, ca) < hi and min(r, g, ra) > lo:
                f *= 2.0
                c *= 2.0
                ca *= 2.0
                r /= 2.0
                g /= 2.0
                ra /= 2.0
            g = c / 2.0
            while g >= r and max(r, ra) < hi and min(f, c, g, ca) > lo:
                f /= 2.0
                c /= 2.0
                g /= 2.0
                ca /= 2.0
                r *= 2.0
                ra *= 2.0
            if c + r >= 0.95 * total:
                continue
            if f < 1.0 and scale[i] < 1.0 and f * scale[i] <= _SAFE_MIN:
                continue
            if f > 1.0 and scale[i] > 1.0 and scale[i] >= _SAFE_MAX / f:
                continue
            scale[i] *= f
            changed = True
            for j in range(n):
                A[i, j] *= 1.0 / f
            for j in range(n):
                A[j, i] *= f
    return A, scale


@njit(cache=True)
def transitions(A, B, length, offsets, from_nodes):
    """``E[i]``, ``H[i]``: the state of ``x' = A x + B w`` after ``offsets[i] * length``
    seconds is ``E[i] x0 + H[i] w_nodes`` for a cubic input ``w`` with values ``w_nodes`` at the
    step's nodes (Van Loan: the exponential of the system beside a chain of integrators that
    generates the input's monomials; ``from_nodes`` maps node values to the monomial
    coefficients ``w = sum a_k tau^k / k!``).

    The augmented matrix is balanced first (exact, powers of 2): a stiff filter's realisation
    puts ``1/Tf^2`` beside 1 in it, and a norm of 1e8 would cost the small entries of the
    exponential their relative accuracy in the squarings. An offset of 0 gives ``E = I``,
    ``H = 0`` without an exponential."""
    n = A.shape[0]
    q = from_nodes.shape[0]
    m = n + q
    M = np.zeros((m, m))
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j] * length
        M[i, n] = B[i] * length
    for k in range(q - 1):
        M[n + k, n + k + 1] = 1.0
    Mb, scale = balance(M)
    E = np.zeros((offsets.size, n, n))
    H = np.zeros((offsets.size, n, q))
    for t in range(offsets.size):
        if offsets[t] == 0.0:
            for i in range(n):
                E[t, i, i] = 1.0
            continue
        R = expm(Mb * offsets[t])
        F = np.empty((m, m))
        for i in range(m):
            for j in range(m):
                F[i, j] = scale[i] * R[i, j] / scale[j]
        E[t] = F[:n, :n]
        if n > 0:
            H[t] = np.ascontiguousarray(F[:n, n:]) @ from_nodes
    return E, H


@njit(cache=True)
def combine(F, A, B, kp, ki, out):
    """``out[p] = F[p] + kp[p] A[p] + ki[p] B[p]`` for every path ``p`` (a PI route's matrices
    for its gains)."""
    flat_f = F.reshape(F.shape[0], -1)
    flat_a = A.reshape(A.shape[0], -1)
    flat_b = B.reshape(B.shape[0], -1)
    flat_o = out.reshape(out.shape[0], -1)
    for p in range(flat_f.shape[0]):
        for i in range(flat_f.shape[1]):
            flat_o[p, i] = flat_f[p, i] + kp[p] * flat_a[p, i] + ki[p] * flat_b[p, i]


@njit(cache=True)
def run_loop(n, hist, r_step, dout_step, bounds, out, src, split, lag, nst, Ox, O1, O2, Sx, S1, S2,
             x, y_rec, u_rec, v_rec, limit, first, last):
    """Run ``n`` steps of stages ``first`` to ``last - 1`` (0: the outputs ``y``, which give the
    errors; 1: the decoupler outputs ``u``; 2: the controller outputs ``v``); records each
    computed signal at the step boundaries (rows ``0 .. n``).

    ``r_step``, ``dout_step``: (n, 2) set-points (less the measurement noise) and output
    disturbances on each step (constant there); ``x``: (paths, max states) zero on entry, updated
    in place; ``hist`` holds the input disturbances (signals 2, 3) on entry and gets the errors
    (signals 0, 1). Stops at the first step whose outputs leave ``limit`` (or are not finite) and
    returns its index (``n`` when none did): the rows from there on are not valid. A call with
    ``first > 0`` reads the errors a call with ``first = 0`` left in ``hist``."""
    q = hist.shape[2]
    nmax = x.shape[1]
    xn = np.zeros(nmax)
    acc = np.zeros(q)
    y = np.zeros((2, q))
    u = np.zeros((2, q))
    v = np.zeros((2, q))
    for k in range(n):
        for i in range(2):
            for j in range(q):
                y[i, j] = dout_step[k, i]
                u[i, j] = 0.0
                v[i, j] = 0.0
        for stage in range(first, last):
            if stage == 1 and first == 0:  # the errors of this step, now that y is known at its nodes
                for i in range(2):
                    for j in range(q):
                        hist[k, i, j] = r_step[k, i] - y[i, j]
            for p in range(bounds[stage], bounds[stage + 1]):
                for j in range(q):
                    acc[j] = 0.0
                _path_step(p, k, hist, src, split, lag, nst, Ox, O1, O2, Sx, S1, S2, x, xn, acc)
                o = out[p]
                for j in range(q):
                    if stage == 0:
                        y[o, j] += acc[j]
                    elif stage == 1:
                        u[o, j] += acc[j]
                    else:
                        v[o, j] += acc[j]
        if first == 0 and last == 1:  # the errors, which the stages after read
            for i in range(2):
                for j in range(q):
                    hist[k, i, j] = r_step[k, i] - y[i, j]
        big = 0.0
        for i in range(2):
            if first == 0:
                y_rec[k, i] = y[i, 0]
                y_rec[k + 1, i] = y[i, q - 1]
            if first <= 1 < last:
                u_rec[k, i] = u[i, 0]
                u_rec[k + 1, i] = u[i, q - 1]
            if last == 3:
                v_rec[k, i] = v[i, 0]
                v_rec[k + 1, i] = v[i, q - 1]
            for j in range(q):
                big += abs(y[i, j]) + abs(u[i, j])
        if not big < limit:
            return k
    return n


# ---------------------------------------------------------------------------------------------
# Quadrature of the error cubics: each step's error is the cubic c0 + c1 tau + c2 tau^2 + c3 tau^3
# in the step's fraction tau in [0, 1]; the integrals below are exact for it, |e| included (its
# sign changes are located to machine precision).
# ---------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _cubic(c, tau):
    return c[0] + tau * (c[1] + tau * (c[2] + tau * c[3]))


@njit(cache=True)
def _pieces(c, a, b, cuts):
    """Fill ``cuts`` with ``a``, the extrema of the cubic inside ``(a, b)`` and ``b`` (sorted);
    returns their number. Between two cuts the cubic is monotone."""
    m = 0
    cuts[m] = a
    m += 1
    # p' = c1 + 2 c2 tau + 3 c3 tau^2
    qa, qb, qc = 3.0 * c[3], 2.0 * c[2], c[1]
    r1 = np.nan
    r2 = np.nan
    if qa != 0.0:
        disc = qb * qb - 4.0 * qa * qc
        if disc > 0.0:
            s = np.sqrt(disc)
            qq = -0.5 * (qb + s if qb >= 0.0 else qb - s)
            r1 = qq / qa
            r2 = qc / qq if qq != 0.0 else np.nan
    elif qb != 0.0:
        r1 = -qc / qb
    if r2 < r1:
        r1, r2 = r2, r1
    for r in (r1, r2):
        if r == r and a < r < b:
            cuts[m] = r
            m += 1
    cuts[m] = b
    return m + 1


@njit(cache=True)
def _root(c, lo, hi, level):
    """The root of ``p - level`` in ``[lo, hi]``, where the cubic is monotone and changes sign
    (bisection with secant steps, to a few ulps of the interval)."""
    flo = _cubic(c, lo) - level
    fhi = _cubic(c, hi) - level
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if flo != fhi:
            sec = lo - flo * (hi - lo) / (fhi - flo)
            if lo < sec < hi:
                mid = 0.5 * (mid + sec)
        fm = _cubic(c, mid) - level
        if fm == 0.0:
            return mid
        if (fm < 0.0) == (flo < 0.0):
            lo, flo = mid, fm
        else:
            hi, fhi = mid, fm
        if hi - lo <= 4e-16 * max(1.0, abs(lo)):
            break
    return 0.5 * (lo + hi)


@njit(cache=True, inline="always")
def _moments(c, a, b):
    """``(int p, int tau p, int p^2)`` over ``[a, b]``."""
    # dm = (b^m - a^m) / m, m = 1 .. 7
    a2, b2 = a * a, b * b
    a3, b3 = a2 * a, b2 * b
    a4, b4 = a2 * a2, b2 * b2
    d1 = b - a
    d2 = (b2 - a2) / 2.0
    d3 = (b3 - a3) / 3.0
    d4 = (b4 - a4) / 4.0
    d5 = (b4 * b - a4 * a) / 5.0
    d6 = (b4 * b2 - a4 * a2) / 6.0
    d7 = (b4 * b3 - a4 * a3) / 7.0
    c0, c1, c2, c3 = c[0], c[1], c[2], c[3]
    m0 = c0 * d1 + c1 * d2 + c2 * d3 + c3 * d4
    m1 = c0 * d2 + c1 * d3 + c2 * d4 + c3 * d5
    m2 = (c0 * c0 * d1 + 2.0 * c0 * c1 * d2 + (c1 * c1 + 2.0 * c0 * c2) * d3 + 2.0 * (c0 * c3 + c1 * c2) * d4
          + (c2 * c2 + 2.0 * c1 * c3) * d5 + 2.0 * c2 * c3 * d6 + c3 * c3 * d7)
    return m0, m1, m2


@njit(cache=True)
def _integrals(c, a, b, cuts):
    m = _pieces(c, a, b, cuts)
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for k in range(m - 1):
        lo, hi = cuts[k], cuts[k + 1]
        flo, fhi = _cubic(c, lo), _cubic(c, hi)
        mid = hi
        if flo * fhi < 0.0:
            mid = _root(c, lo, hi, 0.0)
        for x0, x1 in ((lo, mid), (mid, hi)):
            if x1 <= x0:
                continue
            m0, m1, m2 = _moments(c, x0, x1)
            sign = 1.0 if _cubic(c, 0.5 * (x0 + x1)) >= 0.0 else -1.0
            s0 += sign * m0
            s1 += sign * m1
            s2 += m2
    return s0, s1, s2


@njit(cache=True)
def step_integrals(c, a, b):
    """``(int |p|, int tau |p|, int p^2)`` of the cubic ``c`` over ``[a, b]`` in ``[0, 1]``, exact:
    split at its extrema and at its sign changes."""
    return _integrals(c, a, b, np.empty(4))


@njit(cache=True)
def step_table(coef, h):
    """Per step ``k`` of one loop's error cubics: ``int |e| dt``, ``int t |e| dt`` (``t`` from 0)
    and ``int e^2 dt`` over the whole step, as the rows of an ``(n, 3)`` array."""
    n = coef.shape[0]
    out = np.empty((n, 3))
    cuts = np.empty(4)
    for k in range(n):
        s0, s1, s2 = _integrals(coef[k], 0.0, 1.0, cuts)
        out[k, 0] = h * s0
        out[k, 1] = h * (k * h * s0 + h * s1)
        out[k, 2] = h * s2
    return out


@njit(cache=True)
def last_exit(coef, k0, a0, k1, b1, band):
    """The last time, as ``(step, fraction)``, at which ``|e|`` is above ``band`` in the window
    (``(-1, 0)`` when it never is), located on the cubic."""
    cuts = np.empty(4)
    for k in range(k1, k0 - 1, -1):
        a = a0 if k == k0 else 0.0
        b = b1 if k == k1 else 1.0
        if b <= a:
            continue
        c = coef[k]
        m = _pieces(c, a, b, cuts)
        for j in range(m - 2, -1, -1):  # the monotone pieces, latest first
            lo, hi = cuts[j], cuts[j + 1]
            flo, fhi = abs(_cubic(c, lo)), abs(_cubic(c, hi))
            if fhi > band:
                return k, hi
            if flo > band:  # |p| falls through the band inside the piece
                level = band if _cubic(c, lo) > 0.0 else -band
                return k, _root(c, lo, hi, level)
    return -1, 0.0
