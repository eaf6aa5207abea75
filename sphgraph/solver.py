"""`sphgraph.run`: set up a scene on backends, step it through the scheduler, write output.

Everything is validated (scene, backends, schedule, decomposition) before the
output directory is touched, so bad input writes nothing.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .balance import BalanceConfig, Balancer
from .cells import axis_order
from .domain import MIN_SLAB_H, REACH_H, Slabs, choose_axis, equal_cuts, split
from .errors import CAUSES, CommError, DiskFullError, InputError, NumericalError, SphgraphError
from .features import exclusion_rows
from .particles import in_id_order
from .registry import get
from .scene import Scene
from .schedule import Schedule
from .scheduler import RankContext, Scheduler
from .state import RankState

PRECISIONS = {"float32": np.float32, "float64": np.float64}


@dataclass
class RunResult:
    out_dir: Path | None
    steps: int
    time: float
    wall_s: float
    compile_s: float
    particles: int
    fluid_particles: int
    dim: int
    backend: str
    comm: str
    ranks: int
    precision: str
    integrator: str
    schedule: str
    device: str
    frames: int = 0
    task_seconds: dict = field(default_factory=dict)
    timing: object = None
    start_step: int = 0              # > 0 after a restart (steps counts from the run's start)
    stopped: str | None = None       # "SIGTERM" | "walltime": stopped early after a checkpoint
    checkpoint: str | None = None    # the newest checkpoint written

    @property
    def steps_per_s(self) -> float:
        timed = self.steps - self.start_step - 1
        return timed / max(self.wall_s - self.compile_s, 1e-12) if timed > 0 else 0.0


class Simulation:
    """A scene set up on backends: `step()` advances one step through the scheduler."""

    def __init__(self, scene, *, backend="numba-cpu", comm="single", ranks=1, schedule="production",
                 precision=None, dp=None, end_time=None, user_tasks=(), fixed_dt=None,
                 comm_options=None, decomposition_axis=None, balance=None, particles=None, cuts=None,
                 invariants=True, sample=False):
        """`particles` (optional): start from these particles instead of `scene.build_particles`:
        a `Particles` set (decomposed here), or one block per rank with their slab `cuts`
        (kept when the rank count matches, re-decomposed otherwise) -- a restart. `sample`:
        sample the scene's `[probes]` / `[forces]` (the `probes` task; `probe_sampler`)."""
        if not isinstance(scene, Scene):
            scene = Scene.from_toml(scene)
        if dp is not None or end_time is not None:
            scene = scene.with_overrides(dp=dp, end_time=end_time)
        self.scene = scene
        compute_cls = get("compute", backend, "--backend")
        comm_cls = get("comm", comm, "--comm")
        precision = precision or compute_cls.default_precision
        if precision not in PRECISIONS:
            raise InputError(f"--precision: expected one of {', '.join(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        self.dtype = PRECISIONS[precision]
        if not isinstance(ranks, int) or ranks < 1:
            raise InputError(f"--ranks: expected an integer >= 1, got {ranks!r}")
        self.schedule = Schedule.load(schedule)
        self.user_tasks = tuple(user_tasks)
        phys = scene.physics
        self.integrator = phys.integrator
        self.stages = 1 if phys.integrator == "verlet" else 2
        self.comm = comm_cls(ranks=ranks, **(comm_options or {}))
        self.nranks = self.comm.size
        self.halo_transport = self.comm.halo_transport
        if self.halo_transport == "auto":   # device to device where the ranks share this process
            self.halo_transport = "ipc" if compute_cls.device_resident and self.comm.one_process else "staged"
        if self.halo_transport == "ipc" and not compute_cls.device_resident:
            raise InputError(f"--halo-transport ipc: needs --backend numba-cuda (halos device to device), "
                             f"got --backend {backend}")
        self.balance_cfg = BalanceConfig.resolve(self.schedule.rebalance, scene.extra.get("balance"),
                                                 balance, source=scene.source,
                                                 schedule_source=self.schedule.source)
        self.rebalance = (self.nranks > 1 and self.balance_cfg.enabled
                          and "rebalance" in self.schedule.order)
        from .features import Features
        # mDBC, periodic images, shifting, moving bodies...: only what the scene asks, as tasks
        self.features = Features(scene, sample=sample)
        self.features.check_backend(compute_cls, self.nranks, self.comm.one_process, self.halo_transport)
        self.features.check_schedule(self.schedule, self.nranks)
        self.probe_sampler = self.features.probes   # its samples go into checkpoints and come back
        self.schedule.validate(self.nranks, self.stages, self.user_tasks, rebalance=self.rebalance,
                               features=self.features.kinds)
        self.compute = compute_cls()
        # set-up seconds by phase: scene (the particle count, constants), particles (the
        # rows on the host), state (rank states and the backend's prepare: the upload on a
        # device), rest (scheduler, features, the invariants' start values)
        self.setup_seconds = {}
        t0 = time.perf_counter()
        if particles is None:   # before anything of the scene's size is allocated (scene.constants is)
            from .invariants import check_memory
            check_memory(scene, self.dtype, device_rows=compute_cls.device_resident)
        consts = scene.constants
        self.consts = consts
        blocks = None
        t0 = self._phase("scene", t0)
        if particles is None:
            particles = scene.build_particles(self.dtype)
        elif isinstance(particles, (list, tuple)):
            from .particles import Particles
            keep = len(particles) == self.nranks and (cuts is not None or self.nranks == 1)
            blocks = list(particles) if keep else None
            particles = Particles.concat(particles)
            if blocks is None:   # another rank count: re-decompose from the rows in id order
                particles = particles.take(np.argsort(particles.id, kind="stable"))
        self.n_total = particles.n
        self.n_fluid = particles.n_fluid
        t0 = self._phase("particles", t0)
        self.dim = particles.dim
        self.ids = None
        if self.nranks > 1:
            axis = choose_axis(decomposition_axis or scene.decomposition_axis, particles, consts.gravity)
            if axis >= self.dim:
                raise InputError(f"{scene.source}: decomposition.axis: expected an axis of a "
                                 f"{self.dim}D scene, got {'xyz'[axis]!r}")
            if blocks is not None:
                cuts, slabs = np.asarray(cuts, float), blocks
            else:
                cuts = equal_cuts(particles, axis, self.nranks, consts.h)
                slabs = split(particles, axis, cuts)
            self.axis = axis
        else:
            axis, cuts, slabs = None, None, [blocks[0] if blocks else particles]
            self.axis = None
        self.contexts = []
        reach = REACH_H * consts.h
        from .features import MDBC_KINDS, Mdbc
        if axis is not None and MDBC_KINDS[0] in self.features.kinds:   # the ghosts near a cut: see Mdbc
            ghost = Mdbc.ghost_reach(scene, particles, axis)
            most = (MIN_SLAB_H - REACH_H) * consts.h     # a halo must come from the next slab alone
            if ghost > most:
                raise InputError(f"{scene.source}: boundary: mDBC's ghost nodes lie {ghost:.4g} m from their rows "
                                 f"along axis {'xyz'[axis]}: expected at most {most:.4g} m "
                                 f"({MIN_SLAB_H - REACH_H:g}h) on several ranks (fewer boundary layers)")
            reach += ghost
        ref = particles.pos.min(axis=0) if self.nranks > 1 and particles.n else None
        for r in self.comm.local_ranks:
            st = RankState(particles=slabs[r], consts=consts, dtype=self.dtype, rank=r, nranks=self.nranks,
                           axes=axis_order(self.dim, axis), cfl=phys.cfl,
                           rho_min=phys.rho_min, rho_max=phys.rho_max, ref=ref)
            if axis is not None:
                st.axis, st.cut_lo, st.cut_hi = axis, cuts[r], cuts[r + 1]
            self.compute.prepare(st)
            dom = Slabs(r, axis, cuts, reach=reach) if axis is not None else None
            bal = Balancer(self.balance_cfg, axis, consts.h, scene.dp) if self.rebalance else None
            self.contexts.append(RankContext(rank=r, state=st, compute=self.compute,
                                             comm=self.comm.endpoint(r), domain=dom,
                                             integrator=self.integrator, fixed_dt=fixed_dt, scene=scene,
                                             balancer=bal, halo_transport=self.halo_transport))
        if self.rebalance and self.balance_cfg.policy == "memory":
            self._attach_capacity(scene)
        t0 = self._phase("state", t0)
        # the end-of-step check's bounds, as loose as the scene's extent check (geometry.TOL dp):
        # a wall layer drawn on the domain's face (3.22 + 3 x 0.04 = 3.32 = domain.max in
        # examples/spheric2.toml at dp 0.04) lies 4e-16 beyond it after rounding, and was
        # excluded at the first step
        from .geometry import TOL
        self.lo = np.asarray(scene.domain_min, float) - TOL * scene.dp
        self.hi = np.asarray(scene.domain_max, float) + TOL * scene.dp
        self.step_count = 0
        self.time = 0.0
        self.features.attach(self, particles)   # its task kinds for the split axis now known
        ring = self.features.ring(self.axis, self.nranks)
        if ring:   # the end ranks are neighbours: more messages to prove
            self.schedule.validate(self.nranks, self.stages, self.user_tasks, rebalance=self.rebalance,
                                   features=self.features.kinds, ring=True)
        self.scheduler = Scheduler(self.schedule, self.comm, self.contexts, self.stages, self.user_tasks,
                                   rebalance=self.rebalance, features=self.features.kinds, ring=ring)
        from .invariants import Invariants
        self.invariants = Invariants(self) if invariants else None
        self._phase("rest", t0)

    def _phase(self, name, t0) -> float:
        """Adds the seconds since t0 to set-up phase `name`; returns now."""
        t = time.perf_counter()
        self.setup_seconds[name] = self.setup_seconds.get(name, 0.0) + t - t0
        return t

    def _attach_capacity(self, scene) -> None:
        """memory policy: each rank's capacity from its compute backend (the option on CPU,
        free device memory on GPU), asked again at every check; refuse a scene whose fluid
        cannot fit at all before anything runs."""
        cfg = self.balance_cfg
        sharing = len(self.contexts)   # ranks of this process share its compute backend (one device)

        def capacity(state):
            return self.compute.particle_capacity(state, cfg.max_particles_per_rank, sharing)
        caps = []
        for c in self.contexts:
            c.balancer.capacity = capacity
            cap = capacity(c.state)
            caps.append(math.inf if cap is None else cap)
        total = self.comm.allreduce(sum(caps), "sum")
        if total < self.n_fluid:
            raise InputError(f"{scene.source}: balance.max_particles_per_rank: the scene's {self.n_fluid} fluid "
                             f"particles cannot fit in {self.nranks} ranks that hold {int(total)} in all "
                             f"(max_particles_per_rank; on GPU also the free device memory): expected a "
                             f"capacity >= {-(-self.n_fluid // self.nranks)} per rank or more ranks")

    # ------------------------------------------------------------------ stepping
    def step(self) -> None:
        n = self.step_count
        euler = self.integrator == "verlet" and (n + 1) % self.scene.physics.verlet_euler_every == 0
        for c in self.contexts:
            c.euler = euler
            c.state.step = n
        bal = self.contexts[0].balancer
        self.scheduler.step(rebalance=bal is not None and bal.due(n))
        if bal is not None and bal.move_step == n:
            self._note_balance_move(n)
        dt = self.contexts[0].state.dt
        self.time += dt
        self.step_count = n + 1
        for c in self.contexts:
            c.state.time = self.time
        self.check()

    def _note_balance_move(self, n) -> None:
        """Rows that newly applied cuts displaced move in this step's send_displaced /
        recv_displaced tasks (with the few that the flow moved across a cut): those tasks'
        seconds on rank 0 (the /timing clock: virtual under mock MPI) go to `move_s`."""
        b = next((c.balancer for c in self.contexts if c.rank == 0), None)
        t = self.scheduler.times
        if b is None or not self.scheduler.record_times:
            return
        i = len(t.step) - 1
        while i >= 0 and t.step[i] == n:
            if t.rank[i] == 0 and t.task[i].split("@")[0] in ("send_displaced", "recv_displaced"):
                b.move_s += t.end[i] - t.start[i]
            i -= 1

    def check(self) -> None:
        """Stop on NaN, a particle outside the domain or a density out of bounds."""
        # one backend check a rank (a device backend's one wait): with [domain] exclude_outside
        # the step's `exclude` task ran it (and removed the rows out of bounds), else here
        bads = [c.state.check if c.state.check_step == c.state.step
                else self.compute.check(c.state, self.lo, self.hi) for c in self.contexts]
        self.features.collect_exclusions(self)
        found = None
        for c, bad in zip(self.contexts, bads):
            if bad is None and self.invariants is not None:
                bad = self.invariants.local_problem(c.state)
            if bad is not None and found is None:
                row, cause = bad
                found = (c.rank, int(c.state.particles.id[row]), cause)
        found = self.comm.first_problem(found)
        if found is not None:
            rank, pid, cause = found
            where = f" on rank {rank}" if self.nranks > 1 else ""
            raise NumericalError(f"step {self.step_count} (t = {self.time:.6g} s): {CAUSES[cause]}: "
                                 f"particle id {pid}{where}", step=self.step_count, particle_id=pid,
                                 cause=CAUSES[cause])
        if self.invariants is not None:
            self.invariants.check_step(self)

    def frame_arrays(self) -> dict | None:
        """All ranks' particles in id order (on the root; None elsewhere)."""
        per = {c.rank: self.compute.host_arrays(c.state) for c in self.contexts}
        rows = self.comm.gather_rows(per)
        return None if rows is None else in_id_order(rows)

    def root_attrs(self, backend: str, comm: str) -> dict:
        return {"scene": self.scene.text, "version": __version__, "backend": backend, "comm": comm,
                "ranks": self.nranks, "schedule": self.schedule.name, "precision": self.precision,
                "dim": self.dim, "dp": self.scene.dp, "h": self.consts.h,
                "integrator": self.integrator}


def run(scene, *, backend="numba-cpu", comm="single", ranks=1, schedule="production", out=None,
        overwrite=False, precision=None, end_time=None, max_steps=None, dp=None, progress=True,
        user_tasks=(), fixed_dt=None, comm_options=None, write_output=True, balance=None,
        checkpoint_every=None, restart=None, walltime=None, invariants=True) -> RunResult:
    """Run a scene to its end time (or `max_steps`) and write DIR/output.h5.

    Parameters mirror `sphgraph run` (DESIGN.md §5). Returns a `RunResult`.
    Long runs (docs/long-runs.md): `checkpoint_every` (steps, or "0.05s" simulated
    seconds) writes DIR/checkpoints/ckpt_<step>.h5; `restart=DIR` continues the run in
    DIR from its newest valid checkpoint; SIGTERM or `walltime` seconds write a
    checkpoint and return early (`RunResult.stopped`); `invariants` checks particle
    count, ids and NaN every step.

    In order: the start-up checks (`_start`), the simulation (restored from the
    checkpoint on a restart), the output folder (`_open_output`), then the time loop
    with its frames, samples and checkpoints (`_Run`).
    """
    from . import checkpoint as ck
    scene, out, write_output, precision, saved, every, walltime = _start(
        scene, backend, comm, ranks, out, precision, end_time, max_steps, dp, comm_options, write_output,
        checkpoint_every, restart, walltime)
    sim = Simulation(scene, backend=backend, comm=comm, ranks=ranks, schedule=schedule,
                     precision=precision, user_tasks=user_tasks,
                     fixed_dt=fixed_dt, comm_options=comm_options, balance=balance,
                     particles=None if saved is None else ck.blocks_for(saved, PRECISIONS[precision]),
                     cuts=None if saved is None else saved.cuts,
                     decomposition_axis=None if saved is None or saved.meta["axis"] < 0
                     else "xyz"[saved.meta["axis"]], invariants=invariants, sample=write_output)
    sc = sim.scene
    sampler = sim.probe_sampler   # [probes]/[forces] -> /probes, /forces (the probes task samples each step)
    if saved is not None:
        ck.check_scene(saved, sc)
        ck.restore(sim, saved)
    if not write_output and (every is not None or walltime is not None):
        raise InputError("--checkpoint-every/--walltime: expected an output directory (write_output=True)")
    writer, out_dir = _open_output(sim, out, saved, overwrite) if write_output else (None, None)
    r = _Run(sim, writer, out_dir, saved, sampler, ck.Keeper(sim, out_dir, every, walltime),
             progress, max_steps)
    if saved is not None and every is not None and every[0] == "time" \
            and math.isfinite(saved.meta.get("next_checkpoint", math.inf)):
        r.keeper.next_time = float(saved.meta["next_checkpoint"])
    r.run()
    return RunResult(out_dir=out_dir, steps=sim.step_count, time=sim.time, wall_s=r.wall,
                     compile_s=r.compile_s, particles=sim.n_total, fluid_particles=sim.n_fluid, dim=sim.dim,
                     backend=sim.compute.name, comm=sim.comm.name, ranks=sim.nranks,
                     precision=sim.precision, integrator=sim.integrator, schedule=sim.schedule.name,
                     device=sim.compute.device_name(), frames=r.frames,
                     task_seconds=sim.scheduler.times.seconds_by_kind(first_step=r.start_step + 1),
                     timing=sim.scheduler.times, start_step=r.start_step, stopped=r.stopped,
                     checkpoint=r.keeper.last_path)


def _start(scene, backend, comm, ranks, out, precision, end_time, max_steps, dp, comm_options, write_output,
           checkpoint_every, restart, walltime):
    """The start-up checks, cheapest first and each before anything of its size exists;
    on a restart the run folder, its newest checkpoint and its precision. Returns (scene
    with the overrides, out, write_output, precision, checkpoint or None, every,
    walltime)."""
    from . import checkpoint as ck
    from .files import check_out_dir
    from .preflight import check_backend, check_comm, check_ranks_fit
    from .ranges import check_flag

    every = ck.parse_every(checkpoint_every)
    walltime = ck.parse_walltime(walltime)
    if max_steps is not None:
        check_flag("--max-steps", max_steps, integer=True)
    check_comm(comm if isinstance(comm, str) else comm.name, ranks, comm_options)
    check_backend(backend)
    if not isinstance(scene, Scene):
        scene = Scene.from_toml(scene)
    if dp is not None or end_time is not None:
        scene = scene.with_overrides(dp=dp, end_time=end_time)
    check_ranks_fit(scene, ranks)
    if write_output and restart is None:
        check_out_dir(out if out is not None else Path("out") / scene.name)
    saved = None
    if restart is not None:
        run_dir = ck.run_dir_of(restart)
        if out is not None and Path(out).resolve() != Path(run_dir).resolve():
            raise InputError(f"--out: expected the --restart directory {run_dir} or nothing, got {out}")
        out, write_output = run_dir, True
        saved = ck.find_latest(restart)
        if precision is not None and precision != saved.meta["precision"]:
            raise InputError(f"--precision: expected the checkpoint's {saved.meta['precision']} "
                             f"on restart, got {precision}")
        precision = saved.meta["precision"]
    return scene, out, write_output, precision, saved, every, walltime


def _open_output(sim, out, saved, overwrite):
    """(writer on the root, None elsewhere; the output folder). A restart reopens the
    folder's output.h5 and drops what came after the checkpoint; a new run prepares the
    folder and removes an earlier run's checkpoints."""
    from . import checkpoint as ck
    from .io import OutputWriter, prepare_out_dir
    out_dir = Path(out) if out is not None else Path("out") / sim.scene.name
    writer = None
    if sim.comm.is_root and saved is not None:
        writer = OutputWriter.open_existing(out_dir)
        _keep_exclusions(out_dir, sim, saved.step)
        # frames after the checkpoint go; so does an end-of-run frame at its step (not in its count)
        stray = [i for i, _, s in writer.frames if s == saved.step and i >= int(saved.meta["frames"])]
        writer.truncate(after_step=saved.step - 1 if stray else saved.step)
        ck.prune(out_dir, keep=ck.KEEP, after_step=saved.step)
    elif sim.comm.is_root:
        prepare_out_dir(out_dir, overwrite=overwrite)
        ck.prune(out_dir, keep=0)   # a new run: an earlier run's checkpoints must not be restarted
        writer = OutputWriter(out_dir, sim.root_attrs(sim.compute.name, sim.comm.name), sim.dim, sim.precision)
    return writer, out_dir


class _Run:
    """The time loop of `run`: steps to the end time (or `max_steps`), a frame every
    output interval, probe samples, checkpoints when due and at the end, the stop on
    SIGTERM/walltime; then /timing, /exclusions, /probes and /forces on every rank."""

    def __init__(self, sim, writer, out_dir, saved, sampler, keeper, progress, max_steps):
        from .progress import Progress
        self.sim, self.writer, self.out_dir, self.saved = sim, writer, out_dir, saved
        self.sampler, self.keeper, self.max_steps = sampler, keeper, max_steps
        self.write_output = out_dir is not None
        self.prog = Progress(sim.scene.end_time, enabled=bool(progress) and sim.comm.is_root)
        self.frames = 0 if saved is None else int(saved.meta["frames"])
        self.last_saved = -1 if saved is None else int(saved.meta["last_saved"])  # step of the last frame
        self.next_out = sim.scene.output_interval if saved is None else float(saved.meta["next_out"])
        self.start_step = sim.step_count
        self.stopped = None
        self.wall = self.compile_s = 0.0

    def save_frame(self) -> None:
        sim = self.sim
        arrays = sim.frame_arrays()
        if sim.invariants is not None:
            sim.invariants.check_frame(sim, arrays)
        if self.writer is not None:
            self.writer.write_frame(self.frames, sim.time, sim.step_count, arrays)
        self.frames += 1
        self.last_saved = sim.step_count

    def save_checkpoint(self) -> None:
        self.keeper.save(self.next_out, self.frames, self.last_saved)

    def run(self) -> None:
        sim, keeper = self.sim, self.keeper
        keeper.install()
        try:
            try:
                self.loop()
            except NumericalError:
                keeper.uninstall()
                self.prog.close()
                _finish_output(self.writer, sim, self.sampler)   # on every rank: gathers the ranks' timings under MPI
                raise
            keeper.uninstall()
            self.prog.close()
            _finish_output(self.writer, sim, self.sampler)
        except Exception as e:
            keeper.uninstall()
            if (not isinstance(e, SphgraphError) or isinstance(e, (CommError, DiskFullError))) \
                    and len(sim.comm.local_ranks) < sim.nranks:   # MPI: one rank failed; stop them all, no hang
                _abort_all(sim, e)
            raise

    def loop(self) -> None:
        sim, keeper, prog, sampler = self.sim, self.keeper, self.prog, self.sampler
        t_end, interval = sim.scene.end_time, sim.scene.output_interval
        if self.write_output and self.saved is None:
            self.save_frame()
        if sampler is not None:   # the initial state; each step's own task samples its end
            sampler.sample(sim)
        t0 = time.perf_counter()
        while sim.time < t_end - 1e-12 and (self.max_steps is None or sim.step_count < self.max_steps):
            sim.step()
            if sim.step_count == self.start_step + 1:
                self.compile_s = time.perf_counter() - t0
                prog.note(f"first step {self.compile_s:.2f} s (includes numba compilation)")
                prog.reset_clock(1)
            if self.write_output and sim.time >= self.next_out - 1e-12:
                self.save_frame()
                while self.next_out <= sim.time + 1e-12:
                    self.next_out += interval
            if keeper.due():
                self.save_checkpoint()
            prog.update(sim.time, sim.step_count)
            if self.write_output:
                self.stopped = keeper.stop_reason()
                if self.stopped is not None:
                    if keeper.last_step != sim.step_count:
                        self.save_checkpoint()
                    break
        self.wall = time.perf_counter() - t0
        if self.stopped is None and self.write_output and keeper.last_step != sim.step_count:
            # every finished run can be extended (--restart --end-time), planned or not
            self.save_checkpoint()   # the end state, before the end frame
        if self.stopped is None and self.write_output and self.frames and sim.step_count > 0 \
                and self.last_saved != sim.step_count:
            self.save_frame()
        sim.comm.finish()   # a message sent but never received (a duplicate in the last step): reported


def _finish_output(writer, sim, sampler) -> None:
    """/timing, /exclusions, /probes and /forces, then the final master (call on every rank)."""
    _write_timing(writer, sim)
    _write_exclusions(writer, sim)
    if writer is not None:
        if sampler is not None:
            sampler.write(writer)
        writer.close()


def _abort_all(sim, e) -> None:
    """An exception on one MPI rank: print it once (this rank) and abort every rank (exit 3)."""
    import os
    import sys
    import tempfile
    import traceback
    c = sim.contexts[0]
    if isinstance(e, CommError):   # a message fault: its one line names ranks, task and step
        print(f"sphgraph: communication error: {e}; aborting all ranks", file=sys.stderr, flush=True)
        sim.comm.abort(e.exit_code)
        os._exit(e.exit_code)
    if isinstance(e, DiskFullError):   # the root ran out of space: every rank stops with exit 1
        print(f"sphgraph: {e}; aborting all ranks", file=sys.stderr, flush=True)
        sim.comm.abort(e.exit_code)
        os._exit(e.exit_code)
    fd, log = tempfile.mkstemp(prefix=f"sphgraph-error-rank{c.rank}-", suffix=".log")
    with os.fdopen(fd, "w") as f:
        traceback.print_exc(file=f)
    print(f"sphgraph: internal error on rank {c.rank} at step {sim.step_count}: {type(e).__name__}: {e}; "
          f"aborting all ranks (traceback in {log})", file=sys.stderr, flush=True)
    sim.comm.abort(3)
    os._exit(3)   # never reach the CLI's own report: the line above is the one line


def _write_balance(writer, sim) -> None:
    """/balance: one row per check (DESIGN.md; issue: step, applied, fluid_count, force_seconds)."""
    b = next((c.balancer for c in sim.contexts if c.rank == 0 and c.balancer is not None), None)
    if b is None or not b.datasets():
        return
    d = b.datasets()
    writer.write_group("balance", d, attrs={
        "policy": b.cfg.policy, "every": b.cfg.every, "threshold": b.cfg.threshold,
        "checks": len(d["step"]), "applications": int(d["applied"].sum()),
        "check_seconds": b.check_s, "apply_seconds": b.apply_s, "move_seconds": b.move_s,
        "seconds": "check_seconds, apply_seconds: wall time of rank 0 in the rebalance task (deciding; "
                   "setting the cuts); move_seconds: rank 0's send/recv_displaced tasks in the steps "
                   "after an application (/timing clock: virtual under mock MPI)"})


def _write_exclusions(writer, sim) -> None:
    """/exclusions: every particle removed by [domain] exclude_outside (step, time, id, cause,
    and its position, velocity and density then), gathered from every rank (call on every
    rank), sorted by (step, id)."""
    if not sim.features.exclude_outside:
        return
    rows = sim.features.exclusions(sim)
    if writer is not None and rows is not None:
        writer.write_group("exclusions", rows, attrs={
            "count": len(rows["id"]), "cause": f"2 = {CAUSES[2]}, 3 = {CAUSES[3]}"})


def _keep_exclusions(out_dir, sim, step) -> None:
    """Restart (root): the exclusions up to the checkpoint's step come from the run's /exclusions."""
    from .io import read_group
    if not sim.features.exclude_outside:
        return
    try:
        d = read_group(out_dir, "exclusions")
    except InputError:      # the run was killed before writing it
        return
    if len(d["step"]):
        keep = np.asarray(d["step"]) <= step
        sim.features.excluded[:0] = exclusion_rows(d, sim.scene.dim, keep)


def _write_timing(writer, sim) -> None:
    cols = sim.scheduler.times.columns()
    if len(sim.comm.local_ranks) < sim.nranks:
        parts = sim.comm.gather(cols)    # MPI: every rank's /timing rows to the root
        if parts is not None:
            cols = {k: np.concatenate([p[k] for p in parts]) for k in cols}
    if writer is None:
        return
    _write_balance(writer, sim)
    if len(cols["rank"]):
        writer.write_timing(cols["rank"], cols["step"], cols["task"], cols["lane"], cols["start"], cols["end"],
                            cols["bytes"])
