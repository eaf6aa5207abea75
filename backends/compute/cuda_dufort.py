"""numba.cuda kernels of the DuFort-Frankel density-diffusion step (`[physics] diffusion_time =
"dufort-frankel"`, sphgraph.physics.interact): the GPU twin of cpu_kernels.forces_df and
reduce_parts (its K_a part).

* The fluid force kernels of the rank's own rows (k_forces_fv_df), of an ipc halo
  (k_halo_fv_df) and of a host-binned halo (k_forces_df) are those of cuda_forces /
  cuda_halo_kernels with one more sum a row, K_a = sum_b k_ab (`fluid_pair_df`, the pair
  maths numba-cpu's forces_df calls), written to `ddk_`: reduced (0 where a boundary
  neighbour cancels the diffusion) when the kernel writes the only part, else the part's
  raw sum. The boundary kernels are the plain ones (a boundary row has no K_a: verlet
  reads it for fluid rows only). Kernels of their own, so that the default path is
  compiled as it was.
* k_reduce_ddk / k_reduce_ranged_ddk: the parts' K_a summed in the order of k_reduce /
  k_reduce_ranged, zeroed where a part cancelled the diffusion (cpu_kernels.reduce_parts).
* the Verlet step is cuda_integrate.k_verlet's, whose density is sphgraph.physics.integrate's
  `verlet_density` (the CPU's) with its DuFort-Frankel form on: it reads K_a (`ddk_in`).

`ddk_out`, `reduce` and `ddk_in` are the backend's entry points (numba_cuda calls them; each
is a no-op or empty without `opt[O_DDT_DF]`).
"""
import math  # noqa: F401  (the cloned device functions use it)
import types

import numpy as np
from numba import cuda, int32, njit  # noqa: F401

from sphgraph.cells import cell_window  # noqa: F401
from sphgraph.config import O_DDT_DF, P_H, P_MASS_B, P_MASS_F, P_SUPPORT2
from sphgraph.physics.interact import bound_pair, fluid_pair_df  # noqa: F401

from . import cuda_forces as CF
from . import cuda_halo as CH
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from .cuda_forces import _row_cut, _store_fluid, _trimmed, _warp_max_into, _window  # noqa: F401
from .cuda_memory import dev_array
from .cuda_retarget import SIMULATOR, _clone, at, load4  # noqa: F401

RT = np.float64


def enabled(state) -> bool:
    return bool(state.opt[O_DDT_DF])


# ------------------------------------------------------------------------------ force kernels
@njit(inline="always")
def _fv_pair_df(xb, yb, zb, pb, vel4, j4, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
                support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax, kk):
    """cuda_forces._fv_pair with the pair's k_ab summed into kk (fluid_pair_df)."""
    drx = xa - xb
    dry = ya - yb
    drz = za - zb
    r2 = drx * drx + dry * dry + drz * drz
    if not r2 > support2:
        vxb, vyb, vzb, rho_b = load4(vel4, j4)
        fx, fy, fz, fr, fd, fc, fv, fk = fluid_pair_df(drx, dry, drz, r2, vxa - vxb, vya - vyb, vza - vzb, rho_a,
                                                       inv_rho_a, rho_b, p_a, pb, mass_b, b_bound, prm, kernel_id,
                                                       ddt_kind, laminar)
        axx += fx
        ayy += fy
        azz += fz
        arr += fr
        dd += fd
        cc |= fc
        kk += fk
        if fv > vmax:
            vmax = fv
    return axx, ayy, azz, arr, dd, cc, vmax, kk


@njit(inline="always")
def _fv_part_df(pos4, vel4, j0, j1, b_bound, mass_b, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2,
                prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax, kk):
    """cuda_forces._fv_part (two candidates a turn, 32-bit row index) with kk."""
    j = int32(j0)
    je = int32(j1)
    jl = int32(je - 1)
    while j < je:
        j2 = int32(j + 1)
        xb, yb, zb, pb = load4(pos4, 4 * j)
        xc, yc, zc, pc = load4(pos4, 4 * min(j2, jl))
        axx, ayy, azz, arr, dd, cc, vmax, kk = _fv_pair_df(
            xb, yb, zb, pb, vel4, 4 * j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
            support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax, kk)
        if j2 < je:
            axx, ayy, azz, arr, dd, cc, vmax, kk = _fv_pair_df(
                xc, yc, zc, pc, vel4, 4 * j2, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a,
                mass_b, support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax, kk)
        j = int32(j + 2)
    return axx, ayy, azz, arr, dd, cc, vmax, kk


