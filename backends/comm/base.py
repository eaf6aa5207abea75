"""Communication backends: how ranks talk, and how the scheduler runs their programs.

`execute(jobs, record)` is the one place a step's tasks run: `jobs` is a list
of (RankContext, [Task, ...]) for the ranks this process drives, each list in
schedule order; `record(rank, task, start, end)` is called for every task.
Single-process and MPI backends drive one rank each in issue order (an MPI
receive blocks, a send is posted without waiting); the mock backend drives N
ranks through a discrete-event engine. Every comm backend passes the shared
conformance suite in `tests/test_comm_conformance.py`.
"""
from __future__ import annotations

import time


class CommBackend:
    """Base class. Subclasses register with `@register("comm", NAME)`."""

    name = "base"
    virtual_time = False   # True when task times are simulated seconds

    def __init__(self, ranks: int = 1, **options):
        self.size = ranks

    @property
    def local_ranks(self) -> list[int]:
        """Ranks whose programs this process runs."""
        return [0]

    @property
    def is_root(self) -> bool:
        return 0 in self.local_ranks

    def endpoint(self, rank: int):
        """The object a rank's tasks call: isend, recv, allreduce_min."""
        raise NotImplementedError

    def execute(self, jobs, record) -> None:
        raise NotImplementedError

    def gather_rows(self, per_rank: dict) -> list | None:
        """Collect `per_rank[rank]` objects of all ranks on the root (list in rank order)."""
        raise NotImplementedError

    def allreduce(self, value, op):
        raise NotImplementedError

    def bcast(self, obj):
        return obj

    def abort(self, code: int) -> None:
        pass

    def clock(self) -> float:
        return time.perf_counter()
