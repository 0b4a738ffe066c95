"""CUDA kernels of the QTP closed loop: one GPU thread per lane (one candidate under one scenario).

Two kernels. The continuous-time loop's (:func:`simulate_continuous_lanes`) calls
:func:`heurtune.objectives.qtp.continuous_kernels.continuous_lane`, the per-lane step of the
one-candidate and the batched CPU paths, compiled from its Python source as a device function
together with every kernel function it reaches; its working arrays live in global memory, one
set per lane. The sampled loop's (:func:`simulate_lanes`) calls
:func:`heurtune.objectives.qtp.kernels.sampled_lane`, the per-lane loop of the sampled
one-candidate and batched CPU paths, compiled the same way; its working arrays are the thread's
local memory. Both kernels take the lanes' arrays of the CPU batch drivers
(:func:`heurtune.objectives.qtp.continuous_kernels.simulate_continuous_lanes`,
:func:`heurtune.objectives.qtp.kernels.simulate_lanes`), one lane per row. Device functions are
built from the CPU kernels' own Python source (:func:`_device_lane`; the lane and what it
calls, found by :func:`_reachable`): one text of the arithmetic for every target. Controller
design stays on the CPU. Float64 throughout.

Needs ``numba-cuda`` and an NVIDIA GPU (``pip install heurtune[gpu]``); the tests run it under
Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), which executes the same Python on the CPU.
"""

from __future__ import annotations

import math
import types

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import continuous_kernels as _ck
from heurtune.objectives.qtp import kernels as _kernels

__all__ = ["available", "require", "simulate_lanes", "simulate_continuous_lanes", "MAX_STATES", "THREADS_PER_BLOCK"]

# Controller states a thread holds (in local memory); FOLQI of Oustaloup order N has 2 (2N + 1).
MAX_STATES = 64
THREADS_PER_BLOCK = 128

_KERNEL = None
_CONTINUOUS_KERNEL = None


try:  # the kernel names the module as a global (the CUDA simulator swaps that one)
    from numba import cuda
except ImportError:  # numba without its CUDA target
    cuda = None


def available() -> bool:
    """Whether a CUDA GPU (or Numba's CUDA simulator) can run the kernel.

    Returns
    -------
    bool
    """
    if cuda is None:
        return False
    try:
        return bool(cuda.is_available())
    except Exception:  # a broken driver counts as no GPU
        return False


def require() -> None:
    """Raise ConfigError (one line) when no CUDA GPU is at hand."""
    if not available():
        raise ConfigError("device 'gpu' needs an NVIDIA GPU with CUDA and numba-cuda "
                          "(pip install 'heurtune[gpu]'); none found here: use device 'cpu' or 'cpu-batch'")


def _reachable(module, root: str) -> tuple:
    """Names of the jitted functions of ``module`` that ``root`` calls, directly or not (with it)."""
    found, todo = [], [root]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        found.append(name)
        code = getattr(module, name).py_func.__code__
        todo += [n for n in code.co_names if hasattr(getattr(module, n, None), "py_func")]
    return tuple(found)


def _device_lane(module, root: str):
    """The CUDA device version of the jitted function ``root`` of ``module``, compiled from its
    Python source together with every jitted function of the module it reaches
    (:func:`_reachable`).

    Each function is rebuilt on one namespace (the module's constants, ``math`` and ``np``) in
    which the names of the others point to their device versions, callees first, so that calls
    between them stay on the GPU.
    """
    namespace = {"math": math, "np": np}
    namespace.update({k: v for k, v in vars(module).items() if k.isupper()})
    for name in reversed(_reachable(module, root)):
        source = getattr(module, name).py_func
        fn = types.FunctionType(source.__code__, namespace, name, source.__defaults__, source.__closure__)
        namespace[name] = cuda.jit(device=True)(fn)
    return namespace[root]


def _make_kernel():
    from numba import boolean, float64

    lane = _device_lane(_kernels, "sampled_lane")
    block, out_state, in_state = _kernels.METRIC_BLOCK, _kernels.OUT_STATE, _kernels.IN_STATE

    @cuda.jit
    def kernel(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
               dt, n_steps, noise, lane_noise, band_pct, metrics, status, rec2, rec4):
        k = cuda.grid(1)
        if k >= P.shape[0]:
            return
        work = (cuda.local.array(MAX_STATES, float64), cuda.local.array(MAX_STATES, float64),
                cuda.local.array(4, float64), cuda.local.array((4, block), float64),
                cuda.local.array((2, out_state), float64), cuda.local.array((2, in_state), float64),
                cuda.local.array(2, boolean))
        draw = noise[max(lane_noise[k], 0)]
        lane_draw = draw[0:(draw.shape[0] if lane_noise[k] >= 0 else 0)]
        st, _ = lane(P[k], level_per_state, h_init, h_op, ad[k], bd[k], state_input, Ad[k], Bd[k], Cc[k], Dc[k],
                     state_channel, segments, dt, n_steps, lane_draw, band_pct, metrics[k], rec2[0:0], rec2[0:0],
                     rec4[0:0], 1, work)
        status[k] = st

    return kernel