@njit(inline="always")
def _fluid_rows_df(tpos4, tvel4, i, pos4, vel4, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                   a0, a1, a2, prm, kernel_id, ddt_kind, laminar):
    """The sums of fluid target row i of (tpos4, tvel4) against the sources (pos4, vel4,
    start) of a grid, as k_forces_fv / k_halo_fv take them, and K_a."""
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
    kk = zero
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
            axx, ayy, azz, arr, dd, cc, vmax, kk = _fv_part_df(
                pos4, vel4, j0, j1, False, mf, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax, kk)
            axx, ayy, azz, arr, dd, cc, vmax, kk = _fv_part_df(
                pos4, vel4, b0, b1, True, mb, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax, kk)
    return axx, ayy, azz, arr, dd, cc, prm[P_H] * vmax, kk


@njit(inline="always")
def _store_ddk(i, final, cc, kk, ddk_):
    """K_a of row i out: reduced (0 where a neighbour cancelled the diffusion) with `final`
    (the only part), else the part's raw sum (k_reduce_ddk applies the cancel)."""
    if final:
        ddk_[i] = kk if cc == 0 else 0.0 * kk
    else:
        ddk_[i] = kk


def k_forces_fv_df(pos4, vel4, i0, i1, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                   a0, a1, a2, final, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_, ddk_):
    """cuda_forces.k_forces_fv (arguments and sums alike) and K_a into ddk_."""
    prm = cuda.const.array_like(PRMC)
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)    # spare threads repeat the last row: every lane reaches the warp maximum
    axx, ayy, azz, arr, dd, cc, vmax, kk = _fluid_rows_df(
        pos4, vel4, i, pos4, vel4, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2, a0, a1, a2,
        prm, KID, DDTK, LAM)
    _store_fluid(i, final, a0 >= 0 and a1 >= 0 and a2 >= 0, gx, gy, gz, axx, ayy, azz, arr, dd, cc,
                 ax_, ay_, az_, ar_, ddt_, cancel_)
    _store_ddk(i, final, cc, kk, ddk_)
    if SIMULATOR:
        cuda.atomic.max(visc_, 0, vmax)
    else:
        _warp_max_into(visc_, vmax)


def k_halo_fv_df(tpos4, tvel4, rng, ri, pos4, vel4, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                 a0, a1, a2, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_, ddk_):
    """cuda_halo_kernels.k_halo_fv (arguments and sums alike) and K_a into ddk_ (a part)."""
    prm = cuda.const.array_like(PRMC)
    i0 = rng[ri]
    i1 = rng[ri + 1]
    if i0 >= i1:
        return
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)
    axx, ayy, azz, arr, dd, cc, vmax, kk = _fluid_rows_df(
        tpos4, tvel4, i, pos4, vel4, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2, a0, a1, a2,
        prm, KID, DDTK, LAM)
    _store_fluid(i, False, a0 >= 0 and a1 >= 0 and a2 >= 0, gx, gy, gz, axx, ayy, azz, arr, dd, cc,
                 ax_, ay_, az_, ar_, ddt_, cancel_)
    _store_ddk(i, False, cc, kk, ddk_)
    if SIMULATOR:
        cuda.atomic.max(visc_, 0, vmax)
    else:
        _warp_max_into(visc_, vmax)


