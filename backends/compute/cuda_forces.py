"""numba.cuda force kernels: every pair within 2h of a destination row, with the pair
physics of sphgraph.physics.interact (fluid_pair, bound_pair), in the order of
backends/compute/cpu_kernels.forces.

* k_forces: destinations against any binned source set (a halo), scalar arrays.
* k_forces_fv / k_forces_bv: fluid / boundary destinations against the rank's own rows
  in the kind-split layout (cuda_sort): 16-byte record loads (two a candidate instead of
  eight), cell ranges from the relative positions in the run's type, fluid and boundary
  candidates in loops of their own, each row of cells trimmed to the sphere's chord.
  `compile_forces` builds them with the run's parameters and options as compile-time
  constants. docs/gpu.md has the measurements behind each of these choices;
  benchmarks/cuda_force_variants.py keeps the variants they were measured against.
"""
import math
import types

import numpy as np
from numba import cuda, int32, njit

from sphgraph.cells import cell_window
from sphgraph.config import P_H, P_MASS_B, P_MASS_F, P_SUPPORT2, P_WALL_NOSLIP
from sphgraph.particles import FIXED
from sphgraph.physics.eos import tait
from sphgraph.physics.interact import bound_pair, fluid_pair

from .cuda_retarget import RT, SIMULATOR, _clone, at, load4

FULL_MASK = np.uint32(0xFFFFFFFF)    # all 32 lanes of a warp (shuffles)
KERNELS = ("k_pressure", "k_forces")


def k_pressure(rho, n, prm, press):
    i = cuda.grid(1)
    if i < n:
        press[i] = tait(rho[i], prm)


