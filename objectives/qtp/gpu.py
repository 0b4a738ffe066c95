"""CUDA kernels of the QTP closed loop: one GPU thread per lane (one candidate under one scenario).

Two kernels. The continuous-time loop's (:func:`simulate_continuous_lanes`) calls
:func:`heurtune.objectives.qtp.continuous_kernels.continuous_lane`, the per-lane step of the
one-candidate and the batched CPU paths, compiled from its Python source as a device function
together with every kernel function it reaches; its working arrays live in global memory, one
set per lane. The sampled loop's (:func:`simulate_lanes`) runs the loop of
:func:`heurtune.objectives.qtp.kernels.simulate_loop` (metrics only)
on the lane-last arrays of :func:`heurtune.objectives.qtp.batch_kernels.simulate_batch`, so that
neighbouring threads read neighbouring addresses. The plant step, the metric folds and their
finishing come from the CPU kernels' own Python source, compiled a second time as CUDA device
functions (:func:`_device_functions`; for both kernels, their roots and what these call, found by
:func:`_reachable`): one text of the arithmetic for both targets. Controller design stays on the
CPU. Float64 throughout.

Needs ``numba-cuda`` and an NVIDIA GPU (``pip install heurtune[gpu]``); the tests run it under
Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``), which executes the same Python on the CPU.
"""

from __future__ import annotations

import math
import types

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.qtp import batch_kernels as _batch
from heurtune.objectives.qtp import continuous_kernels as _ck
from heurtune.objectives.qtp import kernels as _kernels

__all__ = ["available", "require", "simulate_lanes", "simulate_continuous_lanes", "MAX_STATES", "THREADS_PER_BLOCK"]

# Controller states a thread holds (in local memory); FOLQI of Oustaloup order N has 2 (2N + 1).
MAX_STATES = 64
THREADS_PER_BLOCK = 128

# The CPU kernels' per-lane functions that the sampled CUDA kernel calls, by module; the
# functions they call are found from them (_reachable), as for the continuous kernel's lane.
_SAMPLED_ROOTS = {
    _kernels: ("_rk4_clipped", "_rk4_limited", "_output_state_init", "_fold_output", "_fold_input",
               "_finish_output", "_finish_input", "_finish_range"),
    _batch: ("_rk4_fast",),
}
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


def _with_callees(roots: dict) -> dict:
    """``roots`` (module to names) with every jitted function of the same module they call,
    directly or not, callees first (:func:`_reachable`)."""
    out = {}
    for module, names in roots.items():
        found = []
        for name in names:
            found += [n for n in reversed(_reachable(module, name)) if n not in found]
        out[module] = tuple(found)
    return out


def _device_functions(shared=None) -> dict:
    """CUDA device versions of the functions in ``shared`` (module to names, callees first;
    default: the sampled kernel's roots with their callees), compiled from their Python source.

    Each function is rebuilt on one shared namespace in which the names of the others point to
    their device versions, so that calls between them stay on the GPU.
    """
    shared = _with_callees(_SAMPLED_ROOTS) if shared is None else shared
    namespace = {"math": math, "np": np}
    for module in shared:
        namespace.update({k: v for k, v in vars(module).items() if k.isupper()})
    for module, names in shared.items():
        for name in names:
            source = getattr(module, name).py_func
            fn = types.FunctionType(source.__code__, namespace, name, source.__defaults__, source.__closure__)
            namespace[name] = cuda.jit(device=True)(fn)
    return namespace


