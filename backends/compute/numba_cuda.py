"""numba.cuda backend: the whole step on the GPU, particle arrays resident between steps.

Device data of a rank live in `state.extra["dev"]` (a `DeviceState`); the host
`state.particles` is brought up to date only when asked (`host_arrays` for frames,
`sync_host` for the comm layer, a failed check). Per step, what crosses the bus is
the dt terms (3 float64), the check result with the rows' bounding box (8 numbers),
and, with several ranks, halos and displaced rows; the counters are
`state.extra["h2d_bytes"]` / `["d2h_bytes"]` (cumulative) and `["bytes_by_kind"]`.

Precision: positions are float64 on the device (no loss of resolution in a large
domain); velocities, densities, pressures and all force arithmetic are in the run's
type (float32 by default). The force loop reads float copies of the positions
relative to a per-rank reference point (the first bounding-box minimum), so a
float32 pair distance resolves ~6e-8 of the scene's extent, not of |x|.

Lanes (issue 6 §3): each rank gets one CUDA stream per schedule lane (compute, comm,
copy), created once, and every kernel launch and copy of a task goes on its lane's
stream (`_k`, `_s`). A cross-lane dependency of the rank's graph (the scheduler's
`LaneStep`, from `graph.build.lane_edges`) is an event recorded on the producer's
stream at its end and waited on by the consumer's stream at its start; host-side
waits (a D2H copy the host must read) synchronise that stream only. Outside tasks
(set-up, check, frames) the backend works on the legacy default stream, which
orders itself against every lane stream. `SPHGRAPH_CUDA_STREAMS=0` runs everything
on the default stream, as before lanes (the same kernels and summation order, so
the same bits).
"""
from __future__ import annotations

import os

import numpy as np
from numba import cuda

from sphgraph.cells import grid_dims, reach_cells
from sphgraph.config import O_DDT, O_KERNEL, O_LAMINAR, P_RHO0, P_SUPPORT2
from sphgraph.registry import register

from . import cuda_dufort as CD
from . import cuda_halo as CH
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from . import cuda_launch as CL
from . import cuda_riemann as CR
from . import upload_kernels as UK
from .base import ComputeBackend, dt_from_terms

_VEC = ("x", "y", "z")
# Symplectic: the corrector's forces see the pressure of the predicted density (as
# numba-cpu and DualSPHysics); False would keep the step-start pressure.
FRESH_PRESSURE = True
# Force rows trimmed to the sphere's chord along the rows of cells (cells sorted by that
# coordinate; k_forces_fv). SPHGRAPH_CUDA_TRIM=0: whole cells, as k_forces_f.
TRIM = os.environ.get("SPHGRAPH_CUDA_TRIM", "1") != "0"
TRIM_OFF = 1e30          # tpad that keeps every row whole (finite: fastmath assumes no inf)
UPLOAD_ROWS = 1 << 23    # rows a chunk of the upload (prepare): a 256 MiB staging buffer


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
        self.pinned_meta = pinned_array(9, np.float64)  # cuda_halo
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

    def __getattr__(self, name):
        d = self.__dict__
        if name in d.get("arrays", {}):
            return d["arrays"][name]
        if name in d.get("views", {}):
            return d["views"][name]
        raise AttributeError(name)

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
        for k, ax in enumerate(_VEC):
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
        for ax in _VEC[:self.dim]:
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
        c = self.__dict__.setdefault("_scratch", {})
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

    def nbytes(self) -> int:
        seen = set()
        total = 0
        slots = self.__dict__.get("edge_slots", {}).values()     # cuda_halo (ipc transport)
        scans = [a for t in self.__dict__.get("edge_scan", {}).values() for a in t]
        for a in list(self.arrays.values()) + self.scan_tmp + [h["buf"] for h in self.halo_pool] + \
                [x for b in self.parts.values() for x in b.values()] + \
                [b for e in slots for b in [e["buf"]] + e["retired"]] + scans:
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


def _layout(fields):
    """Packing of several arrays in one byte buffer: fields = [(name, dtype, count)] ->
    ({name: (offset, dtype, count)}, total bytes). Widest items first, so every offset
    is a multiple of its item size and nothing is padded (the bytes are the fields')."""
    out, off = {}, 0
    for name, dt, cnt in sorted(fields, key=lambda f: -np.dtype(f[1]).itemsize):
        dt = np.dtype(dt)
        out[name] = (off, dt, int(cnt))
        off += dt.itemsize * int(cnt)
    return out, off


def _split(buf, lay):
    """Typed views of a flat uint8 buffer (host or device) by a _layout."""
    return {k: buf[o:o + dt.itemsize * c].view(dt) for k, (o, dt, c) in lay.items()}


def _row_layout(dv, m):
    """m rows as rank-to-rank messages carry them (k_pack_leaving / k_unpack_rows):
    float64 positions, run-type records (history, vel4, rho_m1), kinds, ids."""
    return _layout([("pos", np.float64, m * dv.dim), ("f", dv.dtype, m * (dv.dim + 5)), ("kind", np.int8, m),
                    ("id", dv.arrays["id"].dtype, m)])


def device_grid(box_lo, box_hi, cell_size, axes):
    """The grid over a bounding box given along the particle axes, as
    sphgraph.cells.build_grid makes it: origin, upper corner and cells along (fast, mid,
    slow), and per particle axis the origin, cell count and key stride the key kernels take
    (build_cells; a halo binned on the device, cuda_halo)."""
    lo, hi = np.zeros(3), np.zeros(3)
    for kk in range(3):
        a = axes[kk]
        if a >= 0:
            lo[kk], hi[kk] = box_lo[a], box_hi[a]
    dims = grid_dims(lo, hi, cell_size, axes)
    stride = np.array([1, dims[0], dims[0] * dims[1]], np.int64)
    o_ax, n_ax, s_ax = np.zeros(3), np.ones(3, np.int64), np.zeros(3, np.int64)
    for kk in range(3):
        a = axes[kk]
        if a >= 0:
            o_ax[a], n_ax[a], s_ax[a] = lo[kk], dims[kk], stride[kk]
    return lo, hi, dims, o_ax, n_ax, s_ax


def _count(state, direction, kind, nbytes):
    e = state.extra
    e[direction] = e.get(direction, 0) + int(nbytes)
    by = e.setdefault("bytes_by_kind", {})
    k = f"{direction[:3]}:{kind}"
    by[k] = by.get(k, 0) + int(nbytes)


class _OnStream:
    """A kernel namespace whose launches go on `stream`: `k.name[grid, block](...)` is
    `kernel[grid, block, stream](...)`."""

    __slots__ = ("ns", "stream")

    def __init__(self, ns, stream):
        self.ns, self.stream = ns, stream

    def __getattr__(self, name):
        return _Launch(getattr(self.ns, name), self.stream)


class _Launch:
    __slots__ = ("kern", "stream")

    def __init__(self, kern, stream):
        self.kern, self.stream = kern, stream

    def __getitem__(self, cfg):
        return self.kern[cfg[0], cfg[1], self.stream]


