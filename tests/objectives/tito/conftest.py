"""Fixtures shared by the TITO tests."""

import dataclasses
import warnings

import pytest

import heurtune


@pytest.fixture(scope="session")
def wood_berry(tmp_path_factory):
    """Wood-Berry behind its inverted decoupler (paper 001's chain) and a 200 s scenario of
    set-point steps, then input (60 s) and output (120 s) disturbances of 0.1: ``(problem,
    scenario)``."""
    cfg = tmp_path_factory.mktemp("wb") / "wood_berry.toml"
    cfg.write_text('extends = "paper_001"\n[plant]\ncases = ["wood_berry"]\n')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prob = heurtune.load_experiment(str(cfg)).problem("wood_berry")
    sc = dataclasses.replace(prob.scenario("nominal"), horizon=200.0, input_disturbance=(60.0, (0.1, 0.1)),
                             output_disturbance=(120.0, (0.1, 0.1)))
    return prob, sc


@pytest.fixture(scope="session")
def wood_berry_gpm_pi(wood_berry):
    """The GPM PI of the Wood-Berry loop: ``(decision vector, gains)`` with gains per loop
    ``(Kp, Ki, 0)``."""
    x = wood_berry[0].baseline("gpm")
    return x, ((x[0], x[1], 0.0), (x[3], x[4], 0.0))


@pytest.fixture(scope="session")
def wood_berry_reference(wood_berry, wood_berry_gpm_pi):
    """The method-of-steps reference of the Wood-Berry loop under its GPM PI (LSODA, rtol
    1e-10), solved once: a :class:`tito_dde_reference.DDELoop` to read outputs from."""
    from tito_dde_reference import DDELoop

    prob, sc = wood_berry
    return DDELoop(prob.chain.plant, prob.chain.decoupler, wood_berry_gpm_pi[1], prob.N, sc).solve(
        rtol=1e-10, atol=1e-12, method="LSODA")
