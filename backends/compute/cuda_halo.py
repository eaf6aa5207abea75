"""Halos device to device: the `ipc` halo transport (the default of mock ranks on a GPU).

Staged (`--halo-transport staged`): the sender copies its edge rows to the host, the comm
carries them, the receiver bins them by cell on the host and uploads them. With `ipc` the
rows never leave the devices and nothing is binned again:

sender (`send_edge`)    the edge towards a neighbour is whole planes of the sender's sorted
    cells (one fluid and one boundary row range, read once per sort: `edge_ranges`);
    `k_halo_pack` copies their pos4 / vel4 / kind records and the planes' cell starts into
    the sender's buffer for that message tag behind a generation number, on the task's
    stream, and records an event there. The message (`DeviceEdge`) says where the rows are
    and what grid they form.
receiver (`receive_edge`)  waits for the event on its own stream (no host wait) and reads
    the rows where they are: the halo force kernels (cuda_halo_kernels) take the buffer's
    records and starts as their sources and the receiver's own rows within reach of that
    cut as targets.

The rows beyond the sender's reach that whole planes bring are farther than 2h from any
receiver row: they add no pair (the r^2 test rejects them).

One buffer per tag is enough: a slot is written again one step later (tags differ by
stage), and between the two writes the sender passes a dt allreduce that the receiver
joins only after its host waited for its own halo forces (dt_local reads them).

Mock ranks share one process and one device: the message carries the buffer itself and
the event. Between processes (MPI) the buffer goes once per peer as a CUDA IPC handle; an
event cannot cross processes, so the sender's host waits for the pack before the message
leaves (`to_wire`), and the receiver checks the generation number with its first read.
"""
from __future__ import annotations

import copy
import pickle

import numpy as np

from sphgraph.errors import CommError
from sphgraph.wire import WirePayload, codec

from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from .cuda_lanes import new_event
from .cuda_memory import COUNTERS, VEC, count_bytes, dev_array, edge_capacity, host_wait, kept_views, pinned_array, split

_WIRE = 2            # layout version of DeviceEdge.to_wire
_HEAD = 20           # int64 words before the pickled IPC handle


@codec
class DeviceEdge(WirePayload):
    """An edge message of the ipc transport; once received it is the halo: at most `m`
    rows (`m0` of them fluid at most: bounds; the cell starts hold the counts), cell grid
    `dims` at `origin` (cells of `size`; `ncells` per kind), device views `pos4`, `vel4`,
    `kind`, `start` of the sender's buffer."""

    wire_code = 1

    def __init__(self, src, slot, version, gen, m0, m, nch, dims, origin, size, moved, dim, dtype, nb,
                 array=None, handle=None, owner=None, event=None):
        self.src, self.slot, self.version, self.gen = int(src), int(slot), int(version), int(gen)
        self.m0, self.m, self.ncells = int(m0), int(m), int(nch)
        self.dims = np.asarray(dims, np.int64)
        self.origin = np.asarray(origin, np.float64)
        self.size, self.moved = float(size), float(moved)
        self.dim, self.dtype, self.nb = int(dim), np.dtype(dtype), int(nb)
        self.array = array          # the sender's buffer itself (mock ranks: one process)
        self.handle = handle        # its IPC handle (MPI ranks), sent once per buffer and peer
        self.event = event          # recorded after the pack (one process only)
        self._owner = owner         # the sender's slot (to_wire: was the handle sent?)
        self.n = self.m
        self.n_fluid = self.m0      # fluid rows (whole planes: a few beyond the reach)
        self.views = None
        self._ref = None

    def __deepcopy__(self, memo):
        # the mock comm freezes payloads: the rows live in the sender's device buffer, shared
        # as an IPC mapping would be (see the module doc for why it is not overwritten early)
        return copy.copy(self)

    def nbytes(self) -> int:
        """Bytes of the message itself (the rows move device to device)."""
        return 8 * _HEAD

    def to_wire(self, dest: int) -> np.ndarray:
        """The message between processes: int64 header, then the pickled handle when this
        buffer goes to `dest` for the first time. The host waits for the pack first."""
        if self.event is not None:
            COUNTERS["host_wait"] += 1
            self.event.synchronize()
        o = self._owner
        blob = b""
        if o is not None and dest not in o["sent"]:
            if o.get("handle") is None:
                o["handle"] = o["buf"].get_ipc_handle()
            blob = pickle.dumps(o["handle"])
            o["sent"].add(dest)
        head = np.zeros(_HEAD, np.int64)
        head[:12] = [_WIRE, self.src, self.slot, self.version, self.gen, self.m0, self.m, self.ncells,
                     self.dim, self.dtype.itemsize, self.nb, len(blob)]
        head[12:15] = self.dims
        head[15:18] = self.origin.view(np.int64)
        head[18] = np.array([self.size], np.float64).view(np.int64)[0]
        head[19] = np.array([self.moved], np.float64).view(np.int64)[0]
        return np.concatenate([head.view(np.uint8), np.frombuffer(blob, np.uint8)])

    @classmethod
    def from_wire(cls, buf: np.ndarray) -> "DeviceEdge":
        head = buf[:8 * _HEAD].view(np.int64)
        if int(head[0]) != _WIRE:
            raise CommError(f"--halo-transport ipc: edge message of layout {int(head[0])}, expected {_WIRE}")
        nblob = int(head[11])
        handle = pickle.loads(buf[8 * _HEAD:8 * _HEAD + nblob].tobytes()) if nblob else None
        dtype = {4: np.float32, 8: np.float64}[int(head[9])]
        f = head[15:20].view(np.float64)
        return cls(head[1], head[2], head[3], head[4], head[5], head[6], head[7], head[12:15], f[:3], f[3], f[4],
                   head[8], dtype, head[10], handle=handle)

    # host copies for the host-side pair count (benchmarks)
    def rows(self) -> int:
        """The true row count (the last cell start; a device read)."""
        if self.views is None or not self.m:
            return 0
        return int(self.views["start"][2 * self.ncells:2 * self.ncells + 1].copy_to_host()[0])

    @property
    def pos(self) -> np.ndarray:
        m = self.rows()
        if not m:
            return np.zeros((0, self.dim))
        p4 = self.views["pos4"][:4 * m].copy_to_host().reshape(-1, 4)
        return p4[:, :self.dim].astype(np.float64) + self._ref[:self.dim]

    @property
    def kind(self) -> np.ndarray:
        m = self.rows()
        return self.views["kind"][:m].copy_to_host() if m else np.zeros(0, np.int8)


