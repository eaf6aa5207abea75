"""The numba.cuda kernels of the GPU backend (one thread per particle or per cell), by concern:

* cuda_retarget   plain / @njit functions as CUDA device functions and kernels for one
                  float type (the pair physics of sphgraph.physics is written once)
* cuda_sort       cell keys, block scan, scatter, sort within cells, gathers
* cuda_migrate    rows leaving a slab, packed for their neighbour, and rows arriving
* cuda_edges      edges packed for a neighbour; halos binned on the device (ipc)
* cuda_forces     the force kernels
* cuda_integrate  Verlet and Symplectic
* cuda_reduce     force parts summed, dt's maxima, the numerical check, the pair count

This module is their one entry: `build(dtype)` (every kernel but the per-run force
kernels, as one namespace), `force_kernels(...)` (the fluid and boundary force kernels of
one run) and the launch sizes.

Layout: structure of arrays. Positions are float64 (px, py, pz) for the update; the
force loop reads positions relative to a per-rank reference point (rx, ry, rz, or the
pos4 records) in the run's type, refreshed when the rows are sorted. 2D runs pass a
one-element dummy for every z array.
"""
import types

import numpy as np

from . import cuda_edges, cuda_forces, cuda_integrate, cuda_migrate, cuda_reduce, cuda_sort
from .cuda_retarget import SIMULATOR, device_function, kernel  # noqa: F401  (the backend's names)

BLOCK = 256          # threads per block, element-wise kernels
FORCE_BLOCK = 128    # threads per block, force kernels
REDUCE_BLOCKS = 512  # blocks of the grid-stride reductions (dt, bounds/check)
SCAN_ITEMS = 8       # elements per thread in the block scan (block covers BLOCK * SCAN_ITEMS)
# register cap of the float32 force kernels (0: the compiler's choice): below the ~90
# registers they take uncapped, more warps fit on an SM; 48 keeps the spills to the row
# set-up (none in the candidate loops) within the driver's default per-thread local memory
# (docs/gpu.md: the caps measured)
MAXREG = 48

_MODULES = (cuda_sort, cuda_migrate, cuda_edges, cuda_forces, cuda_integrate, cuda_reduce)
_FAST = {"k_forces", "k_count_pairs2"}   # pair loops: fastmath in float32 (build)
_BUILT: dict = {}
_FORCES: dict = {}


def build(dtype, fastmath: bool | None = None) -> types.SimpleNamespace:
    """The kernels for float type `dtype` (cached). fastmath (default: on for float32)
    applies to the pair loops only."""
    dt = np.dtype(dtype)
    fm = (dt == np.float32) if fastmath is None else bool(fastmath)
    key = (dt.str, fm)
    if key not in _BUILT:
        memo = {}
        _BUILT[key] = types.SimpleNamespace(**{
            name: kernel(getattr(mod, name), dt, memo, fastmath=fm and name in _FAST)
            for mod in _MODULES for name in mod.KERNELS})
    return _BUILT[key]


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar, fastmath: bool | None = None,
                  max_registers: int | None = None) -> types.SimpleNamespace:
    """The fluid and boundary force kernels of one run (k_forces_fv / k_forces_bv, under
    the names k_forces_f / k_forces_b; `relative`: they take relative positions): `prm`
    (the run's parameter vector) and the options become compile-time constants (cached
    per distinct set; a new scene or dp compiles once more). Register cap: MAXREG for
    float32 unless `max_registers`."""
    dt = np.dtype(dtype)
    fm = (dt == np.float32) if fastmath is None else bool(fastmath)
    mr = (MAXREG if dt == np.float32 else 0) if max_registers is None else int(max_registers)
    pc = np.ascontiguousarray(prm, dt)
    key = (dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar), fm, mr)
    if key not in _FORCES:
        _FORCES[key] = cuda_forces.compile_forces(cuda_forces.k_forces_fv, cuda_forces.k_forces_bv, dt, pc,
                                                  kernel_id, ddt_kind, laminar, fm, mr)
    return _FORCES[key]


def blocks(n: int, block: int = BLOCK) -> int:
    return max(1, (int(n) + block - 1) // block)
