"""GPU benchmark of the numba-cuda backend (issue 6): SPHERIC test 2 at several dp.

For each dp: set-up, warm-up steps (the first includes kernel compilation), a profile
pass (device synchronised after every task, so the scheduler's task times are kernel
times), then timed steps through the real scheduler, then the same steps through a
bare loop that calls the backend directly (scheduler overhead), interactions counted
on the device (pairs within 2h from each side, per force evaluation, as DualSPHysics),
and device memory (numba's context memory info after its deferred frees are flushed:
peak held over the run / particles; the count of pairs, which allocates, comes after).

    python3 benchmarks/gpu_bench.py --dp 0.01 0.006 --steps 20 --json out.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def spheric2(dp):
    from sphgraph.scene import Scene
    path = ROOT / "examples" / "spheric2.toml"
    return Scene.from_toml(path).with_overrides(dp=dp)


def _used(cuda, flush=True):
    """Device bytes in use. numba frees device arrays lazily (a queue of deferred frees):
    flush=True empties that queue first, so the figure is what the run holds; the backend
    allocates nothing inside a step (its work buffers persist), so at step boundaries this
    is the peak."""
    if flush:
        cuda.current_context().deallocations.clear()
    free, total = cuda.current_context().get_memory_info()
    return total - free, total


def bare_step(sim):
    """One step calling the backend in the production order (single rank), no scheduler."""
    comp = sim.compute
    c = sim.contexts[0]
    st = c.state
    n = sim.step_count
    st.step = n
    euler = sim.integrator == "verlet" and (n + 1) % sim.scene.physics.verlet_euler_every == 0
    comp.build_cells(st)
    for s in range(1, sim.stages + 1):
        comp.forces(st, "interior")
        if s == 1:
            comp.reduce_forces(st, 1)
            st.dt_local = comp.dt_local(st)
            st.dt = st.dt_local
        comp.reduce_forces(st, s)
        comp.integrate(st, s, sim.integrator, euler)
    sim.time += st.dt
    sim.step_count = n + 1
    st.time = sim.time
    sim.check()


def kernel_info(dtype, block):
    """Registers, local memory and an occupancy estimate of the force kernels (per
    compiled signature), from numba's compiled-kernel attributes."""
    from numba import cuda
    from sphgraph.backends.compute import cuda_kernels as CK
    out = {}
    k = CK.build(dtype)
    dev = cuda.get_current_device()
    regs_sm = 65536
    disps = [(name, getattr(k, name)) for name in ("k_forces",)]
    for j, ns in enumerate(CK._FORCES.values()):
        disps += [(f"{name}[build {j}]", getattr(ns, name)) for name in ("k_forces_f", "k_forces_b")]
    for name, disp in disps:
        for i, (sig, kern) in enumerate(disp.overloads.items()):
            regs = int(getattr(kern, "regs_per_thread", 0) or 0)
            info = {"regs_per_thread": regs,
                    "local_mem_per_thread": int(getattr(kern, "local_mem_per_thread", 0) or 0),
                    "max_threads_per_block": int(getattr(kern, "max_threads_per_block", 0) or 0)}
            if regs:
                per_warp = -(-regs * 32 // 256) * 256
                warps = regs_sm // per_warp
                wpb = max(block // 32, 1)
                blocks_sm = min(warps // wpb, 32)
                info["occupancy_est"] = min(blocks_sm * wpb, 64) / 64
            out[f"{name}#{i}"] = info
    out["sm_count"] = int(dev.MULTIPROCESSOR_COUNT)
    return out


def sweep_blocks(sim, blocks, steps, maxregs=()):
    """Steps/s of the same simulation with each force-kernel block size (and each
    register cap: `max_registers`, block 128; the first step compiles)."""
    from numba import cuda
    from sphgraph.backends.compute import cuda_kernels as CK
    keep = CK.FORCE_BLOCK
    keep_mr = CK.MAXREG
    out = {}
    for b in list(blocks) + [f"maxreg{m}" for m in maxregs]:
        if isinstance(b, str):
            CK.FORCE_BLOCK = keep
            CK.MAXREG = int(b[6:])
        else:
            CK.FORCE_BLOCK = int(b)
            CK.MAXREG = keep_mr
        sim.step()
        cuda.synchronize()
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        cuda.synchronize()
        out[str(b)] = steps / (time.perf_counter() - t0)
    CK.FORCE_BLOCK = keep
    CK.MAXREG = keep_mr
    return out


def one(dp, steps, warmup, precision, profile_steps, bare, blocks=(), maxregs=(), host_profile=False):
    from numba import cuda
    from sphgraph.solver import Simulation
    cuda.synchronize()
    used0, total = _used(cuda)
    t0 = time.perf_counter()
    sim = Simulation(spheric2(dp), backend="numba-cuda", precision=precision)
    setup_s = time.perf_counter() - t0
    st = sim.contexts[0].state
    n = sim.n_total
    t0 = time.perf_counter()
    sim.step()
    cuda.synchronize()
    compile_s = time.perf_counter() - t0
    for _ in range(max(warmup - 1, 0)):
        sim.step()
    cuda.synchronize()
    peak = _used(cuda)[0]
    peak_lazy = _used(cuda, flush=False)[0]
    # profile: synchronise after each task
    sim.compute.sync_tasks = True
    sim.scheduler.times.clear()
    first = sim.step_count
    for _ in range(profile_steps):
        sim.step()
    prof = sim.scheduler.times.seconds_by_kind(first_step=first)
    prof_total = sum(prof.values())
    sim.compute.sync_tasks = False
    # timed, through the scheduler
    sim.scheduler.times.clear()
    cuda.synchronize()
    b0 = dict(st.extra.get("bytes_by_kind", {}))
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    cuda.synchronize()
    wall = time.perf_counter() - t0
    b1 = dict(st.extra.get("bytes_by_kind", {}))
    peak_lazy = max(peak_lazy, _used(cuda, flush=False)[0])
    peak = max(peak, _used(cuda)[0])
    bare_wall = None
    if bare:
        sim.scheduler.record_times = False
        cuda.synchronize()
        t0 = time.perf_counter()
        for _ in range(steps):
            bare_step(sim)
        cuda.synchronize()
        bare_wall = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        cuda.synchronize()
        wall2 = time.perf_counter() - t0
        wall = min(wall, wall2)
    host_prof = None
    if host_profile:
        # where the host's time goes in timed steps: launching, waiting for the device
        # (synchronize / copies), the scheduler
        import cProfile
        import io
        import pstats
        pr = cProfile.Profile()
        cuda.synchronize()
        pr.enable()
        for _ in range(steps):
            sim.step()
        cuda.synchronize()
        pr.disable()
        buf = io.StringIO()
        pstats.Stats(pr, stream=buf).sort_stats("tottime").print_stats(30)
        host_prof = buf.getvalue()
    pairs = sim.compute.count_pairs(st)
    cuda.synchronize()
    sweep = sweep_blocks(sim, blocks, steps, maxregs) if (blocks or maxregs) else None
    from sphgraph.backends.compute import cuda_kernels as CK
    try:
        kinfo = kernel_info(st.dtype, CK.FORCE_BLOCK)
    except Exception as e:  # noqa: BLE001  (simulator: no compiled kernels)
        kinfo = {"error": repr(e)}
    evals = steps * sim.stages
    out = {
        "scene": "spheric2", "dp": dp, "particles": n, "fluid_particles": sim.n_fluid,
        "boundary_particles": n - sim.n_fluid, "precision": precision, "integrator": sim.integrator,
        "steps": steps, "wall_s": wall, "steps_per_s": steps / wall,
        "particle_steps_per_s": steps * n / wall, "interactions_per_s": pairs * evals / wall,
        "pairs_per_particle": pairs / n, "compile_s": compile_s, "setup_s": setup_s,
        "device_bytes_per_particle_peak": (peak - used0) / n,
        "device_bytes_per_particle_with_deferred_frees": (peak_lazy - used0) / n,
        "state_bytes_per_particle": sim.compute.state_bytes(st) / n,
        "device_total_bytes": total,
        "profile_seconds_per_step": {k: v / profile_steps for k, v in prof.items()},
        "profile_share": {k: v / prof_total for k, v in prof.items()} if prof_total else {},
        "bus_bytes_per_step": {k: (b1.get(k, 0) - b0.get(k, 0)) / steps for k in b1},
        "device": sim.compute.device_name(),
        "force_block": __import__("sphgraph.backends.compute.cuda_kernels", fromlist=["x"]).FORCE_BLOCK,
        "kernels": kinfo, "block_sweep_steps_per_s": sweep,
        "pair_count": "DualSPHysics: all neighbours of fluid rows, fluid neighbours of boundary rows",
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "command": " ".join(sys.argv),
    }
    if host_prof is not None:
        out["host_profile"] = host_prof
    if bare_wall is not None:
        out["bare_loop_wall_s"] = bare_wall
        out["scheduler_overhead_share"] = (wall - bare_wall) / wall
    del sim, st
    import gc
    gc.collect()
    cuda.current_context().deallocations.clear()
    return out


def roofline():
    """Device-to-device copy bandwidth (read + write) on this GPU."""
    import numpy as np
    from numba import cuda
    import os
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return {"skipped": "simulator"}
    n = 1 << 28   # 1 GiB of float32
    a = cuda.device_array(n, np.float32)
    b = cuda.device_array(n, np.float32)
    b.copy_to_device(a)
    cuda.synchronize()
    t0 = time.perf_counter()
    for _ in range(5):
        b.copy_to_device(a)
    cuda.synchronize()
    dt = (time.perf_counter() - t0) / 5
    return {"d2d_copy_GBps_read_plus_write": 2 * a.nbytes / dt / 1e9}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, nargs="+", default=[0.01, 0.006])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--profile-steps", type=int, default=3)
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--bare", action="store_true", help="also time a bare loop (scheduler overhead)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--blocks", type=int, nargs="*", default=[],
                    help="also time the force kernels at these block sizes (same run)")
    ap.add_argument("--maxreg", type=int, nargs="*", default=[],
                    help="also time the force kernels compiled with these register caps (same run)")
    ap.add_argument("--host-profile", action="store_true",
                    help="also profile the host (cProfile) over the timed steps, after timing them")
    a = ap.parse_args(argv)
    res = {"runs": [], "roofline": None}
    try:
        res["roofline"] = roofline()
    except Exception as e:  # noqa: BLE001
        res["roofline"] = {"error": repr(e)}
    print(json.dumps(res["roofline"]), flush=True)
    for dp in a.dp:
        try:
            r = one(dp, a.steps, a.warmup, a.precision, a.profile_steps, a.bare, a.blocks, a.maxreg,
                    a.host_profile)
        except Exception as e:  # noqa: BLE001  (e.g. out of memory at the largest size)
            r = {"dp": dp, "error": repr(e)}
        res["runs"].append(r)
        print(json.dumps({k: v for k, v in r.items() if k != "host_profile"}), flush=True)
        if r.get("host_profile"):
            print(r["host_profile"], flush=True)
        if a.json:
            Path(a.json).write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
