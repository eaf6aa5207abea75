"""numba.cuda kernels of particle shifting (sphgraph.shifting), as backends/compute/
cpu_shifting.py: a neighbour pass apart from the force kernels, on the same device grids.

`CudaShifting` holds the three backend methods (`shift_part`, `shift_displacement`,
`shift_apply`) that sphgraph.shifting calls; `NumbaCUDA` gets them by inheriting it.
Kernels are written as plain functions and retargeted per float type by
`cuda_kernels.kernel` (float literals of the run's type, @njit physics as device code).

Buffers (device, counted in DeviceState.nbytes): per source set gx, gy, (gz), div and
cancel. The interior's buffers also hold the sum: at `shift_displacement` the halo and
image parts are added to them in the fixed order of SHIFT_PARTS (as the CPU sums), then
they are turned into the displacement in place. One rank: one set of 3-4 floats and a
byte per row, allocated only in runs that shift.
"""
import math
import types

import numpy as np
from numba import cuda

from sphgraph.config import O_KERNEL
from sphgraph.physics.shifting import clamp, shift_row, shift_scale

from . import cuda_kernels as CK
from .base import SHIFT_PARTS
from .cuda_halo import DeviceEdge



# ------------------------------------------------------------------------------- kernels
def k_shift_sums(dpx, dpy, dpz, drx_, dry_, drz_, dkind, n,
                 spx, spy, spz, ps, po1, po2, sr, rs, ro, skind, start, split,
                 o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
                 prm, dim, kernel_id, mode, gx_, gy_, gz_, div_, cancel_):
    """The per-row sums of sphgraph.physics.shifting.shift_row for fluid row i: cells
    from the float64 position (dpx..), distances from the run-type positions relative to
    the rank's reference (drx_..). Sources as shift_row reads them: the rank's own rows
    in one array per axis (kind-split grid, `split` = its fluid cells), a staged halo
    likewise (plain grid, split 0), an ipc halo as the sender's records (pos4 = x, y,
    z, p and vel4 = vx, vy, vz, rho: stride 4)."""
    i = cuda.grid(1)
    if i >= n:
        return
    zero = drx_[i] - drx_[i]
    gx = zero
    gy = zero
    gz = zero
    dv = zero
    cc = 0
    if dkind[i] == 0:
        # the z terms are read before the call: numba cannot type a call of more than 30
        # arguments (CPython passes them as a tuple, CALL_FUNCTION_EX) with a conditional
        # expression among them
        pz = 0.0
        rz = zero
        if dim == 3:
            pz = dpz[i]
            rz = drz_[i]
        gx, gy, gz, dv, cc = shift_row(dpx[i], dpy[i], pz, drx_[i], dry_[i], rz,
                                       spx, spy, spz, ps, po1, po2, sr, rs, ro, skind, start, split,
                                       o0, o1, o2, inv_size, n0, n1, n2, a0, a1, a2, reach,
                                       prm, dim, kernel_id, mode)
    gx_[i] = gx
    gy_[i] = gy
    if dim == 3:
        gz_[i] = gz
    div_[i] = dv
    cancel_[i] = cc


def k_shift_add_part(n, dim, gx, gy, gz, dv, cc, sx, sy, sz, sd, sc):
    """Sum buffers (the interior's) += one more part."""
    i = cuda.grid(1)
    if i >= n:
        return
    sx[i] += gx[i]
    sy[i] += gy[i]
    if dim == 3:
        sz[i] += gz[i]
    sd[i] += dv[i]
    sc[i] |= cc[i]


def k_shift_final(n, dim, kind, vx, vy, vz, coefumagn, tfs, coeftfs, maxdist, sx, sy, sz, sd, sc):
    """The summed grad C (sx, sy, sz) becomes the displacement in place (cpu_shifting.shift_reduce)."""
    i = cuda.grid(1)
    if i >= n:
        return
    zero = sd[i] - sd[i]
    if kind[i] != 0 or sc[i] != 0:
        sx[i] = zero
        sy[i] = zero
        if dim == 3:
            sz[i] = zero
        return
    v2 = vx[i] * vx[i] + vy[i] * vy[i]
    if dim == 3:
        v2 += vz[i] * vz[i]
    u = shift_scale(math.sqrt(v2), sd[i], coefumagn, tfs, coeftfs)
    sx[i] = clamp(sx[i] * u, maxdist)
    sy[i] = clamp(sy[i] * u, maxdist)
    if dim == 3:
        sz[i] = clamp(sz[i] * u, maxdist)


def k_shift_move(n, dim, px, py, pz, sx, sy, sz):
    """Float64 positions += displacement (after the position update)."""
    i = cuda.grid(1)
    if i >= n:
        return
    px[i] += sx[i]
    py[i] += sy[i]
    if dim == 3:
        pz[i] += sz[i]


_KERNELS = ("k_shift_sums", "k_shift_add_part", "k_shift_final", "k_shift_move")


