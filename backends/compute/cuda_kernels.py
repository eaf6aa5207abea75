"""numba.cuda kernels of the GPU backend (one thread per particle or per cell).

The pair physics is not written here: `sphgraph.physics` holds it once, as plain
`@njit` functions, and `retarget` turns each of them (and each kernel below) into a
CUDA device function or kernel for one floating-point type:

* the function's Python code is compiled again by the CUDA target, with every
  `@njit` function it calls replaced by its own retargeted copy;
* every float literal of the code (``0.5``, ``2.0``, ...) becomes a literal of the
  run's type. numba types a bare literal as float64, so in a float32 run
  ``0.5 * q`` would be computed in double precision (and ``1.0 / r`` with a
  double division): the float32 copies here stay in float32.

In numba's CUDA simulator (`NUMBA_ENABLE_CUDASIM=1`, CI) the same copies run as
plain Python. Kernels must reach `cuda` as a module-level name (the simulator
swaps it in each kernel's globals).

Layout: structure of arrays. Positions are float64 (px, py, pz) for the update; the
force loop reads positions relative to a per-rank reference point (rx, ry, rz) in
the run's type, refreshed when the rows are sorted. 2D runs pass a one-element
dummy for every z array.
"""
import math
import os
import types

import numpy as np
from numba import cuda, int32, njit
from numba.core.dispatcher import Dispatcher

from sphgraph.config import (O_DDT, O_DIM, O_KERNEL, O_LAMINAR, P_H, P_MASS_B, P_MASS_F, P_SUPPORT2)  # noqa: F401
from sphgraph.physics.eos import tait
from sphgraph.physics.interact import bound_pair, fluid_pair

SIMULATOR = os.environ.get("NUMBA_ENABLE_CUDASIM", "0") == "1"
BLOCK = 256          # threads per block, element-wise kernels
FORCE_BLOCK = int(os.environ.get("SPHGRAPH_CUDA_FORCE_BLOCK", "128"))   # threads per block, force kernels
REDUCE_BLOCKS = 512  # blocks of the grid-stride reductions (dt, bounds/check)
SCAN_ITEMS = 8       # elements per thread in the block scan (block covers BLOCK * SCAN_ITEMS)
# The force kernels: "f" (k_forces_f / k_forces_b) or "fv" (k_forces_fv / k_forces_bv:
# 16-byte record loads, cell ranges in the run's type, fluid and boundary candidates in
# loops of their own, rows trimmed to the sphere's chord). Measured on the H200 (SPHERIC 2,
# 4.4 M; docs/gpu.md): fv 1.11x with whole cells, 1.25x trimmed. A variant with a per-lane
# neighbour queue in shared memory (the pair body run only when every lane had a neighbour)
# raised the warp's active lanes from 20.7 to 27 of 32 but executed 15-30 % more
# instructions: 0.6-0.8x, dropped.
RT = np.float64      # the run's float type: each kernel clone gets its own (_clone)
FULL_MASK = np.uint32(0xFFFFFFFF)    # all 32 lanes of a warp (shuffles)
UNROLL = int(os.environ.get("SPHGRAPH_CUDA_UNROLL", "2"))   # k_forces_fv: candidates a turn (_fv_part)
if UNROLL not in (1, 2):
    raise ValueError(f"SPHGRAPH_CUDA_UNROLL={UNROLL}: expected 1 or 2")
# k_forces_fv: skip candidates closer than 1e-9 (r^2 < 1e-18, DualSPHysics' ALMOSTZERO: the
# row itself) in the candidate test. Off (the default), the row itself passes the test and
# adds exact zeros (every term of fluid_pair carries r_ab or v_ab . r_ab), one compare and
# one predicate operation a candidate less: 1.0-1.4 % per forces at 4.4 M on the H200
# (2026-12-02). Rows closer than 1e-9 but apart would count; the float32 relative positions
# resolve ~1e-7 of the domain, so only coincident rows (exact zeros) come that close.
SELF_CUT = os.environ.get("SPHGRAPH_CUDA_SELF_CUT", "0") != "0"
FORCES = os.environ.get("SPHGRAPH_CUDA_FORCES", "fv")
if FORCES not in ("f", "fv"):
    raise ValueError(f"SPHGRAPH_CUDA_FORCES={FORCES!r}: expected f or fv")


# ------------------------------------------------------------------------------- retargeting
# float32 copies only: literal -> replacement. The Fourtakas hydrostatic term switches
# from its binomial series (4 terms) to pow() at |y| >= 1e-3; in float32 the series is
# exact to round-off up to |y| = 0.02 (next term C(1/7,5) y^5 = 6.7e-11 against
# y/7 = 2.9e-3: 2.3e-8 relative, below float32's 6e-8), and pow() in a branch that a
# part of each warp takes costs the whole warp.
F32_REMAP = {"fluid_pair": {1e-3: 2e-2}}


def _cast_consts(code, ft, remap=None):
    out = []
    remap = remap or {}
    for c in code.co_consts:
        if type(c) is float:
            c = ft(remap.get(c, c))
        elif isinstance(c, types.CodeType):
            c = _cast_consts(c, ft, remap)
        out.append(c)
    return code.replace(co_consts=tuple(out))


def _clone(f, dtype, memo, extra=None):
    """A copy of the Python function `f` (or of an @njit dispatcher's py_func) whose
    float literals are of `dtype` and whose @njit callees are CUDA device copies
    (`extra`: more globals, e.g. compile-time constants)."""
    f = getattr(f, "py_func", f)
    code = f.__code__
    if np.dtype(dtype) != np.float64:
        remap = F32_REMAP.get(f.__name__) if np.dtype(dtype) == np.float32 else None
        code = _cast_consts(code, np.dtype(dtype).type, remap)
    g = dict(f.__globals__)
    g["RT"] = np.dtype(dtype).type            # the run's float type (shared arrays)
    g.update(_DEVICE_ONLY)                    # intrinsics in place of their Python twins
    g.update(extra or {})
    for name in code.co_names:
        v = g.get(name)
        if isinstance(v, Dispatcher):
            g[name] = device_function(v, dtype, memo)
    return types.FunctionType(code, g, f.__name__, f.__defaults__, f.__closure__)


