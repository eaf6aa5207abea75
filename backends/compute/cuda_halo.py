"""Halos device to device: `--halo-transport ipc` (issue 6 §7).

Staged (the default): the sender copies its edge rows to the host, MPI carries them, and the
receiver bins them by cell on the host and uploads them. With `ipc` the rows stay on the
devices:

sender (`numba_cuda.edge` given a slot)  packs its edge candidate ranges (k_pack_edge) into
    a device buffer of its own, one per message tag (direction and stage), behind a header
    holding a generation number (k_stamp); waits for its stream; sends a `DeviceEdge`:
    rows, cut, slot, generation and, the first time a buffer goes to a peer, the buffer's
    CUDA IPC handle, which the peer opens once and keeps.
receiver (`numba_cuda.prepare_halo`)     copies the rows out of the sender's buffer device to
    device (peer to peer across GPUs), checks the generation number, cuts them
    (k_edge_bounds: count and bounding box, one 72-byte copy to the host for the grid's
    size), bins them (k_edge_keys, the device scan, scatter, each cell's rows by old row:
    the order of `sphgraph.cells.counting_sort`) and gathers the halo arrays
    (k_edge_gather). Same grid and the same rows in the same order as the staged path: the
    same halo force sums, bit for bit.

One buffer per tag is enough: a slot is written again a step later (tags differ by stage),
and between the two writes the sender passes a dt allreduce that the receiver reaches only
after reading the slot (dt_local reads forces@1, which the halo force tasks accumulate, and
they read the received halos; the receiver's copy is complete when prepare_halo returns).
The header's generation number turns a violation into a CommError instead of wrong halos.

Mock ranks share one process and one device: the message carries the buffer itself (CUDA
will not open an IPC handle in the process that made it), so the same path runs in CI under
numba's CUDA simulator. A buffer that outgrows its slot is replaced and the old one kept
(a peer may still map it; edges are small).
"""
from __future__ import annotations

import copy
import pickle

import numpy as np
from numba import cuda

from sphgraph.errors import CommError

from . import cuda_kernels as CK

_WIRE = 1            # layout version of DeviceEdge.to_wire
_HEAD = 13           # int64 words before the pickled IPC handle


class DeviceEdge:
    """An edge message of the ipc transport; once received (`receive_edge`) it is the halo
    (`n` rows kept, `n_fluid` of them fluid, `press` its device arrays, `cells` its grid)."""

    def __init__(self, src, slot, version, gen, m, dim, dtype, thr, below, axis, nb,
                 array=None, handle=None, owner=None):
        self.src, self.slot, self.version, self.gen = int(src), int(slot), int(version), int(gen)
        self.m, self.dim, self.dtype = int(m), int(dim), np.dtype(dtype)
        self.thr, self.below, self.axis, self.nb = float(thr), bool(below), int(axis), int(nb)
        self.array = array          # the sender's buffer itself (mock ranks: one process)
        self.handle = handle        # its IPC handle (MPI ranks), sent once per buffer and peer
        self._owner = owner         # the sender's slot (to_wire: was the handle sent?)
        self.n = self.m             # rows; the rows kept once received
        self.n_fluid = None
        self.press = None
        self.cells = None
        self._ref = None

    def __deepcopy__(self, memo):
        # the mock comm freezes payloads: the rows live in the sender's device buffer, shared
        # as an IPC mapping would be (see the module doc for why it is not overwritten early)
        return copy.copy(self)

    def nbytes(self) -> int:
        """Bytes of the message (the rows move device to device)."""
        return 8 * (_HEAD + 1)

    # the wire form (backends.comm.mpi): int64 header, then the pickled handle if any
    def to_wire(self, dest: int) -> np.ndarray:
        o = self._owner
        blob = b""
        if o is not None and dest not in o["sent"]:
            if o.get("handle") is None:
                o["handle"] = o["buf"].get_ipc_handle()
            blob = pickle.dumps(o["handle"])
            o["sent"].add(dest)
        head = np.array([_WIRE, self.src, self.slot, self.version, self.gen, self.m, self.dim,
                         self.dtype.itemsize, int(self.below), self.axis, self.nb, len(blob), 0], np.int64)
        head[12] = np.array([self.thr], np.float64).view(np.int64)[0]
        return np.concatenate([head.view(np.uint8), np.frombuffer(blob, np.uint8)])

    @classmethod
    def from_wire(cls, buf: np.ndarray) -> "DeviceEdge":
        head = buf[:8 * _HEAD].view(np.int64)
        if int(head[0]) != _WIRE:
            raise CommError(f"--halo-transport ipc: edge message of layout {int(head[0])}, expected {_WIRE}")
        nblob = int(head[11])
        handle = pickle.loads(buf[8 * _HEAD:8 * _HEAD + nblob].tobytes()) if nblob else None
        dtype = {4: np.float32, 8: np.float64}[int(head[7])]
        thr = float(head[12:13].view(np.float64)[0])
        return cls(head[1], head[2], head[3], head[4], head[5], head[6], dtype, thr, bool(head[8]),
                   head[9], head[10], handle=handle)

    # host copies for the host-side pair count (benchmarks): from the device arrays
    @property
    def pos(self) -> np.ndarray:
        if self.press is None:
            return np.zeros((0, self.dim))
        cols = [self.press["r" + ax][:self.n].copy_to_host().astype(np.float64) + self._ref[i]
                for i, ax in enumerate("xyz"[:self.dim])]
        return np.stack(cols, axis=1)

    @property
    def kind(self) -> np.ndarray:
        if self.press is None:
            return np.zeros(0, np.int8)
        return self.press["kind"][:self.n].copy_to_host()


