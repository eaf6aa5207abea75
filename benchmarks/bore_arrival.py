"""When does Yeh & Petroff's surge reach the column's face? The release in 2D (x-z, the tank's
1.6 m, the 0.4 x 0.3 m column of water, no square column), dry floor or the experiment's 1 cm
wet bed, at several dp: the front is the largest x of the fluid above z = 0.02 m (twice the
bed's depth, so the bed itself does not count), its arrival the first sample at x >= 0.9 m.

    python benchmarks/bore_arrival.py --dp 0.01 0.005 0.0025 --beds dry,wet --json out.json

What it answers (issue 22 §4): whether the 3D run's early force (the surge at the column some
0.07 s before the experiment's force rises, at t = 0.335 s in yeh_petroff_force.csv) comes from
the bed's resolution or depth. Physics as examples/yeh_petroff_wetbed.toml (Wendland, Verlet,
DuFort-Frankel diffusion step, the defaults otherwise); numba-cpu; one JSON line per run.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

FACE_X, ABOVE_Z, BED = 0.9, 0.02, 0.01   # m: the column's face, the front's height floor, the bed


def scene(dp: float, wet: bool) -> dict:
    return {"format": 1, "name": "yeh_petroff_2d", "dim": 2, "dp": dp, "end_time": 0.5,
            "domain": {"min": [-0.05, -0.05], "max": [1.65, 0.8], "origin": [0.0, 0.0]},
            "physics": {"kernel": "wendland", "integrator": "verlet", "diffusion_time": "dufort-frankel"},
            "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.4, 0.3]}]
                     + ([{"type": "box", "min": [0.4, 0.0], "max": [1.6, BED]}] if wet else []),
            "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.6, 0.75], "layers": 1}]}


def run(dp: float, wet: bool, precision: str, t_end: float = 0.45) -> dict:
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    from sphgraph.validation.cases import _arrays
    sim = Simulation(Scene.from_dict(scene(dp, wet), source="bore_arrival"), backend="numba-cpu",
                     precision=precision)
    t0 = time.perf_counter()
    ts, xs = [], []
    while sim.time < t_end:
        sim.step()
        if sim.step_count % 20 == 0:
            arr = _arrays(sim)
            pos = arr["position"][arr["kind"] == 0]
            ts.append(float(sim.time))
            xs.append(float(pos[pos[:, 1] > ABOVE_Z, 0].max()))
    ts, xs = np.array(ts), np.array(xs)
    hit = ts[np.argmax(xs >= FACE_X)] if (xs >= FACE_X).any() else None
    return {"dp": dp, "bed": "wet" if wet else "dry", "precision": precision, "particles": sim.n_total,
            "steps": sim.step_count, "wall_s": time.perf_counter() - t0, "arrival_s": hit,
            "front_x": {f"{t:g}": float(np.interp(t, ts, xs)) for t in (0.1, 0.15, 0.2, 0.25, 0.3)}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, nargs="+", default=[0.01, 0.005])
    ap.add_argument("--beds", default="dry,wet")
    ap.add_argument("--precision", default="float64")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    rows = []
    for dp in a.dp:
        for bed in a.beds.split(","):
            rows.append(run(dp, bed == "wet", a.precision))
            print(json.dumps(rows[-1]), flush=True)
            if a.json:
                with open(a.json, "w") as f:
                    json.dump(rows, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
