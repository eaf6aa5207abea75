"""numba CPU kernels (prange, one particle per iteration: no atomics, no races).

The pair physics lives in `sphgraph.physics`; these loops only find neighbours
and accumulate. Every array argument is plain numpy so the kernels compile once
per dtype and are cached on disk (`cache=True`).
"""
import math

import numpy as np
from numba import njit, prange

from sphgraph.physics import drop_stale_cache

drop_stale_cache(__file__)  # before the cached kernels below are loaded

from sphgraph.cells import cell_window  # noqa: E402
from sphgraph.config import O_DDT, O_DIM, O_KERNEL, O_LAMINAR, P_H, P_MASS_B, P_MASS_F, P_SUPPORT2  # noqa: E402
from sphgraph.physics.eos import tait  # noqa: E402
from sphgraph.physics.interact import bound_pair, diffusion_coef, fluid_pair, riemann_pair  # noqa: E402
from sphgraph.physics.integrate import (bound_density, correct_axis, correct_density, predict_axis,  # noqa: E402
                                        predict_density, verlet_axis, verlet_density)
from sphgraph.physics.kernels import grad_factor  # noqa: E402
from sphgraph.physics.riemann_jump import jump_correction, jump_kept, jump_moments  # noqa: E402
from sphgraph.particles import FIXED  # noqa: E402


@njit(parallel=True, fastmath=True, cache=True)
def forces(dpos, dvel, drho, dpress, dkind,
           spos, svel, srho, spress, skind,
           start, origin, inv_size, dims, axes, reach,
           prm, opt, ace, ar, ddt, cancel, visc):
    """Interactions of destination particles with source particles binned in a grid.

    The destination set may be the source set itself (interior forces) or not
    (a halo as source). Outputs are overwritten (a partial buffer per source set).
    """
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    ddt_kind = opt[O_DDT]
    laminar = opt[O_LAMINAR] != 0
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    nf = dims[0]
    nm = dims[1]
    ns = dims[2]
    for i in prange(dpos.shape[0]):
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(
            dpos[i, 0], dpos[i, 1], dpos[i, 2] if dim == 3 else 0.0, origin[0], origin[1], origin[2], inv_size,
            nf, nm, ns, axes[0], axes[1], axes[2], reach)
        axx = 0.0 * drho[i]
        ayy = axx
        azz = axx
        arr = axx
        dd = axx
        cc = 0
        vmax = axx
        xa = dpos[i, 0]
        ya = dpos[i, 1]
        za = dpos[i, 2] if dim == 3 else 0.0
        vxa = dvel[i, 0]
        vya = dvel[i, 1]
        vza = dvel[i, 2] if dim == 3 else 0.0
        rho_a = drho[i]
        inv_rho_a = 1.0 / rho_a
        p_a = dpress[i]
        a_fluid = dkind[i] == 0
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
                        b_bound = skind[j] != 0
                        dvx = vxa - svel[j, 0]
                        dvy = vya - svel[j, 1]
                        dvz = (vza - svel[j, 2]) if dim == 3 else 0.0
                        if a_fluid:
                            fx, fy, fz, fr, fd, fc, fv = fluid_pair(
                                drx, dry, drz, r2, dvx, dvy, dvz, svel[j, 0], svel[j, 1],
                                svel[j, 2] if dim == 3 else 0.0, rho_a, inv_rho_a, srho[j], p_a, spress[j],
                                mb if b_bound else mf, b_bound, skind[j] == FIXED, prm, kernel, ddt_kind, laminar)
                            axx += fx
                            ayy += fy
                            azz += fz
                            arr += fr
                            dd += fd
                            cc |= fc
                        elif not b_bound:
                            fr, fv = bound_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, srho[j],
                                                mf, prm, kernel)
                            arr += fr
                        else:
                            continue
                        if fv > vmax:
                            vmax = fv
        ace[i, 0] = axx
        ace[i, 1] = ayy
        if dim == 3:
            ace[i, 2] = azz
        ar[i] = arr
        ddt[i] = dd
        cancel[i] = cc
        visc[i] = prm[P_H] * vmax         # the pair terms come without h (fluid_pair)