def edge_layout(m: int, dim: int, dtype):
    """The slot's byte layout: generation header, float64 positions, run-type vel4
    records, kinds (the fields of the staged path's edge copy)."""
    from .numba_cuda import _layout
    return _layout([("head", np.int64, 1), ("pos", np.float64, m * dim), ("v4", dtype, 4 * m),
                    ("kind", np.int8, m)])


def send_edge(be, state, dv, a0, m0, a1, m, thr, below, axis, slot) -> DeviceEdge:
    """Pack rows a0..a0+m0-1 and a1..a1+(m-m0)-1 into this rank's buffer for `slot` (the
    message tag) and describe them; the host waits for the copy before the message goes."""
    from . import numba_cuda as NC
    from .numba_cuda import _split, _wait
    k, s, A = be._k(state), be._s(state), dv.arrays
    lay, nb = edge_layout(m, dv.dim, dv.dtype)
    slots = dv.__dict__.setdefault("edge_slots", {})
    e = slots.get(slot)
    if e is None or e["buf"].shape[0] < nb:
        old = e
        e = {"buf": NC.dev_array(int(nb * 1.5) + 4096, np.uint8), "version": 0 if old is None else
             old["version"] + 1, "gen": 0 if old is None else old["gen"], "sent": set(), "handle": None,
             "retired": [] if old is None else old["retired"] + [old["buf"]]}
        slots[slot] = e
    e["gen"] += 1
    d = _split(e["buf"][:nb], lay)
    k.k_stamp[1, 1](d["head"], e["gen"])
    if m:
        k.k_pack_edge[CK.blocks(m), CK.BLOCK](A["px"], A["py"], A["pz"], A["vel4"], A["kind"], a0, m0, a1, m,
                                               dv.dim, d["pos"], d["v4"], d["kind"])
    _wait(s)
    state.bytes_sent += nb
    return DeviceEdge(state.rank, slot, e["version"], e["gen"], m, dv.dim, dv.dtype, thr, below, axis, nb,
                      array=e["buf"], owner=e)


