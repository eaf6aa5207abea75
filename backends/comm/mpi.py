"""Real MPI through mpi4py: `mpiexec -n N sphgraph run SCENE --comm mpi`.

One rank per process (`local_ranks = [rank]`). Tasks run in schedule order;
`isend` packs a payload (Halo, Particles or None) into one contiguous byte
buffer (an int64 header naming the payload type, the message's sequence number
and each array's dtype and shape, then the arrays, each 8-byte aligned) and
posts it with `Isend`; the request and the buffer stay alive until `execute`
waits for every send at the end of the step. `recv` blocks: `Probe` for the
size, then `Recv`; the sequence number (per (source, dest, tag), `base.SeqCheck`)
must be the next one, else `CommError` reports a duplicated or lost message.
dt is `allreduce(x, op=MPI.MIN)`. Times are `MPI.Wtime()` from a start barrier.

Watchdog (`watchdog` seconds, default 120, 0 = off; `--watchdog`): every
blocking wait (a receive, a collective, the end-of-step wait for sends) marks
itself in `_Watchdog` (two attribute stores: nothing measurable on the normal
path); a daemon thread checks the mark every min(1 s, limit/10) and, when a
wait has lasted longer than the limit, prints one line (rank, step, task, peer)
and calls MPI_Abort: every rank stops with exit 3 instead of hanging. A
collective cannot name the rank it waits for, so it fires 3 polls later: a
neighbour waiting for the missing rank's message usually names it first. Waits
that can include the root's writing of a frame or checkpoint (from a gather of
rows to the end of the next step) are allowed `IO_FACTOR` times the limit.

mpi4py is imported when this backend is chosen (not by `import sphgraph`).
"""
from __future__ import annotations

import os
import sys
import threading
import time

import numpy as np

from sphgraph.errors import InputError
from sphgraph.registry import register
from sphgraph.wire import WirePayload, decode, encode

from .base import CommBackend, SeqCheck

DEFAULT_WATCHDOG = 120.0   # s; --watchdog
IO_FACTOR = 10.0           # waits that may include the root's frame/checkpoint write
ABORT_GRACE_S = 0.3        # s between the one-line report on stderr and MPI_Abort


def _mpi():
    try:
        from mpi4py import MPI
    except ImportError:
        raise InputError("--comm mpi: needs mpi4py: pip install sphgraph[mpi]") from None
    return MPI


# payload types and their arrays, in wire order (_WIRE: a sphgraph.wire.WirePayload, which
# packs itself: its code, then its uint8 array)
_NONE, _HALO, _PARTICLES, _ARRAY, _WIRE = 0, 1, 2, 3, 4
_FIELDS = {_HALO: ("pos", "vel", "rho", "kind"),
           _PARTICLES: ("id", "kind", "pos", "vel", "rho", "vel_m1", "rho_m1"),
           _ARRAY: ("a",), _WIRE: ("code", "a")}
_DTYPES = [np.dtype(x) for x in ("<f8", "<f4", "<i8", "<i4", "|i1", "|u1", "<i2", "|b1")]
_DCODE = {d: i for i, d in enumerate(_DTYPES)}


def _kind_of(payload) -> int:
    from sphgraph.particles import Particles
    from sphgraph.state import Halo
    if payload is None:
        return _NONE
    if isinstance(payload, Halo):
        return _HALO
    if isinstance(payload, Particles):
        return _PARTICLES
    if isinstance(payload, np.ndarray):
        return _ARRAY
    if isinstance(payload, WirePayload):
        return _WIRE
    raise TypeError(f"--comm mpi: cannot send a {type(payload).__name__}")


_HEAD = 3   # int64 words before the per-array entries: type, nfields, seq


