"""numba.cuda kernels of the renormalised Riemann jump (`[physics] riemann_jump = "renormalised"`,
sphgraph.physics.riemann_jump): the GPU twin of numba-cpu's moments `jm` and their correction
where the parts are summed.

* The fluid force kernels of the rank's own rows, of an ipc halo and of a host-binned halo are
  cuda_forces.k_forces_fv, cuda_halo_kernels.k_halo_fv and cuda_forces.k_forces with twelve
  more sums a row (cuda_variants.with_sum, nsum=12), fed by `rjump_fluid_pair`: the Riemann
  pair of cuda_riemann and the pair's `jump_moments` (the maths numba-cpu calls), written raw
  by `_store_jm` into the part's (12, n) array "jm" (moment k of row i at [k, i]: a warp's
  stores of one moment are coalesced). Twelve scalars, not a local array: they stay in
  registers. The boundary kernels are the plain ones (a boundary row has no jump).
* The correction needs all of a row's parts summed (det M_a and M_a^-1 are not linear in
  them), so with this option the interior part is never written reduced (`final`): the parts
  always exist and `reduce` runs after numba_cuda's k_reduce / k_reduce_ranged wrote `ar`,
  adding `jump_correction` of the summed moments to the fluid rows whose jump no part
  cancelled (k_reduce_jm / k_reduce_ranged_jm, the parts as k_reduce / k_reduce_ranged take
  them). One more pass over the rows and a (12, n) array a part, for a term that is off by
  default; the force kernels of the default path are compiled as they are.

The DuFort-Frankel step (Verlet) and the Riemann term (Symplectic) never run together, so a
run's force kernels carry the sums of cuda_dufort or of this module, never both.
`jm_out` and `reduce` are the backend's entry points (no-ops without the option).
"""
import math
import types

from numba import cuda, njit

from sphgraph.physics.riemann_jump import RJ_SUMS, jump_correction, jump_kept, jump_moments, renormalised
from sphgraph.state import PARTS

from . import cuda_forces as CF
from . import cuda_halo as CH
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from .cuda_memory import dev_array
from .cuda_retarget import RT  # noqa: F401  (the run's float type: _clone rebinds it a copy)
from .cuda_riemann import riemann_fluid_pair
from .cuda_variants import ForceVariant, with_sum


def enabled(state) -> bool:
    return renormalised(state.opt)


# ------------------------------------------------------------------------------ force kernels
@njit(inline="always")
def rjump_fluid_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a, inv_rho_a, rho_b, p_a, p_b,
                     mass_b, b_bound, b_still, prm, kernel, ddt_kind, laminar):
    """`riemann_fluid_pair`'s seven values, then the twelve moments the pair adds to row a's
    sums (`jump_moments`): zeros for a boundary b (its pressure is a wall's reaction, not a
    fluid state) and for the row itself (r^2 < 1e-18: the moments' F r would divide by 0)."""
    fx, fy, fz, fr, fd, fc, fv = riemann_fluid_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a,
                                                    inv_rho_a, rho_b, p_a, p_b, mass_b, b_bound, b_still, prm,
                                                    kernel, ddt_kind, laminar)
    if b_bound or r2 < 1e-18:
        z = 0.0 * rho_a
        return fx, fy, fz, fr, fd, fc, fv, z, z, z, z, z, z, z, z, z, z, z, z
    m00, m01, m02, m11, m12, m22, g0, g1, g2, s0, s1, s2 = jump_moments(drx, dry, drz, r2, math.sqrt(r2), rho_a,
                                                                        rho_b, p_a, p_b, mass_b, prm, kernel)
    return fx, fy, fz, fr, fd, fc, fv, m00, m01, m02, m11, m12, m22, g0, g1, g2, s0, s1, s2


@njit(inline="always")
def _store_jm(i, final, cc, k0, k1, k2, k3, k4, k5, k6, k7, k8, k9, k10, k11, jm_):
    """Row i's twelve moments, raw, into its part's jm_ (12, n): never `final` (module doc),
    the cancel is applied where the parts are summed."""
    jm_[0, i] = k0
    jm_[1, i] = k1
    jm_[2, i] = k2
    jm_[3, i] = k3
    jm_[4, i] = k4
    jm_[5, i] = k5
    jm_[6, i] = k6
    jm_[7, i] = k7
    jm_[8, i] = k8
    jm_[9, i] = k9
    jm_[10, i] = k10
    jm_[11, i] = k11


# --------------------------------------------------------------------------------- reduction
def k_reduce_jm(nparts, n, dim, kind, j0, c0, d0, j1, c1, d1, j2, c2, d2, j3, c3, d3, ar_):
    """The parts' moments summed (interior, halo 1, halo 2, images: the `nparts` present, in
    k_reduce's order) and the jump's correction added to the fluid rows' ar_ (k_reduce's
    result) where the row keeps its jump (jump_kept: no part cancelled it, or one did and the
    row is renormalised -- then k_reduce dropped the parts' jumps d0..d3, added back here;
    cpu: the same sums, jump_kept and jump_correction)."""
    i = cuda.grid(1)
    if i >= n or kind[i] != 0:
        return
    cc = c0[i]
    if nparts > 1:
        cc |= c1[i]
    if nparts > 2:
        cc |= c2[i]
    if nparts > 3:
        cc |= c3[i]
    m = cuda.local.array(12, RT)
    for k in range(12):
        s = j0[k, i]
        if nparts > 1:
            s += j1[k, i]
        if nparts > 2:
            s += j2[k, i]
        if nparts > 3:
            s += j3[k, i]
        m[k] = s
    if not jump_kept(cc, m[0], m[1], m[2], m[3], m[4], m[5], dim):
        return
    add = jump_correction(m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], dim)
    if cc != 0:
        dd = d0[i]
        if nparts > 1:
            dd += d1[i]
        if nparts > 2:
            dd += d2[i]
        if nparts > 3:
            dd += d3[i]
        add = dd + add
    ar_[i] += add


