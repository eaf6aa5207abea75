"""Device memory of the numba.cuda backend: a rank's `DeviceState` (its device arrays
and pinned host buffers), the counted allocation helpers and host waits (`COUNTERS`),
the byte counters of the bus (`count_bytes`) and the packing of several arrays in one
buffer (`layout`, `split`, `row_layout`).

Precision: positions are float64 on the device (no loss of resolution in a large
domain); velocities, densities, pressures and all force arithmetic are in the run's
type (float32 by default). The force loop reads float copies of the positions
relative to a per-rank reference point (the first bounding-box minimum), so a
float32 pair distance resolves ~6e-8 of the scene's extent, not of |x|.
"""
from __future__ import annotations

import numpy as np
from numba import cuda

from . import cuda_kernels as CK
from .cuda_lanes import new_event

VEC = ("x", "y", "z")


# per process (mock ranks share it): what the step costs the host in allocations and waits
COUNTERS = {"device_alloc": 0, "pinned_alloc": 0, "host_wait": 0, "images_repacked": 0}


def dev_array(n, dtype):
    """cuda.device_array, counted (COUNTERS["device_alloc"])."""
    COUNTERS["device_alloc"] += 1
    return cuda.device_array(n, dtype)


def pinned_array(n, dtype):
    """A page-locked host array (plain numpy in the simulator), counted."""
    COUNTERS["pinned_alloc"] += 1
    return cuda.pinned_array(n, dtype) if not CK.SIMULATOR else np.zeros(n, dtype)


def host_wait(stream):
    """The host waits for `stream` only (0, the default stream: the copy before was
    synchronous); either way a host wait, counted."""
    COUNTERS["host_wait"] += 1
    if stream:
        stream.synchronize()


def count_bytes(state, direction, kind, nbytes):
    """`nbytes` more crossed the bus in `direction` ("h2d_bytes" / "d2h_bytes") for `kind`."""
    e = state.extra
    e[direction] = e.get(direction, 0) + int(nbytes)
    by = e.setdefault("bytes_by_kind", {})
    k = f"{direction[:3]}:{kind}"
    by[k] = by.get(k, 0) + int(nbytes)


