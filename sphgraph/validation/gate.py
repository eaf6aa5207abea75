"""A lifted gate added to a validation case's scene: the release of a dam break as a moving
boundary (`[[motion]] type = "gate"`), for studies of how the release shapes the surge.

The gate is two boundary rows against the column's face, across the tank's width, from one row
above the floor to a tenth of the column's height above it, lifted at a constant speed from
t = 0 by its own height (so its lowest row clears the column). Speeds are given as
c = V / sqrt(g h0) with h0 the column's height, the Froude scaling that carries a speed between
columns of different size; Lauber & Hager's criterion for a release that counts as instantaneous,
t_op <= sqrt(2 h0 / g) for the gate to travel h0 (Lauber & Hager 1998, J. Hydraulic Res.
36(3):291-307), reads c >= 1/sqrt(2) in these units.

No example or case carries a gate: the experiments' gate speeds are not stated in the sources at
hand, and a speed chosen to fit the data would not be the experiment's (docs/validation.md).
"""
from __future__ import annotations

import copy
import dataclasses
import math

G = 9.81


def with_gate(case, dp: float, face_x: float, h0: float, c: float):
    """`case` with a gate at the column face x = face_x (the fluid's last lattice row), lifted at
    c sqrt(g h0) from t = 0; the domain raised to hold the lifted gate."""
    d = copy.deepcopy(case.scene)
    dim = int(d["dim"])
    tank = next(b for b in d["boundary"] if b["type"] == "tank")
    top = 1.1 * h0
    # across the width, from the lattice row inside one side wall to the row inside the other
    # (the walls' rows are the nodes nearest their planes, as the lattice places them)
    side = [(math.floor(tank["min"][1] / dp + 0.5) + 1) * dp, (math.floor(tank["max"][1] / dp + 0.5) - 1) * dp]
    lo = [face_x + dp] + ([side[0]] if dim == 3 else []) + [dp]
    hi = [face_x + 2 * dp] + ([side[1]] if dim == 3 else []) + [top]
    d["boundary"] = list(d["boundary"]) + [{"type": "box", "name": "gate", "min": lo, "max": hi}]
    d["motion"] = list(d.get("motion", [])) + [
        {"body": "gate", "type": "gate", "speed": c * math.sqrt(G * h0), "lift": top, "start": 0.0}]
    dmax = list(d["domain"]["max"])
    dmax[-1] = max(dmax[-1], 2 * top + 4 * dp)
    d["domain"] = dict(d["domain"], max=dmax)
    return dataclasses.replace(case, scene=d)


def opening_time(h0: float, c: float) -> float:
    """Seconds the gate takes to travel the column's height h0 at c sqrt(g h0)."""
    return h0 / (c * math.sqrt(G * h0))
