"""Steepest descent with finite-difference gradients and a batched Armijo line search
(or the thesis' unit steps, ``line_search="unit"``).

Direction ``-g`` on the free coordinates (projected gradient), normalised so that ``t = 1``
moves the largest component by one box width; trial steps ``t_0 r^k`` with an adaptive ``t_0``
(twice the last accepted step, capped at ``max_step``). Finite differences, bounds, the static
penalty for constraints, convergence and restarts: see ``algorithms/_gradient.py``.
"""

from __future__ import annotations

import dataclasses

from heurtune.algorithms._gradient import GradientOptimizer, GradientSettings
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class SteepestDescentSettings(GradientSettings):
    pass


@register("steepest_descent", settings=SteepestDescentSettings,
          source="Cauchy (1847); Nocedal & Wright, Numerical Optimization (2006), ch. 3",
          description=("Steepest descent, "
                       "FD gradient + batched Armijo line search (2d + K evaluations per iteration), or the "
                       "full gradient step u - grad_u f in box units with line_search='unit' (2d + 1)"))
class SteepestDescent(GradientOptimizer):
    steepest = True

    def direction(self, g, free):
        return -g
