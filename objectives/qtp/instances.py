"""Seeded instances of a QTP plant: the tuning suite's plants around a preset (docs/suite.md).

Instance 1 of a case is its preset. Instance k > 1 draws every perturbed parameter uniformly
within its half-width around the preset's, from a generator seeded by ``(seed, case, k)``: the same
plant for every suite problem on that case. The half-widths are relative for the tank and outlet
areas, the pump gains and the operating levels, absolute for the valve splits; a draw that moves
gamma1 + gamma2 across 1 (the case's phase: minimum or non-minimum phase), whose operating
voltages leave the pump range, or whose operating levels reach a rim, is drawn again.
"""

from __future__ import annotations

import dataclasses
import math
import zlib

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp.model import operating_point, preset

# The parameters an instance perturbs, and whether their half-width is relative.
PERTURBED = {"A": True, "a": True, "k": True, "levels": True, "gamma": False}
MAX_DRAWS = 1000


def instance_plant(case: str, instance: int, seed: int, perturbation: dict) -> dict:
    """The plant parameters of ``instance`` (1-based) of a QTP preset, as ``plant.custom`` takes them.

    Parameters
    ----------
    case : str
        A QTP preset (``min``, ``nmp``, ``P-``, ``P+``).
    instance : int
    seed : int
        The suite's root seed.
    perturbation : dict
        Half-width per parameter (keys of :data:`PERTURBED`; a missing key is not perturbed).

    Returns
    -------
    dict
        ``A, a, k, gamma, levels`` and, where the preset has them, ``height, u_range``.

    Raises
    ------
    ConfigError
        An unknown perturbation key, or no valid draw in :data:`MAX_DRAWS`.
    """
    unknown = sorted(set(perturbation) - set(PERTURBED))
    if unknown:
        raise ConfigError(f"suite.perturbation.qtp.{unknown[0]}: unknown key for the qtp plant; allowed: "
                          f"{', '.join(PERTURBED)}")
    base = preset(case)
    out = dict(A=list(base.A), a=list(base.a), k=list(base.k), gamma=list(base.gamma), levels=list(base.levels))
    if base.height is not None:
        out.update(height=list(base.height))
    if base.u_range is not None:
        out.update(u_range=list(base.u_range))
    if instance == 1:
        return out
    rng = np.random.default_rng([seed, zlib.crc32(case.encode()), instance])
    phase = sum(base.gamma) > 1.0
    lo, hi = base.u_range if base.u_range is not None else (0.0, math.inf)
    for _ in range(MAX_DRAWS):
        draw = dict(out)
        for key, relative in PERTURBED.items():
            width = float(perturbation.get(key, 0.0))
            values = np.asarray(getattr(base, key), dtype=float)
            u = rng.uniform(-1.0, 1.0, values.size)
            draw[key] = [float(v) for v in (values * (1.0 + width * u) if relative else values + width * u)]
        if (sum(draw["gamma"]) > 1.0) != phase or not all(0.0 < g < 1.0 for g in draw["gamma"]):
            continue
        params = dataclasses.replace(base, A=tuple(draw["A"]), a=tuple(draw["a"]), k=tuple(draw["k"]),
                                     gamma=tuple(draw["gamma"]), levels=tuple(draw["levels"]))
        try:
            op = operating_point(params)
        except ConfigError:
            continue
        if np.all(op.u > lo) and np.all(op.u < hi) and (base.height is None or np.all(op.h < base.height)):
            return draw
    raise ConfigError(f"suite: no valid instance {instance} of plant {case!r} in {MAX_DRAWS} draws; narrow "
                      f"suite.perturbation.qtp")
