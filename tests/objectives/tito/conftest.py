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
