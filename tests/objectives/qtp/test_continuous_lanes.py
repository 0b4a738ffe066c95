"""One step for every driver of the continuous-time loop: the batched CPU lanes and the CUDA
kernel against the one-candidate path.

All three call ``continuous_kernels.continuous_lane``. The CPU lanes run the same compiled
function on the same inputs, so they are compared bit for bit. The CUDA kernel is that
function's Python source compiled again as a device function; Numba's CUDA simulator runs it in
plain Python (NumPy's and Python's arithmetic, not the compiled loops), so it may differ from
the compiled one-candidate path by rounding: the bounds of
``test_batch_kernels.assert_metrics_close`` (1e-12 relative; ``ess``, ``Jdev`` and ``TV``, the
differences of nearly equal numbers, against their operands). Measured: 2e-13 without switches;
with saturation and tank limits 3e-12 on ``ess`` (a located switch near a tangential crossing
moves by rounding divided by the slope of its switching function), within the bound.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from numerics import assert_exact, assert_same_bits
from qtp_cases import THESIS_MIN, WEAK, assert_metrics_close, stable_controllers

from heurtune.objectives.qtp.controllers import LinearController
from heurtune.objectives.qtp.loop import ClosedLoop, Scenario
from heurtune.objectives.qtp.model import preset

TOL = 0.005
SCENARIOS = [
    Scenario(horizon=40.0, disturbance_time=5.0, tolerance=TOL),
    Scenario(horizon=40.0, disturbance_time=5.0, tolerance=TOL, saturation=(2.2, 3.0), input_disturbance=(0.2, 0.1),
             input_disturbance_time=20.0),
    Scenario(horizon=40.0, disturbance_time=5.0, tolerance=TOL, output_disturbance=(8.0, -8.0), limits="physical"),
    Scenario(horizon=40.0, disturbance_time=5.0, step=0.5, uncertainty=1.3),
]


def static_gain(k):
    """A controller without states, ``u = -k e`` on the diagonal (k = -1e4 diverges)."""
    D = np.zeros((2, 4))
    D[0, 0] = D[1, 1] = -k
    return LinearController(np.zeros((0, 0)), np.zeros((0, 4)), np.zeros((2, 0)), D, (), ())


def one_by_one(loop, ctrls, scenarios):
    runs = [[loop.run(c, sc, record=False) for sc in scenarios] for c in ctrls]
    return np.array([[r.diverged for r in row] for row in runs]), np.array([[r.metrics for r in row] for row in runs])


# the integer split (a dense controller block, the weak candidate's long run one by one): 9 s on
# the EPYC, `make test-long`
@pytest.mark.parametrize("kind, options", [("folqi", {}), ("folqi", {"plant_model": "qtp_bond_graph"}),
                                           pytest.param("folqi", {"realisation": "integer_split"},
                                                        marks=pytest.mark.long), ("iolqi", {})])
def test_cpu_lanes_equal_the_one_candidate_path_bit_for_bit(kind, options):
    """Lanes of two structures in one batch (the modal controllers and a stateless one, which
    diverges in two scenarios): same flags, same metrics to the bit."""
    loop = ClosedLoop(preset("min"), kind, **options)
    ctrls = stable_controllers(loop, 3, seed=11) + [static_gain(-1e4), static_gain(3.0)]
    if kind == "folqi":
        ctrls += [loop.controller(THESIS_MIN), loop.controller(WEAK)]
    diverged, metrics = loop.run_batch(ctrls, SCENARIOS, device="cpu-batch")
    ref_diverged, ref_metrics = one_by_one(loop, ctrls, SCENARIOS)
    assert_exact(diverged, ref_diverged)
    assert diverged[-4 if kind == "folqi" else -2].any() and not diverged[:3].any()
    assert_same_bits(metrics, ref_metrics, because="shared kernel")


def test_cpu_lanes_with_dense_observers_and_mixed_devices():
    """LADR (dense observer blocks) in lanes, beside sampled scenarios in the same call."""
    from heurtune.objectives.qtp.structures import decision_names
    from heurtune.objectives.qtp.thesis.printed import printed_row

    row = printed_row("4.7", "min-ladr")
    loop = ClosedLoop(preset("min"), "ladr")
    ctrl = loop.controller({n: float(row[n]) for n in decision_names("ladr")})
    scenarios = SCENARIOS[:3] + [Scenario(dt=0.01, horizon=40.0, disturbance_time=5.0)]
    diverged, metrics = loop.run_batch([ctrl, ctrl], scenarios, device="cpu-batch")
    ref_diverged, ref_metrics = one_by_one(loop, [ctrl], scenarios)
    assert not diverged.any() and not ref_diverged.any()
    assert_same_bits(metrics[0, :3], ref_metrics[0, :3], because="shared kernel")
    assert_same_bits(metrics[0], metrics[1], because="shared kernel")  # a lane does not depend on its neighbour
    assert_metrics_close(metrics[0, 3], ref_metrics[0, 3])  # the sampled batch kernel's own bound


_SIMULATED_GPU = r"""
import dataclasses, json, sys
import numpy as np
sys.path[:0] = sys.argv[1:3]
from test_continuous_lanes import SCENARIOS, static_gain
from qtp_cases import THESIS_MIN, WEAK
from heurtune.objectives.qtp import gpu
from heurtune.objectives.qtp.loop import ClosedLoop
from heurtune.objectives.qtp.model import preset

