"""Real MPI through mpi4py: `mpiexec -n N sphgraph run SCENE --comm mpi`.

One rank per process (`local_ranks = [rank]`). Tasks run in schedule order;
`isend` packs a payload (Halo, Particles or None) into one contiguous byte
buffer (an int64 header naming the payload type and each array's dtype and
shape, then the arrays, each 8-byte aligned) and posts it with `Isend`; the
request and the buffer stay alive until `execute` waits for every send at the
end of the step. `recv` blocks: `Probe` for the size, then `Recv`. dt is
`allreduce(x, op=MPI.MIN)`. Times are `MPI.Wtime()` from a start barrier.

mpi4py is imported when this backend is chosen (not by `import sphgraph`).
"""
from __future__ import annotations

import numpy as np

from sphgraph.errors import InputError
from sphgraph.registry import register

from .base import CommBackend


def _mpi():
    try:
        from mpi4py import MPI
    except ImportError:
        raise InputError("--comm mpi: needs mpi4py: pip install sphgraph[mpi]") from None
    return MPI


# payload types and their arrays, in wire order
_NONE, _HALO, _PARTICLES, _ARRAY = 0, 1, 2, 3
_FIELDS = {_HALO: ("pos", "vel", "rho", "kind"),
           _PARTICLES: ("id", "kind", "pos", "vel", "rho", "vel_m1", "rho_m1"),
           _ARRAY: ("a",)}
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
    raise TypeError(f"--comm mpi: cannot send a {type(payload).__name__}")


def pack(payload) -> np.ndarray:
    """One uint8 buffer: int64 header [type, nfields, (dtype, ndim, d0, d1) * nfields], data."""
    kind = _kind_of(payload)
    names = _FIELDS.get(kind, ())
    arrays = [np.ascontiguousarray(payload if kind == _ARRAY else getattr(payload, f)) for f in names]
    header = [kind, len(arrays)]
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


def unpack(buf: np.ndarray):
    from sphgraph.particles import Particles
    from sphgraph.state import Halo
    kind, nf = (int(x) for x in buf[:16].view(np.int64))
    if kind == _NONE:
        return None
    head = buf[16:16 + 32 * nf].view(np.int64).reshape(nf, 4)
    off = 16 + 32 * nf
    arrays = []
    for code, ndim, d0, d1 in head:
        dt = _DTYPES[int(code)]
        shape = (int(d0),) if ndim == 1 else (int(d0), int(d1))
        nbytes = int(np.prod(shape)) * dt.itemsize
        arrays.append(buf[off:off + nbytes].view(dt).reshape(shape).copy())
        off += (nbytes + 7) // 8 * 8
    if kind == _ARRAY:
        return arrays[0]
    fields = dict(zip(_FIELDS[kind], arrays))
    return Halo(**fields) if kind == _HALO else Particles(**fields)


_OPS = {"min": "MIN", "max": "MAX", "sum": "SUM"}


class _Endpoint:
    def __init__(self, backend):
        self.b = backend
        self.rank = backend.rank
        self.size = backend.size

    def isend(self, dest, tag, payload):
        buf = pack(payload)
        req = self.b.comm.Isend([buf, self.b.MPI.BYTE], dest=dest, tag=tag)
        self.b.pending.append((req, buf))

    def recv(self, source, tag):
        MPI = self.b.MPI
        st = MPI.Status()
        self.b.comm.Probe(source=source, tag=tag, status=st)
        buf = np.empty(st.Get_count(MPI.BYTE), np.uint8)
        self.b.comm.Recv([buf, MPI.BYTE], source=source, tag=tag)
        return unpack(buf)

    def allreduce_min(self, x):
        return self.b.comm.allreduce(x, op=self.b.MPI.MIN)

    def allreduce(self, x, op="sum"):
        return self.b.allreduce(x, op)

    def allgather(self, x) -> list:
        return self.b.comm.allgather(x)


@register("comm", "mpi")
class MPIComm(CommBackend):
    """`--comm mpi`: this process is rank COMM_WORLD.rank of COMM_WORLD.size."""

    def __init__(self, ranks: int | None = None, comm=None, **options):
        MPI = _mpi()
        self.MPI = MPI
        self.comm = comm if comm is not None else MPI.COMM_WORLD
        self.rank = self.comm.Get_rank()
        super().__init__(self.comm.Get_size())
        self.pending = []
        self._ep = _Endpoint(self)
        self.comm.Barrier()
        self.t0 = MPI.Wtime()

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
        try:
            for ctx, program in jobs:
                for task in program:
                    a = wt() - self.t0
                    task.fn(ctx, task)
                    record(ctx.rank, task, a, wt() - self.t0)
        finally:
            self.wait_sends()

    def wait_sends(self) -> None:
        if self.pending:
            self.MPI.Request.Waitall([r for r, _ in self.pending])
            self.pending = []

    def gather_rows(self, per_rank: dict):
        return self.comm.gather(per_rank[self.rank], root=0)

    def gather(self, obj):
        return self.comm.gather(obj, root=0)

    def allreduce(self, value, op):
        mop = getattr(self.MPI, _OPS.get(op, str(op).upper()))
        return self.comm.allreduce(value, op=mop)

    def bcast(self, obj):
        return self.comm.bcast(obj, root=0)

    def barrier(self):
        self.comm.Barrier()

    def first_problem(self, found):
        """The lowest rank's problem (or None), the same on every rank."""
        allp = self.comm.gather(found, root=0)
        pick = None
        if self.rank == 0:
            pick = next((p for p in allp if p is not None), None)
        return self.comm.bcast(pick, root=0)

    def abort(self, code: int) -> None:
        self.comm.Abort(code)