def _event(timing):
    """A CUDA event (the simulator's takes no timing flag)."""
    return cuda.event() if CK.SIMULATOR else cuda.event(timing=timing)


# per process (mock ranks share it): what the step costs the host in allocations and waits
COUNTERS = {"device_alloc": 0, "pinned_alloc": 0, "host_wait": 0}


def dev_array(n, dtype):
    """cuda.device_array, counted (COUNTERS["device_alloc"])."""
    COUNTERS["device_alloc"] += 1
    return cuda.device_array(n, dtype)


def pinned_array(n, dtype):
    """A page-locked host array (plain numpy in the simulator), counted."""
    COUNTERS["pinned_alloc"] += 1
    return cuda.pinned_array(n, dtype) if not CK.SIMULATOR else np.zeros(n, dtype)


def _wait(stream):
    """The host waits for `stream` only (0, the default stream: the copy before was
    synchronous); either way a host wait, counted."""
    COUNTERS["host_wait"] += 1
    if stream:
        stream.synchronize()


class Lanes:
    """One rank's lane streams (created once, on first use) and the events between them.

    `events[task]` is recorded on the task's stream at its end when a task on another
    lane depends on it; `tails[lane]` at the end of the step's last task (the next
    step's first task of every other lane waits for it). `current` is the running
    task's stream (None outside tasks: the default stream)."""

    def __init__(self):
        self.streams: dict = {}
        self.events: dict = {}
        self.tails: dict = {}
        self.current = None
        self.task = None           # name of the running task (device trace)
        self.read: list = []       # halo pool entries the running task reads (their read events)

    def stream(self, lane):
        s = self.streams.get(lane)
        if s is None:
            s = self.streams[lane] = cuda.stream()
        return s

    def event(self, table, key):
        e = table.get(key)
        if e is None:
            e = table[key] = _event(False)
        return e


def _per_thread_default_stream() -> bool:
    """numba's per-thread default stream does not order itself against other streams:
    lanes are off then (everything on the default stream)."""
    v = os.environ.get("NUMBA_CUDA_PER_THREAD_DEFAULT_STREAM")
    if v is not None:
        return v not in ("", "0")
    try:
        from numba import config
        return bool(getattr(config, "CUDA_PER_THREAD_DEFAULT_STREAM", 0))
    except Exception:  # noqa: BLE001
        return False


_SELECTED = []


def _select_device():
    """Under mpiexec, one rank per GPU: the node-local rank (MPICH's MPI_LOCALRANKID,
    Open MPI's OMPI_COMM_WORLD_LOCAL_RANK, else the global rank) picks GPU rank % ngpu,
    before any other CUDA call of this process. SPHGRAPH_CUDA_DEVICE overrides."""
    if _SELECTED or CK.SIMULATOR:
        return
    _SELECTED.append(True)
    v = os.environ.get("SPHGRAPH_CUDA_DEVICE")
    if v is None:
        for var in ("MPI_LOCALRANKID", "OMPI_COMM_WORLD_LOCAL_RANK", "PMI_RANK", "OMPI_COMM_WORLD_RANK"):
            if os.environ.get(var) is not None:
                v = os.environ[var]
                break
    if v is None:
        return
    ngpu = len(cuda.gpus)
    if ngpu > 1:
        cuda.select_device(int(v) % ngpu)


def _plain_slabs(domain, *methods) -> bool:
    """The device edge/displaced paths reproduce sphgraph.domain.Slabs; other domains
    (e.g. periodic images) get current host rows and their own methods."""
    from sphgraph.domain import Slabs
    t = type(domain)
    return all(getattr(t, m) is getattr(Slabs, m) for m in (methods or ("edge", "take_displaced")))


