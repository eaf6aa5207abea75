"""Scene features beyond fluid in fixed boxes, switched on by the scene and absent otherwise.

One object per run holds what the scene asks for -- mDBC boundaries
(:mod:`.physics.mdbc`), periodic axes (:mod:`.periodic`), particle shifting
(:mod:`.shifting`), moving bodies (:mod:`.motion`), damping zones (:mod:`.waves`),
exclusion of particles that leave the domain -- and each feature's work is tasks of the
step graph (`graph.kinds.FEATURES`; data access in `graph.tasks.FEATURE_ACCESS`), placed
by :func:`task_kinds` and run through the scheduler like the others:

========================  =============================================================
``mdbc@s``                boundary densities and velocities from the fluid at their ghost
                          nodes, before the stage's forces (``[physics] boundary``); on
                          several ranks the ghosts also sum the halos' fluid rows
``send_mdbc@s``,          several ranks: the new values of the edge's boundary rows, sent
``recv_mdbc_1/2@s``       to the neighbours, whose halos held the values from before mdbc
``forces_images@s``       the rows against the periodic images of their own rows (part
                          ``halo_3``)
``shift_interior``, ...   the shifting sums of each source set (interior, images, halo 1,
                          halo 2), last stage
``shift_displacement``    the displacements, from the velocities before ``integrate``
``shift_apply``           the displacements added to the new positions
``motion@s``              moving bodies at the stage's end time
``damping``, ``wrap``     damping zones, periodic wrapping (last stage)
``exclude``               end of step: the backend's check of the rows; rows out of bounds
                          (``[domain] exclude_outside``, on by default as in DualSPHysics)
                          removed and counted
``probes``                end of step (runs that write output): ``[probes]`` / ``[forces]``
                          sampled when due (:mod:`.probes`)
========================  =============================================================

A scene without a feature gets none of its tasks and none of its work.
"""
from __future__ import annotations

import numpy as np

from .graph.kinds import TaskKind as K
from .particles import MOVING

SHIFT_KINDS = (K.SHIFT_INTERIOR, K.SHIFT_HALO_1, K.SHIFT_HALO_2, K.SHIFT_DISPLACEMENT, K.SHIFT_APPLY)
MDBC_SUPPORTED = "--backend numba-cpu or numba-cuda (one rank or several)"
MDBC_KINDS = (K.MDBC, K.SEND_MDBC, K.RECV_MDBC_1, K.RECV_MDBC_2)


def image_axes(scene, split_axis, nranks: int) -> list[int]:
    """The periodic axes done by images and wrapping: all but a periodic split axis of
    several ranks (a ring of slabs, `sphgraph.periodic`)."""
    axes = ["xyz".index(a) for a in scene.periodic]
    return [a for a in axes if not (nranks > 1 and a == split_axis)]


def is_ring(scene, split_axis, nranks: int) -> bool:
    """Whether the slab chain closes into a ring (the split axis is periodic)."""
    return bool(nranks > 1 and split_axis is not None and "xyz"[split_axis] in scene.periodic)


def samples(scene) -> bool:
    """Whether `scene` asks for probes or body forces."""
    return "probes" in scene.extra or "forces" in scene.extra


def task_kinds(scene, split_axis=None, nranks: int = 1, sample: bool = False) -> frozenset:
    """The feature task kinds of `scene` on `nranks` ranks split along `split_axis` (None:
    not yet known, every periodic axis counted as one of images); `sample`: the run samples
    the scene's probes and forces (a run that writes output)."""
    ph = scene.physics
    out = set()
    if ph.boundary != "dbc":
        out |= set(MDBC_KINDS)     # the exchange's kinds exist only with neighbours
    images = bool(image_axes(scene, split_axis, nranks))
    if images:
        out |= {K.FORCES_IMAGES, K.WRAP}
    if ph.shifting != "none":
        out |= set(SHIFT_KINDS) | ({K.SHIFT_IMAGES} if images else set())
    if scene.extra.get("motion"):
        out.add(K.MOTION)
    if scene.extra.get("damping"):
        out.add(K.DAMPING)
    if scene.exclude_outside:
        out |= {K.CHECK, K.EXCLUDE}
    if sample and samples(scene):
        out.add(K.PROBES)
    return frozenset(out)


