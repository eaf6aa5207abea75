"""Fluid through the wall: the Riemann pressure term on mDBC walls against each alone.

    python benchmarks/riemann_wall_jet.py [--dp 0.01] [--speeds 5,10,20] [--json FILE]

The penetration map's cells (`sphgraph.stability.penetration_map`: the slab of `jet_scene`,
0.4 x 0.2 m, c0 = 28 m/s, shot at a floor of `layers` boundary layers) for each wall model
without the Riemann term, with it (`riemann = "zhang2017"`, `riemann_eta = 0.3`) and with it and
`riemann_wall = "cancel"`, and with the jump renormalised (mDBC only), the Symplectic integrator every way: the most fluid particles seen below
the lowest boundary row at once, and the first step with any. SPHERIC test 2 stopped with the
Riemann term on mDBC walls (docs/validation.md); this isolates the combination on a case of
seconds.
"""
from __future__ import annotations

import argparse
import sys

RIEMANN = {"riemann": "zhang2017", "riemann_eta": 0.3}
# the Riemann arm: none, its default wall ("skip"), a wall cancelling the row's U* jump, the jump
# without its linear part (riemann_jump = "renormalised"; mDBC walls only: refused with DBC)
ARMS = {"none": {}, "skip": RIEMANN, "cancel": dict(RIEMANN, riemann_wall="cancel"),
        "renormalised": dict(RIEMANN, riemann_jump="renormalised"),
        "renormalised-cancel": dict(RIEMANN, riemann_jump="renormalised", riemann_wall="cancel")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.01)
    ap.add_argument("--speeds", default="5,10,20")
    ap.add_argument("--models", default="mdbc-4,mdbc-3,dbc-3")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from sphgraph.stability import penetration_map
    from sweep_rows import record
    rows = []
    for speed in (float(s) for s in a.speeds.split(",")):
        for m in a.models.split(","):
            for riemann, keys in ARMS.items():
                if riemann.startswith("renormalised") and m.startswith("dbc"):
                    continue
                physics = dict({"integrator": "symplectic"}, **keys)
                c = penetration_map([speed], [m], dp=a.dp, physics=physics)[0]
                record(rows, dict(speed=speed, model=m, riemann=riemann, dp=a.dp, through=c["through"],
                                  first_step=c["step"], steps=c["steps"], fluid=c["n_fluid"], verdict=c["verdict"]),
                       a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
