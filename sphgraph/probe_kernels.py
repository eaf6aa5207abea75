"""numba kernels of the `[forces]` sampler (sphgraph.probes): the pressure force of the fluid
on a body's boundary particles through a cell grid over the fluid, O(body x neighbours)
instead of dense body x fluid pair matrices."""
import numpy as np
from numba import njit, prange

from .physics import drop_stale_cache

drop_stale_cache(__file__)  # the kernel inlines sphgraph.physics: recompile when it changes

from .cells import cell_window  # noqa: E402
from .config import P_H  # noqa: E402
from .physics.kernels import grad_factor  # noqa: E402


@njit(parallel=True, cache=True)
def body_force_rows(bpos, brho, bp, fpos, frho, fp, start, origin, inv_size, dims, axes, reach,
                    prm, kernel, mass_f, mass_b, out):
    """out[i] = sum over fluid a within 2h of body particle i of
    m_a m_b (P_a + P_b)/(rho_a rho_b) F_ab (r_a - r_i), F the kernel gradient factor
    (grad_a W = F r_ai): the force the fluid's pressure puts on particle i. `fpos`.. are the
    fluid rows sorted by the grid's cells (`cells.build_grid`)."""
    dim = bpos.shape[1]
    support2 = 4.0 * prm[P_H] * prm[P_H]
    nf = dims[0]
    nm = dims[1]
    for i in prange(bpos.shape[0]):
        x = bpos[i, 0]
        y = bpos[i, 1]
        z = bpos[i, 2] if dim == 3 else 0.0
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(
            x, y, z, origin[0], origin[1], origin[2], inv_size, dims[0], dims[1], dims[2],
            axes[0], axes[1], axes[2], reach)
        fx = 0.0
        fy = 0.0
        fz = 0.0
        if not empty:
            for c2 in range(lo2, hi2 + 1):
                for c1 in range(lo1, hi1 + 1):
                    row = (c2 * nm + c1) * nf
                    for j in range(start[row + lo0], start[row + hi0 + 1]):
                        dx = fpos[j, 0] - x
                        dy = fpos[j, 1] - y
                        dz = (fpos[j, 2] - z) if dim == 3 else 0.0
                        r2 = dx * dx + dy * dy + dz * dz
                        if r2 >= support2 or r2 <= 1e-24:
                            continue
                        c = (fp[j] + bp[i]) / (frho[j] * brho[i]) * grad_factor(r2, prm, kernel)
                        fx += c * dx
                        fy += c * dy
                        fz += c * dz
        m = mass_f * mass_b
        out[i, 0] = m * fx
        out[i, 1] = m * fy
        if dim == 3:
            out[i, 2] = m * fz