def edge_layout(m: int, nch: int, dtype):
    """The slot's byte layout: generation header (16 bytes), pos4 and vel4 records (16-byte
    aligned: the force kernels load a record in one access), cell starts (2 nch + 1),
    kinds: ({name: (offset, dtype, count)}, total bytes)."""
    dt = np.dtype(dtype)
    out, off = {}, 0
    for name, t, cnt in (("head", np.int64, 2), ("pos4", dt, 4 * m), ("vel4", dt, 4 * m),
                         ("start", np.int32, 2 * nch + 1), ("kind", np.int8, m)):
        t = np.dtype(t)
        out[name] = (off, t, int(cnt))
        off += t.itemsize * int(cnt)
    return out, off


def edge_ranges(be, state, dv, domain):
    """{direction: (first plane, planes, fluid rows, boundary rows)} of the current sort:
    the cell planes within reach of each cut (one cell of margin for rows moved since the
    sort) and bounds on the fluid and boundary rows they hold. The exact row ranges
    (a0, b0, a1, b1 per direction) go into the device array `pick8` (k_pick8), where the
    pack, the halo forces and the reduction read them: the host needs only the bounds,
    which the last check counted (`band_counts`, plus rows that arrived since), so no
    wait. Without them (the first sort, moved cuts) the ranges come to the host once
    (one wait) and are their own bounds. Kept per sort for the other edge, the halo
    forces and the second stage."""
    got = dv.edge_ranges
    if got is not None and got[0] == dv.sort_gen and got[1] == (domain.lo, domain.hi):
        return got[2]
    g = dv.grid
    n0, n1, n2 = (int(x) for x in g["dims"])
    ncells = int(g["ncells"])
    plane = n0 * n1
    planes = {}
    if np.isfinite(domain.lo):
        c = min(int(np.floor((domain.lo + domain.reach - g["origin"][2]) * g["inv"])) + 1, n2 - 1)
        planes[-1] = (0, max(c + 1, 0))
    if np.isfinite(domain.hi):
        c = max(int(np.floor((domain.hi - domain.reach - g["origin"][2]) * g["inv"])) - 1, 0)
        planes[1] = (min(c, n2), n2 - min(c, n2))
    idx = []
    for d in (-1, 1):
        c0, np_ = planes.get(d, (0, 0))
        idx += [c0 * plane, (c0 + np_) * plane, ncells + c0 * plane, ncells + (c0 + np_) * plane]
    A = dv.arrays
    if "pick8" not in A:
        A["pick8"] = dev_array(8, np.int32)
        dv.pinned_i8 = pinned_array(8, np.int32)
    s = be._s(state)
    hk = be._on(state, HK.build(dv.dtype))
    hk.k_pick8[1, 1](A["start"], *idx, A["pick8"])
    bound = dv.edge_bound
    if bound is not None and bound[0] == (domain.lo, domain.hi, domain.reach):
        out = {d: (planes[d][0], planes[d][1], *bound[1][d]) for d in planes}
    else:
        h = dv.pinned_i8
        A["pick8"].copy_to_host(h, stream=s)
        host_wait(s)
        count_bytes(state, "d2h_bytes", "edge", 32)
        v = [int(x) for x in h]
        out = {d: (planes[d][0], planes[d][1], v[4 * k + 1] - v[4 * k], v[4 * k + 3] - v[4 * k + 2])
               for k, d in enumerate((-1, 1)) if d in planes}
    dv.edge_ranges = (dv.sort_gen, (domain.lo, domain.hi), out)
    return out


