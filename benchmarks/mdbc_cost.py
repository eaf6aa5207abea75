"""Cost of mDBC against DBC per step (issue 22 §2), one rank, on any backend.

  python benchmarks/mdbc_cost.py [--scene examples/dambreak_wall2d.toml] [--dp 0.0025]
                                 [--backend numba-cuda] [--precision float32] [--steps 50] [--warmup 20]
                                 [--boundaries dbc,mdbc]

The scene (2D by default: examples/dambreak_wall2d.toml, 3 boundary layers; `--dp` refines it)
is run with `[physics] boundary` = "dbc", "mdbc" and "mdbc-noslip"; after `--warmup` steps, the
median wall time of 5 blocks of `--steps` / 5 steps each. Prints one JSON object (seconds a
step by boundary, the mDBC share of the step). Results: BENCHMARKS.md §10.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def seconds_a_step(scene, backend, precision, warmup, steps):
    from sphgraph.solver import Simulation
    sim = Simulation(scene, backend=backend, precision=precision, invariants=False)
    for _ in range(warmup):
        sim.step()
    blocks = []
    per = max(1, steps // 5)
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(per):
            sim.step()
        blocks.append((time.perf_counter() - t0) / per)
    return float(np.median(blocks)), sim.n_total, sim.n_fluid


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "dambreak_wall2d.toml"))
    ap.add_argument("--dp", type=float)
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision")
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--boundaries", default="dbc,mdbc,mdbc-noslip",
                    help="comma-separated [physics] boundary values (a scene with [[motion]]: dbc,mdbc)")
    a = ap.parse_args(argv)
    from sphgraph.scene import Scene
    base = Scene.from_toml(a.scene).to_dict()
    if a.dp:
        base["dp"] = a.dp
    out = {"scene": a.scene, "backend": a.backend, "precision": a.precision, "seconds_a_step": {}}
    for b in a.boundaries.split(","):
        d = dict(base)
        d["physics"] = dict(base.get("physics", {}), boundary=b)
        d.setdefault("domain", {})["exclude_outside"] = False
        s, n, nf = seconds_a_step(Scene.from_dict(d, source=a.scene), a.backend, a.precision, a.warmup, a.steps)
        out["seconds_a_step"][b] = s
        out["particles"], out["fluid"] = n, nf
    t = out["seconds_a_step"]
    if "dbc" in t and "mdbc" in t:
        out["mdbc_share"] = (t["mdbc"] - t["dbc"]) / t["mdbc"]
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
