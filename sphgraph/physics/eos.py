"""Tait equation of state (Monaghan 1994; DualSPHysics JSphCpu::ComputePress):

    P = B [ (rho / rho0)^gamma - 1 ],  B = c0^2 rho0 / gamma
"""
import numpy as np
from numba import njit, prange

from ..config import P_B, P_GAMMA, P_RHO0


@njit(inline="always", cache=True)
def tait(rho, prm):
    x = rho / prm[P_RHO0]
    if prm[P_GAMMA] == 7.0:  # the usual case: multiplications, not pow()
        x2 = x * x
        return prm[P_B] * (x2 * x2 * x2 * x - 1.0)
    return prm[P_B] * (x ** prm[P_GAMMA] - 1.0)


@njit(parallel=True, cache=True)
def pressure_into(rho, prm, out):
    for i in prange(rho.shape[0]):
        out[i] = tait(rho[i], prm)


def pressure(rho, prm):
    out = np.empty_like(rho)
    pressure_into(rho, prm.astype(rho.dtype), out)
    return out