def simulate_lanes(*, P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
                   dt, n_steps, noise, lane_noise, band_pct):
    """:func:`heurtune.objectives.qtp.kernels.simulate_lanes` on the GPU (same arguments,
    without the outputs), one thread a lane.

    Parameters
    ----------
    P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments
        As :func:`heurtune.objectives.qtp.kernels.simulate_lanes` takes them (one lane per row).
    dt, n_steps, noise, lane_noise, band_pct
        Likewise.

    Returns
    -------
    status : (L,) int64 ndarray
    metrics : (L, N_METRICS) ndarray

    Raises
    ------
    ConfigError
        Without a GPU, or for a controller of more than :data:`MAX_STATES` states.
    """
    global _KERNEL
    require()
    if ad.shape[1] + Ad.shape[1] > MAX_STATES:
        raise ConfigError(f"device 'gpu' takes controllers of at most {MAX_STATES} states, "
                          f"got {ad.shape[1] + Ad.shape[1]}")
    if _KERNEL is None:
        _KERNEL = _make_kernel()
    L = P.shape[0]
    if noise.shape[0] == 0:  # a draw for the kernel to index (every lane reads none of it)
        noise = np.zeros((1, 0, 4))
    metrics = cuda.device_array((L, _kernels.N_METRICS), dtype=np.float64)
    status = cuda.device_array(L, dtype=np.int64)
    args = [cuda.to_device(np.ascontiguousarray(P, dtype=np.float64))]
    args += [float(level_per_state)] + [cuda.to_device(np.ascontiguousarray(a)) for a in
                                        (h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments)]
    args += [float(dt), int(n_steps), cuda.to_device(np.ascontiguousarray(noise)),
             cuda.to_device(np.ascontiguousarray(lane_noise)), float(band_pct), metrics, status,
             cuda.to_device(np.zeros((1, 2))), cuda.to_device(np.zeros((1, 4)))]
    blocks = (L + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
    _KERNEL[blocks, THREADS_PER_BLOCK](*args)
    return status.copy_to_host(), metrics.copy_to_host()


def _make_continuous_kernel():
    lane = _device_lane(_ck, "continuous_lane")

    @cuda.jit
    def kernel(level_per_state, x_init, h_op, band_pct, P, lam, bm, mi, Cm, Aq, Bq, Cq, Dc, channel, seg, n_seg,
               metrics, status, n_taken, rec2, rec4,
               rows, coup, prop_m, prop_q, prop_qb, wz, wm, wq, wqb, w4, w2, w10, wi, wb, phw, sqw, rw, bw, vq):
        k = cuda.grid(1)
        if k >= P.shape[0]:
            return
        work = (rows[k], coup[k], prop_m[k], prop_q[k], prop_qb[k], wz[k], wm[k], wq[k], wqb[k], w4[k], w2[k], w10[k],
                wi[k], wb[k], phw[k], sqw[k], rw[k], bw[k], vq[k])
        st, n = lane(P[k], level_per_state, x_init, h_op, lam[k], bm[k], mi[k], Cm[k], Aq[k], Bq[k], Cq[k], Dc[k],
                     channel[k], seg[k], n_seg[k], band_pct, metrics[k], 1.0, rec2, rec2, rec4, 0, work)
        status[k] = st
        n_taken[k] = n

    return kernel


def simulate_continuous_lanes(lanes, level_per_state, x_init, h_op, band_pct):
    """:func:`heurtune.objectives.qtp.continuous_kernels.simulate_continuous_lanes` on the GPU,
    one thread a lane (same arguments).

    Parameters
    ----------
    lanes : dict
        The lanes' inputs (:func:`heurtune.objectives.qtp.continuous.pack_lanes`).
    level_per_state, x_init, h_op, band_pct
        As the CPU function takes them.

    Returns
    -------
    status : (L,) int64 ndarray
    metrics : (L, N_METRICS) ndarray

    Raises
    ------
    ConfigError
        Without a GPU.
    """
    global _CONTINUOUS_KERNEL
    require()
    if _CONTINUOUS_KERNEL is None:
        _CONTINUOUS_KERNEL = _make_continuous_kernel()
    L = lanes["P"].shape[0]
    metrics = cuda.device_array((L, _kernels.N_METRICS), dtype=np.float64)
    status = cuda.device_array(L, dtype=np.int64)
    n_taken = cuda.device_array(L, dtype=np.int64)
    work = [cuda.device_array((L,) + shape, dtype=dtype)
            for shape, dtype in _ck.workspace_shapes(lanes["lam"].shape[1], lanes["Aq"].shape[1])]
    args = [float(level_per_state), cuda.to_device(np.ascontiguousarray(x_init, dtype=np.float64)),
            cuda.to_device(np.ascontiguousarray(h_op, dtype=np.float64)), float(band_pct)]
    args += [cuda.to_device(np.ascontiguousarray(lanes[name])) for name in _ck.LANE_FIELDS]
    args += [metrics, status, n_taken, cuda.to_device(np.zeros((1, 2))), cuda.to_device(np.zeros((1, 4)))] + work
    blocks = (L + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
    _CONTINUOUS_KERNEL[blocks, THREADS_PER_BLOCK](*args)
    return status.copy_to_host(), metrics.copy_to_host()
