"""The `[probes]` / `[forces]` partial sums of one rank on the host (`ComputeBackend.probe_bounds`
and `probe_sums`, the CPU implementation): numba CPU drivers of the per-point and per-row
functions of sphgraph.physics.probes over a cell grid of the rank's own fluid rows.

The grid is built for the sample (2h cells, at the rows' end-of-step positions) over the
fluid rows that can matter: those within 2h of a point, a column, a body box or another
rank's edge row (`regions`); one pass over the rows picks them, a probe or a body costs
what its neighbourhood holds.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from sphgraph.physics import drop_stale_cache

drop_stale_cache(__file__)  # the kernels inline sphgraph.physics: recompile when it changes

from sphgraph.cells import axis_order, build_grid  # noqa: E402
from sphgraph.config import O_KERNEL, P_H  # noqa: E402
from sphgraph.physics.probes import body_row_force, column_zrange, point_sums  # noqa: E402

# rows a thread below which a parallel region costs more than it saves: a region is ~20 us
# idle and milliseconds on a loaded machine, where one thread picks the rows near a body
# among 95 k in 0.16 ms (a few compares a row) and a body row's neighbour loop is ~1 us
ROWS_PER_THREAD_PICK = 500000   # a pass that picks rows (a few compares each)
ROWS_PER_THREAD_LIGHT = 20000   # the grid's sort (numba_cpu's for its O(N) kernels)
ROWS_PER_THREAD_PAIRS = 1000    # a neighbour loop a row (a point, a body row)
SEARCH = 2.0 * (1 + 1e-9)  # the radius of the cells searched, in h: the support, and a hair


@njit(parallel=True, cache=True)
def column_zranges(cols, sp, start, origin, inv_size, dims, axes, radius, prm, dim, out):
    """out[c] = (lowest, highest) vertical coordinate of the fluid rows within 2h of column
    cols[c] horizontally (`column_zrange` over every vertical cell)."""
    for c in prange(cols.shape[0]):
        lo, hi = column_zrange(cols[c, 0], cols[c, 1], 0, 1 << 62, sp, sp, sp, dim, 1, 2, start,
                               origin[0], origin[1], origin[2], inv_size, dims[0], dims[1], dims[2],
                               axes[0], axes[1], axes[2], radius, prm, dim)
        out[c, 0] = lo
        out[c, 1] = hi


@njit(parallel=True, cache=True)
def point_sums_at(pts, sp, sv, sr, start, origin, inv_size, dims, axes, radius, prm, dim, kernel, out):
    """out[i] = `point_sums` at pts[i] (x, y, z; z unused in 2D)."""
    for i in prange(pts.shape[0]):
        sw, swp, s0, s1, s2 = point_sums(pts[i, 0], pts[i, 1], pts[i, 2], sp, sp, sp, dim, 1, 2, sv, dim, sr, 1, 0,
                                         start, origin[0], origin[1], origin[2], inv_size, dims[0], dims[1],
                                         dims[2], axes[0], axes[1], axes[2], radius, prm, dim, kernel)
        out[i, 0] = sw
        out[i, 1] = swp
        out[i, 2] = s0
        out[i, 3] = s1
        out[i, 4] = s2


@njit(parallel=True, cache=True)
def row_forces(qpos, qrho, sp, sr, start, origin, inv_size, dims, axes, radius, prm, dim, kernel, out):
    """out[i] = `body_row_force` on the boundary row at qpos[i] (x, y, z) of density qrho[i]."""
    for i in prange(qpos.shape[0]):
        fx, fy, fz = body_row_force(qpos[i, 0], qpos[i, 1], qpos[i, 2], qrho[i], sp, sp, sp, dim, 1, 2, sr, 1, 0,
                                    start, origin[0], origin[1], origin[2], inv_size, dims[0], dims[1], dims[2],
                                    axes[0], axes[1], axes[2], radius, prm, dim, kernel)
        out[i, 0] = fx
        out[i, 1] = fy
        out[i, 2] = fz


def _threads(n: int, per: int) -> None:
    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS, n // per)))


def _pad3(x) -> np.ndarray:
    """(n, dim) -> (n, 3) float64, zeros beyond dim."""
    x = np.asarray(x, np.float64)
    out = np.zeros((x.shape[0], 3))
    out[:, :x.shape[1]] = x
    return out


@njit(parallel=True, cache=True)
def fluid_in_regions(pos, kind, regions, out):
    """out[i]: row i is fluid and inside any box of `regions` (m, 2, 3: lo, hi; the first dim
    axes)."""
    dim = pos.shape[1]
    for i in prange(pos.shape[0]):
        hit = False
        if kind[i] == 0:
            for k in range(regions.shape[0]):
                inside = True
                for d in range(dim):
                    if pos[i, d] < regions[k, 0, d] or pos[i, d] > regions[k, 1, d]:
                        inside = False
                if inside:
                    hit = True
        out[i] = hit


class HostRows:
    """One rank's rows for a sample: its fluid rows inside `regions` (the boxes that hold every
    fluid row within 2h of what is sampled), sorted by a grid of 2h cells, float64; and its
    boundary rows."""

    def __init__(self, state, regions):
        p = state.particles
        self.dim = p.dim
        self.prm = np.ascontiguousarray(state.consts.prm, np.float64)
        self.kernel = int(state.opt[O_KERNEL])
        _threads(p.n, ROWS_PER_THREAD_PICK)
        near = np.empty(p.n, np.bool_)
        fluid_in_regions(p.pos, p.kind, np.ascontiguousarray(regions, np.float64), near)
        fpos = np.asarray(p.pos[near], np.float64)
        _threads(len(fpos), ROWS_PER_THREAD_LIGHT)
        grid, perm = build_grid(fpos, 2.0 * float(self.prm[P_H]), 1, axis_order(self.dim))
        self.grid = grid
        self.sp = np.ascontiguousarray(fpos[perm]).reshape(-1)
        self.sv = np.ascontiguousarray(np.asarray(p.vel[near], np.float64)[perm]).reshape(-1)
        self.sr = np.ascontiguousarray(np.asarray(p.rho[near], np.float64)[perm])

    def grid_args(self):
        """The drivers' grid arguments; the cells searched: those within 2h (a hair more
        against rounding) of the point, the grid being of the rows' present positions."""
        g = self.grid
        return g.start, g.origin, 1.0 / g.size, g.dims, g.axes, SEARCH * float(self.prm[P_H])

    def forces(self, qpos, qrho) -> np.ndarray:
        """(m, 3) per-row forces of the fluid on boundary rows at qpos (m, 3) of density qrho."""
        out = np.zeros((len(qpos), 3))
        if len(qpos) and len(self.sr):
            _threads(len(qpos), ROWS_PER_THREAD_PAIRS)
            row_forces(np.ascontiguousarray(qpos), np.ascontiguousarray(qrho, np.float64), self.sp, self.sr,
                       *self.grid_args(), self.prm, self.dim, self.kernel, out)
        return out