def band_counts(be, state, dv, k):
    """In the check (after the step's last move): launch the count of the rows that the next
    sort's edges can hold -- every row within reach of a cut plus three cells -- into
    `band` (fluid, boundary below the lower cut's band; the same above the upper one),
    copied with the check's own results (no wait of its own). `take_band` reads it."""
    dom = dv.domain
    if dom is None or not dv.n:
        return False
    A = dv.arrays
    if "band" not in A:
        A["band"] = dev_array(4, np.int32)
        dv.pinned_band = pinned_array(4, np.int32)
    c = state.consts
    wide = dom.reach + 3.0 * c.cell_size
    tlo = dom.lo + wide if np.isfinite(dom.lo) else -np.inf
    thi = dom.hi - wide if np.isfinite(dom.hi) else np.inf
    k.k_fill[1, 32](A["band"], 4, 0)
    be._on(state, HK.build(dv.dtype)).k_band_counts[CK.blocks(dv.n), CK.BLOCK](
        A["p" + VEC[dom.axis]], A["kind"], dv.n, float(tlo), float(thi), A["band"])
    A["band"].copy_to_host(dv.pinned_band, stream=be._s(state))
    dv.band_for = (dom.lo, dom.hi, dom.reach)
    return True


def take_band(dv) -> None:
    """After the check's wait: the counts become the next sort's edge bounds (1 % and 256
    rows of slack on top of the three cells)."""
    h = dv.pinned_band
    f_lo, b_lo, f_hi, b_hi = (int(x) for x in h)
    pad = lambda m: m + m // 100 + 256   # noqa: E731
    dv.edge_bound = (dv.band_for, {-1: (pad(f_lo), pad(b_lo)), 1: (pad(f_hi), pad(b_hi))})


def grow_bounds(dv, m_fluid, m_bound) -> None:
    """Rows arrived after the check: each edge may hold them all."""
    b = dv.edge_bound
    if b is not None:
        dv.edge_bound = (b[0], {d: (f + m_fluid, bb + m_bound) for d, (f, bb) in b[1].items()})


def send_edge(be, state, dv, domain, direction, slot) -> DeviceEdge:
    """The edge towards `direction` packed into this rank's buffer for `slot` (the message
    tag), an event recorded after it; no host wait. The slot's layout is by the row bound:
    the true count is on the device, in the packed cell starts."""
    c0, npl, fb, bb = edge_ranges(be, state, dv, domain)[direction]
    cap = edge_capacity(fb + bb)
    g = dv.grid
    n0, n1 = int(g["dims"][0]), int(g["dims"][1])
    nch = n0 * n1 * npl
    lay, nb = edge_layout(cap, nch, dv.dtype)
    slots = dv.edge_slots
    e = slots.get(slot)
    if e is None or e["buf"].shape[0] < nb:
        old = e
        e = {"buf": dev_array(int(nb * 1.5) + 4096, np.uint8), "version": 0 if old is None else
             old["version"] + 1, "gen": 0 if old is None else old["gen"], "sent": set(), "handle": None,
             "event": new_event(False), "retired": [] if old is None else old["retired"] + [old["buf"]]}
        slots[slot] = e
    e["gen"] += 1
    d = kept_views(e, e["buf"], lay, nb)
    A = dv.arrays
    if "edge_over" not in A:
        A["edge_over"] = dev_array(1, np.int32)
        be._on(state, CK.build(dv.dtype)).k_fill[1, 1](A["edge_over"], 1, 0)
    hk = be._on(state, HK.build(dv.dtype))
    s = be._s(state)
    be._on(state, CK.build(dv.dtype)).k_fill[1, 1](d["head"], 1, e["gen"])     # head[0]: the generation
    # a grid-stride loop: the launch covers the rows' bound, not the slot's rounded capacity
    hk.k_halo_pack[min(CK.blocks(max(fb + bb, 2 * nch + 1)), 4096), CK.BLOCK](
        A["start"], c0 * n0 * n1, nch, int(g["ncells"]), A["pos4"], A["vel4"], A["kind"], cap,
        d["start"], d["pos4"], d["vel4"], d["kind"], A["edge_over"])
    e["event"].record(s if s else 0)
    dv.mdbc_edges[direction] = ("slot", slot, c0 * n0 * n1, nch, cap, bb)     # mdbc_edge: the same planes again
    state.bytes_sent += nb
    origin = np.array(g["origin"], np.float64)
    origin[2] += c0 * g["size"]
    dims = (n0, n1, npl)
    return DeviceEdge(state.rank, slot, e["version"], e["gen"], fb, cap, nch, dims, origin, g["size"], dv.moved,
                      dv.dim, dv.dtype, nb, array=e["buf"], owner=e, event=e["event"])


