"""The per-row maths of velocity relaxation zones (`[[damping]]`, sphgraph.waves.Damping),
written once for the host (ComputeBackend.damp) and the device (cuda_integrate.k_damp).

A zone (axis, start a, end b, overlimit, redumax) multiplies a fluid row's velocity by
max(0, 1 - dt redumax s^2), s = min((x - a) / (b - a), 1), where 0 < s and the row lies no
more than `overlimit` past the end; zones compound (DualSPHysics' RelaxZone damping).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

ZONE = 5      # numbers a zone: axis, start, end, overlimit, redumax


def zone_table(zones) -> np.ndarray:
    """The zones as a flat float64 table, ZONE numbers each."""
    return np.asarray([float(x) for z in zones for x in z], np.float64)


@njit(inline="always", cache=True)
def damping_factor(x0, x1, x2, zones, nz, dt):
    """Multiplier of a row's velocity at (x0, x1, x2) (1 outside every zone)."""
    f = 1.0
    for k in range(nz):
        ax = int(zones[ZONE * k])
        a = zones[ZONE * k + 1]
        b = zones[ZONE * k + 2]
        x = x0 if ax == 0 else (x1 if ax == 1 else x2)
        s = (x - a) / (b - a)
        beyond = (x - b) * math.copysign(1.0, b - a)
        if s > 0.0 and beyond <= zones[ZONE * k + 3]:
            fd = min(s, 1.0)
            f *= max(0.0, 1.0 - dt * zones[ZONE * k + 4] * fd * fd)
    return f


@njit(cache=True)
def damping_factors(pos, zones, dt, out):
    """`damping_factor` of each row of `pos` [n, dim] into out[n]."""
    dim = pos.shape[1]
    nz = len(zones) // ZONE
    for i in range(pos.shape[0]):
        out[i] = damping_factor(pos[i, 0], pos[i, 1], pos[i, 2] if dim == 3 else 0.0, zones, nz, dt)
