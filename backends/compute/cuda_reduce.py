"""numba.cuda kernels that reduce over rows: the force parts summed, dt's maxima, the
numerical check with the rows' bounding box, and the pair count.
"""
import math

import numpy as np
from numba import cuda

from sphgraph.cells import cell_window

KERNELS = ("k_reduce", "k_dt_terms", "k_check_bounds", "k_check_init", "k_count_pairs2")


def k_reduce(nparts, n, dim, kind, gx, gy, gz,
             x0, y0, z0, r0, d0, c0, x1, y1, z1, r1, d1, c1, x2, y2, z2, r2, d2, c2,
             x3, y3, z3, r3, d3, c3, ax_, ay_, az_, ar_):
    """Partial buffers summed in their fixed order (interior, halo 1, halo 2, the periodic
    images: the parts present, `nparts` of them, in that order), as
    cpu_kernels.reduce_parts: gravity on fluid, diffusion unless any part cancelled it
    (the viscous-dt maximum needs no reduction: every part's kernel takes it into one
    scalar)."""
    i = cuda.grid(1)
    if i >= n:
        return
    zero = r0[i] - r0[i]
    sx = zero + x0[i]
    sy = zero + y0[i]
    sz = zero
    s = zero + r0[i]
    dd = zero + d0[i]
    cc = c0[i]
    if dim == 3:
        sz = zero + z0[i]
    if nparts > 1:
        sx += x1[i]
        sy += y1[i]
        if dim == 3:
            sz += z1[i]
        s += r1[i]
        dd += d1[i]
        cc |= c1[i]
    if nparts > 2:
        sx += x2[i]
        sy += y2[i]
        if dim == 3:
            sz += z2[i]
        s += r2[i]
        dd += d2[i]
        cc |= c2[i]
    if nparts > 3:
        sx += x3[i]
        sy += y3[i]
        if dim == 3:
            sz += z3[i]
        s += r3[i]
        dd += d3[i]
        cc |= c3[i]
    if kind[i] == 0:      # accelerations of fluid rows only (rows 0..nf-1: see prepare)
        ax_[i] = sx + gx
        ay_[i] = sy + gy
        if dim == 3:
            az_[i] = sz + gz
    ar_[i] = s + (dd if cc == 0 else zero * dd)


