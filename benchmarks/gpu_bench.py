"""GPU benchmark of the numba-cuda backend (issue 6): SPHERIC test 2 at several dp.

For each dp: set-up, warm-up steps (the first includes kernel compilation), a profile
pass (device synchronised after every task, so the scheduler's task times are kernel
times), then timed steps through the real scheduler, then the same steps through a
bare loop that calls the backend directly (scheduler overhead), interactions counted
on the device (pairs within 2h from each side, per force evaluation, as DualSPHysics),
and device memory (numba's context memory info after its deferred frees are flushed:
peak held over the run / particles; the count of pairs, which allocates, comes after).

The largest scene (issue 6 §6: what fits one H100 80 GB, >= 10 steps): `--lean` skips
what is slow or allocates at that size (the profile pass, the bare loop, the pair count:
4 B per particle on top of the measured peak, the block sweeps, the roofline's 2 GiB) and
reports the peak device memory against an H100's 81,559 MiB; `--plan` (no GPU needed)
finds the dp whose predicted peak fits it with a margin, counting the real scene's
particles (fluid + boundary); `--particles N` asks for a size by count. Every run prints
its set-up phases (`Simulation.setup_seconds`) and host peak memory as it goes.

    python3 benchmarks/gpu_bench.py --dp 0.01 0.006 --steps 20 --json out.json
    python3 benchmarks/gpu_bench.py --plan
    python3 benchmarks/gpu_bench.py --dp 0.00095 --steps 10 --warmup 2 --lean --json largest.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


H100_MIB = 81559              # an H100 SXM 80GB's device memory as cuMemGetInfo counts it
MAX_PARTICLES = 2 ** 31 - 2   # the device's 32-bit ids (cuda_upload.prepare)
FIXED_BYTES = 32 << 20        # device memory beyond the arrays (21.5 MB measured at 4.4 M: gpu_memory.py)
CONTEXT_BYTES = 1 << 30       # what a plan allows for the CUDA context (the run measures it)


def spheric2(dp):
    """SPHERIC test 2 at dp, its particle limit raised to what the device's ids allow."""
    from sphgraph.scene import Scene
    path = ROOT / "examples" / "spheric2.toml"
    d = Scene.from_toml(path).to_dict()
    d["limits"]["max_particles"] = MAX_PARTICLES
    return Scene.from_dict(d, source=str(path)).with_overrides(dp=dp)


def _say(msg):
    print(msg, flush=True)


def host_peak_bytes():
    """The process's resident high-water mark (Linux: kB in ru_maxrss)."""
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def device_bytes(sc, precision="float32"):
    """Device bytes a single-rank numba-cuda run of scene `sc` holds at its peak, without the
    CUDA context: the backend's arrays after prepare, fit_fluid and build_cells
    (cuda_memory.DeviceState) -- per row float64 positions, history velocity and density,
    the (v, rho) and (r, p) records, kind, 32-bit id and `ar`; reduced accelerations per
    fluid row; two int32 cell starts per cell (kind-split keys, 5 % spare) over the rows'
    bounding box -- plus FIXED_BYTES. Within 0.02 B per particle of the H200's state bytes
    at 4.4 and 13.3 M. Needs a scene of boxes only (its row fill gives the bounding box)."""
    import numpy as np
    from sphgraph.cells import grid_dims
    nf, nb = sc.count_particles()
    n = nf + nb
    s = np.dtype(precision).itemsize
    c = sc.constants
    lo, hi = (sc.lattice_origin + np.asarray(b) * sc.dp for b in sc._row_fill().window)
    dims = grid_dims(lo, hi, c.cell_size, np.array([0, 1, 2]))
    cells = int(dims.prod())
    rows = 3 * 8 + 3 * s + 4 * s + s + 1 + 4 + 4 * s + s
    return rows * n + 3 * s * nf + 4 * (int((2 * cells + 1) * 1.05) + 16) + FIXED_BYTES


def _round_up(x, digits=4):
    """x rounded up to `digits` significant digits (a dp a person can type)."""
    import math
    e = math.floor(math.log10(x)) - digits + 1
    return math.ceil(x / 10 ** e) * 10 ** e


