"""Plant: presets, operating points, linearisation, zeros, uncertainty scaling."""

import dataclasses
import math

import numpy as np
import pytest
from numerics import assert_exact

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import kernels as _kernels
from heurtune.objectives.qtp.model import (
    PRESETS,
    QTPParams,
    is_minimum_phase,
    linearise,
    operating_point,
    preset,
    qtp_rhs,
    transmission_zeros,
)


@pytest.mark.parametrize("name, u0, h34", [
    # REFERENCE.md section 1, recomputed values printed to 4 decimals (tolerance: half a unit).
    ("min", (2.4958, 2.5877), (8.680, 8.074)),
    ("nmp", (2.4087, 2.4956), (22.901, 15.274)),
])
def test_thesis_operating_points(name, u0, h34):
    op = operating_point(preset(name))
    np.testing.assert_allclose(op.u, u0, atol=5e-5)
    np.testing.assert_allclose(op.h[2:], h34, atol=5e-4)
    np.testing.assert_allclose(op.h[:2], preset(name).levels)


@pytest.mark.parametrize("name", list(PRESETS))
def test_operating_point_is_an_equilibrium(name):
    p = preset(name)
    op = operating_point(p)
    # Flows are O(1e2) cm^3/s; a residual of 1e-10 cm/s is round-off.
    assert np.max(np.abs(qtp_rhs(op.h, op.u, p))) < 1e-10


def test_johansson_presets_match_published_values():
    # Johansson (2000): P- T = (62.7, 90.3, ...) s and v0 = 3.00 V; the published levels are
    # rounded, so the computed equilibrium agrees to rounding only (0.5 % on T1, T2; 3 % on v0).
    p = preset("P-")
    A, _, _ = linearise(p)
    T = -1.0 / np.diag(A)
    np.testing.assert_allclose(T[:2], (62.7, 90.3), rtol=5e-3)
    np.testing.assert_allclose(operating_point(p).u, (3.0, 3.0), rtol=3e-2)


@pytest.mark.parametrize("name", list(PRESETS))
def test_linearisation_matches_finite_differences(name):
    p = preset(name)
    op = operating_point(p)
    A, B, C = linearise(p, op)
    eps = 1e-5
    A_fd = np.column_stack([
        (qtp_rhs(op.h + eps * e, op.u, p) - qtp_rhs(op.h - eps * e, op.u, p)) / (2 * eps)
        for e in np.eye(4)
    ])
    B_fd = np.column_stack([
        (qtp_rhs(op.h, op.u + eps * e, p) - qtp_rhs(op.h, op.u - eps * e, p)) / (2 * eps)
        for e in np.eye(2)
    ])
    # Central differences: truncation O(eps^2) ~ 1e-10, round-off ~ 1e-16 / eps ~ 1e-11.
    np.testing.assert_allclose(A, A_fd, atol=1e-8)
    np.testing.assert_allclose(B, B_fd, atol=1e-8)
    assert_exact(C, [[1, 0, 0, 0], [0, 1, 0, 0]])


