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
reach). With `slip = False` the boundary particle also takes the mirrored fluid velocity
v_b = -v_g (no-slip at the interface, DualSPHysics SlipMode "no-slip"), which the
viscous terms see; DBC's default is v_b = 0 on the particle itself, i.e. no-slip dp/2
outside the wall.

Normals are implied by the geometry: ghosts come from the scene's boundary entries (tank
inner faces, wall planes, obstacle boxes; cylinders, slopes and STL meshes through
`sphgraph.shapes`, whose `ghosts` mirror across the analytic surface or the nearest
triangle), computed automatically, nearest entry first.
"""
from __future__ import annotations

import numpy as np


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
