"""The tasks of a step: declared data access, messages, and what each one runs.

Data names (what tasks read, write or accumulate; `DATA` lists them):
  rows        which rows the rank owns and their order (ids, kinds, count)
  positions, velocities, densities  the owned rows' fields (velocities and densities
              include their Verlet history); `particles` names all four (`GROUPS`),
              as a schedule's user tasks may declare
  cells       the owned rows' cell grid and pressures (rebuilt by build_cells)
              build_cells and recv_displaced both *accumulate* into particles and
              cells: either order gives bit-identical rows (build first: the arrivals are
              merged into the sorted rows, seed paper §III-B "during the creation of the
              neighbour list the processes send and receive the particles that change
              subdomain"); send_displaced writes before them, every reader comes after both
  halo_1/2    the rows received from the lower / upper neighbour
  images      the periodic images of the rank's own rows (sphgraph.periodic; force part halo_3)
  forces@s    the force buffer of stage s: every force task *accumulates* into its
              own partial (interior, images, halo 1, halo 2); readers see the sum in a
              fixed order
  shift_sums  particle shifting's partial sums (one per source set, accumulated like forces)
  displacement  the shifting displacement of the step
  dt_local, dt  the rank's dt proposal and the global dt
  row_check   the end-of-step check of the rows, started (its finding read by `exclude`)
  check       the end-of-step check's finding (row, cause) or none
  samples     the run's probe and body-force samples (sphgraph.probes)
  edges@s, displaced  outgoing messages (cross-rank edges join them to the receives)

Scene features add their own tasks, only when the scene asks (sphgraph.features): `mdbc@s`
(boundary density and velocity extrapolated before the stage's forces; on several ranks from
the halos' fluid too, then `send_mdbc@s` / `recv_mdbc_1/2@s` put the new values of the edge's
boundary rows on the neighbours' halos), `forces_images@s`
(the rows against their periodic images), the shifting sums of each source set
(`shift_interior`, `shift_images`, `shift_halo_1/2`, last stage), `shift_displacement`
(before `integrate`, from the velocities the forces saw) and `shift_apply` (after it),
`motion@s` (moving bodies at the stage's end time), `damping` and `wrap` (periodic axes,
last stage), `check` and `exclude` (end of step: the backend's check started, then its
finding read and the rows out of bounds removed) and `probes` (end of step, a collective: when a sample is due, each rank's
partial sums of its own rows added on the root). Their place in a schedule that does not name them is
`kinds.PLACEMENT`.

The canonical order below is the step as a sequential program; dependencies
come from it and the declarations (`build.rank_graph`), schedules reorder it.
"""
from __future__ import annotations

from .kinds import FIRST_STAGE_ONLY, LAST_STAGE_ONLY, NEEDS_NEIGHBOUR, TaskKind as K
from .task import GROUPS, Message, Task
from ..wire import payload_nbytes

DATA = ("rows", "positions", "velocities", "densities", "cells", "halo_1", "halo_2", "images",
        "forces@s", "shift_sums", "displacement", "dt_local", "dt", "row_check", "check", "samples", "edges@s",
        "displaced") + tuple(GROUPS)

# tags: one per (message type, stage, direction) so MPI's non-overtaking rule is never needed
TAG_DISPLACED = 1


def tag_edges(stage: int, direction: int) -> int:
    """Edges sent towards `direction` (-1 lower, +1 upper) in force stage `stage`."""
    return 10 + 2 * stage + (0 if direction < 0 else 1)


PRE = (K.SEND_DISPLACED, K.RECV_DISPLACED, K.BUILD_CELLS)
STAGE = (K.SEND_EDGES, K.RECV_HALO_1, K.RECV_HALO_2, K.MDBC, K.SEND_MDBC, K.FORCES_INTERIOR,
         K.FORCES_IMAGES, K.SHIFT_INTERIOR, K.SHIFT_IMAGES, K.RECV_MDBC_1, K.FORCES_HALO_1, K.SHIFT_HALO_1,
         K.RECV_MDBC_2, K.FORCES_HALO_2, K.SHIFT_HALO_2, K.DT_LOCAL, K.DT_ALLREDUCE, K.SHIFT_DISPLACEMENT, K.INTEGRATE,
         K.SHIFT_APPLY, K.MOTION, K.DAMPING, K.WRAP)
POST = (K.REBALANCE, K.CHECK, K.EXCLUDE, K.PROBES)


def in_stage(kind: K, stage: int, stages: int) -> bool:
    """Whether a kind of the stage block has an instance in force stage `stage` of `stages`."""
    if kind in FIRST_STAGE_ONLY:
        return stage == 1
    if kind in LAST_STAGE_ONLY:
        return stage == stages
    return kind.per_stage or stage == 1


