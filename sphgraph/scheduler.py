"""The one run loop: a validated schedule executed on compute + comm backends.

Per step, each rank's program (its tasks in schedule order) is handed to the
comm backend's `execute`, which runs them (in order on one rank, interleaved
by the discrete-event engine under mock MPI) and reports each task's start
and end. Nothing else advances the solver: there is no second time loop.

Lanes: a compute backend with `uses_lanes` (numba-cuda: one CUDA stream per lane)
gets each task's lane and its cross-lane dependencies (`graph.build.lane_edges`)
through `lane_begin` / `lane_end` around the task body (`LaneStep`). Other
backends (numba-cpu) run the programs as they are: nothing is wrapped.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .graph.build import lane_edges, rank_graph
from .graph.kinds import TaskKind
from .schedule import Schedule


@dataclass
class RankContext:
    """What a task body sees: its rank's state and the backends."""

    rank: int
    state: object
    compute: object
    comm: object               # the comm backend's endpoint for this rank
    domain: object = None      # sphgraph.domain.Slabs (multi-rank) or None
    integrator: str = "verlet"
    euler: bool = False
    fixed_dt: float | None = None
    balancer: object = None
    scene: object = None
    halo_transport: str = "staged"   # the comm backend's: "staged" (through the host) or "ipc"
    features: object = None    # sphgraph.features.Features: the bodies of the feature tasks

    def force_buffer(self, name: str):
        """A zeroed partial force buffer `name` for a user task that accumulates into
        `forces@s`; it is summed after the interior and halo parts, in name order."""
        from .state import ForceBuffers
        p = self.state.particles
        buf = ForceBuffers.empty(p.n, p.dim, self.state.dtype)
        self.state.parts[name] = buf
        return buf


@dataclass
class TaskTimes:
    """Start/end of every task on every rank, kept as growing columns."""

    rank: list = field(default_factory=list)
    step: list = field(default_factory=list)
    task: list = field(default_factory=list)
    lane: list = field(default_factory=list)
    start: list = field(default_factory=list)
    end: list = field(default_factory=list)
    nbytes: list = field(default_factory=list)   # bytes the task sent (RankState.bytes_sent's growth)

    def columns(self) -> dict:
        return {"rank": np.array(self.rank, np.int32), "step": np.array(self.step, np.int64),
                "task": np.array(self.task, dtype=object), "lane": np.array(self.lane, dtype=object),
                "start": np.array(self.start, float), "end": np.array(self.end, float),
                "bytes": np.array(self.nbytes, np.int64)}

    def seconds_by_kind(self, first_step: int = 0) -> dict:
        out: dict[str, float] = {}
        for s, name, a, b in zip(self.step, self.task, self.start, self.end):
            if s >= first_step:
                label = name.split("@")[0]
                out[label] = out.get(label, 0.0) + (b - a)
        return out

    def clear(self):
        for v in self.__dict__.values():
            v.clear()


@dataclass(frozen=True)
class LaneStep:
    """What a lane-aware backend is told about one task of a rank's program."""

    lane: str
    waits: tuple = ()          # tasks on other lanes this one depends on (their events)
    record: bool = False       # a task on another lane depends on this one: record its event
    first: bool = False        # first task of its lane in the program: wait for the other
                               # lanes' work of the previous step (step-end events)
    last: bool = False         # last task of the program: record every lane's step-end event


def lane_program(program: list, graph) -> list:
    """`program` with every body wrapped in the backend's lane hooks (see LaneStep)."""
    edges = lane_edges(program, graph)
    waits: dict = {t.name: [] for t in program}
    producers = set()
    for u, v in edges:
        waits[v].append(u)
        producers.add(u)
    seen, out = set(), []
    for i, t in enumerate(program):
        step = LaneStep(t.lane, tuple(waits[t.name]), t.name in producers, t.lane not in seen,
                        i == len(program) - 1)
        seen.add(t.lane)
        out.append(replace(t, fn=_on_lane(t.fn, step)))
    return out


def _on_lane(fn, step):
    def run(ctx, task):
        compute = ctx.compute
        compute.lane_begin(ctx.state, task, step)
        try:
            if fn is not None:
                fn(ctx, task)
        finally:
            compute.lane_end(ctx.state, task, step)
    run.lane_step = step
    run.body = fn
    return run


class Scheduler:
    """Runs steps of `schedule` for the ranks a comm backend drives."""

    def __init__(self, schedule: Schedule, comm, contexts: list[RankContext], stages: int,
                 user_tasks=(), rebalance: bool = False, t_origin: float = 0.0, features=(),
                 ring: bool = False):
        """`features`: the scene features' task kinds (`sphgraph.features.task_kinds`)."""
        self.schedule = schedule
        self.comm = comm
        self.contexts = contexts
        lanes = bool(contexts) and contexts[0].compute.uses_lanes

        def program(rank, reb):
            prog = schedule.program(rank, comm.size, stages, user_tasks, reb, ring=ring, features=features)
            if lanes:
                graph = rank_graph(schedule.canonical(rank, comm.size, stages, user_tasks, reb, ring=ring,
                                                      features=features))
                prog = lane_program(prog, graph)
            return prog

        self.programs = {c.rank: program(c.rank, False) for c in contexts}
        # `rebalance` is conditional: a step that checks the balance runs the program with it
        self.programs_rebalance = {c.rank: program(c.rank, True) for c in contexts} if rebalance else self.programs
        self.times = TaskTimes()
        self.t_origin = t_origin
        self.record_times = True
        self.force_sinks = {c.rank: c.balancer for c in contexts if c.balancer is not None}
        self._ctx = {c.rank: c for c in contexts}
        self._sent = {c.rank: c.state.bytes_sent for c in contexts}

    def _record(self, rank, task, start, end):
        sent = self._ctx[rank].state.bytes_sent    # a rank's tasks are recorded in the order they ran
        nbytes = sent - self._sent[rank]
        self._sent[rank] = sent
        sink = self.force_sinks.get(rank)
        if sink is not None and task.label.startswith("forces_"):
            sink.note_force_time(rank, end - start)
        if not self.record_times:
            return
        t = self.times
        t.rank.append(rank)
        t.step.append(self.contexts[0].state.step)
        t.task.append(task.name)
        t.lane.append(task.lane)
        t.start.append(start - self.t_origin)
        t.end.append(end - self.t_origin)
        t.nbytes.append(nbytes)

    def step(self, rebalance: bool = False) -> None:
        progs = self.programs_rebalance if rebalance else self.programs
        self.comm.execute([(c, progs[c.rank]) for c in self.contexts], self._record)

    def task_kinds(self):
        return {t.label for p in self.programs.values() for t in p if isinstance(t.kind, TaskKind)}
