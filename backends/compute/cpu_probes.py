"""The `[probes]` / `[forces]` partial sums of one rank on the host (`ComputeBackend.probe_bounds`
and `probe_sums`, the CPU implementation): numba CPU drivers of the per-point and per-row
functions of sphgraph.physics.probes over a cell grid of the rank's own fluid rows.

The grid is built for the sample (2h cells, the fluid rows only, at their end-of-step
positions): O(N) once per sample, against O(N) per probe for a scan of every row. Between
`probe_bounds` and `probe_sums` of one sample it is kept in ``state.extra["probe_rows"]``
(the rows do not change between the two) and dropped by `probe_sums`.
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

ROWS_PER_THREAD = 1000    # below this a parallel region costs more than it saves (numba_cpu)


@njit(parallel=True, cache=True)
def column_zranges(cols, sp, start, origin, inv_size, dims, axes, reach, prm, dim, out):
    """out[c] = (lowest, highest) vertical coordinate of the fluid rows within 2h of column
    cols[c] horizontally (`column_zrange` over every vertical cell)."""
    for c in prange(cols.shape[0]):
        lo, hi = column_zrange(cols[c, 0], cols[c, 1], 0, 1 << 62, sp, sp, sp, dim, 1, 2, start,
                               origin[0], origin[1], origin[2], inv_size, dims[0], dims[1], dims[2],
                               axes[0], axes[1], axes[2], reach, prm, dim)
        out[c, 0] = lo
        out[c, 1] = hi


@njit(parallel=True, cache=True)
def point_sums_at(pts, sp, sv, sr, start, origin, inv_size, dims, axes, reach, prm, dim, kernel, out):
    """out[i] = `point_sums` at pts[i] (x, y, z; z unused in 2D)."""
    for i in prange(pts.shape[0]):
        sw, swp, s0, s1, s2 = point_sums(pts[i, 0], pts[i, 1], pts[i, 2], sp, sp, sp, dim, 1, 2, sv, dim, sr, 1, 0,
                                         start, origin[0], origin[1], origin[2], inv_size, dims[0], dims[1],
                                         dims[2], axes[0], axes[1], axes[2], reach, prm, dim, kernel)
        out[i, 0] = sw
        out[i, 1] = swp
        out[i, 2] = s0
        out[i, 3] = s1
        out[i, 4] = s2


@njit(parallel=True, cache=True)
def row_forces(qpos, qrho, sp, sr, start, origin, inv_size, dims, axes, reach, prm, dim, kernel, out):
    """out[i] = `body_row_force` on the boundary row at qpos[i] (x, y, z) of density qrho[i]."""
    for i in prange(qpos.shape[0]):
        fx, fy, fz = body_row_force(qpos[i, 0], qpos[i, 1], qpos[i, 2], qrho[i], sp, sp, sp, dim, 1, 2, sr, 1, 0,
                                    start, origin[0], origin[1], origin[2], inv_size, dims[0], dims[1], dims[2],
                                    axes[0], axes[1], axes[2], reach, prm, dim, kernel)
        out[i, 0] = fx
        out[i, 1] = fy
        out[i, 2] = fz


def _threads(n: int) -> None:
    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS, n // ROWS_PER_THREAD)))


def _pad3(x) -> np.ndarray:
    """(n, dim) -> (n, 3) float64, zeros beyond dim."""
    x = np.asarray(x, np.float64)
    out = np.zeros((x.shape[0], 3))
    out[:, :x.shape[1]] = x
    return out


def in_boxes(pos, boxes) -> np.ndarray:
    """(n, b) bool: row inside box k (inclusive; boxes (b, 2, 3), the first dim axes used)."""
    dim = pos.shape[1]
    lo, hi = boxes[:, 0, :dim], boxes[:, 1, :dim]
    return np.all((pos[:, None, :] >= lo[None]) & (pos[:, None, :] <= hi[None]), axis=2)


class HostRows:
    """One rank's rows for a sample: the fluid rows sorted by a grid of 2h cells and the
    boundary rows, float64."""

    def __init__(self, state):
        p = state.particles
        self.dim = p.dim
        self.prm = np.ascontiguousarray(state.consts.prm, np.float64)
        self.kernel = int(state.opt[O_KERNEL])
        fl = p.kind == 0
        fpos = np.ascontiguousarray(p.pos[fl], np.float64)
        _threads(len(fpos))
        grid, perm = build_grid(fpos, 2.0 * float(self.prm[P_H]), 1, axis_order(self.dim))
        self.grid = grid
        self.sp = np.ascontiguousarray(fpos[perm]).reshape(-1)
        self.sv = np.ascontiguousarray(np.asarray(p.vel[fl], np.float64)[perm]).reshape(-1)
        self.sr = np.ascontiguousarray(np.asarray(p.rho[fl], np.float64)[perm])
        bd = ~fl
        self.bpos = np.asarray(p.pos[bd], np.float64)
        self.brho = np.asarray(p.rho[bd], np.float64)
        self.x = np.asarray(p.pos, np.float64)     # every owned row (the extent along the split axis)

    def grid_args(self):
        g = self.grid
        return g.start, g.origin, 1.0 / g.size, g.dims, g.axes, g.reach

    def forces(self, qpos, qrho) -> np.ndarray:
        """(m, 3) per-row forces of the fluid on boundary rows at qpos (m, 3) of density qrho."""
        out = np.zeros((len(qpos), 3))
        if len(qpos) and len(self.sr):
            _threads(len(qpos) * 16)
            row_forces(np.ascontiguousarray(qpos), np.ascontiguousarray(qrho, np.float64), self.sp, self.sr,
                       *self.grid_args(), self.prm, self.dim, self.kernel, out)
        return out


def _rows(state) -> HostRows:
    """The sample's HostRows, kept from probe_bounds for probe_sums (the same row set: the
    key is the particle set and its arrays)."""
    p = state.particles
    key = (id(p), id(p.pos), id(p.rho), p.n)
    got = state.extra.get("probe_rows")
    if got is not None and got[0] == key:
        return got[1]
    rows = HostRows(state)
    state.extra["probe_rows"] = (key, rows)
    return rows


def edge_rows(bpos, brho, x_axis, lo, hi, boxes, band) -> np.ndarray:
    """(m, 5) rows x, y, z, rho, body of the boundary rows at bpos (n, dim) inside body box
    k (one row per body) whose coordinate x_axis along the split axis is within `band` of
    the rank's extent [lo, hi]; sorted by body, then position (the receivers sum them in
    this order, whatever order the rows were found in)."""
    near = (x_axis <= lo + band) | (x_axis >= hi - band)
    inb = in_boxes(bpos, boxes) & near[:, None]
    r, k = np.nonzero(inb)
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
    rows = _rows(state)
    zr = np.empty((len(columns), 2))
    if len(columns):
        if len(rows.sr):
            _threads(len(rows.sr))
            column_zranges(np.ascontiguousarray(columns, np.float64), rows.sp, *rows.grid_args(), rows.prm,
                           rows.dim, zr)
        else:
            zr[:, 0], zr[:, 1] = np.inf, -np.inf
    edge = np.zeros((0, 5))
    if band > 0 and len(boxes) and len(rows.bpos):
        xa = rows.x[:, state.axis]
        edge = edge_rows(rows.bpos, rows.brho, rows.bpos[:, state.axis], float(xa.min()), float(xa.max()),
                         boxes, band)
    return {"zrange": zr, "edge": edge}


def host_sums(state, points, boxes, extra) -> dict:
    rows = _rows(state)
    state.extra.pop("probe_rows", None)     # the sample's last use
    out = np.zeros((len(points), 5))
    if len(points) and len(rows.sr):
        _threads(len(points) * 64)
        point_sums_at(np.ascontiguousarray(points, np.float64), rows.sp, rows.sv, rows.sr, *rows.grid_args(),
                      rows.prm, rows.dim, rows.kernel, out)
    F = np.zeros((len(boxes), 3))
    if len(boxes):
        inb = in_boxes(rows.bpos, boxes)
        sel = np.nonzero(inb.any(1))[0]
        f = rows.forces(_pad3(rows.bpos[sel]), rows.brho[sel])
        for k in range(len(boxes)):
            F[k] = f[inb[sel, k]].sum(0)
        if len(extra):
            F += extra_forces(rows.forces(extra[:, :3], extra[:, 3]), extra, len(boxes))
    return {"points": out, "forces": F}
