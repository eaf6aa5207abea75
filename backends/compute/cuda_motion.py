"""Moving bodies ([[motion]], sphgraph.motion) on the device, for the numba.cuda backend.

The bodies' positions and velocities at a time are the host's `Motion.table` (the motion's
maths is written once, in sphgraph.motion, for every backend): one table over every moving
particle, in id order, uploaded each stage (two floats per axis a moving particle: a paddle
or a gate is a small share of the rows) and put on the rank's rows by id by one kernel, which
finds a row's slot in the table through a device map id -> slot built once. A rank's rows
are sorted and migrate on the device, so the kernel, not the host, knows which moving
particles the rank holds.

Between a step's force stages (the Symplectic predictor's end) the corrector's forces read
the pos4 records packed by the integrator, so the kernel writes the moved rows' records too;
and the cells' trim slack (`dv.moved`) no longer bounds how far a row went since the sort.

Buffers (allocated on the first call of a rank, kept): the map, the table in float64
(positions) and the run's type (velocities), and two pinned host copies used in turn, so the
host fills one while the other's copy may still be in flight.
"""
from __future__ import annotations

import types

import numpy as np
from numba import cuda

from sphgraph.particles import MOVING

from . import cuda_kernels as CK
from .cuda_memory import count_bytes, dev_array, pinned_array


def k_set_moving(n, dim, kind, ids, slot, nslot, tpos, tvel, px, py, pz, vel4,
                 ref0, ref1, ref2, with_pos4, pos4):
    """Rows of kind MOVING take their table entry (slot[id]): position, velocity, and with
    `with_pos4` their pos4 position (x - ref, as k_pack writes it)."""
    i = cuda.grid(1)
    if i >= n:
        return
    if kind[i] != MOVING:
        return
    q = ids[i]
    if q >= nslot:
        return
    k = slot[q]
    if k < 0:
        return
    b = dim * k
    px[i] = tpos[b]
    py[i] = tpos[b + 1]
    vel4[4 * i] = tvel[b]
    vel4[4 * i + 1] = tvel[b + 1]
    if dim == 3:
        pz[i] = tpos[b + 2]
        vel4[4 * i + 2] = tvel[b + 2]
    if with_pos4:
        pos4[4 * i] = px[i] - ref0
        pos4[4 * i + 1] = py[i] - ref1
        if dim == 3:
            pos4[4 * i + 2] = pz[i] - ref2


_KERNELS = ("k_set_moving",)


def build(dtype) -> types.SimpleNamespace:
    """The motion kernel for float type `dtype` (cached)."""
    return CK.kernel_set(globals(), _KERNELS, dtype)


class _MotionBuffers:
    """One rank's device map id -> slot, device table and pinned host tables."""

    def __init__(self, motion, dim, dtype):
        m = len(motion.ids)
        nslot = int(motion.ids.max()) + 1 if m else 1
        slot = np.full(nslot, -1, np.int32)
        slot[motion.ids] = np.arange(m, dtype=np.int32)
        self.motion = motion
        self.nslot = nslot
        self.slot = dev_array(nslot, np.int32)
        self.slot.copy_to_device(slot)
        self.tpos = dev_array(max(m * dim, 1), np.float64)
        self.tvel = dev_array(max(m * dim, 1), dtype)
        self.host = [(pinned_array(max(m * dim, 1), np.float64), pinned_array(max(m * dim, 1), dtype))
                     for _ in range(2)]
        self.turn = 0


class CudaMotion:
    """`move_bodies` on the device (mixed into NumbaCUDA; launches and copies on the running
    task's lane stream, `NumbaCUDA._on` / `_s`)."""

    def move_bodies(self, state, motion, t: float, mid_step: bool) -> None:
        dv = state.extra["dev"]
        buf = state.extra.get("motion_dev")
        if buf is None or buf.motion is not motion:
            buf = state.extra["motion_dev"] = _MotionBuffers(motion, dv.dim, dv.dtype)
        pos, vel = motion.table(t)
        hp, hv = buf.host[buf.turn]
        buf.turn ^= 1
        m = pos.size
        hp[:m] = pos.ravel()
        hv[:m] = vel.ravel()
        s = self._s(state)
        buf.tpos[:max(m, 1)].copy_to_device(hp[:max(m, 1)], stream=s)
        buf.tvel[:max(m, 1)].copy_to_device(hv[:max(m, 1)], stream=s)
        count_bytes(state, "h2d_bytes", "motion", hp[:m].nbytes + hv[:m].nbytes)
        if not dv.n:
            return
        ref = np.zeros(3)
        ref[:dv.dim] = dv.ref
        A = dv.A()
        k = self._on(state, build(dv.dtype))
        k.k_set_moving[CK.blocks(dv.n), CK.BLOCK](dv.n, dv.dim, A["kind"], A["id"], buf.slot, buf.nslot,
                                                  buf.tpos, buf.tvel, A["px"], A["py"], A["pz"], A["vel4"],
                                                  float(ref[0]), float(ref[1]), float(ref[2]), bool(mid_step),
                                                  A["pos4"])
        if mid_step:
            dv.moved = np.inf
        dv.host_stale = True
