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
    REBALANCE = ("rebalance", "Balancing", "compute", False)
    # scene features (sphgraph.features): placed only when the scene asks for them
    MDBC = ("mdbc", "MDBC", "compute", True)
    # mDBC on several ranks: the edge's boundary rows' new densities and velocities, sent
    # after the sender's mdbc, replace the stale ones its neighbours' halos hold
    SEND_MDBC = ("send_mdbc", "SendMDBC", "comm", True)
    RECV_MDBC_1 = ("recv_mdbc_1", "RecvMDBC", "comm", True)
    RECV_MDBC_2 = ("recv_mdbc_2", "RecvMDBC", "comm", True)
    FORCES_IMAGES = ("forces_images", "FC", "compute", True)
    SHIFT_INTERIOR = ("shift_interior", "Shifting", "compute", True)
    SHIFT_IMAGES = ("shift_images", "Shifting", "compute", True)
    SHIFT_HALO_1 = ("shift_halo_1", "Shifting", "compute", True)
    SHIFT_HALO_2 = ("shift_halo_2", "Shifting", "compute", True)
    SHIFT_DISPLACEMENT = ("shift_displacement", "Shifting", "compute", True)
    SHIFT_APPLY = ("shift_apply", "Shifting", "compute", True)
    MOTION = ("motion", "Motion", "compute", True)
    DAMPING = ("damping", "Damping", "compute", True)
    WRAP = ("wrap", "Periodic", "compute", True)
    # the backend's end-of-step check of the rows, started (a device backend launches it and
    # its copy to the host); `exclude` reads its finding
    CHECK = ("check", "Exclusion", "compute", False)
    EXCLUDE = ("exclude", "Exclusion", "compute", False)
    PROBES = ("probes", "Probes", "compute", False)

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
    TaskKind.SHIFT_HALO_1: 1, TaskKind.SHIFT_HALO_2: 2,
    TaskKind.SEND_MDBC: 0, TaskKind.RECV_MDBC_1: 1, TaskKind.RECV_MDBC_2: 2,
}
# The scene features' kinds: placed only when the run's feature set names them
# (`sphgraph.features.Features.kinds`, an argument of Schedule.program).
FEATURES = (TaskKind.MDBC, TaskKind.SEND_MDBC, TaskKind.RECV_MDBC_1, TaskKind.RECV_MDBC_2,
            TaskKind.FORCES_IMAGES, TaskKind.SHIFT_INTERIOR, TaskKind.SHIFT_IMAGES,
            TaskKind.SHIFT_HALO_1, TaskKind.SHIFT_HALO_2, TaskKind.SHIFT_DISPLACEMENT,
            TaskKind.SHIFT_APPLY, TaskKind.MOTION, TaskKind.DAMPING, TaskKind.WRAP,
            TaskKind.CHECK, TaskKind.EXCLUDE, TaskKind.PROBES)
# Kinds placed only when the run asks for them: rebalance on check steps, a feature's
# tasks when the scene has the feature
CONDITIONAL = (TaskKind.REBALANCE,) + FEATURES
# dt is computed once per step, from the first force stage
FIRST_STAGE_ONLY = (TaskKind.DT_LOCAL, TaskKind.DT_ALLREDUCE)
# shifting is applied in the last force stage (the corrector of a Symplectic step), damping
# and periodic wrapping once the step's positions are final
LAST_STAGE_ONLY = (TaskKind.SHIFT_INTERIOR, TaskKind.SHIFT_IMAGES, TaskKind.SHIFT_HALO_1,
                   TaskKind.SHIFT_HALO_2, TaskKind.SHIFT_DISPLACEMENT, TaskKind.SHIFT_APPLY,
                   TaskKind.DAMPING, TaskKind.WRAP)
# Where a feature's task goes when a schedule's `order` does not name it (schedule files
# written before the feature keep working): ("after", labels) right after whichever of
# `labels` comes last in the order, ("before", labels) right before the first of them,
# ("end", ()) at the end of the step. Kinds are placed in this table's order, so a kind
# may anchor on one placed before it.
PLACEMENT = {
    # before the stage's first force task; on several ranks the schedule must have the halos
    # arrive before it (the ghosts near a cut sum the neighbour's fluid: Features.check_schedule)
    TaskKind.MDBC: ("before", ("forces_interior", "forces_images", "forces_halo_1", "forces_halo_2")),
    TaskKind.SEND_MDBC: ("after", ("mdbc",)),
    TaskKind.RECV_MDBC_1: ("before", ("forces_halo_1",)),
    TaskKind.RECV_MDBC_2: ("before", ("forces_halo_2",)),
    TaskKind.FORCES_IMAGES: ("after", ("forces_interior",)),
    TaskKind.SHIFT_INTERIOR: ("after", ("forces_interior", "forces_images")),
    TaskKind.SHIFT_IMAGES: ("after", ("forces_images", "shift_interior")),
    TaskKind.SHIFT_HALO_1: ("after", ("forces_halo_1",)),
    TaskKind.SHIFT_HALO_2: ("after", ("forces_halo_2",)),
    TaskKind.SHIFT_DISPLACEMENT: ("before", ("integrate",)),
    TaskKind.SHIFT_APPLY: ("after", ("integrate",)),
    TaskKind.MOTION: ("after", ("integrate", "shift_apply")),
    TaskKind.DAMPING: ("after", ("integrate", "shift_apply", "motion")),
    TaskKind.WRAP: ("after", ("integrate", "shift_apply", "motion", "damping")),
    TaskKind.EXCLUDE: ("end", ()),
    TaskKind.CHECK: ("before", ("exclude",)),
    TaskKind.PROBES: ("end", ()),
}
