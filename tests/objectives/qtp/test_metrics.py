"""Metrics of sampled responses on synthetic signals with known answers."""

import math

import numpy as np
import pytest

from heurtune.objectives.qtp.kernels import METRIC_NAMES, N_METRICS, loop_metrics

DT = 0.01
T = 350.0
TD = 50.0
N = int(round(T / DT))
I_D = int(round(TD / DT))
t = np.arange(N + 1) * DT
Y0 = np.array([16.0, 12.0])
U0 = np.array([2.5, 3.0])


def metrics(y, u, band=3.0):
    out = np.empty(N_METRICS)
    loop_metrics(y, u, Y0, U0, DT, I_D, band, out)
    return dict(zip(METRIC_NAMES, out))


def decaying(amplitude, tau):
    """y_i = y0_i + amplitude_i exp(-(t - td) / tau) after td, y0 before."""
    y = np.tile(Y0, (N + 1, 1)).astype(float)
    after = t >= TD
    for i in range(2):
        y[after, i] += amplitude[i] * np.exp(-(t[after] - TD) / tau)
    return y


def test_exponential_decay():
    amp, tau = np.array([1.0, -1.5]), 8.0
    m = metrics(decaying(amp, tau), np.tile(U0, (N + 1, 1)))
    for i, (a, y0) in enumerate(zip(amp, Y0), start=1):
        band = 0.03 * y0
        assert m[f"Mp{i}"] == pytest.approx(abs(a) / y0 * 100, rel=1e-12)
        # ts = tau ln(|a| / band); linear interpolation between samples errs by O(dt^2 / tau).
        assert m[f"ts{i}"] == pytest.approx(tau * math.log(abs(a) / band), abs=1e-4)
        assert m[f"ess{i}"] == pytest.approx(abs(a) * math.exp(-(T - TD) / tau) / y0 * 100, rel=1e-9)
        L = T - TD
        # Trapezoid rule: relative error ~ dt^2 / (12 tau^2) ~ 1e-7.
        assert m[f"IAE{i}"] == pytest.approx(abs(a) * tau * (1 - math.exp(-L / tau)), rel=1e-6)
        assert m[f"ISE{i}"] == pytest.approx(a * a * tau / 2 * (1 - math.exp(-2 * L / tau)), rel=1e-6)
        itae = abs(a) * tau * (TD + tau)  # integral of t e^{-(t - td)/tau} over [td, inf)
        assert m[f"ITAE{i}"] == pytest.approx(itae, rel=1e-6)


def test_deviation_before_the_disturbance_is_ignored_by_mp_and_ts():
    y = np.tile(Y0, (N + 1, 1)).astype(float)
    y[100, 0] += 5.0  # a spike at t = 1 s, before td
    m = metrics(y, np.tile(U0, (N + 1, 1)))
    assert m["Mp1"] == 0.0 and m["ts1"] == 0.0  # exact: no deviation after td, 0 - 0
    assert m["IAE1"] == pytest.approx(5.0 * DT)  # but the integrals see it (trapezoid: 2 x dt/2)


def test_settling_when_the_band_is_never_left_or_never_reached():
    y = decaying(np.array([0.1, 1.0]), 1e9)  # output 2 stays 1 cm off: never settles
    m = metrics(y, np.tile(U0, (N + 1, 1)))
    assert m["ts1"] == 0.0  # exact: never outside the band (0.1 cm < 3 % of 16 cm)
    assert m["ts2"] == pytest.approx(T - TD)


def test_settling_uses_the_last_exit_from_the_band():
    y = np.tile(Y0, (N + 1, 1)).astype(float)
    band = 0.03 * Y0[0]
    y[I_D:, 0] += 2 * band
    k_exit = I_D + 2000  # back inside from t = 70 s ...
    y[k_exit:, 0] = Y0[0]
    y[I_D + 5000, 0] += 3 * band  # ... but one excursion at t = 100 s
    m = metrics(y, np.tile(U0, (N + 1, 1)))
    # The crossing is interpolated between the outside sample at 100 s and the inside one after:
    # |dev| goes 3 band -> 0 over one step, crossing the band at 2/3 of it.
    assert m["ts1"] == pytest.approx(100.0 - TD + DT * 2 / 3, abs=1e-9)


