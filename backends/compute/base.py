"""Compute backends: where the kernels of a step run.

A compute backend implements the compute tasks of a step on a `RankState`.
It knows nothing of ranks or messages: the comm backend moves `Halo` objects
and particle rows; the scheduler decides the order. Every backend passes the
shared conformance suite in `tests/test_compute_conformance.py`.
"""
from __future__ import annotations

import numpy as np


class ComputeBackend:
    """Base class. Subclasses register with `@register("compute", NAME)`."""

    name = "base"
    default_precision = "float64"
    device_resident = False   # rows live on a device between steps (halos can go device to device)
    uses_lanes = False        # the scheduler wraps each task in lane_begin / lane_end (streams)
    # the optional scene features it runs (sphgraph.features refuses the others at start-up):
    # "shifting" (shift_part, shift_displacement, shift_apply), "mdbc" (mdbc), "riemann",
    # "diffusion_time" (physics options of the force and integration kernels), "motion"
    # (move_bodies: [[motion]] bodies)
    scene_features: frozenset = frozenset()

    @classmethod
    def unavailable(cls) -> str | None:
        """Why this backend cannot run on this machine (one line), or None when it can.

        Asked at start-up before an instance exists; cheap, and it must not initialise a
        device that is not there (the run is refused in one line, exit 2)."""
        return None

    def device_name(self) -> str:
        return "cpu"

    def counters(self) -> dict:
        """Cumulative counts of what a step costs the host beyond its kernels (a device
        backend: device and pinned allocations, host waits for the device); {} when the
        backend has none to report."""
        return {}

    # -- set-up and transfers ----------------------------------------------------------
    def prepare(self, state) -> None:
        """Allocate what the kernels need for `state` (called after any change of N)."""
        raise NotImplementedError

    def host_arrays(self, state) -> dict:
        """Output arrays of the owned particles (host numpy): id, kind, position, velocity, density, pressure."""
        raise NotImplementedError

    # -- tasks -------------------------------------------------------------------------
    def build_cells(self, state) -> None:
        raise NotImplementedError

    def merge_displaced(self, state, domain, rows) -> None:
        """Rows that arrived (recv_displaced) after this step's build_cells already sorted
        the owned rows. Default, for a backend without a merge: append them and build the
        cells again (correct, a whole build). numba-cpu merges them into the sorted rows."""
        if any(r is not None and r.n for r in rows):
            self.sync_host(state)
            domain.add_rows(state, rows)
            self.prepare(state)
            self.build_cells(state)

    def forces(self, state, part: str) -> None:
        raise NotImplementedError

    def prepare_halo(self, state, halo) -> None:
        raise NotImplementedError

    def reduce_forces(self, state, stage: int) -> None:
        raise NotImplementedError

    def dt_local(self, state) -> float:
        raise NotImplementedError

    def dt_local_begin(self, state) -> None:
        """Start the rank's dt proposal; `dt_local_end` returns it. A device backend launches
        its reduction and the copy of its terms here and waits for them only in
        `dt_local_end` (the dt_allreduce task), so that ranks sharing a host queue all their
        dt terms before the first wait. Here: computed at once."""
        state.dt_local = self.dt_local(state)

    def dt_local_end(self, state) -> float:
        """The proposal `dt_local_begin` started (waits for it on a device backend)."""
        return state.dt_local

    def integrate(self, state, stage: int, integrator: str, euler: bool) -> None:
        raise NotImplementedError

    def count_pairs(self, state) -> int:
        """Pairs within 2h over owned destinations (interior + halos), counted as
        DualSPHysics counts interactions (from each side; boundary rows count fluid
        neighbours only). Host-side, for benchmarks."""
        from sphgraph.cells import build_grid, reach_cells
        from . import cpu_kernels as K
        a = self.host_arrays(state)
        pos = np.ascontiguousarray(a["position"], dtype=np.float64)
        c = state.consts
        reach = reach_cells(c.h, c.cell_size)
        total = 0
        kind = np.ascontiguousarray(a["kind"], dtype=np.int8)
        sources = [(pos, kind)] + [(np.asarray(h.pos, np.float64), np.asarray(h.kind, np.int8))
                                   for h in state.halos.values() if h is not None and h.n]
        for src, skind in sources:
            grid, perm = build_grid(src, c.cell_size, reach, state.axes)
            counts = np.zeros(len(pos), np.int64)
            K.count_pairs(pos, kind, np.ascontiguousarray(src[perm]), np.ascontiguousarray(skind[perm]),
                          *grid.kernel_args(), 4.0 * c.h * c.h, counts)
            total += int(counts.sum())
        return total

    def state_bytes(self, state) -> int:
        """Memory held for `state` (host arrays on CPU, device arrays on GPU)."""
        n = state.particles.nbytes()
        for a in (state.press, state.ace, state.ar, state.visc):
            n += 0 if a is None else a.nbytes
        for b in state.parts.values():
            n += sum(x.nbytes for x in (b.ace, b.ar, b.ddt, b.cancel, b.visc))
        if state.cells is not None:
            n += state.cells.start.nbytes
        if state.sort_perm is not None:
            n += state.sort_perm.nbytes
        return n

    def particle_capacity(self, state, max_particles_per_rank=None, sharing=1) -> int | None:
        """Fluid particles (halos included) this rank may hold, for the `memory` balancing
        policy: on CPU the `max_particles_per_rank` option, None (unbounded) without it.
        A device backend measures it (free memory shared by `sharing` ranks of this
        process); the option, when given, caps that too."""
        return max_particles_per_rank

    # -- multi-rank rows: what leaves, what arrives, what the neighbours see ---------------
    def take_displaced(self, state, domain) -> dict:
        """Rows that left the slab, removed: {-1: lower, +1: upper} (`Slabs.take_displaced`)."""
        return domain.take_displaced(state)

    def add_displaced(self, state, domain, rows, built: bool) -> None:
        """Rows that came from the neighbours. `built`: this step's build_cells already
        sorted the owned rows (merge them in); otherwise the next build sorts them."""
        if built:
            self.merge_displaced(state, domain, rows)
            return
        domain.add_rows(state, rows)
        self.prepare(state)

    def edge(self, state, domain, direction: int, slot=None):
        """The rows the neighbour in `direction` needs as its halo (`Slabs.edge`); `slot` (the
        message tag) asks for a device message (`--halo-transport ipc`), which only a
        device-resident backend gives."""
        return domain.edge(state, direction)

    def sync_host(self, state) -> None:
        """Bring the host `state.particles` up to date (a device backend); the host rows are
        the truth here."""

    def fluid_count(self, state) -> int:
        """Fluid rows this rank owns."""
        return state.particles.n_fluid

    def axis_extent(self, state, axis: int) -> tuple[float, float]:
        """(min, max) of the rows' coordinate `axis` ((inf, -inf) without rows)."""
        x = state.particles.pos[:, axis]
        return (float(x.min()), float(x.max())) if len(x) else (np.inf, -np.inf)

    def fluid_histogram(self, state, axis: int, edges) -> np.ndarray:
        """Fluid rows per bin of coordinate `axis` (uniform `edges`, as np.histogram)."""
        p = state.particles
        return np.histogram(p.pos[p.kind == 0, axis], bins=edges)[0].astype(np.int64)

    def check(self, state, lo, hi) -> tuple[int, int] | None:
        """(row, cause) of a bad particle or None; the causes are `sphgraph.errors.CAUSES`' codes
        1 (NaN in position or density), 2 (left the domain), 3 (density bounds)."""
        raise NotImplementedError

    def check_begin(self, state, lo, hi) -> None:
        """Start `check` (the ``check`` task); `check_end` (the ``exclude`` task) returns its
        finding. A device backend launches the check and its copy here and waits only in
        `check_end`, as `dt_local_begin`. Here: checked at once."""
        state.pending_check = self.check(state, lo, hi)

    def check_end(self, state) -> tuple[int, int] | None:
        """The finding of the check `check_begin` started."""
        bad, state.pending_check = state.pending_check, None
        return bad


    # -- [probes] / [forces] samples (sphgraph.probes): each rank's partial sums ---------
    def probe_bounds(self, state, columns, boxes, band: float) -> dict:
        """The first part of a sample that needs one (height columns; bodies on several
        ranks), from this rank's own rows at the end of the step:

        * ``"zrange"`` (c, 2): the lowest and highest vertical coordinate of the owned fluid
          rows within 2h horizontally of each column ``columns`` (c, 2: x[, y]); (inf, -inf)
          where there are none;
        * ``"edge"`` (m, 5): x, y, z, rho and body index of the owned boundary rows inside
          body box k (``boxes`` (b, 2, 3): lo, hi, inclusive) whose coordinate along the
          split axis (``state.axis``) is within ``band`` of the ends of the owned rows' extent
          there (``band`` 0: none); sorted by body, then position (`cpu_probes.edge_rows`).

        The CPU implementation works on the host rows (`cpu_probes`); a device backend
        overrides it with its own kernels. Only these few numbers leave the rank."""
        from . import cpu_probes
        self.sync_host(state)
        return cpu_probes.host_bounds(state, columns, boxes, band)

    def probe_sums(self, state, points, boxes, extra) -> dict:
        """The partial sums of a sample over this rank's own fluid rows (end of the step),
        which add up over the ranks to the sample (sphgraph.physics.probes):

        * ``"points"`` (k, 5): at each point of ``points`` (k, 3) the sums of V W, V W P
          and V W v (x, y, z) over the owned fluid rows within 2h;
        * ``"forces"`` (b, 3): the pressure force of the owned fluid rows on the boundary rows
          inside each body box (the owned ones, and ``extra`` (m, 5): other ranks' edge rows
          from `probe_bounds`, counted for their body).

        Each pair (fluid row, body row) is summed once, on the rank that owns the fluid row."""
        from . import cpu_probes
        self.sync_host(state)
        return cpu_probes.host_sums(state, points, boxes, extra)

    # -- scene features (sphgraph.features), for a backend that lists them in scene_features --
    def move_bodies(self, state, motion, t: float, mid_step: bool) -> None:
        """The moving bodies' rows (kind 2) of this rank set to their positions and velocities
        at time `t` (`sphgraph.motion.Motion`); `mid_step`: between a step's force stages (the
        corrector's forces read them next). The host rows are the truth here."""
        motion.move(state, t)

    def periodic_rows(self, state, lo, hi, reach: float, axes):
        """The owned rows within `reach` of a face ([lo, hi) along each of `axes`), in row
        order, as a Halo (positions, velocities, densities, kinds): the sources of the
        periodic images (sphgraph.periodic), which come from these rows alone. Here: the
        host rows."""
        from sphgraph.state import Halo
        p = state.particles
        near = np.zeros(p.n, bool)
        for a in axes:
            x = p.pos[:, a]
            near |= (x < lo[a] + reach) | (x >= hi[a] - reach)
        r = np.nonzero(near)[0]
        return Halo(pos=p.pos[r], vel=p.vel[r], rho=p.rho[r], kind=p.kind[r])

    def periodic_images(self, state, periodic):
        """The images of the owned rows across the faces of `periodic` (sphgraph.periodic.
        Periodic) as the halo of force part halo_3, for `prepare_halo`. Here: the rows near a
        face (`periodic_rows`) imaged on the host (Periodic.images)."""
        src = self.periodic_rows(state, periodic.lo, periodic.hi, periodic.reach, periodic.image_axes)
        return periodic.images(src.pos, src.vel, src.rho, src.kind)

    def damp(self, state, damping, dt: float) -> None:
        """The fluid rows' velocities times their factor of the relaxation zones of `damping`
        (sphgraph.waves.Damping; sphgraph.physics.damping). Here: the host rows."""
        p = state.particles
        rows = np.nonzero(p.kind == 0)[0]
        f = damping.factor(p.pos[rows], dt)
        hit = f < 1.0
        if hit.any():
            r = rows[hit]
            p.vel[r] *= f[hit, None].astype(p.vel.dtype)

    def wrap_periodic(self, state, lo, hi, axes) -> None:
        """Positions along `axes` back into [lo, hi) (periodic axes,
        sphgraph.physics.wrap.wrap_axis). Here: the host rows."""
        from sphgraph.physics.wrap import wrap_rows
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        wrap_rows(state.particles.pos, lo, hi, hi - lo, np.asarray(axes, np.int64))

    def mdbc(self, state, boxes, det_min: float, noslip: bool, moving=None) -> None:
        """mDBC (sphgraph.physics.mdbc): each boundary row's density (and, `noslip`, velocity)
        from the fluid at its ghost node, mirrored across the scene's interface `boxes`: the
        owned fluid rows and the halos' ("mdbc" in scene_features; the halos only with
        "mdbc-ranks"), and the rows' pressures. `moving`: None, or (ids, ghosts) -- the ghost
        nodes [m, dim] of the moving bodies' particles (sorted ids) at the time their rows
        hold (`Mdbc.moving_ghosts`); those rows take their ghost from it and keep their
        velocity, the body's."""
        raise NotImplementedError

    def mdbc_edge(self, state, domain, direction: int):
        """mDBC on several ranks ("mdbc-ranks"): [density, velocity...] of the boundary rows of
        the edge towards `direction` (`Slabs.edge_rows`, in the edge's order), after mdbc."""
        raise NotImplementedError

    def mdbc_halo(self, state, halo, values) -> None:
        """The neighbour's `mdbc_edge` values put on the boundary rows of `halo` (which hold
        the values from before its mdbc), their pressures with them."""
        raise NotImplementedError

    def shift_part(self, state, part: str, mode: int) -> None:
        """Particle shifting's partial sums of source set `part` ("interior", "halo_1",
        "halo_2", "halo_3": the periodic images), kept until `shift_displacement`."""
        raise NotImplementedError

    def shift_displacement(self, state, coefumagn, tfs, coeftfs, maxdist) -> None:
        """The parts summed in the order of `SHIFT_PARTS` and turned into each fluid row's
        displacement (sphgraph.physics.shifting), from the rows' current velocities."""
        raise NotImplementedError

    def shift_apply(self, state) -> None:
        """The displacements added to the positions."""
        raise NotImplementedError

    def lane_begin(self, state, task, step) -> None:
        """Before a task body, when `uses_lanes` (see sphgraph.scheduler.LaneStep)."""

    def lane_end(self, state, task, step) -> None:
        """After a task body, when `uses_lanes`."""

    # -- the device's own task clock (mock MPI's timing = "device") ---------------------
    has_device_clock = False  # True: start_task_clock / task_device_seconds measure device time

    def start_task_clock(self) -> None:
        """From now on, measure each task's device time (a backend with `has_device_clock`),
        each task alone on the device: ranks that share a device must not stretch each
        other's times, which are to stand for a device each."""

    def stop_task_clock(self) -> None:
        """Stop measuring task times (tasks overlap on the device again)."""

    def task_device_seconds(self, state, task) -> float | None:
        """Device seconds of `task`'s work on this rank, the run just finished (None: no
        device clock, or the clock is off)."""
        return None


