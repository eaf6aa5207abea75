"""Kernels of the device halo path: edges as slices of the sender's sorted rows.

A rank's rows are sorted by (kind, cell) with the split axis slowest, so the rows within
reach of a cut are whole planes of cells: one contiguous range of fluid rows and one of
boundary rows. An edge message is those two ranges' records (pos4: positions relative
to the run's reference point and pressure; vel4: velocity and density; kind) with the
cells' starts of those planes (kind-split, as the rank's own `start`), copied device to
device into the sender's slot buffer (`k_halo_pack`). The receiver runs its force
kernels on it as it runs them on its own rows: no binning, no pressures to compute, the
halo is a grid of its own. The target rows of a halo are the receiver's own rows within
reach of that cut: its own edge ranges towards the sender (`k_halo_fv` / `k_halo_bv`
take targets and sources from different arrays), and the reduction adds a halo part to
those rows only (`k_reduce_ranged`).

The pair physics and the neighbour loop are the interior kernels' own device functions
(cuda_forces: `_window`, `_row_cut`, `_trimmed`, `_fv_part`, `bound_pair`): the same
sums in the same order as an interior pass over the same sources.
"""
import math  # noqa: F401  (the cloned device functions use it)
import types

import numpy as np
from numba import cuda, int32  # noqa: F401

from sphgraph.config import P_H, P_MASS_B, P_MASS_F, P_SUPPORT2
from sphgraph.physics.interact import bound_pair  # noqa: F401

from . import cuda_kernels as CK
from .cuda_forces import (_fv_part, _row_cut, _store_boundary, _store_fluid, _trimmed,  # noqa: F401
                          _warp_max_into, _window)
from .cuda_retarget import SIMULATOR, _clone, at, load4  # noqa: F401

RT = np.float64


def k_pick8(start, i0, i1, i2, i3, i4, i5, i6, i7, out):
    """Eight cell starts (the fluid and boundary ranges of both edges) for one copy."""
    if cuda.grid(1) == 0:
        out[0] = start[i0]
        out[1] = start[i1]
        out[2] = start[i2]
        out[3] = start[i3]
        out[4] = start[i4]
        out[5] = start[i5]
        out[6] = start[i6]
        out[7] = start[i7]


def k_halo_pack(start, f0, nch, ncells, pos4, vel4, kind, cap, o_start, o_pos4, o_vel4, o_kind, over):
    """The edge of planes f0 .. f0 + nch - 1 (cell indices of the fluid half; the boundary
    half at ncells + f0): its rows (fluid range, then boundary range) into o_pos4 /
    o_vel4 / o_kind, and the cells' starts rebased to them (2 nch + 1 entries, kind-split
    like `start`). The row count is on the device: a grid-stride loop over the slot's
    `cap` rows; more rows than that (the host's bound failed) are reported in over[0]."""
    a0 = start[f0]
    m0 = start[f0 + nch] - a0
    a1 = start[ncells + f0]
    m = m0 + start[ncells + f0 + nch] - a1
    i = cuda.grid(1)
    if i == 0 and m > cap:
        over[0] = m
    total = max(min(m, cap), 2 * nch + 1)
    while i < total:
        if i < m and i < cap:
            s = a0 + i if i < m0 else a1 + (i - m0)
            for c in range(4):
                o_pos4[4 * i + c] = pos4[4 * s + c]
                o_vel4[4 * i + c] = vel4[4 * s + c]
            o_kind[i] = kind[s]
        if i < nch:
            o_start[i] = start[f0 + i] - a0
        elif i <= 2 * nch:
            o_start[i] = m0 + start[ncells + f0 + (i - nch)] - a1
        i += cuda.gridsize(1)


