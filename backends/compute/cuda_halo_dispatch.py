"""Halos on the numba.cuda backend: a received halo made ready for the force tasks
(`prepare_halo`: staged rows binned on the host and uploaded into a pooled device
buffer, or an ipc edge taken as it is, cuda_halo.receive_edge) and the forces of an
ipc halo (`_halo_forces`, the kernels of cuda_halo_kernels)."""
from __future__ import annotations

import numpy as np

from sphgraph.cells import reach_cells
from sphgraph.config import O_DDT, O_KERNEL, O_LAMINAR, P_SUPPORT2

from . import cuda_dufort as CD
from . import cuda_halo as CH
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from . import cuda_riemann as CR
from . import cuda_rjump as CJ
from .cuda_force_dispatch import TRIM_OFF
from .cuda_images import DeviceImages
from .cuda_memory import VEC, count_bytes, dev_array, layout, split


class CudaHaloDispatch:
    """NumbaCUDA's halo receive and ipc halo forces (a mixin, as the others)."""

    def prepare_halo(self, state, halo) -> None:
        """Halo rows to the device, sorted by cell on the host (sphgraph.cells.build_grid):
        every field packed in the pinned staging buffer, one copy into a reusable device
        buffer (`_halo_buffer`) whose typed views are the halo's device arrays."""
        from sphgraph.cells import build_grid
        if isinstance(halo, CH.DeviceEdge):     # --halo-transport ipc: cut and binned on the device
            CH.receive_edge(self, state, halo)
            return
        if isinstance(halo, DeviceImages):      # periodic images: made and binned on the device
            return
        dv = state.extra["dev"]
        dt = dv.dtype
        c = state.consts
        if halo.n == 0:
            halo.cells = None
            halo.press = None
            return
        reach = reach_cells(c.h, c.cell_size)
        grid, perm = build_grid(np.asarray(halo.pos, np.float64), c.cell_size, reach, state.axes)
        halo.pos, halo.vel = halo.pos[perm], halo.vel[perm]
        halo.rho, halo.kind = halo.rho[perm], halo.kind[perm]
        halo.order = perm            # mdbc_halo: the sender's edge row of each binned row
        m, dim = halo.n, dv.dim
        names = ["r" + ax for ax in VEC[:dim]] + ["v" + ax for ax in VEC[:dim]] + ["rho"]
        lay, nb = layout([("start", grid.start.dtype, grid.start.shape[0]), ("kind", np.int8, m)] +
                          [(key, dt, m) for key in names])
        hb = dv.host_buf(nb)
        h = split(hb, lay)
        h["start"][:] = grid.start
        for i in range(dim):
            h["r" + VEC[i]][:] = halo.pos[:, i] - dv.ref[i]
            h["v" + VEC[i]][:] = halo.vel[:, i]
        h["rho"][:] = halo.rho
        h["kind"][:] = halo.kind
        poff = -(-nb // 8) * 8                   # the pressures (computed on the device) after the upload
        buf = self._halo_buffer(state, dv, halo, poff + m * dt.itemsize)
        s = self._s(state)
        self._copy_mark(state, "halo_h2d", True)
        buf[:nb].copy_to_device(hb, stream=s)        # a lane stream: asynchronous (pinned)
        dv.mark_host_busy(s)
        dd = split(buf, lay)
        dd["press"] = buf[poff:poff + m * dt.itemsize].view(dt)
        for ax in VEC[dim:]:                    # 2D: one-element dummies (never read)
            dd["r" + ax] = dd["v" + ax] = dv.arrays["az"]
        self._k(state).k_pressure[CK.blocks(m), CK.BLOCK](dd["rho"], m, dv.prm_d(state), dd["press"])
        self._copy_mark(state, "halo_h2d", False)
        halo.press = dd
        halo.cells = grid
        count_bytes(state, "h2d_bytes", "halo", nb)

    def _halo_buffer(self, state, dv, halo, nbytes):
        """A device buffer of >= nbytes for `halo`, from a pool: a buffer is reused once its
        last halo is neither in state.halos nor the one prepared just before (received
        but not yet stored), so a halo's device arrays live as long as any task can read
        it; with two neighbours the pool settles at three buffers. With lanes, a reused
        buffer was last read by a halo force task of an earlier stage, on the compute
        lane: the task graph orders it before the receive of its own halo side only, so
        the buffer carries an event recorded at the end of each task that read it
        (`_read_halo`, lane_end) and the receive that reuses it waits for that event."""
        live = [h for h in state.halos.values() if h is not None] + [dv.halo_last]
        free = [e for e in dv.halo_pool if not any(e["owner"] is h for h in live)]
        fit = [e for e in free if e["buf"].shape[0] >= nbytes]
        if fit:
            e = fit[0]
        elif free:
            e = free[0]
            e["buf"] = dev_array(int(nbytes * 1.25) + 4096, np.uint8)
        else:
            e = {"buf": dev_array(int(nbytes * 1.25) + 4096, np.uint8)}
            dv.halo_pool.append(e)
        ev = e.get("read_ev")
        s = self._s(state)
        if ev is not None and s:
            ev.wait(s)
            self._log(state, "wait_buffer", "halo", id(e))
        e["owner"] = dv.halo_last = halo
        return e["buf"][:nbytes]

    def _read_halo(self, state, dv, halo):
        """The running task reads `halo`'s pooled device buffer: lane_end records the
        buffer's read event after the task (see _halo_buffer)."""
        L = self.lanes.get(state.rank)
        if L is None or L.current is None:
            return
        e = next((e for e in dv.halo_pool if e["owner"] is halo), None)
        if e is not None and all(x is not e for x in L.read):
            L.read.append(e)

    def _halo_forces(self, state, dv, part, halo) -> None:
        """Forces of an ipc halo (cuda_halo): the rank's own rows within reach of that cut
        (its edge ranges towards the sender) against the halo's rows and grid, into the
        part's buffer at those rows (k_reduce_ranged adds them there only)."""
        side = int(part[-1])
        if halo.views is None or not halo.m or not dv.n:
            dv.parts.pop(part, None)
            dv.halo_ranges.pop(side, None)
            return
        d = -1 if side == 1 else 1
        _, _, fb, bb = CH.edge_ranges(self, state, dv, dv.domain)[d]
        ro = 0 if d < 0 else 4         # the targets' exact ranges in pick8 (a0, b0, a1, b1)
        buf = dv.part_buffer(part, max(dv.n, dv.cap, 1))
        dv.halo_ranges[side] = ro
        A = dv.arrays
        axes = dv.grid["axes"]
        ft = dv.dtype.type
        inv = 1.0 / halo.size
        rel = [float(halo.origin[k]) - float(dv.ref[axes[k]]) if axes[k] >= 0 else 0.0 for k in range(3)]
        span = max([abs(x) for x in rel] + [float(halo.dims[k]) * halo.size for k in range(3)])
        eps = 16 * np.finfo(dv.dtype).eps * span
        pad = np.sqrt(state.prm[P_SUPPORT2]) * (1 + 1e-6) + eps
        tpad = 2.0 * halo.moved * (1 + 1e-6) + eps
        tpad = TRIM_OFF if not np.isfinite(tpad) or tpad > TRIM_OFF else tpad
        gvec = np.zeros(3)
        gvec[:dv.dim] = state.consts.gravity
        v = halo.views
        args = (v["pos4"], v["vel4"], v["kind"], v["start"], int(halo.ncells), ft(rel[0]), ft(rel[1]), ft(rel[2]), ft(inv),
                ft(pad), ft(tpad), int(halo.dims[0]), int(halo.dims[1]), int(halo.dims[2]),
                int(axes[0]), int(axes[1]), int(axes[2]), ft(gvec[0]), ft(gvec[1]), ft(gvec[2]),
                buf["x"], buf["y"], buf["z"], buf["ar"], buf["ddt"], buf["cancel"], A["visc"])
        dfa = CD.ddk_out(self, state, dv, part, False)      # K_a out (the DuFort-Frankel step), else ()
        jma = CJ.jm_out(self, state, dv, part, False)       # the jump's moments (cuda_rjump), else ()
        kf = self._on(state, (CD.halo_force_kernels if dfa else CJ.halo_force_kernels if jma else
                              CR.halo_force_kernels if CR.enabled(state) else HK.force_kernels)(
            dv.dtype, state.prm, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR])))
        FB = CK.FORCE_BLOCK
        if fb:
            kf.k_halo_fv[CK.blocks(fb, FB), FB](A["pos4"], A["vel4"], A["pick8"], ro, *args, *dfa, *jma)
        if bb:
            kf.k_halo_bv[CK.blocks(bb, FB), FB](A["pos4"], A["vel4"], A["pick8"], ro + 2, *args)
        dv.final = False
        self._sync()