# particle shifting (sphgraph.shifting): partial sums per source set, added in this order
SHIFT_PARTS = ("interior", "halo_1", "halo_2", "halo_3")

def dt_from_terms(a2max: float, v2max: float, viscmax: float, h: float, c0: float, cfl: float) -> float:
    """Variable dt (DualSPHysics JSphCpu::DtVariable, v5):

    dt1 = sqrt(h / max|a|),  dt2 = h / (max(c0, 10 max|v|) + h max ViscDt),
    dt = CFL min(dt1, dt2).
    """
    amax = float(np.sqrt(a2max))
    dt1 = np.sqrt(h / amax) if amax > 0 else np.inf
    dt2 = h / (max(c0, 10.0 * float(np.sqrt(v2max))) + h * viscmax)
    return float(cfl * min(dt1, dt2))


def device_capacity(free_bytes: float, bytes_per_particle: float, held_rows: int = 0,
                    fixed_rows: int = 0, margin: float = 0.8) -> int | None:
    """Fluid particles a device can hold for one rank.

    Rows it holds now (`held_rows`, at `bytes_per_particle` each, measured from the rank's
    allocations) plus what `margin` of the `free_bytes` holds at that size, less the rows
    that are not the balanced quantity (`fixed_rows`: boundary). The margin leaves room
    for what grows with N besides the rows (cells, scan buffers, halos). None when no
    size was measured (nothing allocated yet)."""
    if not bytes_per_particle > 0:
        return None
    rows = held_rows + int(margin * max(free_bytes, 0) // bytes_per_particle)
    return max(rows - fixed_rows, 0)
