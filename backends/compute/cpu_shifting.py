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

from sphgraph.cells import cell_window  # noqa: E402
from sphgraph.config import O_DIM, O_KERNEL, P_MASS_B, P_MASS_F, P_SUPPORT2  # noqa: E402
from sphgraph.particles import FIXED  # noqa: E402
from sphgraph.physics.shifting import clamp, shift_pair, shift_scale  # noqa: E402

# mode ids = index in sphgraph.config.SHIFTINGS (DualSPHysics TpShifting)
NOBOUND, NOFIXED = 1, 2


@njit(parallel=True, fastmath=True, cache=True)
def shift_sums(dpos, dkind, spos, srho, skind, start, origin, inv_size, dims, axes, reach,
               prm, opt, mode, grad, div, cancel):
    """grad C, div r and the cancel flag of every fluid destination row against one
    source set binned in a grid (overwritten; 0 for boundary rows).

    A boundary neighbour cancels the shift in mode "nobound", a fixed one in "nofixed"
    (DualSPHysics: noshift = boundp2 && (NoBound || (NoFixed && fixed))); "full" sums
    boundary neighbours like fluid ones."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    nf = dims[0]
    nm = dims[1]
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
            lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(xa, ya, za, origin[0], origin[1], origin[2], inv_size,
                                                              nf, nm, dims[2], axes[0], axes[1], axes[2], reach)
            if not empty:
                for c2 in range(lo2, hi2 + 1):
                    for c1 in range(lo1, hi1 + 1):
                        row = (c2 * nm + c1) * nf
                        for j in range(start[row + lo0], start[row + hi0 + 1]):
                            drx = xa - spos[j, 0]
                            dry = ya - spos[j, 1]
                            drz = (za - spos[j, 2]) if dim == 3 else 0.0
                            r2 = drx * drx + dry * dry + drz * drz
                            if r2 > support2 or r2 < 1e-18:
                                continue
                            kb = skind[j]
                            if kb != 0 and (mode == NOBOUND or (mode == NOFIXED and kb == FIXED)):
                                cc = 1
                                continue
                            fx, fy, fz, fd = shift_pair(drx, dry, drz, r2, (mb if kb != 0 else mf) / srho[j],
                                                        prm, kernel)
                            gx += fx
                            gy += fy
                            gz += fz
                            dv += fd
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