def test_effort_and_total_variation():
    u = np.tile(U0, (N + 1, 1)).astype(float)
    u[I_D:, 1] = U0[1] - 0.5  # a step down at td
    m = metrics(np.tile(Y0, (N + 1, 1)).astype(float), u)
    # The held input makes the rectangle rule exact (the last sample u[N] is not held).
    assert m["J1"] == pytest.approx(U0[0] ** 2 * T, rel=1e-12)
    assert m["J2"] == pytest.approx(U0[1] ** 2 * TD + (U0[1] - 0.5) ** 2 * (T - TD), rel=1e-12)
    assert m["Jdev1"] == 0.0  # exact: u1 - u_op is 0 - 0 at every sample
    assert m["Jdev2"] == pytest.approx(0.25 * (T - TD), rel=1e-12)
    assert m["TV1"] == 0.0 and m["TV2"] == pytest.approx(0.5)  # TV1 exact: differences of equal samples


def reference_metrics(y, u, y0, u0, dt, i_d, band_pct):
    """The metric definitions written out with numpy, sample by sample where it matters."""
    n = y.shape[0] - 1
    out = {}
    for i in range(2):
        a = np.abs(y[:, i] - y0[i])
        band = band_pct / 100.0 * y0[i]
        out[f"Mp{i + 1}"] = a[i_d:].max() / y0[i] * 100 if i_d <= n else 0.0
        outside = np.flatnonzero(a[i_d:] > band) + i_d
        if outside.size == 0:
            ts = 0.0
        elif outside[-1] >= n:
            ts = (n - i_d) * dt
        else:
            last = outside[-1]
            a0, a1 = a[last], a[last + 1]
            ts = (last - i_d + ((a0 - band) / (a0 - a1) if a0 > a1 else 1.0)) * dt
        out[f"ts{i + 1}"] = ts
        out[f"ess{i + 1}"] = a[n] / y0[i] * 100
        left = a[:-1].copy()
        right = a[1:].copy()
        if 1 <= i_d <= n:
            right[i_d - 1] = left[i_d - 1]  # the jump at t_d: the left value holds
        k = np.arange(1, n + 1)
        out[f"IAE{i + 1}"] = 0.5 * dt * np.sum(left + right)
        out[f"ISE{i + 1}"] = 0.5 * dt * np.sum(left ** 2 + right ** 2)
        out[f"ITAE{i + 1}"] = 0.5 * dt * dt * np.sum((k - 1) * left + k * right)
    for j in range(2):
        out[f"J{j + 1}"] = dt * np.sum(u[:-1, j] ** 2)
        out[f"Jdev{j + 1}"] = dt * np.sum((u[:-1, j] - u0[j]) ** 2)
        out[f"TV{j + 1}"] = np.sum(np.abs(np.diff(u[:, j])))
    return out


@pytest.mark.parametrize("n, i_d, last_exit", [
    (1000, 256, 255), (1000, 256, 256), (1000, 255, 511), (1000, 0, 999), (1000, 1000, 1000),
    (1000, 300, 767), (513, 100, 511), (513, 100, 512), (40, 5, 20),
])
def test_block_folds_match_the_definitions(n, i_d, last_exit):
    """loop_metrics folds samples in blocks of METRIC_BLOCK; exits and t_d on block edges.

    Random signals that leave the band last at ``last_exit`` (or never, when it precedes t_d).
    The folds reassociate the sums: agreement to 1e-11 relative.
    """
    rng = np.random.default_rng(n + i_d + last_exit)
    y0, u0 = np.array([16.0, 12.0]), np.array([2.5, 3.0])
    band = 3.0
    y = y0 + rng.uniform(-0.2, 0.2, (n + 1, 2)) * band / 100 * y0  # inside the band
    y[last_exit, :] = y0 * (1 + rng.uniform(1.5, 3.0, 2) * band / 100)
    y[: last_exit // 2, 1] += 0.1 * y0[1]  # a second output with an earlier excursion
    u = u0 + rng.normal(0, 0.3, (n + 1, 2))
    out = np.empty(N_METRICS)
    loop_metrics(y, u, y0, u0, 0.01, i_d, band, out)
    got = dict(zip(METRIC_NAMES, out))
    ref = reference_metrics(y, u, y0, u0, 0.01, i_d, band)
    for name in ref:  # the 18 performance metrics (the range ones need levels)
        assert got[name] == pytest.approx(ref[name], rel=1e-11, abs=1e-12), name
