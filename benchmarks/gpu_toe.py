"""GPU float32 against CPU float64: the 2D dam-break surge front (issue 6 req 4).

    python3 benchmarks/gpu_toe.py --dp 0.02 --json out.json

Runs the validation case `dambreak` (examples/dambreak2d.toml's formulation) on
numba-cuda in float32 and on numba-cpu in float64, on the same machine, recording
the surge front Z/a every 10 steps, and compares the two at the Martin & Moyce
(1952, a = 1.125 in) reference times inside the case's window (T = t sqrt(2g/a),
0.5-2.5): max |Z_gpu - Z_cpu| / Z_cpu, target <= 0.5 %. Also each run's error
against the experiment, so the float32 difference can be set against the model's.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def front(backend, precision, dp):
    from sphgraph.validation import load, surge_front
    from sphgraph.validation.cases import _sim, load_case, scene_for
    case = load_case("dambreak")
    a = float(case.params["a"])
    scale = math.sqrt(2 * 9.81 / a)
    sim = _sim(scene_for(case, dp, {}), backend, precision)
    T, Z = [0.0], [1.0]
    t0 = time.perf_counter()
    while sim.time * scale < 2.6:
        sim.step()
        if sim.step_count % 10 == 0:
            f = sim.frame_arrays()
            T.append(sim.time * scale)
            Z.append(surge_front(f["position"], f["kind"], a))
    ref, _ = load(case.reference["datasets"]["mm1"])
    return np.array(T), np.array(Z), ref, {"steps": sim.step_count, "wall_s": time.perf_counter() - t0,
                                           "particles": sim.n_total}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--dp", type=float, default=0.02)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    Tg, Zg, ref, ig = front("numba-cuda", "float32", a.dp)
    Tc, Zc, _, ic = front("numba-cpu", "float64", a.dp)
    w = ref[(ref[:, 0] >= 0.5) & (ref[:, 0] <= 2.5)]
    zg, zc = np.interp(w[:, 0], Tg, Zg), np.interp(w[:, 0], Tc, Zc)
    d = np.abs(zg - zc) / zc
    out = {"dp": a.dp, "T": w[:, 0].tolist(), "front_gpu_f32": zg.tolist(), "front_cpu_f64": zc.tolist(),
           "max_rel_diff": float(d.max()), "mean_rel_diff": float(d.mean()),
           "gpu_vs_mm1_mean": float(((zg - w[:, 1]) / w[:, 1]).mean()),
           "cpu_vs_mm1_mean": float(((zc - w[:, 1]) / w[:, 1]).mean()),
           "gpu": ig, "cpu": ic, "target": 0.005, "pass": bool(d.max() <= 0.005),
           "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    print(json.dumps(out))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
