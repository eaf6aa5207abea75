"""Behaviour every comm backend must show (DESIGN.md §2: one shared conformance suite).

Each behaviour is a function of a constructed backend; it runs tasks through the
backend's own `execute` (so the mock engine, a single process and real MPI are
driven the same way) and asserts on every rank this process drives. A class per
backend mixes them in; the MPI backend runs them under `mpiexec` through
tests/mpi_driver.py (`conformance` check, launched by test_multirank.py).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sphgraph.graph.task import Message, Task
from sphgraph.particles import Particles
from sphgraph.scheduler import RankContext
from sphgraph.state import Halo

TAG = 900


def _contexts(backend):
    return {r: RankContext(rank=r, state=SimpleNamespace(got={}, step=0), compute=None,
                           comm=backend.endpoint(r)) for r in backend.local_ranks}


def _run(backend, programs_of, ctxs=None):
    """Run {rank: [Task]} (built by programs_of(rank)) on the backend's local ranks."""
    ctxs = ctxs or _contexts(backend)
    recs = []
    backend.execute([(ctxs[r], programs_of(r)) for r in backend.local_ranks],
                    lambda r, t, a, b: recs.append((r, t.name, a, b)))
    return ctxs, recs


def _halo(r, n):
    x = np.arange(n * 3, dtype=np.float64).reshape(n, 3) + 1000 * r
    return Halo(pos=x, vel=-x, rho=np.full(n, 1000.0 + r), kind=(np.arange(n) % 2).astype(np.int8))


def _particles(r, n):
    p = Particles.create(np.arange(n) + 100 * r, np.zeros(n, np.int8),
                         np.arange(n * 2, dtype=float).reshape(n, 2) + r, np.ones((n, 2)) * r,
                         np.full(n, 999.0 + r))
    return p


# --------------------------------------------------------------------------- behaviours
def b_allreduce_min(backend):
    def fn(ctx, task):
        if backend.size == 1:
            x = 7.0
        else:
            x = np.inf if ctx.rank == 0 else float(ctx.rank) + 1.5
        ctx.state.got["min"] = ctx.comm.allreduce_min(x)
    ctxs, recs = _run(backend, lambda r: [Task("reduce", fn=fn, collective=True)])
    want = 2.5 if backend.size > 1 else 7.0
    for c in ctxs.values():
        assert c.state.got["min"] == want


def _ring(backend, make_payload, check, tag):
    n = backend.size
    if n == 1:
        pytest.skip("one rank: no messages")

    def send(ctx, task):
        r = ctx.rank
        payload = make_payload(r)
        ctx.comm.isend((r + 1) % n, tag, payload)
        if isinstance(payload, (Halo, Particles)) and getattr(payload, "pos", None) is not None \
                and payload.pos.size:
            payload.pos[...] = -12345.0        # mutation after posting must not leak

    def recv(ctx, task):
        ctx.state.got[tag] = ctx.comm.recv((ctx.rank - 1) % n, tag)

    def prog(r):
        up = ((r + 1) % n) - r
        down = ((r - 1) % n) - r
        return [Task("send", fn=send, sends=(Message(up, tag),)),
                Task("recv", fn=recv, recvs=(Message(down, tag),))]
    ctxs, _ = _run(backend, prog)
    for r, c in ctxs.items():
        check(c.state.got[tag], (r - 1) % n)


def b_halo_roundtrip(backend):
    def check(h, src):
        ref = _halo(src, 5)
        assert isinstance(h, Halo) and h.n == 5
        for k in ("pos", "vel", "rho", "kind"):
            assert getattr(h, k).dtype == getattr(ref, k).dtype
            np.testing.assert_array_equal(getattr(h, k), getattr(ref, k))
    _ring(backend, lambda r: _halo(r, 5), check, TAG + 1)


def b_empty_halo(backend):
    def check(h, src):
        assert isinstance(h, Halo) and h.n == 0 and h.pos.shape == (0, 3)
    _ring(backend, lambda r: _halo(r, 0), check, TAG + 2)


