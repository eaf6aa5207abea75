"""Smoothing kernels: W(r) and the gradient factor F with grad W = F * (r_a - r_b).

Plain `@njit` functions, so the CPU drivers and numba.cuda device code share them.
Constants (normalisation aw, gradient factor bw) come from `sphgraph.config.derive`.

Wendland C2 (Wendland 1995), q = r/h in [0, 2]:
    W = aw (1 - q/2)^4 (2q + 1),  aw = 7/(4 pi h^2) in 2D, 21/(16 pi h^3) in 3D
    dW/dr = bw q (1 - q/2)^3,      bw = -5 aw / h
    (DualSPHysics JSphCpu::GetKernelWendland: fac = Bwen*qq*wqq1^3/rad)
Cubic spline (Monaghan & Lattanzio 1985):
    W = aw (1 - 1.5 q^2 + 0.75 q^3) for q < 1, aw/4 (2 - q)^3 for 1 <= q < 2
    aw = 10/(7 pi h^2) in 2D, 1/(pi h^3) in 3D; bw = aw/h
    (DualSPHysics GetKernelCubic: c1 = -3 bw, d1 = 9/4 bw, c2 = -3/4 bw)
"""
import math

from numba import njit

from ..config import P_AW, P_BWH, P_H, P_INV_H, K_WENDLAND


@njit(inline="always", cache=True)
def kernel_w(r, prm, kernel):
    """W(r) for the kernel id `kernel` (0 Wendland, 1 cubic spline)."""
    q = r / prm[P_H]
    if q >= 2.0:
        return 0.0 * q
    if kernel == K_WENDLAND:
        w = 1.0 - 0.5 * q
        return prm[P_AW] * w * w * w * w * (2.0 * q + 1.0)
    if q < 1.0:
        return prm[P_AW] * (1.0 - 1.5 * q * q + 0.75 * q * q * q)
    w = 2.0 - q
    return 0.25 * prm[P_AW] * w * w * w


@njit(inline="always", cache=True)
def grad_factor(r2, prm, kernel):
    """F such that grad_a W_ab = F * (r_a - r_b), for 0 < r <= 2h.

    Written with q/r = 1/h (prm[P_BWH] = bw/h) so the hot path has no division.
    """
    if kernel == K_WENDLAND:
        # bw/h (1 - q/2)^3 = k8 (2h - r)^3, k8 = bw/h / (2h)^3: one subtraction of a
        # constant (2h and k8 fold to constants on the GPU), where 1 - r (0.5/h) takes a
        # multiply-add and a register for its second constant. k8 ~ h^-8 overflows float32
        # for h below ~3e-5: there (a test of constants, folded) the other form
        k8 = prm[P_BWH] * (0.125 * prm[P_INV_H] * prm[P_INV_H] * prm[P_INV_H])
        if abs(k8) < 1e30:
            w = 2.0 * prm[P_H] - math.sqrt(r2)
            return k8 * w * w * w
        w = 1.0 - math.sqrt(r2) * (0.5 * prm[P_INV_H])
        return prm[P_BWH] * w * w * w
    q = math.sqrt(r2) * prm[P_INV_H]
    if q < 1.0:
        return prm[P_BWH] * (-3.0 + 2.25 * q)
    w = 2.0 - q
    return prm[P_BWH] * (-0.75 * w * w) / q