def device_function(f, dtype, memo=None):
    """CUDA device copy of the @njit (or plain) function `f` for float type `dtype`."""
    memo = {} if memo is None else memo
    key = (getattr(f, "py_func", f), np.dtype(dtype).str)
    if key not in memo:
        fn = _clone(f, dtype, memo)
        memo[key] = cuda.jit(device=True)(fn) if not SIMULATOR else cuda.jit(device=True)(fn)
    return memo[key]


def kernel(f, dtype, memo=None, fastmath=False):
    """CUDA kernel copy of the plain function `f` for float type `dtype`."""
    memo = {} if memo is None else memo
    fn = _clone(f, dtype, memo)
    if SIMULATOR:
        return cuda.jit(fn)
    return cuda.jit(fastmath=fastmath)(fn)


# ------------------------------------------------------------------------------- vector loads
# load4 and at are plain @njit functions (CPU, simulator, tests of the helpers); the CUDA
# copies of the kernels get the intrinsics of _DEVICE_ONLY in their place (_clone).
@njit(inline="always")
def _load4_py(a, i):
    return a[i], a[i + 1], a[i + 2], a[i + 3]


@njit(inline="always")
def _at_py(a, i):
    return a[i]


load4 = _load4_py
at = _at_py
_DEVICE_ONLY = {}

if not SIMULATOR:
    from llvmlite import ir as _ir
    from numba.core import cgutils as _cg, types as _nt
    from numba.core.extending import intrinsic as _intrinsic  # noqa: E402

    def _item_ptr(context, builder, aryty, ary_val, idx):
        """Pointer to element idx of an array argument, without the negative-index wraparound."""
        ary = context.make_array(aryty)(context, builder, ary_val)
        return _cg.get_item_pointer2(context, builder, data=ary.data,
                                     shape=_cg.unpack_tuple(builder, ary.shape),
                                     strides=_cg.unpack_tuple(builder, ary.strides),
                                     layout=aryty.layout, inds=[idx], wraparound=False)

    @_intrinsic
    def _load4_vec(typingctx, arr, idx):
        """a[i], a[i+1], a[i+2], a[i+3] in one 16-byte (float32) or two 16-byte (float64)
        loads; i a multiple of 4 in an array whose data is 16-byte aligned (device
        allocations are 256-byte aligned; the pos4/vel4 records start at 0)."""
        sig = _nt.UniTuple(arr.dtype, 4)(arr, idx)

        def codegen(context, builder, sig, args):
            aryty = sig.args[0]
            ptr = _item_ptr(context, builder, aryty, args[0], args[1])
            vty = _ir.VectorType(context.get_data_type(aryty.dtype), 4)
            vec = builder.load(builder.bitcast(ptr, vty.as_pointer()), align=16)
            vals = [builder.extract_element(vec, _ir.Constant(_ir.IntType(32), k)) for k in range(4)]
            return context.make_tuple(builder, sig.return_type, vals)
        return sig, codegen

    @_intrinsic
    def _at_nowrap(typingctx, arr, idx):
        """a[i] for an index known to be in range and >= 0: numba's a[i] also wraps a
        negative signed index around (a compare and an add on 64 bits at every load), which
        the bisections and cell ranges of the force kernels pay per step of their loops."""
        sig = arr.dtype(arr, idx)

        def codegen(context, builder, sig, args):
            return builder.load(_item_ptr(context, builder, sig.args[0], args[0], args[1]))
        return sig, codegen

    _DEVICE_ONLY.update(load4=_load4_vec, at=_at_nowrap)


# ------------------------------------------------------------------------------- kernels
# Written as plain functions; `build(dtype)` turns them into kernels. Scalars passed
# from the host are typed by the caller (floats of the run's type, int64 ints).

def k_fill(a, n, v):
    i = cuda.grid(1)
    if i < n:
        a[i] = v


def k_copy(src, n, dst):
    i = cuda.grid(1)
    if i < n:
        dst[i] = src[i]


def k_keys_hist(px, py, pz, n, dim, ox, oy, oz, inv_size, nx, ny, nz, sx, sy, sz, keys, counts):
    """Cell key of each row (clamped to the grid, as sphgraph.cells.cell_keys) and a histogram."""
    i = cuda.grid(1)
    if i >= n:
        return
    cx = int(math.floor((px[i] - ox) * inv_size))
    cx = min(max(cx, 0), nx - 1)
    cy = int(math.floor((py[i] - oy) * inv_size))
    cy = min(max(cy, 0), ny - 1)
    key = cx * sx + cy * sy
    if dim == 3:
        cz = int(math.floor((pz[i] - oz) * inv_size))
        cz = min(max(cz, 0), nz - 1)
        key += cz * sz
    keys[i] = key
    cuda.atomic.add(counts, key, 1)


def k_scan_blocks(a, n, out, sums):
    """Exclusive scan of a[0:n] within blocks of BLOCK*SCAN_ITEMS; block totals to sums."""
    sh = cuda.shared.array(256, dtype=np.int64)
    t = cuda.threadIdx.x
    base = cuda.blockIdx.x * 2048 + t * 8
    s = 0
    for k in range(8):
        j = base + k
        if j < n:
            s += a[j]
    sh[t] = s
    cuda.syncthreads()
    off = 1
    while off < 256:           # Hillis-Steele inclusive scan of the thread totals
        v = sh[t - off] if t >= off else 0
        cuda.syncthreads()
        sh[t] += v
        cuda.syncthreads()
        off *= 2
    run = sh[t] - s            # exclusive prefix of this thread
    for k in range(8):
        j = base + k
        if j < n:
            x = a[j]
            out[j] = run
            run += x
    if t == 255:
        sums[cuda.blockIdx.x] = sh[t]