def k_dt_terms(ax, ay, az, vx, vy, vz, visc, kind, n, dim, out):
    """max |a|^2 and |v|^2 over fluid rows (block maxima, then one atomic per block into
    out[0:3], zeroed by the caller), and the viscous term's maximum over all rows, which
    the force kernels left in visc[0]."""
    sh = cuda.shared.array((3, 256), dtype=np.float64)
    t = cuda.threadIdx.x
    a2m = 0.0
    v2m = 0.0
    vm = 0.0
    i = cuda.grid(1)
    stride = cuda.gridsize(1)
    if i == 0:
        vm = visc[0]
    while i < n:
        if kind[i] == 0:
            a2 = ax[i] * ax[i] + ay[i] * ay[i]
            v2 = vx[i] * vx[i] + vy[i] * vy[i]
            if dim == 3:
                a2 += az[i] * az[i]
                v2 += vz[i] * vz[i]
            if a2 > a2m:
                a2m = a2
            if v2 > v2m:
                v2m = v2
        i += stride
    sh[0, t] = a2m
    sh[1, t] = v2m
    sh[2, t] = vm
    cuda.syncthreads()
    s = 128
    while s > 0:
        if t < s:
            for q in range(3):
                if sh[q, t + s] > sh[q, t]:
                    sh[q, t] = sh[q, t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        for q in range(3):
            cuda.atomic.max(out, q, sh[q, 0])


def k_check_bounds(px, py, pz, rho, kind, n, dim, lox, loy, loz, hix, hiy, hiz,
                   rho_min, rho_max, bad, box):
    """First bad row (as cpu_kernels.check_state: cause 1 NaN, 2 outside the domain,
    3 density out of bounds) as min(row * 4 + cause) into bad[0] (set to a large value
    by the caller), and the rows' bounding box (box[0:3] min, box[3:6] max, set to
    +-inf by the caller) for the next grid."""
    sh = cuda.shared.array((6, 256), dtype=np.float64)
    t = cuda.threadIdx.x
    mn0 = math.inf
    mn1 = math.inf
    mn2 = math.inf
    mx0 = -math.inf
    mx1 = -math.inf
    mx2 = -math.inf
    i = cuda.grid(1)
    stride = cuda.gridsize(1)
    while i < n:
        x = px[i]
        y = py[i]
        z = pz[i] if dim == 3 else 0.0
        r = rho[i]
        cause = 0
        if r != r:
            cause = 1
        if x != x or y != y or z != z:
            cause = 1
        elif cause == 0:
            if x < lox or x > hix or y < loy or y > hiy:
                cause = 2
            if dim == 3 and (z < loz or z > hiz):
                cause = 2
        if cause == 0 and kind[i] == 0 and (r < rho_min or r > rho_max):
            cause = 3
        if cause:
            cuda.atomic.min(bad, 0, i * 4 + cause)
        mn0 = min(mn0, x)
        mx0 = max(mx0, x)
        mn1 = min(mn1, y)
        mx1 = max(mx1, y)
        mn2 = min(mn2, z)
        mx2 = max(mx2, z)
        i += stride
    sh[0, t] = mn0
    sh[1, t] = mn1
    sh[2, t] = mn2
    sh[3, t] = mx0
    sh[4, t] = mx1
    sh[5, t] = mx2
    cuda.syncthreads()
    s = 128
    while s > 0:
        if t < s:
            for q in range(3):
                if sh[q, t + s] < sh[q, t]:
                    sh[q, t] = sh[q, t + s]
            for q in range(3, 6):
                if sh[q, t + s] > sh[q, t]:
                    sh[q, t] = sh[q, t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        for q in range(3):
            cuda.atomic.min(box, q, sh[q, 0])
        for q in range(3, 6):
            cuda.atomic.max(box, q, sh[q, 0])


def k_check_init(bad, box):
    """k_check_bounds' accumulators: no bad row yet, an empty box."""
    if cuda.grid(1) == 0:
        bad[0] = 9223372036854775807
        for q in range(3):
            box[q] = math.inf
            box[q + 3] = -math.inf


def k_count_pairs2(dpx, dpy, dpz, pos4, n, nf, start, ncells, o0, o1, o2, inv_size, n0, n1, n2,
                   a0, a1, a2, reach, support2, counts):
    """Pairs within 2h of each destination, as DualSPHysics counts them: every
    neighbour of a fluid row, the fluid neighbours of a boundary row."""
    i = cuda.grid(1)
    if i >= n:
        return
    z = dpz[i] if a0 >= 0 and a1 >= 0 and a2 >= 0 else 0.0     # 2D: dpz is a dummy
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(dpx[i], dpy[i], z, o0, o1, o2, inv_size, n0, n1, n2,
                                                      a0, a1, a2, reach)
    m = 0
    halves = 2 if i < nf else 1
    if not empty:
        xa = pos4[4 * i]
        ya = pos4[4 * i + 1]
        za = pos4[4 * i + 2]
        for hh in range(halves):
            base = hh * ncells
            for c2 in range(lo2, hi2 + 1):
                for c1 in range(lo1, hi1 + 1):
                    row = base + (c2 * n1 + c1) * n0
                    for j in range(start[row + lo0], start[row + hi0 + 1]):
                        dx = xa - pos4[4 * j]
                        dy = ya - pos4[4 * j + 1]
                        dz = za - pos4[4 * j + 2]
                        r2 = dx * dx + dy * dy + dz * dz
                        if r2 <= support2 and r2 >= 1e-18:
                            m += 1
    counts[i] = m