def tag_mdbc(stage: int, direction: int) -> int:
    """mDBC's boundary values of the edge sent towards `direction` in force stage `stage`."""
    return 30 + 2 * stage + (0 if direction < 0 else 1)


def neighbours(rank: int, nranks: int) -> list[int]:
    """Offsets of existing neighbours: -1 (lower) and/or +1 (upper)."""
    return [d for d in (-1, 1) if 0 <= rank + d < nranks]


def links(rank: int, nranks: int, ring: bool = False) -> list[tuple[int, int]]:
    """(direction, rank offset) of each neighbour: direction -1 lower, +1 upper. In a
    ring (periodic split axis) the end ranks are neighbours: rank 0's lower is the last."""
    out = []
    for d in (-1, 1):
        if 0 <= rank + d < nranks:
            out.append((d, d))
        elif ring and nranks > 1:
            out.append((d, (rank + d) % nranks - rank))
    return out


def tag_displaced(direction: int, ring: bool = False) -> int:
    """Displaced rows sent towards `direction`; a 2-rank ring needs one tag per direction."""
    return TAG_DISPLACED if not ring else (2 if direction < 0 else 3)


def applicable(kind: K, rank: int, nranks: int, ring: bool = False) -> bool:
    need = NEEDS_NEIGHBOUR.get(kind)
    if need is None:
        return True
    if need == 0 or (ring and nranks > 1):
        return nranks > 1
    return (rank > 0) if need == 1 else (rank < nranks - 1)


def make_task(kind: K, stage: int | None, rank: int, nranks: int, lane: str | None = None,
              ring: bool = False) -> Task:
    """A built-in task instance with its access declarations and messages."""
    s = stage
    lane = lane or kind.default_lane
    nb = links(rank, nranks, ring)
    dirs = {"dirs": tuple(d for d, _ in nb)}
    if kind is K.SEND_DISPLACED:
        return Task(kind, None, reads=("particles",), writes=("particles", "displaced"), lane=lane,
                    fn=run_send_displaced, sends=tuple(Message(o, tag_displaced(d, ring)) for d, o in nb),
                    meta=dirs)
    if kind is K.RECV_DISPLACED:
        return Task(kind, None, accumulates=("particles", "cells"), lane=lane, fn=run_recv_displaced,
                    recvs=tuple(Message(o, tag_displaced(-d, ring)) for d, o in nb))
    if kind is K.BUILD_CELLS:
        return Task(kind, None, accumulates=("particles", "cells"), lane=lane, fn=run_build_cells)
    if kind is K.SEND_EDGES:
        return Task(kind, s, reads=("particles", "cells"), writes=(f"edges@{s}",), lane=lane,
                    fn=run_send_edges, sends=tuple(Message(o, tag_edges(s, d)) for d, o in nb), meta=dirs)
    if kind in (K.RECV_HALO_1, K.RECV_HALO_2):
        side = 1 if kind is K.RECV_HALO_1 else 2
        d = -1 if side == 1 else 1
        o = dict(nb)[d]
        # the neighbour below sent its edge "up" (+1), the one above "down" (-1)
        return Task(kind, s, writes=(f"halo_{side}",), lane=lane, fn=run_recv_halo,
                    recvs=(Message(o, tag_edges(s, -d)),), meta={"side": side})
    if kind is K.SEND_MDBC:
        # the values of the rows of the edge this stage's send_edges made (the ipc transport
        # writes them into that edge's buffer)
        return Task(kind, s, reads=("rows", "positions", "velocities", "densities", f"edges@{s}"), lane=lane,
                    fn=run_send_mdbc, sends=tuple(Message(o, tag_mdbc(s, d)) for d, o in nb), meta=dirs)
    if kind in (K.RECV_MDBC_1, K.RECV_MDBC_2):
        side = 1 if kind is K.RECV_MDBC_1 else 2
        d = -1 if side == 1 else 1
        return Task(kind, s, reads=(f"halo_{side}",), writes=(f"halo_{side}",), lane=lane, fn=run_recv_mdbc,
                    recvs=(Message(dict(nb)[d], tag_mdbc(s, -d)),), meta={"side": side})
    if kind is K.FORCES_INTERIOR:
        return Task(kind, s, reads=("particles", "cells"), accumulates=(f"forces@{s}",), lane=lane,
                    fn=run_forces, meta={"part": "interior"})
    if kind in (K.FORCES_HALO_1, K.FORCES_HALO_2):
        side = 1 if kind is K.FORCES_HALO_1 else 2
        return Task(kind, s, reads=("particles", "cells", f"halo_{side}"),
                    accumulates=(f"forces@{s}",), lane=lane, fn=run_forces,
                    meta={"part": f"halo_{side}"})
    if kind is K.DT_LOCAL:
        return Task(kind, None, reads=("particles", "forces@1"), writes=("dt_local",), lane=lane,
                    fn=run_dt_local)
    if kind is K.DT_ALLREDUCE:
        return Task(kind, None, reads=("dt_local",), writes=("dt",), lane=lane,
                    fn=run_dt_allreduce, collective=True, reduce=("min", _dt_value))
    if kind is K.INTEGRATE:
        return Task(kind, s, reads=(f"forces@{s}", "dt"), writes=("particles",), lane=lane,
                    fn=run_integrate)
    if kind is K.REBALANCE:
        return Task(kind, None, reads=("particles",), writes=("particles", "cells"), lane=lane,
                    fn=run_rebalance, collective=True)
    feature = FEATURE_ACCESS.get(kind)
    if feature is not None:
        reads, writes, accumulates, fn = feature
        at = (lambda names: tuple(x.replace("@s", f"@{s}") for x in names))
        return Task(kind, s if kind.per_stage else None, reads=at(reads), writes=at(writes),
                    accumulates=at(accumulates), lane=lane, fn=fn, collective=kind is K.PROBES,
                    reads_device=kind is K.EXCLUDE, meta={"part": _SHIFT_PART.get(kind)})
    raise ValueError(kind)


