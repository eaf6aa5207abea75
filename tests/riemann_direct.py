"""What tests/test_riemann.py and tests/test_riemann_jump.py share: a still 2D tank with the Riemann
term's keys, the interior part of a step's force evaluation, and the all-pairs geometry (numpy,
O(N^2)) that the kernels' sums are checked against."""
from __future__ import annotations

import numpy as np

from sphgraph import Scene, Simulation
from sphgraph.config import P_BW


def still_tank(jitter=0.0, **physics) -> Scene:
    """Hydrostatic water 1.6 x 0.4 m in a tank of three wall layers, dp 0.04; `physics` on top of
    `riemann = "zhang2017"` under Symplectic."""
    return Scene.from_dict({
        "format": 1, "dim": 2, "dp": 0.04, "end_time": 1.0,
        "domain": {"min": [-0.2, -0.2], "max": [1.8, 0.8], "origin": [0.0, 0.0], "exclude_outside": False},
        "physics": dict({"riemann": "zhang2017", "integrator": "symplectic"}, **physics),
        "initial": {"hydrostatic": True, "jitter": jitter},
        "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [1.6, 0.4]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.6, 0.6], "layers": 3}]})


def interior_forces(scene: Scene, steps: int = 3):
    """A one-rank run `steps` steps in (the state is no longer the lattice), then the interior part's
    force sums on fresh cells: (compute backend, state, the interior part's buffers)."""
    sim = Simulation(scene, invariants=False)
    for _ in range(steps):
        sim.step()
    st = sim.contexts[0].state
    c = sim.compute
    c.build_cells(st)
    c.forces(st, "interior")
    return c, st, st.parts["interior"]


def pair_geometry(st):
    """d[a, b] = r_a - r_b, r2, r, `near` (0 < r <= 2h) and the kernel's gradient factor F (zero
    outside `near`), for every pair of the state's rows."""
    from sphgraph.probes import grad_factor
    k = st.consts
    d = st.particles.pos[:, None, :] - st.particles.pos[None, :, :]
    r2 = (d * d).sum(-1)
    r = np.sqrt(r2)
    near = (r2 <= 4 * k.h ** 2) & (r2 >= 1e-18)
    F = np.where(near, grad_factor(r, k.h, float(k.prm[P_BW]), "wendland"), 0.0)
    return d, r2, r, near, F
