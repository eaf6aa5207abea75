"""numba CPU kernels of particle shifting (sphgraph.shifting, pair maths in
sphgraph.physics.shifting): a neighbour pass apart from the force loop, on the same
cell grids, so the force kernels stay as they are and runs without shifting pay nothing.

Per source set (interior, each halo, periodic images) `shift_sums` writes partial sums;
`shift_reduce` adds them in a fixed order and turns them into displacements;
`shift_add` moves the fluid rows.
"""
import math

from numba import njit, prange

from sphgraph.physics import drop_stale_cache

drop_stale_cache(__file__)  # the kernels inline sphgraph.physics: recompile when it changes

from sphgraph.config import O_DIM, O_KERNEL  # noqa: E402
from sphgraph.physics.shifting import clamp, shift_row, shift_scale  # noqa: E402


@njit(parallel=True, fastmath=True, cache=True)
def shift_sums(dpos, dkind, spos, srho, skind, start, origin, inv_size, dims, axes, reach,
               prm, opt, mode, grad, div, cancel):
    """grad C, div r and the cancel flag of every fluid destination row against one
    source set binned in a plain grid (overwritten; 0 for boundary rows): the per-row
    sums of sphgraph.physics.shifting.shift_row. `spos`: the sources' (n, dim) positions
    flattened."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    for i in prange(dpos.shape[0]):
        gx = 0.0 * grad[i, 0]
        gy = gx
        gz = gx
        dv = gx
        cc = 0
        if dkind[i] == 0:
            xa = dpos[i, 0]
            ya = dpos[i, 1]
            za = dpos[i, 2] if dim == 3 else 0.0
            gx, gy, gz, dv, cc = shift_row(xa, ya, za, xa, ya, za, spos, spos, spos, dim, 1, 2, srho, 1, 0, skind,
                                           start, 0,
                                           origin[0], origin[1], origin[2], inv_size, dims[0], dims[1], dims[2],
                                           axes[0], axes[1], axes[2], reach, prm, dim, kernel, mode)
        grad[i, 0] = gx
        grad[i, 1] = gy
        if dim == 3:
            grad[i, 2] = gz
        div[i] = dv
        cancel[i] = cc


@njit(parallel=True, cache=True)
def shift_reduce(grads, divs, cancels, vel, kind, coefumagn, tfs, coeftfs, maxdist, out):
    """Displacement of each row: the parts summed in their fixed order, then
    dr = clamp(ShiftCoef h dt |v| f(div r) grad C, 0.1 dp); 0 for boundary and cancelled rows."""
    nparts = len(grads)
    dim = out.shape[1]
    for i in prange(out.shape[0]):
        cc = 0
        for k in range(nparts):
            cc |= cancels[k][i]
        if kind[i] != 0 or cc != 0:
            for d in range(dim):
                out[i, d] = 0.0
            continue
        dv = 0.0 * divs[0][i]
        v2 = 0.0 * dv
        for k in range(nparts):
            dv += divs[k][i]
        for d in range(dim):
            v2 += vel[i, d] * vel[i, d]
        u = shift_scale(math.sqrt(v2), dv, coefumagn, tfs, coeftfs)
        for d in range(dim):
            g = 0.0 * dv
            for k in range(nparts):
                g += grads[k][i, d]
            out[i, d] = clamp(g * u, maxdist)


@njit(parallel=True, cache=True)
def shift_add(pos, shift):
    """pos += shift (applied after the position update, as DualSPHysics adds it to dx)."""
    dim = pos.shape[1]
    for i in prange(pos.shape[0]):
        for d in range(dim):
            pos[i, d] += shift[i, d]