def k_reduce_ranged_jm(n, dim, kind, j0, c0, d0, rng, h1, o1, j1, c1, d1, h2, o2, j2, c2, d2, ar_):
    """k_reduce_jm with ipc halo parts, each added at its fluid target rows only (as
    cuda_halo_kernels.k_reduce_ranged)."""
    i = cuda.grid(1)
    if i >= n or kind[i] != 0:
        return
    in1 = h1 != 0 and i >= rng[o1] and i < rng[o1 + 1]
    in2 = h2 != 0 and i >= rng[o2] and i < rng[o2 + 1]
    cc = c0[i]
    if in1:
        cc |= c1[i]
    if in2:
        cc |= c2[i]
    m = cuda.local.array(12, RT)
    for k in range(12):
        s = j0[k, i]
        if in1:
            s += j1[k, i]
        if in2:
            s += j2[k, i]
        m[k] = s
    if not jump_kept(cc, m[0], m[1], m[2], m[3], m[4], m[5], dim):
        return
    add = jump_correction(m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], dim)
    if cc != 0:
        dd = d0[i]
        if in1:
            dd += d1[i]
        if in2:
            dd += d2[i]
        add = dd + add
    ar_[i] += add


# ------------------------------------------------------------------------------ compilation
# the production loops with the twelve moments: the candidate loop, then the kernels (jm_ last)
_pair = dict(pair=rjump_fluid_pair, nsum=RJ_SUMS)
_fv_part = with_sum(CF._fv_part, **_pair, _fv_pair=with_sum(CF._fv_pair, **_pair))
KERNELS = ForceVariant(fluid=with_sum(CF.k_forces_fv, store=_store_jm, **_pair, _fv_part=_fv_part),
                       halo_fluid=with_sum(HK.k_halo_fv, store=_store_jm, **_pair, _fv_part=_fv_part),
                       binned=with_sum(CF.k_forces, store=_store_jm, **_pair),
                       binned_name="k_forces_rj", plain=(k_reduce_jm, k_reduce_ranged_jm))


def build(dtype) -> types.SimpleNamespace:
    """k_forces_rj (k_forces with the moments; host-binned halos as the sources) and the
    reductions for float type `dtype` (cached)."""
    return KERNELS.build(dtype)


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_kernels.force_kernels' namespace: k_forces_f takes jm_ after the plain arguments,
    k_forces_b is cuda_forces.k_forces_bv."""
    return KERNELS.force_kernels(dtype, prm, kernel_id, ddt_kind, laminar)


def halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_halo_kernels.force_kernels' namespace: k_halo_fv takes jm_ last, k_halo_bv as it is."""
    return KERNELS.halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar)


# ------------------------------------------------------------------------ backend entries
def jm_out(be, state, dv, part, final) -> tuple:
    """The extra output of the fluid force kernels of `part` (empty without the option): the
    part buffer's "jm" (12 x the buffer's rows, allocated with it)."""
    if not enabled(state):
        return ()
    if final:       # the dispatch never writes this option's interior reduced (module doc)
        raise AssertionError("cuda_rjump: a part written reduced has no moments to correct with")
    buf = dv.parts[part]
    a = buf.get("jm")
    m = buf["ar"].shape[0]
    if a is None or a.shape[1] < m:
        a = buf["jm"] = dev_array((RJ_SUMS, m), dv.dtype)
    return (a,)


def reduce(be, state, dv, ranged) -> None:
    """The jump's correction into the reduced `ar` (after numba_cuda's reduce_forces summed
    the rest; nothing without the option)."""
    if not enabled(state) or not dv.parts or not dv.n:
        return
    k = be._on(state, build(dv.dtype))
    A = dv.A()
    P = dv.parts
    if ranged:
        inner = P["interior"]
        flat = []
        for used, r, b in CH.ranged_parts(dv):
            flat += [used, r, b["jm"], b["cancel"], b["ddt"]]
        k.k_reduce_ranged_jm[CK.blocks(dv.n), CK.BLOCK](dv.n, dv.dim, A["kind"], inner["jm"], inner["cancel"],
                                                       inner["ddt"], A["pick8"], *flat, A["ar"])
        return
    bufs = [P[p] for p in PARTS if p in P]
    nparts = len(bufs)
    while len(bufs) < 4:
        bufs.append(bufs[0])
    flat = [x for b in bufs for x in (b["jm"], b["cancel"], b["ddt"])]
    k.k_reduce_jm[CK.blocks(dv.n), CK.BLOCK](nparts, dv.n, dv.dim, A["kind"], *flat, A["ar"])
