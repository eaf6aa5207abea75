"""numba.cuda kernels of the `[probes]` / `[forces]` samples: `ComputeBackend.probe_bounds` and
`probe_sums` on the device rows, the GPU twin of cpu_probes with the same per-point and per-row
maths (sphgraph.physics.probes, retargeted).

The kernels read the rank's rows where the step left them: float64 positions (px, py, pz),
the (vx, vy, vz, rho) records, the fluid half of the kind-split cell grid of this step's
sort (the cells within 2h and the most a row moved since of each point: `_probe_radius`).
Only the sums cross the bus: 5 numbers a point, 3 a body, 2 a height column, and on several
ranks the few body rows near the rank's ends (`probe_bounds`). All sums are float64 whatever
the run's type (the arrays' values are read in their type). Reductions run in a fixed order
(block trees), so a sample is the same bits every run.

Kernels (one thread a point, a boundary row, or a vertical cell of a column):

    k_column_zrange   a block a height column, threads over its vertical cells, min / max
    k_point_sums      a thread a point: the Shepard sums
    k_row_forces      a thread a boundary row (rows nf..n-1): its force when inside a body box
    k_box_partials    block sums of those forces per body box (grid: blocks x bodies)
    k_sum_partials    the block sums added, a block a body
    k_extent          the rows' extent along the split axis (atomic min / max of block extremes)
    k_pick_edges      the body rows within the band of that extent, appended (atomic counter)
    k_extra_forces    the other ranks' edge rows' forces, a thread a row

When the device grid is not this row set's (the rows were uploaded again after a step's
exclusions, or no sort ran yet), the sample takes the host path (`ComputeBackend`'s).
"""
import contextlib
import math
import threading
import types

import numpy as np
from numba import cuda, njit

from sphgraph.config import O_KERNEL
from sphgraph.physics.probes import body_row_force, column_zrange, point_sums

from . import cuda_kernels as CK
from . import cpu_probes
from .cpu_probes import sort_edge_rows
from .cuda_memory import VEC, count_bytes, host_wait

RT = np.float64
PB = 128            # threads a block of the reductions (a power of two)
MOVED_H = 1.0       # the most a row moves between the sort and the sample, in h (_probe_radius)
# The probes task is a collective: mock ranks run it in one thread each, at once. A GPU
# takes their launches concurrently; numba's simulator runs one kernel at a time.
_SIM_ONE_KERNEL = threading.Lock() if CK.SIMULATOR else contextlib.nullcontext()


def k_column_zrange(cols, nvert, px, py, pz, start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, radius, prm,
                    dim, out):
    """out[2c], out[2c + 1] = lowest, highest vertical coordinate of the fluid rows within
    2h of column c (cols[2c], cols[2c + 1]) horizontally; block c, its threads over the
    column's vertical cells."""
    c = cuda.blockIdx.x
    t = cuda.threadIdx.x
    smin = cuda.shared.array(PB, RT)
    smax = cuda.shared.array(PB, RT)
    lo = math.inf
    hi = -math.inf
    v = t
    while v < nvert:
        a, b = column_zrange(cols[2 * c], cols[2 * c + 1], v, v, px, py, pz, 1, 0, 0, start, o0, o1, o2,
                             inv_size, n0, n1, n2, a0, a1, a2, radius, prm, dim)
        if a < lo:
            lo = a
        if b > hi:
            hi = b
        v += PB
    smin[t] = lo
    smax[t] = hi
    cuda.syncthreads()
    s = PB // 2
    while s > 0:
        if t < s:
            if smin[t + s] < smin[t]:
                smin[t] = smin[t + s]
            if smax[t + s] > smax[t]:
                smax[t] = smax[t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        out[2 * c] = smin[0]
        out[2 * c + 1] = smax[0]


def k_point_sums(pts, k, px, py, pz, vel4, start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, radius, prm, dim,
                 kernel, out):
    """out[5i:5i+5] = physics.probes.point_sums at point i (pts[3i:3i+3])."""
    i = cuda.grid(1)
    if i >= k:
        return
    sw, swp, s0, s1, s2 = point_sums(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2], px, py, pz, 1, 0, 0, vel4, 4,
                                     vel4, 4, 3, start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, radius,
                                     prm, dim, kernel)
    out[5 * i] = sw
    out[5 * i + 1] = swp
    out[5 * i + 2] = s0
    out[5 * i + 3] = s1
    out[5 * i + 4] = s2


@njit(inline="always")
def _in_box(boxes, b, x, y, z, dim):
    """(x, y, z) inside box b of `boxes` (6 a box: lo xyz, hi xyz; inclusive; z only in 3D)."""
    inside = boxes[6 * b] <= x <= boxes[6 * b + 3] and boxes[6 * b + 1] <= y <= boxes[6 * b + 4]
    if dim == 3:
        inside = inside and boxes[6 * b + 2] <= z <= boxes[6 * b + 5]
    return inside


