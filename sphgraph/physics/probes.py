"""Per-point and per-row sums of the `[probes]` / `[forces]` samples (sphgraph.probes).

Each function sums over the fluid rows one rank owns, binned in a cell grid, so that the
samples of several ranks are the sums of their parts (the ranks own disjoint fluid rows):

* `point_sums` at a point x: the Shepard sums of DualSPHysics' MeasureTool,
  (sum V_b W_xb, sum V_b W_xb P_b, sum V_b W_xb v_b),  V_b = m_b / rho_b,
  P_b = Tait(rho_b); a point probe is their ratio, a height column's points their first
  term (where it reaches 1/2).
* `column_zrange` over a vertical column: the lowest and highest vertical coordinate of the
  fluid rows within 2h horizontally (the extent of a height column's search).
* `body_row_force` on one boundary row b: the pressure force of the fluid on it,
  sum_a m_a m_b (P_a + P_b) / (rho_a rho_b) F_ab (r_a - r_b),  grad_a W_ab = F_ab r_ab.

Plain @njit functions: the numba CPU drivers (backends/compute/cpu_probes.py) and the
numba.cuda kernels (backends/compute/cuda_probes.py, retargeted) call the same code.

Source rows are read as the force kernels read them on each backend: row j's position at
spx[ps j], spy[ps j + po1], spz[ps j + po2] (one flat (n, dim) array thrice on the CPU, one
array per axis on the GPU), its velocity at sv[vs j + d] and its density at sr[rs j + ro]
(flat (n, dim) velocities and a density array on the CPU; the GPU's (vx, vy, vz, rho)
records, vs = rs = 4, ro = 3). The grid is as `cells.cell_window` takes it (origin, cells and
particle axis along fast, mid, slow, a row of cells contiguous); the cells searched are those
within `radius` of the point along each axis (`cells_within`): 2h for a grid built for the
rows' present positions, 2h plus the most any row moved since for an older grid (the
device's, from the start of the step).
"""
import math

from numba import njit

from sphgraph.config import P_H, P_MASS_B, P_MASS_F, P_SUPPORT2

from .eos import tait
from .kernels import grad_factor, kernel_w


@njit(inline="always", cache=True)
def _span(c, radius, o, inv_size, nk):
    """Cells (lo, hi) along one grid axis that hold coordinates within `radius` of c."""
    lo = int(math.floor((c - radius - o) * inv_size))
    hi = int(math.floor((c + radius - o) * inv_size))
    return max(lo, 0), min(hi, nk - 1)


@njit(inline="always", cache=True)
def cells_within(x, y, z, radius, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, vertical, vlo, vhi):
    """Cells of the grid that hold points within `radius` of (x, y, z) along each axis, clipped
    to the grid: (lo0, hi0, lo1, hi1, lo2, hi2, empty) along (fast, mid, slow); a missing axis
    (a = -1) spans cell 0. Along the particle axis `vertical` (-1: none) the cells vlo..vhi
    instead (a column). 2 or 3 cells an axis for a radius of 2h in cells of 2h, where
    `cells.cell_window` takes 3."""
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    empty = False
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        if a < 0:
            continue
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        if a == vertical:
            lo = max(vlo, 0)
            hi = min(vhi, nk - 1)
        else:
            lo, hi = _span(x if a == 0 else (y if a == 1 else z), radius, o0 if k == 0 else (o1 if k == 1 else o2),
                           inv_size, nk)
        if lo > hi:
            empty = True
        if k == 0:
            lo0 = lo
            hi0 = hi
        elif k == 1:
            lo1 = lo
            hi1 = hi
        else:
            lo2 = lo
            hi2 = hi
    return lo0, hi0, lo1, hi1, lo2, hi2, empty