def scene_layout(scene, nranks: int) -> tuple[frozenset, bool]:
    """(feature task kinds, ring) of `scene` on `nranks` ranks, its split axis chosen as a
    run chooses it (`sphgraph schedule show --scene`)."""
    axis = None
    if nranks > 1:
        from .domain import choose_axis
        axis = choose_axis(scene.decomposition_axis, scene.build_particles(), scene.constants.gravity)
    return task_kinds(scene, axis, nranks, sample=True), is_ring(scene, axis, nranks)


class Mdbc:
    """The ``mdbc`` task: modified dynamic boundaries (English et al. 2022, DualSPHysics'
    mDBC) on the boundary rows of one rank."""

    def __init__(self, scene, det_min: float = 1e-3, noslip: bool | None = None, motion=None):
        """`motion`: the scene's moving bodies (sphgraph.motion.Motion) or None."""
        from .physics.mdbc import ghost_positions, interface_boxes
        self.boxes = interface_boxes(scene)
        self.noslip = scene.physics.boundary == "mdbc-noslip" if noslip is None else noslip
        self.det_min = det_min
        self.motion = motion
        # A moving body's ghost nodes are mirrored once, across the interfaces at rest, from
        # its particles' start positions, and then carried with the body (Motion.table): the
        # interface boxes are the scene's at t = 0, so the ghosts of a body's rows at a later
        # time cannot come from their positions then.
        self.ghost_ref = None if motion is None else ghost_positions(np.asarray(motion.ref, np.float64), self.boxes)

    def moving_ghosts(self, state):
        """(ids, ghosts [m, dim]) of the moving bodies' particles at the time their rows hold
        (the last `motion` task's, or the state's time before any), or None without bodies."""
        if self.motion is None:
            return None
        t = state.extra.get("motion_time", state.time)
        return self.motion.ids, self.motion.table(t, self.ghost_ref)[0]

    def apply(self, ctx) -> None:
        """The task body: on a rank with periodic image axes the ghosts near a periodic face
        also sum the fluid across it, from images of the rank's rows made here, now; the
        images datum (`state.halos[IMAGE_SIDE]`, made by forces_images after this task, with
        the new boundary values) holds the previous stage's rows at this point and is not
        read."""
        from .periodic import IMAGE_SIDE
        st = ctx.state
        held = st.halos
        per = ctx.features.periodic if ctx.features is not None else None
        st.halos = {k: h for k, h in held.items() if k != IMAGE_SIDE}
        try:
            if per is not None and per.image_axes:
                im = per.source_images(ctx)
                ctx.compute.prepare_halo(st, im)
                st.halos[IMAGE_SIDE] = im
            ctx.compute.mdbc(st, self.boxes, self.det_min, self.noslip, self.moving_ghosts(st))
        finally:
            st.halos = held

    @staticmethod
    def ghost_reach(scene, particles, axis: int) -> float:
        """How far along `axis` a boundary row's ghost node lies from it (the most over the
        scene's boundary rows): the halos must reach that much further than 2h, so that the
        ghost of a row near a cut finds all its fluid."""
        from .physics.mdbc import ghost_positions, interface_boxes
        b = particles.kind != 0
        if not b.any():
            return 0.0
        pos = np.asarray(particles.pos[b], np.float64)
        off = ghost_positions(pos, interface_boxes(scene)) - pos
        reach = np.abs(off[:, axis])
        if any(e["type"] in ("rotation", "flap") for e in scene.extra.get("motion") or []):
            turn = particles.kind[b] == MOVING     # a turning body turns its ghosts towards the axis
            reach[turn] = np.sqrt((off[turn] ** 2).sum(1))
        return float(reach.max())


