"""Cost of the task-graph machinery: scheduled steps against the same kernels in a bare loop.

    python benchmarks/scheduler_overhead.py [SCENE] [--dp DP] [--steps N]

Both loops run the same kernels on the same state in one process, alternating
blocks of steps (so machine load hits both alike); the bare loop exists only
here, for this measurement. Also times the scheduler with no-op task bodies:
the per-task cost of dispatch plus start/end recording. Prints one JSON object.
"""
import argparse
import json
import os
import sys
import time

import numpy as np

from sphgraph.solver import Simulation


def bare_step(sim):
    """One Verlet step without tasks, scheduler or recording (single rank)."""
    c = sim.contexts[0]
    st, be = c.state, sim.compute
    st.step = sim.step_count
    be.build_cells(st)
    be.forces(st, "interior")
    be.reduce_forces(st, 1)
    st.dt = be.dt_local(st)
    euler = (sim.step_count + 1) % sim.scene.physics.verlet_euler_every == 0
    be.integrate(st, 1, "verlet", euler)
    sim.time += st.dt
    sim.step_count += 1
    sim.check()


def main():
    ap = argparse.ArgumentParser()
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("scene", nargs="?", default=os.path.join(here, "..", "examples", "dambreak2d.toml"))
    ap.add_argument("--dp", type=float, default=0.0045)  # ~100k particles in the 2D dam break
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--blocks", type=int, default=5)
    a = ap.parse_args()
    sim = Simulation(a.scene, dp=a.dp)
    for _ in range(3):
        sim.step()
        bare_step(sim)
    sched, bare = [], []
    for _ in range(a.blocks):
        t0 = time.perf_counter()
        for _ in range(a.steps):
            sim.step()
        sched.append((time.perf_counter() - t0) / a.steps)
        t0 = time.perf_counter()
        for _ in range(a.steps):
            bare_step(sim)
        bare.append((time.perf_counter() - t0) / a.steps)
    ntasks = len(sim.scheduler.programs[0])
    # dispatch + recording cost per task: the same programs with no-op bodies
    noop = [type(t)(**{**t.__dict__, "fn": (lambda ctx, task: None)}) for t in sim.scheduler.programs[0]]
    sim.scheduler.programs[0] = noop * 100
    reps = 200
    t0 = time.perf_counter()
    for _ in range(reps):
        sim.scheduler.step()
    per_task = (time.perf_counter() - t0) / (reps * len(noop) * 100)
    s, b = float(np.median(sched)), float(np.median(bare))
    print(json.dumps({
        "scene": sim.scene.name, "particles": sim.n_total, "dp": sim.scene.dp, "tasks_per_step": ntasks,
        "scheduled_step_s": s, "bare_step_s": b, "overhead_s_per_step": s - b,
        "overhead_fraction": (s - b) / b, "overhead_per_task_us": (s - b) / ntasks * 1e6,
        "dispatch_per_task_us": per_task * 1e6, "threads": int(os.environ.get("NUMBA_NUM_THREADS", 0)) or None,
        "python": sys.version.split()[0]}))


if __name__ == "__main__":
    main()
