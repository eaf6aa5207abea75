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
one run) and the launch sizes. `kernel_set` compiles and caches the kernels of every
cuda_* module's `build` (this one's, and those of the feature modules) per float type.

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
_ALL = {name: getattr(mod, name) for mod in _MODULES for name in mod.KERNELS}
_NAMES = tuple(_ALL)
_FAST = frozenset(("k_forces", "k_count_pairs2"))   # pair loops: fastmath in float32 (build)
_SETS: dict = {}
_FORCES: dict = {}


def kernel_set(namespace, names: tuple[str, ...], dtype, fastmath=()) -> types.SimpleNamespace:
    """The kernels `names` of `namespace` (a module's globals(), or a module-level dict
    name -> plain function: one object for the process's life) compiled for float type
    `dtype`, as one namespace under the same names; those also in `fastmath` with fastmath
    on (the simulator has no fastmath: `kernel`).

    Every cuda_* module's `build` goes through this one cache, keyed by (namespace, names,
    dtype, fastmath), so each set is compiled once a float type and its namespace stays the
    same object (cuda_launch.fast caches its fast launches per namespace object). The entry
    keeps the namespace, so its id, part of the key, is never reused. The kernels of a set
    share one memo (`kernel`: the retargeted copies of the @njit functions they call, by
    function and float type), so a device function is compiled once a set."""
    dt = np.dtype(dtype)
    fast = frozenset(fastmath)
    key = (id(namespace), names, dt, fast)
    e = _SETS.get(key)
    if e is None:
        memo = {}
        ns = types.SimpleNamespace(**{name: kernel(namespace[name], dt, memo, fastmath=name in fast)
                                      for name in names})
        e = _SETS[key] = (namespace, ns)
    return e[1]


def build(dtype, fastmath: bool | None = None) -> types.SimpleNamespace:
    """The kernels for float type `dtype` (cached). fastmath (default: on for float32)
    applies to the pair loops only."""
    dt = np.dtype(dtype)
    fm = (dt == np.float32) if fastmath is None else bool(fastmath)
    return kernel_set(_ALL, _NAMES, dt, _FAST if fm else ())


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