@njit(parallel=True, fastmath=True, cache=True)
def forces_riemann(dpos, dvel, drho, dpress, dkind,
           spos, svel, srho, spress, skind,
           start, origin, inv_size, dims, axes, reach,
           prm, opt, ace, ar, ddt, cancel, visc, jm):
    """`forces` with the Riemann-solver pressure term for fluid destinations
    (`[physics] riemann`, `interact.riemann_pair`): the same traversal and outputs, the U*
    pressure jump as the diffusion term (ddt; with riemann_wall = "cancel" a wall neighbour
    cancels it). With `jm` n rows wide (12 x n: `riemann_jump = "renormalised"`) the pass also
    sums the twelve moments of the renormalised jump (`riemann_jump.jump_moments`, fluid sources
    only), which `reduce_parts` turns into the row's correction; 12 x 0 skips them. A kernel of
    its own, so that `forces` (the default path) is compiled as it was."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    laminar = opt[O_LAMINAR] != 0
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    nf = dims[0]
    nm = dims[1]
    ns = dims[2]
    rj = jm.shape[1] == dpos.shape[0] and dpos.shape[0] > 0
    for i in prange(dpos.shape[0]):
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(
            dpos[i, 0], dpos[i, 1], dpos[i, 2] if dim == 3 else 0.0, origin[0], origin[1], origin[2], inv_size,
            nf, nm, ns, axes[0], axes[1], axes[2], reach)
        axx = 0.0 * drho[i]
        ayy = axx
        azz = axx
        arr = axx
        dd = axx
        cc = 0
        vmax = axx
        m00 = axx
        m01 = axx
        m02 = axx
        m11 = axx
        m12 = axx
        m22 = axx
        g0 = axx
        g1 = axx
        g2 = axx
        s0 = axx
        s1 = axx
        s2 = axx
        xa = dpos[i, 0]
        ya = dpos[i, 1]
        za = dpos[i, 2] if dim == 3 else 0.0
        vxa = dvel[i, 0]
        vya = dvel[i, 1]
        vza = dvel[i, 2] if dim == 3 else 0.0
        rho_a = drho[i]
        inv_rho_a = 1.0 / rho_a
        p_a = dpress[i]
        a_fluid = dkind[i] == 0
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
                        b_bound = skind[j] != 0
                        dvx = vxa - svel[j, 0]
                        dvy = vya - svel[j, 1]
                        dvz = (vza - svel[j, 2]) if dim == 3 else 0.0
                        if a_fluid:
                            fx, fy, fz, fr, fd, fc, fv = riemann_pair(
                                drx, dry, drz, r2, dvx, dvy, dvz, svel[j, 0], svel[j, 1],
                                svel[j, 2] if dim == 3 else 0.0, rho_a, inv_rho_a, srho[j], p_a, spress[j],
                                mb if b_bound else mf, b_bound, skind[j] == FIXED, prm, kernel, laminar)
                            axx += fx
                            ayy += fy
                            azz += fz
                            arr += fr
                            dd += fd
                            cc |= fc
                            if rj and not b_bound:
                                j00, j01, j02, j11, j12, j22, jg0, jg1, jg2, js0, js1, js2 = jump_moments(
                                    drx, dry, drz, r2, math.sqrt(r2), rho_a, srho[j], p_a, spress[j], mf, prm,
                                    kernel)
                                m00 += j00
                                m01 += j01
                                m02 += j02
                                m11 += j11
                                m12 += j12
                                m22 += j22
                                g0 += jg0
                                g1 += jg1
                                g2 += jg2
                                s0 += js0
                                s1 += js1
                                s2 += js2
                        elif not b_bound:
                            fr, fv = bound_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, srho[j],
                                                mf, prm, kernel)
                            arr += fr
                        else:
                            continue
                        if fv > vmax:
                            vmax = fv
        ace[i, 0] = axx
        ace[i, 1] = ayy
        if dim == 3:
            ace[i, 2] = azz
        ar[i] = arr
        ddt[i] = dd
        cancel[i] = cc
        visc[i] = prm[P_H] * vmax         # the pair terms come without h (fluid_pair)
        if rj:
            jm[0, i] = m00
            jm[1, i] = m01
            jm[2, i] = m02
            jm[3, i] = m11
            jm[4, i] = m12
            jm[5, i] = m22
            jm[6, i] = g0
            jm[7, i] = g1
            jm[8, i] = g2
            jm[9, i] = s0
            jm[10, i] = s1
            jm[11, i] = s2


@njit(parallel=True, cache=True)
def forces_df(dpos, dvel, drho, dpress, dkind,
           spos, svel, srho, spress, skind,
           start, origin, inv_size, dims, axes, reach,
           prm, opt, ace, ar, ddt, cancel, visc, ddk):
    """`forces`, and in the same pass `ddk` = K_a = sum_b k_ab over the fluid sources
    (`interact.diffusion_coef`) for the DuFort-Frankel diffusion step (`verlet`); boundary
    sources add nothing (where they cancel a's diffusion, `reduce_parts` zeroes K_a with its
    term). A kernel of its own, so that `forces` (the default path) is compiled as it was.
    Without fastmath: with it, the compiled code (and the run's bits) depended on which
    kernels the process had compiled before this one."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    ddt_kind = opt[O_DDT]
    laminar = opt[O_LAMINAR] != 0
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    nf = dims[0]
    nm = dims[1]
    ns = dims[2]
    for i in prange(dpos.shape[0]):
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(
            dpos[i, 0], dpos[i, 1], dpos[i, 2] if dim == 3 else 0.0, origin[0], origin[1], origin[2], inv_size,
            nf, nm, ns, axes[0], axes[1], axes[2], reach)
        axx = 0.0 * drho[i]
        ayy = axx
        azz = axx
        arr = axx
        dd = axx
        cc = 0
        kk = axx
        vmax = axx
        xa = dpos[i, 0]
        ya = dpos[i, 1]
        za = dpos[i, 2] if dim == 3 else 0.0
        vxa = dvel[i, 0]
        vya = dvel[i, 1]
        vza = dvel[i, 2] if dim == 3 else 0.0
        rho_a = drho[i]
        inv_rho_a = 1.0 / rho_a
        p_a = dpress[i]
        a_fluid = dkind[i] == 0
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
                        b_bound = skind[j] != 0
                        dvx = vxa - svel[j, 0]
                        dvy = vya - svel[j, 1]
                        dvz = (vza - svel[j, 2]) if dim == 3 else 0.0
                        if a_fluid:
                            fx, fy, fz, fr, fd, fc, fv = fluid_pair(
                                drx, dry, drz, r2, dvx, dvy, dvz, svel[j, 0], svel[j, 1],
                                svel[j, 2] if dim == 3 else 0.0, rho_a, inv_rho_a, srho[j], p_a, spress[j],
                                mb if b_bound else mf, b_bound, skind[j] == FIXED, prm, kernel, ddt_kind, laminar)
                            axx += fx
                            ayy += fy
                            azz += fz
                            arr += fr
                            dd += fd
                            cc |= fc
                            if not b_bound:
                                kk += diffusion_coef(r2, grad_factor(r2, prm, kernel), srho[j], mf, prm)
                        elif not b_bound:
                            fr, fv = bound_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, srho[j],
                                                mf, prm, kernel)
                            arr += fr
                        else:
                            continue
                        if fv > vmax:
                            vmax = fv
        ace[i, 0] = axx
        ace[i, 1] = ayy
        if dim == 3:
            ace[i, 2] = azz
        ar[i] = arr
        ddt[i] = dd
        cancel[i] = cc
        ddk[i] = kk
        visc[i] = prm[P_H] * vmax         # the pair terms come without h (fluid_pair)


