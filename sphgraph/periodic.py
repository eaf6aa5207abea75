"""Periodic boundaries along any axis (``[domain] periodic = ["x", ...]``).

The domain's two faces on a periodic axis are joined: a particle leaving through
``max`` re-enters at ``min`` and particles within reach (2.2h, as slab edges) of one
face interact with those near the other. Done as DualSPHysics does it, by images:

* **images** -- copies of the rows within reach of a periodic face, shifted by the
  period P = max - min towards the other face (corners too: an image of an image
  along a second axis). They form one more source set, part ``halo_3`` (summed
  after interior, halo 1 and halo 2 in the fixed order), made and computed by the
  ``forces_images@s`` task (datum ``images``) from the rank's own rows;
* **wrapping** -- the ``wrap`` task at the end of the step, x <- min + (x - min) mod P;
* **ring** -- when the slab (split) axis is periodic, rank 0 and the last rank are
  neighbours: their halos and migrating rows cross the seam shifted by P; the
  task graph gets the extra messages (``Schedule.program(..., ring=True)``).
  Images along the *other* periodic axes travel inside the edges, so corner pairs
  across a cut are found too.

Particles must lie in [min, max) on a periodic axis (a lattice of spacing dp fills it
without a duplicate at max when (max - min)/dp is an integer).
"""
from __future__ import annotations

import numpy as np

from .domain import REACH_H, Slabs
from .errors import InputError
from .state import Halo

IMAGE_SIDE = 3   # state.halos key / force part "halo_3" of the periodic images


class Periodic:
    def __init__(self, axes, lo, hi, reach, split_axis=None, nranks=1):
        self.axes = list(axes)
        self.lo = np.array(lo, float)      # copies: never alias the scene's domain arrays
        self.hi = np.array(hi, float)
        self.period = self.hi - self.lo
        self.reach = float(reach)
        self.ring = nranks > 1 and split_axis in self.axes
        self.split_axis = split_axis
        # axes handled by local images and wrapping (the ring handles the split axis)
        self.image_axes = [a for a in self.axes if not (self.ring and a == split_axis)]

    @classmethod
    def from_scene(cls, scene, sim) -> "Periodic":
        axes = ["xyz".index(a) for a in scene.periodic]
        return cls(axes, scene.domain_min, scene.domain_max, REACH_H * sim.consts.h, sim.axis, sim.nranks)

    def attach(self, sim) -> None:
        for a in self.axes:
            if self.period[a] < 2 * self.reach:
                raise InputError(f"{sim.scene.source}: domain.periodic: expected a period >= 4.4h "
                                 f"= {2 * self.reach:.4g} m along {'xyz'[a]}, got {self.period[a]:.4g} m")
        for c in sim.contexts:
            # a backend that writes a lone interior part reduced must not: images come after it
            c.state.extra["images"] = bool(self.image_axes)
            x = c.state.particles.pos
            for a in self.axes:
                if np.any(x[:, a] < self.lo[a]) or np.any(x[:, a] >= self.hi[a] - 1e-9 * sim.scene.dp):
                    raise InputError(f"{sim.scene.source}: domain.periodic: expected every particle in "
                                     f"[min, max) along {'xyz'[a]} = [{self.lo[a]}, {self.hi[a]}) (the "
                                     "point at max is the image of the one at min)")
            if c.domain is not None:
                c.domain = PeriodicSlabs(c.domain, self, sim.nranks)
        # a particle may step out by a little before it is wrapped or migrated
        sim.lo, sim.hi = np.array(sim.lo, float), np.array(sim.hi, float)
        for a in self.axes:
            sim.lo[a] = self.lo[a] - self.reach
            sim.hi[a] = self.hi[a] + self.reach

    # ------------------------------------------------------------------ images
    def image_rows(self, pos):
        """(row index, shift vector) of every image of rows ``pos`` along the image axes."""
        dim = pos.shape[1]
        rows = np.arange(len(pos))
        shift = np.zeros((len(pos), dim))
        idx_all, sh_all = [], []
        cur_rows, cur_shift = rows, shift
        for a in self.image_axes:
            x = pos[cur_rows, a] + cur_shift[:, a]
            new_r, new_s = [], []
            for sel, sgn in ((x < self.lo[a] + self.reach, 1.0), (x >= self.hi[a] - self.reach, -1.0)):
                s = cur_shift[sel].copy()
                s[:, a] += sgn * self.period[a]
                new_r.append(cur_rows[sel])
                new_s.append(s)
            nr, ns = np.concatenate(new_r), np.concatenate(new_s)
            idx_all.append(nr)
            sh_all.append(ns)
            cur_rows = np.concatenate([cur_rows, nr])
            cur_shift = np.concatenate([cur_shift, ns])
        if not idx_all:
            return np.empty(0, np.int64), np.zeros((0, dim))
        return np.concatenate(idx_all), np.concatenate(sh_all)

    def images(self, pos, vel, rho, kind) -> Halo:
        r, s = self.image_rows(np.asarray(pos))
        return Halo(pos=np.ascontiguousarray(pos[r] + s.astype(pos.dtype)), vel=vel[r], rho=rho[r],
                    kind=kind[r])

    def source_images(self, ctx) -> Halo:
        """The images of the rank's rows now (`ComputeBackend.periodic_images`: made from
        the rows near a periodic face alone; on a device, without leaving it)."""
        return ctx.compute.periodic_images(ctx.state, self)

    def image_forces(self, ctx) -> None:
        """The ``forces_images`` task, force part ``halo_3``: the rank's rows against the
        images of its own rows (placed only when there are image axes)."""
        st = ctx.state
        halo = self.source_images(ctx)
        ctx.compute.prepare_halo(st, halo)
        st.halos[IMAGE_SIDE] = halo
        ctx.compute.forces(st, f"halo_{IMAGE_SIDE}")

    def wrap(self, ctx) -> None:
        """The ``wrap`` task: positions on the image axes back into [min, max), on the
        backend's rows (sphgraph.physics.wrap.wrap_axis)."""
        if self.image_axes:
            ctx.compute.wrap_periodic(ctx.state, self.lo, self.hi, self.image_axes)