def k_scan_add(out, n, offs):
    i = cuda.grid(1)
    if i < n:
        out[i] += offs[i // 2048]


def k_set_last(out, ncells, n):
    if cuda.grid(1) == 0:
        out[ncells] = n


def k_scatter(keys, n, fill, perm):
    i = cuda.grid(1)
    if i < n:
        slot = cuda.atomic.add(fill, keys[i], 1)
        perm[slot] = i


def k_sort_cells(start, ncells, perm):
    """Rows of each cell in increasing old order: the sort is then stable (as on the CPU);
    used when the cells' rows are not sorted along the rows of cells (TRIM off)."""
    c = cuda.grid(1)
    if c >= ncells:
        return
    a = start[c]
    b = start[c + 1]
    for i in range(a + 1, b):
        v = perm[i]
        j = i - 1
        while j >= a and perm[j] > v:
            perm[j + 1] = perm[j]
            j -= 1
        perm[j + 1] = v


def k_sort_cells_by(start, ncells, perm, key):
    """Rows of each cell in increasing `key` (the coordinate along the rows of cells;
    ties in increasing old order): the force kernels trim each row of cells to the
    sphere's chord by bisection (k_forces_fv)."""
    c = cuda.grid(1)
    if c >= ncells:
        return
    a = start[c]
    b = start[c + 1]
    for i in range(a + 1, b):
        v = perm[i]
        kv = key[v]
        j = i - 1
        while j >= a:
            u = perm[j]
            ku = key[u]
            if ku < kv or (ku == kv and u < v):
                break
            perm[j + 1] = u
            j -= 1
        perm[j + 1] = v


def k_gather3(a, b, c, m, perm, n, sa, sb, sc):
    """The first m (1-3) of a, b, c gathered by perm in one pass (numba_cuda._permute:
    one launch and one read of perm for up to three arrays)."""
    i = cuda.grid(1)
    if i < n:
        p = perm[i]
        sa[i] = a[p]
        if m > 1:
            sb[i] = b[p]
        if m > 2:
            sc[i] = c[p]


def k_copy3(sa, sb, sc, m, n, a, b, c):
    """The first m (1-3) of sa, sb, sc copied into a, b, c (k_gather3's way back)."""
    i = cuda.grid(1)
    if i < n:
        a[i] = sa[i]
        if m > 1:
            b[i] = sb[i]
        if m > 2:
            c[i] = sc[i]


def k_gather_pos(src, perm, n, ref, dst, rel):
    """Sorted float64 position and its copy relative to the rank's reference, run type."""
    i = cuda.grid(1)
    if i < n:
        v = src[perm[i]]
        dst[i] = v
        rel[i] = v - ref


def k_rel(src, n, ref, rel):
    i = cuda.grid(1)
    if i < n:
        rel[i] = src[i] - ref


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
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    q0 = 0.0   # destination coordinate along (fast, mid, slow), float64
    q1 = 0.0
    q2 = 0.0
    empty = False
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        o = o0 if k == 0 else (o1 if k == 1 else o2)
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        lo = 0
        hi = 0
        x = 0.0
        if a >= 0:
            x = dpx[i] if a == 0 else (dpy[i] if a == 1 else dpz[i])
            c = int(math.floor((x - o) * inv_size))
            lo = max(c - reach, 0)
            hi = min(c + reach, nk - 1)
            if lo > hi:
                empty = True
        if k == 0:
            lo0 = lo
            hi0 = hi
            q0 = x
        elif k == 1:
            lo1 = lo
            hi1 = hi
            q1 = x
        else:
            lo2 = lo
            hi2 = hi
            q2 = x
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
                            drx, dry, drz, r2, dvx, dvy, dvz, rho_a, inv_rho_a, srho[j], p_a, spress[j],
                            mb if b_bound else mf, b_bound, prm, kernel_id, ddt_kind, laminar)
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


def k_reduce(nparts, n, dim, kind, gx, gy, gz,
             x0, y0, z0, r0, d0, c0, x1, y1, z1, r1, d1, c1, x2, y2, z2, r2, d2, c2,
             ax_, ay_, az_, ar_):
    """Partial buffers summed in their fixed order (interior, halo 1, halo 2), as
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


def k_verlet(px, py, pz, vx, vy, vz, rho, vxm, vym, vzm, rhom, kind, ax, ay, az, ar,
             n, dim, dt, euler, rho0):
    """As cpu_kernels.verlet (DualSPHysics ComputeVerlet), Euler step when `euler`."""
    i = cuda.grid(1)
    if i >= n:
        return
    dt2 = 2.0 * dt
    dt205 = 0.5 * dt * dt
    if euler:
        rnew = rho[i] + dt * ar[i]
    else:
        rnew = rhom[i] + dt2 * ar[i]
    rhom[i] = rho[i]
    if kind[i] == 0:
        v = vx[i]
        px[i] += dt * v + dt205 * ax[i]
        vx[i] = (v if euler else vxm[i]) + (dt if euler else dt2) * ax[i]
        vxm[i] = v
        v = vy[i]
        py[i] += dt * v + dt205 * ay[i]
        vy[i] = (v if euler else vym[i]) + (dt if euler else dt2) * ay[i]
        vym[i] = v
        if dim == 3:
            v = vz[i]
            pz[i] += dt * v + dt205 * az[i]
            vz[i] = (v if euler else vzm[i]) + (dt if euler else dt2) * az[i]
            vzm[i] = v
        rho[i] = rnew
    else:
        rho[i] = rnew if rnew > rho0 else rho0


def k_sym_predict(px, py, pz, vx, vy, vz, rho, vx0, vy0, vz0, rho0_, kind, ax, ay, az, ar,
                  n, dim, dt, rho_ref):
    """As cpu_kernels.symplectic_predict (half step dt/2). The stage-start position is
    not kept: the corrector advances the predicted one (see k_sym_correct)."""
    i = cuda.grid(1)
    if i >= n:
        return
    h = 0.5 * dt
    rho0_[i] = rho[i]
    r = rho[i] + h * ar[i]
    if kind[i] == 0:
        vx0[i] = vx[i]
        vy0[i] = vy[i]
        px[i] += h * vx[i]
        py[i] += h * vy[i]
        vx[i] += h * ax[i]
        vy[i] += h * ay[i]
        if dim == 3:
            vz0[i] = vz[i]
            pz[i] += h * vz[i]
            vz[i] += h * az[i]
        rho[i] = r
    else:
        rho[i] = r if r > rho_ref else rho_ref


def k_sym_correct(px, py, pz, vx, vy, vz, rho, vx0, vy0, vz0, rho0_, kind, ax, ay, az, ar,
                  n, dim, dt, rho_ref):
    """As cpu_kernels.symplectic_correct: rho = rho0 (2 - e)/(2 + e), e = -ar/rho dt (Pade
    form of rho0 exp(ar/rho dt)); v = v0 + dt a, r = r0 + dt (v + v0)/2, written
    as r = r_pred + dt v / 2 (r_pred = r0 + dt v0 / 2): equal up to round-off, and no
    stage-start copy of the float64 positions (24 B per particle) is needed."""
    i = cuda.grid(1)
    if i >= n:
        return
    e = -ar[i] / rho[i] * dt
    r = rho0_[i] * (2.0 - e) / (2.0 + e)
    if kind[i] == 0:
        hd = 0.5 * dt
        v = vx0[i] + dt * ax[i]
        px[i] += hd * v
        vx[i] = v
        v = vy0[i] + dt * ay[i]
        py[i] += hd * v
        vy[i] = v
        if dim == 3:
            v = vz0[i] + dt * az[i]
            pz[i] += hd * v
            vz[i] = v
        rho[i] = r
    else:
        rho[i] = r if r > rho_ref else rho_ref


def k_count_pairs(dpx, dpy, dpz, drx_, dry_, drz_, n, srx, sry, srz,
                  start, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach, support2, dim, counts):
    """Pairs within 2h of each destination (DualSPHysics' count: from each side)."""
    i = cuda.grid(1)
    if i >= n:
        return
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        o = o0 if k == 0 else (o1 if k == 1 else o2)
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        lo = 0
        hi = 0
        if a >= 0:
            x = dpx[i] if a == 0 else (dpy[i] if a == 1 else dpz[i])
            c = int(math.floor((x - o) * inv_size))
            lo = max(c - reach, 0)
            hi = min(c + reach, nk - 1)
        if k == 0:
            lo0 = lo
            hi0 = hi
        elif k == 1:
            lo1 = lo
            hi1 = hi
        else:
            lo2 = lo
            hi2 = hi
    m = 0
    if lo0 <= hi0 and lo1 <= hi1 and lo2 <= hi2:
        xa = drx_[i]
        ya = dry_[i]
        za = drz_[i] if dim == 3 else xa - xa
        for c2 in range(lo2, hi2 + 1):
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + lo0], start[row + hi0 + 1]):
                    dx = xa - srx[j]
                    dy = ya - sry[j]
                    dz = (za - srz[j]) if dim == 3 else dx - dx
                    r2 = dx * dx + dy * dy + dz * dz
                    if r2 <= support2 and r2 >= 1e-18:
                        m += 1
    counts[i] = m

