"""numba.cuda kernel of mDBC (sphgraph.physics.mdbc): the GPU twin of cpu_mdbc.mdbc_boundary, one
thread a boundary row, with the same per-row maths (`ghost_add`, `ghost_value`) on local arrays.

The ghost node of each boundary particle is fixed (the scene's geometry; no moving bodies): it
is computed once on the host from the particle's start position (`ghost_positions`) and kept
on the device as a table by particle id, so a stage moves nothing across the bus. The
kernel reads the rank's fluid rows through the kind-split cells (the fluid half of `start`)
and writes each boundary row's density, velocity and pressure in place (fluid rows are only
read: no race).
"""
import math  # noqa: F401  (the cloned device functions use it)
import types

import numpy as np
from numba import cuda

from sphgraph.cells import cell_window
from sphgraph.config import O_KERNEL, P_MASS_F, P_SUPPORT2
from sphgraph.physics.eos import tait
from sphgraph.physics.mdbc import ghost_add, ghost_positions, ghost_value

from . import cuda_kernels as CK

RT = np.float64


def k_mdbc(px, py, pz, ghost, ids, vx, vy, vz, rho, press, i0, n, start, o0, o1, o2, inv_size,
           n0, n1, n2, a0, a1, a2, reach, prm, dim, kernel_id, det_min, noslip):
    """Boundary rows i0..n-1: density (and, with `noslip`, velocity) from the fluid about the
    row's ghost node ghost[3 id : 3 id + 3], and the row's pressure."""
    i = cuda.grid(1) + i0
    if i >= n:
        return
    A = cuda.local.array((4, 4), RT)
    b = cuda.local.array(4, RT)
    A2 = cuda.local.array((4, 4), RT)
    b2 = cuda.local.array(4, RT)
    vs = cuda.local.array(3, RT)
    for r in range(4):
        b[r] = 0.0
        for c in range(4):
            A[r, c] = 0.0
    for r in range(3):
        vs[r] = 0.0
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    g = 3 * ids[i]
    gx = ghost[g]
    gy = ghost[g + 1]
    gz = ghost[g + 2] if dim == 3 else 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(gx, gy, gz, o0, o1, o2, inv_size, n0, n1, n2,
                                                      a0, a1, a2, reach)
    sw = 0.0 * rho[i]
    if not empty:
        for c2 in range(lo2, hi2 + 1):
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + lo0], start[row + hi0 + 1]):     # the fluid half: fluid rows
                    dx0 = px[j] - gx
                    dx1 = py[j] - gy
                    dx2 = (pz[j] - gz) if dim == 3 else 0.0
                    r2 = dx0 * dx0 + dx1 * dx1 + dx2 * dx2
                    if r2 >= support2:
                        continue
                    sw += ghost_add(A, b, vs, dx0, dx1, dx2, r2, rho[j], vx[j], vy[j],
                                    vz[j] if dim == 3 else 0.0, m, dim, prm, kernel_id)
    rr, u0, u1, u2 = ghost_value(A, b, A2, b2, vs, sw, px[i] - gx, py[i] - gy,
                                 (pz[i] - gz) if dim == 3 else 0.0, dim, prm, det_min, noslip)
    rho[i] = rr
    vx[i] = u0
    vy[i] = u1
    if dim == 3:
        vz[i] = u2
    press[i] = tait(rr, prm)


_BUILT: dict = {}


def build(dtype) -> types.SimpleNamespace:
    dt = np.dtype(dtype)
    if dt.str not in _BUILT:
        _BUILT[dt.str] = types.SimpleNamespace(k_mdbc=CK.kernel(k_mdbc, dt, {}))
    return _BUILT[dt.str]


def ghost_table(particles, boxes) -> np.ndarray:
    """Ghost nodes by particle id (3 float64 each, flat) of the boundary rows of `particles`."""
    p = particles
    rows = np.nonzero(p.kind != 0)[0]
    table = np.zeros((max(int(p.id.max()) + 1, 1) if p.n else 1, 3))
    if len(rows):
        table[p.id[rows], :p.dim] = ghost_positions(np.asarray(p.pos[rows], np.float64), boxes)
    return table.ravel()


class CudaMdbc:
    """`ComputeBackend.mdbc` on the device rows (mixed into NumbaCUDA): the ghost table is
    built from the host rows' boundary positions on first use (boundary particles do not
    move: no [[motion]] bodies with mDBC) and kept on the device."""

    def mdbc(self, state, boxes, det_min, noslip) -> None:
        dv = state.extra["dev"]
        if dv.n <= dv.nf:
            return
        tab = state.extra.get("mdbc_ghost")
        if tab is None:
            tab = state.extra["mdbc_ghost"] = cuda.to_device(ghost_table(state.particles, boxes))
        A = dv.A()
        g = dv.grid
        o, dims, axes = g["origin"], g["dims"], g["axes"]
        k = self._on(state, build(dv.dtype))
        k.k_mdbc[CK.blocks(dv.n - dv.nf), CK.BLOCK](
            A["px"], A["py"], A["pz"], tab, A["id"], A["vx"], A["vy"], A["vz"], A["rho"], A["press"], dv.nf, dv.n,
            A["start"], float(o[0]), float(o[1]), float(o[2]), float(g["inv"]), int(dims[0]), int(dims[1]),
            int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), int(g["reach"]), dv.prm_d(state), dv.dim,
            int(state.opt[O_KERNEL]), float(det_min), bool(noslip))
        dv.host_stale = True
