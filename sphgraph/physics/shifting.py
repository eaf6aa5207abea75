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

from .kernels import grad_factor


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