# ----------------------------------------------------------------- kind-split layout
# Rows are sorted by (kind != 0, cell): fluid rows first, each kind's rows grouped by
# cell, `start` holding 2 * ncells + 1 offsets (fluid cells, then boundary cells), as
# DualSPHysics keeps bound and fluid apart. A boundary destination then visits only
# fluid candidates (it interacts with nothing else), and fluid and boundary
# destinations run as two launches (no fluid_pair/bound_pair divergence in a warp).
# Sources are packed records of the run's type: pos4 = (x - ref, y - ref, z - ref, p)
# and vel4 = (vx, vy, vz, rho), so a candidate costs two 16-byte records (one cache
# sector each) instead of eight arrays. vel4 is the velocity/density storage itself;
# pos4 is rebuilt by k_pack after each sort and predictor, and is the sort's scratch.

def k_keys_hist2(px, py, pz, kind, n, dim, ox, oy, oz, inv_size, nx, ny, nz, sx, sy, sz, ncells, keys, counts):
    """As k_keys_hist, boundary rows keyed after all fluid cells (key + ncells)."""
    i = cuda.grid(1)
    if i >= n:
        return
    cx = int(math.floor((px[i] - ox) * inv_size))
    cx = min(max(cx, 0), nx - 1)
    cy = int(math.floor((py[i] - oy) * inv_size))
    cy = min(max(cy, 0), ny - 1)
    key = cx * sx + cy * sy
    if dim == 3:
        cz = int(math.floor((pz[i] - oz) * inv_size))
        cz = min(max(cz, 0), nz - 1)
        key += cz * sz
    if kind[i] != 0:
        key += ncells
    keys[i] = key
    cuda.atomic.add(counts, key, 1)


# ----------------------------------------------------------------- rows between ranks
# Rows leaving a slab are found and removed on the device (only they cross the bus):
# k_mig_keep flags the rows that stay and counts the leaving ones; an exclusive scan of
# the flags gives each kept row its new place (k_compact_perm, then the usual gather)
# and each leaving row its place in the message (k_pack_leaving: increasing row order;
# the host tells the sides apart by position).

def k_mig_keep(pa, n, lo, hi, keep, count):
    """keep[i] = 1 for rows in [lo, hi) along the split axis, else 0 (counted)."""
    i = cuda.grid(1)
    if i >= n:
        return
    x = pa[i]
    if x < lo or x >= hi:
        keep[i] = 0
        cuda.atomic.add(count, 0, 1)
    else:
        keep[i] = 1


def k_compact_perm(keep, pos, n, perm):
    i = cuda.grid(1)
    if i < n and keep[i] != 0:
        perm[pos[i]] = i


# Packed transfers: every field a message needs is gathered into (or scattered from) one
# device buffer by one launch and crosses the bus in one copy. Row records of the run's
# type, `w = dim + 5` values per row: (vm_x, vm_y[, vm_z], vx, vy, vz, rho, rho_m1),
# i.e. the history, the vel4 record, the density history; positions are float64 records
# of `dim` values.

def k_pack_leaving(keep, pos, n, dim, px, py, pz, vmx, vmy, vmz, vel4, rhom, kind, ids,
                   o64, of, okind, oid):
    """Rows with keep == 0 into slot i - pos[i] (pos: exclusive scan of keep), so the
    leaving rows come out in increasing row order."""
    i = cuda.grid(1)
    if i >= n or keep[i] != 0:
        return
    j = i - pos[i]
    b = j * dim
    o64[b] = px[i]
    o64[b + 1] = py[i]
    w = dim + 5
    f = j * w
    of[f] = vmx[i]
    of[f + 1] = vmy[i]
    if dim == 3:
        o64[b + 2] = pz[i]
        of[f + 2] = vmz[i]
    s = 4 * i
    of[f + dim] = vel4[s]
    of[f + dim + 1] = vel4[s + 1]
    of[f + dim + 2] = vel4[s + 2]
    of[f + dim + 3] = vel4[s + 3]
    of[f + dim + 4] = rhom[i]
    okind[j] = kind[i]
    oid[j] = ids[i]


