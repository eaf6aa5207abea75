"""Where the 2D surge front's lead over the experiments comes from: the front Z/a of the case
`dambreak` (DualSPHysics' formulation) sampled through T = 0.5-2.5, each experiment's point's
relative error, and the time lag dT = T_sim(Z_data) - T_data (negative: the run is there first).
Beside `sphgraph validate`'s front (the largest x of the fluid) it keeps a bulk front (the far
end of the last dp-wide x-bin holding >= 3 fluid rows), so that a few particles ahead of the
tongue would show as a difference between the two.

    python benchmarks/front_lag.py --dp 0.02 --json out.json

A constant lag is a late start (a release, e.g. a gate, that the model does not have); a lag
that grows with T is a front that runs faster. numba-cpu, float64.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

G = 9.81


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.02)
    ap.add_argument("--case", default="dambreak")
    ap.add_argument("--boundary", default="dbc")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from sphgraph.validation import load
    from sphgraph.validation.cases import _arrays, _sim, load_case, scene_for
    case = load_case(a.case)
    w = float(case.params["a"])
    scale = math.sqrt(2 * G / w)
    sim = _sim(scene_for(case, a.dp, {}, layers=case.params.get("layers")), "numba-cpu", "float64",
               boundary=a.boundary)
    t0 = time.perf_counter()
    T, zmax, zbulk = [], [], []
    while sim.time * scale < 2.6:
        sim.step()
        if sim.step_count % 10 == 0:
            arr = _arrays(sim)
            p = arr["position"][arr["kind"] == 0]
            cnt = np.bincount(np.floor(p[:, 0] / a.dp).astype(int))
            full = np.nonzero(cnt >= 3)[0]
            T.append(sim.time * scale)
            zmax.append(float(p[:, 0].max()) / w)
            zbulk.append((full.max() + 1) * a.dp / w)
    T, fronts = np.array(T), {"max-x": np.array(zmax), "bulk": np.array(zbulk)}
    out = {"case": a.case, "dp": a.dp, "boundary": a.boundary, "particles": sim.n_total,
           "steps": sim.step_count, "wall_s": time.perf_counter() - t0, "datasets": {}}
    for key, ds in case.reference["datasets"].items():
        d, _ = load(ds)
        d = d[(d[:, 0] >= 0.5) & (d[:, 0] <= 2.5)]
        row = {"T": d[:, 0].tolist()}
        for name, z in fronts.items():
            row[name] = {"rel_err": ((np.interp(d[:, 0], T, z) - d[:, 1]) / d[:, 1]).round(4).tolist(),
                         "lag_dT": (np.interp(d[:, 1], np.maximum.accumulate(z), T) - d[:, 0]).round(4).tolist()}
        out["datasets"][key] = row
        print(key, json.dumps(row), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
