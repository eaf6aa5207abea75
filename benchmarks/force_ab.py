"""A/B of the GPU force kernels on one SPHERIC 2 state (issue 6 §6).

Sets up SPHERIC 2 at `--dp` on the GPU, runs `--warmup` steps (a state in motion), then
times the interior forces (k_forces_f and k_forces_b, one `forces` call) for each
variant of the fluid kernel, interleaved over `--rounds`, on the same arrays, and
compares every variant's accelerations and density rates with the first one's.
A variant is KERNEL:MAXREG:BLOCK[:FLAG ...] (KERNEL f or fv, benchmarks/cuda_force_variants.py;
flags: notrim, fv with whole cells, as right after a step that moved rows since the sort;
u1 / u2, fv's candidates one or two (production) a turn; selfcut, fv's candidate test with
the r^2 < 1e-18 cut, noself without it (production)). The cells are
sorted again before the timings, so fv trims its rows with no slack.
Also prints the device memory held per particle by array, after numba's deferred
frees are flushed.

    python3 benchmarks/force_ab.py --dp 0.006 --variants f:64:128 fv:64:128 fv:72:128
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.006)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--reps", type=int, default=10, help="forces calls per timing")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--variants", nargs="+", default=["f:64:128", "fv:64:128"])
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from numba import cuda
    from benchmarks import cuda_force_variants as V
    from benchmarks.gpu_bench import spheric2
    from sphgraph.backends.compute import cuda_kernels as CK
    from sphgraph.solver import Simulation
    sim = Simulation(spheric2(a.dp), backend="numba-cuda", precision=a.precision)
    for _ in range(a.warmup):
        sim.step()
    cuda.synchronize()
    st = sim.contexts[0].state
    dv = st.extra["dev"]
    n = dv.n
    keep = (CK.MAXREG, CK.FORCE_BLOCK)

    sim.compute.build_cells(st)          # freshly sorted: fv trims its rows with no slack
    cuda.synchronize()

    def setv(v):
        f, mr, fb, *flags = v.split(":")
        V.select(forces=f, unroll=1 if "u1" in flags else 2, self_cut="selfcut" in flags)
        CK.MAXREG, CK.FORCE_BLOCK = int(mr), int(fb)
        dv.moved = np.inf if "notrim" in flags else 0.0

    def outputs():
        A = dv.A()
        return {k: A[k].copy_to_host()[:n].astype(np.float64) for k in ("ax", "ay", "az", "ar", "visc")}

    ref = None
    res = {"dp": a.dp, "particles": n, "fluid": dv.nf, "variants": {}}
    for v in a.variants:      # compile and check each once
        setv(v)
        t0 = time.perf_counter()
        sim.compute.forces(st, "interior")
        cuda.synchronize()
        comp = time.perf_counter() - t0
        out = outputs()
        if ref is None:
            ref = out
        diff = {k: float(np.abs(out[k] - ref[k]).max() / max(np.abs(ref[k]).max(), 1e-30)) for k in out}
        res["variants"][v] = {"first_call_s": comp, "max_rel_diff_vs_first": diff, "times_ms": []}
        print(v, "compile+run %.1f s" % comp, "diff", {k: "%.2e" % x for k, x in diff.items()}, flush=True)
    for _ in range(a.rounds):
        for v in a.variants:
            setv(v)
            sim.compute.forces(st, "interior")
            cuda.synchronize()
            t0 = time.perf_counter()
            for _ in range(a.reps):
                sim.compute.forces(st, "interior")
            cuda.synchronize()
            res["variants"][v]["times_ms"].append((time.perf_counter() - t0) / a.reps * 1e3)
    CK.MAXREG, CK.FORCE_BLOCK = keep
    V.select()
    dv.moved = 0.0
    pairs = sim.compute.count_pairs(st)
    base = None
    for v in a.variants:
        r = res["variants"][v]
        r["median_ms"] = float(np.median(r["times_ms"]))
        r["interactions_per_s"] = pairs / (r["median_ms"] * 1e-3)
        base = base or r["median_ms"]
        r["speedup_vs_first"] = base / r["median_ms"]
    res["pairs"] = int(pairs)
    # device memory: live bytes (deferred frees flushed) and the state's arrays by name
    import gc
    gc.collect()
    cuda.current_context().deallocations.clear()
    free, total = cuda.current_context().get_memory_info()
    res["device_used_bytes_per_particle"] = (total - free) / n
    res["arrays_bytes_per_particle"] = {k: float(getattr(x, "nbytes", 0)) / n for k, x in dv.arrays.items()
                                        if getattr(x, "nbytes", 0) > n // 100}
    res["state_bytes_per_particle"] = sim.compute.state_bytes(st) / n
    print(f"{'variant':>18} {'ms/forces':>10} {'G int/s':>8} {'speedup':>8}")
    for v in a.variants:
        r = res["variants"][v]
        print(f"{v:>18} {r['median_ms']:10.3f} {r['interactions_per_s'] / 1e9:8.1f} {r['speedup_vs_first']:8.3f}")
    print("memory B/particle: used %.1f, state %.1f" % (res["device_used_bytes_per_particle"],
                                                        res["state_bytes_per_particle"]))
    print(json.dumps(res["arrays_bytes_per_particle"]))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
