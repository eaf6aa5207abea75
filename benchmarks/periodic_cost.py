"""What a periodic axis costs a step, against the same water closed by walls: a 3D channel
(water 0.2 m deep in L x W = 1.0 x 0.3 m, 3-layer floor and side walls), driven along x by a
body force of 0.5 m/s^2. `periodic`: x periodic (images and wrapping, `sphgraph.periodic`);
`walls`: end walls at x = 0 and L instead. Median seconds a step of 5 blocks after the
warm-up, and the bytes the device sent to the host a step, by kind (the periodic images'
rows: `images`).

    python benchmarks/periodic_cost.py [--dp 0.004] [--backend numba-cuda] [--precision float32]
                                       [--steps 30] [--warmup 10] [--boundary dbc] [--orders 2]
                                       [--images device|host]
                                       [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

L, W, H = 1.0, 0.3, 0.2


def scene(dp, periodic, boundary):
    from sphgraph import Scene
    h = 0.5 * dp
    m = max(0.05, 4 * dp)      # room for 3 wall layers
    walls = [{"type": "wall", "min": [h, 0.0, 0.0], "max": [L - h, W, 0.0], "direction": "-", "layers": 3},
             {"type": "wall", "min": [h, 0.0, dp], "max": [L - h, 0.0, 0.35], "direction": "-", "layers": 3},
             {"type": "wall", "min": [h, W, dp], "max": [L - h, W, 0.35], "direction": "+", "layers": 3}]
    d = {"format": 1, "name": "channel", "dim": 3, "dp": dp, "end_time": 1.0,
         "domain": {"min": [0.0, -m, -m], "max": [L, W + m, 0.4], "origin": [h, 0.0, 0.0],
                    "exclude_outside": False},
         "physics": {"coefsound": 20.0, "gravity": [0.5, 0.0, -9.81], "boundary": boundary},
         "initial": {"hydrostatic": True},
         "fluid": [{"type": "box", "min": [h, dp, dp], "max": [L - h, W - dp, H]}],
         "boundary": walls}
    if periodic:
        d["domain"]["periodic"] = ["x"]
    else:   # end walls where the period closed the channel, the domain widened for them
        d["domain"]["min"][0], d["domain"]["max"][0] = -m, L + m
        d["fluid"][0]["min"][0], d["fluid"][0]["max"][0] = h + 2 * dp, L - h - 2 * dp
        walls += [{"type": "wall", "min": [h, 0.0, 0.0], "max": [h, W, 0.35], "direction": "-", "layers": 3},
                  {"type": "wall", "min": [L - h, 0.0, 0.0], "max": [L - h, W, 0.35], "direction": "+", "layers": 3}]
    return Scene.from_dict(d, source=f"channel dp {dp}{' periodic' if periodic else ''}")


def host_images(backend):
    """`backend` (numba-cuda) making its periodic images on the host, as before
    backends/compute/cuda_images.py: the same-call baseline of `--images host`."""
    from sphgraph.backends.compute.base import ComputeBackend
    from sphgraph.registry import get
    base = get("compute", backend)

    class HostImages(base):
        periodic_images = ComputeBackend.periodic_images
    HostImages.name = base.name
    return HostImages


def seconds_a_step(sc, backend, precision, warmup, steps):
    from sphgraph.solver import Simulation
    sim = Simulation(sc, backend=backend, precision=precision, invariants=False)
    for _ in range(warmup):
        sim.step()
    st = sim.contexts[0].state
    before = dict(st.extra.get("bytes_by_kind", {}))
    first = sim.step_count
    blocks, per = [], max(1, steps // 5)
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(per):
            sim.step()
        blocks.append((time.perf_counter() - t0) / per)
    after = st.extra.get("bytes_by_kind", {})
    d2h = {k[4:]: (after[k] - before.get(k, 0)) / (5 * per) for k in after if k.startswith("d2h:")}
    # host seconds in each task kind (a device backend's tasks launch and return: the time
    # shows in the task that waits for the device)
    tasks = {k: round(1e3 * v / (5 * per), 4)
             for k, v in sorted(sim.scheduler.times.seconds_by_kind(first_step=first).items(), key=lambda kv: -kv[1])}
    return {"seconds_a_step": float(np.median(blocks)), "particles": sim.n_total, "fluid": sim.n_fluid,
            "d2h_bytes_a_step": d2h, "task_ms_a_step": tasks}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.004)
    ap.add_argument("--backend", default="numba-cuda")
    ap.add_argument("--precision")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--boundary", default="dbc")
    ap.add_argument("--images", choices=("device", "host"), default="device",
                    help="host: the periodic run's images made on the host (numba-cuda before cuda_images)")
    ap.add_argument("--orders", type=int, choices=(1, 2), default=2,
                    help="1: walls then periodic; 2: also periodic then walls (the ratio of the means)")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    out = {"dp": a.dp, "backend": a.backend, "precision": a.precision, "boundary": a.boundary, "images": a.images}
    # both orders (walls, periodic, periodic, walls): a run's place in the process moved
    # single timings of a GPU step by as much as the difference asked about
    runs = {"walls": [], "periodic": []}
    for name in ("walls", "periodic", "periodic", "walls")[:2 * a.orders]:
        be = host_images(a.backend) if name == "periodic" and a.images == "host" else a.backend
        r = seconds_a_step(scene(a.dp, name == "periodic", a.boundary), be, a.precision, a.warmup, a.steps)
        runs[name].append(r)
        print(name, json.dumps(r), flush=True)
    for name, rs in runs.items():
        out[name] = rs[0]
        out[name + "_seconds_a_step_each"] = [r["seconds_a_step"] for r in rs]
    out["periodic_over_walls"] = (float(np.mean(out["periodic_seconds_a_step_each"]))
                                  / float(np.mean(out["walls_seconds_a_step_each"])))
    print(json.dumps(out))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