def k_halo_fv(tpos4, tvel4, rng, ri, pos4, vel4, kind, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
              a0, a1, a2, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """k_forces_fv for fluid targets rng[ri] .. rng[ri + 1] - 1 of (tpos4, tvel4) against the sources
    (pos4, vel4, kind, start) of a halo's grid: the same loop and pair sums; partial sums out."""
    prm = cuda.const.array_like(PRMC)
    kernel_id = KID
    ddt_kind = DDTK
    laminar = LAM
    i0 = rng[ri]          # the targets' rows, from the device (edge_ranges): the launch covers a bound
    i1 = rng[ri + 1]
    if i0 >= i1:
        return
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)    # spare threads repeat the last row: every lane reaches the warp maximum
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    d4 = 4 * i
    xa, ya, za, p_a = load4(tpos4, d4)
    vxa, vya, vza, rho_a = load4(tvel4, d4)
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
            j0, j1 = _trimmed(pos4, start, row, clo, chi, a0, lo_t, hi_t)
            b0, b1 = _trimmed(pos4, start, ncells + row, clo, chi, a0, lo_t, hi_t)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_part(
                pos4, vel4, kind, j0, j1, False, mf, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_part(
                pos4, vel4, kind, b0, b1, True, mb, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
    _store_fluid(i, False, a0 >= 0 and a1 >= 0 and a2 >= 0, gx, gy, gz, axx, ayy, azz, arr, dd, cc,
                 ax_, ay_, az_, ar_, ddt_, cancel_)
    vmax = prm[P_H] * vmax
    if SIMULATOR:
        cuda.atomic.max(visc_, 0, vmax)
    else:
        _warp_max_into(visc_, vmax)


def k_halo_bv(tpos4, tvel4, rng, ri, pos4, vel4, kind, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
              a0, a1, a2, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """k_forces_bv for boundary targets rng[ri] .. rng[ri + 1] - 1 against a halo's fluid sources."""
    prm = cuda.const.array_like(PRMC)
    kernel_id = KID
    i0 = rng[ri]
    i1 = rng[ri + 1]
    if i0 >= i1:
        return
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    d4 = 4 * i
    xa, ya, za, p_a = load4(tpos4, d4)
    vxa, vya, vza, rho_a = load4(tvel4, d4)
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
            while j < je:
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
    _store_boundary(i, False, a0 >= 0 and a1 >= 0 and a2 >= 0, zero, arr, ax_, ay_, az_, ar_, ddt_, cancel_)
    vmax = prm[P_H] * vmax
    if SIMULATOR:
        cuda.atomic.max(visc_, 0, vmax)
    else:
        _warp_max_into(visc_, vmax)


def k_reduce_ranged(n, dim, kind, gx, gy, gz, x0, y0, z0, r0, d0, c0, rng,
                    h1, o1, x1, y1, z1, r1, d1, c1, h2, o2, x2, y2, z2, r2, d2, c2, ax_, ay_, az_, ar_):
    """k_reduce (interior, halo 1, halo 2 in that order) where a halo part holds sums for
    its target rows only (rows rng[o] .. rng[o+1]-1 and rng[o+2] .. rng[o+3]-1 of the
    device's edge ranges; h = 0: no such halo)."""
    i = cuda.grid(1)
    if i >= n:
        return
    f1a = rng[o1]
    f1b = rng[o1 + 1]
    b1a = rng[o1 + 2]
    b1b = rng[o1 + 3]
    f2a = rng[o2]
    f2b = rng[o2 + 1]
    b2a = rng[o2 + 2]
    b2b = rng[o2 + 3]
    zero = r0[i] - r0[i]
    sx = zero + x0[i]
    sy = zero + y0[i]
    sz = zero
    s = zero + r0[i]
    dd = zero + d0[i]
    cc = c0[i]
    if dim == 3:
        sz = zero + z0[i]
    if h1 != 0 and ((i >= f1a and i < f1b) or (i >= b1a and i < b1b)):
        sx += x1[i]
        sy += y1[i]
        if dim == 3:
            sz += z1[i]
        s += r1[i]
        dd += d1[i]
        cc |= c1[i]
    if h2 != 0 and ((i >= f2a and i < f2b) or (i >= b2a and i < b2b)):
        sx += x2[i]
        sy += y2[i]
        if dim == 3:
            sz += z2[i]
        s += r2[i]
        dd += d2[i]
        cc |= c2[i]
    if kind[i] == 0:
        ax_[i] = sx + gx
        ay_[i] = sy + gy
        if dim == 3:
            az_[i] = sz + gz
    ar_[i] = s + (dd if cc == 0 else zero * dd)


def k_axis_hist(x, n, e0, e1, inv_w, nbins, out):
    """Rows 0..n-1 (the fluid rows) per uniform bin of x over [e0, e1] (np.histogram's
    bins: the last one closed) by atomic adds."""
    i = cuda.grid(1)
    if i < n:
        v = x[i]
        if v >= e0 and v <= e1:
            b = min(int((v - e0) * inv_w), nbins - 1)
            cuda.atomic.add(out, b, 1)


def k_band_counts(x, kind, n, tlo, thi, out):
    """Rows below tlo and at or above thi, fluid and boundary: out += (fluid < tlo,
    boundary < tlo, fluid >= thi, boundary >= thi) (shared-memory sums, an atomic a block
    and counter): bounds on the next sort's edge rows."""
    sh = cuda.shared.array(4, int32)
    t = cuda.threadIdx.x
    if t < 4:
        sh[t] = 0
    cuda.syncthreads()
    i = cuda.grid(1)
    if i < n:
        v = x[i]
        b = 0 if kind[i] == 0 else 1
        if v < tlo:
            cuda.atomic.add(sh, b, 1)
        if v >= thi:
            cuda.atomic.add(sh, 2 + b, 1)
    cuda.syncthreads()
    if t < 4 and sh[t] != 0:
        cuda.atomic.add(out, t, sh[t])


_PLAIN = ("k_pick8", "k_halo_pack", "k_reduce_ranged", "k_axis_hist", "k_band_counts")
_FORCES: dict = {}


def build(dtype) -> types.SimpleNamespace:
    """The element-wise kernels of this module for float type `dtype` (cached)."""
    return CK.kernel_set(globals(), _PLAIN, dtype)


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """k_halo_fv / k_halo_bv for one run, compiled as cuda_kernels.force_kernels compiles
    the interior ones (the run's parameters as constants, fastmath and register cap)."""
    dt = np.dtype(dtype)
    fm = dt == np.float32
    mr = CK.MAXREG if fm else 0
    pc = np.ascontiguousarray(prm, dt)
    key = (dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar), mr)
    if key not in _FORCES:
        memo = {}
        extra = {"PRMC": pc, "KID": int(kernel_id), "DDTK": int(ddt_kind), "LAM": int(laminar)}
        out = {}
        for name in ("k_halo_fv", "k_halo_bv"):
            fn = _clone(globals()[name], dt, memo, extra)
            if SIMULATOR:
                out[name] = cuda.jit(fn)
            elif mr:
                out[name] = cuda.jit(fastmath=fm, max_registers=mr)(fn)
            else:
                out[name] = cuda.jit(fastmath=fm)(fn)
        _FORCES[key] = types.SimpleNamespace(**out)
    return _FORCES[key]
