"""Particle shifting (Lind et al. 2012, in DualSPHysics' form): the pair sums and the shift.

Lind, Xu, Stansby & Rogers (2012), J. Comput. Phys. 231: particles move down the
gradient of the particle concentration C (Fick's law),

    dr_a = -D grad C_a,   D = A h |v_a| dt,   grad C_a = sum_b V_b grad_a W_ab,  V_b = m_b/rho_b.

DualSPHysics (v5, JSphCpu::InteractionForcesFluid "Shifting correction" and
JSphShifting::RunCpu / JSphShifting_ker.cu) sums, per fluid particle a and neighbour b,

    shiftposfs.xyz += V_b grad_a W_ab                  (grad C)
    shiftposfs.w   -= V_b r_ab . grad_a W_ab           (div r, ~dim inside the fluid)

and then sets dr = ShiftCoef h |v| dt grad C (ShiftCoef = -2 by default: A = 2), each
component clamped to +-0.1 dp. With a free-surface threshold ShiftTFS > 0 the shift is
zero where div r < ShiftTFS and scaled by (div r - ShiftTFS)/(dim - ShiftTFS) above it,
so particles at the surface (truncated kernel support) are not pushed out of the fluid.

Plain @njit functions: the numba CPU kernels and the numba.cuda kernels share them.
"""
from numba import njit

from sphgraph.cells import cell_window
from sphgraph.config import P_MASS_B, P_MASS_F, P_SUPPORT2
from sphgraph.particles import FIXED

from .kernels import grad_factor

NOBOUND, NOFIXED = 1, 2   # mode ids = index in sphgraph.config.SHIFTINGS (DualSPHysics TpShifting)


@njit(inline="always", cache=True)
def shift_pair(drx, dry, drz, r2, vol_b, prm, kernel):
    """What b (volume V_b = m_b/rho_b, r_ab = (drx, dry, drz), r2 = |r_ab|^2 > 0)
    adds to a's concentration gradient and position divergence: (gx, gy, gz, div)."""
    f = vol_b * grad_factor(r2, prm, kernel)   # grad_a W_ab = F r_ab, so r_ab . grad W = F r2
    return f * drx, f * dry, f * drz, -f * r2


@njit(inline="always", cache=True)
def shift_scale(speed, div, coefumagn, tfs, coeftfs):
    """dr = scale * grad C (before the clamp): coefumagn = ShiftCoef h dt, coeftfs = dim - tfs
    (DualSPHysics JSphShifting::RunCpu: umagn = coefumagn |v|, free-surface factor)."""
    u = coefumagn * speed
    if tfs > 0.0:
        if div < tfs:
            u = 0.0 * u
        else:
            u *= (div - tfs) / coeftfs
    return u


@njit(inline="always", cache=True)
def clamp(x, m):
    """x limited to [-m, m] (DualSPHysics: max shifting distance 0.1 dp per component)."""
    if x > m:
        return m
    if x < -m:
        return -m
    return x


@njit(cache=True)   # a call, not inlined: numba cannot inline it into the prange loop
def shift_row(cx, cy, cz, xa, ya, za, spx, spy, spz, ps, po1, po2, sr, rs, ro, skind, start, split,
              o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach, prm, dim, kernel, mode):
    """One fluid row's sums against one source set binned in a grid: (gx, gy, gz, div,
    cancel). The row's cells come from (cx, cy, cz), its distances from (xa, ya, za) (the
    same point; the GPU finds cells from float64 positions and measures distances in the
    run's type). Source j is at spx[ps j], spy[ps j + po1], spz[ps j + po2] with density
    sr[rs j + ro] and kind skind[j]: one flat (n, dim) array thrice on the CPU, one array
    per axis or the halo records on the GPU. `split` > 0: a kind-split grid (fluid cells,
    then boundary cells from start[split]).

    A boundary neighbour cancels the shift in mode "nobound", a fixed one in "nofixed"
    (DualSPHysics: noshift = boundp2 && (NoBound || (NoFixed && fixed))); "full" sums
    boundary neighbours like fluid ones."""
    support2 = prm[P_SUPPORT2]
    mf = prm[P_MASS_F]
    mb = prm[P_MASS_B]
    zero = xa - xa
    gx = zero
    gy = zero
    gz = zero
    dv = zero
    cc = 0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(cx, cy, cz, o0, o1, o2, inv_size, n0, n1, n2,
                                                      a0, a1, a2, reach)
    if empty:
        return gx, gy, gz, dv, cc
    nsets = 2 if split > 0 else 1
    for c2 in range(lo2, hi2 + 1):
        for c1 in range(lo1, hi1 + 1):
            row = (c2 * n1 + c1) * n0
            for s in range(nsets):
                off = s * split
                for j in range(start[off + row + lo0], start[off + row + hi0 + 1]):
                    q = ps * j
                    drx = xa - spx[q]
                    dry = ya - spy[q + po1]
                    drz = (za - spz[q + po2]) if dim == 3 else zero
                    r2 = drx * drx + dry * dry + drz * drz
                    if r2 > support2 or r2 < 1e-18:
                        continue
                    kb = skind[j]
                    if kb != 0 and (mode == NOBOUND or (mode == NOFIXED and kb == FIXED)):
                        cc = 1
                        continue
                    fx, fy, fz, fd = shift_pair(drx, dry, drz, r2, (mb if kb != 0 else mf) / sr[rs * j + ro],
                                                prm, kernel)
                    gx += fx
                    gy += fy
                    gz += fz
                    dv += fd
    return gx, gy, gz, dv, cc