def pack(payload, seq: int = 0, dest: int | None = None) -> np.ndarray:
    """One uint8 buffer: int64 header [type, nfields, seq, (dtype, ndim, d0, d1) * nfields], data."""
    kind = _kind_of(payload)
    names = _FIELDS.get(kind, ())
    if kind == _WIRE:
        code, data = encode(payload, dest)
        arrays = [np.array([code], np.int64), data]
    else:
        arrays = [np.ascontiguousarray(payload if kind == _ARRAY else getattr(payload, f)) for f in names]
    header = [kind, len(arrays), int(seq)]
    for a in arrays:
        if a.ndim > 2:
            raise TypeError("--comm mpi: arrays of at most 2 dimensions")
        dt = a.dtype.newbyteorder("<") if a.dtype.byteorder == ">" else a.dtype
        header += [_DCODE[np.dtype(dt.str)], a.ndim] + list(a.shape) + [0] * (2 - a.ndim)
    head = np.array(header, np.int64)
    sizes = [(a.nbytes + 7) // 8 * 8 for a in arrays]
    buf = np.zeros(head.nbytes + sum(sizes), np.uint8)
    buf[:head.nbytes] = head.view(np.uint8)
    off = head.nbytes
    for a, s in zip(arrays, sizes):
        buf[off:off + a.nbytes] = a.reshape(-1).view(np.uint8)
        off += s
    return buf


def seq_of(buf: np.ndarray) -> int:
    """The sequence number in a packed buffer's header."""
    return int(buf[16:24].view(np.int64)[0])


def unpack(buf: np.ndarray):
    from sphgraph.particles import Particles
    from sphgraph.state import Halo
    h0 = 8 * _HEAD
    kind, nf = (int(x) for x in buf[:16].view(np.int64))
    if kind == _NONE:
        return None
    head = buf[h0:h0 + 32 * nf].view(np.int64).reshape(nf, 4)
    off = h0 + 32 * nf
    arrays = []
    for code, ndim, d0, d1 in head:
        dt = _DTYPES[int(code)]
        shape = (int(d0),) if ndim == 1 else (int(d0), int(d1))
        nbytes = int(np.prod(shape)) * dt.itemsize
        arrays.append(buf[off:off + nbytes].view(dt).reshape(shape).copy())
        off += (nbytes + 7) // 8 * 8
    if kind == _ARRAY:
        return arrays[0]
    if kind == _WIRE:
        return decode(int(arrays[0][0]), arrays[1])
    fields = dict(zip(_FIELDS[kind], arrays))
    return Halo(**fields) if kind == _HALO else Particles(**fields)


_OPS = {"min": "MIN", "max": "MAX", "sum": "SUM"}


class _Watchdog:
    """Aborts every rank when this rank waits longer than `limit` s in one blocking call.

    The main thread marks a wait with `begin(peer)` / `end()` (two attribute stores);
    a daemon thread looks at the mark every min(1 s, limit/10)."""

    def __init__(self, backend, limit: float):
        self.b = backend
        self.limit = float(limit)
        self.task = None          # the step task running now (name), set by execute
        self.step = None          # the step being run, 1-based
        self.io = True            # waits may include the root's output (start: frame 0, compilation)
        self._mark = None         # (t0, peer, what, collective) of the wait in progress
        if self.limit > 0:
            threading.Thread(target=self._run, name="sphgraph-watchdog", daemon=True).start()

    def begin(self, peer, what: str | None = None, collective: bool = False) -> None:
        """`peer`: (source, tag) of a receive, or words ("every rank (collective)")."""
        self._mark = (time.monotonic(), peer, what, collective)

    def end(self) -> None:
        self._mark = None

    def _run(self) -> None:
        poll = min(1.0, self.limit / 10)
        while True:
            time.sleep(poll)
            mark, task, step, io = self._mark, self.task, self.step, self.io
            if mark is None:
                continue
            # a collective cannot name the rank it waits for: it gives a rank waiting for a
            # message (usually that rank's neighbour, which names it) a few polls to speak first
            limit = self.limit * (IO_FACTOR if io else 1.0)
            waited = time.monotonic() - mark[0]
            if waited > limit + (3 * poll if mark[3] else 0.0):
                at = f" at step {step}" if step is not None else ""
                peer = f"rank {mark[1][0]} (tag {mark[1][1]})" if isinstance(mark[1], tuple) else mark[1]
                print(f"sphgraph: watchdog: rank {self.b.rank} has waited {waited:.1f} s in {task or mark[2]}"
                      f"{at} for {peer} (limit {limit:g} s, --watchdog); aborting all ranks",
                      file=sys.stderr, flush=True)
                try:
                    time.sleep(ABORT_GRACE_S)    # let mpiexec forward the line first
                    self.b.comm.Abort(3)
                finally:
                    os._exit(3)


class _Endpoint:
    def __init__(self, backend):
        self.b = backend
        self.rank = backend.rank
        self.size = backend.size
        self.seq = SeqCheck(self.rank)

    def isend(self, dest, tag, payload):
        buf = pack(payload, self.seq.next_send(dest, tag), dest)
        req = self.b.comm.Isend([buf, self.b.MPI.BYTE], dest=dest, tag=tag)
        self.b.pending.append((req, buf, dest))

    def recv(self, source, tag):
        MPI = self.b.MPI
        st = MPI.Status()
        wd = self.b.watchdog
        wd.begin((source, tag))      # formatted only if the watchdog fires
        self.b.comm.Probe(source=source, tag=tag, status=st)
        buf = np.empty(st.Get_count(MPI.BYTE), np.uint8)
        self.b.comm.Recv([buf, MPI.BYTE], source=source, tag=tag)
        wd.end()
        self.seq.accept(source, tag, seq_of(buf), wd.task, wd.step)
        return unpack(buf)

    def allreduce_min(self, x):
        return self.b.collective(self.b.comm.allreduce, x, op=self.b.MPI.MIN)

    def allreduce(self, x, op="sum"):
        return self.b.allreduce(x, op)

    def allgather(self, x) -> list:
        return self.b.collective(self.b.comm.allgather, x)

    def gather(self, x) -> list | None:
        return self.b.collective(self.b.comm.gather, x, root=0)


@register("comm", "mpi")
class MPIComm(CommBackend):
    """`--comm mpi`: this process is rank COMM_WORLD.rank of COMM_WORLD.size."""

    def __init__(self, ranks: int | None = None, comm=None, watchdog=DEFAULT_WATCHDOG, halo_transport="auto",
                 **options):
        MPI = _mpi()
        self.MPI = MPI
        self.comm = comm if comm is not None else MPI.COMM_WORLD
        self.rank = self.comm.Get_rank()
        super().__init__(self.comm.Get_size(), halo_transport)
        watchdog = DEFAULT_WATCHDOG if watchdog is None else watchdog
        if isinstance(watchdog, bool) or not isinstance(watchdog, (int, float)) or not watchdog >= 0:
            raise InputError(f"--watchdog: expected seconds >= 0 (0 = off), got {watchdog!r}")
        self.pending = []
        self._ep = _Endpoint(self)
        self.comm.Barrier()
        self.t0 = MPI.Wtime()
        self.watchdog = _Watchdog(self, watchdog)

    def collective(self, fn, *args, what="a collective", **kw):
        """`fn(*args, **kw)` (a blocking collective) under the watchdog; `what` names it
        outside a step task."""
        self.watchdog.begin("every rank (collective)", what, collective=True)
        out = fn(*args, **kw)
        self.watchdog.end()
        return out

    @property
    def local_ranks(self) -> list[int]:
        return [self.rank]

    @property
    def is_root(self) -> bool:
        return self.rank == 0

    def endpoint(self, rank: int):
        return self._ep

    def clock(self) -> float:
        return self.MPI.Wtime() - self.t0

    def execute(self, jobs, record) -> None:
        wt = self.MPI.Wtime
        wd = self.watchdog
        try:
            for ctx, program in jobs:
                step = getattr(ctx.state, "step", None)
                wd.step = None if step is None else int(step) + 1
                for task in program:
                    wd.task = task.name
                    a = wt() - self.t0
                    task.fn(ctx, task)
                    record(ctx.rank, task, a, wt() - self.t0)
        finally:
            self.wait_sends()
            wd.task = None
        wd.io = False          # the step after a gather of rows (root writing) is over

    def wait_sends(self) -> None:
        if self.pending:
            peers = ", ".join(map(str, sorted({p[2] for p in self.pending})))
            self.watchdog.task = None
            self.watchdog.begin(f"rank(s) {peers} to receive its messages", "the end-of-step wait for sends")
            self.MPI.Request.Waitall([p[0] for p in self.pending])
            self.watchdog.end()
            self.pending = []

    def gather_rows(self, per_rank: dict):
        # frames and checkpoints: the root writes next; the waits until the next step ends may include it
        self.watchdog.io = True
        return self.collective(self.comm.gather, per_rank[self.rank], root=0, what="the gather of rows for output")

    def gather(self, obj):
        return self.collective(self.comm.gather, obj, root=0, what="a gather")

    def allreduce(self, value, op):
        mop = getattr(self.MPI, _OPS.get(op, str(op).upper()))
        return self.collective(self.comm.allreduce, value, op=mop, what="an allreduce")

    def bcast(self, obj):
        return self.collective(self.comm.bcast, obj, root=0, what="a bcast")

    def barrier(self):
        self.collective(self.comm.Barrier, what="a barrier")

    def first_problem(self, found):
        """The lowest rank's problem (or None), the same on every rank."""
        what = "the end-of-step check"
        allp = self.collective(self.comm.gather, found, root=0, what=what)
        pick = None
        if self.rank == 0:
            pick = next((p for p in allp if p is not None), None)
        return self.collective(self.comm.bcast, pick, root=0, what=what)

    def abort(self, code: int) -> None:
        # the one-line report was just written to stderr: give mpiexec's proxy a moment to
        # forward it before MPI_Abort kills the processes (the line was lost at times)
        time.sleep(ABORT_GRACE_S)
        self.comm.Abort(code)

    def finish(self) -> None:
        """Every step receives what it sent, so a message still pending after the last
        step (and a barrier) is a duplicate or a stray: reported, not dropped."""
        self.barrier()
        st = self.MPI.Status()
        if self.comm.Iprobe(source=self.MPI.ANY_SOURCE, tag=self.MPI.ANY_TAG, status=st):
            src, tag = st.Get_source(), st.Get_tag()
            buf = np.empty(st.Get_count(self.MPI.BYTE), np.uint8)
            self.comm.Recv([buf, self.MPI.BYTE], source=src, tag=tag)
            self._ep.seq.accept(src, tag, seq_of(buf), "the end-of-run check", self.watchdog.step)
            from sphgraph.errors import CommError
            raise CommError(f"message not received: rank {self.rank} has message #{seq_of(buf)} from rank "
                            f"{src} (tag {tag}) pending after the last step")