class DeviceState:
    """Device arrays of one rank (structure of arrays) and the pinned host buffers."""

    def __init__(self, n, dim, dtype, ref):
        self.n = n
        self.dim = dim
        self.dtype = np.dtype(dtype)
        self.ref = np.asarray(ref, np.float64)     # reference point of the float positions
        self.arrays = {}                            # name -> device array (owned)
        self.views = {}                             # name -> view into an owned array (see make_views)
        self.nf = 0                                 # fluid rows: rows 0..nf-1 after each sort
        self.cap = max(n, 1)                        # rows allocated (>= n: room for arriving rows)
        self.grid = None                            # dict: origin(perm), dims, axes, inv, reach, ncells
        self.box = None                             # host bounding box [min3, max3] of the rows
        self.parts = {}
        self.cell_cap = 0
        self.scan_tmp = []
        self.pinned_dt = pinned_array(3, np.float64)
        self.pinned_chk = pinned_array(7, np.float64)
        self.pinned_bad = pinned_array(1, np.int64)
        self.pinned_i4 = pinned_array(4, np.int32)
        self.pinned_over = pinned_array(1, np.int32)   # dt's edge_over flag: read in dt_allreduce, after other tasks' pinned_i4
        self.pinned_meta = pinned_array(9, np.float64)  # the periodic images' count and box (cuda_images)
        self.images_cap = None                      # cuda_images: the bound its rows are packed to
        self.images_scan = []                       # cuda_images: its scan's block sums
        self.pinned_xfer = None                     # staging of packed messages (host_buf)
        self.halo_pool = []                         # reusable device buffers of halos (_halo_buffer)
        self.halo_last = None                       # the halo prepared last (may not be in state.halos yet)
        self.host_busy = None                       # event of an async copy still reading pinned_xfer
        self.busy_ev = None                         # the event object host_busy reuses
        self.host_stale = False
        self.final = True
        self.moved = np.inf                         # bound on any row's move since the sort (inf: unsorted)
        self.vmax = None                            # (step, fluid rows' fastest speed) from dt_local
        self.sort_gen = 0                           # sorts so far (what an edge's row ranges belong to)
        self.halo_ranges = {}                       # halo side -> own target rows (ipc halos; reduce_forces)
        self.host_obj = None                        # the host Particles the device rows were uploaded from
        self.integrator = None                      # the integrator of the last integrate (None: none yet)
        self.ddk_zeroed = None                      # cuda_dufort: the layout whose boundary K_a rows are zeroed
        self._scratch = {}                          # scratch views (scratch)
        self.permute_groups = {}                    # cuda_cells._permute_groups' cache
        # --halo-transport ipc (cuda_halo)
        self.domain = None                          # the slabs of the last device edge (the halo forces' cut)
        self.edge_slots = {}                        # message tag -> this rank's edge buffer
        self.edge_peers = {}                        # (rank, tag) -> a peer's buffer mapped here
        self.edge_views = {}                        # (rank, tag) -> the views of a peer's slot (kept_views)
        self.edge_ranges = None                     # (sort_gen, cut, ranges) of the current sort
        self.edge_bound = None                      # (cut, row bounds by direction) from the check
        self.band_for = None                        # the cut the band counts were launched for
        self.pinned_i8 = None                       # pinned host copies of pick8 and band
        self.pinned_band = None
        self.gen_pending = []                       # generation numbers to check (other processes)
        self.gen_pinned = []                        # their pinned host copies
        # mDBC on several ranks (cuda_mdbc)
        self.reads = {}                             # name -> payload of a pinned read started (start_read)
        self.read_events = {}                       # name -> the event that read waits for (kept)
        self.mdbc_edges = {}                        # direction -> the last edge's boundary rows (staged or slot)
        self.bound_arrived = 0                      # boundary rows appended since the upload (ghost table)

    # the arrays the sort and the migration read by name (prepare / make_views make them)
    px = property(lambda self: self.arrays["px"])
    py = property(lambda self: self.arrays["py"])
    pz = property(lambda self: self.arrays["pz"])
    kind = property(lambda self: self.arrays["kind"])
    start = property(lambda self: self.arrays["start"])
    perm = property(lambda self: self.views["perm"])

    def start_read(self, name, stream, payload=None) -> None:
        """Copies into pinned memory were queued on `stream` for the read `name`: an event
        after them; `wait_read(name)` waits for it and returns `payload`. The host waits
        late, so ranks sharing a host queue their work before any of them waits."""
        ev = self.read_events.get(name)
        if ev is None:
            ev = self.read_events[name] = new_event(False)
        ev.record(stream)
        self.reads[name] = payload

    def wait_read(self, name):
        """(True, payload) once the host waited for the read `name`; (False, None) when none
        is pending (read already)."""
        if name not in self.reads:
            return False, None
        payload = self.reads.pop(name)
        COUNTERS["host_wait"] += 1
        self.read_events[name].synchronize()
        return True, payload

    def A(self) -> dict:
        """Owned arrays and views by name."""
        return {**self.arrays, **self.views}

    def make_views(self):
        """Per-component views of the packed records, and the aliases that keep the
        footprint down: the sort's permutation lives in `ar` (dead from the integration to
        the next forces), and pos4 (rebuilt after each sort) is the sort's gather scratch
        and holds the histogram and the cell keys when they fit."""
        a, v = self.arrays, self.views
        v4, p4 = a["vel4"], a["pos4"]
        n = p4.shape[0] // 4
        for k, ax in enumerate(VEC):
            v["v" + ax] = _every4(v4, k)
            v["r" + ax] = _every4(p4, k)
        v["rho"] = _every4(v4, 3)
        v["press"] = _every4(p4, 3)
        v["perm"] = a["ar"].view(np.int32)[:n]

    def fit_fluid(self):
        """The reduced accelerations (ax, ay, az) hold fluid rows only: the rows are sorted
        fluid first, and only fluid rows move by them (12 B per boundary row saved in 3D).
        Room for every row the capacity may still bring being fluid; grown when fluid rows
        arrive beyond it (their values are rewritten by the next forces)."""
        # (in the simulator exactly the fluid rows: a boundary row's access is an IndexError there)
        want = max(self.nf + (0 if CK.SIMULATOR else self.cap - self.n), 1)
        for ax in VEC[:self.dim]:
            a = self.arrays.get("a" + ax)
            if a is None or a.shape[0] < self.nf or a.shape[0] < 1:
                self.arrays["a" + ax] = dev_array(want, self.dtype)

    def scratch(self, dtype, m, off=0):
        """m elements of `dtype` from element `off` on in the pos4 buffer (None when they
        do not fit)."""
        p4 = self.arrays["pos4"]
        if (off + m) * np.dtype(dtype).itemsize > p4.nbytes:
            return None
        # kept: a numba view costs tens of microseconds of host time, and the sort asks
        # for the same few every step
        c = self._scratch
        key = (id(p4), np.dtype(dtype).str, m, off)
        v = c.get(key)
        if v is None or v[0] is not p4:
            if len(c) > 32:
                c.clear()
            v = c[key] = (p4, p4.view(dtype)[off:off + m])
        return v[1]

    def host_buf(self, nbytes):
        """The first `nbytes` of a reusable page-locked host buffer (uint8; plain numpy in
        the simulator), grown with spare room when a message outgrows it. A copy out of
        it may still run on a lane stream (`host_busy`, an upload): it is waited for
        first; a copy into it is waited for by its caller, and what is read from it is
        copied out."""
        if self.host_busy is not None:
            COUNTERS["host_wait"] += 1
            self.host_busy.synchronize()
            self.host_busy = None
        b = self.pinned_xfer
        if b is None or b.shape[0] < nbytes:
            cap = int(nbytes * 1.5) + 4096
            b = self.pinned_xfer = pinned_array(cap, np.uint8)
        return b[:nbytes]

    def dev_buf(self, name, nbytes):
        """The first `nbytes` of the device scratch `arrays[name]` (uint8), grown with spare room."""
        a = self.arrays.get(name)
        if a is None or a.shape[0] < nbytes:
            a = self.arrays[name] = dev_array(int(nbytes * 1.5) + 4096, np.uint8)
        return a[:nbytes]

    def prm_d(self, state):
        """The run's parameters on the device (uploaded once)."""
        d = self.arrays.get("prm")
        if d is None:
            d = self.arrays["prm"] = cuda.to_device(np.ascontiguousarray(state.prm, self.dtype))
        return d

    def mark_host_busy(self, stream):
        """An upload from the pinned staging buffer was queued on `stream`: the next use of
        the buffer (host_buf) waits for it (the host does not wait here)."""
        if stream:
            if self.busy_ev is None:
                self.busy_ev = new_event(False)
            ev = self.busy_ev
            ev.record(stream)
            self.host_busy = ev

    def part_buffer(self, part, need):
        """The force part's output buffers (x, y, z, ar, ddt, cancel), reallocated when they
        hold fewer than `need` rows; sized by the row capacity, so they are kept while rows
        come and go."""
        buf = self.parts.get(part)
        if buf is None or buf["ar"].shape[0] < need:
            m = max(self.n, self.cap, 1)
            buf = {"x": dev_array(m, self.dtype), "y": dev_array(m, self.dtype),
                   "z": dev_array(m if self.dim == 3 else 1, self.dtype),
                   "ar": dev_array(m, self.dtype), "ddt": dev_array(m, self.dtype),
                   "cancel": dev_array(m, np.int8)}
            self.parts[part] = buf
        return buf

    def nbytes(self) -> int:
        seen = set()
        total = 0
        slots = self.edge_slots.values()
        for a in list(self.arrays.values()) + self.scan_tmp + [h["buf"] for h in self.halo_pool] + \
                [x for b in self.parts.values() for x in b.values()] + \
                [b for e in slots for b in [e["buf"]] + e["retired"]]:
            if id(a) not in seen:
                seen.add(id(a))
                total += a.nbytes
        return total


