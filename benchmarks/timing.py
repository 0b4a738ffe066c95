"""The timing the benchmarks share: the median of repeated calls after one warm-up call."""

import time

import numpy as np


def median_seconds(fn, repeats: int) -> float:
    """Median wall time (s) of ``repeats`` calls of ``fn`` after one call that is not timed
    (compilation, caches)."""
    fn()
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t0)
    return float(np.median(runs))
