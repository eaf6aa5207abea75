"""Where the device memory of a SPHERIC 2 run goes beyond its arrays (issue 6 §6, bytes per
particle): used memory (cuMemGetInfo, numba's deferred frees flushed) after the context, after
one tiny kernel's first launch (the cost of loading a module), after the set-up (uploads),
after the first step (every kernel module of a step loaded, work buffers), after warm-up; the
backend's own count of its arrays (state_bytes) next to it.

    python3 benchmarks/gpu_memory.py --dp 0.006 --json out.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.006)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    import numpy as np
    from numba import cuda
    from benchmarks.gpu_bench import _used, spheric2
    from sphgraph.solver import Simulation
    cuda.synchronize()
    rows = [("context", _used(cuda)[0])]

    @cuda.jit
    def tiny(x):
        i = cuda.grid(1)
        if i < x.shape[0]:
            x[i] += 1.0

    @cuda.jit
    def tiny2(x):
        i = cuda.grid(1)
        if i < x.shape[0]:
            x[i] *= 2.0

    x = cuda.device_array(1, np.float32)
    rows.append(("one float32 of data", _used(cuda)[0]))
    tiny[1, 32](x)
    cuda.synchronize()
    rows.append(("first module loaded", _used(cuda)[0]))
    tiny2[1, 32](x)
    cuda.synchronize()
    rows.append(("second module loaded", _used(cuda)[0]))
    sim = Simulation(spheric2(a.dp), backend="numba-cuda", precision="float32")
    cuda.synchronize()
    rows.append(("set-up (uploads)", _used(cuda)[0]))
    st = sim.contexts[0].state
    sim.step()
    cuda.synchronize()
    rows.append(("first step", _used(cuda)[0]))
    for _ in range(a.steps):
        sim.step()
    cuda.synchronize()
    rows.append((f"{a.steps} more steps", _used(cuda)[0]))
    n = sim.n_total
    base = rows[0][1]
    out = {"date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "command": " ".join(sys.argv), "particles": n,
           "device": cuda.get_current_device().name.decode() if isinstance(cuda.get_current_device().name, bytes)
           else cuda.get_current_device().name,
           "used_after": {k: v - base for k, v in rows},
           "state_bytes": sim.compute.state_bytes(st),
           "state_bytes_per_particle": sim.compute.state_bytes(st) / n,
           "peak_bytes_per_particle": (rows[-1][1] - base) / n,
           "module_bytes": rows[3][1] - rows[2][1],
           "fixed_bytes": (rows[-1][1] - base) - sim.compute.state_bytes(st)}
    print(json.dumps(out, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
