"""The force-kernel variants that the GPU backend's choices were measured against
(docs/gpu.md, BENCHMARKS.md §6), kept for A/B runs (benchmarks/force_ab.py,
benchmarks/force_ptx.py) and for the simulator test that the production kernels sum alike
(tests/test_cuda_backend.py). Production compiles none of them.

* ``forces="f"``: k_forces_f / k_forces_b, whole cells of scalar loads: float64 cell
  ranges from (px, py, pz), candidate records read one value at a time, one maximum per
  block through shared memory. The production k_forces_fv / k_forces_bv give the same sums
  in the same order.
* ``unroll=1``: k_forces_fv's candidates one a turn (production: two, both records loaded
  first).
* ``self_cut=True``: k_forces_fv's candidate test also skips r^2 < 1e-18 (the row itself;
  production lets it add exact zeros: one compare and one predicate operation a candidate
  less).

`select(...)` makes the backend compile a variant: numba_cuda asks
`cuda_kernels.force_kernels` for its force kernels at every call, and this replaces it.
"""
from __future__ import annotations

import functools
import math
import sys
import types
from pathlib import Path

import numpy as np
from numba import cuda, int32, njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sphgraph.backends.compute import cuda_forces as F  # noqa: E402
from sphgraph.backends.compute import cuda_kernels as CK  # noqa: E402
from sphgraph.backends.compute.cuda_forces import _store_boundary, _store_fluid  # noqa: E402,F401
from sphgraph.backends.compute.cuda_retarget import RT, load4  # noqa: E402,F401
from sphgraph.cells import cell_window  # noqa: E402
from sphgraph.config import P_H, P_MASS_B, P_MASS_F, P_SUPPORT2, P_WALL_NOSLIP  # noqa: E402
from sphgraph.particles import FIXED  # noqa: E402
from sphgraph.physics.interact import bound_pair, fluid_pair  # noqa: E402

PRODUCTION = CK.force_kernels
_CACHE: dict = {}


def _with_globals(f, **names):
    """An @njit(inline="always") copy of the @njit function `f` whose globals `names` are
    replaced (its device copy then calls those instead)."""
    py = f.py_func
    g = dict(py.__globals__, **names)
    return njit(inline="always")(types.FunctionType(py.__code__, g, py.__name__, py.__defaults__, py.__closure__))


@njit(inline="always")
def _fv_pair_cut(xb, yb, zb, pb, vel4, kind, j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
                 support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax):
    """cuda_forces._fv_pair with the r^2 < 1e-18 cut in the candidate test."""
    drx = xa - xb
    dry = ya - yb
    drz = za - zb
    r2 = drx * drx + dry * dry + drz * drz
    if not (r2 > support2 or r2 < 1e-18):
        vxb, vyb, vzb, rho_b = load4(vel4, 4 * j)
        still = b_bound and prm[P_WALL_NOSLIP] != 0.0 and kind[j] == FIXED
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
def _fv_part_one(pos4, vel4, kind, j0, j1, b_bound, mass_b, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, support2,
                 prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax):
    """cuda_forces._fv_part with one candidate a turn."""
    j = int32(j0)
    je = int32(j1)
    while j < je:
        xb, yb, zb, pb = load4(pos4, 4 * j)
        axx, ayy, azz, arr, dd, cc, vmax = _fv_pair(
            xb, yb, zb, pb, vel4, kind, j, b_bound, xa, ya, za, p_a, vxa, vya, vza, rho_a, inv_rho_a, mass_b,
            support2, prm, kernel_id, ddt_kind, laminar, axx, ayy, azz, arr, dd, cc, vmax)
        j = int32(j + 1)
    return axx, ayy, azz, arr, dd, cc, vmax


_fv_pair = F._fv_pair      # _fv_part_one's pair body unless _with_globals replaces it


