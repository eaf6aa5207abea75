"""numba.cuda kernel of mDBC (sphgraph.physics.mdbc): the GPU twin of cpu_mdbc.mdbc_boundary, one
thread a boundary row, with the same per-row maths (`ghost_add`, `ghost_value`) on local arrays.

The ghost node of each fixed boundary particle is the scene's geometry: it is computed once
on the host from the particle's position (`ghost_positions`) and kept on the device as a
table by particle id, so a stage moves nothing across the bus for it. A moving body's ghost
nodes move with the body: each mdbc puts them (`Mdbc.moving_ghosts`, dim numbers a moving
particle, uploaded) into the table by id (`k_set_ghosts`), and the body's rows keep their
velocity, the body's. The
kernel reads the rank's fluid rows through the kind-split cells (the fluid half of `start`)
and writes each boundary row's density, velocity and pressure in place (fluid rows are only
read: no race).

On several ranks a ghost near a cut also sums the halos' fluid rows: the sums of each
boundary row go through a device scratch (`ACC` numbers a row) from the owned rows
(`k_mdbc_src` with `first`) over each halo (`k_mdbc_src`: a staged halo's uploaded arrays and host grid,
or an ipc halo's records and planes in the sender's edge slot) to the row's values
(`k_mdbc_value`). send_mdbc / recv_mdbc then bring the new values of the edge's boundary
rows to the neighbours' halos, which hold those from before the sender's mdbc: staged, read
from the device in the edge's order and uploaded into the halo's buffer (the message is a
plain array: mock and MPI ranks alike); ipc, copied again into the sender's edge slot
(`k_edge_bound`), which the neighbour's halo views, behind an event that the neighbour's
stream waits for; between processes (MPI) the sender's host waits for the copy before
the message leaves (`MdbcDone.to_wire`), as for the edge itself.
"""
import copy
import math  # noqa: F401  (the cloned device functions use it)
import types

import numpy as np
from numba import cuda, njit

from sphgraph.cells import cell_window
from sphgraph.config import O_KERNEL, P_MASS_F, P_SUPPORT2
from sphgraph.errors import CommError
from sphgraph.particles import MOVING
from sphgraph.physics.eos import tait
from sphgraph.physics.mdbc import ghost_add, ghost_positions, ghost_value
from sphgraph.wire import WirePayload, codec

from . import cuda_halo as CH
from . import cuda_kernels as CK
from .cuda_lanes import new_event
from .cuda_memory import COUNTERS, VEC, _every4, count_bytes, host_wait, kept_views

RT = np.float64


def k_mdbc(px, py, pz, ghost, ids, kind, vx, vy, vz, rho, press, i0, n, start, o0, o1, o2, inv_size,
           n0, n1, n2, a0, a1, a2, reach, prm, dim, kernel_id, det_min, noslip):
    """Boundary rows i0..n-1: density (and, with `noslip`, velocity; a moving body's rows
    keep theirs) from the fluid about the row's ghost node ghost[3 id : 3 id + 3], and the
    row's pressure."""
    i = cuda.grid(1) + i0
    if i >= n:
        return
    A = cuda.local.array((4, 4), RT)
    b = cuda.local.array(4, RT)
    A2 = cuda.local.array((4, 4), RT)
    b2 = cuda.local.array(4, RT)
    vs = cuda.local.array(3, RT)
    for r in range(4):
        b[r] = 0.0
        for c in range(4):
            A[r, c] = 0.0
    for r in range(3):
        vs[r] = 0.0
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    g = 3 * ids[i]
    gx = ghost[g]
    gy = ghost[g + 1]
    gz = ghost[g + 2] if dim == 3 else 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(gx, gy, gz, o0, o1, o2, inv_size, n0, n1, n2,
                                                      a0, a1, a2, reach)
    sw = 0.0 * rho[i]
    if not empty:
        for c2 in range(lo2, hi2 + 1):
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + lo0], start[row + hi0 + 1]):     # the fluid half: fluid rows
                    dx0 = px[j] - gx
                    dx1 = py[j] - gy
                    dx2 = (pz[j] - gz) if dim == 3 else 0.0
                    r2 = dx0 * dx0 + dx1 * dx1 + dx2 * dx2
                    if r2 >= support2:
                        continue
                    sw += ghost_add(A, b, vs, dx0, dx1, dx2, r2, rho[j], vx[j], vy[j],
                                    vz[j] if dim == 3 else 0.0, m, dim, prm, kernel_id)
    rr, u0, u1, u2 = ghost_value(A, b, A2, b2, vs, sw, px[i] - gx, py[i] - gy,
                                 (pz[i] - gz) if dim == 3 else 0.0, dim, prm, det_min, noslip)
    rho[i] = rr
    if kind[i] != MOVING:
        vx[i] = u0
        vy[i] = u1
        if dim == 3:
            vz[i] = u2
    press[i] = tait(rr, prm)