def regions(h, dim, points=(), columns=(), boxes=(), extra=()) -> np.ndarray:
    """(m, 2, 3) boxes that hold every fluid row within 2h of a point, a column (horizontally;
    the vertical axis is dim - 1), a body box or an edge row of another rank."""
    r = SEARCH * h
    # a height column's points, on one vertical line dp/4 apart, in one box
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.lexsort((pts[:, dim - 1],) + tuple(pts[:, d] for d in range(dim - 2, -1, -1)))]
    apart = ~(np.all(pts[1:, :dim - 1] == pts[:-1, :dim - 1], axis=1) & (np.diff(pts[:, dim - 1]) < r))
    first = np.concatenate([[0], np.nonzero(apart)[0] + 1]).astype(np.int64)
    last = np.concatenate([first[1:] - 1, [len(pts) - 1]]).astype(np.int64)
    out = [np.stack([pts[i] - r, pts[j] + r]) for i, j in zip(first, last)] if len(pts) else []
    for c in np.asarray(columns, np.float64).reshape(-1, 2):
        lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
        lo[:dim - 1], hi[:dim - 1] = c[:dim - 1] - r, c[:dim - 1] + r
        out.append(np.stack([lo, hi]))
    out += [np.stack([b[0] - r, b[1] + r]) for b in np.asarray(boxes, np.float64).reshape(-1, 2, 3)]
    if len(extra):
        out.append(np.stack([extra[:, :3].min(0) - r, extra[:, :3].max(0) + r]))
    return np.array(out).reshape(-1, 2, 3)


