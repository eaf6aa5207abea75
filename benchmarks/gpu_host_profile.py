"""Where the host time of a GPU step goes: cProfile of `--steps` steps of SPHERIC 2 on
numba-cuda, one rank and N mock ranks in one process (wall clock and the top functions
by their own time). With many ranks in one process the host work of every rank runs
in one thread, so it bounds the speed once it passes the device's time a step.

    python3 benchmarks/gpu_host_profile.py --dp 0.006 --ranks 1 2 --steps 20 --top 30
"""
from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "spheric2.toml"))
    ap.add_argument("--dp", type=float, default=0.006)
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--precision", default="float32")
    a = ap.parse_args(argv)
    from numba import cuda

    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    sc = Scene.from_toml(a.scene).with_overrides(dp=a.dp)
    for n in a.ranks:
        sim = Simulation(sc, backend="numba-cuda", comm="single" if n == 1 else "mock", ranks=n,
                         precision=a.precision)
        for _ in range(a.warmup):
            sim.step()
        cuda.synchronize()
        pr = cProfile.Profile()
        t0 = time.perf_counter()
        pr.enable()
        for _ in range(a.steps):
            sim.step()
        cuda.synchronize()
        pr.disable()
        wall = time.perf_counter() - t0
        out = io.StringIO()
        st = pstats.Stats(pr, stream=out)
        st.sort_stats("tottime").print_stats(a.top)
        st.sort_stats("cumulative").print_stats(a.top)
        print(f"== ranks {n}: {sim.n_total} particles, {a.steps / wall:.2f} steps/s (wall, under the profiler), "
              f"{1e3 * wall / a.steps:.2f} ms a step")
        print(out.getvalue())
        del sim
    return 0


if __name__ == "__main__":
    sys.exit(main())
