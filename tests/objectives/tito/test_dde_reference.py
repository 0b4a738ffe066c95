"""The sampled TITO loop against an independent continuous-time reference (``tests/tito_dde_reference.py``:
the delay differential equations by the method of steps with ``solve_ivp``).

The sampled loop (``heurtune.objectives.tito.sim``) holds the plant exactly between samples but
runs the controllers and the decoupler as sampled-data systems, so it differs from the
continuous loop by terms of order ``dt``. Measured here on Wood-Berry with its GPM PI behind the
inverted decoupler (set-point steps, then input and output disturbances): the largest output
difference halves with ``dt`` (0.012 at the default dt = 0.1 s on unit steps over paper 001's
600 s scenario; this test runs 200 s of it),
and the reference agrees with itself across two solvers and tolerances (LSODA at 1e-10, RK45 at
1e-9: 4e-9 apart).
"""

import dataclasses

import numpy as np
import pytest
from numerics import assert_close
from tito_dde_reference import DDELoop

# the reference solved twice more at tight tolerances: `make test-long` (docs/testing.md, "Two tiers")
pytestmark = pytest.mark.long


@pytest.fixture(scope="module")
def reference(wood_berry, wood_berry_gpm_pi, wood_berry_reference):
    prob, sc = wood_berry
    times = np.arange(0.0, sc.horizon + 1e-9, 0.5)
    rk45 = DDELoop(prob.chain.plant, prob.chain.decoupler, wood_berry_gpm_pi[1], prob.N, sc).solve(
        rtol=1e-9, atol=1e-11, method="RK45")
    return times, {"LSODA": wood_berry_reference.outputs(times), "RK45": rk45.outputs(times)}


def test_the_reference_agrees_with_itself(reference):
    _, y = reference
    assert_close(y["RK45"], y["LSODA"], rtol=1e-6, atol=1e-6,
                 because="two integrators at rtol 1e-9 and 1e-10 (4e-9 apart here): the reference's own error")
    assert np.abs(y["LSODA"]).max() > 0.5  # the loop moved


def test_the_sampled_loop_converges_to_it_at_first_order(wood_berry, wood_berry_gpm_pi, reference):
    prob, sc = wood_berry
    x = wood_berry_gpm_pi[0]
    times, y = reference
    errors = []
    for dt in (0.1, 0.05, 0.025):
        df = prob.simulate(x, dataclasses.replace(sc, dt=dt))
        assert df.attrs["status"] == "ok"
        rows = np.rint(times / dt).astype(int)
        errors.append(float(np.abs(df[["y1", "y2"]].to_numpy()[rows] - y["LSODA"]).max()))
    # first order: each halving of dt halves the difference (ratios 2 within 15 %)
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(1.7 < r < 2.3 for r in ratios), (errors, ratios)
    # and at the default step the difference is real (the sampled-data controller), not rounding
    assert 1e-3 < errors[0] < 5e-2, errors
