"""Streams of the numba.cuda backend: one CUDA stream per schedule lane and rank, the
events between them, and the device trace (timing events per task and copy).

Each rank gets one CUDA stream per schedule lane (compute, comm, copy), created once,
and every kernel launch and copy of a task goes on its lane's stream (`_k`, `_s`). A
cross-lane dependency of the rank's graph (the scheduler's `LaneStep`, from
`graph.build.lane_edges`) is an event recorded on the producer's stream at its end and
waited on by the consumer's stream at its start; host-side waits (a D2H copy the host
must read) synchronise that stream only. Outside tasks (set-up, check, frames) the
backend works on the legacy default stream, which orders itself against every lane
stream. `SPHGRAPH_CUDA_STREAMS=0` runs everything on the default stream (the same
kernels and summation order, so the same bits).
"""
from __future__ import annotations

import os

from numba import cuda

from . import cuda_kernels as CK
from . import cuda_launch as CL


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


def new_event(timing):
    """A CUDA event (the simulator's takes no timing flag)."""
    return cuda.event() if CK.SIMULATOR else cuda.event(timing=timing)


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
            e = table[key] = new_event(False)
        return e


def per_thread_default_stream() -> bool:
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


class CudaLanes:
    """NumbaCUDA's lanes and device trace: `self.lanes` (rank -> Lanes), `self.lane_log`,
    `self.trace` and `self.sync_tasks` are set by NumbaCUDA.__init__."""

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
        if self.task_clock is not None:
            self._clock_begin(state, task, s)

    def lane_end(self, state, task, step) -> None:
        """After a task body: its event (when a task on another lane depends on it), the
        step-end events of every lane (after the step's last task); back to the default stream."""
        L = self.lanes[state.rank]
        s = L.current
        if self.trace is not None:
            self._mark(state, task.name, step.lane, False)
        if self.task_clock is not None:
            self._clock_end(state, task, s)
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

    # -- the device's task clock (timing events; off unless start_task_clock) -------------
    def start_task_clock(self) -> None:
        """Time every task on its stream from now on, alone: a (start, end) event pair per
        rank and task, and the host waits for the device at the task's end. Mock ranks
        share this one device; timed while other ranks' kernels ran beside them, a rank's
        tasks took up to twice their own time (its receives the senders' too), which no
        longer stood for a device of its own. The wall clock of such steps is not the
        path's speed: `sphgraph bench` times its steps with the clock off."""
        cuda.synchronize()
        self.task_clock = {}

    def stop_task_clock(self) -> None:
        self.task_clock = None

    def _clock_begin(self, state, task, s) -> None:
        key = (state.rank, task.name)
        e = self.task_clock.get(key)
        if e is None:
            e = self.task_clock[key] = [None, new_event(True), new_event(True)]   # [seconds, start, end]
        e[0] = None
        e[1].record(s)

    def _clock_end(self, state, task, s) -> None:
        e = self.task_clock[(state.rank, task.name)]
        e[2].record(s)
        cuda.synchronize()      # the next task starts on an idle device
        e[0] = e[1].elapsed_time(e[2]) * 1e-3

    def task_device_seconds(self, state, task):
        e = None if self.task_clock is None else self.task_clock.get((state.rank, task.name))
        return None if e is None else e[0]

    # -- device trace (timing events; off unless start_device_trace) ---------------------
    def start_device_trace(self) -> None:
        """Record timing events from now on: per task on its lane's stream (start: when the
        stream reaches the task, after its waits; end: after its work) and around the edge
        and halo copies (`edge_d2h`, `halo_h2d`). Read them with `device_trace`."""
        cuda.synchronize()
        t0 = new_event(True)
        t0.record()
        t0.synchronize()
        self.trace = []
        self._trace_t0 = t0
        self._trace_open = {}

    def _mark(self, state, label, lane, begin, inside=None):
        ev = new_event(True)
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
