"""numba.cuda kernels of the cell sort: keys and histogram, block scan, scatter, the sort
within cells, and the gathers that put the rows (and their packed records) in cell order.

Rows are sorted by (kind != 0, cell): fluid rows first, each kind's rows grouped by
cell, `start` holding 2 * ncells + 1 offsets (fluid cells, then boundary cells), as
DualSPHysics keeps bound and fluid apart. A boundary destination then visits only
fluid candidates (it interacts with nothing else), and fluid and boundary
destinations run as two launches (no fluid_pair/bound_pair divergence in a warp).
Sources are packed records of the run's type: pos4 = (x - ref, y - ref, z - ref, p)
and vel4 = (vx, vy, vz, rho), so a candidate costs two 16-byte records (one cache
sector each) instead of eight arrays. vel4 is the velocity/density storage itself;
pos4 is rebuilt by k_pack after each sort and predictor, and is the sort's scratch.

Written as plain functions; `cuda_kernels.build(dtype)` turns them into kernels. Scalars
passed from the host are typed by the caller (floats of the run's type, int64 ints).
"""
import math

import numpy as np
from numba import cuda

from sphgraph.physics.eos import tait

KERNELS = ("k_fill", "k_copy", "k_keys_hist2", "k_scan_blocks", "k_scan_add", "k_set_last", "k_scatter",
           "k_sort_cells", "k_sort_cells_by", "k_gather3", "k_copy3", "k_gather4", "k_pack", "k_pick4")


def k_fill(a, n, v):
    i = cuda.grid(1)
    if i < n:
        a[i] = v


def k_copy(src, n, dst):
    i = cuda.grid(1)
    if i < n:
        dst[i] = src[i]


def k_keys_hist2(px, py, pz, kind, n, dim, ox, oy, oz, inv_size, nx, ny, nz, sx, sy, sz, ncells, keys, counts):
    """Cell key of each row (clamped to the grid, as sphgraph.cells.cell_keys), boundary rows
    keyed after all fluid cells (key + ncells), and a histogram of the keys."""
    i = cuda.grid(1)
    if i >= n:
        return
    cx = int(math.floor((px[i] - ox) * inv_size))
    cx = min(max(cx, 0), nx - 1)
    cy = int(math.floor((py[i] - oy) * inv_size))
    cy = min(max(cy, 0), ny - 1)
    key = cx * sx + cy * sy
    if dim == 3:
        cz = int(math.floor((pz[i] - oz) * inv_size))
        cz = min(max(cz, 0), nz - 1)
        key += cz * sz
    if kind[i] != 0:
        key += ncells
    keys[i] = key
    cuda.atomic.add(counts, key, 1)


def k_scan_blocks(a, n, out, sums):
    """Exclusive scan of a[0:n] within blocks of BLOCK*SCAN_ITEMS; block totals to sums."""
    sh = cuda.shared.array(256, dtype=np.int64)
    t = cuda.threadIdx.x
    base = cuda.blockIdx.x * 2048 + t * 8
    s = 0
    for k in range(8):
        j = base + k
        if j < n:
            s += a[j]
    sh[t] = s
    cuda.syncthreads()
    off = 1
    while off < 256:           # Hillis-Steele inclusive scan of the thread totals
        v = sh[t - off] if t >= off else 0
        cuda.syncthreads()
        sh[t] += v
        cuda.syncthreads()
        off *= 2
    run = sh[t] - s            # exclusive prefix of this thread
    for k in range(8):
        j = base + k
        if j < n:
            x = a[j]
            out[j] = run
            run += x
    if t == 255:
        sums[cuda.blockIdx.x] = sh[t]


def k_scan_add(out, n, offs):
    i = cuda.grid(1)
    if i < n:
        out[i] += offs[i // 2048]


def k_set_last(out, ncells, n):
    if cuda.grid(1) == 0:
        out[ncells] = n


def k_scatter(keys, n, fill, perm):
    i = cuda.grid(1)
    if i < n:
        slot = cuda.atomic.add(fill, keys[i], 1)
        perm[slot] = i


def k_sort_cells(start, ncells, perm):
    """Rows of each cell in increasing old order: the sort is then stable (as on the CPU);
    used when the cells' rows are not sorted along the rows of cells (TRIM off)."""
    c = cuda.grid(1)
    if c >= ncells:
        return
    a = start[c]
    b = start[c + 1]
    for i in range(a + 1, b):
        v = perm[i]
        j = i - 1
        while j >= a and perm[j] > v:
            perm[j + 1] = perm[j]
            j -= 1
        perm[j + 1] = v


def k_sort_cells_by(start, ncells, perm, key):
    """Rows of each cell in increasing `key` (the coordinate along the rows of cells;
    ties in increasing old order): the force kernels trim each row of cells to the
    sphere's chord by bisection (k_forces_fv)."""
    c = cuda.grid(1)
    if c >= ncells:
        return
    a = start[c]
    b = start[c + 1]
    for i in range(a + 1, b):
        v = perm[i]
        kv = key[v]
        j = i - 1
        while j >= a:
            u = perm[j]
            ku = key[u]
            if ku < kv or (ku == kv and u < v):
                break
            perm[j + 1] = u
            j -= 1
        perm[j + 1] = v


def k_gather3(a, b, c, m, perm, n, sa, sb, sc):
    """The first m (1-3) of a, b, c gathered by perm in one pass (cuda_cells._permute:
    one launch and one read of perm for up to three arrays)."""
    i = cuda.grid(1)
    if i < n:
        p = perm[i]
        sa[i] = a[p]
        if m > 1:
            sb[i] = b[p]
        if m > 2:
            sc[i] = c[p]


def k_copy3(sa, sb, sc, m, n, a, b, c):
    """The first m (1-3) of sa, sb, sc copied into a, b, c (k_gather3's way back)."""
    i = cuda.grid(1)
    if i < n:
        a[i] = sa[i]
        if m > 1:
            b[i] = sb[i]
        if m > 2:
            c[i] = sc[i]


def k_gather4(src, perm, n, dst):
    """Records of 4 (flat arrays of 4 n)."""
    i = cuda.grid(1)
    if i < n:
        s = 4 * perm[i]
        d = 4 * i
        dst[d] = src[s]
        dst[d + 1] = src[s + 1]
        dst[d + 2] = src[s + 2]
        dst[d + 3] = src[s + 3]


def k_pack(px, py, pz, vel4, n, dim, ref0, ref1, ref2, prm, with_press, pos4):
    """pos4 = (x - ref, y - ref, z - ref [0 in 2D], tait(rho)) in the run's type."""
    i = cuda.grid(1)
    if i >= n:
        return
    d = 4 * i
    pos4[d] = px[i] - ref0
    pos4[d + 1] = py[i] - ref1
    if dim == 3:
        pos4[d + 2] = pz[i] - ref2
    else:
        pos4[d + 2] = 0.0
    if with_press:
        pos4[d + 3] = tait(vel4[d + 3], prm)


def k_pick4(src, i0, i1, i2, i3, out):
    """Four entries of src (e.g. cell starts) for one copy to the host."""
    if cuda.grid(1) == 0:
        out[0] = src[i0]
        out[1] = src[i1]
        out[2] = src[i2]
        out[3] = src[i3]