def _make_kernel():
    from numba import float64

    d = _device_functions()
    rk4_fast, rk4_clipped, rk4_limited = d["_rk4_fast"], d["_rk4_clipped"], d["_rk4_limited"]
    state_init, fold_output, fold_input = d["_output_state_init"], d["_fold_output"], d["_fold_input"]
    finish_output, finish_input, finish_range = d["_finish_output"], d["_finish_input"], d["_finish_range"]
    block, out_state, in_state = _kernels.METRIC_BLOCK, _kernels.OUT_STATE, _kernels.IN_STATE
    n_metrics, level_limit = _kernels.N_METRICS, _kernels.LEVEL_LIMIT
    ok_status, diverged_status = _kernels.STATUS_OK, _kernels.STATUS_DIVERGED
    # the rows of the lane parameters, as plain integers (constants of the compiled kernel)
    P_UOP, P_UMIN, P_UMAX = _kernels.P_UOP, _kernels.P_UMIN, _kernels.P_UMAX
    P_SAT, P_CLIP, P_HMAX = _kernels.P_SAT, _kernels.P_CLIP, _kernels.P_HMAX
    P_OUT, P_IN, P_I_OUT, P_I_IN = _kernels.P_OUT, _kernels.P_IN, _kernels.P_I_OUT, _kernels.P_I_IN

    @cuda.jit
    def kernel(P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
               dt, n_steps, noise, lane_noise, band_pct, metrics, status):
        lane = cuda.grid(1)
        if lane >= P.shape[1]:
            return
        nd = ad.shape[0]
        nq = Ad.shape[0]
        g1 = segments[1]
        nu = segments[2]
        z = cuda.local.array(MAX_STATES, float64)
        zd = cuda.local.array(MAX_STATES, float64)
        buf = cuda.local.array((4, block), float64)
        so = cuda.local.array((2, out_state), float64)
        si = cuda.local.array((2, in_state), float64)
        for i in range(nd + nq):
            z[i] = 0.0
        for j in range(2):
            state_init(so[j])
            for i in range(in_state):
                si[j, i] = 0.0
        c = P[:10, lane]
        u_op0, u_op1 = P[P_UOP, lane], P[P_UOP + 1, lane]
        u_min, u_max = P[P_UMIN, lane], P[P_UMAX, lane]
        saturate, clip = P[P_SAT, lane] > 0.0, P[P_CLIP, lane] > 0.0
        i_out, i_in = int(P[P_I_OUT, lane]), int(P[P_I_IN, lane])
        s_noise = lane_noise[lane]
        band1 = band_pct / 100.0 * h_op[0]
        band2 = band_pct / 100.0 * h_op[1]
        state_limit = level_limit / level_per_state
        h1, h2, h3, h4 = h_init[0], h_init[1], h_init[2], h_init[3]
        h_lo = math.inf
        h_hi = -math.inf
        cz1 = 0.0
        cz2 = 0.0
        nb = 0
        k0 = 0
        diverged = False
        for k in range(n_steps + 1):
            h_lo = min(h_lo, min(min(h1, h2), min(h3, h4)))
            h_hi = max(h_hi, max(max(h1, h2), max(h3, h4)))
            d1 = P[P_OUT, lane] if k >= i_out else 0.0
            d2 = P[P_OUT + 1, lane] if k >= i_out else 0.0
            w0 = level_per_state * h1 + (d1 - h_op[0])
            w1 = level_per_state * h2 + (d2 - h_op[1])
            w2 = level_per_state * h3 - h_op[2]
            w3 = level_per_state * h4 - h_op[3]
            if s_noise >= 0:
                w0 += noise[s_noise, k, 0]
                w1 += noise[s_noise, k, 1]
                w2 += noise[s_noise, k, 2]
                w3 += noise[s_noise, k, 3]
            u1 = u_op0 + cz1 + Dc[0, 0, lane] * w0 + Dc[0, 1, lane] * w1 + Dc[0, 2, lane] * w2 + Dc[0, 3, lane] * w3
            u2 = u_op1 + cz2 + Dc[1, 0, lane] * w0 + Dc[1, 1, lane] * w1 + Dc[1, 2, lane] * w2 + Dc[1, 3, lane] * w3
            frozen1 = False
            frozen2 = False
            if saturate:
                frozen1 = u1 > u_max or u1 < u_min
                frozen2 = u2 > u_max or u2 < u_min
                u1 = min(max(u1, u_min), u_max)
                u2 = min(max(u2, u_min), u_max)
            buf[0, nb] = abs(w0)
            buf[1, nb] = abs(w1)
            buf[2, nb] = u1
            buf[3, nb] = u2
            nb += 1
            if nb == block or k == n_steps:
                fold_output(buf[0], k0, nb, i_out, band1, so[0])
                fold_output(buf[1], k0, nb, i_out, band2, so[1])
                fold_input(buf[2], k0, nb, u_op0, si[0])
                fold_input(buf[3], k0, nb, u_op1, si[1])
                k0 += nb
                nb = 0
            if k == n_steps:
                break
            cz1 = 0.0
            cz2 = 0.0
            for i in range(nd):
                src = state_input[i]
                w = w0 if src == 0 else (w1 if src == 1 else (w2 if src == 2 else w3))
                held = frozen1 if state_channel[i] == 0 else frozen2
                if not held:
                    z[i] = ad[i, lane] * z[i] + bd[i, lane] * w
                if i < nu:
                    if saturate:
                        cz1 += Cc[0, i, lane] * z[i]
                        cz2 += Cc[1, i, lane] * z[i]
                    elif i < g1:
                        cz1 += z[i]
                    else:
                        cz2 += z[i]
            for i in range(nq):
                acc = Bd[i, 0, lane] * w0 + Bd[i, 1, lane] * w1 + Bd[i, 2, lane] * w2 + Bd[i, 3, lane] * w3
                for j in range(nq):
                    acc += Ad[i, j, lane] * z[nd + j]
                zd[i] = acc
            for i in range(nq):
                held = frozen1 if state_channel[nd + i] == 0 else frozen2
                if not held:
                    z[nd + i] = zd[i]
            for i in range(nu, nd + nq):
                cz1 += Cc[0, i, lane] * z[i]
                cz2 += Cc[1, i, lane] * z[i]
            if k >= i_in:
                u1 += P[P_IN, lane]
                u2 += P[P_IN + 1, lane]
            f1, f2, f3, f4 = c[6] * u1, c[7] * u2, c[8] * u2, c[9] * u1
            if clip:
                h1, h2, h3, h4 = rk4_limited(h1, h2, h3, h4, f1, f2, f3, f4, c, dt, P[P_HMAX, lane],
                                             P[P_HMAX + 1, lane], P[P_HMAX + 2, lane], P[P_HMAX + 3, lane])
            else:
                n1, n2, n3, n4, fine = rk4_fast(h1, h2, h3, h4, f1, f2, f3, f4, c[0], c[1], c[2], c[3], c[4], c[5], dt)
                if fine:
                    h1, h2, h3, h4 = n1, n2, n3, n4
                else:
                    h1, h2, h3, h4 = rk4_clipped(h1, h2, h3, h4, f1, f2, f3, f4, c, dt)
            if not (abs(h1) + abs(h2) + abs(h3) + abs(h4) < state_limit):
                diverged = True
                break
        out = metrics[lane]
        if diverged:
            for i in range(n_metrics):
                out[i] = math.nan
            status[lane] = diverged_status
            return
        finish_output(n_steps, dt, i_out, band1, h_op[0], so[0], out, 0)
        finish_output(n_steps, dt, i_out, band2, h_op[1], so[1], out, 1)
        finish_input(dt, u_op0, si[0], out, 0)
        finish_input(dt, u_op1, si[1], out, 1)
        finish_range(level_per_state * h_lo, level_per_state * h_hi, si, out)
        status[lane] = ok_status

    return kernel