def b_particles_roundtrip(backend):
    def check(p, src):
        ref = _particles(src, 4)
        assert isinstance(p, Particles) and p.n == 4
        for k, v in ref.arrays().items():
            got = getattr(p, k)
            assert got.dtype == v.dtype and got.shape == v.shape
            np.testing.assert_array_equal(got, v)
    _ring(backend, lambda r: _particles(r, 4), check, TAG + 3)


def b_empty_particles_and_none(backend):
    def check_empty(p, src):
        assert isinstance(p, Particles) and p.n == 0 and p.pos.shape == (0, 2)
    _ring(backend, lambda r: _particles(r, 0), check_empty, TAG + 4)

    def check_none(p, src):
        assert p is None
    _ring(backend, lambda r: None, check_none, TAG + 5)


def b_gather_rows_order(backend):
    per = {r: {"id": np.array([r * 10, r * 10 + 1])} for r in backend.local_ranks}
    rows = backend.gather_rows(per)
    if backend.is_root:
        assert [int(x["id"][0]) for x in rows] == [10 * r for r in range(backend.size)]
    else:
        assert rows is None


def b_records_every_task(backend):
    def noop(ctx, task):
        pass
    ctxs, recs = _run(backend, lambda r: [Task("a", fn=noop), Task("b", fn=noop)])
    mine = [(r, name) for r, name, _, _ in recs]
    assert sorted(mine) == sorted((r, x) for r in backend.local_ranks for x in ("a", "b"))
    assert all(b >= a for _, _, a, b in recs)
    by_rank = {}
    for r, name, a, b in recs:
        by_rank.setdefault(r, []).append((name, a, b))
    for r, xs in by_rank.items():   # program order on each rank
        assert [x[0] for x in xs] == ["a", "b"] and xs[1][1] >= xs[0][2] - 1e-12


def b_rank_and_size(backend):
    assert backend.size >= 1 and len(backend.local_ranks) >= 1
    assert all(0 <= r < backend.size for r in backend.local_ranks)
    assert backend.is_root == (0 in backend.local_ranks)
    for r in backend.local_ranks:
        ep = backend.endpoint(r)
        assert ep.rank == r and ep.size == backend.size


def b_collectives_of_the_core(backend):
    """gather, bcast, barrier and first_problem, as the core calls them: every rank of
    the run in this process (single, mock) or one a process (MPI)."""
    backend.barrier()
    one_process = len(backend.local_ranks) == backend.size
    me = backend.local_ranks[0]
    got = backend.gather({"rank": me})
    if one_process:
        assert got == [{"rank": me}]
    elif backend.is_root:
        assert [g["rank"] for g in got] == list(range(backend.size))
    else:
        assert got is None
    assert backend.bcast(("from", me)) == ("from", 0 if not one_process else me)
    found = None if me == 0 and backend.size > 1 else (me, 7, 2)
    first = backend.first_problem(found)
    assert first == (found if one_process else (1, 7, 2))


BEHAVIOURS = [b_rank_and_size, b_collectives_of_the_core, b_allreduce_min, b_halo_roundtrip, b_empty_halo, b_particles_roundtrip,
              b_empty_particles_and_none, b_gather_rows_order, b_records_every_task]


def behaviours():
    return [(f.__name__[2:], f) for f in BEHAVIOURS]


# --------------------------------------------------------------------------- per backend
class CommConformance:
    """Mixin: subclasses define `make()` returning a fresh backend."""

    def make(self):
        raise NotImplementedError

    @pytest.mark.parametrize("name", [n for n, _ in behaviours()])
    def test_behaviour(self, name):
        dict(behaviours())[name](self.make())


class TestSingle(CommConformance):
    def make(self):
        from sphgraph.registry import get
        return get("comm", "single")()


class TestMock(CommConformance):
    def make(self):
        from sphgraph.registry import get
        return get("comm", "mock")(ranks=3)


class TestMockTwoRanksDelayed(CommConformance):
    def make(self):
        from sphgraph.registry import get
        return get("comm", "mock")(ranks=2, delay=1e-3, reorder=True, seed=3)


# The MPI backend: test_multirank.py::test_mpi_conformance runs these behaviours under mpiexec.
