"""numba.cuda kernels of the DuFort-Frankel density-diffusion step (`[physics] diffusion_time =
"dufort-frankel"`, sphgraph.physics.interact): the GPU twin of cpu_kernels.forces_df and
reduce_parts (its K_a part).

* The fluid force kernels of the rank's own rows, of an ipc halo and of a host-binned halo
  are cuda_forces.k_forces_fv, cuda_halo_kernels.k_halo_fv and cuda_forces.k_forces with one
  more sum a row (cuda_variants.with_sum), K_a = sum_b k_ab (`fluid_pair_df`, the pair maths
  numba-cpu's forces_df calls), written to `ddk_` by `_store_ddk`: reduced (0 where a
  boundary neighbour cancels the diffusion) when the kernel writes the only part, else the
  part's raw sum. The boundary kernels are the plain ones (a boundary row has no K_a: verlet
  reads it for fluid rows only). Copies of their own, so that the default path is compiled
  as it is.
* k_reduce_ddk / k_reduce_ranged_ddk: the parts' K_a summed in the order of k_reduce /
  k_reduce_ranged, zeroed where a part cancelled the diffusion (cpu_kernels.reduce_parts).
* the Verlet step is cuda_integrate.k_verlet's, whose density is sphgraph.physics.integrate's
  `verlet_density` (the CPU's) with its DuFort-Frankel form on: it reads K_a (`ddk_in`).

`ddk_out`, `reduce` and `ddk_in` are the backend's entry points (numba_cuda calls them; each
is a no-op or empty without `opt[O_DDT_DF]`).
"""
import types

import numpy as np
from numba import cuda, njit

from sphgraph.config import O_DDT_DF
from sphgraph.physics.interact import fluid_pair_df
from sphgraph.state import PARTS

from . import cuda_forces as CF
from . import cuda_halo as CH
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from .cuda_memory import dev_array
from .cuda_variants import ForceVariant, with_sum


def enabled(state) -> bool:
    return bool(state.opt[O_DDT_DF])


# ------------------------------------------------------------------------------ force kernels
@njit(inline="always")
def _store_ddk(i, final, cc, kk, ddk_):
    """K_a of row i out: reduced (0 where a neighbour cancelled the diffusion) with `final`
    (the only part), else the part's raw sum (k_reduce_ddk applies the cancel)."""
    if final:
        ddk_[i] = kk if cc == 0 else 0.0 * kk
    else:
        ddk_[i] = kk


# ------------------------------------------------------------------- reduction, integration
def k_reduce_ddk(nparts, n, kind, k0, c0, k1, c1, k2, c2, k3, c3, ddk_):
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
    if nparts > 3:
        s += k3[i]
        cc |= c3[i]
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
# the production loops with K_a: the candidate loop, then the kernels (ddk_ their last argument)
_fv_part = with_sum(CF._fv_part, fluid_pair_df, _fv_pair=with_sum(CF._fv_pair, fluid_pair_df))
KERNELS = ForceVariant(fluid=with_sum(CF.k_forces_fv, fluid_pair_df, _store_ddk, _fv_part=_fv_part),
                       halo_fluid=with_sum(HK.k_halo_fv, fluid_pair_df, _store_ddk, _fv_part=_fv_part),
                       binned=with_sum(CF.k_forces, fluid_pair_df, _store_ddk),
                       binned_name="k_forces_df", plain=(k_reduce_ddk, k_reduce_ranged_ddk))


def build(dtype) -> types.SimpleNamespace:
    """k_forces_df (k_forces with K_a; host-binned halos as the sources) and the reductions for
    float type `dtype` (cached)."""
    return KERNELS.build(dtype)


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_kernels.force_kernels' namespace for the DuFort-Frankel step: k_forces_f takes
    ddk_ after the plain arguments, k_forces_b is cuda_forces.k_forces_bv."""
    return KERNELS.force_kernels(dtype, prm, kernel_id, ddt_kind, laminar)


def halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_halo_kernels.force_kernels' namespace: k_halo_fv takes ddk_ last, k_halo_bv as it is."""
    return KERNELS.halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar)


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
    names = [p for p in PARTS if p in P]
    bufs = [P[p] for p in names]
    while len(bufs) < 4:
        bufs.append(bufs[0])
    flat = [x for b in bufs for x in (b["ddk"], b["cancel"])]
    k.k_reduce_ddk[CK.blocks(dv.n), CK.BLOCK](len(names), dv.n, A["kind"], *flat, out)


def ddk_in(state, dv):
    """The reduced K_a that numba_cuda's Verlet kernel reads (`k_verlet`, df on), or None
    without the DuFort-Frankel step."""
    if not enabled(state):
        return None
    return _ddk_array(dv, max(dv.n, dv.cap, 1))
