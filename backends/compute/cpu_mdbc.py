"""numba CPU kernel of mDBC (sphgraph.physics.mdbc): corrected fluid density and velocity at
each boundary particle's ghost node, extrapolated back to the particle (`NumbaCPU.mdbc`, the
body of the ``mdbc`` task that sphgraph.features places for `[physics] boundary = "mdbc"`)."""
import numpy as np
from numba import njit, prange

from sphgraph.physics import drop_stale_cache

drop_stale_cache(__file__)  # the kernel inlines sphgraph.physics: recompile when it changes

from sphgraph.cells import cell_window  # noqa: E402
from sphgraph.config import O_DIM, O_KERNEL, P_MASS_F, P_SUPPORT2  # noqa: E402
from sphgraph.physics.mdbc import ghost_add, ghost_value  # noqa: E402


@njit(parallel=True, cache=True)
def mdbc_boundary(rows, ghost, pos, vel, rho, kind, start, origin, inv_size, dims, axes, reach,
                  prm, opt, det_min, noslip, rho_out, vel_out):
    """For boundary rows `rows` with ghost nodes `ghost`: rho_out[i], vel_out[i] (mDBC; the
    per-row maths of sphgraph.physics.mdbc, ghost_add / ghost_value)."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    nf = dims[0]
    nm = dims[1]
    for t in prange(rows.shape[0]):
        i = rows[t]
        A = np.zeros((4, 4))
        b = np.zeros(4)
        A2 = np.zeros((4, 4))
        b2 = np.zeros(4)
        vs = np.zeros(3)
        sw = 0.0
        gz = ghost[t, 2] if dim == 3 else 0.0
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(ghost[t, 0], ghost[t, 1], gz, origin[0], origin[1],
                                                          origin[2], inv_size, dims[0], dims[1], dims[2],
                                                          axes[0], axes[1], axes[2], reach)
        if not empty:
            for c2 in range(lo2, hi2 + 1):
                for c1 in range(lo1, hi1 + 1):
                    row = (c2 * nm + c1) * nf
                    for j in range(start[row + lo0], start[row + hi0 + 1]):
                        if kind[j] != 0:
                            continue
                        dx0 = pos[j, 0] - ghost[t, 0]       # x_j - x_g
                        dx1 = pos[j, 1] - ghost[t, 1]
                        dx2 = (pos[j, 2] - gz) if dim == 3 else 0.0
                        r2 = dx0 * dx0 + dx1 * dx1 + dx2 * dx2
                        if r2 >= support2:
                            continue
                        sw += ghost_add(A, b, vs, dx0, dx1, dx2, r2, rho[j], vel[j, 0], vel[j, 1],
                                        vel[j, 2] if dim == 3 else 0.0, m, dim, prm, kernel)
        r, u0, u1, u2 = ghost_value(A, b, A2, b2, vs, sw, pos[i, 0] - ghost[t, 0], pos[i, 1] - ghost[t, 1],
                                    (pos[i, 2] - gz) if dim == 3 else 0.0, dim, prm, det_min, noslip)
        rho_out[t] = r
        vel_out[t, 0] = u0
        vel_out[t, 1] = u1
        if dim == 3:
            vel_out[t, 2] = u2

