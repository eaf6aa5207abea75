"""Scene features beyond fluid in fixed boxes, switched on by the scene and absent otherwise.

One object per run holds what the scene asks for -- moving bodies (:mod:`.motion`),
damping zones (:mod:`.waves`), periodic axes (:mod:`.periodic`), exclusion of
particles that leave the domain, particle shifting (:mod:`.shifting`) -- and the
solver calls it at fixed points:

* ``motion`` task (after ``integrate`` of each stage; placed in the step graph only
  when :attr:`Features.motion_task` is true): :meth:`post_integrate`;
* each force task: :meth:`after_forces` -- ``forces_interior`` adds the periodic-image
  force part; with shifting, every force task adds its source set's shifting sums;
* ``integrate``: :meth:`before_integrate` / :meth:`after_integrate` (shifting);
* the end-of-step check: :meth:`exclude` removes and counts particles out of bounds
  (``[domain] exclude_outside``, on by default as in DualSPHysics) and stops the run once
  they pass ``exclude_max_share`` of its fluid particles.

A scene without any of them gets ``Features.none`` behaviour: no extra task, no work.
"""
from __future__ import annotations

import numpy as np


class Features:
    def __init__(self, scene):
        self.scene = scene
        self.motion = None
        self.damping = None
        self.periodic = None
        self.shifting = None
        self.exclude_outside = bool(scene.exclude_outside)
        self.excluded = []          # (step, time, id, cause) rows of this process's ranks
        self.restored = None        # a checkpoint's rows (every rank's, on the root), see restore_exclusions
        self.restored_step = -1
        self.stages = 1 if scene.physics.integrator == "verlet" else 2

    @property
    def motion_task(self) -> bool:
        """Whether the step graph needs the ``motion`` task."""
        s = self.scene
        return bool(s.extra.get("motion") or s.extra.get("damping") or s.periodic)

    def ring(self, axis, nranks: int) -> bool:
        """Whether the slab chain closes into a ring (the split axis is periodic)."""
        return bool(nranks > 1 and axis is not None and "xyz"[axis] in self.scene.periodic)

    @property
    def active(self) -> bool:
        ph = self.scene.physics
        return (self.motion_task or self.exclude_outside or ph.shifting != "none"
                or ph.diffusion_time != "leapfrog" or ph.riemann != "none")

    def attach(self, sim, particles) -> None:
        """Build the features from the scene's initial ``particles`` and hook them to every rank."""
        from .motion import Motion
        from .waves import Damping
        s = self.scene
        self.motion = Motion.from_scene(s, particles)
        self.damping = Damping.from_scene(s)
        if s.periodic:
            from .periodic import Periodic
            self.periodic = Periodic.from_scene(s, sim)
            self.periodic.attach(sim)
        if s.physics.shifting != "none":
            from .shifting import Shifting
            self.shifting = Shifting.from_scene(s, sim)
        for c in sim.contexts:
            c.features = self
            c.state.extra["excluded_ids"] = np.empty(0, np.int64)

    # ------------------------------------------------------------------ hooks
    def post_integrate(self, ctx, stage: int) -> None:
        """The ``motion`` task: bodies at the stage's end time; damping and periodic
        wrapping once the step is complete (last stage)."""
        st = ctx.state
        last = stage >= self.stages
        t = st.time + (st.dt if last else 0.5 * st.dt)
        if self.motion is not None:
            self.motion.move(st, t)
        if last:
            if self.damping is not None:
                self.damping.apply(st, st.dt)
            if self.periodic is not None:
                self.periodic.wrap(st)

    def after_forces(self, ctx, part: str, stage: int) -> None:
        if part == "interior" and self.periodic is not None:
            self.periodic.image_forces(ctx)
        if self.shifting is not None:
            self.shifting.accumulate(ctx, part, stage)

    def before_integrate(self, ctx, stage: int) -> None:
        if self.shifting is not None:
            self.shifting.before_integrate(ctx, stage)

    def after_integrate(self, ctx, stage: int) -> None:
        if self.shifting is not None:
            self.shifting.after_integrate(ctx, stage)

    def exclude(self, sim, bads: list) -> list:
        """Remove particles outside the domain (non-periodic axes) or, fluid only, outside
        [rho_min, rho_max]; count them in ``state.extra["excluded_ids"]``. Each rank's rows
        are scanned on the host only when the backend's own end-of-step check finds a row out
        of bounds (a device backend keeps its rows on the device otherwise). Raises
        `NumericalError` once the run's exclusions pass ``domain.exclude_max_share`` of its
        fluid particles. `bads`: each context's result of the backend's check; returned with
        the ranks whose rows were removed checked again."""
        if not self.exclude_outside:
            return bads
        ph = self.scene.physics
        bads = list(bads)
        for k, c in enumerate(sim.contexts):
            st = c.state
            bad = bads[k]
            if bad is None or bad[1] not in (2, 3):   # NaN (1) is the solver's to report
                continue
            sim.compute.sync_host(st)    # the host rows current (a device backend), then removed
            p = st.particles
            x = np.asarray(p.pos)
            out = np.zeros(p.n, bool)
            for a in range(p.dim):
                if self.periodic is not None and a in self.periodic.axes:
                    continue
                out |= (x[:, a] < sim.lo[a]) | (x[:, a] > sim.hi[a])
            cause = np.where(out, 2, 0)
            bad_rho = (p.kind == 0) & ((p.rho < ph.rho_min) | (p.rho > ph.rho_max)) & ~out
            cause[bad_rho] = 3
            rows = np.nonzero(cause)[0]
            if len(rows) == 0:
                continue
            for r in rows:
                self.excluded.append((sim.step_count, sim.time, int(p.id[r]), int(cause[r])))
            st.extra["excluded_ids"] = np.concatenate([st.extra["excluded_ids"], p.id[rows]])
            st.particles = p.take(np.nonzero(cause == 0)[0])
            sim.compute.prepare(st)
            bads[k] = sim.compute.check(st, sim.lo, sim.hi)
        self._check_share(sim)
        return bads

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
        self.restored = [(int(a), float(b), int(c), int(e)) for a, b, c, e in
                         zip(cols["step"], cols["time"], cols["id"], cols["cause"])] if root else []

    def exclusions(self, sim) -> dict | None:
        """Every rank's exclusions gathered (root), sorted by (step, id); None elsewhere."""
        rows = self.excluded
        if self.restored is not None:
            rows = self.restored + [r for r in rows if r[0] > self.restored_step]
        if hasattr(sim.comm, "gather") and len(sim.comm.local_ranks) < sim.nranks:
            parts = sim.comm.gather(rows)
            if parts is None:
                return None
            rows = [r for p in parts for r in p]
        rows = sorted(rows, key=lambda r: (r[0], r[2]))
        return {"step": np.array([r[0] for r in rows], np.int64),
                "time": np.array([r[1] for r in rows], float),
                "id": np.array([r[2] for r in rows], np.int64),
                "cause": np.array([r[3] for r in rows], np.int8)}


def exclusion_summary(rows: dict, n_fluid: int) -> str:
    """One line for the end of a run: how many particles were excluded, their share of the
    fluid and the count by cause (`rows`: the /exclusions columns)."""
    from .errors import CAUSES
    n = len(rows["id"])
    causes, counts = np.unique(np.asarray(rows["cause"]), return_counts=True)
    by = ", ".join(f"{k} {CAUSES[int(c)]}" for c, k in zip(causes, counts))
    span = f", steps {int(rows['step'][0])}-{int(rows['step'][-1])}" if n else ""
    return (f"excluded {n} particles ({100.0 * n / max(n_fluid, 1):.3g} % of {n_fluid} fluid"
            + (f"; {by}" if n else "") + f"{span})")