def k_row_forces(i0, n, px, py, pz, vel4, boxes, nb, start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, radius,
                 prm, dim, kernel, fx, fy, fz):
    """Boundary rows i0..n-1: f[i - i0] = the fluid's force on row i when it lies in any
    body box (boxes[6b:6b+6]: lo xyz, hi xyz), else 0."""
    i = cuda.grid(1) + i0
    if i >= n:
        return
    z = 0.0
    if dim == 3:
        z = pz[i]
    x = px[i]
    y = py[i]
    inside = False
    for b in range(nb):
        if _in_box(boxes, b, x, y, z, dim):
            inside = True
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if inside:
        gx, gy, gz = body_row_force(x, y, z, vel4[4 * i + 3], px, py, pz, 1, 0, 0, vel4, 4, 3, start, o0, o1, o2,
                                    inv_size, n0, n1, n2, a0, a1, a2, radius, prm, dim, kernel)
    fx[i - i0] = gx
    fy[i - i0] = gy
    fz[i - i0] = gz


def k_box_partials(i0, n, px, py, pz, dim, boxes, fx, fy, fz, part):
    """part[3 (b nblk + blk) + d] = sum of f_d over the rows of block blk that lie in box b
    (grid: blocks x boxes)."""
    blk = cuda.blockIdx.x
    b = cuda.blockIdx.y
    nblk = cuda.gridDim.x
    t = cuda.threadIdx.x
    sh = cuda.shared.array((3, PB), RT)
    i = i0 + blk * PB + t
    sh[0, t] = 0.0
    sh[1, t] = 0.0
    sh[2, t] = 0.0
    if i < n:
        z = 0.0
        if dim == 3:
            z = pz[i]
        if _in_box(boxes, b, px[i], py[i], z, dim):
            sh[0, t] = fx[i - i0]
            sh[1, t] = fy[i - i0]
            sh[2, t] = fz[i - i0]
    cuda.syncthreads()
    s = PB // 2
    while s > 0:
        if t < s:
            for d in range(3):
                sh[d, t] += sh[d, t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        for d in range(3):
            part[3 * (b * nblk + blk) + d] = sh[d, 0]


def k_sum_partials(part, nblk, out):
    """out[3b + d] = the block sums of box b added (block b; each thread a fixed stride of
    blocks, then a tree)."""
    b = cuda.blockIdx.x
    t = cuda.threadIdx.x
    sh = cuda.shared.array((3, PB), RT)
    for d in range(3):
        acc = 0.0
        k = t
        while k < nblk:
            acc += part[3 * (b * nblk + k) + d]
            k += PB
        sh[d, t] = acc
    cuda.syncthreads()
    s = PB // 2
    while s > 0:
        if t < s:
            for d in range(3):
                sh[d, t] += sh[d, t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        for d in range(3):
            out[3 * b + d] = sh[d, 0]


def k_extent(xa, n, ext):
    """ext[0], ext[1] = min, max of xa[0:n] (ext set to +inf, -inf by the caller)."""
    t = cuda.threadIdx.x
    smin = cuda.shared.array(PB, RT)
    smax = cuda.shared.array(PB, RT)
    lo = math.inf
    hi = -math.inf
    i = cuda.grid(1)
    while i < n:
        if xa[i] < lo:
            lo = xa[i]
        if xa[i] > hi:
            hi = xa[i]
        i += cuda.gridsize(1)
    smin[t] = lo
    smax[t] = hi
    cuda.syncthreads()
    s = PB // 2
    while s > 0:
        if t < s:
            if smin[t + s] < smin[t]:
                smin[t] = smin[t + s]
            if smax[t + s] > smax[t]:
                smax[t] = smax[t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        cuda.atomic.min(ext, 0, smin[0])
        cuda.atomic.max(ext, 1, smax[0])


def k_pick_edges(i0, n, px, py, pz, vel4, dim, xa, ext, band, boxes, nb, cnt, cap, out):
    """Boundary rows i0..n-1 within `band` of the extent ext along the split axis (xa) and
    inside box b: (x, y, z, rho, b) appended to out (5 a row; the first `cap`), counted in
    cnt[0] (order: whichever thread comes first; the host sorts them)."""
    i = cuda.grid(1) + i0
    if i >= n:
        return
    if not (xa[i] <= ext[0] + band or xa[i] >= ext[1] - band):
        return
    z = 0.0
    if dim == 3:
        z = pz[i]
    for b in range(nb):
        if _in_box(boxes, b, px[i], py[i], z, dim):
            k = cuda.atomic.add(cnt, 0, 1)
            if k < cap:
                out[5 * k] = px[i]
                out[5 * k + 1] = py[i]
                out[5 * k + 2] = z
                out[5 * k + 3] = vel4[4 * i + 3]
                out[5 * k + 4] = b


def k_extra_forces(m, rows, px, py, pz, vel4, start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, radius, prm,
                   dim, kernel, out):
    """out[3i:3i+3] = the owned fluid's force on edge row i of another rank (rows[5i:5i+5]:
    x, y, z, rho, body)."""
    i = cuda.grid(1)
    if i >= m:
        return
    gx, gy, gz = body_row_force(rows[5 * i], rows[5 * i + 1], rows[5 * i + 2], rows[5 * i + 3], px, py, pz, 1, 0,
                                0, vel4, 4, 3, start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, radius, prm,
                                dim, kernel)
    out[3 * i] = gx
    out[3 * i + 1] = gy
    out[3 * i + 2] = gz


KERNELS = ("k_column_zrange", "k_point_sums", "k_row_forces", "k_box_partials", "k_sum_partials", "k_extent",
           "k_pick_edges", "k_extra_forces")


def build() -> types.SimpleNamespace:
    """The kernels, float64 sums (built once)."""
    return CK.kernel_set(globals(), KERNELS, np.float64)


class CudaProbes:
    """`probe_bounds` / `probe_sums` on the device rows (mixed into NumbaCUDA)."""

    def _probe_grid(self, state, dv):
        """The grid arguments of the kernels, or None when the device grid is not of the rows
        the device holds (uploaded again since the sort, or none sorted yet)."""
        g = None if dv is None else dv.grid
        if g is None or g.get("rows") != (dv.n, dv.nf):
            return None
        o, dims, axes = g["origin"], g["dims"], g["axes"]
        return (dv.arrays["start"], float(o[0]), float(o[1]), float(o[2]), float(g["inv"]), int(dims[0]),
                int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), self._probe_radius(state))

    @staticmethod
    def _probe_radius(state) -> float:
        """The cells searched about a point: the grid is of the rows' positions at the sort
        (the step's start), so 2h plus the most a fluid row moves in a step, bounded by h: a
        CFL step moves one by a few hundredths of h (dt <= CFL h / (10 |v|max) and
        CFL sqrt(h / |a|max)), shifting by at most 0.1 dp a component."""
        return (cpu_probes.SEARCH + MOVED_H) * float(state.consts.h)

    def _probe_in(self, state, name, host):
        """`host` (float64) on the device in the kept buffer `name` (flat)."""
        dv = state.extra["dev"]
        h = np.ascontiguousarray(host, np.float64).reshape(-1)
        d = dv.dev_buf(name, max(h.nbytes, 8)).view(np.float64)[:max(len(h), 1)]
        if len(h):
            d[:len(h)].copy_to_device(h, stream=self._s(state))
            count_bytes(state, "h2d_bytes", "probes", h.nbytes)
        return d

    def _probe_out(self, state, name, m):
        return state.extra["dev"].dev_buf(name, max(8 * m, 8)).view(np.float64)[:max(m, 1)]

    def _probe_host(self, state, dev, m):
        """The first m values of `dev` on the host (waits for the task's stream)."""
        s = self._s(state)
        h = dev[:max(m, 1)].copy_to_host(stream=s)
        host_wait(s)
        count_bytes(state, "d2h_bytes", "probes", 8 * m)
        return h[:m]

    def _probe_prm(self, state):
        dv = state.extra["dev"]
        d = dv.arrays.get("probe_prm")
        if d is None:
            d = dv.arrays["probe_prm"] = cuda.to_device(np.ascontiguousarray(state.consts.prm, np.float64))
        return d

    def probe_bounds(self, state, columns, boxes, band) -> dict:
        dv = state.extra.get("dev")
        grid = self._probe_grid(state, dv)
        if grid is None:
            return super().probe_bounds(state, columns, boxes, band)
        with _SIM_ONE_KERNEL:
            return self._probe_bounds(state, dv, grid, columns, boxes, band)

    def _probe_bounds(self, state, dv, grid, columns, boxes, band) -> dict:
        k = self._on(state, build())
        A = dv.A()
        dim = dv.dim
        prm = self._probe_prm(state)
        c = len(columns)
        zr = np.empty((c, 2))
        if c:
            g = dv.grid
            vert = int(np.nonzero(np.asarray(g["axes"]) == dim - 1)[0][0])
            nvert = int(g["dims"][vert])
            out = self._probe_out(state, "probe_zr", 2 * c)
            k.k_column_zrange[c, PB](self._probe_in(state, "probe_cols", columns), nvert, A["px"], A["py"], A["pz"],
                                     *grid, prm, dim, out)
            zr = self._probe_host(state, out, 2 * c).reshape(c, 2)
        edge = np.zeros((0, 5))
        nbd = dv.n - dv.nf
        if band > 0 and len(boxes) and nbd > 0:
            edge = self._probe_edges(state, dv, k, A, boxes, band)
        return {"zrange": zr, "edge": edge}

    def _probe_edges(self, state, dv, k, A, boxes, band):
        """The body rows within `band` of the rows' extent along the split axis (cpu_probes.edge_rows)."""
        s = self._s(state)
        xa = A["p" + VEC[state.axis]]
        ext = self._probe_in(state, "probe_ext", np.array([np.inf, -np.inf]))
        k.k_extent[min(CK.REDUCE_BLOCKS, CK.blocks(dv.n, PB)), PB](xa, dv.n, ext)
        cnt = dv.arrays.get("probe_cnt")
        if cnt is None:
            cnt = dv.arrays["probe_cnt"] = cuda.to_device(np.zeros(1, np.int32))
        bx = self._probe_in(state, "probe_boxes", boxes)
        nbd = dv.n - dv.nf
        cap = state.extra.get("probe_edge_cap", 1024)
        while True:
            cnt.copy_to_device(np.zeros(1, np.int32), stream=s)
            out = self._probe_out(state, "probe_edge", 5 * cap)
            k.k_pick_edges[CK.blocks(nbd), CK.BLOCK](dv.nf, dv.n, A["px"], A["py"], A["pz"], A["vel4"], dv.dim, xa,
                                                     ext, float(band), bx, len(boxes), cnt, cap, out)
            m = int(self._probe_host_i(state, cnt))
            if m <= cap:
                break
            cap = state.extra["probe_edge_cap"] = int(m * 1.5) + 64
        return sort_edge_rows(self._probe_host(state, out, 5 * m).reshape(m, 5))

    def _probe_host_i(self, state, dev):
        s = self._s(state)
        h = dev.copy_to_host(stream=s)
        host_wait(s)
        count_bytes(state, "d2h_bytes", "probes", 4)
        return h[0]

    def probe_sums(self, state, points, boxes, extra) -> dict:
        dv = state.extra.get("dev")
        grid = self._probe_grid(state, dv)
        if grid is None:
            return super().probe_sums(state, points, boxes, extra)
        with _SIM_ONE_KERNEL:
            return self._probe_sums(state, dv, grid, points, boxes, extra)

    def _probe_sums(self, state, dv, grid, points, boxes, extra) -> dict:
        k = self._on(state, build())
        A = dv.A()
        dim = dv.dim
        prm = self._probe_prm(state)
        kern = int(state.opt[O_KERNEL])
        res = {"points": np.zeros((len(points), 5)), "forces": np.zeros((len(boxes), 3))}
        if len(points):
            n = len(points)
            out = self._probe_out(state, "probe_pts_out", 5 * n)
            k.k_point_sums[CK.blocks(n, PB), PB](self._probe_in(state, "probe_pts", points), n, A["px"], A["py"],
                                                 A["pz"], A["vel4"], *grid, prm, dim, kern, out)
            res["points"] = self._probe_host(state, out, 5 * n).reshape(n, 5)
        nbd = dv.n - dv.nf
        if len(boxes) and nbd > 0:
            nb = len(boxes)
            bx = self._probe_in(state, "probe_boxes", boxes)
            f = [self._probe_out(state, "probe_f" + ax, nbd) for ax in VEC]
            k.k_row_forces[CK.blocks(nbd, PB), PB](dv.nf, dv.n, A["px"], A["py"], A["pz"], A["vel4"], bx, nb,
                                                   *grid, prm, dim, kern, *f)
            nblk = CK.blocks(nbd, PB)
            part = self._probe_out(state, "probe_part", 3 * nb * nblk)
            k.k_box_partials[(nblk, nb), PB](dv.nf, dv.n, A["px"], A["py"], A["pz"], dim, bx, *f, part)
            out = self._probe_out(state, "probe_F", 3 * nb)
            k.k_sum_partials[nb, PB](part, nblk, out)
            res["forces"] = self._probe_host(state, out, 3 * nb).reshape(nb, 3)
        if len(boxes) and len(extra):
            from .cpu_probes import extra_forces
            m = len(extra)
            out = self._probe_out(state, "probe_xf", 3 * m)
            k.k_extra_forces[CK.blocks(m, PB), PB](m, self._probe_in(state, "probe_extra", extra), A["px"], A["py"],
                                                   A["pz"], A["vel4"], *grid, prm, dim, kern, out)
            res["forces"] += extra_forces(self._probe_host(state, out, 3 * m).reshape(m, 3), extra, len(boxes))
        return res