@njit(cache=True)
def column_zrange(h0, h1, vlo, vhi, spx, spy, spz, ps, po1, po2, start, o0, o1, o2, inv_size, n0, n1, n2,
                  a0, a1, a2, radius, prm, dim):
    """(lowest, highest) vertical coordinate of the rows within 2h of the column over
    (h0, h1) along every horizontal axis (|x_a - h_a| < 2h), among the cells vlo..vhi along
    the vertical; (inf, -inf) when there is none."""
    two_h = 2.0 * prm[P_H]
    zmin = math.inf
    zmax = -math.inf
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cells_within(h0, h1, 0.0, radius, o0, o1, o2, inv_size, n0, n1, n2,
                                                       a0, a1, a2, dim - 1, vlo, vhi)
    if empty:
        return zmin, zmax
    for c2 in range(lo2, hi2 + 1):
        for c1 in range(lo1, hi1 + 1):
            row = (c2 * n1 + c1) * n0
            for j in range(start[row + lo0], start[row + hi0 + 1]):
                q = ps * j
                if abs(spx[q] - h0) >= two_h:
                    continue
                if dim == 3:
                    if abs(spy[q + po1] - h1) >= two_h:
                        continue
                    z = spz[q + po2]
                else:
                    z = spy[q + po1]
                if z < zmin:
                    zmin = z
                if z > zmax:
                    zmax = z
    return zmin, zmax


@njit(cache=True)
def point_sums(x, y, z, spx, spy, spz, ps, po1, po2, sv, vs, sr, rs, ro, start, o0, o1, o2, inv_size,
               n0, n1, n2, a0, a1, a2, radius, prm, dim, kernel):
    """At the point (x, y, z): (sum V W, sum V W P, sum V W vx, sum V W vy, sum V W vz) over
    the rows within 2h, V = m / rho, W = W(|x - x_j|), P = Tait(rho) (vz = 0 in 2D)."""
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    sw = 0.0
    swp = 0.0
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cells_within(x, y, z, radius, o0, o1, o2, inv_size, n0, n1, n2,
                                                       a0, a1, a2, -1, 0, 0)
    if empty:
        return sw, swp, s0, s1, s2
    for c2 in range(lo2, hi2 + 1):
        for c1 in range(lo1, hi1 + 1):
            row = (c2 * n1 + c1) * n0
            for j in range(start[row + lo0], start[row + hi0 + 1]):
                q = ps * j
                dx = spx[q] - x
                dy = spy[q + po1] - y
                dz = (spz[q + po2] - z) if dim == 3 else 0.0
                r2 = dx * dx + dy * dy + dz * dz
                if r2 >= support2:
                    continue
                rho = sr[rs * j + ro]
                w = kernel_w(math.sqrt(r2), prm, kernel) * m / rho
                sw += w
                swp += w * tait(rho, prm)
                v = vs * j
                s0 += w * sv[v]
                s1 += w * sv[v + 1]
                if dim == 3:
                    s2 += w * sv[v + 2]
    return sw, swp, s0, s1, s2


@njit(cache=True)
def body_row_force(x, y, z, rb, spx, spy, spz, ps, po1, po2, sr, rs, ro, start, o0, o1, o2, inv_size,
                   n0, n1, n2, a0, a1, a2, radius, prm, dim, kernel):
    """The pressure force of the rows within 2h on the boundary row at (x, y, z) of density
    rb: m_f m_b sum_a (P_a + P_b)/(rho_a rho_b) F_ab (r_a - r_b), as (fx, fy, fz)."""
    support2 = prm[P_SUPPORT2]
    pb = tait(rb, prm)
    fx = 0.0
    fy = 0.0
    fz = 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cells_within(x, y, z, radius, o0, o1, o2, inv_size, n0, n1, n2,
                                                       a0, a1, a2, -1, 0, 0)
    if not empty:
        for c2 in range(lo2, hi2 + 1):
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + lo0], start[row + hi0 + 1]):
                    q = ps * j
                    dx = spx[q] - x
                    dy = spy[q + po1] - y
                    dz = (spz[q + po2] - z) if dim == 3 else 0.0
                    r2 = dx * dx + dy * dy + dz * dz
                    if r2 >= support2 or r2 <= 1e-24:
                        continue
                    ra = sr[rs * j + ro]
                    c = (tait(ra, prm) + pb) / (ra * rb) * grad_factor(r2, prm, kernel)
                    fx += c * dx
                    fy += c * dy
                    fz += c * dz
    m = prm[P_MASS_F] * prm[P_MASS_B]
    return m * fx, m * fy, m * fz
