"""Compile both CUDA kernels of the QTP loop to PTX for compute capability 9.0, without a GPU.

Run by ``test_continuous_lanes.test_cuda_kernel_compiles_to_ptx`` where numba-cuda and NVVM are
installed. Numba compiles a kernel's device functions for the current device; with none, this
script tells it the device is a 9.0 one (in this process only).
"""

import numba.cuda.dispatcher as dispatcher
import numpy as np
from numba import cuda
from numba import types as nt

from heurtune.objectives.qtp import continuous_kernels as ck
from heurtune.objectives.qtp import gpu


class _Hopper:
    compute_capability = (9, 0)


dispatcher.get_current_device = lambda: _Hopper()

# the rank and dtype of each lane array (a leading lane axis included)
RANKS = {"P": 2, "lam": 2, "bm": 2, "mi": (2, nt.int64), "Cm": 3, "Aq": 3, "Bq": 3, "Cq": 3, "Dc": 3,
         "channel": (2, nt.int64), "seg": 3, "n_seg": (1, nt.int64)}
DTYPES = {np.float64: nt.float64, np.int64: nt.int64, np.bool_: nt.boolean}


def array(rank, dtype=nt.float64):
    return nt.Array(dtype, rank, "C")


signature = [nt.float64, array(1), array(1), nt.float64]
signature += [array(*RANKS[n]) if isinstance(RANKS[n], tuple) else array(RANKS[n]) for n in ck.LANE_FIELDS]
signature += [array(2), array(1, nt.int64), array(1, nt.int64), array(2), array(2)]
signature += [array(len(shape) + 1, DTYPES[dtype]) for shape, dtype in ck.workspace_shapes(24, 2)]
ptx, _ = cuda.compile_ptx(gpu._make_continuous_kernel().py_func, tuple(signature), cc=(9, 0))
print(f"continuous kernel: {len(ptx):,} characters of PTX")

# the sampled loop's kernel (gpu.simulate_lanes)
f8, i8 = nt.float64, nt.int64
sampled = (array(2), f8, array(1), array(1), array(2), array(2), array(1, i8), array(3), array(3), array(3), array(3),
           array(1, i8), array(1, i8), f8, i8, array(3), array(1, i8), f8, array(2), array(1, i8), array(2), array(2))
ptx, _ = cuda.compile_ptx(gpu._make_kernel().py_func, sampled, cc=(9, 0))
print(f"sampled kernel: {len(ptx):,} characters of PTX")
