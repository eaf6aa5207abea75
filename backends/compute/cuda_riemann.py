"""numba.cuda force kernels of the Riemann-solver pressure term (`[physics] riemann = "zhang2017"`,
`interact.riemann_pair`): the GPU twin of cpu_kernels.forces_riemann.

No kernel is written here: the force kernels of cuda_forces (the rank's own rows, k_forces
for host-binned halos) and of cuda_halo_kernels (ipc halos) are retargeted with their fluid
pair function replaced by `riemann_fluid_pair` -- `riemann_pair` (the pair maths numba-cpu
calls) in `fluid_pair`'s signature, with no diffusion term and nothing cancelled -- so the
neighbour loops, sums and stores are those of the default path, which is compiled as it was.
Boundary rows keep `bound_pair` (DBC continuity), as on the CPU.
"""
import types

import numpy as np
from numba import njit
from numba.core.dispatcher import Dispatcher

from sphgraph.config import O_RIEMANN
from sphgraph.physics.interact import riemann_pair

from . import cuda_forces as CF
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK


def enabled(state) -> bool:
    return bool(state.opt[O_RIEMANN])


@njit(inline="always")
def riemann_fluid_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, inv_rho_a, rho_b, p_a, p_b, mass_b,
                       b_bound, prm, kernel, ddt_kind, laminar):
    """`riemann_pair` as `fluid_pair` returns: (ax, ay, az, ar, ddt, cancel, visc) with no
    diffusion term (ddt 0) and no cancel (the Riemann term carries its own dissipation). The
    row itself adds nothing: k_forces_fv's loop has no r^2 < 1e-18 cut (every term of
    fluid_pair is an exact zero there), and riemann_pair divides by r."""
    if r2 < 1e-18:
        z = 0.0 * rho_a
        return z, z, z, z, z, 0, z
    ax, ay, az, ar, visc = riemann_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, inv_rho_a, rho_b, p_a, p_b,
                                        mass_b, b_bound, prm, kernel, laminar)
    return ax, ay, az, ar, 0.0 * ar, 0, visc


def _with(f, **subs):
    """A copy of the function `f` (plain, or @njit: then an inlined @njit copy) whose global
    names `subs` rebind: cuda_retarget then retargets the copy and what it calls."""
    py = getattr(f, "py_func", f)
    g = dict(py.__globals__)
    g.update(subs)
    fn = types.FunctionType(py.__code__, g, py.__name__, py.__defaults__, py.__closure__)
    return njit(inline="always")(fn) if isinstance(f, Dispatcher) else fn


# the fluid candidate loop of k_forces_fv / k_halo_fv, with the Riemann pair
_fv_part = _with(CF._fv_part, _fv_pair=_with(CF._fv_pair, fluid_pair=riemann_fluid_pair))
_BUILT: dict = {}
_FORCES: dict = {}
_HALO: dict = {}


def build(dtype) -> types.SimpleNamespace:
    """k_forces (host-binned halos as the sources) with the Riemann pair, for `dtype` (cached)."""
    dt = np.dtype(dtype)
    if dt.str not in _BUILT:
        _BUILT[dt.str] = types.SimpleNamespace(
            k_forces=CK.kernel(_with(CF.k_forces, fluid_pair=riemann_fluid_pair), dt, {},
                               fastmath=dt == np.float32))
    return _BUILT[dt.str]


def _compile(fluid, boundary, dtype, prm, kernel_id, ddt_kind, laminar):
    """cuda_forces.compile_forces of `fluid` / `boundary` with the Riemann candidate loop, with
    cuda_kernels.force_kernels' fastmath and register cap (cached per run's constants)."""
    dt = np.dtype(dtype)
    fm = dt == np.float32
    mr = CK.MAXREG if fm else 0
    pc = np.ascontiguousarray(prm, dt)
    key = (fluid.__name__, dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar))
    if key not in _FORCES:
        _FORCES[key] = CF.compile_forces(fluid, boundary, dt, pc, kernel_id, ddt_kind, laminar, fm, mr,
                                         extra={"_fv_part": _fv_part})
    return _FORCES[key]


def force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_kernels.force_kernels' namespace (k_forces_f / k_forces_b) with the Riemann pair."""
    return _compile(CF.k_forces_fv, CF.k_forces_bv, dtype, prm, kernel_id, ddt_kind, laminar)


def halo_force_kernels(dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
    """cuda_halo_kernels.force_kernels' namespace (k_halo_fv / k_halo_bv) with the Riemann pair."""
    ns = _compile(HK.k_halo_fv, HK.k_halo_bv, dtype, prm, kernel_id, ddt_kind, laminar)
    key = id(ns)      # one namespace object a compiled pair: the launch layer caches per object
    if key not in _HALO or _HALO[key][0] is not ns:
        _HALO[key] = (ns, types.SimpleNamespace(k_halo_fv=ns.k_forces_f, k_halo_bv=ns.k_forces_b))
    return _HALO[key][1]
