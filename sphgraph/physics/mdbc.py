"""Modified dynamic boundary conditions (mDBC; English et al. 2019, Comput. Part. Mech. 9:1-15,
doi:10.1007/s40571-021-00403-3), DualSPHysics' "mDBC" option.

Each boundary particle b gets a ghost node g mirrored across the boundary interface (dp/2 on
the fluid side of the first boundary layer). Every force stage, before the forces, the fluid
density at g is interpolated with a first-order (linearly) corrected kernel sum and
extrapolated back to b:

    [ sum V W        sum V (x_j - x_g) W       ] [ rho_g      ]   [ sum m W      ]
    [ sum V grad W   sum V (x_j - x_g) grad W  ] [ grad rho_g ] = [ sum m grad W ]

    rho_b = max(rho0, rho_g + (x_b - x_g) . grad rho_g)

(Shepard's rho_g = sum m W / sum V W where the matrix is singular, rho0 with no fluid in
reach). With no-slip the boundary particle also takes the mirrored tangential fluid velocity
v_b = -v_g,t (no-slip at the interface, DualSPHysics SlipMode "no-slip"), which the viscous
terms see; the continuity equation keeps the wall's own velocity, zero
(`physics.interact.wall_dot`). DBC's default is v_b = 0 on the particle itself, i.e. no-slip
dp/2 outside the wall.

Normals are implied by the geometry: ghosts come from the scene's boundary entries (tank
inner faces, wall planes, obstacle boxes; cylinders, slopes and STL meshes through
`sphgraph.shapes`, whose `ghosts` mirror across the analytic surface or the nearest
triangle), computed automatically, nearest entry first.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..config import P_RHO0
from .kernels import grad_factor, kernel_w


def interface_boxes(scene):
    """[(kind, lo, hi, data)] of the interfaces of each boundary entry, dp/2 on the fluid side."""
    dp = scene.dp
    from ..shapes import SHAPE_TYPES, make
    out = []
    for e in scene.boundary:
        t = e["type"]
        if t in SHAPE_TYPES:   # closed bodies: interface on the surface; slopes: dp/2 above
            out.append(("shape", None, None, (make(e, scene.dim), dp)))
            continue
        lo, hi = np.array(e["min"], float), np.array(e["max"], float)
        if t == "tank":
            ilo, ihi = lo + 0.5 * dp, hi - 0.5 * dp
            if e.get("open_top", True):
                ihi[-1] = np.inf
            out.append(("inside", ilo, ihi, e))
        elif t == "wall":
            axis = int(np.flatnonzero(hi == lo)[0])
            sign = 1.0 if e.get("direction", "-") == "-" else -1.0   # layers grow away from the fluid
            out.append(("plane", lo, hi, (axis, lo[axis] + sign * 0.5 * dp, sign)))
        else:  # obstacle box: fluid outside
            out.append(("outside", lo - 0.5 * dp, hi + 0.5 * dp, e))
    return out


def ghost_positions(pos: np.ndarray, boxes) -> np.ndarray:
    """Ghost node of each boundary position (rows of `pos`), mirrored across the nearest interface."""
    best = np.full(len(pos), np.inf)
    ghost = pos.copy()
    for kind, lo, hi, data in boxes:
        if kind == "inside":
            c = np.clip(pos, lo, hi)
            g = 2.0 * c - pos
            d = np.sqrt(((c - pos) ** 2).sum(1))
            # distance to the entry's walls (for picking the entry): outside the interior only;
            # a particle inside it (an obstacle in the tank) is not this tank's
            d[d == 0.0] = np.inf
        elif kind == "shape":
            shape, dp = data
            g, d = shape.ghosts(pos, dp)
        elif kind == "plane":
            axis, x0, sign = data
            g = pos.copy()
            g[:, axis] = 2.0 * x0 - pos[:, axis]
            d = np.abs(pos[:, axis] - x0)
            other = [a for a in range(pos.shape[1]) if a != axis]
            out = np.zeros(len(pos))
            for a in other:
                out += np.maximum(lo[a] - pos[:, a], 0) ** 2 + np.maximum(pos[:, a] - hi[a], 0) ** 2
            d = d + np.sqrt(out)
        else:
            inside = np.all((pos >= lo) & (pos <= hi), axis=1)
            g = pos.copy()
            d = np.full(len(pos), np.inf)
            if inside.any():
                p = pos[inside]
                dlo, dhi = p - lo, hi - p
                dist = np.concatenate([dlo, dhi], axis=1)
                k = dist.argmin(1)
                gi = p.copy()
                dim = pos.shape[1]
                for row, kk in enumerate(k):
                    a = kk % dim
                    gi[row, a] = 2 * lo[a] - p[row, a] if kk < dim else 2 * hi[a] - p[row, a]
                g[inside] = gi
                d[inside] = dist.min(1)
        take = d < best
        ghost[take] = g[take]
        best[take] = d[take]
    return ghost


# ------------------------------------------------------------------ per-row maths (CPU and GPU)
# One boundary row's corrected sums and its value, written once: backends/compute/cpu_mdbc
# calls them with numpy arrays, cuda_mdbc's kernel (retargeted) with local arrays.
@njit(inline="always", cache=True)
def ghost_add(A, b, vs, dx0, dx1, dx2, r2, rho_j, vx, vy, vz, m, dim, prm, kernel):
    """Fluid neighbour j (x_j - x_g = dx, within 2h) into the ghost's corrected sums: the
    matrix A, the right-hand side b (module docstring) and the velocity sum vs. Returns
    V W, its Shepard weight."""
    w = kernel_w(math.sqrt(r2), prm, kernel)
    f = grad_factor(r2, prm, kernel) if r2 > 1e-18 else 0.0 * r2
    V = m / rho_j
    # grad_g W(x_g - x_j) = F (x_g - x_j) = -F dx
    A[0, 0] += V * w
    b[0] += m * w
    for d in range(dim):
        xd = dx0 if d == 0 else (dx1 if d == 1 else dx2)
        gd = -f * xd
        A[0, 1 + d] += V * xd * w
        A[1 + d, 0] += V * gd
        b[1 + d] += m * gd
        for e in range(dim):
            xe = dx0 if e == 0 else (dx1 if e == 1 else dx2)
            A[1 + d, 1 + e] += V * xe * gd
    vs[0] += V * vx * w
    vs[1] += V * vy * w
    if dim == 3:
        vs[2] += V * vz * w
    return V * w


@njit(inline="always", cache=True)
def solve_small(A, b, n):
    """Gaussian elimination with partial pivoting on the leading n x n block of A (b becomes
    the solution). Returns the block's determinant (the pivots' product, signed by the row
    swaps), 0 if singular."""
    det = 1.0 + 0.0 * b[0]
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if abs(A[p, c]) < 1e-300:
            return 0.0 * det
        if p != c:
            det = -det
            for k in range(n):
                t = A[c, k]
                A[c, k] = A[p, k]
                A[p, k] = t
            t = b[c]
            b[c] = b[p]
            b[p] = t
        det *= A[c, c]
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
    return det


@njit(inline="always", cache=True)
def ghost_value(A, b, A2, b2, vs, sw, bx0, bx1, bx2, dim, prm, det_min, noslip):
    """The boundary row's density and velocity from its ghost's sums (ghost_add; A2, b2:
    scratch of A's and b's shape; x_b - x_g = bx): rho_g + (x_b - x_g) . grad rho_g, Shepard's
    rho_g where the matrix is near singular (|det| < det_min, DualSPHysics' threshold, in 2D
    and 3D: without it a 3D ghost with a few fluid rows at the edge of its support took
    densities of 1e20 and the first step's dt 1e-31), rho0 with no fluid in reach; at least
    rho0. Velocity with `noslip`: minus the tangential part of the ghost's vs / sw, else 0."""
    rho0 = prm[P_RHO0]
    zero = 0.0 * sw
    if sw <= 0.0:
        return rho0 + zero, zero, zero, zero
    n = dim + 1
    for r in range(n):
        b2[r] = b[r]
        for c in range(n):
            A2[r, c] = A[r, c]
    det_ok = True
    if dim == 2:
        det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
               + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
        det_ok = abs(det) >= det_min
    r = b[0] / A[0, 0]
    det = solve_small(A2, b2, n) if det_ok else 0.0 * sw     # 0: singular (2D: tested above)
    if det != 0.0 and (dim == 2 or abs(det) >= det_min):
        r = b2[0] + bx0 * b2[1] + bx1 * b2[2]
        if dim == 3:
            r += bx2 * b2[3]
    if r < rho0:
        r = rho0 + zero
    if not noslip:
        return r, zero, zero, zero
    # No-slip mirrors the ghost's tangential velocity only (x_b - x_g lies along the wall's
    # normal), as DualSPHysics' mDBC gives its viscosity the tangential part; the fluid rows'
    # continuity sums take the wall's own velocity instead (interact.wall_dot): with the
    # mirrored velocity in them, fluid leaving the wall, or slowing along it, read as an
    # expansion, and Yeh & Petroff's wet bed was pulled into the floor (docs/validation.md).
    g0 = vs[0] / sw
    g1 = vs[1] / sw
    g2 = (vs[2] / sw) if dim == 3 else zero
    bb = bx0 * bx0 + bx1 * bx1 + bx2 * bx2
    if bb > 0.0:
        vn = (g0 * bx0 + g1 * bx1 + g2 * bx2) / bb
        g0 -= vn * bx0
        g1 -= vn * bx1
        g2 -= vn * bx2
    return r, -g0, -g1, (-g2) if dim == 3 else zero