@njit(inline="always")
def _along(x, y, z, a):
    """The coordinate of (x, y, z) along axis `a` (0, 1, 2), 0 for a missing axis (a < 0)."""
    if a < 0:
        return 0.0 * x
    return x if a == 0 else (y if a == 1 else z)


def k_forces_f(dpx, dpy, dpz, pos4, vel4, kind, i0, i1, start, ncells,
               o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
               prm_, dim, kernel_id_, ddt_kind_, laminar_, final, gx, gy, gz,
               ax_, ay_, az_, ar_, ddt_, cancel_, visc_):
    """Fluid destinations rows i0..i1-1 against the rank's own rows (kind-split grid):
    per row of cells, its fluid candidates then its boundary candidates. Pair physics,
    row cut and results as cuda_forces.k_forces.

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
    x = dpx[i]
    y = dpy[i]
    z = dpz[i] if dim == 3 else 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(x, y, z, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach)
    q0 = _along(x, y, z, a0)
    q1 = _along(x, y, z, a1)
    q2 = _along(x, y, z, a2)
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
                    jr = (jb + t) if b_bound else (jf + t)
                    j4 = 4 * jr
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
                        drx, dry, drz, r2, dvx, dvy, dvz, vel4[j4], vel4[j4 + 1], vel4[j4 + 2], rho_a, inv_rho_a,
                        vel4[j4 + 3], p_a, pos4[j4 + 3], mb if b_bound else mf, b_bound,
                        b_bound and prm[P_WALL_NOSLIP] != 0.0 and kind[jr] == FIXED, prm, kernel_id, ddt_kind, laminar)
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


def k_forces_b(dpx, dpy, dpz, pos4, vel4, kind, i0, i1, start, ncells,
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
    x = dpx[i]
    y = dpy[i]
    z = dpz[i] if dim == 3 else 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(x, y, z, o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach)
    q0 = _along(x, y, z, a0)
    q1 = _along(x, y, z, a1)
    q2 = _along(x, y, z, a2)
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



def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar, fastmath: bool | None = None,
                  max_registers: int | None = None, *, forces="fv", unroll=2, self_cut=False):
    """cuda_kernels.force_kernels for a variant (same arguments and defaults, the register
    cap read from cuda_kernels.MAXREG at each call, as there)."""
    dt = np.dtype(dtype)
    fm = (dt == np.float32) if fastmath is None else bool(fastmath)
    mr = (CK.MAXREG if dt == np.float32 else 0) if max_registers is None else int(max_registers)
    pc = np.ascontiguousarray(prm, dt)
    key = (dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar), fm, mr, forces, unroll, self_cut)
    if key not in _CACHE:
        if forces == "f":
            _CACHE[key] = F.compile_forces(k_forces_f, k_forces_b, dt, pc, kernel_id, ddt_kind, laminar, fm, mr,
                                           relative=False)
        else:
            pair = _fv_pair_cut if self_cut else F._fv_pair
            part = _fv_part_one if unroll == 1 else F._fv_part
            extra = {"_fv_part": _with_globals(part, _fv_pair=pair)} if (unroll, self_cut) != (2, False) else None
            _CACHE[key] = F.compile_forces(F.k_forces_fv, F.k_forces_bv, dt, pc, kernel_id, ddt_kind, laminar,
                                           fm, mr, extra=extra)
    return _CACHE[key]


def select(forces: str = "fv", unroll: int = 2, self_cut: bool = False) -> None:
    """The force kernels the backend compiles from now on: a variant, or (the defaults)
    production's."""
    if forces not in ("f", "fv") or unroll not in (1, 2):
        raise ValueError(f"force variant: expected forces f|fv and unroll 1|2, got {forces!r}, {unroll!r}")
    if (forces, unroll, self_cut) == ("fv", 2, False):
        CK.force_kernels = PRODUCTION
    else:
        CK.force_kernels = functools.partial(force_kernels, forces=forces, unroll=unroll, self_cut=self_cut)
