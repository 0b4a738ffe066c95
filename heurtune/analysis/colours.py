"""One colour per algorithm and per controller structure, the same in every figure and report.

A name keeps its colour whatever else a figure shows: the shipped optimisers and structures
have fixed places in a 20-colour palette (tab10, then tab20's lighter shades), and any other
name takes the place a stable hash of it gives (CRC-32, not Python's salted ``hash``). Only
when two names of one figure land on the same place does the later of them, in sorted order,
move to the next free one. A label is coloured by its base name, lower case, before any
`` [variant]`` or `` (run 3)`` suffix: ``"CS"``, ``"cs"`` and ``"cs [seed1]"`` share cuckoo
search's colour unless they appear together (then the variants move on).
"""

from __future__ import annotations

import zlib

import matplotlib

# The palette: tab10's ten colours, then tab20's ten lighter shades.
_N_PALETTE = 20

# Places in the palette: optimisers (the shipped ones, then the analytic baselines) and, in a
# separate range of the same palette (a figure compares algorithms or structures, not both),
# the QTP's and TITO's structures. Random search, the suite's floor, is grey.
FIXED = {
    "cs": 0, "apso": 1, "pso": 2, "firefly": 3, "ga": 4, "cmaes": 5, "cmaes_sqp": 6, "random_search": 7,
    "lshade": 8, "jso": 9, "sqp_multistart": 10, "nsga2": 11, "sms_emoa": 12, "bfgs": 13, "dfp": 14,
    "steepest_descent": 15, "newton_raphson": 16, "gpm": 17, "sqp": 10,
    "folqi": 0, "iolqi": 1, "ladr": 2, "lqi": 3, "pid": 4, "fopid": 5, "pi2dof": 6, "2-dof pi": 6,
}


def _palette(i: int):
    if i < 10:
        return matplotlib.colormaps["tab10"](i)
    return matplotlib.colormaps["tab20"](2 * (i - 10) + 1)


def base_name(label) -> str:
    """The name a label is coloured by: lower case, without a ``" [variant]"`` or ``" (...)"``
    suffix.

    Parameters
    ----------
    label : object

    Returns
    -------
    str
    """
    return str(label).split(" [", 1)[0].split(" (", 1)[0].strip().lower()


def preferred_place(label) -> int:
    """The palette place of ``label`` when no other name of its figure holds it.

    Parameters
    ----------
    label : object

    Returns
    -------
    int
    """
    name = base_name(label)
    if name in FIXED:
        return FIXED[name]
    return zlib.crc32(name.encode("utf-8")) % _N_PALETTE


def colours_of(labels) -> dict:
    """One colour per label of a figure: each its preferred place, a clash moved on.

    Parameters
    ----------
    labels : iterable
        The labels (repeats are fine).

    Returns
    -------
    dict
        Label (as given) to an RGBA colour.
    """
    taken, out = set(), {}
    for label in sorted(set(labels), key=str):
        place = preferred_place(label)
        for k in range(_N_PALETTE):
            if (place + k) % _N_PALETTE not in taken:
                place = (place + k) % _N_PALETTE
                break
        taken.add(place)
        out[label] = _palette(place)
    return out