# -- several ranks: the sums of a ghost span the owned rows and the halos --------------
# Per boundary row, ACC numbers in `acc` hold the ghost's sums between the kernels: the
# matrix A (16), the right-hand side b (4), the velocity sum vs (3) and the Shepard weight
# sw (1). k_mdbc_src sums one source's fluid rows: first the owned ones (`first`: from zero,
# reference 0, the fluid half of the rank's grid), then each halo's; k_mdbc_value turns the
# sums into the row's values.
ACC = 24


@njit(inline="always")
def _acc_load(acc, k, A, b, vs):
    """The sums of one boundary row from acc[k : k + ACC] into A, b, vs; returns sw."""
    for r in range(4):
        for c in range(4):
            A[r, c] = acc[k + 4 * r + c]
        b[r] = acc[k + 16 + r]
    for r in range(3):
        vs[r] = acc[k + 20 + r]
    return acc[k + 23]


def k_mdbc_src(ghost, ids, i0, n, ref0, ref1, ref2, sx, sy, sz, svx, svy, svz, srho, skind, start, o0, o1, o2,
               inv_size, n0, n1, n2, a0, a1, a2, reach, prm, dim, kernel_id, acc, first):
    """One source's fluid rows (positions relative to ref, as the source holds them; cells
    start[0 .. n0 n1 n2]; rows of other kinds skipped) added to the sums in acc of
    boundary rows i0..n-1, or, with `first`, stored there as their first sums."""
    i = cuda.grid(1) + i0
    if i >= n:
        return
    A = cuda.local.array((4, 4), RT)
    b = cuda.local.array(4, RT)
    vs = cuda.local.array(3, RT)
    k = (i - i0) * 24
    if first:
        for r in range(4):
            b[r] = 0.0
            for c in range(4):
                A[r, c] = 0.0
        for r in range(3):
            vs[r] = 0.0
        sw = 0.0
    else:
        sw = _acc_load(acc, k, A, b, vs)
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    g = 3 * ids[i]
    gx = ghost[g] - ref0
    gy = ghost[g + 1] - ref1
    gz = (ghost[g + 2] - ref2) if dim == 3 else 0.0
    lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(gx, gy, gz, o0, o1, o2, inv_size, n0, n1, n2,
                                                      a0, a1, a2, reach)
    if not empty:
        for c2 in range(lo2, hi2 + 1):
            for c1 in range(lo1, hi1 + 1):
                row = (c2 * n1 + c1) * n0
                for j in range(start[row + lo0], start[row + hi0 + 1]):
                    if skind[j] != 0:
                        continue
                    dx0 = sx[j] - gx
                    dx1 = sy[j] - gy
                    dx2 = (sz[j] - gz) if dim == 3 else 0.0
                    r2 = dx0 * dx0 + dx1 * dx1 + dx2 * dx2
                    if r2 >= support2:
                        continue
                    sw += ghost_add(A, b, vs, dx0, dx1, dx2, r2, srho[j], svx[j], svy[j],
                                    svz[j] if dim == 3 else 0.0, m, dim, prm, kernel_id)
    for r in range(4):
        for c in range(4):
            acc[k + 4 * r + c] = A[r, c]
        acc[k + 16 + r] = b[r]
    for r in range(3):
        acc[k + 20 + r] = vs[r]
    acc[k + 23] = sw


def k_mdbc_value(px, py, pz, ghost, ids, kind, vx, vy, vz, rho, press, i0, n, prm, dim, det_min, noslip, acc):
    """Boundary rows i0..n-1: their density, velocity and pressure from the sums in acc."""
    i = cuda.grid(1) + i0
    if i >= n:
        return
    A = cuda.local.array((4, 4), RT)
    b = cuda.local.array(4, RT)
    A2 = cuda.local.array((4, 4), RT)
    b2 = cuda.local.array(4, RT)
    vs = cuda.local.array(3, RT)
    k = (i - i0) * 24
    sw = _acc_load(acc, k, A, b, vs) + 0.0 * rho[i]
    g = 3 * ids[i]
    gx = ghost[g]
    gy = ghost[g + 1]
    gz = ghost[g + 2] if dim == 3 else 0.0
    rr, u0, u1, u2 = ghost_value(A, b, A2, b2, vs, sw, px[i] - gx, py[i] - gy,
                                 (pz[i] - gz) if dim == 3 else 0.0, dim, prm, det_min, noslip)
    rho[i] = rr
    if kind[i] != MOVING:
        vx[i] = u0
        vy[i] = u1
        if dim == 3:
            vz[i] = u2
    press[i] = tait(rr, prm)


