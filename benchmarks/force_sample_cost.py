"""Cost of one `[forces]` sample against one step (issue 22 §5), numba-cpu.

  python benchmarks/force_sample_cost.py [--dp 0.0108] [--steps 30] [--body wall|column] [--dense]

examples/yeh_petroff.toml at `--dp` (0.0108: ~100 k particles); the body is the tank's back wall
behind the water (`wall`, wetted from the start: the sample's full cost) or the column (dry
until the surge arrives at t ~ 0.4 s); after `--steps` steps, the median wall time of 5 steps against the median of
5 samples (`ProbeSampler.sample`: the gathered rows, then the cell-grid force) and, with
`--dense`, one sample by the dense body x fluid pair sum (the sampler before the cell grid).
Prints one JSON object. Results: BENCHMARKS.md §10.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.0108)
    ap.add_argument("--body", choices=("wall", "column"), default="wall")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--dense", action="store_true")
    a = ap.parse_args(argv)
    import numba
    from sphgraph.probes import ProbeSampler
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    scene = Scene.from_toml(ROOT / "examples" / "yeh_petroff.toml").with_overrides(dp=a.dp)
    if a.body == "column":
        lo, hi = np.array([0.9, 0.245, 0.0]), np.array([1.02, 0.365, 0.75])
    else:   # the wall at x = 0 and its layer, the whole width and height
        lo, hi = np.array([-0.05, -0.05, -0.05]), np.array([0.0, 0.66, 0.75])
    spec = {"interval": 0.0, "points": [], "heights": [], "force_interval": 0.0, "bodies": [(a.body, lo, hi)]}
    sampler = ProbeSampler(scene, spec)
    sim = Simulation(scene)
    for _ in range(a.steps):
        sim.step()
    steps, samples = [], []
    for _ in range(5):
        t0 = time.perf_counter()
        sim.step()
        steps.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        sampler.sample(sim)
        samples.append(time.perf_counter() - t0)
    out = {"dp": a.dp, "particles": sim.n_total, "threads": numba.config.NUMBA_NUM_THREADS,
           "step_s": float(np.median(steps)), "sample_s": float(np.median(samples)),
           "body": a.body, "body_particles": int(np.all((sim.frame_arrays()["position"] >= lo - 1e-9)
                                                          & (sim.frame_arrays()["position"] <= hi + 1e-9), axis=1).sum()),
           "force_N": sampler.rows["forces"][-1][a.body].tolist()}
    if a.dense:
        sys.path.insert(0, str(ROOT / "tests"))
        from test_probe_forces import dense_force
        t0 = time.perf_counter()
        ref = dense_force(sampler, lo, hi, sim.frame_arrays())
        out["dense_sample_s"] = time.perf_counter() - t0
        out["dense_force_N"] = ref.tolist()
    out["sample_over_step"] = out["sample_s"] / out["step_s"]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
