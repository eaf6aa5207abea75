"""Task kinds: the one table that names every task of a step.

TOML keys in schedules, trace labels, plot labels and the paper's timer names
all come from here (seed paper Figs. 11-12 timers in brackets).
"""
from __future__ import annotations

from enum import Enum

LANES = ("compute", "comm", "copy")


class TaskKind(Enum):
    #                 label              paper timer      lane       per stage
    SEND_DISPLACED = ("send_displaced", "SendDisplaced", "comm", False)
    RECV_DISPLACED = ("recv_displaced", "RecvDisplaced", "comm", False)
    BUILD_CELLS = ("build_cells", "NL", "compute", False)
    SEND_EDGES = ("send_edges", "SendEdge", "comm", True)
    RECV_HALO_1 = ("recv_halo_1", "RecvHalo", "comm", True)
    RECV_HALO_2 = ("recv_halo_2", "RecvHalo", "comm", True)
    FORCES_INTERIOR = ("forces_interior", "FC", "compute", True)
    FORCES_HALO_1 = ("forces_halo_1", "FC", "compute", True)
    FORCES_HALO_2 = ("forces_halo_2", "FC", "compute", True)
    DT_LOCAL = ("dt_local", "PU", "compute", False)
    DT_ALLREDUCE = ("dt_allreduce", "SynchroDt", "comm", False)
    INTEGRATE = ("integrate", "PU", "compute", True)
    MOTION = ("motion", "Motion", "compute", True)    # conditional: scenes with moving bodies etc.
    REBALANCE = ("rebalance", "Balancing", "compute", False)

    def __init__(self, label, timer, lane, per_stage):
        self.label = label
        self.timer = timer
        self.default_lane = lane
        self.per_stage = per_stage

    @classmethod
    def from_label(cls, label: str) -> "TaskKind":
        return _BY_LABEL[label]

    @classmethod
    def labels(cls) -> list[str]:
        return [k.label for k in cls]


_BY_LABEL = {k.label: k for k in TaskKind}

# Kinds that exist only with neighbours (a single rank skips them), and the
# neighbour each needs: 1 = lower (r-1), 2 = upper (r+1), 0 = any.
NEEDS_NEIGHBOUR = {
    TaskKind.SEND_DISPLACED: 0, TaskKind.RECV_DISPLACED: 0, TaskKind.SEND_EDGES: 0,
    TaskKind.RECV_HALO_1: 1, TaskKind.FORCES_HALO_1: 1,
    TaskKind.RECV_HALO_2: 2, TaskKind.FORCES_HALO_2: 2,
}
# Kinds placed only when the run asks for them (a flag of Schedule.program):
# rebalance on check steps, motion when the scene has moving bodies, damping
# zones or periodic axes (sphgraph.features).
CONDITIONAL = (TaskKind.REBALANCE, TaskKind.MOTION)
# dt is computed once per step, from the first force stage
FIRST_STAGE_ONLY = (TaskKind.DT_LOCAL, TaskKind.DT_ALLREDUCE)
