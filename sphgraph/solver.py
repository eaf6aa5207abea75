"""`sphgraph.run`: set up a scene on backends, step it through the scheduler, write output.

Everything is validated (scene, backends, schedule, decomposition) before the
output directory is touched, so bad input writes nothing.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .balance import BalanceConfig, Balancer
from .cells import axis_order
from .domain import Slabs, choose_axis, equal_cuts, split
from .errors import InputError, NumericalError
from .registry import get
from .scene import Scene
from .schedule import Schedule
from .scheduler import RankContext, Scheduler
from .state import RankState

PRECISIONS = {"float32": np.float32, "float64": np.float64}
CAUSES = {1: "NaN in position or density", 2: "particle left the domain",
          3: "density outside the bounds [rho_min, rho_max]"}


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

    @property
    def steps_per_s(self) -> float:
        timed = self.steps - 1
        return timed / max(self.wall_s - self.compile_s, 1e-12) if timed > 0 else 0.0


class Simulation:
    """A scene set up on backends: `step()` advances one step through the scheduler."""

    def __init__(self, scene, *, backend="numba-cpu", comm="single", ranks=1, schedule="production",
                 precision=None, dp=None, end_time=None, user_tasks=(), fixed_dt=None,
                 comm_options=None, decomposition_axis=None, balance=None):
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
        self.balance_cfg = BalanceConfig.resolve(self.schedule.rebalance, scene.extra.get("balance"),
                                                 balance, source=scene.source)
        self.rebalance = (self.nranks > 1 and self.balance_cfg.enabled
                          and "rebalance" in self.schedule.order)
        self.schedule.validate(self.nranks, self.stages, self.user_tasks, rebalance=self.rebalance)
        self.compute = compute_cls()
        consts = scene.constants
        self.consts = consts
        particles = scene.build_particles(self.dtype)
        self.n_total = particles.n
        self.n_fluid = particles.n_fluid
        self.dim = particles.dim
        self.ids = None
        cap = self.balance_cfg.max_particles_per_rank
        if self.rebalance and self.balance_cfg.policy == "memory" and cap and self.n_fluid > cap * self.nranks:
            raise InputError(f"{scene.source}: balance.max_particles_per_rank: the scene's {self.n_fluid} fluid "
                             f"particles cannot fit in {self.nranks} ranks of {cap}: expected a cap >= "
                             f"{-(-self.n_fluid // self.nranks)} or more ranks")
        if self.nranks > 1:
            axis = choose_axis(decomposition_axis or scene.decomposition_axis, particles, consts.gravity)
            if axis >= self.dim:
                raise InputError(f"{scene.source}: decomposition.axis: expected an axis of a "
                                 f"{self.dim}D scene, got {'xyz'[axis]!r}")
            cuts = equal_cuts(particles, axis, self.nranks, consts.h)
            slabs = split(particles, axis, cuts)
            self.axis = axis
        else:
            axis, cuts, slabs = None, None, [particles]
            self.axis = None
        self.contexts = []
        for r in self.comm.local_ranks:
            st = RankState(particles=slabs[r], consts=consts, dtype=self.dtype, rank=r, nranks=self.nranks,
                           axes=axis_order(self.dim, axis), cfl=phys.cfl,
                           rho_min=phys.rho_min, rho_max=phys.rho_max)
            if axis is not None:
                st.axis, st.cut_lo, st.cut_hi = axis, cuts[r], cuts[r + 1]
            self.compute.prepare(st)
            dom = Slabs(r, axis, cuts, reach=2.2 * consts.h) if axis is not None else None
            bal = Balancer(self.balance_cfg, axis, consts.h, scene.dp) if self.rebalance else None
            self.contexts.append(RankContext(rank=r, state=st, compute=self.compute,
                                             comm=self.comm.endpoint(r), domain=dom,
                                             integrator=self.integrator, fixed_dt=fixed_dt, scene=scene,
                                             balancer=bal))
        self.scheduler = Scheduler(self.schedule, self.comm, self.contexts, self.stages, self.user_tasks,
                                   rebalance=self.rebalance)
        self.lo = np.asarray(scene.domain_min, float)
        self.hi = np.asarray(scene.domain_max, float)
        self.step_count = 0
        self.time = 0.0

    # ------------------------------------------------------------------ stepping
    def step(self) -> None:
        n = self.step_count
        euler = self.integrator == "verlet" and (n + 1) % self.scene.physics.verlet_euler_every == 0
        for c in self.contexts:
            c.euler = euler
            c.state.step = n
        bal = self.contexts[0].balancer
        self.scheduler.step(rebalance=bal is not None and bal.due(n))
        dt = self.contexts[0].state.dt
        self.time += dt
        self.step_count = n + 1
        for c in self.contexts:
            c.state.time = self.time
        self.check()

    def check(self) -> None:
        """Stop on NaN, a particle outside the domain or a density out of bounds."""
        found = None
        for c in self.contexts:
            bad = self.compute.check(c.state, self.lo, self.hi)
            if bad is not None and found is None:
                row, cause = bad
                found = (c.rank, int(c.state.particles.id[row]), cause)
        found = self.comm.first_problem(found) if hasattr(self.comm, "first_problem") else found
        if found is not None:
            rank, pid, cause = found
            where = f" on rank {rank}" if self.nranks > 1 else ""
            raise NumericalError(f"step {self.step_count} (t = {self.time:.6g} s): {CAUSES[cause]}: "
                                 f"particle id {pid}{where}", step=self.step_count, particle_id=pid,
                                 cause=CAUSES[cause])

    def frame_arrays(self) -> dict | None:
        """All ranks' particles in id order (on the root; None elsewhere)."""
        per = {c.rank: self.compute.host_arrays(c.state) for c in self.contexts}
        rows = self.comm.gather_rows(per)
        if rows is None:
            return None
        if len(rows) == 1:
            a = rows[0]
        else:
            a = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
        order = np.argsort(a["id"], kind="stable")
        if not np.array_equal(order, np.arange(len(order))):
            a = {k: v[order] for k, v in a.items()}
        return a

    def root_attrs(self, backend: str, comm: str) -> dict:
        return {"scene": self.scene.text, "version": __version__, "backend": backend, "comm": comm,
                "ranks": self.nranks, "schedule": self.schedule.name, "precision": self.precision,
                "dim": self.dim, "dp": self.scene.dp, "h": self.consts.h,
                "integrator": self.integrator}