def canonical_tasks(rank: int, nranks: int, stages: int, rebalance: bool = False,
                    features=(), ring: bool = False) -> list[Task]:
    """The step as a sequential program for one rank (the reference order); `features`:
    the feature kinds the run places (`sphgraph.features.Features.kinds`)."""
    from .kinds import CONDITIONAL
    features = frozenset(features)

    def placed(k):
        return (k not in CONDITIONAL or k in features) and applicable(k, rank, nranks, ring)

    out = [make_task(k, None, rank, nranks, ring=ring) for k in PRE if applicable(k, rank, nranks, ring)]
    for s in range(1, stages + 1):
        for k in STAGE:
            if in_stage(k, s, stages) and placed(k):
                out.append(make_task(k, s if k.per_stage else None, rank, nranks, ring=ring))
    if rebalance and nranks > 1:
        out.append(make_task(K.REBALANCE, None, rank, nranks))
    out += [make_task(k, None, rank, nranks, ring=ring) for k in POST if k is not K.REBALANCE and placed(k)]
    return out


# --------------------------------------------------------------------------- task bodies
# Each takes (ctx, task): ctx is a `sphgraph.scheduler.RankContext`.

def run_send_displaced(ctx, task):
    # a device-resident backend first brings the host rows up to date if any row left
    # the slab (its `take_displaced`); otherwise the host rows are current
    ctx.state.cells_step = None      # the rows change: any cells built before are stale
    out = ctx.compute.take_displaced(ctx.state, ctx.domain)
    for m, d in zip(task.sends, task.meta["dirs"]):
        ctx.state.bytes_sent += payload_nbytes(out[d])   # the edges count theirs as they are packed
        ctx.comm.isend(ctx.rank + m.peer, m.tag, out[d])


def run_recv_displaced(ctx, task):
    rows = [ctx.comm.recv(ctx.rank + m.peer, m.tag) for m in task.recvs]
    st = ctx.state
    built = st.cells_step is not None and st.cells_step == st.step  # build_cells ran first
    ctx.compute.add_displaced(st, ctx.domain, rows, built)


def run_build_cells(ctx, task):
    ctx.compute.build_cells(ctx.state)
    ctx.state.cells_step = ctx.state.step


def run_send_edges(ctx, task):
    ipc = ctx.halo_transport == "ipc"    # the rows stay on the device, a buffer per message tag
    for m, d in zip(task.sends, task.meta["dirs"]):
        payload = ctx.compute.edge(ctx.state, ctx.domain, d, slot=m.tag if ipc else None)
        ctx.comm.isend(ctx.rank + m.peer, m.tag, payload)


def run_recv_halo(ctx, task):
    m = task.recvs[0]
    halo = ctx.comm.recv(ctx.rank + m.peer, m.tag)
    ctx.compute.prepare_halo(ctx.state, halo)
    ctx.state.halos[task.meta["side"]] = halo


def run_send_mdbc(ctx, task):
    for m, d in zip(task.sends, task.meta["dirs"]):
        values = ctx.compute.mdbc_edge(ctx.state, ctx.domain, d)
        ctx.state.bytes_sent += payload_nbytes(values)
        ctx.comm.isend(ctx.rank + m.peer, m.tag, values)


def run_recv_mdbc(ctx, task):
    m = task.recvs[0]
    values = ctx.comm.recv(ctx.rank + m.peer, m.tag)
    ctx.compute.mdbc_halo(ctx.state, ctx.state.halos[task.meta["side"]], values)