def k_unpack_rows(n0, m, dim, i64, if_, ikind, iid, px, py, pz, vmx, vmy, vmz, vel4, rhom, kind, ids):
    """Records packed as k_pack_leaving packs them, written to rows n0 .. n0+m-1."""
    j = cuda.grid(1)
    if j >= m:
        return
    i = n0 + j
    b = j * dim
    px[i] = i64[b]
    py[i] = i64[b + 1]
    w = dim + 5
    f = j * w
    vmx[i] = if_[f]
    vmy[i] = if_[f + 1]
    if dim == 3:
        pz[i] = i64[b + 2]
        vmz[i] = if_[f + 2]
    s = 4 * i
    vel4[s] = if_[f + dim]
    vel4[s + 1] = if_[f + dim + 1]
    vel4[s + 2] = if_[f + dim + 2]
    vel4[s + 3] = if_[f + dim + 3]
    rhom[i] = if_[f + dim + 4]
    kind[i] = ikind[j]
    ids[i] = iid[j]


def k_pack_edge(px, py, pz, vel4, kind, a0, m0, a1, m, dim, o64, o4, okind):
    """Rows a0 .. a0+m0-1 then a1 .. a1+(m-m0)-1 (the fluid and boundary candidate
    ranges of an edge): float64 position records, vel4 records, kinds."""
    j = cuda.grid(1)
    if j >= m:
        return
    i = a0 + j if j < m0 else a1 + (j - m0)
    b = j * dim
    o64[b] = px[i]
    o64[b + 1] = py[i]
    if dim == 3:
        o64[b + 2] = pz[i]
    s = 4 * i
    d = 4 * j
    o4[d] = vel4[s]
    o4[d + 1] = vel4[s + 1]
    o4[d + 2] = vel4[s + 2]
    o4[d + 3] = vel4[s + 3]
    okind[j] = kind[i]


def k_pick4(src, i0, i1, i2, i3, out):
    """Four entries of src (e.g. cell starts) for one copy to the host."""
    if cuda.grid(1) == 0:
        out[0] = src[i0]
        out[1] = src[i1]
        out[2] = src[i2]
        out[3] = src[i3]


# --- halos binned on the device (--halo-transport ipc: edge rows arrive device to device)

def k_stamp(a, v):
    """a[0] = v: the generation number in an edge slot's header (cuda_halo)."""
    if cuda.grid(1) == 0:
        a[0] = v


def k_edge_init(head, meta):
    """k_edge_bounds' accumulators in meta (rows kept, fluid rows kept, box min3, box max3)
    and, in meta[8], the generation number the received slot's header holds."""
    if cuda.grid(1) == 0:
        meta[0] = 0.0
        meta[1] = 0.0
        for q in range(3):
            meta[2 + q] = math.inf
            meta[5 + q] = -math.inf
        meta[8] = head[0]


def k_edge_bounds(pos, kind, m, dim, axis, thr, below, meta):
    """The rows of a received edge (pos: m records of dim float64, as k_pack_edge) that pass
    its cut (coordinate `axis` < thr when `below`, else >= thr: numba_cuda.edge's cut):
    how many, how many fluid, and their bounding box (0 along a missing z), into meta
    (set by k_edge_init; one atomic per block and quantity)."""
    sh = cuda.shared.array((8, 256), dtype=np.float64)
    t = cuda.threadIdx.x
    cnt = 0.0
    fl = 0.0
    mn0 = math.inf
    mn1 = math.inf
    mn2 = math.inf
    mx0 = -math.inf
    mx1 = -math.inf
    mx2 = -math.inf
    i = cuda.grid(1)
    stride = cuda.gridsize(1)
    while i < m:
        b = i * dim
        x = pos[b + axis]
        if (x < thr) if below else (x >= thr):
            cnt += 1.0
            if kind[i] == 0:
                fl += 1.0
            p0 = pos[b]
            p1 = pos[b + 1]
            p2 = pos[b + 2] if dim == 3 else 0.0
            mn0 = min(mn0, p0)
            mx0 = max(mx0, p0)
            mn1 = min(mn1, p1)
            mx1 = max(mx1, p1)
            mn2 = min(mn2, p2)
            mx2 = max(mx2, p2)
        i += stride
    sh[0, t] = cnt
    sh[1, t] = fl
    sh[2, t] = mn0
    sh[3, t] = mn1
    sh[4, t] = mn2
    sh[5, t] = mx0
    sh[6, t] = mx1
    sh[7, t] = mx2
    cuda.syncthreads()
    s = 128
    while s > 0:
        if t < s:
            for q in range(2):
                sh[q, t] += sh[q, t + s]
            for q in range(2, 5):
                if sh[q, t + s] < sh[q, t]:
                    sh[q, t] = sh[q, t + s]
            for q in range(5, 8):
                if sh[q, t + s] > sh[q, t]:
                    sh[q, t] = sh[q, t + s]
        cuda.syncthreads()
        s //= 2
    if t == 0:
        for q in range(2):
            cuda.atomic.add(meta, q, sh[q, 0])
        for q in range(2, 5):
            cuda.atomic.min(meta, q, sh[q, 0])
        for q in range(5, 8):
            cuda.atomic.max(meta, q, sh[q, 0])


def k_edge_keys(pos, m, dim, axis, thr, below, ox, oy, oz, inv_size, nx, ny, nz, sx, sy, sz, ncells,
                keys, counts):
    """Cell key of each received edge row (as k_keys_hist and sphgraph.cells.cell_keys) and
    a histogram; a row outside the edge's cut gets key ncells, binned after every cell."""
    i = cuda.grid(1)
    if i >= m:
        return
    b = i * dim
    x = pos[b + axis]
    key = ncells
    if (x < thr) if below else (x >= thr):
        cx = int(math.floor((pos[b] - ox) * inv_size))
        cx = min(max(cx, 0), nx - 1)
        cy = int(math.floor((pos[b + 1] - oy) * inv_size))
        cy = min(max(cy, 0), ny - 1)
        key = cx * sx + cy * sy
        if dim == 3:
            cz = int(math.floor((pos[b + 2] - oz) * inv_size))
            cz = min(max(cz, 0), nz - 1)
            key += cz * sz
    keys[i] = key
    cuda.atomic.add(counts, key, 1)


