"""One process, one rank: no messages; tasks run in schedule order, wall-clock timed."""
from __future__ import annotations

import time

from sphgraph.registry import register

from .base import CommBackend


class _Endpoint:
    rank = 0
    size = 1

    def isend(self, dest, tag, payload):
        raise RuntimeError("single-rank run: no neighbour to send to")

    def recv(self, source, tag):
        raise RuntimeError("single-rank run: no neighbour to receive from")

    def allreduce_min(self, x):
        return x

    def gather(self, x) -> list:
        return [x]

    def allgather(self, x) -> list:
        return [x]


@register("comm", "single")
class SingleComm(CommBackend):
    def __init__(self, ranks: int = 1, halo_transport: str = "auto", **options):
        super().__init__(1, halo_transport)

    def endpoint(self, rank: int):
        return _Endpoint()

    def execute(self, jobs, record) -> None:
        clock = time.perf_counter
        for ctx, program in jobs:
            for task in program:
                t0 = clock()
                task.fn(ctx, task)
                record(ctx.rank, task, t0, clock())

    def gather_rows(self, per_rank: dict):
        return [per_rank[0]]

    def allreduce(self, value, op):
        return value
