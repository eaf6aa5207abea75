"""numba kernels of the row fill (:class:`sphgraph.geometry.RowFill`): the particles of a
scene drawn with index boxes only, one lattice row at a time.

A *row* is the line of lattice points that share every index but the last (the vertical
axis: y in 2D, z in 3D). Rows are numbered in row-major order over the fill's window, so
walking rows in order and each row's points by increasing last index visits the points
in key order (:class:`sphgraph.geometry.Grid`), the order of the sorted-unique key path.

Along one row every box is an interval of the last index. The endpoints of the boxes that
cross the row cut it into segments on which membership is constant; a segment is

* boundary (1): inside a BOUNDARY box and inside no HOLLOW box;
* fluid (2): inside a FLUID box, not boundary, inside no SOLID box;
* nothing (0) otherwise.

Box roles (`role`): 0 BOUNDARY, 1 HOLLOW, 2 FLUID, 3 SOLID (the names are in geometry).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _row_index(r, wlo, rshape, out):
    """Index vector (all axes but the last) of row `r` in the window starting at `wlo`."""
    for a in range(rshape.shape[0] - 1, -1, -1):
        out[a] = wlo[a] + r % rshape[a]
        r //= rshape[a]


@njit(cache=True)
def _segments(irow, lo, hi, role, cov, pts, seg_lo, seg_hi, seg_role):
    """Segments [seg_lo, seg_hi) of the row `irow` that hold boundary (1) or fluid (2)
    points, by increasing last index; returns how many. `cov`, `pts`: scratch."""
    m = lo.shape[0]
    last = lo.shape[1] - 1
    nc = 0
    for b in range(m):
        if lo[b, last] > hi[b, last]:
            continue
        inside = True
        for a in range(last):
            if irow[a] < lo[b, a] or irow[a] > hi[b, a]:
                inside = False
                break
        if inside:
            cov[nc] = b
            nc += 1
    if nc == 0:
        return 0
    k = 0
    for j in range(nc):
        b = cov[j]
        pts[k] = lo[b, last]
        pts[k + 1] = hi[b, last] + 1
        k += 2
    for i in range(1, k):          # insertion sort: a few tens of endpoints
        v = pts[i]
        j = i - 1
        while j >= 0 and pts[j] > v:
            pts[j + 1] = pts[j]
            j -= 1
        pts[j + 1] = v
    ns = 0
    for i in range(k - 1):
        s = pts[i]
        e = pts[i + 1]
        if e == s:
            continue
        bnd = False
        hol = False
        fl = False
        sol = False
        for j in range(nc):
            b = cov[j]
            if lo[b, last] <= s and s <= hi[b, last]:
                rl = role[b]
                if rl == 0:
                    bnd = True
                elif rl == 1:
                    hol = True
                elif rl == 2:
                    fl = True
                else:
                    sol = True
        what = 0
        if bnd and not hol:
            what = 1
        elif fl and not sol:
            what = 2
        if what == 0:
            continue
        if ns > 0 and seg_role[ns - 1] == what and seg_hi[ns - 1] == s:
            seg_hi[ns - 1] = e       # adjacent segments of one kind: one
        else:
            seg_lo[ns] = s
            seg_hi[ns] = e
            seg_role[ns] = what
            ns += 1
    return ns


@njit(cache=True)
def _scratch(lo):
    """Per-thread scratch of _row: (row index, covering boxes, endpoints, segment starts,
    ends, kinds)."""
    m = lo.shape[0]
    return (np.zeros(max(lo.shape[1] - 1, 1), np.int64), np.empty(m, np.int64), np.empty(2 * m, np.int64),
            np.empty(2 * m, np.int64), np.empty(2 * m, np.int64), np.empty(2 * m, np.int8))


@njit(cache=True)
def _row(r, wlo, rshape, lo, hi, role, sc):
    """_segments of row number r (its index vector left in sc[0])."""
    irow, cov, pts, slo, shi, srl = sc
    _row_index(r, wlo, rshape, irow)
    return _segments(irow, lo, hi, role, cov, pts, slo, shi, srl)


@njit(parallel=True, cache=True)
def row_counts(lo, hi, role, wlo, rshape, nb_row, nf_row, fmin, fmax, nchunks):
    """Boundary and fluid points of every row, and the lowest / highest last index of the
    row's fluid points (fmin > fmax where it has none)."""
    nrows = nb_row.shape[0]
    for c in prange(nchunks):
        sc = _scratch(lo)
        slo, shi, srl = sc[3], sc[4], sc[5]
        for r in range(c * nrows // nchunks, (c + 1) * nrows // nchunks):
            ns = _row(r, wlo, rshape, lo, hi, role, sc)
            cb = 0
            cf = 0
            mn = np.int64(2 ** 62)
            mx = -np.int64(2 ** 62)
            for s in range(ns):
                if srl[s] == 1:
                    cb += shi[s] - slo[s]
                else:
                    cf += shi[s] - slo[s]
                    mn = min(mn, slo[s])
                    mx = max(mx, shi[s] - 1)
            nb_row[r] = cb
            nf_row[r] = cf
            fmin[r] = mn
            fmax[r] = mx


@njit(parallel=True, cache=True)
def fill_rows(lo, hi, role, wlo, rshape, first, bounds, origin, dp, kinds, rho0,
              pos, ids, kind, rho, rho_m1):
    """The points of every row: boundary rows from first[0, r], fluid rows from
    first[1, r] (the rows' offsets, fluid after all the boundary), position
    ``origin + index * dp`` (float64, as Lattice.positions), id = row number, kind
    kinds[0] / kinds[1], density rho0 (rho and rho_m1, in their type). Chunk c does rows
    bounds[c]:bounds[c + 1] (chunks of about equal point counts)."""
    last = lo.shape[1] - 1
    for c in prange(bounds.shape[0] - 1):
        sc = _scratch(lo)
        irow, slo, shi, srl = sc[0], sc[3], sc[4], sc[5]
        xrow = np.zeros(max(last, 1), np.float64)
        o = np.empty(2, np.int64)
        for r in range(bounds[c], bounds[c + 1]):
            ns = _row(r, wlo, rshape, lo, hi, role, sc)
            for a in range(last):
                xrow[a] = origin[a] + np.float64(irow[a]) * dp
            o[0] = first[0, r]
            o[1] = first[1, r]
            for s in range(ns):
                g = srl[s] - 1
                i = o[g]
                for t in range(slo[s], shi[s]):
                    for a in range(last):
                        pos[i, a] = xrow[a]
                    pos[i, last] = origin[last] + np.float64(t) * dp
                    ids[i] = i
                    kind[i] = kinds[g]
                    rho[i] = rho0
                    rho_m1[i] = rho0
                    i += 1
                o[g] = i


@njit(parallel=True, cache=True)
def hydrostatic_density(pos, vertical, zs, rho0, g, B, inv_gamma, rho):
    """rho[i] = rho0 * (1 + rho0*g*max(zs - z_i, 0)/B) ** inv_gamma, in float64, rounded to
    rho's type once. A loop over libm's pow rather than numpy's `**`: numpy sends float64
    powers to SIMD code chosen by the CPU (SVML on AVX-512 machines, libm elsewhere), so the
    same scene would start with densities a few ulps apart on different machines."""
    for i in prange(rho.shape[0]):
        depth = max(zs - pos[i, vertical], 0.0)
        rho[i] = rho0 * (1.0 + rho0 * g * depth / B) ** inv_gamma
