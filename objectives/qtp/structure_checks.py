"""The QTP's contract for controller structures, as checks any structure can be run through.

``python -m heurtune.check_plugin my_structure.py`` runs them on a plugin's structures (the test
suite on every shipped one). Each returns ``(name, passed, one-line reason)``:

- ``design``: the centre of the default bounds designs a LinearController whose matrices have
  the kernels' shapes (``B`` (nz, 4), ``C`` (2, nz), ``D`` (2, 4)), are finite, and whose blocks
  cover the states in order with a pump (0 or 1) each;
- ``pairing``: a paired structure designs differently under the diagonal and the anti-diagonal
  pairing (a design that ignores ``options["pairing"]`` fails);
- ``deterministic``: designing the same values twice gives the same matrices, bit for bit;
- ``corners``: every corner of the default bounds designs, or fails with a ControllerDesignError
  (a reason the evaluation counts), never another exception;
- ``simulates``: a 60 s disturbance scenario of the centre's loop gives finite metrics, or a
  flagged divergence, on min and nmp;
- ``batch``: a batched design, where one is declared, equals the design row by row (1e-12);
- ``pickles``: a loop of the structure survives pickling (workers receive loops by pickle);
- ``variables``: each variable, moved towards the far end of its bounds at the centre and at a
  random point, changes a metric of the 60 s disturbance scenario on min (a variable the design
  does not read fails, named, unless the structure declares it in ``extras["unread"]``, as LADR
  does for the gains of its tracking differentiator; the experiment runner warns about such
  variables too, :mod:`heurtune.core.dead_variables`).
"""

from __future__ import annotations

import itertools
import pickle

import numpy as np

from heurtune.core.contract import run_named_checks
from heurtune.core.structures import register_checks
from heurtune.objectives.qtp.controllers import N_INPUTS, N_MEASURED, ControllerDesignError, LinearController
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset

__all__ = ["CHECKS", "run_checks"]


def _loop(structure, case="min"):
    return ClosedLoop(preset(case), structure.name)


def _centre(structure) -> dict:
    return {v: 0.5 * (structure.bounds[v][0] + structure.bounds[v][1]) for v in structure.variables}


def check_design(structure):
    ctrl = _loop(structure).controller(_centre(structure))
    assert isinstance(ctrl, LinearController), f"design returned {type(ctrl).__name__}, not a LinearController"
    nz = ctrl.A.shape[0]
    for name, shape in (("A", (nz, nz)), ("B", (nz, N_MEASURED)), ("C", (N_INPUTS, nz)), ("D", (N_INPUTS, N_MEASURED))):
        M = getattr(ctrl, name)
        assert M.shape == shape, f"{name} has shape {M.shape}, the kernels need {shape}"
        assert np.all(np.isfinite(M)), f"{name} is not finite"
    stops = [0] + [b for _, b in ctrl.blocks]
    assert [a for a, _ in ctrl.blocks] == stops[:-1] and stops[-1] == nz, "blocks must cover the states in order"
    assert len(ctrl.block_channel) == len(ctrl.blocks) and set(ctrl.block_channel) <= {0, 1}, \
        "block_channel needs a pump (0 or 1) per block"
    declared = bool(structure.extras.get("reads_reference"))
    assert ctrl.reads_reference == declared, (
        "the design returns Br and Dr but the structure does not declare extras['reads_reference']" if not declared
        else "extras['reads_reference'] is declared but the design returns no Br, Dr")
    if declared:
        assert np.all(np.isfinite(ctrl.Br)) and np.all(np.isfinite(ctrl.Dr)), "Br or Dr is not finite"


def check_pairing(structure):
    if not structure.paired:
        return
    x = _centre(structure)
    diag = ClosedLoop(preset("min"), structure.name, pairing="diagonal").controller(x)
    anti = ClosedLoop(preset("min"), structure.name, pairing="anti-diagonal").controller(x)
    same = all(np.array_equal(getattr(diag, n), getattr(anti, n)) for n in ("A", "B", "C", "D"))
    assert not same, ("the diagonal and anti-diagonal pairings design the same controller: read "
                      "options['pairing'] (or declare integral_action 'full' or 'none')")


def check_deterministic(structure):
    loop, x = _loop(structure), _centre(structure)
    a, b = loop.controller(x), loop.controller(x)
    for name in ("A", "B", "C", "D"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), f"two designs of the same values differ in {name}"


