"""Cost of one `[forces]` sample against one step (issue 22 §5), numba-cpu or numba-cuda.

  python benchmarks/force_sample_cost.py [--dp 0.0108] [--steps 30] [--body wall|column]
      [--backend numba-cpu|numba-cuda] [--precision float32|float64] [--probes] [--dense]

examples/yeh_petroff.toml at `--dp` (0.0108: ~100 k particles; 0.0045: ~1 M); the body is the
tank's back wall behind the water (`wall`, wetted from the start: the sample's full cost) or
the column (dry until the surge arrives at t ~ 0.4 s); `--probes` also times a sample of two
point probes and a height column (`probes_sample_s`). After `--steps` steps, the median wall
time of `--repeat` steps against the median of as many samples (`ProbeSampler.sample`: each rank's partial sums from
its own rows, `ComputeBackend.probe_sums`, as the run's `probes` task takes them; on
numba-cuda on the device) and, with `--dense`, one sample by the dense body x fluid pair sum
(the sampler before the cell grid). Prints one JSON object; `on_device`: the sample took the
device path (no host copy of the rows). Results: BENCHMARKS.md §10.
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
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--backend", choices=("numba-cpu", "numba-cuda"), default="numba-cpu")
    ap.add_argument("--precision", choices=("float32", "float64"), default=None,
                    help="default: the backend's (numba-cpu float64, numba-cuda float32)")
    ap.add_argument("--probes", action="store_true", help="also time a sample of two point probes and a height column")
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
    probes = None
    if a.probes:    # a second sampler: two point probes (at the wall, at the column) and a height column
        probes = ProbeSampler(scene, {"interval": 0.0, "force_interval": 0.0, "bodies": [],
                                      "points": [("P_wall", np.array([0.01, 0.3, 0.05])),
                                                 ("P_col", np.array([0.88, 0.3, 0.05]))],
                                      "heights": [("H", np.array([0.3, 0.3]))]})
    t0 = time.perf_counter()
    sim = Simulation(scene, backend=a.backend, precision=a.precision)
    setup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(a.steps):
        sim.step()
    warm_s = time.perf_counter() - t0
    for s in (sampler, probes):     # the first: compiles the sample's kernels
        if s is not None:
            s.sample(sim)
    host0 = sum(c.state.extra.get("bytes_by_kind", {}).get("d2h:sync_host", 0) for c in sim.contexts)
    steps, samples, psamples = [], [], []
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        sim.step()
        steps.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        sampler.sample(sim)
        samples.append(time.perf_counter() - t0)
        if probes is not None:
            t0 = time.perf_counter()
            probes.sample(sim)
            psamples.append(time.perf_counter() - t0)
    by = [c.state.extra.get("bytes_by_kind", {}) for c in sim.contexts]
    host1 = sum(b.get("d2h:sync_host", 0) for b in by)
    out = {"dp": a.dp, "particles": sim.n_total, "backend": a.backend, "precision": sim.precision,
           "device": sim.compute.device_name(), "threads": numba.config.NUMBA_NUM_THREADS,
           "step_s": float(np.median(steps)), "sample_s": float(np.median(samples)),
           "steps_s": steps, "samples_s": samples, "setup_s": setup_s, "warmup_steps_s": warm_s,
           "on_device": a.backend == "numba-cuda" and host1 == host0 and sum(b.get("d2h:probes", 0) for b in by) > 0,
           "body": a.body, "force_N": sampler.rows["forces"][-1][a.body].tolist()}
    if probes is not None:
        r = probes.rows["probes"][-1]
        out["probes_sample_s"] = float(np.median(psamples))
        out["probes_samples_s"] = psamples
        out["probes_over_step"] = out["probes_sample_s"] / out["step_s"]
        out["probes"] = {"P_wall": r["P_wall"]["pressure"], "P_col": r["P_col"]["pressure"], "H": r["H"]}
    f = sim.frame_arrays()
    out["body_particles"] = int(np.all((f["position"] >= lo - 1e-9) & (f["position"] <= hi + 1e-9), axis=1).sum())
    if a.dense:
        sys.path.insert(0, str(ROOT / "tests"))
        from test_probe_forces import dense_force
        t0 = time.perf_counter()
        ref = dense_force(sampler, lo, hi, f)
        out["dense_sample_s"] = time.perf_counter() - t0
        out["dense_force_N"] = ref.tolist()
    out["sample_over_step"] = out["sample_s"] / out["step_s"]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