@njit(parallel=True, cache=True)
def pressure_into(rho, prm, out):
    for i in prange(rho.shape[0]):
        out[i] = tait(rho[i], prm)


@njit(inline="always", cache=True)
def _psum(jms, c, i):
    """Moment c of row i summed over the parts, in their order."""
    s = 0.0 * jms[0][c, i]
    for q in range(len(jms)):
        s += jms[q][c, i]
    return s


@njit(parallel=True, cache=True)
def reduce_parts(aces, ars, ddts, cancels, viscs, kind, gravity, ace, ar, visc, ddks, dk, jms):
    """Sum partial buffers in their fixed order (interior, halo 1, halo 2).

    Fluid acceleration gets gravity; density diffusion is added unless any
    part cancelled it (DBC neighbour). Same result whatever order the parts
    were computed in. With `dk` as long as `ar` (the DuFort-Frankel step) the parts'
    diffusion coefficients K_a are summed into it the same way (0 where cancelled). With
    `jms` n rows wide (12 x n each, the renormalised jump) the parts' moments are summed and
    the row's correction (riemann_jump.jump_correction) added to its jump where it is kept
    (riemann_jump.jump_kept: a cancel drops only the jump of a row it cannot renormalise).
    """
    df = dk.shape[0] == ar.shape[0] and ar.shape[0] > 0
    rj = jms[0].shape[1] == ar.shape[0] and ar.shape[0] > 0
    nparts = len(aces)
    dim = ace.shape[1]
    for i in prange(ace.shape[0]):
        for d in range(dim):
            s = 0.0 * ace[i, d]
            for k in range(nparts):
                s += aces[k][i, d]
            ace[i, d] = s + gravity[d] if kind[i] == 0 else 0.0 * s
        s = 0.0 * ar[i]
        dd = s
        cc = 0
        v = s
        for k in range(nparts):
            s += ars[k][i]
            dd += ddts[k][i]
            cc |= cancels[k][i]
            if viscs[k][i] > v:
                v = viscs[k][i]
        keep = cc == 0
        if rj and kind[i] == 0:
            m0, m1, m2 = _psum(jms, 0, i), _psum(jms, 1, i), _psum(jms, 2, i)
            m3, m4, m5 = _psum(jms, 3, i), _psum(jms, 4, i), _psum(jms, 5, i)
            keep = jump_kept(cc, m0, m1, m2, m3, m4, m5, dim)
            if keep:
                dd += jump_correction(m0, m1, m2, m3, m4, m5, _psum(jms, 6, i), _psum(jms, 7, i),
                                      _psum(jms, 8, i), _psum(jms, 9, i), _psum(jms, 10, i), _psum(jms, 11, i), dim)
        ar[i] = s + (dd if keep else 0.0 * dd)
        visc[i] = v
        if df:
            k = 0.0 * s
            for q in range(nparts):
                k += ddks[q][i]
            dk[i] = k if cc == 0 else 0.0 * k


