"""CMA-ES, then an SLSQP polish of its best point with the active bounds fixed (a memetic
schedule of two registered optimisers: :mod:`heurtune.algorithms.cmaes` and the local solve of
:mod:`heurtune.algorithms.sqp_multistart`).

Why: on problems whose optimum lies on some of the bounds (``benchmark_qtp``: the weights and
integral gains of the best controllers sit on their box), CMA-ES approaches those faces only
through pycma's boundary transformation, and spends its last evaluations on the digits. A
local solve on the face is cheaper: with the coordinates on a bound fixed there, SLSQP's
finite-difference gradients cost one evaluation per free coordinate.

The schedule:

1. **CMA-ES** (``cmaes``, with all its settings: ``popsize``, ``sigma0``, ``restarts``,
   ``incpopsize``, ``constraints``) runs on ``1 - polish`` of the budget, generation by
   generation, as the engine runs it; without an evaluation budget it runs until pycma's
   termination criteria first fire.
2. **The polish.** From the best point so far, the coordinates within ``active_tol`` (a fraction
   of the variable's range) of a bound are set on that bound and fixed; SLSQP
   (``scipy.optimize.minimize(method="SLSQP")``, constraints ``g <= 0`` as inequalities, forward
   differences) moves the others inside their bounds, with the rest of the budget as its cap
   (``max_iter`` iterations, ``ftol``). It runs where the run's evaluations run (a worker).
   The run keeps the best evaluated point by the run's rules, so the polish can only improve it.
   With every coordinate on a bound there is nothing to polish.
3. **The rest of the budget**, what the polish did not use, goes back to the same CMA-ES
   strategy, so the budget is spent exactly. Without a budget the run ends after the polish
   (``stop_reason = "finished"``).

``CMAESSQP.polished`` records the polish: its free coordinates, evaluations, iterations and
SLSQP's message.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from heurtune.algorithms.cmaes import CMAES, CMAESSettings
from heurtune.algorithms.sqp_multistart import _local_solve, _Task
from heurtune.core.engine import BudgetExhausted, Driver, evaluate_generation
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class CMAESSQPSettings(CMAESSettings):
    polish: float = dataclasses.field(default=0.1, metadata={
        "help": "fraction of the evaluation budget kept for the SLSQP polish"})
    active_tol: float = dataclasses.field(default=1e-3, metadata={
        "help": "a coordinate this close to a bound (fraction of its range) is fixed on it for the polish"})
    max_iter: int = dataclasses.field(default=100, metadata={"help": "SLSQP iterations of the polish"})
    ftol: float = dataclasses.field(default=1e-10, metadata={"help": "SLSQP precision goal on f"})

    def __post_init__(self):
        super().__post_init__()
        if not 0 < self.polish < 1:
            raise ValueError(f"polish must lie in (0, 1), got {self.polish}")
        if not 0 <= self.active_tol < 0.5:
            raise ValueError(f"active_tol must lie in [0, 0.5), got {self.active_tol}")
        if self.max_iter < 1:
            raise ValueError(f"max_iter must be >= 1, got {self.max_iter}")
        if not self.ftol > 0:
            raise ValueError(f"ftol must be positive, got {self.ftol}")

    def cmaes(self) -> CMAESSettings:
        """The settings of the CMA-ES phase."""
        return CMAESSettings(**{f.name: getattr(self, f.name) for f in dataclasses.fields(CMAESSettings)})


@dataclasses.dataclass(frozen=True)
class _OnFace:
    """The run's objective on the free coordinates, the fixed ones held (picklable)."""

    objective: object
    x: np.ndarray
    free: np.ndarray

    def __call__(self, Z):
        X = np.repeat(self.x[None, :], len(Z), axis=0)
        X[:, self.free] = Z
        return self.objective(X)