def simulate_lanes(*, P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments,
                   dt, n_steps, noise, lane_noise, band_pct):
    """Run the lanes of :func:`heurtune.objectives.qtp.batch_kernels.simulate_batch` (same
    arguments, without the outputs) on the GPU, one thread each.

    Parameters
    ----------
    P, level_per_state, h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments
        As :func:`heurtune.objectives.qtp.batch_kernels.simulate_batch` takes them.
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
    if ad.shape[0] + Ad.shape[0] > MAX_STATES:
        raise ConfigError(f"device 'gpu' takes controllers of at most {MAX_STATES} states, "
                          f"got {ad.shape[0] + Ad.shape[0]}")
    if _KERNEL is None:
        _KERNEL = _make_kernel()
    L = P.shape[1]
    metrics = cuda.device_array((L, _kernels.N_METRICS), dtype=np.float64)
    status = cuda.device_array(L, dtype=np.int64)
    args = [cuda.to_device(np.ascontiguousarray(a)) for a in (P,)]
    args += [level_per_state] + [cuda.to_device(np.ascontiguousarray(a)) for a in
                                 (h_init, h_op, ad, bd, state_input, Ad, Bd, Cc, Dc, state_channel, segments)]
    args += [dt, n_steps, cuda.to_device(np.ascontiguousarray(noise)), cuda.to_device(lane_noise), band_pct,
             metrics, status]
    blocks = (L + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
    _KERNEL[blocks, THREADS_PER_BLOCK](*args)
    return status.copy_to_host(), metrics.copy_to_host()


def _make_continuous_kernel():
    lane = _device_functions(_with_callees({_ck: ("continuous_lane",)}))["continuous_lane"]

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