@njit(parallel=True, cache=True)
def dt_terms(ace, vel, visc, kind, out):
    """Per-thread partial maxima of |ace|^2 (fluid), |vel|^2 (fluid), visc: out = [a2, v2, visc]."""
    n = ace.shape[0]
    dim = ace.shape[1]
    nt = out.shape[0]
    chunk = (n + nt - 1) // nt
    for t in prange(nt):
        a2m = 0.0
        v2m = 0.0
        vm = 0.0
        for i in range(t * chunk, min(n, (t + 1) * chunk)):
            if visc[i] > vm:
                vm = visc[i]
            if kind[i] != 0:
                continue
            a2 = 0.0
            v2 = 0.0
            for d in range(dim):
                a2 += ace[i, d] * ace[i, d]
                v2 += vel[i, d] * vel[i, d]
            if a2 > a2m:
                a2m = a2
            if v2 > v2m:
                v2m = v2
        out[t, 0] = a2m
        out[t, 1] = v2m
        out[t, 2] = vm


@njit(parallel=True, cache=True)
def verlet(pos, vel, rho, vel_m1, rho_m1, kind, ace, ar, dt, euler, rho0, dk):
    """Verlet step of every row (sphgraph.physics.integrate), Euler step when `euler`;
    `dk` (K_a, as long as rho) selects the DuFort-Frankel density-diffusion form."""
    dim = pos.shape[1]
    df = dk.shape[0] == rho.shape[0] and rho.shape[0] > 0
    for i in prange(pos.shape[0]):
        rnew = verlet_density(rho[i], rho_m1[i], ar[i], dk[i] if df else 0.0, dt, euler, df)
        rho_m1[i] = rho[i]
        if kind[i] == 0:
            for d in range(dim):
                v = vel[i, d]
                pos[i, d], vel[i, d] = verlet_axis(pos[i, d], v, vel_m1[i, d], ace[i, d], dt, euler)
                vel_m1[i, d] = v
            rho[i] = rnew
        else:
            rho[i] = bound_density(rnew, rho0)


@njit(parallel=True, cache=True)
def symplectic_predict(pos, vel, rho, pos0, vel0, rho0_, kind, ace, ar, dt, rho_ref):
    """Symplectic predictor of every row (half step dt/2), the stage start kept in
    pos0, vel0, rho0_."""
    dim = pos.shape[1]
    for i in prange(pos.shape[0]):
        rho0_[i] = rho[i]
        r = predict_density(rho[i], ar[i], dt)
        if kind[i] == 0:
            for d in range(dim):
                pos0[i, d] = pos[i, d]
                vel0[i, d] = vel[i, d]
                pos[i, d], vel[i, d] = predict_axis(pos[i, d], vel[i, d], ace[i, d], dt)
            rho[i] = r
        else:
            rho[i] = bound_density(r, rho_ref)


@njit(parallel=True, cache=True)
def symplectic_correct(pos, vel, rho, pos0, vel0, rho0_, kind, ace, ar, dt, rho_ref):
    """Symplectic corrector of every row from the stage start (pos0, vel0, rho0_)."""
    dim = pos.shape[1]
    for i in prange(pos.shape[0]):
        r = correct_density(rho0_[i], rho[i], ar[i], dt)
        if kind[i] == 0:
            for d in range(dim):
                pos[i, d], vel[i, d] = correct_axis(pos0[i, d], vel0[i, d], ace[i, d], dt)
            rho[i] = r
        else:
            rho[i] = bound_density(r, rho_ref)


