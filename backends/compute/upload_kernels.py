"""Host-side numba kernels of the numba-cuda upload (`cuda_upload.prepare`): the row arrays
go to the device through a reusable staging buffer a chunk of rows at a time, each chunk
filled by all cores in the device's type and layout. Single-threaded numpy took ~0.12 s per
million rows (column copies of the (n, dim) positions, the (v, rho) records, the casts, two
minima and a maximum over the positions): 130 s of the 835.8 M-particle SPHERIC 2 set-up.

The values are numpy's to the bit: the same IEEE casts, minima and maxima (NaN propagates,
as in ndarray.min / max).
"""
import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def column_bounds(pos, lo, hi):
    """lo[d], hi[d] = min / max of pos[:, d] (NaN if the column holds one), in parallel
    over blocks of rows; pos has at least one row."""
    n, dim = pos.shape
    nb = min(n, 256)
    step = (n + nb - 1) // nb
    plo = np.empty((nb, dim))
    phi = np.empty((nb, dim))
    for b in prange(nb):
        a = b * step
        e = min(n, a + step)
        for d in range(dim):
            mn = np.inf
            mx = -np.inf
            nan = False
            for i in range(a, e):
                x = pos[i, d]
                if x != x:
                    nan = True
                elif x < mn:
                    mn = x
                if x > mx:
                    mx = x
            if a >= e:          # an empty block (n < nb * step): neutral
                mn = np.inf
                mx = -np.inf
            plo[b, d] = np.nan if nan else mn
            phi[b, d] = np.nan if nan else mx
    for d in range(dim):
        mn = np.inf
        mx = -np.inf
        for b in range(nb):
            if plo[b, d] != plo[b, d]:
                mn = np.nan
                mx = np.nan
                break
            mn = min(mn, plo[b, d])
            mx = max(mx, phi[b, d])
        lo[d] = mn
        hi[d] = mx


@njit(parallel=True, cache=True)
def column_into(src, d, a, out):
    """out[k] = src[a + k, d] in out's type, k < len(out)."""
    for k in prange(out.shape[0]):
        out[k] = src[a + k, d]


@njit(parallel=True, cache=True)
def flat_into(src, a, out):
    """out[k] = src[a + k] in out's type, k < len(out)."""
    for k in prange(out.shape[0]):
        out[k] = src[a + k]


@njit(parallel=True, cache=True)
def records_into(vel, rho, a, out):
    """(vx, vy, vz, rho) records of rows a.. into out (4 a row; vz = 0 in 2D)."""
    dim = vel.shape[1]
    for k in prange(out.shape[0] // 4):
        i = a + k
        out[4 * k + 2] = 0.0
        for d in range(dim):
            out[4 * k + d] = vel[i, d]
        out[4 * k + 3] = rho[i]


@njit(parallel=True, cache=True)
def int_max(x):
    """The largest element of the non-empty integer array x."""
    n = x.shape[0]
    nb = min(n, 256)
    step = (n + nb - 1) // nb
    part = np.empty(nb, np.int64)
    for b in prange(nb):
        m = x[min(b * step, n - 1)]
        for i in range(b * step, min(n, (b + 1) * step)):
            if x[i] > m:
                m = x[i]
        part[b] = m
    return part.max()