def k_forces(dpx, dpy, dpz, drx_, dry_, drz_, dvx_, dvy_, dvz_, drho, dpress, dkind, n,
             srx, sry, srz, svx, svy, svz, srho, spress, skind,
             start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
             prm, dim, kernel_id, ddt_kind, laminar, final, gx, gy, gz,
             ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """Interactions of destination row i with the sources binned in a grid (as
    cpu_kernels.forces: same loop order over cells and rows, same pair physics).

    final=1: the only part of this stage, written reduced (gravity on fluid, density
    diffusion unless cancelled) into ax/ay/az/ar/visc; final=0: a partial buffer.
    """
    i = cuda.grid(1)
    i = min(i, n - 1)     # a block's spare threads repeat the last row (same values, same
    #                       stores) so that every thread reaches the block maximum below
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    z = dpz[i] if dim == 3 else 0.0     # 2D: dpz is a dummy
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(dpx[i], dpy[i], z, o0, o1, o2, inv_size, n0, n1, n2,
                                                      a0, a1, a2, reach)
    # the destination's coordinate along (fast, mid, slow), for the chords below
    q0 = dpx[i] if a0 == 0 else (dpy[i] if a0 == 1 else z)
    q1 = dpx[i] if a1 == 0 else (dpy[i] if a1 == 1 else z)
    q2 = dpx[i] if a2 == 0 else (dpy[i] if a2 == 1 else z)
    # rows of cells along the fast axis are cut to the part that the 2h sphere can reach
    # (padded: only rows/cells wholly beyond 2h are skipped, so the pairs are the CPU's)
    size = 1.0 / inv_size
    reach2 = float(prm[P_SUPPORT2]) * 1.000001 + 1e-30
    zero = drho[i] - drho[i]
    axx = zero
    ayy = zero
    azz = zero
    arr = zero
    dd = zero
    cc = 0
    vmax = zero
    xa = drx_[i]
    ya = dry_[i]
    za = drz_[i] if dim == 3 else zero
    vxa = dvx_[i]
    vya = dvy_[i]
    vza = dvz_[i] if dim == 3 else zero
    rho_a = drho[i]
    inv_rho_a = 1.0 / rho_a
    p_a = dpress[i]
    a_fluid = dkind[i] == 0
    if not empty:
        for c2 in range(lo2, hi2 + 1):
            d2 = 0.0
            if a2 >= 0:
                d2 = max(0.0, o2 + c2 * size - q2, q2 - (o2 + (c2 + 1) * size))
            for c1 in range(lo1, hi1 + 1):
                d1 = 0.0
                if a1 >= 0:
                    d1 = max(0.0, o1 + c1 * size - q1, q1 - (o1 + (c1 + 1) * size))
                rem = reach2 - d1 * d1 - d2 * d2
                if rem < 0.0:
                    continue
                rr = math.sqrt(rem)
                clo = max(lo0, int(math.floor((q0 - rr - o0) * inv_size)))
                chi = min(hi0, int(math.floor((q0 + rr - o0) * inv_size)))
                if clo > chi:
                    continue
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + clo], start[row + chi + 1]):
                    drx = xa - srx[j]
                    dry = ya - sry[j]
                    drz = (za - srz[j]) if dim == 3 else zero
                    r2 = drx * drx + dry * dry + drz * drz
                    if r2 > support2 or r2 < 1e-18:
                        continue
                    b_bound = skind[j] != 0
                    if not a_fluid and b_bound:
                        continue
                    dvx = vxa - svx[j]
                    dvy = vya - svy[j]
                    dvz = (vza - svz[j]) if dim == 3 else zero
                    if a_fluid:
                        fx, fy, fz, fr, fd, fc, fv = fluid_pair(
                            drx, dry, drz, r2, dvx, dvy, dvz, svx[j], svy[j], svz[j] if dim == 3 else zero, rho_a,
                            inv_rho_a, srho[j], p_a, spress[j], mb if b_bound else mf, b_bound, skind[j] == FIXED,
                            prm, kernel_id, ddt_kind, laminar)
                        axx += fx
                        ayy += fy
                        azz += fz
                        arr += fr
                        dd += fd
                        cc |= fc
                    else:
                        fr, fv = bound_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, srho[j],
                                            mf, prm, kernel_id)
                        arr += fr
                    if fv > vmax:
                        vmax = fv
    if final:
        if a_fluid:
            ax_[i] = axx + gx
            ay_[i] = ayy + gy
            if dim == 3:
                az_[i] = azz + gz
        else:
            ax_[i] = zero * axx
            ay_[i] = zero * ayy
            if dim == 3:
                az_[i] = zero * azz
        ar_[i] = arr + (dd if cc == 0 else zero * dd)
    else:
        ax_[i] = axx
        ay_[i] = ayy
        if dim == 3:
            az_[i] = azz
        ar_[i] = arr
        ddt_[i] = dd
        cancel_[i] = cc
    # the viscous-dt term: one maximum per block into visc_[0] (written out here, not in a
    # device function: the simulator runs cuda.* only in kernel bodies); the pair terms
    # come without the factor h (fluid_pair)
    vmax = prm[P_H] * vmax
    sh = cuda.shared.array(1, RT)
    if cuda.threadIdx.x == 0:
        sh[0] = vmax
    cuda.syncthreads()
    if vmax > sh[0]:
        cuda.atomic.max(sh, 0, vmax)
    cuda.syncthreads()
    if cuda.threadIdx.x == 0:
        cuda.atomic.max(visc_, 0, sh[0])


@njit(inline="always")
def _store_fluid(i, final, dim3, gx, gy, gz, axx, ayy, azz, arr, dd, cc, ax_, ay_, az_, ar_, ddt_, cancel_):
    """Fluid row i's sums out (k_forces_fv): with `final` (one part) the reduced
    result (gravity, diffusion unless a neighbour cancelled it), else the part's raw sums."""
    if final:
        ax_[i] = axx + gx
        ay_[i] = ayy + gy
        if dim3:
            az_[i] = azz + gz
        ar_[i] = arr + (dd if cc == 0 else 0.0 * dd)
    else:
        ax_[i] = axx
        ay_[i] = ayy
        if dim3:
            az_[i] = azz
        ar_[i] = arr
        ddt_[i] = dd
        cancel_[i] = cc


