"""Seeded instances of a TITO plant: the tuning suite's plants around a preset (docs/suite.md).

Instance 1 of a case is its preset. Instance k > 1 multiplies the gain K, every lag time
constant and the dead time L of each of the four elements by its own factor drawn uniformly in
``1 +- width`` (``perturbation``: one half-width per key), from a generator seeded by
``(seed, case, k)``, the same plant for every suite problem on that case. Signs and lead times
are kept, so a plant keeps the sign pattern its decoupler and pairing were chosen for. A draw
whose steady-state gain matrix changes the sign of its determinant (the pairing's condition) is
drawn again.
"""

from __future__ import annotations

import zlib

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.tito.model import preset

# The parameters an instance perturbs (all relative half-widths).
PERTURBED = ("K", "lags", "L")
MAX_DRAWS = 1000


def instance_plant(case: str, instance: int, seed: int, perturbation: dict) -> dict:
    """The plant of ``instance`` (1-based) of a TITO preset, as ``plant.custom`` takes it.

    Parameters
    ----------
    case : str
        A TITO preset (``qts``, ``ccts``, ``csts``, ``two_tank``, ``wood_berry``).
    instance : int
    seed : int
        The suite's root seed.
    perturbation : dict
        Relative half-width per key of :data:`PERTURBED` (a missing key is not perturbed).

    Returns
    -------
    dict
        ``g11, g12, g21, g22``, each ``{K, leads, lags, L}``.

    Raises
    ------
    ConfigError
        An unknown perturbation key, or no valid draw in :data:`MAX_DRAWS`.
    """
    unknown = sorted(set(perturbation) - set(PERTURBED))
    if unknown:
        raise ConfigError(f"suite.perturbation.tito.{unknown[0]}: unknown key for the tito plant; allowed: "
                          f"{', '.join(PERTURBED)}")
    base = preset(case)
    keys = ("g11", "g12", "g21", "g22")

    def element(e, fk=1.0, flags=None, fl=1.0):
        lags = e.lags if flags is None else [t * f for t, f in zip(e.lags, flags)]
        return {"K": float(e.K * fk), "leads": [float(t) for t in e.leads], "lags": [float(t) for t in lags],
                "L": float(e.L * fl)}

    if instance == 1:
        return {k: element(getattr(base, k)) for k in keys}
    rng = np.random.default_rng([seed, zlib.crc32(case.encode()), instance])
    widths = {k: float(perturbation.get(k, 0.0)) for k in PERTURBED}
    sign = np.sign(base.g11.K * base.g22.K - base.g12.K * base.g21.K)
    for _ in range(MAX_DRAWS):
        out = {}
        for k in keys:
            e = getattr(base, k)
            fk = 1.0 + widths["K"] * rng.uniform(-1.0, 1.0)
            flags = 1.0 + widths["lags"] * rng.uniform(-1.0, 1.0, len(e.lags))
            fl = 1.0 + widths["L"] * rng.uniform(-1.0, 1.0)
            out[k] = element(e, fk, flags, fl)
        if np.sign(out["g11"]["K"] * out["g22"]["K"] - out["g12"]["K"] * out["g21"]["K"]) == sign:
            return out
    raise ConfigError(f"suite: no valid instance {instance} of plant {case!r} in {MAX_DRAWS} draws; narrow "
                      f"suite.perturbation.tito")