@njit(parallel=True, cache=True)
def boundary_in_boxes(pos, kind, boxes, out):
    """out[i, k]: row i is a boundary row inside box k (boxes (b, 2, 3): lo, hi, inclusive;
    the first dim axes)."""
    dim = pos.shape[1]
    for i in prange(pos.shape[0]):
        for k in range(boxes.shape[0]):
            inside = kind[i] != 0
            for d in range(dim):
                if pos[i, d] < boxes[k, 0, d] or pos[i, d] > boxes[k, 1, d]:
                    inside = False
            out[i, k] = inside


def body_rows(state, boxes):
    """The rank's boundary rows inside any body box: (positions (m, dim), densities (m,),
    membership (m, b) bool), float64."""
    p = state.particles
    _threads(p.n, ROWS_PER_THREAD_PICK)
    inb = np.empty((p.n, len(boxes)), np.bool_)
    boundary_in_boxes(p.pos, p.kind, np.ascontiguousarray(boxes, np.float64), inb)
    sel = np.nonzero(inb.any(1))[0]
    return np.asarray(p.pos[sel], np.float64), np.asarray(p.rho[sel], np.float64), inb[sel]


def edge_rows(bpos, brho, inb, x_axis, lo, hi, band) -> np.ndarray:
    """(m, 5) rows x, y, z, rho, body of the body rows at bpos (n, dim) (inb (n, b): inside
    body box k; one row a body) whose coordinate x_axis along the split axis is within `band`
    of the rank's extent [lo, hi]; sorted by body, then position (the receivers sum them in
    this order, whatever order the rows were found in)."""
    near = (x_axis <= lo + band) | (x_axis >= hi - band)
    r, k = np.nonzero(inb & near[:, None])
    out = np.zeros((len(r), 5))
    out[:, :bpos.shape[1]] = bpos[r]
    out[:, 3] = brho[r]
    out[:, 4] = k
    return sort_edge_rows(out)


def sort_edge_rows(e) -> np.ndarray:
    return e[np.lexsort((e[:, 2], e[:, 1], e[:, 0], e[:, 4]))] if len(e) else e


def extra_forces(rows_forces, extra, nbodies) -> np.ndarray:
    """(b, 3): the per-row forces of the other ranks' edge rows summed by body, in row order."""
    F = np.zeros((nbodies, 3))
    for k in range(nbodies):
        F[k] = rows_forces[extra[:, 4] == k].sum(0)
    return F


def host_bounds(state, columns, boxes, band) -> dict:
    p = state.particles
    zr = np.empty((len(columns), 2))
    zr[:, 0], zr[:, 1] = np.inf, -np.inf
    h = float(state.consts.h)
    if len(columns):
        rows = HostRows(state, regions(h, p.dim, columns=columns))
        if len(rows.sr):
            _threads(len(columns), 1)
            column_zranges(np.ascontiguousarray(columns, np.float64), rows.sp, *rows.grid_args(), rows.prm,
                           rows.dim, zr)
    edge = np.zeros((0, 5))
    if band > 0 and len(boxes) and p.n:
        bpos, brho, inb = body_rows(state, boxes)
        xa = np.asarray(p.pos[:, state.axis])
        edge = edge_rows(bpos, brho, inb, bpos[:, state.axis], float(xa.min()), float(xa.max()), band)
    return {"zrange": zr, "edge": edge}


def host_sums(state, points, boxes, extra) -> dict:
    rows = HostRows(state, regions(float(state.consts.h), state.particles.dim, points=points, boxes=boxes, extra=extra))
    out = np.zeros((len(points), 5))
    if len(points) and len(rows.sr):
        _threads(len(points), ROWS_PER_THREAD_PAIRS)
        point_sums_at(np.ascontiguousarray(points, np.float64), rows.sp, rows.sv, rows.sr, *rows.grid_args(),
                      rows.prm, rows.dim, rows.kernel, out)
    F = np.zeros((len(boxes), 3))
    if len(boxes):
        bpos, brho, inb = body_rows(state, boxes)
        f = rows.forces(_pad3(bpos), brho)
        for k in range(len(boxes)):
            F[k] = f[inb[:, k]].sum(0)
        if len(extra):
            F += extra_forces(rows.forces(extra[:, :3], extra[:, 3]), extra, len(boxes))
    return {"points": out, "forces": F}
