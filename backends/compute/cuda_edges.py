"""numba.cuda kernels of edges and halos: a rank's edge rows packed for a neighbour, a
rank's rows near a periodic face packed as their images, and rows so packed binned into a
halo's cells on the device (cuda_images).
"""
import math

import numpy as np
from numba import cuda, njit

from sphgraph.physics.eos import tait

KERNELS = ("k_pack_edge", "k_pack_images", "k_edge_init", "k_edge_bounds", "k_edge_keys", "k_edge_gather")


@njit(inline="always")
def _copy_record(vel4, kind, i, o4, okind, j):
    """Row i's vel4 record (vx, vy, vz, rho) and kind into packed slot j."""
    s = 4 * i
    d = 4 * j
    o4[d] = vel4[s]
    o4[d + 1] = vel4[s + 1]
    o4[d + 2] = vel4[s + 2]
    o4[d + 3] = vel4[s + 3]
    okind[j] = kind[i]


def k_pack_edge(px, py, pz, vel4, kind, a0, m0, a1, m, dim, o64, o4, okind):
    """Rows a0 .. a0+m0-1 then a1 .. a1+(m-m0)-1 (the fluid and boundary candidate
    ranges of an edge): float64 position records, vel4 records, kinds."""
    j = cuda.grid(1)
    if j >= m:
        return
    i = a0 + j if j < m0 else a1 + (j - m0)
    b = j * dim
    o64[b] = px[i]
    o64[b + 1] = py[i]
    if dim == 3:
        o64[b + 2] = pz[i]
    _copy_record(vel4, kind, i, o4, okind, j)


def k_pack_images(keep, pos, n, cap, dim, px, py, pz, vel4, kind, axis, t, period, o64, o4, okind):
    """The image of each row with keep == 0 (k_near_faces; pos: exclusive scan of keep) into
    slot i - pos[i], as k_pack_edge packs a row: moved by +period along `axis` when the row
    lies below t (lo + reach), else by -period (sphgraph.periodic.Periodic.image_rows with
    one image axis). The float64 sum is the host path's. Slots from `cap` on are not
    written (the caller's bound on the rows: it reads their count after)."""
    i = cuda.grid(1)
    if i >= n or keep[i] != 0:
        return
    j = i - pos[i]
    if j >= cap:
        return
    b = j * dim
    x = px[i] if axis == 0 else (py[i] if axis == 1 else pz[i])
    s = period if x < t else -period
    o64[b] = px[i] + s if axis == 0 else px[i]
    o64[b + 1] = py[i] + s if axis == 1 else py[i]
    if dim == 3:
        o64[b + 2] = pz[i] + s if axis == 2 else pz[i]
    _copy_record(vel4, kind, i, o4, okind, j)


def k_edge_init(head, meta):
    """k_edge_bounds' accumulators in meta (rows kept, fluid rows kept, box min3, box max3)
    and, in meta[8], head[0] (the rows near a face, k_near_faces' count: cuda_images)."""
    if cuda.grid(1) == 0:
        meta[0] = 0.0
        meta[1] = 0.0
        for q in range(3):
            meta[2 + q] = math.inf
            meta[5 + q] = -math.inf
        meta[8] = head[0]


def k_edge_bounds(pos, kind, m, count, dim, axis, thr, below, meta):
    """Of the first min(m, count[0]) rows packed (pos: records of dim float64, as
    k_pack_edge), those that pass the cut (coordinate `axis` < thr when `below`, else >=
    thr): how many, how many fluid, and their bounding box (0 along a missing z), into meta
    (set by k_edge_init; one atomic per block and quantity)."""
    sh = cuda.shared.array((8, 256), dtype=np.float64)
    t = cuda.threadIdx.x
    m = min(m, count[0])
    cnt = 0.0
    fl = 0.0
    mn0 = math.inf
    mn1 = math.inf
    mn2 = math.inf
    mx0 = -math.inf
    mx1 = -math.inf
    mx2 = -math.inf
    i = cuda.grid(1)
    stride = cuda.gridsize(1)
    while i < m:
        b = i * dim
        x = pos[b + axis]
        if (x < thr) if below else (x >= thr):
            cnt += 1.0
            if kind[i] == 0:
                fl += 1.0
            p0 = pos[b]
            p1 = pos[b + 1]
            p2 = pos[b + 2] if dim == 3 else 0.0
            mn0 = min(mn0, p0)
            mx0 = max(mx0, p0)
            mn1 = min(mn1, p1)
            mx1 = max(mx1, p1)
            mn2 = min(mn2, p2)
            mx2 = max(mx2, p2)
        i += stride
    sh[0, t] = cnt
    sh[1, t] = fl
    sh[2, t] = mn0
    sh[3, t] = mn1
    sh[4, t] = mn2
    sh[5, t] = mx0
    sh[6, t] = mx1
    sh[7, t] = mx2
    cuda.syncthreads()
    s = 128
    while s > 0:
        if t < s:
            for q in range(2):
                sh[q, t] += sh[q, t + s]
            for q in range(2, 5):
                if sh[q, t + s] < sh[q, t]:
                    sh[q, t] = sh[q, t + s]
            for q in range(5, 8):
                if sh[q, t + s] > sh[q, t]:
                    sh[q, t] = sh[q, t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        for q in range(2):
            cuda.atomic.add(meta, q, sh[q, 0])
        for q in range(2, 5):
            cuda.atomic.min(meta, q, sh[q, 0])
        for q in range(5, 8):
            cuda.atomic.max(meta, q, sh[q, 0])


def k_edge_keys(pos, m, dim, axis, thr, below, ox, oy, oz, inv_size, nx, ny, nz, sx, sy, sz, ncells,
                keys, counts):
    """Cell key of each packed row (as sphgraph.cells.cell_keys) and a histogram; a row
    outside the cut gets key ncells, binned after every cell."""
    i = cuda.grid(1)
    if i >= m:
        return
    b = i * dim
    x = pos[b + axis]
    key = ncells
    if (x < thr) if below else (x >= thr):
        cx = int(math.floor((pos[b] - ox) * inv_size))
        cx = min(max(cx, 0), nx - 1)
        cy = int(math.floor((pos[b + 1] - oy) * inv_size))
        cy = min(max(cy, 0), ny - 1)
        key = cx * sx + cy * sy
        if dim == 3:
            cz = int(math.floor((pos[b + 2] - oz) * inv_size))
            cz = min(max(cz, 0), nz - 1)
            key += cz * sz
    keys[i] = key
    cuda.atomic.add(counts, key, 1)


def k_edge_gather(pos, v4, kind, perm, n, dim, ref0, ref1, ref2, prm, rx, ry, rz, vx, vy, vz, rho, press,
                  okind):
    """The halo's arrays in cell order from the packed records: positions relative to the
    rank's reference point (float64 difference, then the run's type, as the host path's
    prepare_halo), velocity, density, its pressure, kind."""
    i = cuda.grid(1)
    if i >= n:
        return
    j = perm[i]
    b = j * dim
    rx[i] = pos[b] - ref0
    ry[i] = pos[b + 1] - ref1
    s = 4 * j
    vx[i] = v4[s]
    vy[i] = v4[s + 1]
    if dim == 3:
        rz[i] = pos[b + 2] - ref2
        vz[i] = v4[s + 2]
    r = v4[s + 3]
    rho[i] = r
    press[i] = tait(r, prm)
    okind[i] = kind[j]
