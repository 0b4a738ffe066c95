"""BFGS quasi-Newton method with finite-difference gradients and a batched Armijo line search
(or the thesis' unit steps, ``line_search="unit"``).

Inverse-Hessian update :func:`bfgs_update` (Nocedal & Wright 2006, eq. 6.17), skipped when the
curvature condition ``s^T y > 0`` fails; ``H_0 = I`` in box units (see
``QuasiNewtonOptimizer``). Finite differences, bounds, the static penalty for constraints,
fallbacks, convergence and restarts: see ``algorithms/_gradient.py``.
"""

from __future__ import annotations

import dataclasses

from heurtune.algorithms._gradient import GradientSettings, QuasiNewtonOptimizer, bfgs_update
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class BFGSSettings(GradientSettings):
    pass


@register("bfgs", settings=BFGSSettings,
          source="Broyden, Fletcher, Goldfarb, Shanno (1970); Nocedal & Wright (2006), sec. 6.1",
          description=("BFGS quasi-Newton, "
                       "FD gradient + batched Armijo line search (2d + K evaluations per iteration), or the "
                       "thesis' unit step x + d with line_search='unit' (2d + 1)"))
class BFGS(QuasiNewtonOptimizer):
    update = staticmethod(bfgs_update)
