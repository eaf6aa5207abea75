"""numba CPU kernel of mDBC (sphgraph.physics.mdbc): corrected fluid density and velocity at
each boundary particle's ghost node, extrapolated back to the particle (`NumbaCPU.mdbc`, the
body of the ``mdbc`` task that sphgraph.features places for `[physics] boundary = "mdbc"`)."""
import math

import numpy as np
from numba import njit, prange

from sphgraph.physics import drop_stale_cache

drop_stale_cache(__file__)  # the kernel inlines sphgraph.physics: recompile when it changes

from sphgraph.config import O_DIM, O_KERNEL, P_MASS_F, P_RHO0, P_SUPPORT2  # noqa: E402
from sphgraph.physics.kernels import grad_factor, kernel_w  # noqa: E402


@njit(cache=True)
def _solve(A, b, n):
    """Gaussian elimination with partial pivoting on the leading n x n block; False if singular."""
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if abs(A[p, c]) < 1e-300:
            return False
        if p != c:
            for k in range(n):
                t = A[c, k]
                A[c, k] = A[p, k]
                A[p, k] = t
            t = b[c]
            b[c] = b[p]
            b[p] = t
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            for k in range(c, n):
                A[r, k] -= f * A[c, k]
            b[r] -= f * b[c]
    for c in range(n - 1, -1, -1):
        s = b[c]
        for k in range(c + 1, n):
            s -= A[c, k] * b[k]
        b[c] = s / A[c, c]
    return True


@njit(parallel=True, cache=True)
def mdbc_boundary(rows, ghost, pos, vel, rho, kind, start, origin, inv_size, dims, axes, reach,
                  prm, opt, det_min, noslip, rho_out, vel_out):
    """For boundary rows `rows` with ghost nodes `ghost`: rho_out[i], vel_out[i] (mDBC)."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    rho0 = prm[P_RHO0]
    nf = dims[0]
    nm = dims[1]
    n = dim + 1
    for t in prange(rows.shape[0]):
        i = rows[t]
        A = np.zeros((4, 4))
        b = np.zeros(4)
        vs = np.zeros(3)
        sw = 0.0
        lo = np.zeros(3, np.int64)
        hi = np.zeros(3, np.int64)
        empty = False
        for k in range(3):
            a = axes[k]
            if a >= 0:
                c = int(math.floor((ghost[t, a] - origin[k]) * inv_size))
                lo[k] = max(c - reach, 0)
                hi[k] = min(c + reach, dims[k] - 1)
                if lo[k] > hi[k]:
                    empty = True
        if not empty:
            for c2 in range(lo[2], hi[2] + 1):
                for c1 in range(lo[1], hi[1] + 1):
                    row = (c2 * nm + c1) * nf
                    for j in range(start[row + lo[0]], start[row + hi[0] + 1]):
                        if kind[j] != 0:
                            continue
                        dx = np.zeros(3)
                        r2 = 0.0
                        for d in range(dim):
                            dx[d] = pos[j, d] - ghost[t, d]       # x_j - x_g
                            r2 += dx[d] * dx[d]
                        if r2 >= support2:
                            continue
                        w = kernel_w(math.sqrt(r2), prm, kernel)
                        f = grad_factor(r2, prm, kernel) if r2 > 1e-18 else 0.0
                        V = m / rho[j]
                        # grad_g W(x_g - x_j) = F (x_g - x_j) = -F dx
                        A[0, 0] += V * w
                        b[0] += m * w
                        sw += V * w
                        for d in range(dim):
                            gd = -f * dx[d]
                            A[0, 1 + d] += V * dx[d] * w
                            A[1 + d, 0] += V * gd
                            b[1 + d] += m * gd
                            for e in range(dim):
                                A[1 + d, 1 + e] += V * dx[e] * gd
                            vs[d] += V * vel[j, d] * w
        if sw <= 0.0:
            rho_out[t] = rho0
            for d in range(dim):
                vel_out[t, d] = 0.0
            continue
        # determinant of the corrected matrix (DualSPHysics falls back to Shepard below a threshold)
        shepard = True
        A2 = A.copy()
        b2 = b.copy()
        det_ok = False
        if dim == 2:
            det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
                   + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
            det_ok = abs(det) >= det_min
        else:
            det_ok = True
        if det_ok and _solve(A2, b2, n):
            shepard = False
        r = b[0] / A[0, 0]
        if not shepard:
            r = b2[0]
            for d in range(dim):
                r += (pos[i, d] - ghost[t, d]) * b2[1 + d]
        rho_out[t] = r if r > rho0 else rho0
        for d in range(dim):
            vel_out[t, d] = -vs[d] / sw if noslip else 0.0