def run(scene, *, backend="numba-cpu", comm="single", ranks=1, schedule="production", out=None,
        overwrite=False, precision=None, end_time=None, max_steps=None, dp=None, progress=True,
        user_tasks=(), fixed_dt=None, comm_options=None, write_output=True, balance=None) -> RunResult:
    """Run a scene to its end time (or `max_steps`) and write DIR/output.h5.

    Parameters mirror `sphgraph run` (DESIGN.md §5). Returns a `RunResult`.
    """
    from .io import OutputWriter, prepare_out_dir
    from .progress import Progress

    sim = Simulation(scene, backend=backend, comm=comm, ranks=ranks, schedule=schedule,
                     precision=precision, dp=dp, end_time=end_time, user_tasks=user_tasks,
                     fixed_dt=fixed_dt, comm_options=comm_options, balance=balance)
    scene = sim.scene
    t_end = scene.end_time
    if max_steps is not None and (isinstance(max_steps, bool) or int(max_steps) < 1):
        raise InputError(f"--max-steps: expected an integer >= 1, got {max_steps!r}")
    root = sim.comm.is_root
    writer = None
    out_dir = None
    if write_output:
        out_dir = Path(out) if out is not None else Path("out") / scene.name
        if root:
            prepare_out_dir(out_dir, overwrite=overwrite)
            writer = OutputWriter(out_dir, sim.root_attrs(sim.compute.name, sim.comm.name),
                                  sim.dim, sim.precision)
    prog = Progress(t_end, enabled=bool(progress) and root)
    frames = 0
    last_saved = -1   # step of the last frame, known on every rank (frame_arrays gathers)

    def save_frame():
        nonlocal frames, last_saved
        arrays = sim.frame_arrays()
        if writer is not None:
            writer.write_frame(frames, sim.time, sim.step_count, arrays)
        frames += 1
        last_saved = sim.step_count

    try:
        if write_output:
            save_frame()
        next_out = scene.output_interval
        t0 = time.perf_counter()
        compile_s = 0.0
        while sim.time < t_end - 1e-12 and (max_steps is None or sim.step_count < max_steps):
            sim.step()
            if sim.step_count == 1:
                compile_s = time.perf_counter() - t0
                prog.note(f"first step {compile_s:.2f} s (includes numba compilation)")
                prog.reset_clock(1)
            if write_output and sim.time >= next_out - 1e-12:
                save_frame()
                while next_out <= sim.time + 1e-12:
                    next_out += scene.output_interval
            prog.update(sim.time, sim.step_count)
        wall = time.perf_counter() - t0
        if write_output and frames and sim.step_count > 0 and last_saved != sim.step_count:
            save_frame()
    except NumericalError:
        prog.close()
        _write_timing(writer, sim)   # on every rank: gathers the ranks' timings under MPI
        if writer is not None:
            writer.close()
        raise
    prog.close()
    _write_timing(writer, sim)
    if writer is not None:
        writer.close()
    return RunResult(out_dir=out_dir, steps=sim.step_count, time=sim.time, wall_s=wall,
                     compile_s=compile_s, particles=sim.n_total, fluid_particles=sim.n_fluid, dim=sim.dim,
                     backend=sim.compute.name, comm=sim.comm.name, ranks=sim.nranks,
                     precision=sim.precision, integrator=sim.integrator, schedule=sim.schedule.name,
                     device=sim.compute.device_name(), frames=frames,
                     task_seconds=sim.scheduler.times.seconds_by_kind(first_step=1),
                     timing=sim.scheduler.times)


def _write_balance(writer, sim) -> None:
    """/balance: one row per check (DESIGN.md; issue: step, applied, fluid_count, force_seconds)."""
    b = next((c.balancer for c in sim.contexts if c.rank == 0 and c.balancer is not None), None)
    if b is None or not b.datasets():
        return
    d = b.datasets()
    writer.write_group("balance", d, attrs={
        "policy": b.cfg.policy, "every": b.cfg.every, "threshold": b.cfg.threshold,
        "checks": len(d["step"]), "applications": int(d["applied"].sum()),
        "check_seconds": b.check_s, "apply_seconds": b.apply_s})


def _write_timing(writer, sim) -> None:
    cols = sim.scheduler.times.columns()
    if len(sim.comm.local_ranks) < sim.nranks and hasattr(sim.comm, "gather"):
        parts = sim.comm.gather(cols)    # MPI: every rank's /timing rows to the root
        if parts is not None:
            cols = {k: np.concatenate([p[k] for p in parts]) for k in cols}
    if writer is None:
        return
    _write_balance(writer, sim)
    if len(cols["rank"]):
        writer.write_timing(cols["rank"], cols["step"], cols["task"], cols["lane"], cols["start"], cols["end"])
