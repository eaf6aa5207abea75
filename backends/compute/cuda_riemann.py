"""numba.cuda force kernels of the Riemann-solver pressure term (`[physics] riemann = "zhang2017"`,
`interact.riemann_pair`): the GPU twin of cpu_kernels.forces_riemann.

No kernel is written here: the force kernels of cuda_forces (the rank's own rows, k_forces
for host-binned halos) and of cuda_halo_kernels (ipc halos) are copied (cuda_variants.with_globals)
with their fluid pair function replaced by `riemann_fluid_pair` -- `riemann_pair` (the pair maths numba-cpu
calls, which returns `fluid_pair`'s tuple: the U* jump as the diffusion term, cancelled next to
walls with riemann_wall = "cancel") in `fluid_pair`'s signature -- so the
neighbour loops, sums and stores are those of the default path, which is compiled as it was.
Boundary rows keep `bound_pair` (DBC continuity), as on the CPU.
"""
import types

import numpy as np
from numba import njit

from sphgraph.config import O_RIEMANN
from sphgraph.physics.interact import riemann_pair

from . import cuda_forces as CF
from . import cuda_halo_kernels as HK
from .cuda_variants import ForceVariant, with_globals


def enabled(state) -> bool:
    return bool(state.opt[O_RIEMANN])


@njit(inline="always")
def riemann_fluid_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a, inv_rho_a, rho_b, p_a, p_b,
                       mass_b, b_bound, b_still, prm, kernel, ddt_kind, laminar):
    """`riemann_pair` in `fluid_pair`'s signature (ddt_kind unused: the pair's diffusion is
    the U* jump). The row itself adds nothing: k_forces_fv's loop has no r^2 < 1e-18 cut
    (every term of fluid_pair is an exact zero there), and riemann_pair divides by r."""
    if r2 < 1e-18:
        z = 0.0 * rho_a
        return z, z, z, z, z, 0, z
    return riemann_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a, inv_rho_a, rho_b,
                        p_a, p_b, mass_b, b_bound, b_still, prm, kernel, laminar)


# the fluid candidate loop of k_forces_fv / k_halo_fv with the Riemann pair, then the kernels
_fv_part = with_globals(CF._fv_part, _fv_pair=with_globals(CF._fv_pair, fluid_pair=riemann_fluid_pair))
KERNELS = ForceVariant(fluid=with_globals(CF.k_forces_fv, _fv_part=_fv_part),
                       halo_fluid=with_globals(HK.k_halo_fv, _fv_part=_fv_part),
                       binned=with_globals(CF.k_forces, fluid_pair=riemann_fluid_pair))


def build(dtype) -> types.SimpleNamespace:
    """k_forces (host-binned halos as the sources) with the Riemann pair, for `dtype` (cached)."""
    return KERNELS.build(dtype)


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_kernels.force_kernels' namespace (k_forces_f / k_forces_b) with the Riemann pair."""
    return KERNELS.force_kernels(dtype, prm, kernel_id, ddt_kind, laminar)


def halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_halo_kernels.force_kernels' namespace (k_halo_fv / k_halo_bv) with the Riemann pair."""
    return KERNELS.halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar)