def k_edge_gather(pos, v4, kind, perm, n, dim, ref0, ref1, ref2, prm, rx, ry, rz, vx, vy, vz, rho, press,
                  okind):
    """The halo's arrays in cell order from the received edge records: positions relative
    to the rank's reference point (float64 difference, then the run's type, as the host
    path), velocity, density, its pressure, kind."""
    i = cuda.grid(1)
    if i >= n:
        return
    j = perm[i]
    b = j * dim
    rx[i] = pos[b] - ref0
    ry[i] = pos[b + 1] - ref1
    s = 4 * j
    vx[i] = v4[s]
    vy[i] = v4[s + 1]
    if dim == 3:
        rz[i] = pos[b + 2] - ref2
        vz[i] = v4[s + 2]
    r = v4[s + 3]
    rho[i] = r
    press[i] = tait(r, prm)
    okind[i] = kind[j]


def k_gather4(src, perm, n, dst):
    """Records of 4 (flat arrays of 4 n)."""
    i = cuda.grid(1)
    if i < n:
        s = 4 * perm[i]
        d = 4 * i
        dst[d] = src[s]
        dst[d + 1] = src[s + 1]
        dst[d + 2] = src[s + 2]
        dst[d + 3] = src[s + 3]


def k_pack(px, py, pz, vel4, n, dim, ref0, ref1, ref2, prm, with_press, pos4):
    """pos4 = (x - ref, y - ref, z - ref [0 in 2D], tait(rho)) in the run's type."""
    i = cuda.grid(1)
    if i >= n:
        return
    d = 4 * i
    pos4[d] = px[i] - ref0
    pos4[d + 1] = py[i] - ref1
    if dim == 3:
        pos4[d + 2] = pz[i] - ref2
    else:
        pos4[d + 2] = 0.0
    if with_press:
        pos4[d + 3] = tait(vel4[d + 3], prm)