class Features:
    def __init__(self, scene, sample: bool = False):
        """`sample`: the run samples the scene's probes and forces (`probes` task)."""
        self.scene = scene
        self.sample = bool(sample and samples(scene))
        self.probes = None
        if self.sample:   # validated before anything of the scene's size exists
            from .probes import ProbeSampler
            self.probes = ProbeSampler(scene)
        self.mdbc = None
        self.motion = None
        self.damping = None
        self.periodic = None
        self.shifting = None
        self.exclude_outside = bool(scene.exclude_outside)
        self.excluded = []          # (step, time, id, cause, position, velocity, density) rows of this process's ranks
        self.restored = None        # a checkpoint's rows (every rank's, on the root), see restore_exclusions
        self.restored_step = -1
        self.stages = 1 if scene.physics.integrator == "verlet" else 2
        self.kinds = task_kinds(scene, sample=self.sample)   # until the split axis is known (`attach`)
        self.lo = self.hi = None    # the domain bounds of the end-of-step check (periodic: widened)

    def ring(self, axis, nranks: int) -> bool:
        """Whether the slab chain closes into a ring (the split axis is periodic)."""
        return is_ring(self.scene, axis, nranks)

    def check_backend(self, compute_cls, nranks: int, one_process: bool = True, halo_transport: str = "staged") -> None:
        """Refuse (InputError, one line) a feature the compute backend does not run
        (`one_process`: the ranks share this process, as mock ranks do; `halo_transport`:
        the run's, "auto" resolved)."""
        from .errors import InputError
        s, ph, name = self.scene, self.scene.physics, compute_cls.name
        have = compute_cls.scene_features
        for key, value, off in (("riemann", ph.riemann, "none"), ("riemann_jump", ph.riemann_jump, "plain"),
                               ("diffusion_time", ph.diffusion_time, "leapfrog")):
            if value != off and key not in have:
                raise InputError(f"{s.source}: physics.{key}: {value!r} runs with --backend numba-cpu "
                                 f"(or use {key} = \"{off}\"), got {name}")
        if s.extra.get("motion") and "motion" not in have:
            raise InputError(f"{s.source}: motion: [[motion]] bodies run with --backend numba-cpu or numba-cuda, "
                             f"got {name}")
        if ph.shifting != "none" and "shifting" not in have:
            raise InputError(f"{s.source}: physics.shifting: expected \"none\" with --backend {name} (it has "
                             f"no particle shifting; use numba-cpu), got {ph.shifting!r}")
        if ph.boundary != "dbc":
            why = (f"--backend {name}" if "mdbc" not in have
                   else f"{nranks} ranks on --backend {name}" if nranks != 1 and "mdbc-ranks" not in have
                   else None)
            if why is not None:
                raise InputError(f"{s.source}: physics.boundary: \"{ph.boundary}\" runs with {MDBC_SUPPORTED} "
                                 f"(or use boundary = \"dbc\"), got {why}")

    def check_schedule(self, schedule, nranks: int) -> None:
        """mDBC on several ranks: the schedule must bring both halos before the stage's first
        force task (where `mdbc` goes), since the ghosts near a cut sum the neighbour's fluid."""
        from .errors import InputError
        if K.MDBC not in self.kinds or nranks == 1:
            return
        labels = schedule.labels(self.kinds)
        late = [h for h in ("recv_halo_1", "recv_halo_2") if h in labels and labels.index(h) > labels.index("mdbc")]
        if late:
            raise InputError(f"{schedule.source}: order: physics.boundary \"{self.scene.physics.boundary}\" on "
                             f"{nranks} ranks needs {' and '.join(late)} before the stage's first force task "
                             f"(mdbc's ghosts near a cut sum the neighbour's fluid): expected a schedule with both "
                             f"halos before the forces (e.g. --schedule bulk-synchronous), got {schedule.name!r}")

    def attach(self, sim, particles) -> None:
        """Build the features from the scene's initial ``particles`` and hand them to every rank."""
        from .motion import Motion
        from .waves import Damping
        s = self.scene
        self.kinds = task_kinds(s, sim.axis, sim.nranks, sample=self.sample)
        if self.probes is not None:   # every rank's task shares the one sampler (mock) or not (MPI)
            self.probes.shared = len(sim.comm.local_ranks) == sim.nranks
        self.motion = Motion.from_scene(s, particles)
        if K.MDBC in self.kinds:
            self.mdbc = Mdbc(s, motion=self.motion)
        self.damping = Damping.from_scene(s)
        if s.periodic:
            from .periodic import Periodic
            self.periodic = Periodic.from_scene(s, sim)
            self.periodic.attach(sim)
        if s.physics.shifting != "none":
            from .shifting import Shifting
            self.shifting = Shifting.from_scene(s, sim)
        self.lo, self.hi = sim.lo, sim.hi
        for c in sim.contexts:
            c.features = self
            c.state.extra["excluded_ids"] = np.empty(0, np.int64)

    # ------------------------------------------------------------------ task bodies
    def move_bodies(self, ctx, stage: int) -> None:
        """The ``motion`` task: bodies at the stage's end time."""
        st = ctx.state
        mid = stage < self.stages
        t = st.time + (0.5 * st.dt if mid else st.dt)
        ctx.compute.move_bodies(st, self.motion, t, mid)
        st.extra["motion_time"] = t     # the time the bodies' rows hold: their mDBC ghosts' (Mdbc)

    def check_begin(self, ctx) -> None:
        """The ``check`` task: the backend's end-of-step check of this rank's rows started;
        ``exclude`` reads its finding."""
        ctx.compute.check_begin(ctx.state, self.lo, self.hi)

    def exclude(self, ctx) -> None:
        """The ``exclude`` task: the backend's end-of-step check of this rank's rows; when it
        finds a row out of bounds, the rows outside the domain (non-periodic axes) or, fluid
        only, outside [rho_min, rho_max] are removed, counted in
        ``state.extra["excluded_ids"]`` and listed in ``state.excluded`` (the rows are
        scanned on the host only then: a device backend keeps them on the device otherwise),
        and the rows left are checked again. The finding is ``state.check``
        (`Simulation.check` reports it)."""
        st = ctx.state
        bad = ctx.compute.check_end(st)
        if bad is not None and bad[1] in (2, 3):   # NaN (1) is the solver's to report
            bad = self._remove(ctx, bad)
        st.check, st.check_step = bad, st.step

    def _remove(self, ctx, bad):
        ph = self.scene.physics
        st = ctx.state
        ctx.compute.sync_host(st)    # the host rows current (a device backend), then removed
        p = st.particles
        x = np.asarray(p.pos)
        out = np.zeros(p.n, bool)
        for a in range(p.dim):
            if self.periodic is not None and a in self.periodic.axes:
                continue
            out |= (x[:, a] < self.lo[a]) | (x[:, a] > self.hi[a])
        cause = np.where(out, 2, 0)
        bad_rho = (p.kind == 0) & ((p.rho < ph.rho_min) | (p.rho > ph.rho_max)) & ~out
        cause[bad_rho] = 3
        rows = np.nonzero(cause)[0]
        if len(rows) == 0:
            return bad
        step, time = st.step + 1, st.time + st.dt    # as the solver counts them once the step ends
        # where and how each row left: what a user needs to find the wall or the jet it came through
        vel, rho = np.asarray(p.vel), np.asarray(p.rho)
        st.excluded = [(step, time, int(p.id[r]), int(cause[r]), tuple(map(float, x[r])),
                        tuple(map(float, vel[r])), float(rho[r])) for r in rows]
        st.extra["excluded_ids"] = np.concatenate([st.extra["excluded_ids"], p.id[rows]])
        st.particles = p.take(np.nonzero(cause == 0)[0])
        ctx.compute.prepare(st)
        return ctx.compute.check(st, self.lo, self.hi)

    def collect_exclusions(self, sim) -> None:
        """After a step: the rows its ``exclude`` tasks removed, in rank order, into
        :attr:`excluded`; raises `NumericalError` once the run's exclusions pass
        ``domain.exclude_max_share`` of its fluid particles."""
        if K.EXCLUDE not in self.kinds:
            return
        for c in sim.contexts:
            self.excluded += c.state.excluded
            c.state.excluded = []
        self._check_share(sim)

    def _check_share(self, sim) -> None:
        """Stop (NumericalError, exit 1) when the exclusions of the whole run, every rank's,
        pass ``exclude_max_share`` of its fluid particles: past that the run no longer holds
        the scene's water (docs/features.md, "Open boundaries")."""
        n = sum(len(c.state.extra.get("excluded_ids", ())) for c in sim.contexts)
        if len(sim.comm.local_ranks) < sim.nranks:    # MPI: one rank per process
            n = int(sim.comm.allreduce(n, "sum"))
        limit = self.scene.exclude_max_share * sim.n_fluid
        if n <= limit:
            return
        from .errors import NumericalError
        from .errors import CAUSES
        last = self.excluded[-1] if self.excluded else None
        what = (f": the last, particle id {last[2]} ({CAUSES[last[3]]})" if last is not None
                and last[0] == sim.step_count else "")
        raise NumericalError(
            f"step {sim.step_count} (t = {sim.time:.6g} s): {n} particles excluded, "
            f"{100.0 * n / max(sim.n_fluid, 1):.3g} % of the run's {sim.n_fluid} fluid particles, above "
            f"domain.exclude_max_share = {100.0 * self.scene.exclude_max_share:g} %{what}",
            step=sim.step_count, particle_id=None if not what else last[2], cause="exclusions")

    def restore_exclusions(self, cols: dict, step: int, root: bool) -> None:
        """A restart: the checkpoint's exclusions (every rank's, up to its `step`) are the
        record up to that step -- kept by the root process; rows in :attr:`excluded` at or
        before `step` (the solver may add them from ``output.h5``'s ``/exclusions``) are
        then the same ones and left out of :meth:`exclusions`."""
        self.restored_step = int(step)
        self.restored = exclusion_rows(cols, self.scene.dim) if root else []

    def exclusions(self, sim) -> dict | None:
        """Every rank's exclusions gathered (root), sorted by (step, id); None elsewhere."""
        rows = self.excluded
        if self.restored is not None:
            rows = self.restored + [r for r in rows if r[0] > self.restored_step]
        if len(sim.comm.local_ranks) < sim.nranks:    # MPI: one rank per process
            parts = sim.comm.gather(rows)
            if parts is None:
                return None
            rows = [r for p in parts for r in p]
        return exclusion_columns(sorted(rows, key=lambda r: (r[0], r[2])), self.scene.dim)


