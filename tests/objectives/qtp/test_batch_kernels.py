"""The batched QTP simulations (CPU lanes and the CUDA kernel) against the one-candidate kernel.

Every driver of the sampled loop runs one per-lane function, ``kernels.sampled_lane``: the
one-candidate path, the lanes of ``cpu-batch`` (``kernels.simulate_lanes``) and, compiled from
its source as a device function, the CUDA kernel. With the same controllers, ``cpu-batch`` runs
the same compiled code as ``cpu`` and gives its metrics bit for bit.

Tolerance, where the numbers may part. The CUDA kernel, run here by Numba's simulator in plain
Python (no fused multiply-adds, sums in order), and a problem's batched design (another Riccati
algorithm) round differently: the metrics agree within ``RTOL = 1e-12`` relative. Two metrics
are differences of nearly equal numbers, whose rounding is relative to the numbers, not to their
difference: ``ess``, the last deviation from the operating level in percent of it, is compared
with the absolute tolerance ``ESS_ATOL = 1e-10`` percent (a level within 1e-12 of the operating
level), and ``Jdev``, the integral of (u - u_op)^2, with ``RTOL`` times ``J``, the integral of
u^2. ``TV``, a sum of differences of consecutive voltages, gets ``TV_RTOL = 1e-10`` (measured:
2.3e-12).
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from numerics import assert_close, assert_exact, assert_same_bits
from qtp_cases import RTOL, assert_metrics_close, stable_controllers

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import gpu
from heurtune.objectives.qtp.controllers import LinearController
from heurtune.objectives.qtp.kernels import METRIC_NAMES
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset

# An unstable candidate's margin, the largest real part of its closed-loop eigenvalues, from
# numpy's stacked eigvals and from LAPACK dgeev called directly: two routes whose difference is
# bounded to first order by kappa eps |M| / |margin| (kappa the eigenvalue's condition number,
# |M| the norm of the balanced closed-loop matrix). On the candidates drawn here that is below
# 1e-8 (kappa < 1.5e3, |M| up to about 1e3 from the Oustaloup band, margins down to about 1e-3).
MARGIN_RTOL = 1e-7
MARGIN_BECAUSE = "eigenvalue margins by two LAPACK routes: kappa eps |M| / |margin| < 1e-8 on these candidates"
# The Riccati gains of the stacked eigenvectors and of the ordered Schur form: the Hamiltonians'
# eigenvector bases have condition numbers below 60 on the thesis bounds, so the two stable
# subspaces, and the gains, agree to about 2n eps cond^2 < 1e-11.
GAIN_RTOL = 1e-10
GAIN_BECAUSE = "Riccati gains by eigenvectors and by the Schur form: 2n eps cond(V)^2 < 1e-11 with cond(V) < 60"

SCENARIOS = {
    "nominal": Scenario(dt=0.01, horizon=120.0, disturbance_time=20.0),
    "noise_saturation": Scenario(dt=0.01, horizon=80.0, disturbance_time=10.0, noise_sd=0.05, noise_seed=3,
                                 saturation=(0.0, 4.0)),
    "uncertain_input_disturbance": Scenario(dt=0.01, horizon=80.0, uncertainty=1.3, input_disturbance=(0.3, -0.2),
                                            input_disturbance_time=20.0),
    "physical_limits": Scenario(dt=0.01, horizon=80.0, disturbance_time=10.0, output_disturbance=(8.0, -8.0),
                                limits="physical"),
    "coarse_step": Scenario(horizon=60.0, dt=0.05, disturbance_time=10.0),
}


@pytest.fixture(scope="module")
def folqi():
    loop = ClosedLoop(preset("min"), "folqi")
    return loop, stable_controllers(loop, 10, seed=1)


def test_batch_equals_the_one_candidate_kernel(folqi):
    loop, ctrls = folqi
    scenarios = list(SCENARIOS.values())
    diverged, metrics = loop.run_batch(ctrls, scenarios)
    for s, sc in enumerate(scenarios):
        ref = [loop.run(c, sc, record=False) for c in ctrls]
        assert list(diverged[:, s]) == [r.diverged for r in ref]
        # the lanes run the one-candidate kernel's own compiled loop: bit for bit
        assert_same_bits(metrics[:, s], [r.metrics for r in ref], because="shared kernel")
    # the physical-limits scenario reaches the limits (else it would test nothing)
    limited = metrics[:, list(SCENARIOS).index("physical_limits")]
    assert np.nanmin(limited[:, METRIC_NAMES.index("umin")]) == 0.0  # exact: clamped to the literal limit


@pytest.mark.parametrize("kind, plant_model", [("lqi", "qtp"), ("ladr", "qtp"), ("folqi", "qtp_bond_graph")])
def test_other_structures_and_the_pressure_model(kind, plant_model):
    loop = ClosedLoop(preset("min"), kind, plant_model=plant_model)
    ctrls = stable_controllers(loop, 4, seed=2)
    sc = SCENARIOS["noise_saturation"]
    diverged, metrics = loop.run_batch(ctrls, [sc])
    ref = [loop.run(c, sc, record=False) for c in ctrls]
    assert list(diverged[:, 0]) == [r.diverged for r in ref]
    assert_same_bits(metrics[:, 0], [r.metrics for r in ref], because="shared kernel")


def test_a_lane_does_not_depend_on_its_neighbours(folqi):
    """Bit for bit: a candidate's metrics are the same alone, in another order or in another
    batch, so that results do not depend on how the work is split."""
    loop, ctrls = folqi
    sc = SCENARIOS["noise_saturation"]
    _, together = loop.run_batch(ctrls, [sc])
    order = np.random.default_rng(0).permutation(len(ctrls))
    _, shuffled = loop.run_batch([ctrls[i] for i in order], [sc])
    assert_same_bits(shuffled[:, 0], together[order, 0], because="shared kernel")
    _, alone = loop.run_batch(ctrls[3:4], [sc])
    assert_same_bits(alone[0, 0], together[3, 0], because="shared kernel")


def test_a_diverging_lane_is_flagged_and_leaves_the_others_alone(folqi):
    loop, ctrls = folqi
    D = np.zeros((2, 4))
    D[0, 0] = D[1, 1] = 1e4  # strong positive feedback: floods and empties tanks
    bad = LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ())
    sc = SCENARIOS["nominal"]
    diverged, metrics = loop.run_batch([ctrls[0], bad, ctrls[1]], [sc])
    assert list(diverged[:, 0]) == [False, True, False]
    assert np.isnan(metrics[1, 0]).all()
    ref = [loop.run(c, sc, record=False).metrics for c in ctrls[:2]]
    assert_same_bits(metrics[[0, 2], 0], ref, because="shared kernel")


def test_problem_on_the_batched_device_equals_cpu():
    import heurtune

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    rng = np.random.default_rng(4)
    X = prob.lower + rng.random((12, prob.dim)) * (prob.upper - prob.lower)
    scs = [Scenario(dt=0.01, horizon=60.0, disturbance_time=10.0), SCENARIOS["noise_saturation"]]
    ref = prob.evaluate_scenarios(X, scs)
    prob.set_device("cpu-batch")
    got = prob.evaluate_scenarios(X, scs)
    for a, b in zip(ref, got):
        assert list(a.reason) == list(b.reason)
        assert set(a.reason) >= {"", "unstable"}  # both kinds of candidate in the batch
        assert_metrics_close(b.metrics, a.metrics)
        assert_exact(a.feasible, b.feasible)
        assert_close(b.f, a.f, rtol=RTOL, because="objectives of the metrics, within the metrics' RTOL (qtp_cases)")
        # an unstable candidate's violation grows with its eigenvalue margin, which the batched
        # design takes from numpy's stacked eigvals, another LAPACK route than dgeev called directly
        unstable = a.reason == "unstable"
        assert_close(b.g[~unstable], a.g[~unstable], rtol=RTOL, atol=1e-12,
                     because="constraints of the metrics, within the metrics' RTOL (qtp_cases)")
        assert_close(b.g[unstable], a.g[unstable], rtol=MARGIN_RTOL, because=MARGIN_BECAUSE)


def test_device_errors(monkeypatch):
    import heurtune

    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    with pytest.raises(ConfigError, match="device must be one of 'cpu', 'cpu-batch', 'gpu'.*got 'tpu'"):
        prob.set_device("tpu")
    monkeypatch.setattr(gpu, "available", lambda: False)
    with pytest.raises(ConfigError, match=r"device 'gpu' needs an NVIDIA GPU.*pip install 'heurtune\[gpu\]'"):
        prob.set_device("gpu")
    assert prob.device == "cpu"


def test_runner_rejects_a_device_without_a_gpu(tmp_path, capsys, monkeypatch):
    from heurtune.runner import experiment

    monkeypatch.setattr(gpu, "available", lambda: False)
    code = experiment.run(["cs_folqi_qtp", "--smoke", "--device", "gpu", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: device 'gpu' needs an NVIDIA GPU")
    assert not (tmp_path / "r" / "parts").exists()


_SIMULATED_GPU = r"""
import json, sys
import numpy as np
sys.path[:0] = sys.argv[1:3]
from test_batch_kernels import SCENARIOS
from qtp_cases import stable_controllers
from heurtune.objectives.qtp import gpu
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset
from heurtune.objectives.qtp.controllers import LinearController