def build(dtype) -> types.SimpleNamespace:
    """The shifting kernels for float type `dtype` (cached)."""
    return CK.kernel_set(globals(), _KERNELS, dtype)


# ------------------------------------------------------------------------------- backend methods
class CudaShifting:
    """Particle shifting on the device (mixed into NumbaCUDA; launches and copies on the
    running task's lane stream, `NumbaCUDA._on` / `_s`)."""

    def _shift_bufs(self, dv, part):
        """gx, gy, gz, div, cancel of `part` in dv.arrays, of the rows' capacity (dv.n may
        grow up to dv.cap when rows arrive); allocated on first use."""
        names = [f"sh_{part}_{c}" for c in ("gx", "gy", "gz", "div", "cc")]
        if names[0] not in dv.arrays or dv.arrays[names[0]].shape[0] < dv.n:
            m = max(dv.n, dv.cap, 1)
            for c, name in enumerate(names):
                size = 1 if (c == 2 and dv.dim == 2) else m
                dv.arrays[name] = cuda.device_array(size, np.int8 if c == 4 else dv.dtype)
        return [dv.arrays[x] for x in names]

    def shift_part(self, state, part: str, mode: int) -> None:
        dv = state.extra["dev"]
        n = dv.n
        A = dv.A()
        if part == "interior":
            g = dv.grid
            src = (A["rx"], A["ry"], A["rz"], 1, 0, 0, A["rho"], 1, 0, A["kind"])
            start, split = A["start"], int(g["ncells"])
            origin, inv, dims, axes, reach = g["origin"], g["inv"], g["dims"], g["axes"], g["reach"]
        else:
            halo = state.halos.get(int(part[-1]))
            if isinstance(halo, DeviceEdge):   # ipc: the sender's sorted rows, its kind-split grid
                if halo.views is None:         # empty halo: contributes nothing
                    return
                v = halo.views
                src = (v["pos4"], v["pos4"], v["pos4"], 4, 1, 2, v["vel4"], 4, 3, v["kind"])
                start, split = v["start"], int(halo.ncells)
                g = dv.grid
                origin, inv, dims, axes = halo.origin, 1.0 / halo.size, halo.dims, g["axes"]
                reach = g["reach"] + (1 if halo.moved > 0 else 0)   # rows moved since the sender's sort
            else:
                if halo is None or halo.cells is None:   # empty halo: contributes nothing
                    return
                hd, gr = halo.press, halo.cells
                src = (hd["rx"], hd["ry"], hd["rz"], 1, 0, 0, hd["rho"], 1, 0, hd["kind"])
                start, split = hd["start"], 0
                origin, inv, dims, axes, reach = gr.origin, 1.0 / gr.size, gr.dims, gr.axes, gr.reach
        out = self._shift_bufs(dv, part)
        if n:
            self._on(state, build(dv.dtype)).k_shift_sums[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
                A["px"], A["py"], A["pz"], A["rx"], A["ry"], A["rz"], A["kind"], n, *src, start, split,
                float(origin[0]), float(origin[1]), float(origin[2]), float(inv),
                int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), int(reach),
                dv.prm_d(state), dv.dim, int(state.opt[O_KERNEL]), int(mode), *out)
        state.extra.setdefault("shift_done", set()).add(part)
        self._sync()

    def shift_displacement(self, state, coefumagn, tfs, coeftfs, maxdist) -> None:
        dv = state.extra["dev"]
        k = self._on(state, build(dv.dtype))
        n, dim = dv.n, dv.dim
        A = dv.A()
        done = state.extra.pop("shift_done", set())
        S = self._shift_bufs(dv, "interior")
        if "interior" not in done:   # no sums this step: no shift
            for a in S:
                a.copy_to_device(np.zeros(a.shape[0], a.dtype), stream=self._s(state))
        for part in SHIFT_PARTS[1:]:
            if part in done and n:
                k.k_shift_add_part[CK.blocks(n), CK.BLOCK](n, dim, *self._shift_bufs(dv, part), *S)
        ft = dv.dtype.type
        if n:
            k.k_shift_final[CK.blocks(n), CK.BLOCK](n, dim, A["kind"], A["vx"], A["vy"], A["vz"], ft(coefumagn),
                                                    ft(tfs), ft(coeftfs), ft(maxdist), *S)
        self._sync()

    def shift_apply(self, state) -> None:
        dv = state.extra["dev"]
        n = dv.n
        if n:
            sx, sy, sz = self._shift_bufs(dv, "interior")[:3]
            A = dv.A()
            k = self._on(state, build(dv.dtype))
            k.k_shift_move[CK.blocks(n), CK.BLOCK](n, dv.dim, A["px"], A["py"], A["pz"], sx, sy, sz)
        dv.host_stale = True
        dv.moved = np.inf          # shifted rows: the force rows are not trimmed until the next sort
        self._sync()
