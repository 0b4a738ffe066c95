"""Shared machinery of the gradient-based optimisers (steepest descent, DFP, BFGS, Newton-Raphson).

The leading underscore keeps this module from being loaded as a plugin.

Conventions common to the four methods
--------------------------------------
* **Objective.** The methods minimise the merit ``f + penalty * v`` with the engine's static
  penalty (``Comparator.penalty``, default 1e6), whatever ``constraint_handling`` is: the
  gradient methods treat constraints by this static penalty only. The engine still ranks the
  best-so-far by its own comparator (Deb's rules by default). Non-finite merits count as +inf.
* **Iterate and history.** One start point; ``self.X``/``self.f``/``self.v`` hold the current
  iterate (one row) for the engine's history.
* **One iteration** = a derivative batch (``tell`` returns False) + a line-search batch
  (``tell`` returns True). The derivative batch holds the gradient stencil (and, for
  Newton-Raphson, the Hessian stencil); at a (re)start it also holds the start point itself.
  After a failed line search the gradient is still valid, so the next iteration is a
  line-search batch only.
* **Finite differences.** Gradient: for coordinate i two stencil points ``x + a e_i`` and
  ``x + b e_i`` with ``h_i = fd_step * max(1, |x_i|)``: central (``a = h, b = -h``) when both fit
  in the box, else the one-sided three-point formula (``h, 2h`` or ``-h, -2h``), else the step is
  shrunk to fit; the derivative is that of the quadratic through ``(0, f0), (a, fa), (b, fb)``
  (second order in every case, exact for quadratics). A non-finite stencil value falls back to
  the two-point difference with the finite neighbour, or to 0. Hessian: at a centre ``c``
  (``x`` moved inwards by at most one step so that the stencil fits), step ``hess_step``,
  diagonal ``(f(c+h_i) - 2 f(c) + f(c-h_i)) / h_i^2`` and off-diagonal
  ``(f(c+h_i+h_j) + f(c-h_i-h_j) - f(c+h_i) - f(c-h_i) - f(c+h_j) - f(c-h_j) + 2 f(c)) /
  (2 h_i h_j)`` (second order; ``d^2 + d + 1`` points).
* **Box units.** Directions, steps and quasi-Newton/Newton matrices live in the box-normalised
  coordinates ``u = (x - lower) / width`` (gradient ``g_u = g * width``): a diagonal scaling
  that makes the methods indifferent to the units of the parameters (Newton-Raphson is
  invariant anyway; for steepest descent it is a fixed diagonal preconditioner).
* **Bounds.** Trial points are projected on the box, ``P(x) = clip(x, lower, upper)``. A
  coordinate at a bound whose gradient points out of the box is *active*: its direction
  component is 0 and the direction of the others uses the free block (``-g_F``,
  ``-H_FF g_F``, or ``-(B_FF)^-1 g_F``). The convergence test uses this projected gradient.
* **Line search** (one batch): ``P(x + t_k d)``, ``t_k = t_0 r^k``, ``k = 0..K-1``
  (``r = step_ratio``, ``K = line_search_points``), the longest trial moving no coordinate by
  more than ``max_step`` box widths. Newton and quasi-Newton: ``t_0 = T r^-extrapolation``
  with ``T = max(1, last accepted t)``, so the set holds the full step ``t = 1`` (or ``T``)
  and ``extrapolation`` longer trials (default 2: ``t = 4, 2, 1, 1/2, ..., 1/32``); when the
  cap bites, extrapolated trials are dropped first, then the steps shortened. Steepest
  descent: the direction is normalised to one box width and ``t_0`` adapts (twice the last
  accepted step, at most ``max_step``; after a failure the search continues below the
  shortest step tried). Accepted: the trial with the lowest merit among those meeting
  Armijo's condition ``m(p) <= m(x) + armijo * g.(p - x)`` (projected step), else the lowest
  merit if it improves on ``m(x)``. Otherwise the search failed: Newton and quasi-Newton fall
  back to a steepest-descent search from the same point (the quasi-Newton matrix is reset).
  A direction that is not a descent direction is replaced by steepest descent as well.
* **Unit steps** (``line_search="unit"``: the step rule of the thesis' chapter 6, where
  Newton-Raphson, DFP and BFGS take ``alpha_k = 1``, ``x_{k+1} = x_k + d_k``). The line-search
  batch is the single trial ``P(x + d)`` with the method's direction ``d`` in box units (not
  normalised, not capped by ``max_step``: the projection keeps it in the box), and it is
  taken whatever its merit, uphill included, as the thesis does; the engine still keeps the
  best-so-far. An iteration costs the derivative batch plus one evaluation (``2d + 1``; Newton-
  Raphson ``d^2 + 3d + 2``). Quasi-Newton matrices are updated after every step exactly as with
  Armijo steps, with the same curvature safeguard (update skipped when ``s^T y`` is not
  clearly positive), so a step that went uphill along a direction of negative curvature leaves
  ``H`` unchanged. Steepest descent: the thesis prescribes an exact line search
  (``alpha_k = argmin phi``), which the Armijo batch approximates; its ``unit`` variant is the
  literal ``alpha = 1`` on the gradient in box units, ``u_{k+1} = P(u_k - grad_u m)``, i.e. the
  quasi-Newton step with ``H = I`` (the first DFP/BFGS step). Chosen over a step normalised to
  one box width because that one would always end on a bound, while this one is the same
  reading of ``alpha = 1`` as for the other three methods; it converges only where the
  curvature in box units stays below 2 and otherwise oscillates or ends on bounds (use
  ``armijo`` for real work). A direction that is not a descent direction is replaced by the
  unit steepest-descent step. A trial with non-finite merit is not taken: the unit steepest-
  descent step from the same point is tried next (the quasi-Newton matrix is reset), and if that
  fails too the method counts as converged.
* **Convergence and restarts.** Converged when the projected gradient in box units satisfies
  ``max|g_i width_i| <= gtol * max(1, |m(x)|)``, when an accepted step moves every coordinate
  by less than ``xtol`` box widths (the thesis' ``|x_{k+1} - x_k| < tol``; default 0: off, and
  without effect when ``restart=False``), or after two failed line searches in a row.
  With ``restart=True`` (default) the method then restarts from a uniform random point of the
  box (multistart, so the whole budget is used; the engine keeps the best-so-far, and the
  history's population statistics jump at a restart); with ``restart=False`` it keeps
  polishing the same point with ever shorter steepest-descent steps (Armijo searches, also
  after unit steps, which from then on are no longer used). A start point with non-finite
  merit is replaced by a random one at once (that iteration has no line search).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.core.engine import Optimizer

__all__ = ["GradientSettings", "GradientOptimizer", "gradient_stencil", "gradient_from_stencil",
           "hessian_stencil", "hessian_from_stencil", "finite_difference_gradient",
           "finite_difference_hessian", "bfgs_update", "dfp_update", "modify_eigenvalues",
           "project", "QuasiNewtonOptimizer"]

START_CHOICES = ("random", "center")
LINE_SEARCH_CHOICES = ("armijo", "unit")


# ---------------------------------------------------------------------------------------------
# settings


@dataclasses.dataclass(frozen=True)
class GradientSettings:
    start: str = dataclasses.field(default="random", metadata={
        "help": "start point: 'random' (uniform in the box) or 'center'; restarts are random"})
    fd_step: float = dataclasses.field(default=1e-6, metadata={
        "help": "relative finite-difference step of the gradient, h_i = fd_step*max(1,|x_i|)"})
    line_search_points: int = dataclasses.field(default=8, metadata={
        "help": "trial steps per line-search batch, t_k = t_0*step_ratio^k"})
    step_ratio: float = dataclasses.field(default=0.5, metadata={
        "help": "ratio of consecutive line-search steps, in (0, 1)"})
    extrapolation: int = dataclasses.field(default=2, metadata={
        "help": "(quasi-)Newton trials longer than the full step: t_0 = step_ratio^-extrapolation"})
    armijo: float = dataclasses.field(default=1e-4, metadata={
        "help": "Armijo sufficient-decrease constant c1, in (0, 1)"})
    max_step: float = dataclasses.field(default=1.0, metadata={
        "help": "longest trial step, in box widths per coordinate"})
    gtol: float = dataclasses.field(default=1e-8, metadata={
        "help": "converged when max|projected gradient * box width| <= gtol*max(1,|merit|)"})
    restart: bool = dataclasses.field(default=True, metadata={
        "help": "after convergence restart from a random point (else keep polishing)"})
    line_search: str = dataclasses.field(
        default="armijo",
        metadata={
            "help": "'armijo' (batched Armijo search) or 'unit' (the thesis' alpha_k = 1: one trial "
            "P(x + d), always taken)"
        },
    )
    xtol: float = dataclasses.field(default=0.0, metadata={
        "help": "also converged when an accepted step moves no coordinate by xtol box widths or more (0: off)"})

    def __post_init__(self):
        if self.start not in START_CHOICES:
            raise ValueError(f"start must be one of {', '.join(START_CHOICES)}, got {self.start!r}")
        if not 0 < self.fd_step < 1:
            raise ValueError(f"fd_step must lie in (0, 1), got {self.fd_step}")
        if self.line_search_points < 1:
            raise ValueError(f"line_search_points must be >= 1, got {self.line_search_points}")
        if not 0 < self.step_ratio < 1:
            raise ValueError(f"step_ratio must lie in (0, 1), got {self.step_ratio}")
        if not 0 <= self.extrapolation < self.line_search_points:
            raise ValueError(f"extrapolation must lie in [0, line_search_points), got {self.extrapolation}")
        if not 0 < self.armijo < 1:
            raise ValueError(f"armijo must lie in (0, 1), got {self.armijo}")
        if not self.max_step > 0:
            raise ValueError(f"max_step must be positive, got {self.max_step}")
        if not self.gtol >= 0:
            raise ValueError(f"gtol must be >= 0, got {self.gtol}")
        if self.line_search not in LINE_SEARCH_CHOICES:
            raise ValueError(f"line_search must be one of {', '.join(LINE_SEARCH_CHOICES)}, "
                             f"got {self.line_search!r}")
        if not self.xtol >= 0:
            raise ValueError(f"xtol must be >= 0, got {self.xtol}")


# ---------------------------------------------------------------------------------------------
# pure helpers


def project(X, lower, upper):
    """Projection on the box (clip)."""
    return np.clip(X, lower, upper)


def gradient_stencil(x, lower, upper, rel_step):
    """Stencil points of the finite-difference gradient at ``x`` (inside the box).

    Returns ``(P, a, b)``: ``P`` (2d, d) holds ``x + a_i e_i`` in row ``2i`` and ``x + b_i e_i`` in
    row ``2i + 1``; ``a``, ``b`` (d,) are the offsets actually realised in floating point
    (``a_i = b_i = 0`` for a coordinate with zero width).
    """
    x = np.asarray(x, dtype=np.float64)
    d = x.size
    h = rel_step * np.maximum(1.0, np.abs(x))
    room_up, room_down = upper - x, x - lower
    a = np.empty(d)
    b = np.empty(d)
    for i in range(d):
        hi = h[i]
        if room_up[i] >= hi and room_down[i] >= hi:
            a[i], b[i] = hi, -hi
        elif room_up[i] >= 2 * hi:
            a[i], b[i] = hi, 2 * hi
        elif room_down[i] >= 2 * hi:
            a[i], b[i] = -hi, -2 * hi
        elif room_up[i] >= room_down[i]:
            a[i], b[i] = room_up[i] / 2, room_up[i]
        else:
            a[i], b[i] = -room_down[i] / 2, -room_down[i]
    P = np.repeat(x[None, :], 2 * d, axis=0)
    idx = np.arange(d)
    P[2 * idx, idx] = project(x + a, lower, upper)
    P[2 * idx + 1, idx] = project(x + b, lower, upper)
    a = P[2 * idx, idx] - x  # realised offsets
    b = P[2 * idx + 1, idx] - x
    return P, a, b


def gradient_from_stencil(f0, F, a, b):
    """Gradient from the stencil values ``F`` (2d,) of :func:`gradient_stencil` and ``f0 = f(x)``.

    Derivative at 0 of the quadratic through ``(0, f0), (a, fa), (b, fb)``; a non-finite value
    falls back to the two-point difference with the finite neighbour, else to 0.
    """
    F = np.asarray(F, dtype=np.float64)
    fa, fb = F[0::2], F[1::2]
    g = np.zeros(a.size)
    with np.errstate(all="ignore"):
        for i in range(a.size):
            ai, bi = a[i], b[i]
            if ai == 0 or bi == 0 or ai == bi or not np.isfinite(f0):
                if np.isfinite(fa[i]) and np.isfinite(fb[i]) and ai != bi:
                    g[i] = (fa[i] - fb[i]) / (ai - bi)
                continue
            if np.isfinite(fa[i]) and np.isfinite(fb[i]):
                g[i] = (-(ai + bi) / (ai * bi) * f0 - bi / (ai * (ai - bi)) * fa[i]
                        - ai / (bi * (bi - ai)) * fb[i])
            elif np.isfinite(fa[i]):
                g[i] = (fa[i] - f0) / ai
            elif np.isfinite(fb[i]):
                g[i] = (fb[i] - f0) / bi
    return np.where(np.isfinite(g), g, 0.0)


def hessian_stencil(x, lower, upper, rel_step):
    """Stencil of the finite-difference Hessian near ``x``.

    The centre ``c`` is ``x`` moved inwards (by at most one step) so that ``c +- h_i e_i`` fits in
    the box; a coordinate narrower than two steps uses half its width, one of zero width gets
    ``h_i = 0`` (its row and column of the Hessian are left 0). Returns ``(P, h)``, ``P`` with
    rows ``c``, then ``c + h_i e_i``, ``c - h_i e_i`` for each i, then ``c + h_i e_i + h_j e_j``,
    ``c - h_i e_i - h_j e_j`` for each pair i < j (``d^2 + d + 1`` rows).
    """
    x = np.asarray(x, dtype=np.float64)
    d = x.size
    width = upper - lower
    h = rel_step * np.maximum(1.0, np.abs(x))
    h = np.minimum(h, width / 2)
    c = np.clip(x, lower + h, upper - h)
    rows = [c]
    for i in range(d):
        e = np.zeros(d)
        e[i] = h[i]
        rows += [c + e, c - e]
    for i in range(d):
        for j in range(i + 1, d):
            e = np.zeros(d)
            e[i], e[j] = h[i], h[j]
            rows += [c + e, c - e]
    P = project(np.array(rows), lower, upper)
    return P, h


def hessian_from_stencil(F, h):
    """Symmetric Hessian from the values ``F`` at the points of :func:`hessian_stencil`.

    Entries involving a non-finite value or a zero step are 0.
    """
    F = np.asarray(F, dtype=np.float64)
    d = h.size
    f0 = F[0]
    fp, fm = F[1:1 + 2 * d:2], F[2:2 + 2 * d:2]
    B = np.zeros((d, d))
    k = 1 + 2 * d
    with np.errstate(all="ignore"):
        for i in range(d):
            if h[i] > 0:
                B[i, i] = (fp[i] - 2 * f0 + fm[i]) / h[i] ** 2
        for i in range(d):
            for j in range(i + 1, d):
                fpp, fmm = F[k], F[k + 1]
                k += 2
                if h[i] > 0 and h[j] > 0:
                    B[i, j] = B[j, i] = ((fpp + fmm - fp[i] - fm[i] - fp[j] - fm[j] + 2 * f0)
                                         / (2 * h[i] * h[j]))
    return np.where(np.isfinite(B), B, 0.0)


def finite_difference_gradient(fun, x, lower, upper, rel_step=1e-6):
    """Gradient of a vectorised ``fun`` ((n, d) -> (n,)) at ``x`` (one batch of 2d + 1 points)."""
    x = np.asarray(x, dtype=np.float64)
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    P, a, b = gradient_stencil(x, lower, upper, rel_step)
    F = np.asarray(fun(np.vstack([x[None, :], P])), dtype=np.float64)
    return gradient_from_stencil(F[0], F[1:], a, b)


def finite_difference_hessian(fun, x, lower, upper, rel_step=1e-4):
    """Hessian of a vectorised ``fun`` near ``x`` (one batch of d^2 + d + 1 points)."""
    x = np.asarray(x, dtype=np.float64)
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    P, h = hessian_stencil(x, lower, upper, rel_step)
    return hessian_from_stencil(fun(P), h)


def bfgs_update(H, s, y):
    """BFGS update of the inverse Hessian approximation (Nocedal & Wright 2006, eq. 6.17).

    ``H+ = (I - rho s y^T) H (I - rho y s^T) + rho s s^T``, ``rho = 1 / (y^T s)``; requires
    ``y^T s > 0`` (the caller skips the update otherwise). Satisfies ``H+ y = s``.
    """
    s, y = np.asarray(s, dtype=np.float64), np.asarray(y, dtype=np.float64)
    rho = 1.0 / float(y @ s)
    V = np.eye(s.size) - rho * np.outer(s, y)
    Hn = V @ H @ V.T + rho * np.outer(s, s)
    return 0.5 * (Hn + Hn.T)


def dfp_update(H, s, y):
    """DFP update of the inverse Hessian approximation (Nocedal & Wright 2006, eq. 6.15).

    ``H+ = H - (H y y^T H) / (y^T H y) + (s s^T) / (y^T s)``; requires ``y^T s > 0`` (the caller
    skips the update otherwise). Satisfies ``H+ y = s``.
    """
    s, y = np.asarray(s, dtype=np.float64), np.asarray(y, dtype=np.float64)
    Hy = H @ y
    Hn = H - np.outer(Hy, Hy) / float(y @ Hy) + np.outer(s, s) / float(y @ s)
    return 0.5 * (Hn + Hn.T)


def modify_eigenvalues(B, floor):
    """Positive-definite modification of a symmetric matrix by its eigenvalues.

    Each eigenvalue ``l`` becomes ``max(|l|, floor * max(1, max|l|))`` (negative curvature is
    mirrored, tiny curvature floored); the eigenvectors are kept. Returns ``(Q, lam)`` with
    ``B_mod = Q diag(lam) Q^T``.
    """
    B = 0.5 * (B + B.T)
    lam, Q = np.linalg.eigh(B)
    scale = max(1.0, float(np.max(np.abs(lam)))) if lam.size else 1.0
    return Q, np.maximum(np.abs(lam), floor * scale)


# ---------------------------------------------------------------------------------------------
# the shared ask/tell optimiser


class GradientOptimizer(Optimizer):
    """Single-point line-search descent with finite-difference derivatives (see module doc).

    Subclasses set ``uses_hessian`` and implement :meth:`direction` (the method's search
    direction on the free coordinates) and optionally :meth:`learn` (quasi-Newton update) and
    :meth:`reset_model`.
    """

    uses_hessian = False
    steepest = False  # steepest descent: always the adaptive steepest-descent line search

    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.lower, self.upper = space.lower, space.upper
        self.width = space.width
        self.fixed = self.width <= 0
        self.scale = np.where(self.fixed, 1.0, self.width)  # x = lower + scale * u
        if settings.start == "center":
            x = 0.5 * (self.lower + self.upper)
        else:
            x = space.uniform(rng, 1)[0]
        self._begin(x)
        self.sd_step = settings.max_step  # steepest-descent t_0, in box widths
        self.n_restarts = 0
        # unit steps (thesis alpha_k = 1); switched off for good when restart=False polishing begins
        self.unit = settings.line_search == "unit"

    # -- state ---------------------------------------------------------------------------------

    def _begin(self, x):
        """(Re)start at ``x``: its merit and gradient are unknown."""
        self.x = np.asarray(x, dtype=np.float64)
        self.mx = None  # merit at x
        self.grad = None
        self.hess = None
        self.phase = "derivatives"
        self.failures = 0
        self.use_sd = self.steepest
        self.qn_step = 1.0  # (quasi-)Newton trials centre on max(1, last accepted step)
        self.prev_x = self.prev_g = None
        self.reset_model()

    def _restart(self):
        self.n_restarts += 1
        self.sd_step = self.settings.max_step
        self._begin(self.space.uniform(self.rng, 1)[0])

    def _merit(self, f, v):
        m = np.asarray(self.compare.merit(f, v), dtype=np.float64)
        return np.where(np.isfinite(m), m, np.inf)

    def _set_current(self, f, v):
        self.X = self.x[None, :].copy()
        self.f = np.array([f], dtype=np.float64)
        self.v = np.array([v], dtype=np.float64)

    # -- hooks -----------------------------------------------------------------------------------

    def reset_model(self):
        """Forget curvature information (quasi-Newton matrix)."""

    def learn(self, s, y):
        """Use the step ``s`` and gradient change ``y`` (quasi-Newton update)."""

    def direction(self, g, free):
        """Search direction (d,) from the gradient; components outside ``free`` are ignored."""
        raise NotImplementedError

    # -- geometry --------------------------------------------------------------------------------

    def _free(self, g):
        """Coordinates not held at a bound by the gradient."""
        tol = 1e-12 * np.maximum(self.width, 1.0)
        at_low = (self.x <= self.lower + tol) & (g > 0)
        at_up = (self.x >= self.upper - tol) & (g < 0)
        return ~(at_low | at_up | self.fixed)

    # -- ask/tell --------------------------------------------------------------------------------

    def ask(self):
        if self.phase == "derivatives":
            parts = []
            if self.mx is None:
                parts.append(self.x[None, :])
            P, self._a, self._b = gradient_stencil(self.x, self.lower, self.upper, self.settings.fd_step)
            parts.append(P)
            if self.uses_hessian:
                H, self._h = hessian_stencil(self.x, self.lower, self.upper, self.settings.hess_step)
                parts.append(H)
            return np.vstack(parts)
        return self.trials

    def tell(self, X, f, v):
        if self.phase == "derivatives":
            return self._tell_derivatives(f, v)
        return self._tell_line_search(X, f, v)

    def _tell_derivatives(self, f, v):
        s = self.settings
        m = self._merit(f, v)
        k = 0
        if self.mx is None:
            self.mx = float(m[0])
            self._set_current(f[0], v[0])
            k = 1
        if not np.isfinite(self.mx):  # unusable start point: start again elsewhere
            self._restart()
            return True
        d = self.x.size
        g = gradient_from_stencil(self.mx, m[k:k + 2 * d], self._a, self._b)
        k += 2 * d
        if self.uses_hessian:
            self.hess = hessian_from_stencil(m[k:], self._h)
        g[self.fixed] = 0.0
        if self.prev_g is not None:
            self.learn((self.x - self.prev_x) / self.scale, (g - self.prev_g) * self.scale)
            self.prev_x = self.prev_g = None
        self.grad = g
        free = self._free(g)
        if np.max(np.abs(g[free] * self.scale[free]), initial=0.0) <= s.gtol * max(1.0, abs(self.mx)):
            self._converged()
            return True
        self.use_sd = self.steepest
        self._plan_line_search()
        return False

    def _plan_line_search(self):
        """Direction and trial points of the next line-search batch."""
        s = self.settings
        free = self._free(self.grad)
        g = self.grad * self.scale  # gradient in box units
        if not self.use_sd:
            d = np.where(free, self.direction(g, free), 0.0)
            if not (np.all(np.isfinite(d)) and g @ d < 0):
                self.use_sd = True  # not a descent direction: fall back
        if self.unit:  # the full step of the direction, alpha = 1, in box units (no normalisation)
            if self.use_sd:
                d = np.where(free, -g, 0.0)
            self.steps = np.ones(1)
            self.trials = project(self.x + d * self.scale, self.lower, self.upper)[None, :]
            self.phase = "line_search"
            return
        if self.use_sd:
            d = np.where(free, -g, 0.0)
            extent = float(np.max(np.abs(d)))
            d = d / extent if extent > 0 else d
            t0 = self.sd_step
        else:
            extent = float(np.max(np.abs(d)))
            # the longest trial moves at most max_step box widths: drop extrapolated trials
            # first (so that the full step t = 1 stays in the set), then shorten
            t0 = self.qn_step * s.step_ratio ** -s.extrapolation
            while t0 * extent > s.max_step and t0 > self.qn_step:
                t0 *= s.step_ratio
            if t0 * extent > s.max_step:
                t0 = s.max_step / extent
        self.steps = t0 * s.step_ratio ** np.arange(s.line_search_points)
        step = d * self.scale  # back to x units
        self.trials = project(self.x + self.steps[:, None] * step[None, :], self.lower, self.upper)
        self.phase = "line_search"

    def _accept(self, X, f, v, m, i):
        """Move to trial ``i``; True when that step is below ``xtol`` and the method restarts."""
        step = np.max(np.abs(X[i] - self.x) / self.scale, initial=0.0)
        self.prev_x, self.prev_g = self.x, self.grad
        self.x = np.array(X[i], dtype=np.float64)
        self.mx = float(m[i])
        self._set_current(f[i], v[i])
        self.grad = None
        self.failures = 0
        self.phase = "derivatives"
        if step < self.settings.xtol and self.settings.restart:
            self._converged()
            return True
        return False

    def _tell_unit_step(self, X, f, v):
        m = self._merit(f, v)
        if np.isfinite(m[0]):  # taken even when it does not decrease the merit (thesis)
            self._accept(X, f, v, m, 0)
            return True
        # non-finite merit: x and its gradient stay valid; try the unit steepest-descent step,
        # and give up (restart or polish) when that fails too
        self.failures += 1
        if self.use_sd or self.failures >= 2:
            self._converged()
            return True
        self.reset_model()
        self.use_sd = True
        self._plan_line_search()
        return True

    def _tell_line_search(self, X, f, v):
        if self.unit:
            return self._tell_unit_step(X, f, v)
        s = self.settings
        m = self._merit(f, v)
        decrease = (X - self.x) @ self.grad
        armijo = m <= self.mx + s.armijo * decrease
        improving = m < self.mx
        pick = armijo & improving if np.any(armijo & improving) else improving
        if np.any(pick):
            i = int(np.flatnonzero(pick)[np.argmin(m[pick])])
            if self.use_sd:
                self.sd_step = min(s.max_step, self.steps[i] / s.step_ratio)
            else:
                self.qn_step = max(1.0, self.steps[i])
            self._accept(X, f, v, m, i)
            return True
        # failed: x and its gradient stay valid
        self.failures += 1
        if self.use_sd:
            self.sd_step = self.steps[-1] * s.step_ratio
        if self.failures >= 2 and s.restart:
            self._converged()
            return True
        if not self.use_sd:
            self.reset_model()
        self.use_sd = True
        self._plan_line_search()
        return True

    def _converged(self):
        if self.settings.restart:
            self._restart()
            return
        # keep polishing: shorter steepest-descent steps from the same point (Armijo search,
        # also after unit steps: repeating a unit step from the same point would change nothing)
        self.unit = False
        self.use_sd = True
        self.sd_step = min(self.sd_step, self.settings.max_step) * self.settings.step_ratio
        self._plan_line_search()


class QuasiNewtonOptimizer(GradientOptimizer):
    """Inverse-Hessian quasi-Newton method; subclasses set ``update`` (bfgs_update/dfp_update).

    Everything is in box units ``u = (x - lower) / width``: ``s = du``, ``y = dg/du``. ``H``
    starts (and restarts) as the identity, not rescaled: in box units a unit step is one box
    width and the step cap ``max_step`` bounds it; on the test problems this beat the
    ``(s^T y / y^T y) I`` scaling of Nocedal & Wright (2006, eq. 6.20) clearly for DFP
    (median evaluations to f < 1e-8 on the 4-D quadratic of condition 1000: 97 against ~1500)
    and slightly for BFGS. The update is skipped when the curvature condition fails,
    ``s^T y <= 1e-10 |s| |y|`` (non-positive or numerically zero curvature), or ``y`` is not
    finite. Direction: ``d_F = -H_FF g_F`` on the free coordinates.
    """

    update = None  # staticmethod(H, s, y) -> H_new
    curvature_eps = 1e-10

    def reset_model(self):
        self.H = np.eye(self.space.dim)
        self.n_updates = getattr(self, "n_updates", 0)
        self.n_skipped = getattr(self, "n_skipped", 0)

    def learn(self, s, y):
        sy = float(s @ y)
        if not (np.all(np.isfinite(y)) and sy > self.curvature_eps * np.linalg.norm(s) * np.linalg.norm(y)):
            self.n_skipped += 1
            return
        self.H = self.update(self.H, s, y)
        self.n_updates += 1

    def direction(self, g, free):
        d = np.zeros_like(g)
        d[free] = -self.H[np.ix_(free, free)] @ g[free]
        return d
