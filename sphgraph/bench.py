"""`sphgraph bench`: time a scene's steps through the real scheduler (DESIGN.md §5 fields)."""
from __future__ import annotations

import time

from . import __version__

PREDICT_STEPS = 10   # steps of a device-timed prediction window (each task alone on the device)


def bench(scene, *, steps=50, warmup=5, backend="numba-cpu", comm="single", ranks=1,
          schedule="production", precision=None, dp=None, comm_options=None,
          balance=None) -> dict | None:
    """Run `warmup` untimed steps (compilation), then `steps` timed ones; no output files.

    Interactions are counted as DualSPHysics does: pairs within 2h, from each
    particle's side, per force evaluation; counted on the final state and
    multiplied by the force evaluations of the timed steps.
    """
    from .errors import InputError
    from .solver import Simulation
    if steps < 1 or warmup < 0:
        raise InputError(f"--steps/--warmup: expected steps >= 1 and warmup >= 0, got {steps}, {warmup}")
    t0 = time.perf_counter()
    sim = Simulation(scene, backend=backend, comm=comm, ranks=ranks, schedule=schedule,
                     precision=precision, dp=dp, end_time=None, comm_options=comm_options,
                     balance=balance)
    setup_s = time.perf_counter() - t0
    # the first step compiles (or loads cached) kernels: its time is compile_s; the rest
    # of the warm-up is untimed
    t0 = time.perf_counter()
    sim.step()
    compile_s = time.perf_counter() - t0
    for _ in range(warmup - 1):
        sim.step()
    sim.scheduler.times.clear()
    first = sim.step_count
    sim.comm.barrier()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    sim.comm.barrier()
    wall = time.perf_counter() - t0
    pairs = sum(sim.compute.count_pairs(c.state) for c in sim.contexts)
    pairs = sim.comm.allreduce(pairs, "sum") if sim.nranks > 1 else pairs
    mem = sum(sim.compute.state_bytes(c.state) for c in sim.contexts)
    mem = sim.comm.allreduce(mem, "sum") if sim.nranks > 1 else mem
    if not sim.comm.is_root:
        return None
    evals = steps * sim.stages
    # the speed is the wall clock; a mock run's virtual clock is a prediction: over the timed
    # steps (the cost model), or, where the clock can read the device, over PREDICT_STEPS
    # steps after them with every task timed alone on the device (the timed steps stay free
    # of that synchronisation), scaled to `steps`
    times, scale, predict_steps = sim.scheduler.times, 1.0, steps
    if sim.comm.device_clock_window(True):
        predict_steps = min(steps, PREDICT_STEPS)
        times.clear()
        first = sim.step_count
        for _ in range(predict_steps):
            sim.step()
        sim.comm.device_clock_window(False)
        scale = steps / predict_steps
    task_s = {k: v * scale for k, v in times.seconds_by_kind(first_step=first).items()}
    predicted = None
    if sim.comm.virtual_time and times.end:
        predicted = (max(times.end) - min(times.start)) * scale
    return {
        "scene": sim.scene.name, "particles": sim.n_total, "fluid_particles": sim.n_fluid, "dim": sim.dim,
        "steps": steps, "wall_s": wall, "compile_s": compile_s, "setup_s": setup_s,
        "steps_per_s": steps / wall, "particle_steps_per_s": steps * sim.n_total / wall,
        "interactions_per_s": pairs * evals / wall, "pairs_per_particle": pairs / sim.n_total,
        "bytes_per_particle": mem / sim.n_total, "task_seconds": task_s,
        "backend": sim.compute.name, "comm": sim.comm.name, "ranks": sim.nranks,
        "precision": sim.precision, "integrator": sim.integrator, "schedule": sim.schedule.name,
        "halo_transport": sim.halo_transport,
        "dp": sim.scene.dp, "device": sim.compute.device_name(), "version": __version__,
        "virtual_time": bool(sim.comm.virtual_time),
        # mock MPI: the virtual clock (durations from the cost model, or the device's own task
        # times on numba-cuda), a prediction of the ranks' speed, not a measurement
        "predicted_wall_s": predicted,
        "predicted_steps_per_s": None if not predicted else steps / predicted,
        "predicted_from": sim.comm.clock if sim.comm.virtual_time else None,
        "task_seconds_are": f"predicted (virtual clock: {sim.comm.clock})" if sim.comm.virtual_time else "measured",
        "predict_steps": predict_steps if sim.comm.virtual_time else None,
    }
