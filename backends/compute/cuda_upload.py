"""Host rows to the device and back, for the numba.cuda backend: the upload (`prepare`),
the host copy brought up to the device rows (`sync_host`, `host_arrays`).

Device data of a rank live in `state.extra["dev"]` (a cuda_memory.DeviceState); the host
`state.particles` is brought up to date only when asked (`host_arrays` for frames,
`sync_host` for the comm layer, a failed check). Per step, what crosses the bus is
the dt terms (3 float64), the check result with the rows' bounding box (8 numbers),
and, with several ranks, halos and displaced rows; the counters are
`state.extra["h2d_bytes"]` / `["d2h_bytes"]` (cumulative) and `["bytes_by_kind"]`.
"""
from __future__ import annotations

import numpy as np

from . import upload_kernels as UK
from .cuda_memory import VEC, DeviceState, count_bytes, dev_array

UPLOAD_ROWS = 1 << 23    # rows a chunk of the upload (prepare): a 256 MiB staging buffer


class CudaUpload:
    """NumbaCUDA's upload and host copies (a mixin: NumbaCUDA supplies the rest)."""

    def prepare(self, state) -> None:
        """Upload the host particles (all of them: called at set-up and after rows moved)."""
        p = state.particles
        dim = p.dim
        dt = np.dtype(state.dtype)
        old = state.extra.get("dev")
        if old is not None and old.host_obj is p and old.n == p.n:
            return   # same host row set as on the device (no rows left or came): keep the device rows
        lo = hi = None
        if p.n:     # the rows' bounding box (the first grid), one parallel pass (upload_kernels)
            lo, hi = np.empty(dim), np.empty(dim)
            UK.column_bounds(p.pos, lo, hi)
        # the reference point of the float positions: the run's (every rank the same, so a
        # rank's records are valid on its neighbours: ipc halos), else the rows' minimum
        if old is not None:
            ref = old.ref
        elif state.ref is not None:
            ref = np.asarray(state.ref, np.float64).copy()
        else:
            ref = lo.copy() if p.n else np.zeros(dim)
        dv = DeviceState(p.n, dim, dt, ref)
        dv.nf = p.n_fluid
        # row capacity: with several ranks, room for rows that arrive (appended on the
        # device by add_displaced; a rank that outgrows it is uploaded again, larger)
        n = max(p.n, 1)
        if state.nranks > 1:
            n += max(p.n // 16, 1024)
        dv.cap = n
        up = 0
        # a chunk of rows at a time through one staging buffer, filled by all cores in the
        # device's type and layout (upload_kernels): no full-size host temporaries
        rows = min(p.n, UPLOAD_ROWS)
        stage = np.empty(32 * max(rows, 1), np.uint8)     # the widest: float64 vel4 records

        def put(name, dtype, fill, per=1):
            nonlocal up
            dv.arrays[name] = d = dev_array(per * n, dtype)
            for a in range(0, p.n, max(rows, 1)):
                m = min(rows, p.n - a)
                h = stage[:per * m * np.dtype(dtype).itemsize].view(dtype)
                fill(a, h)
                d[per * a:per * (a + m)].copy_to_device(h)
                up += h.nbytes

        for d in range(3):
            ax = VEC[d]
            if d < dim:
                put("p" + ax, np.float64, lambda a, h, d=d: UK.column_into(p.pos, d, a, h))
                put("vm" + ax, dt, lambda a, h, d=d: UK.column_into(p.vel_m1, d, a, h))
            else:   # 2D: one-element dummies
                for pre in ("p", "vm"):
                    dv.arrays[pre + ax] = dev_array(1, np.float64 if pre == "p" else dt)
        # (vx, vy, vz, rho) records: velocity and density live here
        put("vel4", dt, lambda a, h: UK.records_into(p.vel, p.rho, a, h), per=4)
        put("rhom", dt, lambda a, h: UK.flat_into(p.rho_m1, a, h))
        put("kind", np.int8, lambda a, h: UK.flat_into(p.kind, a, h))
        wide = p.n and UK.int_max(p.id) >= 2 ** 31 - 1
        put("id", np.int64 if wide else np.int32, lambda a, h: UK.flat_into(p.id, a, h))
        # work arrays (not uploaded)
        dv.arrays["pos4"] = dev_array(4 * n, dt)   # (x-ref, y-ref, z-ref, p) records; sort scratch
        dv.fit_fluid()                                           # reduced acceleration, fluid rows
        for ax in VEC[dim:]:
            dv.arrays["a" + ax] = dev_array(1, dt)
        dv.arrays["ar"] = dev_array(n, dt)
        # the viscous-dt term: one maximum (the force kernels' block maxima), zeroed after
        # each stage's integration
        dv.arrays["visc"] = dev_array(1, dt)
        dv.arrays["visc"].copy_to_device(np.zeros(1, dt))
        dv.make_views()
        dv.arrays["dtout"] = dev_array(3, np.float64)
        dv.arrays["chk_bad"] = dev_array(1, np.int64)
        dv.arrays["chk_box"] = dev_array(6, np.float64)
        dv.box = np.zeros((2, 3))
        if p.n:
            dv.box[0, :dim] = lo
            dv.box[1, :dim] = hi
        dv.host_obj = p
        if old is not None:     # staging and halo buffers outlive a re-upload
            dv.integrator = old.integrator
            if old.host_busy is not None:
                old.host_busy.synchronize()
            dv.pinned_xfer, dv.halo_pool, dv.halo_last = old.pinned_xfer, old.halo_pool, old.halo_last
            # --halo-transport ipc: this rank's edge buffers (their handles went to the peers
            # once) and the peers' buffers it has mapped (cuda_halo)
            dv.edge_slots, dv.edge_peers, dv.edge_views = old.edge_slots, old.edge_peers, old.edge_views
        state.extra["dev"] = dv
        count_bytes(state, "h2d_bytes", "upload", up)
        state.parts = {}
        state.reduced_stage = -1
        # the solver's stage-0 / press / ace slots stay None: the device holds them

    def sync_host(self, state) -> None:
        """Bring the host `state.particles` up to the device rows (order included)."""
        dv = state.extra.get("dev")
        if dv is None or not dv.host_stale:
            return
        p = state.particles
        n, dim = dv.n, dv.dim
        down = 0

        def get(name):
            nonlocal down
            a = dv.arrays[name][:n].copy_to_host()
            down += a.nbytes
            return a

        pos = np.empty((n, dim), np.float64)
        vm = np.empty((n, dim), dv.dtype)
        for d in range(dim):
            ax = VEC[d]
            pos[:, d] = get("p" + ax)
            vm[:, d] = get("vm" + ax)
        v4 = dv.arrays["vel4"][:4 * n].copy_to_host().reshape(-1, 4)
        down += v4.nbytes
        p.pos = pos.astype(p.pos.dtype, copy=False)
        p.vel = np.ascontiguousarray(v4[:, :dim]).astype(p.vel.dtype, copy=False)
        p.vel_m1 = vm.astype(p.vel_m1.dtype, copy=False)
        p.rho = np.ascontiguousarray(v4[:, 3]).astype(p.rho.dtype, copy=False)
        p.rho_m1 = get("rhom").astype(p.rho_m1.dtype, copy=False)
        p.kind = get("kind")
        p.id = get("id").astype(np.int64)
        dv.host_stale = False
        count_bytes(state, "d2h_bytes", "sync_host", down)

    def device_rows_to_host(self, state, rows) -> dict:
        """Position, velocity, density, kind of device rows `rows` (host index array), as a
        halo/edge would carry them (phase 2 of multi-GPU: gathered on the device, pinned)."""
        self.sync_host(state)
        p = state.particles
        return {"pos": p.pos[rows], "vel": p.vel[rows], "rho": p.rho[rows], "kind": p.kind[rows]}

    def host_arrays(self, state) -> dict:
        self.sync_host(state)
        p = state.particles
        from sphgraph.physics.eos import pressure
        press = pressure(np.asarray(p.rho), state.prm.astype(p.rho.dtype))
        return {"id": p.id, "kind": p.kind, "position": p.pos, "velocity": p.vel,
                "density": p.rho, "pressure": press}