def check_corners(structure):
    loop = _loop(structure)
    corners = itertools.product(*[structure.bounds[v] for v in structure.variables])
    for corner in itertools.islice(corners, 64):
        try:
            loop.controller(dict(zip(structure.variables, corner)))
        except ControllerDesignError:
            pass
        except Exception as exc:  # noqa: BLE001 - the check reports what escaped
            raise AssertionError(f"a corner of the bounds raised {type(exc).__name__}: {exc} "
                                 "(raise ControllerDesignError for a candidate without a controller)") from None


def check_simulates(structure):
    for case in ("min", "nmp"):
        loop = _loop(structure, case)
        sim = loop.run(loop.controller(_centre(structure)), Scenario(horizon=60.0, disturbance_time=10.0), record=False)
        assert sim.diverged or np.all(np.isfinite(sim.metrics)), f"{case}: finite metrics or a flagged divergence"


def check_batch(structure):
    if structure.batch_design is None:
        return
    loop = _loop(structure)
    rng = np.random.default_rng(0)
    lo = np.array([structure.bounds[v][0] for v in structure.variables])
    hi = np.array([structure.bounds[v][1] for v in structure.variables])
    X = lo + (hi - lo) * rng.random((6, lo.size))
    built = structure.batch_design(X, structure.variables, loop.plant_linearisation, loop.options)
    for x, b in zip(X, built):
        try:
            one = loop.controller(dict(zip(structure.variables, x)))
        except ControllerDesignError:
            assert isinstance(b, ControllerDesignError), "the batch designed a candidate the design refuses"
            continue
        for name in ("A", "B", "C", "D"):
            np.testing.assert_allclose(getattr(b, name), getattr(one, name), rtol=1e-12, atol=1e-12,
                                       err_msg=f"batched {name} differs from the design's")


def check_pickles(structure):
    loop = _loop(structure)
    again = pickle.loads(pickle.dumps(loop))
    x = _centre(structure)
    assert np.array_equal(again.controller(x).D, loop.controller(x).D), "an unpickled loop designs differently"


def check_variables(structure):
    loop = _loop(structure)
    reads = bool(structure.extras.get("reads_reference"))
    # a structure that reads the reference is moved by a set-point step as well
    scenario = (Scenario(horizon=60.0, disturbance_time=30.0, setpoint_step=(1.0, 1.0), setpoint_time=5.0) if reads
                else Scenario(horizon=60.0, disturbance_time=10.0))
    lo = np.array([structure.bounds[v][0] for v in structure.variables], dtype=float)
    hi = np.array([structure.bounds[v][1] for v in structure.variables], dtype=float)
    points = [0.5 * (lo + hi), lo + (hi - lo) * np.random.default_rng(0).random(lo.size)]

    def metrics(x):
        try:
            sim = loop.run(loop.controller(dict(zip(structure.variables, x))), scenario, record=False)
        except ControllerDesignError:
            return None
        return np.asarray(sim.metrics, dtype=float)

    alive = hi <= lo  # fixed by its bounds: not searched
    for x in points:
        before = metrics(x)
        if before is None:
            continue
        for i in np.flatnonzero(~alive):
            y = x.copy()
            far = lo[i] if x[i] - lo[i] > hi[i] - x[i] else hi[i]
            y[i] = x[i] + 0.75 * (far - x[i])
            after = metrics(y)
            alive[i] = after is None or not np.array_equal(after, before, equal_nan=True)
    declared = set(structure.extras.get("unread", ()))
    dead = [v for v, a in zip(structure.variables, alive) if not a and v not in declared]
    what = "a set-point and a disturbance step" if reads else "a disturbance scenario"
    hint = "" if reads else " (a set-point weight needs extras['reads_reference'] and Br, Dr)"
    assert not dead, (f"{', '.join(dead)} change{'s' if len(dead) == 1 else ''} no metric of {what}: the design "
                      f"does not read them{hint}, or declare them in extras['unread']")
    read = [v for v, a in zip(structure.variables, alive) if a and v in declared]
    assert not read, f"{', '.join(read)} declared unread (extras['unread']) but change a metric"


CHECKS = {
    "design": check_design,
    "pairing": check_pairing,
    "deterministic": check_deterministic,
    "corners": check_corners,
    "simulates": check_simulates,
    "batch": check_batch,
    "pickles": check_pickles,
    "variables": check_variables,
}


def run_checks(structure) -> list:
    """``[(check, passed, reason), ...]`` of :data:`CHECKS` on ``structure``.

    Parameters
    ----------
    structure : ControllerStructure

    Returns
    -------
    list of (str, bool, str)
    """
    return run_named_checks(CHECKS, structure)


register_checks("qtp", run_checks)