def k_set_ghosts(mids, mg, m, dim, ghost, nslot):
    """The moving bodies' ghost nodes (mg: dim numbers each, ids mids) put in the table by
    id (ids past the table's nslot rows are not this rank's)."""
    k = cuda.grid(1)
    if k >= m:
        return
    q = mids[k]
    if q >= nslot:
        return
    for c in range(dim):
        ghost[3 * q + c] = mg[dim * k + c]


def k_edge_bound(start, f0, nch, ncells, pos4, vel4, cap, o_pos4, o_vel4):
    """After mdbc: the boundary rows of the edge packed by cuda_halo_kernels.k_halo_pack
    (the same planes, the same sort) copied again into the slot, their velocity, density
    (vel4) and pressure (pos4's fourth lane); their positions and the fluid rows stay."""
    m0 = start[f0 + nch] - start[f0]
    a1 = start[ncells + f0]
    mb = start[ncells + f0 + nch] - a1
    i = cuda.grid(1)
    while i < mb and m0 + i < cap:
        s = a1 + i
        o = m0 + i
        for c in range(4):
            o_vel4[4 * o + c] = vel4[4 * s + c]
        o_pos4[4 * o + 3] = pos4[4 * s + 3]
        i += cuda.gridsize(1)


_KERNELS = ("k_mdbc", "k_mdbc_src", "k_mdbc_value", "k_set_ghosts", "k_edge_bound")


def build(dtype) -> types.SimpleNamespace:
    """The mDBC kernels for float type `dtype` (cached)."""
    return CK.kernel_set(globals(), _KERNELS, dtype)


def ghost_table(particles, boxes) -> np.ndarray:
    """Ghost nodes by particle id (3 float64 each, flat) of the boundary rows of `particles`."""
    p = particles
    rows = np.nonzero(p.kind != 0)[0]
    table = np.zeros((max(int(p.id.max()) + 1, 1) if p.n else 1, 3))
    if len(rows):
        table[p.id[rows], :p.dim] = ghost_positions(np.asarray(p.pos[rows], np.float64), boxes)
    return table.ravel()


@codec
class MdbcDone(WirePayload):
    """send_mdbc's message with --halo-transport ipc: the new boundary values are already in
    the sender's slot buffer, which the neighbour's halo views. Mock ranks (one process): the
    message carries the event recorded after they were copied there, which the receiver's
    stream waits for. Between processes (MPI) an event cannot travel: as DeviceEdge does,
    the sender's host waits for the copy before the message leaves (`to_wire`), and the
    receiver's message has no event (`from_wire`): the values are in place."""

    wire_code = 2

    def __init__(self, event):
        self.event = event

    def __deepcopy__(self, memo):
        return copy.copy(self)

    def nbytes(self) -> int:
        return 8

    def to_wire(self, dest: int) -> np.ndarray:
        if self.event is not None:
            COUNTERS["host_wait"] += 1
            self.event.synchronize()
        return np.zeros(8, np.uint8)

    @classmethod
    def from_wire(cls, buf: np.ndarray) -> "MdbcDone":
        return cls(None)


