"""QTP test cases shared by several test modules: gains, random stable controllers, and the
comparison of batched metrics with the one-candidate ones (see
``objectives/qtp/test_batch_kernels.py`` for why its tolerances are what they are)."""

import numpy as np
from numerics import assert_exact

from heurtune.objectives.qtp.controllers import ControllerDesignError
from heurtune.objectives.qtp.kernels import METRIC_NAMES

THESIS_MIN = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
                  Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)
THESIS_NMP = dict(Q11=1.0788, Q22=1.0036, Q33=0.1676, Q44=1.7933, R11=3.6276, R22=3.7317,
                  Ki1=6.9248, Ki2=2.6781, alpha1=0.8020, alpha2=0.8700)
# Weakly damped (closed-loop poles -0.005 +- 1.14j) inside the thesis bounds: the example.
WEAK = dict(Q11=2.5, Q22=2.5, Q33=2.5, Q44=2.5, R11=0.1, R22=0.1, Ki1=8.0, Ki2=8.0, alpha1=1.8, alpha2=1.8)
IOLQI_NMP = dict(Q11=2.4266, Q22=1.1754, Q33=0.1141, Q44=2.3565, R11=4.9639, R22=3.8190, Ki1=1.0003, Ki2=1.0205)

RTOL = 1e-12
ESS_ATOL = 1e-10
ESS = [METRIC_NAMES.index("ess1"), METRIC_NAMES.index("ess2")]
JDEV = [METRIC_NAMES.index("Jdev1"), METRIC_NAMES.index("Jdev2")]
J = [METRIC_NAMES.index("J1"), METRIC_NAMES.index("J2")]
TV = [METRIC_NAMES.index("TV1"), METRIC_NAMES.index("TV2")]
TV_RTOL = 1e-10


def stable_controllers(loop, n, seed):
    """n designable controllers with a stable linearised loop, drawn in the thesis bounds."""
    from heurtune.objectives.qtp.structures import decision_names, default_bounds

    names = decision_names(loop.kind)
    bounds = np.array([default_bounds(loop.kind)[k] for k in names])
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        x = bounds[:, 0] + rng.random(len(names)) * (bounds[:, 1] - bounds[:, 0])
        try:
            ctrl = loop.controller(dict(zip(names, x)))
        except ControllerDesignError:
            continue
        if loop.stability_margin(ctrl) < 0.0:
            out.append(ctrl)
    return out


def assert_metrics_close(got, ref):
    """Metrics of the batched paths against the one-candidate ones (arrays of any shape, the
    metrics on the last axis): RTOL relative; ess, TV and Jdev against their operands."""
    got, ref = np.asarray(got), np.asarray(ref)
    assert_exact(np.isnan(got), np.isnan(ref))  # the same candidates fail (NaN) both ways
    other = [j for j in range(len(METRIC_NAMES)) if j not in ESS + JDEV + TV]
    np.testing.assert_allclose(got[..., other], ref[..., other], rtol=RTOL, atol=0.0)
    np.testing.assert_allclose(got[..., TV], ref[..., TV], rtol=TV_RTOL, atol=0.0)
    np.testing.assert_allclose(got[..., ESS], ref[..., ESS], rtol=0.0, atol=ESS_ATOL)
    both = ~np.isnan(ref[..., JDEV])
    assert np.all(np.abs(got[..., JDEV] - ref[..., JDEV])[both] <= RTOL * ref[..., J][both])


def sampled_experiment(name, folder):
    """The shipped experiment ``name`` with ``[controller] sample_time = 0.01``: the sampled loop
    that was the default before the continuous-time loop (a config file written in ``folder``)."""
    import heurtune

    cfg = folder / f"{name}.toml"
    cfg.write_text(f'extends = "{name}"\n[controller]\nsample_time = 0.01\n')
    return heurtune.load_experiment(str(cfg))
