"""Fluid through the wall: the Riemann pressure term on mDBC walls against each alone.

    python benchmarks/riemann_wall_jet.py [--dp 0.01] [--speeds 5,10,20] [--json FILE]

The slab of `sphgraph.stability.jet_scene` (0.4 x 0.2 m, c0 = 28 m/s) shot at a floor of
`layers` boundary layers, as the penetration map (`sphgraph plot stability --map penetration`)
does, for each wall model with and without `riemann = "zhang2017"` (`riemann_eta = 0.3`, the
Symplectic integrator both ways): the most fluid particles seen below the lowest boundary row
at once, and the first step with any. SPHERIC test 2 stopped with the Riemann term on mDBC
walls (docs/validation.md); this isolates the combination on a case of seconds.
"""
from __future__ import annotations

import argparse
import json
import sys

MODELS = {"mdbc-4": ("mdbc", 4), "mdbc-3": ("mdbc", 3), "dbc-3": ("dbc", 3)}


def run(dp, speed, boundary, layers, riemann) -> dict:
    from sphgraph.solver import Simulation
    from sphgraph.stability import beyond_wall, jet_scene, outer_wall, set_jet_velocity
    ov = {"integrator": "symplectic"}
    if riemann:
        ov.update(riemann="zhang2017", riemann_eta=0.3)
    sc = jet_scene(dp=dp, speed=speed, layers=layers, boundary=boundary, end_time=0.3 / speed).with_overrides(**ov)
    sim = Simulation(sc, backend="numba-cpu")
    set_jet_velocity(sim, speed)
    wall = (1, outer_wall(sim), -1)
    worst, first = 0, None
    while sim.time < sc.end_time:
        sim.step()
        n = beyond_wall(sim, wall)
        if n and first is None:
            first = sim.step_count
        worst = max(worst, n)
    return {"through": worst, "first_step": first, "steps": sim.step_count, "fluid": sim.n_fluid}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.01)
    ap.add_argument("--speeds", default="5,10,20")
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    rows = []
    for speed in (float(s) for s in a.speeds.split(",")):
        for m in a.models.split(","):
            for riemann in (False, True):
                r = dict(speed=speed, model=m, riemann=riemann, dp=a.dp, **run(a.dp, speed, *MODELS[m], riemann))
                rows.append(r)
                print(json.dumps(r), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