def k_forces_f(dpx, dpy, dpz, pos4, vel4, i0, i1, start, ncells,
               o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
               prm_, dim, kernel_id_, ddt_kind_, laminar_, final, gx, gy, gz,
               ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """Fluid destinations rows i0..i1-1 against the rank's own rows (kind-split grid):
    per row of cells, its fluid candidates then its boundary candidates. Pair physics,
    row cut and results as k_forces.

    Built by `force_kernels` with the run's parameters and options as compile-time
    constants (PRMC, KID, DDTK, LAM): the parameters sit in constant memory (or fold
    into the instructions) instead of ~20 registers of hoisted loads, and the branches
    of unused options (cubic kernel, Molteni, laminar) are not compiled. prm_ and
    the *_ options arguments are ignored."""
    prm = cuda.const.array_like(PRMC)
    kernel_id = KID
    ddt_kind = DDTK
    laminar = LAM
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)    # a block's spare threads repeat the last row (same values, same
    #                       stores) so that every thread reaches the block maximum below
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    q0 = 0.0
    q1 = 0.0
    q2 = 0.0
    empty = False
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        o = o0 if k == 0 else (o1 if k == 1 else o2)
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        lo = 0
        hi = 0
        x = 0.0
        if a >= 0:
            x = dpx[i] if a == 0 else (dpy[i] if a == 1 else dpz[i])
            c = int(math.floor((x - o) * inv_size))
            lo = max(c - reach, 0)
            hi = min(c + reach, nk - 1)
            if lo > hi:
                empty = True
        if k == 0:
            lo0 = lo
            hi0 = hi
            q0 = x
        elif k == 1:
            lo1 = lo
            hi1 = hi
            q1 = x
        else:
            lo2 = lo
            hi2 = hi
            q2 = x
    size = 1.0 / inv_size
    reach2 = float(prm[P_SUPPORT2]) * 1.000001 + 1e-30
    d4 = 4 * i
    xa = pos4[d4]
    ya = pos4[d4 + 1]
    za = pos4[d4 + 2]
    p_a = pos4[d4 + 3]
    vxa = vel4[d4]
    vya = vel4[d4 + 1]
    vza = vel4[d4 + 2]
    rho_a = vel4[d4 + 3]
    inv_rho_a = 1.0 / rho_a
    zero = rho_a - rho_a
    axx = zero
    ayy = zero
    azz = zero
    arr = zero
    dd = zero
    cc = 0
    vmax = zero
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
                jf = start[row + clo]
                nfl = start[row + chi + 1] - jf
                jb = start[ncells + row + clo] - nfl
                m = nfl + start[ncells + row + chi + 1] - start[ncells + row + clo]
                for t in range(m):
                    b_bound = t >= nfl
                    j4 = 4 * ((jb + t) if b_bound else (jf + t))
                    drx = xa - pos4[j4]
                    dry = ya - pos4[j4 + 1]
                    drz = za - pos4[j4 + 2]
                    r2 = drx * drx + dry * dry + drz * drz
                    if r2 > support2 or r2 < 1e-18:
                        continue
                    dvx = vxa - vel4[j4]
                    dvy = vya - vel4[j4 + 1]
                    dvz = vza - vel4[j4 + 2]
                    fx, fy, fz, fr, fd, fc, fv = fluid_pair(
                        drx, dry, drz, r2, dvx, dvy, dvz, rho_a, inv_rho_a, vel4[j4 + 3], p_a, pos4[j4 + 3],
                        mb if b_bound else mf, b_bound, prm, kernel_id, ddt_kind, laminar)
                    axx += fx
                    ayy += fy
                    azz += fz
                    arr += fr
                    dd += fd
                    cc |= fc
                    if fv > vmax:
                        vmax = fv
    _store_fluid(i, final, dim == 3, gx, gy, gz, axx, ayy, azz, arr, dd, cc, ax_, ay_, az_, ar_, ddt_, cancel_)
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
    """Fluid row i's sums out (k_forces_f, k_forces_fv): with `final` (one part) the reduced
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
    """Boundary row i's sums out (k_forces_b, k_forces_bv): the density rate; a partial
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
def _fv_pair(xb, yb, zb, pb, vel4, j4, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b, support2,
             prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax):
    """k_forces_fv's test and pair body for the candidate at record j4 (position record
    xb, yb, zb, pb): the sums (axx .. vmax) with its contribution when it is within reach."""
    drx = xa - xb
    dry = ya - yb
    drz = za - zb
    r2 = drx * drx + dry * dry + drz * drz
    if not (r2 > support2 or (SELF_CUT and r2 < 1e-18)):
        vxb, vyb, vzb, rho_b = load4(vel4, j4)
        fx, fy, fz, fr, fd, fc, fv = fluid_pair(drx, dry, drz, r2, vxa - vxb, vya - vyb, vza - vzb, rho_a,
                                                inv_rho_a, rho_b, p_a, pb, mass_b, b_bound, prm, kernel_id,
                                                ddt_kind, laminar)
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
def _fv_part(pos4, vel4, j0, j1, b_bound, mass_b, unroll, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2,
             prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax):
    """k_forces_fv's loop over the candidates j0..j1-1 of one part of a row (fluid, or
    boundary with `b_bound`), on a 32-bit row index (rows < 2^31: `start` is int32): with a
    64-bit record offset the loop and address took 10 instructions a candidate (64-bit
    adds and compares), 4 with this; numba's range() would add a trip count and a second
    counter. With `unroll` 2 (a compile-time constant) two candidates a turn, both records
    loaded first, so that the second load's wait overlaps the first's (the same sums in the
    same order). (Loading each record one candidate ahead instead was 6 % slower on the
    H200: the register rotation costs 7 instructions a candidate.)"""
    j = int32(j0)
    je = int32(j1)
    if unroll == 2:
        jl = int32(je - 1)
        while j < je:
            j2 = int32(j + 1)
            xb, yb, zb, pb = load4(pos4, 4 * j)
            xc, yc, zc, pc = load4(pos4, 4 * min(j2, jl))
            axx, ayy, azz, arr, dd, cc, vmax = _fv_pair(
                xb, yb, zb, pb, vel4, 4 * j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
                support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
            if j2 < je:
                axx, ayy, azz, arr, dd, cc, vmax = _fv_pair(
                    xc, yc, zc, pc, vel4, 4 * j2, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a,
                    mass_b, support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
            j = int32(j + 2)
    else:
        while j < je:
            xb, yb, zb, pb = load4(pos4, 4 * j)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_pair(
                xb, yb, zb, pb, vel4, 4 * j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
                support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
            j = int32(j + 1)
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


def k_forces_fv(pos4, vel4, i0, i1, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                a0, a1, a2, final, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """k_forces_f (same sums in the same order) with 16-byte record loads (two a
    candidate instead of eight), cell ranges from the relative positions in the run's
    type (no float64 registers), and each row of cells trimmed to the candidates whose
    coordinate along the row lies within the sphere's chord: o0..o2 is the grid origin
    less the rank's reference point, `pad` the support radius plus the rounding of
    positions and origin (host side), so the range holds every row within reach
    whatever the rounding, and `tpad` twice the most a row moved since the cells were
    sorted (the sort order along the row may be stale by that much). The r^2 test
    decides, as in k_forces_f: trimming drops only candidates it would reject."""
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
            # its own (on the H200 one loop over both with a select per candidate is 5 %
            # slower, and a loop over the two parts 4 %)
            # (both ranges first: fewer values live across the loops, fewer registers)
            j0, j1 = _trimmed(pos4, start, row, clo, chi, a0, lo_t, hi_t)
            b0, b1 = _trimmed(pos4, start, ncells + row, clo, chi, a0, lo_t, hi_t)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_part(
                pos4, vel4, j0, j1, False, mf, UNR, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
                kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
            axx, ayy, azz, arr, dd, cc, vmax = _fv_part(
                pos4, vel4, b0, b1, True, mb, UNR, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2, prm,
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


def k_forces_bv(pos4, vel4, i0, i1, start, ncells, o0, o1, o2, inv_size, pad, tpad, n0, n1, n2,
                a0, a1, a2, final, gx, gy, gz, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """k_forces_b (same sums in the same order: boundary destinations, fluid candidates,
    DBC continuity) with k_forces_fv's record loads, cell ranges and trimmed rows;
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


def k_forces_b(dpx, dpy, dpz, pos4, vel4, i0, i1, start, ncells,
               o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
               prm_, dim, kernel_id_, final, ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """Boundary destinations rows i0..i1-1: fluid candidates only (DBC continuity).
    Constants as k_forces_f."""
    prm = cuda.const.array_like(PRMC)
    kernel_id = KID
    i = cuda.grid(1) + i0
    i = min(i, i1 - 1)    # a block's spare threads repeat the last row (same values, same
    #                       stores) so that every thread reaches the block maximum below
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    q0 = 0.0
    q1 = 0.0
    q2 = 0.0
    empty = False
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        o = o0 if k == 0 else (o1 if k == 1 else o2)
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        lo = 0
        hi = 0
        x = 0.0
        if a >= 0:
            x = dpx[i] if a == 0 else (dpy[i] if a == 1 else dpz[i])
            c = int(math.floor((x - o) * inv_size))
            lo = max(c - reach, 0)
            hi = min(c + reach, nk - 1)
            if lo > hi:
                empty = True
        if k == 0:
            lo0 = lo
            hi0 = hi
            q0 = x
        elif k == 1:
            lo1 = lo
            hi1 = hi
            q1 = x
        else:
            lo2 = lo
            hi2 = hi
            q2 = x
    size = 1.0 / inv_size
    reach2 = float(prm[P_SUPPORT2]) * 1.000001 + 1e-30
    d4 = 4 * i
    xa = pos4[d4]
    ya = pos4[d4 + 1]
    za = pos4[d4 + 2]
    vxa = vel4[d4]
    vya = vel4[d4 + 1]
    vza = vel4[d4 + 2]
    rho_a = vel4[d4 + 3]
    zero = rho_a - rho_a
    arr = zero
    vmax = zero
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
                    j4 = 4 * j
                    drx = xa - pos4[j4]
                    dry = ya - pos4[j4 + 1]
                    drz = za - pos4[j4 + 2]
                    r2 = drx * drx + dry * dry + drz * drz
                    if r2 > support2 or r2 < 1e-18:
                        continue
                    fr, fv = bound_pair(drx, dry, drz, r2, vxa - vel4[j4], vya - vel4[j4 + 1],
                                        vza - vel4[j4 + 2], rho_a, vel4[j4 + 3], mf, prm, kernel_id)
                    arr += fr
                    if fv > vmax:
                        vmax = fv
    _store_boundary(i, final, dim == 3, zero, arr, ax_, ay_, az_, ar_, ddt_, cancel_)
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


def k_count_pairs2(dpx, dpy, dpz, pos4, n, nf, start, ncells, o0, o1, o2, inv_size, n0, n1, n2,
                   a0, a1, a2, reach, support2, counts):
    """Pairs within 2h of each destination, as DualSPHysics counts them: every
    neighbour of a fluid row, the fluid neighbours of a boundary row."""
    i = cuda.grid(1)
    if i >= n:
        return
    lo0 = 0
    hi0 = 0
    lo1 = 0
    hi1 = 0
    lo2 = 0
    hi2 = 0
    for k in range(3):
        a = a0 if k == 0 else (a1 if k == 1 else a2)
        o = o0 if k == 0 else (o1 if k == 1 else o2)
        nk = n0 if k == 0 else (n1 if k == 1 else n2)
        lo = 0
        hi = 0
        if a >= 0:
            x = dpx[i] if a == 0 else (dpy[i] if a == 1 else dpz[i])
            c = int(math.floor((x - o) * inv_size))
            lo = max(c - reach, 0)
            hi = min(c + reach, nk - 1)
        if k == 0:
            lo0 = lo
            hi0 = hi
        elif k == 1:
            lo1 = lo
            hi1 = hi
        else:
            lo2 = lo
            hi2 = hi
    m = 0
    halves = 2 if i < nf else 1
    if lo0 <= hi0 and lo1 <= hi1 and lo2 <= hi2:
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


_KERNELS = ("k_fill", "k_copy", "k_keys_hist", "k_scan_blocks", "k_scan_add", "k_set_last", "k_scatter",
            "k_sort_cells", "k_sort_cells_by", "k_gather3", "k_copy3", "k_gather_pos", "k_rel", "k_pressure", "k_forces", "k_reduce",
            "k_dt_terms", "k_check_bounds", "k_check_init", "k_verlet", "k_sym_predict", "k_sym_correct", "k_count_pairs",
            "k_keys_hist2", "k_gather4", "k_pack", "k_count_pairs2", "k_compact_perm",
            "k_mig_keep", "k_pack_leaving", "k_unpack_rows", "k_pack_edge", "k_pick4",
            "k_stamp", "k_edge_init", "k_edge_bounds", "k_edge_keys", "k_edge_gather")
_FAST = {"k_forces", "k_count_pairs", "k_count_pairs2"}
_BUILT: dict = {}


def build(dtype, fastmath: bool | None = None) -> types.SimpleNamespace:
    """The kernels for float type `dtype` (cached). fastmath (default: on for float32)
    applies to the force loop only."""
    dt = np.dtype(dtype)
    fm = (dt == np.float32) if fastmath is None else bool(fastmath)
    key = (dt.str, fm)
    if key not in _BUILT:
        memo = {}
        g = globals()
        _BUILT[key] = types.SimpleNamespace(**{
            name: kernel(g[name], dt, memo, fastmath=fm and name in _FAST) for name in _KERNELS})
    return _BUILT[key]


# register cap of the force kernels, float32 (0: the compiler's choice). Measured on the H100
# (SPHERIC 2, 2026-11-22): uncapped k_forces_f takes 87 registers (31 % occupancy); capped at
# 64 (50 %, 64 B of spills) it is 15 % faster at 4.4 M and 9 % at 13 M, 2 % at 1.1 M.
# H200, 2026-12-02 (k_forces_fv with 32-bit loop indices): cap 56 is 3 % faster than 64 per
# forces at 4.4 M (7.23 / 7.45 ms), 72 is 10 % slower; its 48-56 B stack frame stays within the
# driver's default per-thread reservation (peak device memory unchanged, 98.3 B a particle).
# H200, 2026-12-02 (pair bodies of ~55 instructions): cap 48 is 2.2 % faster per forces than 56
# (6.40 / 6.55 ms at 4.4 M), whole steps 274.1 / 266.0 M particle-steps/s at 4.4 M and 281.3 /
# 278.3 M at 13.3 M; its 72-80 B stack frame (spills of the row set-up, none in the candidate
# loops) stays within the default per-thread local memory (peak 98.3 B a particle at 4.4 M).
MAXREG = int(os.environ.get("SPHGRAPH_CUDA_MAXREG", "48"))
_FORCES: dict = {}


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar, fastmath: bool | None = None,
                  max_registers: int | None = None) -> types.SimpleNamespace:
    """The fluid and boundary force kernels (k_forces_f / k_forces_b, or with FORCES "fv"
    k_forces_fv / k_forces_bv, under the names k_forces_f / k_forces_b) for one run: `prm` (the run's parameter vector) and the
    options become compile-time constants (cached per distinct set; a new scene or dp
    compiles once more)."""
    dt = np.dtype(dtype)
    fm = (dt == np.float32) if fastmath is None else bool(fastmath)
    mr = (MAXREG if dt == np.float32 else 0) if max_registers is None else int(max_registers)
    pc = np.ascontiguousarray(prm, dt)
    key = (dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar), fm, mr, FORCES, UNROLL, SELF_CUT)
    if key not in _FORCES:
        memo = {}
        extra = {"PRMC": pc, "KID": int(kernel_id), "DDTK": int(ddt_kind), "LAM": int(laminar), "UNR": UNROLL}
        out = {}
        out["relative"] = FORCES != "f"      # k_forces_fv's arguments
        for name in ("k_forces_f", "k_forces_b"):
            src = name if FORCES == "f" else name + "v"     # fv: k_forces_fv / k_forces_bv
            fn = _clone(globals()[src], dt, memo, extra)
            if SIMULATOR:
                out[name] = cuda.jit(fn)
            elif mr:
                out[name] = cuda.jit(fastmath=fm, max_registers=mr)(fn)
            else:
                out[name] = cuda.jit(fastmath=fm)(fn)
        _FORCES[key] = types.SimpleNamespace(**out)
    return _FORCES[key]


def blocks(n: int, block: int = BLOCK) -> int:
    return max(1, (int(n) + block - 1) // block)