def run_forces(ctx, task):
    ctx.compute.forces(ctx.state, task.meta["part"])


def run_dt_local(ctx, task):
    ctx.compute.reduce_forces(ctx.state, 1)
    if ctx.fixed_dt is None:
        # started only: a device backend's wait for it is in dt_allreduce, so that on many
        # ranks of one host every rank's dt terms are queued before the first wait
        ctx.compute.dt_local_begin(ctx.state)
    else:
        ctx.state.dt_local = ctx.fixed_dt


def run_dt_allreduce(ctx, task):
    ctx.state.dt = ctx.comm.allreduce_min(_dt_value(ctx))


def _dt_value(ctx):
    """The rank's dt proposal, read from the backend (its wait, once) unless fixed."""
    if ctx.fixed_dt is None:
        ctx.state.dt_local = ctx.compute.dt_local_end(ctx.state)
    return ctx.state.dt_local


def run_integrate(ctx, task):
    ctx.compute.reduce_forces(ctx.state, task.stage)
    ctx.compute.integrate(ctx.state, task.stage, ctx.integrator, ctx.euler)


def run_rebalance(ctx, task):
    ctx.balancer.step(ctx)


# the feature tasks' bodies are the scene features' own (sphgraph.features: ctx.features)
def run_mdbc(ctx, task):
    ctx.features.mdbc.apply(ctx)


def run_forces_images(ctx, task):
    ctx.features.periodic.image_forces(ctx)


def run_shift_part(ctx, task):
    ctx.features.shifting.sums(ctx, task.meta["part"])


def run_shift_displacement(ctx, task):
    ctx.features.shifting.displacement(ctx)


def run_shift_apply(ctx, task):
    ctx.features.shifting.apply(ctx)


def run_motion(ctx, task):
    ctx.features.move_bodies(ctx, task.stage)


def run_damping(ctx, task):
    ctx.features.damping.apply(ctx)


def run_wrap(ctx, task):
    ctx.features.periodic.wrap(ctx)


def run_check(ctx, task):
    ctx.features.check_begin(ctx)


def run_exclude(ctx, task):
    ctx.features.exclude(ctx)


def run_probes(ctx, task):
    ctx.features.probes.sample_step(ctx)


_SHIFT_PART = {K.SHIFT_INTERIOR: "interior", K.SHIFT_IMAGES: "halo_3", K.SHIFT_HALO_1: "halo_1",
               K.SHIFT_HALO_2: "halo_2"}
_FIELDS = ("rows", "positions", "velocities", "densities")
# kind -> (reads, writes, accumulates, body) of the feature tasks; "@s" is the task's stage
FEATURE_ACCESS = {
    # the boundary rows' densities and velocities (and their pressures, part of cells) from the fluid
    # (on several ranks the ghosts near a cut also sum the halos' fluid rows)
    K.MDBC: (_FIELDS + ("cells", "halo_1", "halo_2"), ("densities", "velocities", "cells"), (), run_mdbc),
    # images of the own rows made and binned, then summed like a halo into the stage's forces
    K.FORCES_IMAGES: (_FIELDS + ("cells",), ("images",), ("forces@s",), run_forces_images),
    K.SHIFT_INTERIOR: (("rows", "positions", "densities", "cells"), (), ("shift_sums",), run_shift_part),
    K.SHIFT_IMAGES: (("rows", "positions", "images"), (), ("shift_sums",), run_shift_part),
    K.SHIFT_HALO_1: (("rows", "positions", "halo_1"), (), ("shift_sums",), run_shift_part),
    K.SHIFT_HALO_2: (("rows", "positions", "halo_2"), (), ("shift_sums",), run_shift_part),
    # from the velocities the forces saw: before integrate writes new ones
    K.SHIFT_DISPLACEMENT: (("rows", "velocities", "shift_sums", "dt"), ("displacement",), (),
                           run_shift_displacement),
    K.SHIFT_APPLY: (("displacement", "positions"), ("positions",), (), run_shift_apply),
    K.MOTION: (("rows", "dt"), ("positions", "velocities"), (), run_motion),
    K.DAMPING: (("rows", "positions", "velocities", "dt"), ("velocities",), (), run_damping),
    K.WRAP: (("positions",), ("positions",), (), run_wrap),
    # the backend's end-of-step check started, then its finding read; rows out of bounds
    # removed (buffers for the new count)
    K.CHECK: (("particles", "dt"), ("row_check",), (), run_check),
    K.EXCLUDE: (("particles", "row_check"), ("particles", "cells", "check"), (), run_exclude),
    # a collective (each rank's partial sums to the root) at the steps a sample is due
    K.PROBES: (("particles", "dt"), ("samples",), (), run_probes),
}