def face_of(x, lower, upper, active_tol):
    """``(x on its face, free coordinates)``: the coordinates of ``x`` within ``active_tol`` of
    the range of a bound are set on it, the others are free (a boolean mask).

    Parameters
    ----------
    x : ndarray (d,)
    lower, upper : ndarray (d,)
    active_tol : float
        Fraction of each coordinate's range.

    Returns
    -------
    tuple
        ``(x on its face, free mask)``.
    """
    width = upper - lower
    at_lower = x - lower <= active_tol * width
    at_upper = upper - x <= active_tol * width
    on_face = np.where(at_lower, lower, np.where(at_upper, upper, x))
    return on_face, ~(at_lower | at_upper)


@register("cmaes_sqp", kind="driver", settings=CMAESSQPSettings,
          description="CMA-ES (pycma, IPOP), then an SLSQP polish of the best point with its active bounds fixed",
          source="Hansen & Ostermeier 2001; Auger & Hansen 2005; scipy SLSQP (Kraft 1988); memetic schedule")
class CMAESSQP(Driver):
    def __init__(self, space, settings, rng, compare):
        super().__init__(space, settings, rng, compare)
        self.polished = None  # the polish's record: free coordinates, nfev, nit, message

    def run(self, ctx) -> None:
        cma_settings = self.settings.cmaes()
        if ctx.max_evals is None:  # no budget to share: CMA-ES until its criteria first fire
            cma_settings = dataclasses.replace(cma_settings, restarts="stop")
        opt = CMAES(self.space, cma_settings, self.rng, self.compare)
        reserve = 0 if ctx.max_evals is None else int(round(self.settings.polish * ctx.max_evals))
        if self._evolve(opt, ctx, reserve) or self._polish(ctx):
            return
        if ctx.max_evals is not None and not self._evolve(opt, ctx, 0):  # what the polish left
            if not ctx.check_stop():  # CMA-ES ended itself (restarts = "stop")
                ctx.stop_reason = "finished"

    @staticmethod
    def _evolve(opt, ctx, reserve) -> bool:
        """The CMA-ES phase, up to ``reserve`` evaluations from the end of the budget; True when
        the run must stop (a stopping rule of the run fired)."""
        while True:
            left = ctx.remaining
            if left is not None and left <= reserve:
                return False
            X = ctx.space.repair(opt.ask())
            try:
                evaluate_generation(opt, ctx, X, None if left is None else left - reserve)
            except BudgetExhausted:
                return False
            if ctx.record_epoch(opt.f, opt.v):
                return True
            if getattr(opt, "finished", False):
                return False

    def _polish(self, ctx) -> bool:
        """The SLSQP polish; True when the run must stop."""
        s = self.settings
        if ctx.remaining is not None and ctx.remaining <= 0:
            return ctx.check_stop()
        if ctx.best_x is None:  # nothing with finite values yet
            return False
        x0, free = face_of(ctx.best_x, self.space.lower, self.space.upper, s.active_tol)
        if not free.any():
            self.polished = dict(free=[], nfev=0, nit=0, message="every coordinate on a bound")
            return False
        idx = np.flatnonzero(free)
        task = _Task(_OnFace(ctx.objective, x0, idx), self.space.lower[idx], self.space.upper[idx],
                     self.compare, s.max_iter, s.ftol, 0.0)
        item = (0, x0[idx], ctx.remaining)
        [(_, res)] = list(ctx.map_unordered(functools.partial(_local_solve, task), [item]))
        x = x0.copy()
        x[idx] = res["x"]
        ctx.count_evaluations(res["nfev"])
        ctx.offer(x[None, :], np.array([res["f"]]), np.array([res["violation"]]),
                  np.asarray(res["g"], dtype=np.float64).reshape(1, -1))
        self.polished = dict(free=idx.tolist(), nfev=res["nfev"], nit=res["nit"], message=res["message"])
        if ctx.record_epoch(np.array([res["f"]]), np.array([res["violation"]])):
            return True
        if ctx.max_evals is None:
            ctx.stop_reason = "finished"
            return True
        return False