def k_forces_df(dpx, dpy, dpz, drx_, dry_, drz_, dvx_, dvy_, dvz_, drho, dpress, dkind, n,
                srx, sry, srz, svx, svy, svz, srho, spress, skind,
                start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
                prm, dim, kernel_id, ddt_kind, laminar, final, gx, gy, gz,
                ax_, ay_, az_, ar_, ddt_, cancel_, visc_, ddk_):
    """cuda_forces.k_forces (a host-binned halo as the sources; arguments alike) and, for
    fluid rows, K_a into ddk_. Whole cells of the window (sphgraph.cells.cell_window), not
    k_forces' rows cut to the sphere's chord: the pairs within reach and their order are the
    same (the cut skips only cells wholly beyond 2h), so are the sums."""
    i = cuda.grid(1)
    i = min(i, n - 1)     # spare threads repeat the last row: every thread reaches the block maximum
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(dpx[i], dpy[i], dpz[i] if dim == 3 else 0.0, o0, o1, o2,
                                                      inv_size, n0, n1, n2, a0, a1, a2, reach)
    zero = drho[i] - drho[i]
    axx = zero
    ayy = zero
    azz = zero
    arr = zero
    dd = zero
    cc = 0
    kk = zero
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
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + lo0], start[row + hi0 + 1]):
                    drx = xa - srx[j]
                    dry = ya - sry[j]
                    drz = (za - srz[j]) if dim == 3 else zero
                    r2 = drx * drx + dry * dry + drz * drz
                    b_bound = skind[j] != 0
                    if r2 > support2 or r2 < 1e-18 or (b_bound and not a_fluid):
                        continue
                    dvx = vxa - svx[j]
                    dvy = vya - svy[j]
                    dvz = (vza - svz[j]) if dim == 3 else zero
                    if a_fluid:
                        fx, fy, fz, fr, fd, fc, fv, fk = fluid_pair_df(
                            drx, dry, drz, r2, dvx, dvy, dvz, rho_a, inv_rho_a, srho[j], p_a, spress[j],
                            mb if b_bound else mf, b_bound, prm, kernel_id, ddt_kind, laminar)
                        axx += fx
                        ayy += fy
                        azz += fz
                        arr += fr
                        dd += fd
                        cc |= fc
                        kk += fk
                    else:
                        fr, fv = bound_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, srho[j], mf, prm, kernel_id)
                        arr += fr
                    if fv > vmax:
                        vmax = fv
    # a boundary row's sums hold no acceleration, diffusion or K_a (exact zeros); with `final`
    # it gets no gravity either
    _store_fluid(i, final, dim == 3, gx if a_fluid else zero, gy if a_fluid else zero, gz if a_fluid else zero,
                 axx, ayy, azz, arr, dd, cc, ax_, ay_, az_, ar_, ddt_, cancel_)
    _store_ddk(i, final, cc, kk, ddk_)
    # the viscous-dt term: one maximum per block into visc_[0] (k_forces' form: the simulator
    # runs cuda.* only in kernel bodies), the pair terms without the factor h
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


# ------------------------------------------------------------------- reduction, integration
def k_reduce_ddk(nparts, n, kind, k0, c0, k1, c1, k2, c2, ddk_):
    """The parts' K_a summed in k_reduce's order, 0 where any part cancelled the diffusion
    and on boundary rows (cpu_kernels.reduce_parts)."""
    i = cuda.grid(1)
    if i >= n:
        return
    if kind[i] != 0:      # no K_a (a boundary part's ddk is never written)
        ddk_[i] = 0.0
        return
    zero = k0[i] - k0[i]
    s = zero + k0[i]
    cc = c0[i]
    if nparts > 1:
        s += k1[i]
        cc |= c1[i]
    if nparts > 2:
        s += k2[i]
        cc |= c2[i]
    ddk_[i] = s if cc == 0 else zero * s


def k_reduce_ranged_ddk(n, kind, k0, c0, rng, h1, o1, k1, c1, h2, o2, k2, c2, ddk_):
    """k_reduce_ddk with ipc halo parts, each added at its target rows only (as
    cuda_halo_kernels.k_reduce_ranged)."""
    i = cuda.grid(1)
    if i >= n:
        return
    if kind[i] != 0:
        ddk_[i] = 0.0
        return
    f1a = rng[o1]
    f1b = rng[o1 + 1]
    f2a = rng[o2]
    f2b = rng[o2 + 1]
    zero = k0[i] - k0[i]
    s = zero + k0[i]
    cc = c0[i]
    if h1 != 0 and i >= f1a and i < f1b:
        s += k1[i]
        cc |= c1[i]
    if h2 != 0 and i >= f2a and i < f2b:
        s += k2[i]
        cc |= c2[i]
    ddk_[i] = s if cc == 0 else zero * s


# ------------------------------------------------------------------------------ compilation
_PLAIN = ("k_forces_df", "k_reduce_ddk", "k_reduce_ranged_ddk")
_BUILT: dict = {}
_FORCES: dict = {}


def build(dtype) -> types.SimpleNamespace:
    """k_forces_df and the reductions for float type `dtype` (cached)."""
    dt = np.dtype(dtype)
    if dt.str not in _BUILT:
        memo = {}
        g = globals()
        _BUILT[dt.str] = types.SimpleNamespace(**{
            name: CK.kernel(g[name], dt, memo, fastmath=name == "k_forces_df" and dt == np.float32)
            for name in _PLAIN})
    return _BUILT[dt.str]


