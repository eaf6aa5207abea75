"""The per-row maths of periodic wrapping, written once for the host (sphgraph.periodic, through
ComputeBackend.wrap_periodic) and the device (backends/compute/cuda_integrate.k_wrap)."""
from __future__ import annotations

from numba import njit


@njit(inline="always", cache=True)
def wrap_axis(x, lo, hi, period):
    """x brought into [lo, hi), hi = lo + period: x itself when inside (a row that did not
    cross keeps its bits), else lo + (x - lo) mod period. The remainder by whole periods:
    for a row less than a period outside, as any row is after one step, each subtraction
    is exact (Sterbenz), as numpy's fmod-based mod is."""
    if x >= lo and x < hi:
        return x
    r = x - lo
    while r >= period:
        r -= period
    while r < 0.0:
        r += period
    return lo + r


@njit(cache=True)
def wrap_rows(pos, lo, hi, period, axes):
    """`wrap_axis` over the rows of `pos` [n, dim] along each axis in `axes`."""
    for a in axes:
        for i in range(pos.shape[0]):
            pos[i, a] = wrap_axis(pos[i, a], lo[a], hi[a], period[a])