assert gpu.available()
loop = ClosedLoop(preset("min"), "folqi")
ctrls = stable_controllers(loop, 2, seed=5)
D = np.zeros((2, 4)); D[0, 0] = D[1, 1] = 1e4
ctrls.append(LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ()))
scs = [Scenario(dt=0.01, horizon=3.0, disturbance_time=1.0),
       Scenario(dt=0.01, horizon=3.0, disturbance_time=1.0, noise_sd=0.05, saturation=(0.0, 3.0),
                input_disturbance=(0.2, 0.1), input_disturbance_time=0.5),
       Scenario(dt=0.01, horizon=3.0, disturbance_time=0.5, output_disturbance=(8.0, -8.0), limits="physical")]
diverged, metrics = loop.run_batch(ctrls, scs, device="gpu")
ref = [[loop.run(c, sc, record=False) for sc in scs] for c in ctrls]
print(json.dumps(dict(diverged=diverged.tolist(), metrics=metrics.tolist(),  # NaN travels as JSON NaN
                      ref_diverged=[[r.diverged for r in row] for row in ref],
                      ref=[[r.metrics.tolist() for r in row] for row in ref])))
"""


def test_gpu_kernel_under_the_cuda_simulator():
    """The CUDA kernel, run by Numba's CUDA simulator: 3 controllers (one diverging) under 3
    scenarios (saturation with noise and an input disturbance, physical limits), 300 steps."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    here = os.path.dirname(__file__)
    tests = os.path.dirname(os.path.dirname(here))
    out = subprocess.run([sys.executable, "-c", _SIMULATED_GPU, here, tests], env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["diverged"] == res["ref_diverged"]
    assert res["diverged"][2][0] and not any(res["diverged"][0])  # limits and saturation hold the flood
    assert_metrics_close(np.array(res["metrics"]), np.array(res["ref"]))


# -- the design of a batch ---------------------------------------------------------------------

@pytest.mark.parametrize("experiment, case", [("cs_folqi_qtp", "min"), ("cs_folqi_qtp", "nmp"),
                                              ("cs_iolqi_qtp", "min")])
def test_a_candidate_gets_the_same_result_alone_and_in_any_batch(experiment, case):
    """Bit for bit on the batched device: a candidate's design (gains, margin) and metrics do not
    depend on the candidates designed beside it or on their order, so a lockstep run reproduces
    whatever its batches. (numpy's stacked eig returns real eigenvectors only when all of a
    stack's eigenvalues are real; a real and a complex solve round differently, which moved the
    gains of 6 of these 30 FOLQI candidates before the Riccati solve was made complex always.)"""
    import heurtune

    prob = heurtune.load_experiment(experiment).problem(case)
    prob.set_device("cpu-batch")
    X = prob.lower + np.random.default_rng(5).random((30, prob.dim)) * (prob.upper - prob.lower)
    scs = [Scenario(horizon=60.0, disturbance_time=10.0)]
    together = prob.evaluate_scenarios(X, scs)[0]
    reversed_ = prob.evaluate_scenarios(X[::-1], scs)[0]
    for name in ("reason", "metrics", "f", "g"):
        assert_same_bits(getattr(reversed_, name)[::-1], getattr(together, name), because="shared kernel")
    for i in range(len(X)):
        alone = prob.evaluate_scenarios(X[i:i + 1], scs)[0]
        for name in ("reason", "metrics", "f", "g"):
            assert_same_bits(getattr(alone, name)[0], getattr(together, name)[i], because="shared kernel",
                             err_msg=f"{name}, {i}")


@pytest.mark.parametrize("experiment", ["cs_folqi_qtp", "cs_iolqi_qtp"])
def test_stacked_closed_loop_matrices_are_each_controllers_own(experiment):
    """The stability check of a batch assembles the closed-loop matrices of one size together;
    each must be the controller's ``closed_loop_matrix``: the same blocks, copied, and the same
    products ``B D`` and ``B C`` by numpy's stacked matmul instead of single ones (another BLAS
    call, which may round otherwise: two terms per entry, a few eps of ``|B| |D|``)."""
    import heurtune
    from heurtune.objectives.qtp.batch_design import _closed_loop_matrices

    prob = heurtune.load_experiment(experiment).problem("nmp")
    loop = prob.loop
    X = prob.lower + np.random.default_rng(3).random((60, prob.dim)) * (prob.upper - prob.lower)
    by_size = {}
    for x in X:
        ctrl = loop.controller(dict(zip(prob.names, x.tolist())))
        by_size.setdefault(ctrl.n_states, []).append(ctrl)
    assert len(by_size) >= (2 if experiment == "cs_folqi_qtp" else 1)  # orders with 0, 1 and 2 integrators
    for ctrls in by_size.values():
        M = _closed_loop_matrices(loop.A, loop.B, ctrls)
        for Mi, ctrl in zip(M, ctrls):
            ref = ctrl.closed_loop_matrix(loop.A, loop.B)
            scale = np.abs(loop.A).max() + (np.abs(loop.B) @ np.abs(np.hstack([ctrl.D, ctrl.C]))).max()
            assert_close(Mi, ref, rtol=1e-13, atol=1e-13 * scale,
                         because="stacked and single matmul, inner dimension 2: a few eps of |A| + |B| |D, C|")
            assert_exact(Mi[4:, 4:], ctrl.A)  # the blocks where they belong, copied
            assert_exact(Mi[4:, :4], ctrl.B)


@pytest.mark.parametrize("experiment, case, options", [
    ("cs_folqi_qtp", "min", {}), ("cs_folqi_qtp", "nmp", {}), ("cs_iolqi_qtp", "min", {}), ("cs_lqi_qtp", "min", {}),
    ("cs_folqi_qtp", "min", {"realisation": "integer_split"}), ("cs_folqi_qtp", "nmp", {"pairing": "anti-diagonal"}),
])
def test_batch_design_equals_the_one_candidate_design(experiment, case, options):
    """Same reasons for every candidate; gains to GAIN_RTOL (the stacked Riccati solution is
    another algorithm than the ordered Schur form); unstable margins to MARGIN_RTOL (numpy's
    stacked eigvals against LAPACK dgeev called directly); the integrators' poles, and the
    discretisation of the same controllers, bit for bit: the same numpy element-wise operations
    in the same order, on a stack instead of one candidate (no BLAS, no reduction)."""
    import heurtune
    from heurtune.objectives.qtp.batch_design import design_batch, discretise_many

    prob = heurtune.load_experiment(experiment).problem(case)
    if options:
        prob.loop.options.update(options)
    rng = np.random.default_rng(7)
    X = prob.lower + rng.random((120, prob.dim)) * (prob.upper - prob.lower)
    X[0, 0] = np.nan
    if "alpha1" in prob.names:  # integer orders, two integrators: the one-by-one paths
        X[1, prob.names.index("alpha1")] = 2.0
        X[2, prob.names.index("alpha2")] = 1.0
    ctrls, reasons, margins = design_batch(prob.loop, prob.names, X)
    designed = 0
    for i, x in enumerate(X):
        ctrl, reason, margin = prob._design(x)
        assert reasons[i] == reason
        if ctrl is not None:
            designed += 1
            assert_close(ctrls[i].D, ctrl.D, rtol=GAIN_RTOL, atol=GAIN_RTOL * np.abs(ctrl.D).max(),
                         because=GAIN_BECAUSE)
            assert_close(ctrls[i].C, ctrl.C, rtol=GAIN_RTOL, because=GAIN_BECAUSE)
            # the poles: batch_design._modal_integrators is oustaloup_zpk's formula on a stack
            assert_same_bits(ctrls[i].A, ctrl.A, because="same code")
            assert_exact(ctrls[i].B, ctrl.B)  # 0 and -1
            # the modal form the design hands the continuous loop: the same, where it has one
            assert (ctrls[i].modal_arrays is None) == (ctrl.modal_arrays is None)
            for got, ref in zip(ctrls[i].modal_arrays or (), ctrl.modal_arrays or ()):
                assert_same_bits(got, ref, because="same code")  # poles as A's, constants, indices
            for got, ref in zip(ctrls[i].modal_blocks(), ctrl.modal_blocks()):
                assert len(got) == len(ref) and got[0] == ref[0]
                for a, b in zip(got[1:], ref[1:]):  # arrays (C's with the gains), signal, pump
                    assert_close(a, b, rtol=GAIN_RTOL, because=GAIN_BECAUSE)
        if reason == "unstable":
            assert margins[i] == pytest.approx(margin, rel=MARGIN_RTOL)  # MARGIN_BECAUSE
    assert designed >= (1 if case == "nmp" else 5)
    good = [c for c in ctrls if c is not None]
    for fast, one in zip(discretise_many(good, 0.01), [c.discretise(0.01) for c in good]):
        for name in ("ad", "bd", "state_input", "Ad", "Bd", "Cc", "Dc", "state_channel", "segments"):
            # same bits: discretise_many is discretise's element-wise arithmetic on a stack
            assert_same_bits(getattr(fast, name), getattr(one, name), because="same code", err_msg=name)
