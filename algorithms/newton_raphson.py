"""Newton-Raphson with finite-difference gradient and Hessian and a batched Armijo line search
(or the thesis' unit steps, ``line_search="unit"``).

Each iteration evaluates one derivative batch: the gradient stencil (step ``fd_step``, 2d
points) and the Hessian stencil (step ``hess_step``, ``d^2 + d + 1`` points, second-order
central formulas), then one line-search batch. The Hessian of the free coordinates is made
positive definite by eigenvalue modification (:func:`modify_eigenvalues`: each eigenvalue
``l -> max(|l|, eig_floor * max(1, max|l|))``), and the direction is ``d_F = -(B_FF)^-1 g_F``.
Finite differences, bounds, the static penalty for constraints, fallbacks, convergence and
restarts: see ``algorithms/_gradient.py``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from heurtune.algorithms._gradient import GradientOptimizer, GradientSettings, modify_eigenvalues
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class NewtonRaphsonSettings(GradientSettings):
    hess_step: float = dataclasses.field(default=1e-4, metadata={
        "help": "relative finite-difference step of the Hessian, h_i = hess_step*max(1,|x_i|)"})
    eig_floor: float = dataclasses.field(default=1e-8, metadata={
        "help": "smallest Hessian eigenvalue kept, relative to max(1, largest |eigenvalue|)"})

    def __post_init__(self):
        super().__post_init__()
        if not 0 < self.hess_step < 1:
            raise ValueError(f"hess_step must lie in (0, 1), got {self.hess_step}")
        if not 0 < self.eig_floor < 1:
            raise ValueError(f"eig_floor must lie in (0, 1), got {self.eig_floor}")


@register("newton_raphson", settings=NewtonRaphsonSettings,
          source="Nocedal & Wright, Numerical Optimization (2006), sec. 3.3-3.4 (modified Newton)",
          description=("Newton-Raphson, FD gradient + Hessian (eigenvalue-modified) + batched Armijo "
                       "line search (d^2 + 3d + 1 + K evaluations per iteration), or the thesis' unit step "
                       "x + d with line_search='unit' (d^2 + 3d + 2)"))
class NewtonRaphson(GradientOptimizer):
    uses_hessian = True

    def direction(self, g, free):
        d = np.zeros_like(g)
        if not np.any(free):
            return d
        B = self.hess * np.outer(self.scale, self.scale)  # Hessian in box units
        Q, lam = modify_eigenvalues(B[np.ix_(free, free)], self.settings.eig_floor)
        d[free] = -Q @ ((Q.T @ g[free]) / lam)
        return d
