"""Rows between ranks, for the numba.cuda backend: displaced rows taken from and added to
the device rows (`take_displaced`, `add_displaced`; the packed row messages of
cuda_memory.row_layout), and the edges towards the neighbours (`edge`; with
--halo-transport ipc, cuda_halo.send_edge). Only the rows that move cross the bus."""
from __future__ import annotations

import numpy as np

from . import cuda_halo as CH
from . import cuda_kernels as CK
from .cuda_memory import VEC, count_bytes, dev_array, host_wait, layout, row_layout, split


def _plain_slabs(domain, *methods) -> bool:
    """The device edge/displaced paths reproduce sphgraph.domain.Slabs; other domains
    (e.g. periodic images) get current host rows and their own methods."""
    from sphgraph.domain import Slabs
    t = type(domain)
    return all(getattr(t, m) is getattr(Slabs, m) for m in (methods or ("edge", "take_displaced")))


class CudaRows:
    """NumbaCUDA's multi-rank row protocol: displaced rows and edges (a mixin: the sort's
    _scan / _permute, prepare, sync_host and the lanes' _k / _s come from the others)."""

    def take_displaced(self, state, domain) -> dict:
        """Rows that left the slab (as Slabs.take_displaced). The check's bounding box
        says whether any row is outside [lo, hi) along the split axis: if none is, nothing
        crosses the bus. Otherwise the leaving rows are found, copied out and removed on
        the device (`_remove_rows`): only they cross the bus."""
        dv = state.extra.get("dev")
        if dv is not None and dv.n and dv.box is not None and _plain_slabs(domain):
            a = domain.axis
            if dv.box[0, a] >= domain.lo and dv.box[1, a] < domain.hi:
                empty = state.particles.take(np.zeros(0, np.int64))
                return {-1: empty, 1: empty}
            return self._remove_rows(state, dv, domain)
        self.sync_host(state)
        out = domain.take_displaced(state)
        if any(r.n for r in out.values()):
            self.prepare(state)     # the device rows follow the host's (prepare sees a new row set)
        return out

    def _remove_rows(self, state, dv, domain):
        """{-1: rows below lo, +1: rows at or above hi} as host Particles, removed from
        the device rows (kept rows compacted in their order), however many leave (moved
        cuts displace many). Bus: the count, then the leaving rows packed in one buffer
        (k_pack_leaving), one copy."""
        k = self._k(state)
        n, A = dv.n, dv.arrays
        keep = dv.scratch(np.int32, n)             # the pos4 records are dead until the next
        pos = dv.scratch(np.int32, n, n)           # sort rebuilds them (ax holds fluid rows only)
        cnt = self._zeroed_count(dv, k)
        b = CK.blocks(n)
        k.k_mig_keep[b, CK.BLOCK](A["p" + VEC[domain.axis]], n, float(domain.lo), float(domain.hi), keep, cnt)
        m = self._read_count(state, dv, cnt, "displaced")
        if m == 0:
            empty = state.particles.take(np.zeros(0, np.int64))
            return {-1: empty, 1: empty}
        self._scan(dv, k, keep, pos, n)
        out = self._rows_to_host(state, dv, k, keep, pos, m, domain)
        k.k_compact_perm[b, CK.BLOCK](keep, pos, n, dv.perm)
        dv.n = n - m
        dv.moved = np.inf          # rows moved in the arrays: no trimming until the next sort
        dv.nf -= sum(int(np.count_nonzero(o.kind == 0)) for o in out.values())
        self._permute(state, dv, k)
        self._host_rows_changed(state, dv)
        return out

    def periodic_rows(self, state, lo, hi, reach, axes):
        """ComputeBackend.periodic_rows from the device rows: the rows near a face flagged
        (k_near_faces), packed in row order (the scan and k_pack_leaving of _remove_rows),
        and only they cross the bus (the host copy when it is current)."""
        from sphgraph.state import Halo
        dv = state.extra.get("dev")
        if dv is None or not dv.host_stale or not dv.n:
            return super().periodic_rows(state, lo, hi, reach, axes)
        k = self._k(state)
        keep, pos, cnt = self._near_faces(state, dv, k, lo, hi, reach, axes)
        m = self._read_count(state, dv, cnt, "images")
        if m == 0:
            r = state.particles.take(np.zeros(0, np.int64))
        else:
            self._scan(dv, k, keep, pos, dv.n, tmp=dv.images_scan)
            r = self._packed_rows(state, dv, k, keep, pos, m, "images")
        return Halo(pos=r.pos, vel=r.vel, rho=r.rho, kind=r.kind)

    def _near_faces(self, state, dv, k, lo, hi, reach, axes):
        """(keep, pos, count) of the device rows within `reach` of a face along `axes`
        (k_near_faces: keep 0 and counted there, else 1; pos for the scan of keep), for the
        periodic images, host path (periodic_rows) or device (cuda_images). Not the pos4
        scratch that migration uses: these are live mid-stage."""
        n, A = dv.n, dv.arrays
        keep = dv.dev_buf("images_keep", 4 * n).view(np.int32)
        pos = dv.dev_buf("images_pos", 4 * n).view(np.int32)
        cnt = self._zeroed_count(dv, k)
        t, u, w = [0.0] * 3, [0.0] * 3, [0] * 3
        for a in axes:
            t[a], u[a], w[a] = float(lo[a] + reach), float(hi[a] - reach), 1
        k.k_near_faces[CK.blocks(n), CK.BLOCK](A["px"], A["py"], A["pz"], n, *t, *u, *w, keep, cnt)
        return keep, pos, cnt

    def periodic_images(self, state, periodic):
        """ComputeBackend.periodic_images made and binned on the device (cuda_images) when the
        scene has one image axis; else the host path. The device rows are the truth here
        whether or not the host copy is current (sync_host copies them down, a changed host
        copy is uploaded), so a current host copy is no reason for the host path."""
        from .cuda_images import device_images
        dv = state.extra.get("dev")
        if dv is not None and dv.n:
            out = device_images(self, state, periodic)
            if out is not None:
                return out
        return super().periodic_images(state, periodic)

    def _zeroed_count(self, dv, k):
        """The rank's device row counter (one int32), set to 0 on the running stream."""
        A = dv.arrays
        if "mig_cnt" not in A:
            A["mig_cnt"] = dev_array(1, np.int32)
        k.k_fill[1, 1](A["mig_cnt"], 1, 0)
        return A["mig_cnt"]

    def _read_count(self, state, dv, cnt, what) -> int:
        """The counter's value on the host (its 4 bytes booked under `what`)."""
        s = self._s(state)
        cnt.copy_to_host(dv.pinned_i4[:1], stream=s)
        host_wait(s)
        count_bytes(state, "d2h_bytes", what, 4)
        return int(dv.pinned_i4[0])

    def _packed_rows(self, state, dv, k, keep, pos, m, what):
        """The m rows with keep == 0 (pos: exclusive scan of keep) as one host Particles in
        increasing row order: one packing launch, one copy to the pinned staging buffer."""
        from sphgraph.particles import Particles
        p = state.particles
        n, dim, A = dv.n, dv.dim, dv.arrays
        lay, nb = row_layout(dv, m)
        dbuf = dv.dev_buf("xfer", nb)
        d = split(dbuf, lay)
        k.k_pack_leaving[CK.blocks(n), CK.BLOCK](keep, pos, n, dim, A["px"], A["py"], A["pz"], A["vmx"], A["vmy"],
                                                  A["vmz"], A["vel4"], A["rhom"], A["kind"], A["id"],
                                                  d["pos"], d["f"], d["kind"], d["id"])
        hb = dv.host_buf(nb)
        s = self._s(state)
        dbuf.copy_to_host(hb, stream=s)
        host_wait(s)
        count_bytes(state, "d2h_bytes", what, nb)
        h = split(hb, lay)
        P = h["pos"].reshape(m, dim)
        F = h["f"].reshape(m, dim + 5)      # copies below: nothing aliases the staging buffer
        return Particles(id=h["id"].astype(np.int64), kind=h["kind"].copy(), pos=P.astype(p.pos.dtype, copy=True),
                         vel=np.ascontiguousarray(F[:, dim:2 * dim]).astype(p.vel.dtype, copy=True),
                         rho=np.ascontiguousarray(F[:, dim + 3]).astype(p.rho.dtype, copy=True),
                         vel_m1=np.ascontiguousarray(F[:, :dim]).astype(p.vel_m1.dtype, copy=True),
                         rho_m1=np.ascontiguousarray(F[:, dim + 4]).astype(p.rho_m1.dtype, copy=True))

    def _rows_to_host(self, state, dv, k, keep, pos, m, domain):
        """The m rows with keep == 0 (pos: exclusive scan of keep) as host Particles by
        side, each in increasing row order (`_packed_rows`); the side of a row is read from
        its position on the host (the same comparison as k_mig_keep)."""
        rows = self._packed_rows(state, dv, k, keep, pos, m, "displaced")
        x = rows.pos[:, domain.axis]
        return {side: rows.take(np.nonzero(sel)[0])
                for side, sel in ((-1, x < float(domain.lo)), (1, x >= float(domain.hi)))}

    def _host_rows_changed(self, state, dv):
        """The host rows no longer match the device's in number: a stale placeholder of
        dv.n rows (np.empty: nothing is touched) that `sync_host` fills when asked."""
        from sphgraph.particles import Particles
        p, n, dim = state.particles, dv.n, dv.dim
        state.particles = q = Particles(
            id=np.empty(n, np.int64), kind=np.empty(n, np.int8), pos=np.empty((n, dim), p.pos.dtype),
            vel=np.empty((n, dim), p.vel.dtype), rho=np.empty(n, p.rho.dtype),
            vel_m1=np.empty((n, dim), p.vel_m1.dtype), rho_m1=np.empty(n, p.rho_m1.dtype))
        dv.host_obj = q
        dv.host_stale = True

    def add_displaced(self, state, domain, rows, built: bool) -> None:
        """Rows that came from the neighbours, appended to the device rows (only they
        cross the bus; a build_cells sorts them in: this step's again when it ran before).
        A domain other than the plain slabs goes through its own rows."""
        rows = [r for r in rows if r is not None and r.n]
        if not rows:
            return
        if not _plain_slabs(domain, "add_rows"):
            super().add_displaced(state, domain, rows, built)
            return
        self._append_rows(state, domain, rows)
        if built:
            # no device merge: the appended rows are unsorted, a whole device build sorts
            # them in (correct; the order of equal-cell rows may differ from build after recv)
            self.build_cells(state)

    def _append_rows(self, state, domain, rows) -> None:
        """`rows` appended on the device; a rank without room, or whose host rows are
        current anyway, goes through the host and `prepare`."""
        dv = state.extra.get("dev")
        m = sum(r.n for r in rows)
        # through the host when the host rows are the truth (take_displaced went through
        # the host), there is no room, or an id needs more than the device's int32
        if (dv is None or dv.host_obj is not state.particles or dv.n + m > dv.cap or
                (dv.arrays["id"].dtype == np.int32 and max(int(r.id.max()) for r in rows) >= 2 ** 31 - 1)):
            self.sync_host(state)
            domain.add_rows(state, rows)
            self.prepare(state)
            return
        from sphgraph.particles import Particles
        r = Particles.concat(rows)
        n, dim, A = dv.n, dv.dim, dv.arrays
        # packed as k_pack_leaving packs them: one copy from the pinned staging buffer,
        # one launch writes the rows n .. n+m-1
        lay, nb = row_layout(dv, m)
        hb = dv.host_buf(nb)
        h = split(hb, lay)
        h["pos"].reshape(m, dim)[:] = r.pos
        F = h["f"].reshape(m, dim + 5)
        F[:, :dim] = r.vel_m1
        F[:, dim:dim + 3] = 0           # vel4 records: (vx, vy, vz, rho), vz = 0 in 2D
        F[:, dim:2 * dim] = r.vel
        F[:, dim + 3] = r.rho
        F[:, dim + 4] = r.rho_m1
        h["kind"][:] = r.kind
        h["id"][:] = r.id
        dbuf = dv.dev_buf("xfer", nb)
        s = self._s(state)
        dbuf.copy_to_device(hb, stream=s)
        dv.mark_host_busy(s)
        d = split(dbuf, lay)
        self._k(state).k_unpack_rows[CK.blocks(m), CK.BLOCK](
            n, m, dim, d["pos"], d["f"], d["kind"], d["id"], A["px"], A["py"], A["pz"], A["vmx"], A["vmy"],
            A["vmz"], A["vel4"], A["rhom"], A["kind"], A["id"])
        up = nb
        dv.n = n + m
        dv.moved = np.inf          # rows moved in the arrays: no trimming until the next sort
        mf = int(np.count_nonzero(r.kind == 0))
        dv.nf += mf
        dv.bound_arrived += m - mf
        CH.grow_bounds(dv, mf, m - mf)
        dv.fit_fluid()
        if dv.box is not None:      # the next grid must hold the new rows
            dv.box[0, :dim] = np.minimum(dv.box[0, :dim], r.pos.min(axis=0))
            dv.box[1, :dim] = np.maximum(dv.box[1, :dim], r.pos.max(axis=0))
        count_bytes(state, "h2d_bytes", "displaced", up)
        self._host_rows_changed(state, dv)

    def edge(self, state, domain, direction, slot=None):
        """Rows within `reach` of the neighbour's slab, as Slabs.edge, read from the device:
        rows are sorted by (kind, cell) with the split axis slowest, so the candidates are
        one contiguous range per kind (the cells from one cell short of the threshold on,
        a margin for rows moved since the sort); only those ranges are copied, then cut
        exactly on the host. With a `slot` (the message tag; --halo-transport ipc) the
        ranges stay on the device and a cuda_halo.DeviceEdge describes them: the receiver
        copies them device to device and cuts them there."""
        from sphgraph.state import Halo
        dv = state.extra.get("dev")
        g = None if dv is None else dv.grid
        if g is None or not dv.n or int(g["axes"][2]) != domain.axis or not _plain_slabs(domain):
            if dv is not None:
                dv.mdbc_edges[direction] = ("host",)
            self.sync_host(state)
            return domain.edge(state, direction)
        if slot is not None:
            dv.domain = domain      # the halo forces' targets: the same cut's rows
            return CH.send_edge(self, state, dv, domain, direction, slot)
        n0, n1, n2 = (int(x) for x in g["dims"])
        ncells = int(g["ncells"])
        plane = n0 * n1
        if direction < 0:
            thr = domain.lo + domain.reach
            c = min(int(np.floor((thr - g["origin"][2]) * g["inv"])) + 1, n2 - 1)
            idx = [0, (c + 1) * plane, ncells, ncells + (c + 1) * plane]
        else:
            thr = domain.hi - domain.reach
            c = max(int(np.floor((thr - g["origin"][2]) * g["inv"])) - 1, 0)
            idx = [c * plane, ncells, ncells + c * plane, 2 * ncells]
        k = self._k(state)
        A, dim = dv.arrays, dv.dim
        if "pick4" not in A:
            A["pick4"] = dev_array(4, np.int32)
        s = self._s(state)
        self._copy_mark(state, "edge_d2h", True)
        k.k_pick4[1, 1](A["start"], *idx, A["pick4"])      # the 4 range ends: one copy
        A["pick4"].copy_to_host(dv.pinned_i4, stream=s)
        host_wait(s)
        a0, b0, a1, b1 = (int(x) for x in dv.pinned_i4)
        m0, m1 = max(b0 - a0, 0), max(b1 - a1, 0)
        m = m0 + m1
        pos, vel, rho, kind = [], [], [], []
        dv.mdbc_edges[direction] = ("rows", a1, np.zeros(0, bool))   # mdbc_edge: the boundary rows sent
        nb = 0
        if m:   # both ranges packed by one launch, one copy to the pinned staging buffer
            lay, nb = layout([("pos", np.float64, m * dim), ("v4", dv.dtype, 4 * m), ("kind", np.int8, m)])
            dbuf = dv.dev_buf("xfer", nb)
            d = split(dbuf, lay)
            k.k_pack_edge[CK.blocks(m), CK.BLOCK](A["px"], A["py"], A["pz"], A["vel4"], A["kind"], a0, m0, a1, m,
                                                   dim, d["pos"], d["v4"], d["kind"])
            hb = dv.host_buf(nb)
            dbuf.copy_to_host(hb, stream=s)
            host_wait(s)
            h = split(hb, lay)
            P = h["pos"].reshape(m, dim)
            v4 = h["v4"].reshape(m, 4)
            x = P[:, domain.axis]
            sel = x < thr if direction < 0 else x >= thr
            dv.mdbc_edges[direction] = ("rows", a1, sel[m0:].copy())
            pos.append(P[sel])            # boolean indexing copies: nothing aliases the staging buffer
            vel.append(v4[sel, :dim])
            rho.append(v4[sel, 3])
            kind.append(h["kind"][sel])
        self._copy_mark(state, "edge_d2h", False)
        count_bytes(state, "d2h_bytes", "edge", nb + 16)
        p = state.particles
        if pos:
            h = Halo(pos=np.concatenate(pos).astype(p.pos.dtype, copy=False),
                     vel=np.ascontiguousarray(np.concatenate(vel)).astype(p.vel.dtype, copy=False),
                     rho=np.concatenate(rho).astype(p.rho.dtype, copy=False), kind=np.concatenate(kind))
        else:
            h = Halo(pos=np.zeros((0, dim), p.pos.dtype), vel=np.zeros((0, dim), p.vel.dtype),
                     rho=np.zeros(0, p.rho.dtype), kind=np.zeros(0, p.kind.dtype))
        state.bytes_sent += h.nbytes()
        return h