def _every4(a, k):
    """a[k::4] of a flat device array. Built from its descriptor: numba-cuda's own
    strided slicing walks every element in Python (7 s for 1 M records)."""
    if CK.SIMULATOR:
        return a[k::4]
    it = a.dtype.itemsize
    return type(a)(shape=((a.shape[0] - k + 3) // 4,), strides=(4 * it,), dtype=a.dtype,
                   gpu_data=a.gpu_data.view(k * it))


def layout(fields):
    """Packing of several arrays in one byte buffer: fields = [(name, dtype, count)] ->
    ({name: (offset, dtype, count)}, total bytes). Widest items first, so every offset
    is a multiple of its item size and nothing is padded (the bytes are the fields')."""
    out, off = {}, 0
    for name, dt, cnt in sorted(fields, key=lambda f: -np.dtype(f[1]).itemsize):
        dt = np.dtype(dt)
        out[name] = (off, dt, int(cnt))
        off += dt.itemsize * int(cnt)
    return out, off


def split(buf, lay):
    """Typed views of a flat uint8 buffer (host or device) by a `layout`."""
    return {k: buf[o:o + dt.itemsize * c].view(dt) for k, (o, dt, c) in lay.items()}


def kept_views(holder, buf, lay, nb):
    """split(buf[:nb], lay) of a kept device buffer, made once per (buffer, layout) and kept
    in the dict `holder`: numba-cuda's slicing costs tens of microseconds of host time a
    view, and a halo slot is written and read with the same layout step after step
    (`edge_capacity` rounds its row bound so that the layout rarely changes)."""
    key = (nb, tuple(lay.items()))
    got = holder.get("views")
    if got is not None and got[0] is buf and got[1] == key:
        return got[2]
    v = split(buf[:nb], lay)
    holder["views"] = (buf, key, v)
    return v


def edge_capacity(rows: int) -> int:
    """A halo slot's row bound rounded up to a multiple of about 1/32 of itself (at least
    4096 rows): the bound follows the band counts, which change by a few rows a step, and
    a new bound means new views and launch plans on both sides."""
    q = 1 << max(12, (max(int(rows), 1) // 32).bit_length())
    return -(-int(rows) // q) * q


def row_layout(dv, m):
    """m rows as rank-to-rank messages carry them (k_pack_leaving / k_unpack_rows):
    float64 positions, run-type records (history, vel4, rho_m1), kinds, ids."""
    return layout([("pos", np.float64, m * dv.dim), ("f", dv.dtype, m * (dv.dim + 5)), ("kind", np.int8, m),
                    ("id", dv.arrays["id"].dtype, m)])
