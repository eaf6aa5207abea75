"""A task instance: kind (or user name), stage, declared data access and messages.

Dependencies are never wired by hand: `build.rank_graph` derives them from the
`reads`, `writes` and `accumulates` declared here (sequential task flow: the
canonical step order defines what "after" means, like StarPU's STF model).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

from .kinds import TaskKind

# Data names that stand for several: a declaration of "particles" reads (or writes) every
# field of the owned rows. Tasks of the features name the fields they touch, so the graph
# orders them by what they share; user tasks and the core's coarse tasks keep "particles".
GROUPS = {"particles": ("rows", "positions", "velocities", "densities")}


def fine(names) -> tuple:
    """`names` with every group name replaced by its members (order kept, no repeats)."""
    out = []
    for n in names:
        for m in GROUPS.get(n, (n,)):
            if m not in out:
                out.append(m)
    return tuple(out)


@dataclass(frozen=True)
class Message:
    """One point-to-point message: `peer` is a rank offset (-1 lower, +1 upper)."""

    peer: int
    tag: int


@dataclass
class Task:
    kind: TaskKind | str             # str for a user-defined task
    stage: int | None = None
    reads: tuple = ()
    writes: tuple = ()
    accumulates: tuple = ()
    lane: str = "compute"
    fn: Callable | None = None       # fn(ctx, task)
    sends: tuple = ()                # Message, posted without waiting
    recvs: tuple = ()                # Message, the task waits for each
    collective: bool = False         # joined by every rank (dt allreduce)
    # a collective that is one reduction: (op, value(ctx)), the value fn hands to ctx.comm.
    # A comm that holds every rank (mock) reduces the values first, and fn's call returns
    # the result without waiting for the other ranks
    reduce: tuple | None = None
    # the body waits for the rank's device work to read a result on the host (dt, the check):
    # a comm that runs several ranks in one thread issues the other ranks' work first
    reads_device: bool = False
    meta: dict = field(default_factory=dict)

    # label and name are read for every task a rank runs (the engine, the records, the
    # lanes): computed once; a task is never changed after it is made (`replace` makes a
    # new one)
    @cached_property
    def label(self) -> str:
        return self.kind.label if isinstance(self.kind, TaskKind) else self.kind

    @cached_property
    def name(self) -> str:
        return self.label if self.stage is None else f"{self.label}@{self.stage}"

    def __repr__(self):
        return f"Task({self.name})"

    def __hash__(self):
        return hash(self.name)

    def __eq__(self, other):
        return isinstance(other, Task) and other.name == self.name


@dataclass
class UserTask:
    """A task a user adds: a function plus its declared data access.

    `fn(ctx, task)` gets the rank context (`ctx.state`, `ctx.compute`, ...).
    Data names are those of `sphgraph.graph.tasks.DATA` ("particles" for every
    field of the owned rows) or new names of the
    user's own (kept in `ctx.state.extra`). Place it in a schedule's `order`
    by `name`; `per_stage` places one instance per force stage.
    """

    name: str
    fn: Callable
    reads: tuple = ()
    writes: tuple = ()
    accumulates: tuple = ()
    lane: str = "compute"
    per_stage: bool = False