assert gpu.available()
loop = ClosedLoop(preset("min"), "folqi")
# -8 diverges on the plain scenario within the structure's step; a larger positive feedback
# (-1e4) would make feedback_step shrink its step to 1e-4 s, 65,000 steps for the simulator
scs = [dataclasses.replace(sc, horizon=4.0, disturbance_time=1.0, input_disturbance_time=2.5) for sc in SCENARIOS[:3]]
# the thesis gains under the plain scenario; the weakly damped ones, which saturate the pumps
# and reach their limits as the thesis gains do, and the diverging gain under all three (the
# thesis gains' sliding pumps cost the simulator half a minute a scenario)
out = {}
for name, ctrls, scenarios in (("plain", [loop.controller(THESIS_MIN)], scs[:1]),
                               ("all", [loop.controller(WEAK), static_gain(-8.0)], scs)):
    diverged, metrics = loop.run_batch(ctrls, scenarios, device="gpu")
    ref = [[loop.run(c, sc, record=False) for sc in scenarios] for c in ctrls]
    out[name] = dict(diverged=diverged.tolist(), metrics=metrics.tolist(),
                     ref_diverged=[[r.diverged for r in row] for row in ref],
                     ref=[[r.metrics.tolist() for r in row] for row in ref])
print(json.dumps(out))
"""


@pytest.mark.long  # 6 s on the EPYC: `make test` runs the sampled kernel under the simulator (test_batch_kernels)
def test_cuda_kernel_under_the_simulator_follows_the_one_candidate_path():
    """The CUDA kernel of the continuous loop, run by Numba's CUDA simulator: the thesis gains
    under the plain scenario, and a weakly damped and a diverging controller under 3 scenarios
    (plain; saturation with sliding pumps and an input step; tank and pump limits), 4 s each
    (the simulator interprets every step in Python)."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    here = os.path.dirname(__file__)
    tests = os.path.dirname(os.path.dirname(here))
    out = subprocess.run([sys.executable, "-c", _SIMULATED_GPU, here, tests], env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    both = json.loads(out.stdout.strip().splitlines()[-1])
    for res in both.values():
        assert res["diverged"] == res["ref_diverged"]
        assert_metrics_close(np.array(res["metrics"]), np.array(res["ref"]))
    assert not any(both["plain"]["diverged"][0]) and not any(both["all"]["diverged"][0])
    assert both["all"]["diverged"][1][0]


def test_cuda_kernels_compile_to_ptx():
    """Both CUDA kernels lower to PTX for a Hopper GPU, without one. This needs numba-cuda (the
    CUDA target that ``heurtune[gpu]`` installs; numba's own, deprecated one is not enough) and
    NVIDIA's NVVM, and is skipped without them."""
    pytest.importorskip("numba_cuda")
    from numba import cuda

    try:
        cuda.compile_ptx(lambda a: None, "(float64[:],)", cc=(9, 0))
    except Exception as exc:  # no NVVM here
        pytest.skip(f"no CUDA compiler: {type(exc).__name__}")
    out = subprocess.run([sys.executable, os.path.join(os.path.dirname(__file__), "compile_cuda_ptx.py")],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "continuous kernel" in out.stdout and "sampled kernel" in out.stdout