@njit(inline="always")
def _store_boundary(i, final, dim3, zero, arr, ax_, ay_, az_, ar_, ddt_, cancel_):
    """Boundary row i's sums out (k_forces_bv): the density rate; a partial
    buffer also gets no acceleration, no diffusion and no cancel. The rank's reduced
    accelerations (final) hold fluid rows only (rows 0..nf-1 after the sort): nothing there."""
    ar_[i] = arr
    if not final:
        ax_[i] = zero
        ay_[i] = zero
        if dim3:
            az_[i] = zero
        ddt_[i] = zero
        cancel_[i] = 0


@njit(inline="always")
def _fv_pair(xb, yb, zb, pb, vel4, kind, j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
             support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax):
    """k_forces_fv's test and pair body for the candidate row j (position record xb, yb, zb,
    pb): the sums (axx .. vmax) with its contribution when it is within reach. Its kind is
    read only for a boundary candidate of a scene with no-slip walls (prm is constant: the
    load folds away elsewhere).
    The row itself passes the test and adds exact zeros (every term of fluid_pair carries
    r_ab or v_ab . r_ab): no r^2 < 1e-18 cut, one compare a candidate less. Only coincident
    rows come that close (float32 relative positions resolve ~1e-7 of the domain)."""
    drx = xa - xb
    dry = ya - yb
    drz = za - zb
    r2 = drx * drx + dry * dry + drz * drz
    if not r2 > support2:
        vxb, vyb, vzb, rho_b = load4(vel4, 4 * j)
        still = b_bound and prm[P_WALL_NOSLIP] != 0.0 and at(kind, j) == FIXED
        fx, fy, fz, fr, fd, fc, fv = fluid_pair(drx, dry, drz, r2, vxa - vxb, vya - vyb, vza - vzb, vxb, vyb, vzb,
                                                rho_a, inv_rho_a, rho_b, p_a, pb, mass_b, b_bound, still, prm,
                                                kernel_id, ddt_kind, laminar)
        axx += fx
        ayy += fy
        azz += fz
        arr += fr
        dd += fd
        cc |= fc
        if fv > vmax:
            vmax = fv
    return axx, ayy, azz, arr, dd, cc, vmax


