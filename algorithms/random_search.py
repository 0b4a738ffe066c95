"""Pure random search: every generation draws ``n`` points uniformly in the box.

The floor every tuning method must beat, and the reference of the tuning suite's easiest
targets (``heurtune.suite``: the median best value random search reaches at the budget, as
COCO places its targets). Nothing is learned from the evaluations; the engine keeps the best
so far by its own comparator (Deb's rules or the penalty), as for every optimiser, and with
several objectives the front of everything drawn (so it is also the floor of the suite's
multi-objective problems).
"""

from __future__ import annotations

import dataclasses

from heurtune.core.engine import Optimizer
from heurtune.core.registry import register


@dataclasses.dataclass(frozen=True)
class RandomSearchSettings:
    n: int = dataclasses.field(default=25, metadata={"help": "points drawn per generation"})

    def __post_init__(self):
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")


@register(
    "random_search",
    settings=RandomSearchSettings,
    multi_objective=True,
    source="Brooks (1958); the baseline of COCO's and IOHprofiler's benchmarks",
    description="Random search: n points uniform in the box per generation (the floor to beat)",
)
class RandomSearch(Optimizer):
    def ask(self):
        return self.space.uniform(self.rng, self.settings.n)

    def tell(self, X, f, v):
        self.X, self.f, self.v = X.copy(), f.copy(), v.copy()
        return True