class PeriodicSlabs(Slabs):
    """Slabs whose edges carry periodic images, and, in a ring, whose end ranks
    exchange halos and migrating rows across the seam (shifted by the period)."""

    def __init__(self, base: Slabs, periodic: Periodic, nranks: int):
        super().__init__(base.rank, base.axis, base.cuts, base.reach)
        self.per = periodic
        self.nranks = nranks

    @property
    def lo(self):
        if self.per.ring and self.rank == 0:
            return self.per.lo[self.axis]
        return self.cuts[self.rank]

    @property
    def hi(self):
        if self.per.ring and self.rank == self.nranks - 1:
            return self.per.hi[self.axis]
        return self.cuts[self.rank + 1]

    def _seam(self, direction: int) -> float:
        """Shift along the split axis of what crosses the seam towards `direction` (0 if none)."""
        if not self.per.ring:
            return 0.0
        P = self.per.period[self.axis]
        if direction < 0 and self.rank == 0:
            return P
        if direction > 0 and self.rank == self.nranks - 1:
            return -P
        return 0.0

    def take_displaced(self, state) -> dict:
        out = super().take_displaced(state)
        for d, rows in out.items():
            s = self._seam(d)
            if s and rows.n:
                rows.pos[:, self.axis] += s
        return out

    def edge_sources(self, state, direction: int) -> np.ndarray:
        """The edge's rows, then the rows its images (along the other periodic axes) copy,
        in `edge`'s order."""
        sel = self.edge_rows(state, direction)
        if self.per.image_axes and len(sel):
            r, _ = self.per.image_rows(np.asarray(state.particles.pos[sel]))
            sel = np.concatenate([sel, sel[r]])
        return sel

    def edge(self, state, direction: int) -> Halo:
        h = super().edge(state, direction)
        if self.per.image_axes and h.n:   # images of the edge rows along the other periodic axes
            im = self.per.images(h.pos, h.vel, h.rho, h.kind)
            h = Halo(pos=np.concatenate([h.pos, im.pos]), vel=np.concatenate([h.vel, im.vel]),
                     rho=np.concatenate([h.rho, im.rho]), kind=np.concatenate([h.kind, im.kind]))
            state.bytes_sent += im.nbytes()
        s = self._seam(direction)
        if s:
            h.pos = h.pos.copy()
            h.pos[:, self.axis] += s
        return h