@njit(inline="always")
def _fv_part(pos4, vel4, kind, j0, j1, b_bound, mass_b, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2,
             prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax):
    """k_forces_fv's loop over the candidates j0..j1-1 of one part of a row (fluid, or
    boundary with `b_bound`), on a 32-bit row index (rows < 2^31: `start` is int32): with a
    64-bit record offset the loop and address take 10 instructions a candidate (64-bit
    adds and compares), 4 with this; numba's range() would add a trip count and a second
    counter. Two candidates a turn, both records loaded first, so that the second load's
    wait overlaps the first's (the same sums in the same order)."""
    j = int32(j0)
    je = int32(j1)
    jl = int32(je - 1)
    while j < je:
        j2 = int32(j + 1)
        xb, yb, zb, pb = load4(pos4, 4 * j)
        xc, yc, zc, pc = load4(pos4, 4 * min(j2, jl))
        axx, ayy, azz, arr, dd, cc, vmax = _fv_pair(
            xb, yb, zb, pb, vel4, kind, j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
            support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
        if j2 < je:
            axx, ayy, azz, arr, dd, cc, vmax = _fv_pair(
                xc, yc, zc, pc, vel4, kind, j2, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a,
                mass_b, support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
        j = int32(j + 2)
    return axx, ayy, azz, arr, dd, cc, vmax


@njit(inline="always")
def _warp_max_into(out, v):
    """out[0] = max(out[0], the warp's largest v): shuffles, then one atomic a warp. Every
    lane of the warp must call it (k_forces_fv / bv: spare threads repeat the last row). A
    per-block maximum through shared memory took two block barriers, at which a block's
    warps waited for its slowest (9 % of the fluid kernel's stall samples). GPU only."""
    for off in (16, 8, 4, 2, 1):
        v = max(v, cuda.shfl_down_sync(FULL_MASK, v, off))
    if cuda.laneid == 0:
        cuda.atomic.max(out, 0, v)


@njit(inline="always")
def _first_at_least(pos4, comp, lo, hi, t):
    """First j in [lo, hi) whose coordinate `comp` (pos4[4 j + comp]) is >= t, hi if none:
    a cell's rows are sorted by that coordinate (k_sort_cells_by)."""
    lo = int32(lo)
    hi = int32(hi)
    while lo < hi:        # 32-bit: rows < 2^31 (see k_forces_fv)
        mid = int32((lo + hi) >> 1)       # lo, hi >= 0: a shift, not numba's floor division
        if at(pos4, 4 * mid + comp) < t:
            lo = int32(mid + 1)
        else:
            hi = mid
    return lo


@njit(inline="always")
def _first_above(pos4, comp, lo, hi, t):
    """First j in [lo, hi) whose coordinate `comp` is > t, hi if none (sorted as above)."""
    lo = int32(lo)
    hi = int32(hi)
    while lo < hi:
        mid = int32((lo + hi) >> 1)
        if at(pos4, 4 * mid + comp) <= t:
            lo = int32(mid + 1)
        else:
            hi = mid
    return lo


@njit(inline="always")
def _trimmed(pos4, start, base, clo, chi, comp, lo_t, hi_t):
    """The rows of cells clo..chi of the row at `base` whose coordinate `comp` lies in
    [lo_t, hi_t]: the cells are consecutive along `comp` and each is sorted by it, so
    the ends are found in the first and the last cell only."""
    s0 = at(start, base + clo)
    j0 = _first_at_least(pos4, comp, s0, at(start, base + clo + 1), lo_t)
    e0 = at(start, base + chi)
    j1 = _first_above(pos4, comp, max(e0, j0), at(start, base + chi + 1), hi_t)
    return j0, j1


@njit(inline="always")
def _window(xa, ya, za, zero, o1, o2, inv_size, pad, n1, n2, a0, a1, a2):
    """k_forces_fv / k_forces_bv: the destination's coordinate along the rows of cells (q0)
    and across them (q1, q2), and the cells across the rows within `pad` (lo1..hi1,
    lo2..hi2; 0..0 for an axis the grid lacks)."""
    q0 = xa if a0 == 0 else (ya if a0 == 1 else za)
    q1 = zero
    q2 = zero
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    if a1 >= 0:
        q1 = xa if a1 == 0 else (ya if a1 == 1 else za)
        lo1 = max(int(math.floor((q1 - pad - o1) * inv_size)), 0)
        hi1 = min(int(math.floor((q1 + pad - o1) * inv_size)), n1 - 1)
    if a2 >= 0:
        q2 = xa if a2 == 0 else (ya if a2 == 1 else za)
        lo2 = max(int(math.floor((q2 - pad - o2) * inv_size)), 0)
        hi2 = min(int(math.floor((q2 + pad - o2) * inv_size)), n2 - 1)
    return q0, q1, q2, lo1, hi1, lo2, hi2


@njit(inline="always")
def _slab_gap(q, o, c, size, zero):
    """Distance from q to the slab of cell c (origin o, cells of `size`), 0 inside it; in
    the run's type (an int64 cell index times a float32 size would be float64 in numba,
    and the row set-up with it: twice the registers, spills)."""
    lo = o + RT(c) * size
    return max(zero, lo - q, q - (lo + size))


@njit(inline="always")
def _row_cut(q0, q1, q2, c1, c2, o0, o1, o2, size, inv_size, reach2, n0, a1, a2, zero):
    """The row of cells (c1, c2) against a sphere of radius^2 reach2 about (q0, q1, q2):
    the chord's half length rr along the row and the cells clo..chi it spans (clo > chi:
    out of reach)."""
    d1 = _slab_gap(q1, o1, c1, size, zero) if a1 >= 0 else zero
    d2 = _slab_gap(q2, o2, c2, size, zero) if a2 >= 0 else zero
    rem = reach2 - d1 * d1 - d2 * d2
    if rem < 0.0:
        return zero, 1, 0
    rr = math.sqrt(rem)
    clo = max(0, int(math.floor((q0 - rr - o0) * inv_size)))
    chi = min(n0 - 1, int(math.floor((q0 + rr - o0) * inv_size)))
    return rr, clo, chi


def k_forces_fv(pos4, vel4, kind, i0, i1, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                a0, a1, a2, final, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """Fluid destinations rows i0..i1-1 against the rank's own rows (kind-split layout):
    per row of cells its fluid candidates, then its boundary ones, with the pair physics
    and sums of k_forces. 16-byte record loads (two a candidate instead of eight), cell
    ranges from the relative positions in the run's type (no float64 registers), and each
    row of cells trimmed to the candidates whose
    coordinate along the row lies within the sphere's chord: o0..o2 is the grid origin
    less the rank's reference point, `pad` the support radius plus the rounding of
    positions and origin (host side), so the range holds every row within reach
    whatever the rounding, and `tpad` twice the most a row moved since the cells were
    sorted (the sort order along the row may be stale by that much). The r^2 test
    decides, as in k_forces: trimming drops only candidates it would reject.

    Built by `compile_forces`: the run's parameters (PRMC) and options (KID, DDTK, LAM)
    are compile-time constants."""
    prm = cuda.const.array_like(PRMC)
    kernel_id = KID
    ddt_kind = DDTK
    laminar = LAM
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)    # a block's spare threads repeat the last row (same values, same
    #                       stores) so that every lane reaches the warp maximum below
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    d4 = 4 * i
    xa, ya, za, p_a = load4(pos4, d4)
    vxa, vya, vza, rho_a = load4(vel4, d4)
    zero = rho_a - rho_a
    q0, q1, q2, lo1, hi1, lo2, hi2 = _window(xa, ya, za, zero, o1, o2, inv_size, pad, n1, n2, a0, a1, a2)
    size = 1.0 / inv_size
    reach2 = pad * pad
    inv_rho_a = 1.0 / rho_a
    axx = zero
    ayy = zero
    azz = zero
    arr = zero
    dd = zero
    cc = 0
    vmax = zero
    for c2 in range(lo2, hi2 + 1):
        for c1 in range(lo1, hi1 + 1):
            rr, clo, chi = _row_cut(q0, q1, q2, c1, c2, o0, o1, o2, size, inv_size, reach2, n0, a1, a2, zero)
            if clo > chi:
                continue
            row = (c2 * n1 + c1) * n0
            lo_t = q0 - rr - tpad
            hi_t = q0 + rr + tpad
            # the row's fluid candidates, then its boundary ones, each in a loop over j of
            # its own (one loop over both, with a select per candidate, is slower); both
            # ranges first: fewer values live across the loops, fewer registers
            j0, j1 = _trimmed(pos4, start, row, clo, chi, a0, lo_t, hi_t)
            b0, b1 = _trimmed(pos4, start, ncells + row, clo, chi, a0, lo_t, hi_t)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_part(
                pos4, vel4, kind, j0, j1, False, mf, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_part(
                pos4, vel4, kind, b0, b1, True, mb, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
    _store_fluid(i, final, a0 >= 0 and a1 >= 0 and a2 >= 0, gx, gy, gz, axx, ayy, azz, arr, dd, cc,
                 ax_, ay_, az_, ar_, ddt_, cancel_)
    # the viscous-dt term into visc_[0], one atomic a warp (_warp_max_into); the simulator
    # has no warp shuffles and runs cuda.* only in kernel bodies: there one atomic a row.
    # The pair terms come without the factor h (fluid_pair)
    vmax = prm[P_H] * vmax
    if SIMULATOR:
        cuda.atomic.max(visc_, 0, vmax)
    else:
        _warp_max_into(visc_, vmax)


def k_forces_bv(pos4, vel4, kind, i0, i1, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                a0, a1, a2, final, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """Boundary destinations rows i0..i1-1: fluid candidates only (DBC continuity), the
    sums of k_forces, with k_forces_fv's record loads, cell ranges and trimmed rows;
    arguments as k_forces_fv (gx..gz unused)."""
    prm = cuda.const.array_like(PRMC)
    kernel_id = KID
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)    # a block's spare threads repeat the last row (same values, same
    #                       stores) so that every lane reaches the warp maximum below
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    d4 = 4 * i
    xa, ya, za, p_a = load4(pos4, d4)
    vxa, vya, vza, rho_a = load4(vel4, d4)
    zero = rho_a - rho_a
    q0, q1, q2, lo1, hi1, lo2, hi2 = _window(xa, ya, za, zero, o1, o2, inv_size, pad, n1, n2, a0, a1, a2)
    size = 1.0 / inv_size
    reach2 = pad * pad
    arr = zero
    vmax = zero
    for c2 in range(lo2, hi2 + 1):
        for c1 in range(lo1, hi1 + 1):
            rr, clo, chi = _row_cut(q0, q1, q2, c1, c2, o0, o1, o2, size, inv_size, reach2, n0, a1, a2, zero)
            if clo > chi:
                continue
            j0, j1 = _trimmed(pos4, start, (c2 * n1 + c1) * n0, clo, chi, a0, q0 - rr - tpad, q0 + rr + tpad)
            j = int32(j0)
            je = int32(j1)
            while j < je:           # a 32-bit row index, as in k_forces_fv (_fv_part)
                j4 = 4 * j
                xb, yb, zb, pb = load4(pos4, j4)
                drx = xa - xb
                dry = ya - yb
                drz = za - zb
                r2 = drx * drx + dry * dry + drz * drz
                if not (r2 > support2 or r2 < 1e-18):
                    vxb, vyb, vzb, rho_b = load4(vel4, j4)
                    fr, fv = bound_pair(drx, dry, drz, r2, vxa - vxb, vya - vyb, vza - vzb, rho_a, rho_b, mf,
                                        prm, kernel_id)
                    arr += fr
                    if fv > vmax:
                        vmax = fv
                j = int32(j + 1)
    _store_boundary(i, final, a0 >= 0 and a1 >= 0 and a2 >= 0, zero, arr, ax_, ay_, az_, ar_, ddt_, cancel_)
    # the viscous-dt term: the warp's maximum, one atomic a warp (as k_forces_fv), times h
    vmax = prm[P_H] * vmax
    if SIMULATOR:
        cuda.atomic.max(visc_, 0, vmax)
    else:
        _warp_max_into(visc_, vmax)



def compile_forces(fluid, boundary, dtype, prm, kernel_id, ddt_kind, laminar, fastmath, max_registers,
                   relative=True, extra=None) -> types.SimpleNamespace:
    """The kernels `fluid` and `boundary` (plain functions, e.g. k_forces_fv / k_forces_bv)
    compiled for one run, as `k_forces_f` / `k_forces_b`: the parameter vector `prm` (of
    `dtype`, PRMC: constant memory, or folded into the instructions) and the options (KID,
    DDTK, LAM) are compile-time constants, so the branches of unused options (cubic kernel,
    Molteni, laminar) are not compiled and the parameters take no registers. `relative`
    says which arguments the kernels take (cuda_force_dispatch: k_forces_fv's); `extra`: more
    globals of the kernels (benchmarks' variants of their device functions)."""
    memo = {}
    consts = {"PRMC": prm, "KID": int(kernel_id), "DDTK": int(ddt_kind), "LAM": int(laminar), **(extra or {})}
    out = {"relative": relative}
    for name, f in (("k_forces_f", fluid), ("k_forces_b", boundary)):
        fn = _clone(f, dtype, memo, consts)
        if SIMULATOR:
            out[name] = cuda.jit(fn)
        elif max_registers:
            out[name] = cuda.jit(fastmath=fastmath, max_registers=max_registers)(fn)
        else:
            out[name] = cuda.jit(fastmath=fastmath)(fn)
    return types.SimpleNamespace(**out)