def _compile(pairs, dt, prm, kernel_id, ddt_kind, laminar):
    """The kernels (name, function) with the run's parameters and options as compile-time
    constants, fastmath and the register cap as cuda_kernels.force_kernels compiles them."""
    fm = dt == np.float32
    mr = CK.MAXREG if fm else 0
    pc = np.ascontiguousarray(prm, dt)
    key = (tuple(n for n, _ in pairs), dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar))
    if key not in _FORCES:
        memo = {}
        extra = {"PRMC": pc, "KID": int(kernel_id), "DDTK": int(ddt_kind), "LAM": int(laminar)}
        out = {"relative": True}
        for name, f in pairs:
            fn = _clone(f, dt, memo, extra)
            if SIMULATOR:
                out[name] = cuda.jit(fn)
            elif mr:
                out[name] = cuda.jit(fastmath=fm, max_registers=mr)(fn)
            else:
                out[name] = cuda.jit(fastmath=fm)(fn)
        _FORCES[key] = types.SimpleNamespace(**out)
    return _FORCES[key]


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_kernels.force_kernels' namespace for the DuFort-Frankel step: k_forces_f takes
    ddk_ after the plain arguments, k_forces_b is cuda_forces.k_forces_bv."""
    return _compile((("k_forces_f", k_forces_fv_df), ("k_forces_b", CF.k_forces_bv)), np.dtype(dtype), prm,
                    kernel_id, ddt_kind, laminar)


def halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_halo_kernels.force_kernels' namespace: k_halo_fv takes ddk_ last, k_halo_bv as it is."""
    return _compile((("k_halo_fv", k_halo_fv_df), ("k_halo_bv", HK.k_halo_bv)), np.dtype(dtype), prm,
                    kernel_id, ddt_kind, laminar)


# ------------------------------------------------------------------------ backend entries
def _ddk_array(dv, m, name="ddk"):
    a = dv.arrays.get(name)
    if a is None or a.shape[0] < m:
        a = dv.arrays[name] = dev_array(m, dv.dtype)
    return a


def ddk_out(be, state, dv, part, final) -> tuple:
    """The extra output of the fluid force kernels of `part` (empty without the DuFort-Frankel
    step): the reduced K_a when the part is `final`, else the part buffer's "ddk" (allocated
    with the buffer's rows). The Verlet kernel reads K_a of every row: a final part has the
    boundary rows' (nf..n-1) set to 0 here, once for each layout of the rows (nothing else
    writes them; k_reduce_ddk writes them 0 where there are parts)."""
    if not enabled(state):
        return ()
    m = max(dv.n, dv.cap, 1)
    if final:
        a = _ddk_array(dv, m)
        key = (id(a), dv.nf, dv.n)
        if dv.ddk_zeroed != key and dv.n > dv.nf:
            be._on(state, CK.build(dv.dtype)).k_fill[CK.blocks(dv.n - dv.nf), CK.BLOCK](a[dv.nf:dv.n], dv.n - dv.nf,
                                                                                       0.0)
            dv.ddk_zeroed = key
        return (a,)
    buf = dv.parts[part]
    a = buf.get("ddk")
    if a is None or a.shape[0] < buf["ar"].shape[0]:
        a = buf["ddk"] = dev_array(buf["ar"].shape[0], dv.dtype)
    return (a,)


def reduce(be, state, dv, ranged) -> None:
    """The parts' K_a into the reduced `ddk` (after numba_cuda's reduce_forces summed the
    rest; nothing without the DuFort-Frankel step or with one part written reduced)."""
    if not enabled(state) or not dv.parts or not dv.n:
        return
    k = be._on(state, build(dv.dtype))
    A = dv.A()
    out = _ddk_array(dv, max(dv.n, dv.cap, 1))
    P = dv.parts
    if ranged:
        inner = P["interior"]
        flat = []
        for used, r, b in CH.ranged_parts(dv):
            flat += [used, r, b["ddk"], b["cancel"]]
        k.k_reduce_ranged_ddk[CK.blocks(dv.n), CK.BLOCK](dv.n, A["kind"], inner["ddk"], inner["cancel"],
                                                        A["pick8"], *flat, out)
        return
    names = [p for p in ("interior", "halo_1", "halo_2") if p in P]
    bufs = [P[p] for p in names]
    while len(bufs) < 3:
        bufs.append(bufs[0])
    flat = [x for b in bufs for x in (b["ddk"], b["cancel"])]
    k.k_reduce_ddk[CK.blocks(dv.n), CK.BLOCK](len(names), dv.n, A["kind"], *flat, out)


def ddk_in(state, dv):
    """The reduced K_a that numba_cuda's Verlet kernel reads (`k_verlet`, df on), or None
    without the DuFort-Frankel step."""
    if not enabled(state):
        return None
    return _ddk_array(dv, max(dv.n, dv.cap, 1))