@njit(parallel=True, cache=True)
def check_state(pos, rho, kind, lo, hi, rho_min, rho_max, bad):
    """First bad row per thread chunk: bad[t] = (row, cause) with cause 1 NaN,
    2 outside the domain, 3 density out of bounds; -1 when none."""
    n = pos.shape[0]
    dim = pos.shape[1]
    nt = bad.shape[0]
    chunk = (n + nt - 1) // nt
    for t in prange(nt):
        bad[t, 0] = -1
        bad[t, 1] = 0
        for i in range(t * chunk, min(n, (t + 1) * chunk)):
            cause = 0
            r = rho[i]
            if r != r:
                cause = 1
            for d in range(dim):
                x = pos[i, d]
                if x != x:
                    cause = 1
                elif cause == 0 and (x < lo[d] or x > hi[d]):
                    cause = 2
            if cause == 0 and kind[i] == 0 and (r < rho_min or r > rho_max):
                cause = 3
            if cause:
                bad[t, 0] = i
                bad[t, 1] = cause
                break


@njit(parallel=True, cache=True)
def gather_rows(src, perm, dst):
    for i in prange(perm.shape[0]):
        dst[i] = src[perm[i]]


@njit(parallel=True, cache=True)
def gather_rows2(src, perm, dst):
    m = src.shape[1]
    for i in prange(perm.shape[0]):
        for d in range(m):
            dst[i, d] = src[perm[i], d]


@njit(parallel=True, cache=True)
def merge_sorted(start, akeys, perm, new_start):
    """Merge m arrivals with cell keys `akeys` into n rows already sorted by cell (cell c
    holds rows start[c]:start[c+1]).

    Fills perm [n + m] (new row i = old row perm[i] of [rows, arrivals]: arrival j is n + j)
    and new_start [ncells + 1]. The arrivals are stable-sorted by key (counting sort), and
    each goes after every row whose key is equal or smaller (searchsorted side="right",
    which for the sorted rows is start[key + 1]): a row of cell c moves down by the
    arrivals of smaller keys. This is the order a stable sort of [rows, arrivals] by key
    gives, ties to the rows, so merging equals sorting the rows and arrivals together."""
    ncells = start.shape[0] - 1
    n = start[ncells]
    m = akeys.shape[0]
    before = np.zeros(ncells + 1, np.int64)      # arrivals with a key < c
    for j in range(m):
        before[akeys[j] + 1] += 1
    for c in range(ncells):
        before[c + 1] += before[c]
    fill = before[:-1].copy()
    order = np.empty(m, np.int64)                # arrivals in stable key order
    for j in range(m):
        k = akeys[j]
        order[fill[k]] = j
        fill[k] += 1
    for c in prange(ncells + 1):
        new_start[c] = start[c] + before[c]
    for c in prange(ncells):
        sh = before[c]
        for i in range(start[c], start[c + 1]):
            perm[i + sh] = i
    for r in range(m):
        j = order[r]
        perm[start[akeys[j] + 1] + r] = n + j


@njit(parallel=True, cache=True)
def count_pairs(dpos, dkind, spos, skind, start, origin, inv_size, dims, axes, reach, support2, counts):
    """Pairs within 2h of each destination, counted as DualSPHysics counts interactions:
    from each side, every neighbour of a fluid row, only fluid neighbours of a boundary
    row (boundary-boundary pairs are never evaluated)."""
    dim = dpos.shape[1]
    nf = dims[0]
    nm = dims[1]
    for i in prange(dpos.shape[0]):
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(
            dpos[i, 0], dpos[i, 1], dpos[i, 2] if dim == 3 else 0.0, origin[0], origin[1], origin[2], inv_size,
            dims[0], dims[1], dims[2], axes[0], axes[1], axes[2], reach)
        n = 0
        for c2 in range(lo2, hi2 + 1):
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * nm + c1) * nf
                if empty:
                    continue
                for j in range(start[row + lo0], start[row + hi0 + 1]):
                    if dkind[i] != 0 and skind[j] != 0:
                        continue
                    r2 = 0.0
                    for d in range(dim):
                        t = dpos[i, d] - spos[j, d]
                        r2 += t * t
                    if r2 <= support2 and r2 >= 1e-18:
                        n += 1
        counts[i] = n