def exclusion_columns(rows: list, dim: int) -> dict:
    """The /exclusions columns of (step, time, id, cause, position, velocity, density) rows:
    position and velocity (n, dim) as they were in the step that removed the row."""
    vec = lambda k: np.array([r[k] for r in rows], float).reshape(len(rows), dim)
    return {"step": np.array([r[0] for r in rows], np.int64),
            "time": np.array([r[1] for r in rows], float),
            "id": np.array([r[2] for r in rows], np.int64),
            "cause": np.array([r[3] for r in rows], np.int8),
            "position": vec(4), "velocity": vec(5),
            "density": np.array([r[6] for r in rows], float)}


def exclusion_rows(cols: dict, dim: int, keep=None) -> list:
    """The rows of /exclusions columns (`keep`: a mask of the rows to take). Columns written
    before position, velocity and density were recorded give NaN there."""
    n = len(cols["step"])
    keep = np.ones(n, bool) if keep is None else np.asarray(keep, bool)
    nan = np.full((n, dim), np.nan)
    pos = np.asarray(cols.get("position", nan), float).reshape(n, dim)
    vel = np.asarray(cols.get("velocity", nan), float).reshape(n, dim)
    rho = np.asarray(cols.get("density", nan[:, 0]), float)
    return [(int(cols["step"][i]), float(cols["time"][i]), int(cols["id"][i]), int(cols["cause"][i]),
             tuple(map(float, pos[i])), tuple(map(float, vel[i])), float(rho[i]))
            for i in np.nonzero(keep)[0]]


def exclusion_summary(rows: dict, n_fluid: int) -> str:
    """One line for the end of a run: how many particles were excluded, their share of the
    fluid, the count by cause, the steps and the box their positions span -- where to look for
    the leak (`rows`: the /exclusions columns)."""
    from .errors import CAUSES
    n = len(rows["id"])
    causes, counts = np.unique(np.asarray(rows["cause"]), return_counts=True)
    by = ", ".join(f"{k} {CAUSES[int(c)]}" for c, k in zip(causes, counts))
    span = f", steps {int(rows['step'][0])}-{int(rows['step'][-1])}" if n else ""
    pos = np.asarray(rows.get("position", np.empty((0, 1))), float)    # (n, dim); none in older outputs
    pos = pos[np.isfinite(pos).all(axis=1)]
    where = ("; at " + ", ".join(f"{'xyz'[a]} {pos[:, a].min():.4g}..{pos[:, a].max():.4g}"
                                 for a in range(pos.shape[1])) + " m") if len(pos) else ""
    return (f"excluded {n} particles ({100.0 * n / max(n_fluid, 1):.3g} % of {n_fluid} fluid"
            + (f"; {by}" if n else "") + f"{span}{where})")