def _smallest_dp(test, lo=5e-4, hi=0.02):
    """The smallest dp in (lo, hi] with test(dp) (true at hi, false at lo; false below some
    dp and true above it, up to lattice rounding; a scene over the particle limit counts as
    false), rounded up to 4 digits and checked."""
    from sphgraph.errors import InputError

    def ok(dp):
        try:
            return test(dp)
        except InputError:
            return False
    for _ in range(60):
        mid = (lo * hi) ** 0.5
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
        if hi / lo - 1 < 1e-7:
            break
    dp = float(f"{_round_up(hi):.4g}")
    while not ok(dp):
        dp = float(f"{_round_up(dp * 1.0002):.4g}")
    return dp


def dp_for_particles(n):
    """The smallest 4-digit dp whose SPHERIC 2 (fluid + boundary, counted by the scene) has
    at most n particles."""
    return _smallest_dp(lambda dp: sum(spheric2(dp).count_particles()) <= n)


def plan(budget_mib=H100_MIB, margin=0.04, precision="float32"):
    """The largest SPHERIC 2 whose predicted peak (device_bytes + CONTEXT_BYTES) stays
    `margin` below `budget_mib`: dp, particles, predicted device and host memory."""
    from sphgraph.invariants import bytes_per_particle
    cap = budget_mib * 2 ** 20 * (1 - margin) - CONTEXT_BYTES
    dp = _smallest_dp(lambda dp: device_bytes(spheric2(dp), precision) <= cap)
    sc = spheric2(dp)
    nf, nb = sc.count_particles()
    n = nf + nb
    dev = device_bytes(sc, precision)
    import numpy as np
    host = bytes_per_particle(3, np.dtype(precision).itemsize, device_rows=True, row_fill=sc.uses_row_fill())
    return {"dp": dp, "particles": n, "fluid_particles": nf, "boundary_particles": nb,
            "predicted_device_bytes": dev, "predicted_device_bytes_per_particle": dev / n,
            "predicted_peak_MiB_with_context": (dev + CONTEXT_BYTES) / 2 ** 20,
            "budget_MiB": budget_mib, "margin": margin,
            "predicted_share_of_budget": (dev + CONTEXT_BYTES) / 2 ** 20 / budget_mib,
            "host_bytes_guard": host * n, "host_guard_bytes_per_particle": host}


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


def one(dp, steps, warmup, precision, profile_steps, bare, blocks=(), maxregs=(), host_profile=False,
        lean=False):
    """One size. `lean` (the largest scenes): no profile pass, bare loop, pair count or sweeps."""
    from numba import cuda
    from sphgraph.solver import Simulation
    if lean:
        profile_steps, bare, blocks, maxregs, host_profile = 0, False, (), (), False
    cuda.synchronize()
    used0, total = _used(cuda)
    t0 = time.perf_counter()
    sim = Simulation(spheric2(dp), backend="numba-cuda", precision=precision)
    setup_s = time.perf_counter() - t0
    st = sim.contexts[0].state
    n = sim.n_total
    phases = dict(sim.setup_seconds)
    _say(f"dp {dp}: {n:,} particles ({sim.n_fluid:,} fluid): set-up {setup_s:.1f} s ("
         + ", ".join(f"{k} {v:.1f} s" for k, v in phases.items())
         + f"), host peak {host_peak_bytes() / 2 ** 30:.1f} GiB, device {(_used(cuda)[0] - used0) / n:.1f} B per particle")
    t0 = time.perf_counter()
    sim.step()
    cuda.synchronize()
    compile_s = time.perf_counter() - t0
    _say(f"  first step (compiles the kernels) {compile_s:.1f} s")
    for _ in range(max(warmup - 1, 0)):
        sim.step()
    cuda.synchronize()
    peak_lazy = _used(cuda, flush=False)[0]
    peak = _used(cuda)[0]
    _say(f"  warm-up {warmup} steps, device peak {peak / 2 ** 20:,.0f} MiB ({(peak - used0) / n:.1f} B per particle)")
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
    _say(f"  {steps} timed steps {wall:.2f} s: {steps * n / wall / 1e6:.1f} M particle-steps/s")
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
    # the pair count allocates an int32 per row after the peak was taken: not at the largest sizes
    pairs = None if lean else sim.compute.count_pairs(st)
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
        "particle_steps_per_s": steps * n / wall,
        "interactions_per_s": None if pairs is None else pairs * evals / wall,
        "pairs_per_particle": None if pairs is None else pairs / n, "compile_s": compile_s, "setup_s": setup_s,
        "setup_phases_s": phases, "host_peak_bytes": host_peak_bytes(),
        "host_peak_bytes_per_particle": host_peak_bytes() / n,
        "device_used_before_setup_bytes": used0, "device_peak_bytes": peak,
        "device_predicted_bytes": device_bytes(sim.scene, precision),
        "h100_80gb": {"total_MiB": H100_MIB, "peak_MiB": peak / 2 ** 20, "peak_share": peak / 2 ** 20 / H100_MIB,
                      "margin_MiB": H100_MIB - peak / 2 ** 20,
                      "note": "peak = device memory in use (total - free, the CUDA context included) on "
                              "this device, against an H100 SXM 80GB's total"},
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
    if lean:
        out["lean"] = ("skipped: profile pass, bare loop, block sweeps, and the pair count "
                       "(an int32 per row on top of the measured peak)")
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