def _peer_buffer(dv, edge):
    """The sender's buffer: itself (same process) or its IPC mapping, opened once per
    buffer and kept (a new version closes the old mapping)."""
    if edge.array is not None:
        return edge.array
    peers = dv.edge_peers
    key = (edge.src, edge.slot)
    have = peers.get(key)
    if have is not None and have["version"] == edge.version:
        return have["array"]
    if edge.handle is None:
        raise CommError(f"--halo-transport ipc: rank {edge.src}'s edge (tag {edge.slot}, buffer "
                        f"{edge.version}) came without the IPC handle of its buffer")
    if have is not None:
        have["handle"].close()
    arr = edge.handle.open()
    peers[key] = {"version": edge.version, "handle": edge.handle, "array": arr}
    return arr


def receive_edge(be, state, edge) -> None:
    """`edge` becomes the halo: its views on the sender's buffer, read after the pack
    (the receiver's stream waits for the sender's event; between processes the sender
    waited before sending, and the generation number is checked)."""
    dv = state.extra["dev"]
    edge._ref = dv.ref
    if edge.m == 0:
        edge.views = None
        return
    if edge.dtype != dv.dtype or edge.dim != dv.dim:
        raise CommError(f"--halo-transport ipc: rank {edge.src} sent {edge.dim}D {edge.dtype} rows to a "
                        f"{dv.dim}D {dv.dtype} rank")
    lay, nb = edge_layout(edge.m, edge.ncells, dv.dtype)
    buf = _peer_buffer(dv, edge)
    s = be._s(state)
    if edge.event is not None:
        if s:
            edge.event.wait(s)
        else:
            edge.event.wait()
    else:
        _check_generation(be, state, dv, edge, buf)
    # views kept per (sender, tag): a receiver reads each of its peers' slots
    edge.views = kept_views(dv.edge_views.setdefault((edge.src, edge.slot), {}), buf, lay, nb)
    be._log(state, "halo_views", edge.slot, edge.gen)


def _check_generation(be, state, dv, edge, buf):
    """Between processes: the buffer's generation number must be the message's (a buffer
    rewritten before it was read is a CommError, not wrong halos). Its 8 bytes are copied
    on the receive's stream and checked after the rank's next host wait (`check_generations`,
    from dt_local): no wait of its own."""
    pend = dv.gen_pending
    pool = dv.gen_pinned
    while len(pool) <= len(pend):
        pool.append(pinned_array(1, np.int64))
    h = pool[len(pend)]
    buf[:8].view(np.int64).copy_to_host(h, stream=be._s(state))
    pend.append((edge.src, edge.slot, edge.gen, h))


def check_generations(state, dv) -> None:
    """The generation numbers copied by `_check_generation`, after a host wait that
    followed those copies."""
    pend = dv.gen_pending
    if not pend:
        return
    bad = next(((src, slot, gen, int(h[0])) for src, slot, gen, h in pend if int(h[0]) != gen), None)
    pend.clear()
    if bad is not None:
        src, slot, gen, got = bad
        raise CommError(f"--halo-transport ipc: rank {src}'s edge buffer (tag {slot}) was rewritten "
                        f"before rank {state.rank} read it: generation {got}, expected {gen}")


def ranged_parts(dv) -> list:
    """[(used, offset in pick8, part buffers)] for halo sides 1 and 2 of a reduction with
    ipc halo parts (each added at its own target rows): an unused side passes the interior
    buffers, which the kernel does not read."""
    P = dv.parts
    out = []
    for side in (1, 2):
        name = f"halo_{side}"
        r = dv.halo_ranges.get(side) if name in P else None
        out.append((1 if r is not None else 0, r or 0, P[name] if r is not None else P["interior"]))
    return out
