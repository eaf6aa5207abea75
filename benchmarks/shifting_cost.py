"""Particle shifting on the 2D dam break: its cost and its effect (docs/features.md).

Runs examples/dambreak2d.toml once per shifting setting, the runs interleaved in chunks of
simulated time so that a loaded machine slows them alike, and reports per setting:
steps/s (first step, the compile, left out), the surge front Z/a against Koshizuka & Oka
1996 and Martin & Moyce 1952 (the `dambreak` validation case's window T = 0.5-2.5,
T = t sqrt(2g/a)), the interior pressure noise (sphgraph.stability.pressure_noise,
relative to rho0 g 2a) and the spread (std/mean) of fluid nearest-neighbour distances
at the end.

    python benchmarks/shifting_cost.py --dp 0.02 --T-end 2.6
    python benchmarks/shifting_cost.py --backend numba-cuda --precision float32 --dp 0.01
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

from sphgraph import Scene, Simulation
from sphgraph.stability import _cells, _neighbours, pressure_noise
from sphgraph.validation import load, surge_front

EXAMPLE = os.path.join(os.path.dirname(__file__), "..", "examples", "dambreak2d.toml")
DATA = {"ko": "koshizuka_oka_1996_experiment", "mm1": "martin_moyce_1952_a1.125in",
        "mm2": "martin_moyce_1952_a2.25in"}
A, G = 1.0, 9.81


def backend_class(name):
    """numba-cuda with the shifting methods (cuda_shifting.CudaShifting) even before
    numba_cuda.NumbaCUDA inherits them."""
    if name != "numba-cuda":
        return name
    from sphgraph.backends.compute.cuda_shifting import CudaShifting
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA
    return NumbaCUDA if issubclass(NumbaCUDA, CudaShifting) else type("NumbaCUDA", (CudaShifting, NumbaCUDA), {})


def nn_spread(sim) -> float:
    """std/mean of each fluid particle's nearest fluid neighbour distance."""
    a = sim.frame_arrays()
    pos = a["position"][a["kind"] == 0]
    cell = _cells(pos, 2.0 * sim.scene.dp)
    d = np.empty(len(pos))
    for i in range(len(pos)):
        j = _neighbours(cell, pos, i, 2.0 * sim.scene.dp)
        d[i] = np.sqrt(((pos[j] - pos[i]) ** 2).sum(1)).min() if len(j) else np.nan
    d = d[np.isfinite(d)]
    return float(d.std() / d.mean())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.02)
    ap.add_argument("--T-end", type=float, default=2.6, help="end, in T = t sqrt(2g/a)")
    ap.add_argument("--settings", default="none,full:1.5,nobound:1.5",
                    help="comma-separated MODE[:TFS] (physics.shifting, physics.shifting_tfs)")
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", default=None)
    ap.add_argument("--chunk", type=float, default=0.02, help="simulated seconds per interleaved chunk")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args(argv)
    base = Scene.from_toml(EXAMPLE)
    scale = math.sqrt(2 * G / A)
    t_end = args.T_end / scale
    runs = {}
    for s in args.settings.split(","):
        mode, _, tfs = s.partition(":")
        sc = base.with_overrides(dp=args.dp, end_time=t_end, shifting=mode, shifting_tfs=float(tfs or 0.0))
        sim = Simulation(sc, backend=backend_class(args.backend), precision=args.precision)
        t0 = time.perf_counter()
        sim.step()                                     # compiles
        runs[s] = {"sim": sim, "compile_s": time.perf_counter() - t0, "wall": 0.0, "steps0": sim.step_count,
                   "T": [sim.time * scale], "Z": [surge_front(*_front(sim), A)]}
    t = 0.0
    while t < t_end:
        t = min(t + args.chunk, t_end)
        for r in runs.values():
            sim = r["sim"]
            t0 = time.perf_counter()
            while sim.time < t:
                sim.step()
            r["wall"] += time.perf_counter() - t0
            r["T"].append(sim.time * scale)
            r["Z"].append(surge_front(*_front(sim), A))
    out = {"dp": args.dp, "backend": args.backend, "particles": None, "T_end": args.T_end, "settings": {}}
    for s, r in runs.items():
        sim = r["sim"]
        out["particles"] = sim.n_total
        steps = sim.step_count - r["steps0"]
        res = {"steps": sim.step_count, "steps_per_s": steps / r["wall"], "wall_s": r["wall"],
               "compile_s": r["compile_s"]}
        T, Z = np.array(r["T"]), np.array(r["Z"])
        for key, name in DATA.items():
            data, _ = load(name)
            w = data[(data[:, 0] >= 0.5) & (data[:, 0] <= 2.5)]
            e = (np.interp(w[:, 0], T, Z) - w[:, 1]) / w[:, 1]
            res[f"front_mean_rel_err_{key}"] = float(e.mean())
        res["Z_at_T2"] = float(np.interp(2.0, T, Z))
        if args.backend == "numba-cpu":   # host pressures of the CPU state
            res["pressure_noise"] = pressure_noise(sim, sim.scene.physics.rho0 * G * 2 * A)
        res["nn_spread"] = nn_spread(sim)
        out["settings"][s] = res
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


def _front(sim):
    a = sim.frame_arrays()
    return a["position"], a["kind"]


if __name__ == "__main__":
    main()