def apply_knobs(env=None) -> dict:
    """The force kernels' tuning knobs of benchmark sessions (benchmarks/gpu_session.sh), read
    here and not by the backend: SPHGRAPH_CUDA_MAXREG (register cap), SPHGRAPH_CUDA_FORCE_BLOCK
    (block size), SPHGRAPH_CUDA_FORCES=f and SPHGRAPH_CUDA_UNROLL=1
    (benchmarks/cuda_force_variants.py). Returns the ones set."""
    import os
    env = os.environ if env is None else env
    got = {k: env[k] for k in ("SPHGRAPH_CUDA_MAXREG", "SPHGRAPH_CUDA_FORCE_BLOCK", "SPHGRAPH_CUDA_FORCES",
                               "SPHGRAPH_CUDA_UNROLL") if k in env}
    if not got:
        return got
    from sphgraph.backends.compute import cuda_kernels as CK
    if "SPHGRAPH_CUDA_MAXREG" in got:
        CK.MAXREG = int(got["SPHGRAPH_CUDA_MAXREG"])
    if "SPHGRAPH_CUDA_FORCE_BLOCK" in got:
        CK.FORCE_BLOCK = int(got["SPHGRAPH_CUDA_FORCE_BLOCK"])
    if "SPHGRAPH_CUDA_FORCES" in got or "SPHGRAPH_CUDA_UNROLL" in got:
        sys.path.insert(0, str(ROOT))
        from benchmarks import cuda_force_variants as V
        V.select(forces=got.get("SPHGRAPH_CUDA_FORCES", "fv"), unroll=int(got.get("SPHGRAPH_CUDA_UNROLL", 2)))
    return got


def main(argv=None):
    knobs = apply_knobs()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, nargs="+", default=None, help="default 0.01 0.006")
    ap.add_argument("--particles", type=float, nargs="+", default=[],
                    help="sizes by particle count: the smallest 4-digit dp whose scene has at most this many")
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
    ap.add_argument("--lean", action="store_true",
                    help="the largest sizes: no roofline, profile pass, bare loop, pair count or sweeps")
    ap.add_argument("--plan", type=float, nargs="?", const=H100_MIB, default=None, metavar="MIB",
                    help="print the largest dp whose predicted peak fits MIB (default an H100's "
                         f"{H100_MIB}) less --margin, and stop (no GPU needed)")
    ap.add_argument("--margin", type=float, default=0.04, help="--plan: share of MIB left free")
    a = ap.parse_args(argv)
    if a.plan is not None:
        res = plan(a.plan, a.margin, a.precision)
        _say(json.dumps(res, indent=1))
        if a.json:
            Path(a.json).write_text(json.dumps(res, indent=1))
        return res
    dps = list(a.dp or ([] if a.particles else [0.01, 0.006]))
    for want in a.particles:
        dps.append(dp_for_particles(int(want)))
        _say(f"{int(want):,} particles at most: dp {dps[-1]}")
    res = {"runs": [], "roofline": None, "knobs": knobs}
    if not a.lean:
        try:
            res["roofline"] = roofline()
        except Exception as e:  # noqa: BLE001
            res["roofline"] = {"error": repr(e)}
        _say(json.dumps(res["roofline"]))
    for dp in dps:
        try:
            r = one(dp, a.steps, a.warmup, a.precision, a.profile_steps, a.bare, a.blocks, a.maxreg,
                    a.host_profile, a.lean)
        except Exception as e:  # noqa: BLE001  (e.g. out of memory at the largest size)
            r = {"dp": dp, "error": repr(e), "host_peak_bytes": host_peak_bytes()}
        res["runs"].append(r)
        _say(json.dumps({k: v for k, v in r.items() if k not in ("host_profile", "kernels")}))
        if r.get("host_profile"):
            _say(r["host_profile"])
        if a.json:
            Path(a.json).write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