def _peer_buffer(dv, edge):
    """The sender's buffer: itself (same process) or its IPC mapping, opened once per
    buffer and kept (a new version closes the old mapping)."""
    if edge.array is not None:
        return edge.array
    peers = dv.__dict__.setdefault("edge_peers", {})
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
    """Bring a DeviceEdge's rows over, cut and bin them on the device: `edge` becomes the
    halo, with the device arrays the halo force kernels read."""
    from sphgraph.cells import CellGrid, reach_cells
    from . import numba_cuda as NC
    from .numba_cuda import _VEC, _count, _layout, _split, _wait, device_grid
    dv = state.extra["dev"]
    k, s = be._k(state), be._s(state)
    c = state.consts
    dim, dt, m = dv.dim, dv.dtype, edge.m
    edge._ref = dv.ref
    if m == 0:
        edge.n, edge.n_fluid, edge.cells, edge.press = 0, 0, None, None
        return
    if edge.dtype != dt or edge.dim != dim:
        raise CommError(f"--halo-transport ipc: rank {edge.src} sent {edge.dim}D {edge.dtype} rows to a "
                        f"{dim}D {dt} rank")
    lay, nb = edge_layout(m, dim, dt)
    tag = edge.slot
    be._copy_mark(state, "halo_d2d", True)
    raw = dv.dev_buf(f"edge_in{tag}", nb)
    raw.copy_to_device(_peer_buffer(dv, edge)[:nb], stream=s)     # device to device
    d = _split(raw, lay)
    meta = dv.arrays.get(f"edge_meta{tag}")
    if meta is None:
        meta = dv.arrays[f"edge_meta{tag}"] = NC.dev_array(9, np.float64)
    k.k_edge_init[1, 1](d["head"], meta)
    k.k_edge_bounds[min(CK.blocks(m, 256), CK.REDUCE_BLOCKS), 256](d["pos"], d["kind"], m, dim, edge.axis,
                                                                   edge.thr, edge.below, meta)
    hm = dv.pinned_meta
    meta.copy_to_host(hm, stream=s)
    _wait(s)
    _count(state, "d2d_bytes", "halo", nb)
    _count(state, "d2h_bytes", "halo_meta", meta.nbytes)
    if int(hm[8]) != edge.gen:
        raise CommError(f"--halo-transport ipc: rank {edge.src}'s edge buffer (tag {tag}) was rewritten "
                        f"before rank {state.rank} read it: generation {int(hm[8])}, expected {edge.gen}")
    kept = int(hm[0])
    edge.n, edge.n_fluid = kept, int(hm[1])
    if kept == 0:
        edge.cells, edge.press = None, None
        be._copy_mark(state, "halo_d2d", False)
        return
    # the grid over the kept rows' bounding box
    axes = np.asarray(state.axes, np.int64)
    lo, hi, dims, o_ax, n_ax, s_ax = device_grid(hm[2:5], hm[5:8], c.cell_size, axes)
    ncells = int(dims.prod())
    # the halo's arrays in a pooled buffer (numba_cuda._halo_buffer: lives while tasks read it)
    names = ["r" + ax for ax in _VEC[:dim]] + ["v" + ax for ax in _VEC[:dim]] + ["rho", "press"]
    hl, hnb = _layout([("start", np.int64, ncells + 1), ("kind", np.int8, kept)] + [(x, dt, kept) for x in names])
    dd = _split(be._halo_buffer(state, dv, edge, hnb), hl)
    for ax in _VEC[dim:]:                    # 2D: one-element dummies (never read)
        dd["r" + ax] = dd["v" + ax] = dv.arrays["az"]
    sl, snb = _layout([("counts", np.int64, ncells + 1), ("keys", np.int32, m), ("perm", np.int32, m)])
    sc = _split(dv.dev_buf(f"edge_sort{tag}", snb), sl)
    counts, start = sc["counts"], dd["start"]
    inv = 1.0 / c.cell_size
    k.k_fill[CK.blocks(ncells + 1), CK.BLOCK](counts, ncells + 1, 0)
    k.k_edge_keys[CK.blocks(m), CK.BLOCK](d["pos"], m, dim, edge.axis, edge.thr, edge.below, o_ax[0], o_ax[1],
                                          o_ax[2], inv, n_ax[0], n_ax[1], n_ax[2], s_ax[0], s_ax[1], s_ax[2],
                                          ncells, sc["keys"], counts)
    tmp = dv.__dict__.setdefault("edge_scan", {}).setdefault(tag, [])
    be._scan(dv, k, counts, start, ncells + 1, tmp=tmp)     # start[ncells] = rows kept
    k.k_copy[CK.blocks(ncells + 1), CK.BLOCK](start, ncells + 1, counts)   # fill pointers
    k.k_scatter[CK.blocks(m), CK.BLOCK](sc["keys"], m, counts, sc["perm"])
    k.k_sort_cells[CK.blocks(ncells), CK.BLOCK](start, ncells, sc["perm"])
    ref = np.zeros(3)
    ref[:dim] = dv.ref
    k.k_edge_gather[CK.blocks(kept), CK.BLOCK](d["pos"], d["v4"], d["kind"], sc["perm"], kept, dim,
                                               float(ref[0]), float(ref[1]), float(ref[2]), dv.prm_d(state),
                                               dd["rx"], dd["ry"], dd["rz"], dd["vx"], dd["vy"], dd["vz"],
                                               dd["rho"], dd["press"], dd["kind"])
    be._copy_mark(state, "halo_d2d", False)
    reach = reach_cells(c.h, c.cell_size)
    edge.press = dd
    edge.cells = CellGrid(origin=lo, size=c.cell_size, dims=dims, axes=axes, start=None, reach=reach, hi=hi)
