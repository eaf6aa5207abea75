"""Cell lists: a grid over the particles' bounding box and an O(N) counting sort.

The grid spans only where the particles are (DualSPHysics shrinks its cell
domain to the particles' limits, seed paper §III-A). Cells are numbered with a
chosen axis order (fast, mid, slow): a slab decomposition puts the split axis
slowest, so the particles of a slice are contiguous and a rank's edges are two
contiguous row ranges (seed paper §III-A, "XYZ, XZY or YZX").

Neighbours of a particle lie in cells within `reach` cells along each axis
(reach 1 for cells of 2h, 2 for cells of h). Rows of cells along the fast axis
are contiguous, so the force loop visits 3 ranges in 2D and 9 in 3D.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange


@dataclass
class CellGrid:
    origin: np.ndarray   # float64 [3], in permuted axis order (fast, mid, slow)
    size: float          # cell edge
    dims: np.ndarray     # int64 [3] cells along (fast, mid, slow); 1 for a missing axis
    axes: np.ndarray     # int64 [3] particle axis of (fast, mid, slow); -1 for none (2D)
    start: np.ndarray    # int64 [ncells + 1]: cell c holds rows start[c]:start[c+1]
    reach: int
    hi: np.ndarray = None  # float64 [3]: upper corner of the binned rows' bounding box (permuted)

    @property
    def ncells(self) -> int:
        return int(self.dims.prod())

    def kernel_args(self):
        """Arguments the force kernels take, in their order."""
        return self.start, self.origin, 1.0 / self.size, self.dims, self.axes, self.reach


def axis_order(dim: int, slow_axis: int | None = None) -> np.ndarray:
    """(fast, mid, slow) particle axes; `slow_axis` last when a split axis is given."""
    order = list(range(dim))
    if slow_axis is not None:
        order.remove(slow_axis)
        order.append(slow_axis)
    if dim == 2:
        order = order[:1] + [-1] + order[1:] if slow_axis is not None else order + [-1]
    return np.array(order, np.int64)


@njit(cache=True)
def _bounds(pos, axes, lo, hi):
    """lo/hi of positions along each permuted axis (missing axis: 0)."""
    n = pos.shape[0]
    for k in range(3):
        a = axes[k]
        if a < 0 or n == 0:
            lo[k] = 0.0
            hi[k] = 0.0
            continue
        mn = np.inf
        mx = -np.inf
        for i in range(n):
            v = pos[i, a]
            if v < mn:
                mn = v
            if v > mx:
                mx = v
        lo[k] = mn
        hi[k] = mx


@njit(parallel=True, cache=True)
def cell_keys(pos, origin, inv_size, dims, axes, keys):
    for i in prange(pos.shape[0]):
        key = 0
        for k in range(2, -1, -1):
            a = axes[k]
            ck = 0
            if a >= 0:
                ck = int(math.floor((pos[i, a] - origin[k]) * inv_size))
                if ck < 0:
                    ck = 0
                elif ck >= dims[k]:
                    ck = dims[k] - 1
            key = key * dims[k] + ck
        keys[i] = key


@njit(cache=True)
def counting_sort(keys, ncells):
    """Stable O(N + ncells) sort by cell: returns (perm, start)."""
    n = keys.shape[0]
    start = np.zeros(ncells + 1, np.int64)
    for i in range(n):
        start[keys[i] + 1] += 1
    for c in range(ncells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    perm = np.empty(n, np.int64)
    for i in range(n):
        k = keys[i]
        perm[fill[k]] = i
        fill[k] += 1
    return perm, start


@njit(inline="always", cache=True)
def cell_window(x, y, z, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach):
    """Cells within `reach` of the point (x, y, z) along (fast, mid, slow), clipped to the
    grid: (lo0, hi0, lo1, hi1, lo2, hi2, empty). A missing axis (a = -1) spans cell 0.
    Plain @njit: CPU kernels call it and numba.cuda kernels get a device copy."""
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    empty = False
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        if a < 0:
            continue
        o = o0 if k == 0 else (o1 if k == 1 else o2)
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        c = int(math.floor(((x if a == 0 else (y if a == 1 else z)) - o) * inv_size))
        lo = max(c - reach, 0)
        hi = min(c + reach, nk - 1)
        if lo > hi:
            empty = True
        if k == 0:
            lo0 = lo
            hi0 = hi
        elif k == 1:
            lo1 = lo
            hi1 = hi
        else:
            lo2 = lo
            hi2 = hi
    return lo0, hi0, lo1, hi1, lo2, hi2, empty


def reach_cells(h: float, cell_size: float) -> int:
    """Cells a 2h support spans from a particle's own cell along each axis."""
    return int(np.ceil(2.0 * h / cell_size - 1e-9))


def grid_dims(lo, hi, cell_size, axes):
    """Cells along (fast, mid, slow) of a grid from lo to hi (permuted axes; 1 for a missing axis)."""
    dims = np.maximum(np.floor((hi - lo) / cell_size).astype(np.int64) + 1, 1)
    dims[axes < 0] = 1
    return dims


def build_grid(pos: np.ndarray, cell_size: float, reach: int, axes: np.ndarray, slow_span=None):
    """Grid over `pos`' bounding box; returns (grid, perm) with rows to reorder by perm.

    `slow_span` (lo, hi), the slab's cuts along the slow (split) axis: the grid spans at
    least the finite ones there, so rows that enter the slab later in the step fall in
    it (recv_displaced merges them, `grid_takes`).

    The key of a row is (slow, mid, fast) cell index read as one mixed-radix number:
    the order of keys is lexicographic in the cell index (slow axis most significant),
    whatever the extents. The counting sort is stable: rows of one cell keep their order."""
    lo = np.zeros(3)
    hi = np.zeros(3)
    _bounds(pos, axes, lo, hi)
    if slow_span is not None and axes[2] >= 0 and pos.shape[0]:
        a, b = float(slow_span[0]), float(slow_span[1])
        if np.isfinite(a):
            lo[2] = min(lo[2], a)
        if np.isfinite(b):
            hi[2] = max(hi[2], b)
    dims = grid_dims(lo, hi, cell_size, axes)
    keys = np.empty(pos.shape[0], np.int64)
    cell_keys(pos, lo, 1.0 / cell_size, dims, axes, keys)
    perm, start = counting_sort(keys, int(dims.prod()))
    return CellGrid(origin=lo, size=cell_size, dims=dims, axes=axes, start=start, reach=reach, hi=hi), perm


def grid_takes(grid: CellGrid, pos: np.ndarray):
    """Whether `build_grid` over the grid's rows plus the rows at `pos` would give this very
    grid (same origin, same dims: every row keeps its cell and key), and the bounding box's
    upper corner with them. False when the grid holds no rows or its bounds are unknown."""
    if grid.hi is None or int(grid.start[-1]) == 0:
        return False, None
    if pos.shape[0] == 0:
        return True, grid.hi
    lo = np.zeros(3)
    hi = np.zeros(3)
    _bounds(pos, grid.axes, lo, hi)
    used = grid.axes >= 0
    if np.any(lo[used] < grid.origin[used]):
        return False, None
    hi = np.where(used, np.maximum(grid.hi, hi), 0.0)
    return bool(np.array_equal(grid_dims(grid.origin, hi, grid.size, grid.axes), grid.dims)), hi