class CudaMdbc:
    """`ComputeBackend.mdbc`, `mdbc_edge` and `mdbc_halo` on the device rows (mixed into
    NumbaCUDA). The ghost table is built from the host rows' boundary positions and kept on
    the device; it is built again after an upload or once boundary rows came from a
    neighbour (moved cuts), whose ids it lacks. A moving body's entries are put there again
    at every mdbc (`_moving_ghosts`)."""

    def _mdbc_ghosts(self, state, dv, boxes):
        have = state.extra.get("mdbc_ghost")
        if have is None or have[0] is not dv or have[1] != dv.bound_arrived:
            self.sync_host(state)      # the host rows may be a placeholder (rows came or went)
            have = state.extra["mdbc_ghost"] = (dv, dv.bound_arrived,
                                                cuda.to_device(ghost_table(state.particles, boxes)))
        return have[2]

    def _moving_ghosts(self, state, dv, k, tab, moving) -> None:
        """The moving bodies' ghost nodes at the rows' time into the table by id (the ids'
        device copy made once a run, the nodes uploaded each call)."""
        ids, carried = moving
        m = len(ids)
        if not m:
            return
        have = state.extra.get("mdbc_moving_ids")
        if have is None or have[0] is not ids:
            have = state.extra["mdbc_moving_ids"] = (ids, cuda.to_device(np.ascontiguousarray(ids, np.int64)))
        s = self._s(state)
        flat = np.ascontiguousarray(carried, np.float64).ravel()
        mg = dv.dev_buf("mdbc_moving", flat.nbytes).view(np.float64)
        mg.copy_to_device(flat, stream=s)   # pageable: CUDA has staged it when the call returns
        count_bytes(state, "h2d_bytes", "mdbc", flat.nbytes)
        k.k_set_ghosts[CK.blocks(m), CK.BLOCK](have[1], mg, m, dv.dim, tab, tab.size // 3)

    def mdbc(self, state, boxes, det_min, noslip, moving=None) -> None:
        dv = state.extra["dev"]
        if dv.n <= dv.nf:
            return
        tab = self._mdbc_ghosts(state, dv, boxes)
        A = dv.A()
        g = dv.grid
        o, dims, axes = g["origin"], g["dims"], g["axes"]
        k = self._on(state, build(dv.dtype))
        if moving is not None:
            self._moving_ghosts(state, dv, k, tab, moving)
        geo = (A["start"], float(o[0]), float(o[1]), float(o[2]), float(g["inv"]), int(dims[0]), int(dims[1]),
               int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), int(g["reach"]), dv.prm_d(state), dv.dim,
               int(state.opt[O_KERNEL]))
        halos = [(side, h) for side, h in sorted(state.halos.items()) if h is not None and h.n]
        nb = dv.n - dv.nf
        if not halos:
            k.k_mdbc[CK.blocks(nb), CK.BLOCK](
                A["px"], A["py"], A["pz"], tab, A["id"], A["kind"], A["vx"], A["vy"], A["vz"], A["rho"], A["press"],
                dv.nf, dv.n, *geo, float(det_min), bool(noslip))
            dv.host_stale = True
            return
        # the ghosts near a cut reach into the halos: their sums go on over each halo's fluid
        acc = dv.dev_buf("mdbc_acc", 8 * ACC * nb).view(np.float64)
        # the owned fluid first (the fluid half of this rank's grid, in the ghosts' frame)
        k.k_mdbc_src[CK.blocks(nb), CK.BLOCK](tab, A["id"], dv.nf, dv.n, 0.0, 0.0, 0.0, A["px"], A["py"], A["pz"],
                                               A["vx"], A["vy"], A["vz"], A["rho"], A["kind"], *geo, acc, True)
        for _, h in halos:
            src = self._mdbc_source(state, dv, h)
            if src is not None:
                k.k_mdbc_src[CK.blocks(nb), CK.BLOCK](tab, A["id"], dv.nf, dv.n, *(float(x) for x in dv.ref[:3]),
                                                       *([0.0] * (3 - dv.dim)), *src, int(g["reach"]),
                                                       dv.prm_d(state), dv.dim, int(state.opt[O_KERNEL]), acc,
                                                       False)
        k.k_mdbc_value[CK.blocks(nb), CK.BLOCK](A["px"], A["py"], A["pz"], tab, A["id"], A["kind"], A["vx"], A["vy"],
                                                 A["vz"], A["rho"], A["press"], dv.nf, dv.n, dv.prm_d(state), dv.dim,
                                                 float(det_min), bool(noslip), acc)
        dv.host_stale = True

    def _mdbc_source(self, state, dv, halo):
        """k_mdbc_src's arguments for a halo's rows (positions relative to the run's
        reference point, its grid's origin likewise), or None when it holds no rows: a
        staged halo's uploaded arrays and host grid, or an ipc halo's records in the
        sender's slot and the planes' cells (the fluid half of its kind-split starts)."""
        az = dv.arrays["az"]
        if isinstance(halo, CH.DeviceEdge):
            v = halo.views
            if v is None or not halo.m:
                return None
            p4, v4 = v["pos4"], v["vel4"]
            comp = [_every4(p4, 0), _every4(p4, 1), _every4(p4, 2) if dv.dim == 3 else az,
                    _every4(v4, 0), _every4(v4, 1), _every4(v4, 2) if dv.dim == 3 else az, _every4(v4, 3),
                    v["kind"], v["start"]]
            origin, size, dims = halo.origin, halo.size, halo.dims
        else:
            if halo.cells is None:
                return None
            hd = halo.press
            self._read_halo(state, dv, halo)
            comp = [hd["rx"], hd["ry"], hd["rz"], hd["vx"], hd["vy"], hd["vz"], hd["rho"], hd["kind"], hd["start"]]
            origin, size, dims = halo.cells.origin, halo.cells.size, halo.cells.dims
        axes = dv.grid["axes"]
        rel = [float(origin[k]) - float(dv.ref[axes[k]]) if axes[k] >= 0 else 0.0 for k in range(3)]
        return (*comp, *rel, 1.0 / float(size), int(dims[0]), int(dims[1]), int(dims[2]),
                int(axes[0]), int(axes[1]), int(axes[2]))

    def mdbc_edge(self, state, domain, direction: int):
        """The new values of the boundary rows of the edge sent towards `direction` this
        stage (the sort has not changed since): staged, [density, velocity...] of those rows
        in the edge's order, read from the device; ipc, the rows copied again into the
        edge's slot on the device (`k_edge_bound`) and an `MdbcDone`."""
        dv = state.extra["dev"]
        rec = dv.mdbc_edges.get(direction, ("host",))
        dim = dv.dim
        if rec[0] == "slot":
            _, slot, f0, nch, cap, bb = rec
            e = dv.edge_slots[slot]
            lay, nb = CH.edge_layout(cap, nch, dv.dtype)
            d = kept_views(e, e["buf"], lay, nb)
            ev = e.get("mdbc_event")
            if ev is None:
                ev = e["mdbc_event"] = new_event(False)
            A = dv.arrays
            # a grid-stride loop over the boundary rows: the launch covers their bound
            self._on(state, build(dv.dtype)).k_edge_bound[min(CK.blocks(max(bb, 1)), 4096), CK.BLOCK](
                A["start"], f0, nch, int(dv.grid["ncells"]), A["pos4"], A["vel4"], cap, d["pos4"], d["vel4"])
            s = self._s(state)
            ev.record(s if s else 0)
            return MdbcDone(ev)
        p = state.particles
        if rec[0] == "host":      # the edge came from the host rows (Slabs.edge): so do its values
            self.sync_host(state)
            sel = domain.edge_sources(state, direction)
            b = sel[p.kind[sel] != 0]
            out = np.empty((len(b), 1 + dim), p.rho.dtype)
            out[:, 0] = p.rho[b]
            out[:, 1:] = p.vel[b]
            return out
        _, a1, sel = rec
        out = np.empty((int(sel.sum()), 1 + dim), p.rho.dtype)
        if len(sel):
            s = self._s(state)
            h = np.empty(4 * len(sel), dv.dtype)
            dv.arrays["vel4"][4 * a1:4 * (a1 + len(sel))].copy_to_host(h, stream=s)
            host_wait(s)
            count_bytes(state, "d2h_bytes", "mdbc", h.nbytes)
            v4 = h.reshape(-1, 4)[sel]
            out[:, 0] = v4[:, 3]
            out[:, 1:] = v4[:, :dim]
        return out

    def mdbc_halo(self, state, halo, values) -> None:
        if halo is None or halo.n == 0:
            return
        if isinstance(halo, CH.DeviceEdge):
            if not isinstance(values, MdbcDone):
                raise CommError("mDBC halo: an ipc halo needs the ipc exchange's message, got host values")
            if values.event is None:      # from another process: its host waited (MdbcDone.to_wire)
                return
            s = self._s(state)
            if s:
                values.event.wait(s)
            else:
                values.event.wait()
            return
        dv = state.extra["dev"]
        rows = np.nonzero(halo.kind != 0)[0]
        src = halo.order[rows]                  # the sender's edge rows, whose values come in edge order
        if len(rows) != len(values):
            raise ValueError(f"mDBC halo: {len(values)} boundary values for {len(rows)} boundary rows")
        if not len(rows):
            return
        k = np.searchsorted(np.sort(src), src)
        halo.rho[rows] = values[k, 0]
        halo.vel[rows] = values[k, 1:]
        hd = halo.press
        s = self._s(state)
        self._read_halo(state, dv, halo)
        m = halo.n
        dt = dv.dtype
        hd["rho"].copy_to_device(np.ascontiguousarray(halo.rho, dt), stream=s)
        for i in range(dv.dim):
            hd["v" + VEC[i]].copy_to_device(np.ascontiguousarray(halo.vel[:, i], dt), stream=s)
        count_bytes(state, "h2d_bytes", "mdbc", (1 + dv.dim) * m * dt.itemsize)
        self._k(state).k_pressure[CK.blocks(m), CK.BLOCK](hd["rho"], m, dv.prm_d(state), hd["press"])
