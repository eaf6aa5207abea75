"""A validation case at another size: the experiments' own columns (centimetres) instead of the
case's 1 m one.

An inviscid, Froude-scaled run gives the same Z(T) at any size, so the cases are written at
a = 1 m; viscosity does not scale that way. Water's laminar viscosity acts on the surge's thin tip
as a Reynolds number sqrt(g a) a / nu, which is about 200 times smaller in Martin & Moyce's
1.125 in column than at 1 m. A run that carries the experiment's viscosity must therefore also
carry its size: :func:`at_size` scales every length of the case's scene (domain, lattice origin,
fluid and boundary boxes) and the case's length parameters together, leaving the dimensionless
physics keys (coefh, coefsound, alpha, delta) as they are, so that with no viscosity the scaled
run is the same run in other units.
"""
from __future__ import annotations

import copy
import dataclasses

#: the runners whose case parameters hold one length, the column width `a`, and give times as
#: T = t sqrt(2g/a): the only cases whose every input this module knows how to scale
RUNNERS = ("surge_front",)


def _scaled(v, s):
    return [float(x) * s for x in v]


def at_size(case, a: float):
    """`case` with its column width parameter `a` set to `a` metres and every length of its scene
    scaled by a / case.params["a"] (times by the square root, as Froude scaling does)."""
    if case.runner not in RUNNERS:
        raise ValueError(f"at_size: case {case.name!r} (runner {case.runner!r}) is not one of {RUNNERS}")
    s = float(a) / float(case.params["a"])
    d = copy.deepcopy(case.scene)
    d["dp"] = float(d["dp"]) * s
    d["end_time"] = float(d["end_time"]) * s ** 0.5
    dom = dict(d["domain"])
    for k in ("min", "max", "origin"):
        if k in dom:
            dom[k] = _scaled(dom[k], s)
    d["domain"] = dom
    for group in ("fluid", "boundary"):
        d[group] = [dict(b, min=_scaled(b["min"], s), max=_scaled(b["max"], s)) for b in d.get(group, [])]
    params = dict(case.params, a=float(a))
    return dataclasses.replace(case, scene=d, params=params, dp=float(case.dp) * s)