@register("compute", "numba-cuda")
class NumbaCUDA(ComputeBackend):
    default_precision = "float32"
    device_resident = True

    def __init__(self):
        self.sync_tasks = os.environ.get("SPHGRAPH_CUDA_SYNC", "0") == "1"  # profile: time kernels per task
        # schedule lanes as CUDA streams (the scheduler calls lane_begin / lane_end)
        self.uses_lanes = os.environ.get("SPHGRAPH_CUDA_STREAMS", "1") != "0" and not _per_thread_default_stream()
        self.lanes: dict = {}          # rank -> Lanes
        self.lane_log = None           # a list: every event record / wait appended (tests)
        self.trace = None              # a list: timing events per task and copy (start_device_trace)
        _select_device()

    @classmethod
    def unavailable(cls) -> str | None:
        # is_available() loads the driver library and, only where there is one, initialises it
        if CK.SIMULATOR or cuda.is_available():
            return None
        return ("no usable CUDA GPU or driver (numba.cuda.is_available() is False; "
                "NUMBA_ENABLE_CUDASIM=1 runs the simulator)")

    def device_name(self) -> str:
        if CK.SIMULATOR:
            return "cuda simulator"
        d = cuda.get_current_device()
        name = d.name.decode() if isinstance(d.name, bytes) else str(d.name)
        return f"cuda {name} (cc {d.compute_capability[0]}.{d.compute_capability[1]})"

    def counters(self) -> dict:
        return dict(COUNTERS)

    def _k(self, state):
        return self._on(state, CK.build(state.dtype))

    # -- lanes: streams and events -------------------------------------------------------
    def _s(self, state):
        """The stream of the running task (0: the default stream, outside tasks or lanes off)."""
        L = self.lanes.get(state.rank)
        return 0 if L is None or L.current is None else L.current

    def _on(self, state, kernels):
        kernels = CL.fast(kernels)
        s = self._s(state)
        return kernels if not s else _OnStream(kernels, s)

    def _log(self, state, *entry):
        if self.lane_log is not None:
            self.lane_log.append((state.rank, state.step) + entry)

    def lane_begin(self, state, task, step) -> None:
        """Before a task body: its lane's stream waits for the events of the tasks on other
        lanes it depends on (and, for the first task of a lane in the step, for the
        other lanes' previous step); the body's launches and copies then go on it."""
        L = self.lanes.get(state.rank)
        if L is None:
            L = self.lanes[state.rank] = Lanes()
        if task.collective:
            cuda.current_context()     # mock MPI runs a collective's bodies in threads of their own
        s = L.stream(step.lane)
        if step.first:
            for lane, ev in L.tails.items():
                if lane != step.lane:
                    ev.wait(s)
                    self._log(state, "wait_tail", task.name, lane)
        for u in step.waits:
            ev = L.events.get(u)
            if ev is not None:
                ev.wait(s)
                self._log(state, "wait", task.name, u)
        L.current, L.task = s, task.name
        if self.trace is not None:
            self._mark(state, task.name, step.lane, True)

    def lane_end(self, state, task, step) -> None:
        """After a task body: its event (when a task on another lane depends on it), the
        step-end events of every lane (after the step's last task); back to the default stream."""
        L = self.lanes[state.rank]
        s = L.current
        if self.trace is not None:
            self._mark(state, task.name, step.lane, False)
        if step.record:
            L.event(L.events, task.name).record(s)
            self._log(state, "record", task.name, step.lane)
        for e in L.read:
            L.event(e, "read_ev").record(s)
            self._log(state, "record_buffer", task.name, id(e))
        L.read.clear()
        if step.last:
            for lane, st in L.streams.items():
                L.event(L.tails, lane).record(st)
                self._log(state, "record_tail", task.name, lane)
        L.current = L.task = None

    # -- device trace (timing events; off unless start_device_trace) ---------------------
    def start_device_trace(self) -> None:
        """Record timing events from now on: per task on its lane's stream (start: when the
        stream reaches the task, after its waits; end: after its work) and around the edge
        and halo copies (`edge_d2h`, `halo_h2d`). Read them with `device_trace`."""
        cuda.synchronize()
        t0 = _event(True)
        t0.record()
        t0.synchronize()
        self.trace = []
        self._trace_t0 = t0
        self._trace_open = {}

    def _mark(self, state, label, lane, begin, inside=None):
        ev = _event(True)
        s = self._s(state) if lane is None else self.lanes[state.rank].stream(lane)
        ev.record(s)
        key = (state.rank, label)
        if begin:
            self._trace_open[key] = ev
        else:
            ev0 = self._trace_open.pop(key, None)
            if ev0 is not None:
                self.trace.append((state.rank, state.step, label, lane, inside, ev0, ev))

    def _copy_mark(self, state, label, begin):
        """Timing events around a copy, on the running task's stream (device trace only)."""
        if self.trace is not None:
            L = self.lanes.get(state.rank)
            lane = next((k for k, v in L.streams.items() if v is L.current), None) if L is not None else None
            self._mark(state, label, lane, begin, None if L is None else L.task)

    def device_trace(self) -> list:
        """[{rank, step, task, lane, inside, start, end}] in seconds since start_device_trace,
        from the device's clock (synchronises the device); `inside`: for a copy, the task that
        made it (None for a task)."""
        cuda.synchronize()
        t0 = self._trace_t0
        return [{"rank": r, "step": st, "task": lab, "lane": lane, "inside": inside,
                 "start": t0.elapsed_time(a) / 1e3, "end": t0.elapsed_time(b) / 1e3}
                for r, st, lab, lane, inside, a, b in (self.trace or [])]

    def _sync(self):
        if self.sync_tasks:
            cuda.synchronize()

    # -- set-up and transfers ----------------------------------------------------------
    def prepare(self, state) -> None:
        """Upload the host particles (all of them: called at set-up and after rows moved)."""
        p = state.particles
        dim = p.dim
        dt = np.dtype(state.dtype)
        old = state.extra.get("dev")
        if old is not None and old.__dict__.get("host_obj") is p and old.n == p.n:
            return   # same host row set as on the device (no rows left or came): keep the device rows
        lo = hi = None
        if p.n:     # the rows' bounding box (the first grid), one parallel pass (upload_kernels)
            lo, hi = np.empty(dim), np.empty(dim)
            UK.column_bounds(p.pos, lo, hi)
        # the reference point of the float positions: the run's (every rank the same, so a
        # rank's records are valid on its neighbours: ipc halos), else the rows' minimum
        if old is not None:
            ref = old.ref
        elif getattr(state, "ref", None) is not None:
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
            ax = _VEC[d]
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
        for ax in _VEC[dim:]:
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
        dv.__dict__["host_obj"] = p
        if old is not None and "integrator" in old.__dict__:
            dv.__dict__["integrator"] = old.__dict__["integrator"]
        if old is not None:     # staging and halo buffers outlive a re-upload
            if old.host_busy is not None:
                old.host_busy.synchronize()
            dv.pinned_xfer, dv.halo_pool, dv.halo_last = old.pinned_xfer, old.halo_pool, old.halo_last
            # --halo-transport ipc: this rank's edge buffers (their handles went to the peers
            # once) and the peers' buffers it has mapped (cuda_halo)
            for key in ("edge_slots", "edge_peers", "edge_scan"):
                if key in old.__dict__:
                    dv.__dict__[key] = old.__dict__[key]
        state.extra["dev"] = dv
        _count(state, "h2d_bytes", "upload", up)
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
            ax = _VEC[d]
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
        _count(state, "d2h_bytes", "sync_host", down)

    def device_rows_to_host(self, state, rows) -> dict:
        """Position, velocity, density, kind of device rows `rows` (host index array), as a
        halo/edge would carry them (phase 2 of multi-GPU: gathered on the device, pinned)."""
        self.sync_host(state)
        p = state.particles
        return {"pos": p.pos[rows], "vel": p.vel[rows], "rho": p.rho[rows], "kind": p.kind[rows]}

    # -- multi-rank: displaced rows and edges --------------------------------------------
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
        if "mig_cnt" not in A:
            A["mig_cnt"] = dev_array(1, np.int32)
        keep = dv.scratch(np.int32, n)             # the pos4 records are dead until the next
        pos = dv.scratch(np.int32, n, n)           # sort rebuilds them (ax holds fluid rows only)
        cnt = A["mig_cnt"]
        k.k_fill[1, 1](cnt, 1, 0)
        b = CK.blocks(n)
        k.k_mig_keep[b, CK.BLOCK](A["p" + _VEC[domain.axis]], n, float(domain.lo), float(domain.hi), keep, cnt)
        s = self._s(state)
        cnt.copy_to_host(dv.pinned_i4[:1], stream=s)
        _wait(s)
        m = int(dv.pinned_i4[0])
        _count(state, "d2h_bytes", "displaced", 4)
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

    def _rows_to_host(self, state, dv, k, keep, pos, m, domain):
        """The m rows with keep == 0 (pos: exclusive scan of keep) as host Particles by
        side, each in increasing row order: one packing launch, one copy to the pinned
        staging buffer; the side of a row is read from its position on the host (the
        same comparison as k_mig_keep)."""
        from sphgraph.particles import Particles
        p = state.particles
        n, dim, A = dv.n, dv.dim, dv.arrays
        lay, nb = _row_layout(dv, m)
        dbuf = dv.dev_buf("xfer", nb)
        d = _split(dbuf, lay)
        k.k_pack_leaving[CK.blocks(n), CK.BLOCK](keep, pos, n, dim, A["px"], A["py"], A["pz"], A["vmx"], A["vmy"],
                                                  A["vmz"], A["vel4"], A["rhom"], A["kind"], A["id"],
                                                  d["pos"], d["f"], d["kind"], d["id"])
        hb = dv.host_buf(nb)
        s = self._s(state)
        dbuf.copy_to_host(hb, stream=s)
        _wait(s)
        _count(state, "d2h_bytes", "displaced", nb)
        h = _split(hb, lay)
        P = h["pos"].reshape(m, dim)
        F = h["f"].reshape(m, dim + 5)
        x = P[:, domain.axis]
        out = {}
        for side, sel in ((-1, x < float(domain.lo)), (1, x >= float(domain.hi))):
            f = F[sel]                    # boolean indexing copies: nothing aliases the staging buffer
            out[side] = Particles(id=h["id"][sel].astype(np.int64), kind=h["kind"][sel],
                                  pos=P[sel].astype(p.pos.dtype, copy=False),
                                  vel=np.ascontiguousarray(f[:, dim:2 * dim]).astype(p.vel.dtype, copy=False),
                                  rho=np.ascontiguousarray(f[:, dim + 3]).astype(p.rho.dtype, copy=False),
                                  vel_m1=np.ascontiguousarray(f[:, :dim]).astype(p.vel_m1.dtype, copy=False),
                                  rho_m1=np.ascontiguousarray(f[:, dim + 4]).astype(p.rho_m1.dtype, copy=False))
        return out

    def _host_rows_changed(self, state, dv):
        """The host rows no longer match the device's in number: a stale placeholder of
        dv.n rows (np.empty: nothing is touched) that `sync_host` fills when asked."""
        from sphgraph.particles import Particles
        p, n, dim = state.particles, dv.n, dv.dim
        state.particles = q = Particles(
            id=np.empty(n, np.int64), kind=np.empty(n, np.int8), pos=np.empty((n, dim), p.pos.dtype),
            vel=np.empty((n, dim), p.vel.dtype), rho=np.empty(n, p.rho.dtype),
            vel_m1=np.empty((n, dim), p.vel_m1.dtype), rho_m1=np.empty(n, p.rho_m1.dtype))
        dv.__dict__["host_obj"] = q
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
        if (dv is None or dv.__dict__.get("host_obj") is not state.particles or dv.n + m > dv.cap or
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
        lay, nb = _row_layout(dv, m)
        hb = dv.host_buf(nb)
        h = _split(hb, lay)
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
        self._host_busy(dv, s)
        d = _split(dbuf, lay)
        self._k(state).k_unpack_rows[CK.blocks(m), CK.BLOCK](
            n, m, dim, d["pos"], d["f"], d["kind"], d["id"], A["px"], A["py"], A["pz"], A["vmx"], A["vmy"],
            A["vmz"], A["vel4"], A["rhom"], A["kind"], A["id"])
        up = nb
        dv.n = n + m
        dv.moved = np.inf          # rows moved in the arrays: no trimming until the next sort
        mf = int(np.count_nonzero(r.kind == 0))
        dv.nf += mf
        CH.grow_bounds(dv, mf, m - mf)
        dv.fit_fluid()
        if dv.box is not None:      # the next grid must hold the new rows
            dv.box[0, :dim] = np.minimum(dv.box[0, :dim], r.pos.min(axis=0))
            dv.box[1, :dim] = np.maximum(dv.box[1, :dim], r.pos.max(axis=0))
        _count(state, "h2d_bytes", "displaced", up)
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
            self.sync_host(state)
            return domain.edge(state, direction)
        if slot is not None:
            dv.__dict__["domain"] = domain      # the halo forces' targets: the same cut's rows
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
        _wait(s)
        a0, b0, a1, b1 = (int(x) for x in dv.pinned_i4)
        m0, m1 = max(b0 - a0, 0), max(b1 - a1, 0)
        m = m0 + m1
        pos, vel, rho, kind = [], [], [], []
        nb = 0
        if m:   # both ranges packed by one launch, one copy to the pinned staging buffer
            lay, nb = _layout([("pos", np.float64, m * dim), ("v4", dv.dtype, 4 * m), ("kind", np.int8, m)])
            dbuf = dv.dev_buf("xfer", nb)
            d = _split(dbuf, lay)
            k.k_pack_edge[CK.blocks(m), CK.BLOCK](A["px"], A["py"], A["pz"], A["vel4"], A["kind"], a0, m0, a1, m,
                                                   dim, d["pos"], d["v4"], d["kind"])
            hb = dv.host_buf(nb)
            dbuf.copy_to_host(hb, stream=s)
            _wait(s)
            h = _split(hb, lay)
            P = h["pos"].reshape(m, dim)
            v4 = h["v4"].reshape(m, 4)
            x = P[:, domain.axis]
            sel = x < thr if direction < 0 else x >= thr
            pos.append(P[sel])            # boolean indexing copies: nothing aliases the staging buffer
            vel.append(v4[sel, :dim])
            rho.append(v4[sel, 3])
            kind.append(h["kind"][sel])
        self._copy_mark(state, "edge_d2h", False)
        _count(state, "d2h_bytes", "edge", nb + 16)
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

    def host_arrays(self, state) -> dict:
        self.sync_host(state)
        p = state.particles
        from sphgraph.physics.eos import pressure
        press = pressure(np.asarray(p.rho), state.prm.astype(p.rho.dtype))
        return {"id": p.id, "kind": p.kind, "position": p.pos, "velocity": p.vel,
                "density": p.rho, "pressure": press}

    # -- cells -------------------------------------------------------------------------
    def _scan(self, dv, k, counts, out, n, level=0, tmp=None):
        """Exclusive scan of counts[0:n] into out[0:n] (device, recursive over block sums);
        `tmp` the list of block-sum buffers (default the rank's; a halo binned on another
        stream brings its own)."""
        per = 2048
        nb = (n + per - 1) // per
        tmp = dv.scan_tmp if tmp is None else tmp
        while len(tmp) < 2 * level + 2:
            tmp.append(dev_array(1, np.int64))
        if tmp[2 * level].shape[0] < nb:
            tmp[2 * level] = dev_array(int(nb * 1.25) + 1, np.int64)
            tmp[2 * level + 1] = dev_array(int(nb * 1.25) + 1, np.int64)
        sums, offs = tmp[2 * level], tmp[2 * level + 1]
        k.k_scan_blocks[nb, 256](counts, n, out, sums)
        if nb > 1:
            self._scan(dv, k, sums, offs, nb, level + 1, tmp)
            k.k_scan_add[CK.blocks(n), CK.BLOCK](out, n, offs)

    def build_cells(self, state) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        n, dim = dv.n, dv.dim
        c = state.consts
        reach = reach_cells(c.h, c.cell_size)
        axes = np.asarray(state.axes, np.int64)
        # grid over the rows' bounding box (from the last check)
        box = dv.box if n else np.zeros((2, 3))
        lo, _, dims, o_ax, n_ax, s_ax = device_grid(box[0], box[1], c.cell_size, axes)
        ncells = int(dims.prod())
        # kind-split keys: fluid cells 0..ncells-1, boundary cells ncells..2 ncells-1
        nk = 2 * ncells
        if dv.cell_cap < nk + 1:
            cap = int((nk + 1) * 1.05) + 16    # room for a grid that grows a little (5 %: memory counts)
            dv.arrays["start"] = dev_array(cap, np.int32)
            dv.cell_cap = cap
            dv.arrays.pop("counts", None)
        start = dv.start
        counts = dv.scratch(np.int32, nk)            # the histogram in the (dead) pos4 records
        koff = nk
        if counts is None:
            if "counts" not in dv.arrays or dv.arrays["counts"].shape[0] < nk:
                dv.arrays["counts"] = dev_array(dv.cell_cap, np.int32)
            counts = dv.arrays["counts"]
            koff = 0
        keys = dv.scratch(np.int32, n, koff)          # the cell keys after it (dead once scattered)
        if keys is None:
            if "keys" not in dv.arrays or dv.arrays["keys"].shape[0] < n:
                dv.arrays["keys"] = dev_array(max(dv.cap, 1), np.int32)
            keys = dv.arrays["keys"]
        inv = 1.0 / c.cell_size
        if n:
            k.k_fill[CK.blocks(nk), CK.BLOCK](counts, nk, 0)
            k.k_keys_hist2[CK.blocks(n), CK.BLOCK](dv.px, dv.py, dv.pz, dv.kind, n, dim, o_ax[0], o_ax[1],
                                                    o_ax[2], inv, n_ax[0], n_ax[1], n_ax[2],
                                                    s_ax[0], s_ax[1], s_ax[2], ncells, keys, counts)
            self._scan(dv, k, counts, start, nk)
            k.k_set_last[1, 1](start, nk, n)
            # scatter: counts becomes the fill pointer (a copy of start)
            k.k_copy[CK.blocks(nk), CK.BLOCK](start, nk, counts)
            k.k_scatter[CK.blocks(n), CK.BLOCK](keys, n, counts, dv.perm)
            # each cell's rows in increasing coordinate along the rows of cells (axes[0]):
            # the force kernels trim every row of cells to the sphere's chord by bisection
            key = (dv.px, dv.py, dv.pz)[int(axes[0])] if axes[0] >= 0 and TRIM else None
            if key is not None:
                k.k_sort_cells_by[CK.blocks(nk), CK.BLOCK](start, nk, dv.perm, key)
            else:
                k.k_sort_cells[CK.blocks(nk), CK.BLOCK](start, nk, dv.perm)
            self._permute(state, dv, k)
        else:
            k.k_fill[CK.blocks(nk + 1), CK.BLOCK](start, nk + 1, 0)
        dv.sort_gen += 1
        dv.grid = {"origin": lo, "dims": dims, "axes": axes, "inv": inv, "reach": reach,
                   "ncells": ncells, "size": c.cell_size}
        # rows sorted along the cell rows just now (or trimming off until they are)
        dv.moved = 0.0 if (TRIM and axes[0] >= 0) else np.inf
        if n:
            self._pack(state, dv, k, True)
        dv.host_stale = True
        self._sync()

    def _permute(self, state, dv, k):
        """Every row array reordered by perm: gathered into the pos4 buffer (dead until
        _pack rebuilds it) and copied back, so no array needs a twin. Up to three arrays
        go in one gather and one copy (k_gather3 / k_copy3), as many as fit the buffer's
        16 bytes a row, widest first so each view is aligned: 3D Symplectic, positions x
        and y, then z with kind and id (4 launches and one read of perm each, where one
        array a pass took 10)."""
        n, perm = dv.n, dv.perm
        b = CK.blocks(n)
        A = dv.arrays
        k.k_gather4[b, CK.BLOCK](A["vel4"], perm, n, A["pos4"])
        k.k_copy[CK.blocks(4 * n), CK.BLOCK](A["pos4"], 4 * n, A["vel4"])
        hist = getattr(dv, "integrator", "verlet") == "verlet"   # Symplectic: history rewritten each step
        for g in self._permute_groups(dv, hist):
            arrs = [A[nm] for nm in g]
            views, off = [], 0               # bytes into the buffer, a multiple of each width
            for a in arrs:
                w = a.dtype.itemsize
                views.append(dv.scratch(a.dtype, n, off * n // w))
                off += w
            m = len(arrs)
            arrs += [arrs[0]] * (3 - m)      # unused slots (m tells the kernels)
            views += [views[0]] * (3 - m)
            k.k_gather3[b, CK.BLOCK](*arrs, m, perm, n, *views)
            k.k_copy3[b, CK.BLOCK](*views, m, n, *arrs)

    @staticmethod
    def _permute_groups(dv, hist):
        """_permute's arrays in groups of at most three and 16 bytes a row, widest first
        (cached per device state: the same every sort)."""
        cache = dv.__dict__.setdefault("_permute_groups", {})
        if hist not in cache:
            A = dv.arrays
            names = ["p" + _VEC[d] for d in range(dv.dim)]
            if hist:
                names += ["vm" + _VEC[d] for d in range(dv.dim)] + ["rhom"]
            names += ["kind", "id"]
            names.sort(key=lambda nm: -A[nm].dtype.itemsize)        # stable: the order above within a width
            groups, cur, width = [], [], 0
            for nm in names:
                w = A[nm].dtype.itemsize
                if len(cur) == 3 or width + w > 16:
                    groups.append(cur)
                    cur, width = [], 0
                cur.append(nm)
                width += w
            groups.append(cur)
            cache[hist] = groups
        return cache[hist]

    def _pack(self, state, dv, k, with_press):
        """pos4 records from the float64 positions (and the pressure of rho)."""
        ref = np.zeros(3)
        ref[:dv.dim] = dv.ref
        A = dv.arrays
        k.k_pack[CK.blocks(dv.n), CK.BLOCK](A["px"], A["py"], A["pz"], A["vel4"], dv.n, dv.dim,
                                             float(ref[0]), float(ref[1]), float(ref[2]), dv.prm_d(state),
                                             bool(with_press), A["pos4"])

    def prepare_halo(self, state, halo) -> None:
        """Halo rows to the device, sorted by cell on the host (sphgraph.cells.build_grid):
        every field packed in the pinned staging buffer, one copy into a reusable device
        buffer (`_halo_buffer`) whose typed views are the halo's device arrays."""
        from sphgraph.cells import build_grid
        if isinstance(halo, CH.DeviceEdge):     # --halo-transport ipc: cut and binned on the device
            CH.receive_edge(self, state, halo)
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
        m, dim = halo.n, dv.dim
        names = ["r" + ax for ax in _VEC[:dim]] + ["v" + ax for ax in _VEC[:dim]] + ["rho"]
        lay, nb = _layout([("start", grid.start.dtype, grid.start.shape[0]), ("kind", np.int8, m)] +
                          [(key, dt, m) for key in names])
        hb = dv.host_buf(nb)
        h = _split(hb, lay)
        h["start"][:] = grid.start
        for i in range(dim):
            h["r" + _VEC[i]][:] = halo.pos[:, i] - dv.ref[i]
            h["v" + _VEC[i]][:] = halo.vel[:, i]
        h["rho"][:] = halo.rho
        h["kind"][:] = halo.kind
        poff = -(-nb // 8) * 8                   # the pressures (computed on the device) after the upload
        buf = self._halo_buffer(state, dv, halo, poff + m * dt.itemsize)
        s = self._s(state)
        self._copy_mark(state, "halo_h2d", True)
        buf[:nb].copy_to_device(hb, stream=s)        # a lane stream: asynchronous (pinned)
        self._host_busy(dv, s)
        dd = _split(buf, lay)
        dd["press"] = buf[poff:poff + m * dt.itemsize].view(dt)
        for ax in _VEC[dim:]:                    # 2D: one-element dummies (never read)
            dd["r" + ax] = dd["v" + ax] = dv.arrays["az"]
        self._k(state).k_pressure[CK.blocks(m), CK.BLOCK](dd["rho"], m, dv.prm_d(state), dd["press"])
        self._copy_mark(state, "halo_h2d", False)
        halo.press = dd
        halo.cells = grid
        _count(state, "h2d_bytes", "halo", nb)

    @staticmethod
    def _host_busy(dv, stream):
        """An upload from the pinned staging buffer was queued on `stream`: the next use of
        the buffer (host_buf) waits for it (the host does not wait here)."""
        if stream:
            if dv.busy_ev is None:
                dv.busy_ev = _event(False)
            ev = dv.busy_ev
            ev.record(stream)
            dv.host_busy = ev

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

    # -- forces ------------------------------------------------------------------------
    def forces(self, state, part: str) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        n, dim = dv.n, dv.dim
        halos_exist = any(h is not None and h.n for h in state.halos.values())
        final = part == "interior" and not halos_exist and state.nranks == 1
        A = dv.A()
        if part == "interior":
            g = dv.grid
            src = (A["rx"], A["ry"], A["rz"], A["vx"], A["vy"], A["vz"], A["rho"], A["press"], A["kind"])
            start, origin, inv, dims, axes, reach = A["start"], g["origin"], g["inv"], g["dims"], g["axes"], g["reach"]
        else:
            halo = state.halos.get(int(part[-1]))
            if isinstance(halo, CH.DeviceEdge):
                self._halo_forces(state, dv, part, halo)
                return
            if halo is None or halo.cells is None:
                dv.parts.pop(part, None)
                return
            hd = halo.press
            src = (hd["rx"], hd["ry"], hd["rz"], hd["vx"], hd["vy"], hd["vz"], hd["rho"], hd["press"], hd["kind"])
            gr = halo.cells
            self._read_halo(state, dv, halo)
            start, origin, inv, dims, axes, reach = hd["start"], gr.origin, 1.0 / gr.size, gr.dims, gr.axes, gr.reach
        if final:
            out = (A["ax"], A["ay"], A["az"], A["ar"], A["ar"], A["kind"], A["visc"])
            dv.parts = {}
        else:
            buf = dv.parts.get(part)
            if buf is None or buf["ar"].shape[0] < max(n, 1):   # sized by the row capacity: kept while rows come and go
                m = max(n, dv.cap, 1)
                buf = {"x": dev_array(m, dv.dtype), "y": dev_array(m, dv.dtype),
                       "z": dev_array(m if dim == 3 else 1, dv.dtype),
                       "ar": dev_array(m, dv.dtype), "ddt": dev_array(m, dv.dtype),
                       "cancel": dev_array(m, np.int8)}
                dv.parts[part] = buf
            out = (buf["x"], buf["y"], buf["z"], buf["ar"], buf["ddt"], buf["cancel"], A["visc"])
        dfa = CD.ddk_out(self, state, dv, part, final)      # K_a out (the DuFort-Frankel step), else ()
        gvec = np.zeros(3)
        gvec[:dim] = state.consts.gravity
        ft = dv.dtype.type
        if n and part == "interior":
            g = dv.grid
            nf, FB = dv.nf, CK.FORCE_BLOCK
            built = (CD.force_kernels if dfa else CR.force_kernels if CR.enabled(state) else CK.force_kernels)(
                dv.dtype, state.prm, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]))
            kf = self._on(state, built)
            if built.relative:
                # cell ranges from the relative positions: origin less the reference point,
                # support radius padded by the rounding of both (k_forces_fv)
                rel = [float(origin[k]) - float(dv.ref[axes[k]]) if axes[k] >= 0 else 0.0 for k in range(3)]
                span = max([abs(x) for x in rel] + [float(dims[k]) / float(inv) for k in range(3)])
                pad = np.sqrt(state.prm[P_SUPPORT2]) * (1 + 1e-6) + 16 * np.finfo(dv.dtype).eps * span
                # rows trimmed along the cell rows with the sort order stale by at most
                # 2 * moved (the Symplectic predictor), or not at all (TRIM_OFF)
                tpad = 2.0 * dv.moved * (1 + 1e-6) + 16 * np.finfo(dv.dtype).eps * span
                tpad = TRIM_OFF if not np.isfinite(tpad) or tpad > TRIM_OFF else tpad
                rel_args = (ft(rel[0]), ft(rel[1]), ft(rel[2]), ft(inv), ft(pad), ft(tpad),
                            int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]),
                            1 if final else 0, ft(gvec[0]), ft(gvec[1]), ft(gvec[2]))
                if nf:
                    kf.k_forces_f[CK.blocks(nf, FB), FB](A["pos4"], A["vel4"], 0, nf, start, int(g["ncells"]),
                                                         *rel_args, *out, *dfa)
                if n > nf:
                    kf.k_forces_b[CK.blocks(n - nf, FB), FB](A["pos4"], A["vel4"], nf, n, start,
                                                             int(g["ncells"]), *rel_args, *out)
            else:           # k_forces_f / k_forces_b (SPHGRAPH_CUDA_FORCES=f)
                geo = (start, int(g["ncells"]), float(origin[0]), float(origin[1]), float(origin[2]), float(inv),
                       int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]),
                       int(reach), dv.prm_d(state), dim, int(state.opt[O_KERNEL]))
                if nf:
                    kf.k_forces_f[CK.blocks(nf, FB), FB](
                        A["px"], A["py"], A["pz"], A["pos4"], A["vel4"], 0, nf, *geo,
                        int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]), 1 if final else 0,
                        ft(gvec[0]), ft(gvec[1]), ft(gvec[2]), *out)
                if n > nf:
                    kf.k_forces_b[CK.blocks(n - nf, FB), FB](
                        A["px"], A["py"], A["pz"], A["pos4"], A["vel4"], nf, n, *geo, 1 if final else 0, *out)
        elif n:
            kh = (self._on(state, CD.build(dv.dtype)).k_forces_df if dfa else
                  self._on(state, CR.build(dv.dtype)).k_forces if CR.enabled(state) else k.k_forces)
            kh[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
                A["px"], A["py"], A["pz"], A["rx"], A["ry"], A["rz"], A["vx"], A["vy"], A["vz"],
                A["rho"], A["press"], A["kind"], n, *src,
                start, float(origin[0]), float(origin[1]), float(origin[2]), float(inv),
                int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), int(reach),
                dv.prm_d(state), dim, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]),
                1 if final else 0, ft(gvec[0]), ft(gvec[1]), ft(gvec[2]), *out, *dfa)
        dv.final = final
        self._sync()

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
        _, _, fb, bb = CH.edge_ranges(self, state, dv, dv.__dict__["domain"])[d]
        ro = 0 if d < 0 else 4         # the targets' exact ranges in pick8 (a0, b0, a1, b1)
        m = max(dv.n, dv.cap, 1)
        buf = dv.parts.get(part)
        if buf is None or buf["ar"].shape[0] < m:
            buf = {"x": dev_array(m, dv.dtype), "y": dev_array(m, dv.dtype),
                   "z": dev_array(m if dv.dim == 3 else 1, dv.dtype),
                   "ar": dev_array(m, dv.dtype), "ddt": dev_array(m, dv.dtype), "cancel": dev_array(m, np.int8)}
            dv.parts[part] = buf
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
        args = (v["pos4"], v["vel4"], v["start"], int(halo.ncells), ft(rel[0]), ft(rel[1]), ft(rel[2]), ft(inv),
                ft(pad), ft(tpad), int(halo.dims[0]), int(halo.dims[1]), int(halo.dims[2]),
                int(axes[0]), int(axes[1]), int(axes[2]), ft(gvec[0]), ft(gvec[1]), ft(gvec[2]),
                buf["x"], buf["y"], buf["z"], buf["ar"], buf["ddt"], buf["cancel"], A["visc"])
        dfa = CD.ddk_out(self, state, dv, part, False)
        kf = self._on(state, (CD.halo_force_kernels if dfa else CR.halo_force_kernels if CR.enabled(state)
                              else HK.force_kernels)(
            dv.dtype, state.prm, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR])))
        FB = CK.FORCE_BLOCK
        if fb:
            kf.k_halo_fv[CK.blocks(fb, FB), FB](A["pos4"], A["vel4"], A["pick8"], ro, *args, *dfa)
        if bb:
            kf.k_halo_bv[CK.blocks(bb, FB), FB](A["pos4"], A["vel4"], A["pick8"], ro + 2, *args)
        dv.final = False
        self._sync()

    def reduce_forces(self, state, stage: int) -> None:
        if state.reduced_stage == (state.step, stage):
            return
        dv = state.extra["dev"]
        state.reduced_stage = (state.step, stage)
        if not dv.parts:      # single part written reduced by the force kernel
            return
        k = self._k(state)
        if dv.halo_ranges and dv.n:
            self._reduce_ranged(state, dv)
            CD.reduce(self, state, dv, True)
            self._sync()
            return
        bufs = [dv.parts[p] for p in ("interior", "halo_1", "halo_2") if p in dv.parts]
        while len(bufs) < 3:
            bufs.append(bufs[0])
        nparts = len([p for p in ("interior", "halo_1", "halo_2") if p in dv.parts])
        flat = []
        for b in bufs:
            flat += [b["x"], b["y"], b["z"], b["ar"], b["ddt"], b["cancel"]]
        gvec = np.zeros(3)
        gvec[:dv.dim] = state.consts.gravity
        ft = dv.dtype.type
        A = dv.A()
        if dv.n:
            k.k_reduce[CK.blocks(dv.n), CK.BLOCK](nparts, dv.n, dv.dim, A["kind"], ft(gvec[0]), ft(gvec[1]),
                                                 ft(gvec[2]), *flat, A["ax"], A["ay"], A["az"], A["ar"])
        CD.reduce(self, state, dv, False)
        self._sync()

    def _reduce_ranged(self, state, dv) -> None:
        """reduce_forces with ipc halo parts, each added at its target rows only."""
        P = dv.parts
        inner = P["interior"]
        flat = []
        for side in (1, 2):
            name = f"halo_{side}"
            r = dv.halo_ranges.get(side) if name in P else None
            b = P[name] if r is not None else inner
            flat += [1 if r is not None else 0, r or 0, b["x"], b["y"], b["z"], b["ar"], b["ddt"], b["cancel"]]
        gvec = np.zeros(3)
        gvec[:dv.dim] = state.consts.gravity
        ft = dv.dtype.type
        A = dv.A()
        hk = self._on(state, HK.build(dv.dtype))
        hk.k_reduce_ranged[CK.blocks(dv.n), CK.BLOCK](
            dv.n, dv.dim, A["kind"], ft(gvec[0]), ft(gvec[1]), ft(gvec[2]),
            inner["x"], inner["y"], inner["z"], inner["ar"], inner["ddt"], inner["cancel"], A["pick8"], *flat,
            A["ax"], A["ay"], A["az"], A["ar"])

    def dt_local(self, state) -> float:
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        s = self._s(state)
        k.k_fill[1, 32](A["dtout"], 3, 0.0)       # on the device: no host copy, no host wait
        if dv.n:
            k.k_dt_terms[min(CK.REDUCE_BLOCKS, CK.blocks(dv.n)), 256](
                A["ax"], A["ay"], A["az"], A["vx"], A["vy"], A["vz"], A["visc"], A["kind"], dv.n, dv.dim, A["dtout"])
        A["dtout"].copy_to_host(dv.pinned_dt, stream=s)     # after the compute lane's forces and reduce
        over = A.get("edge_over")
        if over is not None:                     # an edge outgrew its bound (ipc halos): never silent
            over.copy_to_host(dv.pinned_i4[:1], stream=s)
        _wait(s)
        if over is not None and int(dv.pinned_i4[0]):
            from sphgraph.errors import SphgraphError
            raise SphgraphError(f"rank {state.rank}: an edge of {int(dv.pinned_i4[0])} rows outgrew the bound "
                                f"counted at the last check (cuda_halo.band_counts)")
        CH.check_generations(state, dv)          # ipc halos from other processes
        _count(state, "d2h_bytes", "dt", 24)
        a2, v2, vm = (float(x) for x in dv.pinned_dt)
        dv.vmax = (state.step, np.sqrt(v2))       # the fluid rows' fastest speed (trim slack)
        c = state.consts
        return dt_from_terms(a2, v2, vm, c.h, c.c0, state.cfl)

    @staticmethod
    def _stage_start(dv):
        """The Symplectic stage-start float64 positions (px0, py0, pz0) of the rows'
        capacity: written by the predictor, read by the corrector of the same step (no
        sort or migration between them), allocated on first use."""
        A = dv.arrays
        m = max(dv.n, dv.cap, 1)
        if "px0" not in A or A["px0"].shape[0] < m:
            for ax in "xyz":
                A["p" + ax + "0"] = dev_array(m if (ax != "z" or dv.dim == 3) else 1, np.float64)
        return A["px0"], A["py0"], A["pz0"]

    def integrate(self, state, stage: int, integrator: str, euler: bool) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        n, dim = dv.n, dv.dim
        ft = dv.dtype.type
        dt = ft(state.dt)
        rho0 = ft(state.consts.prm[P_RHO0])
        dv.__dict__["integrator"] = integrator
        if n:
            b = CK.blocks(n)
            if integrator == "verlet":
                dk = CD.ddk_in(state, dv)          # K_a of the DuFort-Frankel step, else None
                k.k_verlet[b, CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"], A["rho"],
                                        A["vmx"], A["vmy"], A["vmz"], A["rhom"], A["kind"],
                                        A["ax"], A["ay"], A["az"], A["ar"], A["ar"] if dk is None else dk, n, dim,
                                        dt, bool(euler), rho0, dk is not None)
            else:
                # Symplectic stage-start velocity and density reuse the Verlet history slots;
                # the stage-start positions live only from the predictor to the corrector
                p0 = self._stage_start(dv)
                kern = k.k_sym_predict if stage == 1 else k.k_sym_correct
                kern[b, CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"], A["rho"], *p0,
                                  A["vmx"], A["vmy"], A["vmz"], A["rhom"], A["kind"],
                                  A["ax"], A["ay"], A["az"], A["ar"], n, dim, dt, rho0)
            # how far a row may have moved since the sort (k_forces_fv's trim slack): the
            # predictor moves fluid rows by dt/2 v, the fastest speed known from dt_local
            if integrator != "verlet" and stage == 1 and dv.vmax is not None and dv.vmax[0] == state.step:
                dv.moved += 0.5 * float(state.dt) * dv.vmax[1]
            else:
                dv.moved = np.inf
            if integrator != "verlet" and stage == 1:
                # the corrector's forces see the predicted positions (build_cells refreshes
                # them for the next step); pressure: see FRESH_PRESSURE
                self._pack(state, dv, k, FRESH_PRESSURE)
        k.k_fill[1, 32](A["visc"], 1, 0.0)   # the next stage's forces start the viscous maximum anew
        dv.host_stale = True
        self._sync()

    def check(self, state, lo, hi):
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        n, dim = dv.n, dv.dim
        k.k_check_init[1, 1](A["chk_bad"], A["chk_box"])   # on the device: no host copy, no host wait
        lo3 = np.zeros(3)
        hi3 = np.zeros(3)
        lo3[:dim] = lo
        hi3[:dim] = hi
        if n:
            k.k_check_bounds[min(CK.REDUCE_BLOCKS, CK.blocks(n)), 256](
                A["px"], A["py"], A["pz"], A["rho"], A["kind"], n, dim, *lo3, *hi3,
                float(state.rho_min), float(min(state.rho_max, 1e300)), A["chk_bad"], A["chk_box"])
        band = CH.band_counts(self, state, dv, k)     # the next sort's edge bounds, in the same wait
        s = self._s(state)
        A["chk_box"].copy_to_host(dv.pinned_chk[:6], stream=s)
        A["chk_bad"].copy_to_host(dv.pinned_bad, stream=s)
        _wait(s)
        if band:
            CH.take_band(dv)
        box = dv.pinned_chk[:6].copy()
        bad = int(dv.pinned_bad[0])
        _count(state, "d2h_bytes", "check", 56)
        if n:
            dv.box = np.array([box[:3], box[3:]])
            dv.box[:, dim:] = 0.0
        if bad == np.iinfo(np.int64).max:
            return None
        dv.host_stale = True
        self.sync_host(state)
        return bad // 4, bad % 4

    # -- load balancing: from the device rows, no download ------------------------------
    def fluid_count(self, state) -> int:
        return state.extra["dev"].nf

    def axis_extent(self, state, axis: int) -> tuple[float, float]:
        """From the bounding box of the last check (the rows have not moved since)."""
        dv = state.extra["dev"]
        return (float(dv.box[0, axis]), float(dv.box[1, axis])) if dv.n else (np.inf, -np.inf)

    def fluid_histogram(self, state, axis: int, edges) -> np.ndarray:
        """One atomic-add pass over the fluid rows (k_axis_hist), one copy to the host."""
        dv = state.extra["dev"]
        nb = len(edges) - 1
        out = dv.dev_buf("hist", 8 * nb).view(np.int64)
        k = self._k(state)
        k.k_fill[CK.blocks(nb), CK.BLOCK](out, nb, 0)
        if dv.nf:
            hk = self._on(state, HK.build(dv.dtype))
            e0, e1 = float(edges[0]), float(edges[-1])
            hk.k_axis_hist[CK.blocks(dv.nf), CK.BLOCK](dv.arrays["p" + _VEC[axis]], dv.nf, e0, e1,
                                                       nb / (e1 - e0), nb, out)
        h = dv.host_buf(8 * nb).view(np.int64)
        s = self._s(state)
        out.copy_to_host(h, stream=s)
        _wait(s)
        return h.copy()

    # -- benchmarks --------------------------------------------------------------------
    def count_pairs(self, state) -> int:
        """Interior pairs within 2h counted on the device as DualSPHysics counts them
        (every neighbour of a fluid row, the fluid neighbours of a boundary row; halos:
        the host count)."""
        if any(h is not None and h.n for h in state.halos.values()):
            return super().count_pairs(state)
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        n = dv.n
        if not n:
            return 0
        g = dv.grid
        counts = dev_array(n, np.int32)
        sup2 = dv.dtype.type(state.prm[P_SUPPORT2])
        k.k_count_pairs2[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
            A["px"], A["py"], A["pz"], A["pos4"], n, dv.nf, A["start"], int(g["ncells"]),
            *(float(x) for x in g["origin"]), float(g["inv"]), *(int(x) for x in g["dims"]),
            *(int(x) for x in g["axes"]), int(g["reach"]), sup2, counts)
        return int(counts.copy_to_host().astype(np.int64).sum())

    def state_bytes(self, state) -> int:
        dv = state.extra.get("dev")
        return 0 if dv is None else dv.nbytes()

    def particle_capacity(self, state, max_particles_per_rank=None, sharing=1) -> int | None:
        """Free device memory (split among the `sharing` ranks on this device) at the rank's
        measured bytes per allocated row, plus the rows it holds, less its boundary rows
        (sphgraph.balance.device_capacity); never above `max_particles_per_rank`."""
        from sphgraph.balance import device_capacity
        dv = state.extra.get("dev")
        if dv is None or CK.SIMULATOR:
            return max_particles_per_rank
        free, _total = cuda.current_context().get_memory_info()
        rows = max(dv.cap, 1)
        cap = device_capacity(free / max(sharing, 1), dv.nbytes() / rows, held_rows=rows,
                              fixed_rows=dv.n - dv.nf)
        if cap is None or max_particles_per_rank is None:
            return cap if cap is not None else max_particles_per_rank
        return min(cap, max_particles_per_rank)


def _prm_d(self, state):
    d = self.arrays.get("prm")
    if d is None:
        d = self.arrays["prm"] = cuda.to_device(np.ascontiguousarray(state.prm, self.dtype))
    return d


DeviceState.prm_d = _prm_d