@pytest.mark.parametrize("name", list(PRESETS))
def test_kernel_rhs_matches_python_rhs(name):
    p = preset(name)
    c = _kernels.plant_coefficients(p.as_array())
    rng = np.random.default_rng(1)
    for _ in range(5):
        h = rng.uniform(-1, 30, 4)  # negative levels exercise the clip at zero
        u = rng.uniform(0, 5, 2)
        np.testing.assert_allclose(_kernels.qtp_rhs(h, u, c), qtp_rhs(h, u, p), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name, minimum_phase", [("min", True), ("nmp", False), ("P-", True), ("P+", False)])
def test_zeros_and_phase_classification(name, minimum_phase):
    p = preset(name)
    A, B, C = linearise(p)
    z = transmission_zeros(A, B, C)
    # Analytic: zeros solve (1 + s T3)(1 + s T4) = (1 - g1)(1 - g2) / (g1 g2).
    T3, T4 = -1 / A[2, 2], -1 / A[3, 3]
    g1, g2 = p.gamma
    eta = (1 - g1) * (1 - g2) / (g1 * g2)
    analytic = np.sort_complex(np.roots([T3 * T4, T3 + T4, 1 - eta]).astype(complex))
    np.testing.assert_allclose(z, analytic, rtol=1e-8)
    assert is_minimum_phase(p) is minimum_phase
    assert (1 < sum(p.gamma) < 2) is minimum_phase


def test_uncertainty_scaling_keeps_levels_and_time_constants():
    p = preset("min")
    for f in (0.7, 1.3):
        q = p.scaled(f)
        op, opq = operating_point(p), operating_point(q)
        np.testing.assert_allclose(opq.h, op.h, rtol=1e-12)
        np.testing.assert_allclose(opq.u, f * op.u, rtol=1e-12)
        np.testing.assert_allclose(np.diag(linearise(q)[0]), np.diag(linearise(p)[0]), rtol=1e-12)


def test_singular_valve_split_is_a_clear_error():
    p = dataclasses.replace(preset("min"), gamma=(0.4, 0.6))
    with pytest.raises(ConfigError, match="gamma1 \\+ gamma2 = 1"):
        operating_point(p)


def test_unreachable_levels_are_a_clear_error():
    p = dataclasses.replace(preset("min"), levels=(30.0, 1.0))
    with pytest.raises(ConfigError, match="must be positive"):
        operating_point(p)


@pytest.mark.parametrize("field, value", [
    ("gamma", (1.2, 0.5)), ("gamma", (0.5,)), ("A", (1, 1, 1, -1)), ("a", (1, 1, 1, math.nan)),
    ("levels", (10, 0)), ("k", "abc"),
])
def test_invalid_parameters_are_rejected(field, value):
    kwargs = dict(A=(1,) * 4, a=(0.1,) * 4, k=(1, 1), gamma=(0.6, 0.6), levels=(10, 10))
    kwargs[field] = value
    with pytest.raises(ConfigError, match=field):
        QTPParams(**kwargs)


def test_unknown_preset_lists_allowed():
    with pytest.raises(ConfigError, match="allowed: min, nmp, P-, P\\+"):
        preset("maximum")


def _rk4_reference(h, u, p, dt):
    """Textbook RK4 on the Python right-hand side (levels clipped at 0 under the roots)."""
    f = lambda x: qtp_rhs(x, u, p)  # noqa: E731
    k1 = f(h)
    k2 = f(h + 0.5 * dt * k1)
    k3 = f(h + 0.5 * dt * k2)
    k4 = f(h + dt * k3)
    return h + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


@pytest.mark.parametrize("name", ["min", "nmp"])
def test_kernel_rk4_step_is_textbook_rk4(name):
    """The rearranged kernel step equals textbook RK4, including its clipped fallback.

    Levels near zero (some stage argument negative, taking the fallback), a drained tank, a
    large step and ordinary levels; agreement to rounding (1e-12 relative to the level size).
    """
    p = preset(name)
    c = _kernels.plant_coefficients(p.as_array())
    rng = np.random.default_rng(2)
    cases = [(rng.uniform(0, 30, 4), rng.uniform(0, 5, 2), 0.01) for _ in range(20)]
    cases += [(np.array([1e-6, 5.0, 0.0, 2.0]), np.array([0.0, 0.0]), 0.01),
              (np.array([0.3, 0.2, 1e-4, 1e-3]), np.array([0.0, 1.0]), 0.5),
              (np.array([-0.1, 4.0, 3.0, -2.0]), np.array([2.0, 2.0]), 0.01)]
    for h, u, dt in cases:
        f = (c[6] * u[0], c[7] * u[1], c[8] * u[1], c[9] * u[0])
        got = np.array(_kernels._rk4_step(h[0], h[1], h[2], h[3], *f, c, dt))
        np.testing.assert_allclose(got, _rk4_reference(h, u, p, dt), rtol=1e-12, atol=1e-12)
    nan = np.array(_kernels._rk4_step(np.nan, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, c, 0.01))
    assert np.isnan(nan[0])
