"""Body forces of `[forces]` (issue 22 §5): the sampler's cell-grid sum (the backend's `probe_sums`)
equals the dense sum over every (body, fluid) pair within 2h, the formula of `sphgraph.probes`, to
round-off."""
from __future__ import annotations

import numpy as np
import pytest

from sphgraph import Scene, Simulation
from sphgraph.probes import ProbeSampler, grad_factor


def dense_force(s, lo, hi, a):
    """The sampler before the cell grid: the body rows against the fluid rows in the body's box
    grown by 2h, in dense 256-row pair matrices,
    F = sum m_a m_b (P_a+P_b)/(rho_a rho_b) F_ab (r_a - r_b)."""
    fl = a["kind"] == 0
    tol = 1e-9 + 1e-6 * s.dp
    bpos, brho, bp = a["position"][~fl], a["density"][~fl], a["pressure"][~fl]
    inb = np.all((bpos >= lo - tol) & (bpos <= hi + tol), axis=1)
    bpos, brho, bp = bpos[inb], brho[inb], bp[inb]
    reach = 2.0 * s.h
    fpos, frho, fp = a["position"][fl], a["density"][fl], a["pressure"][fl]
    near = np.all((fpos >= bpos.min(0) - reach) & (fpos <= bpos.max(0) + reach), axis=1)
    fpos, frho, fp = fpos[near], frho[near], fp[near]
    F = np.zeros(s.dim)
    for i0 in range(0, len(bpos), 256):
        b = slice(i0, i0 + 256)
        d = fpos[None, :, :] - bpos[b][:, None, :]
        r = np.sqrt((d * d).sum(-1))
        m = (r < reach) & (r > 1e-12)
        fac = np.where(m, grad_factor(r, s.h, s.bw, s.kernel), 0.0)
        coef = (fp[None, :] + bp[b][:, None]) / (frho[None, :] * brho[b][:, None]) * fac
        F += s.mass_f * s.mass_b * (coef[:, :, None] * d).sum((0, 1))
    return F


def column_scene(dim, kernel):
    if dim == 2:
        return Scene.from_dict({
            "format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
            "domain": {"min": [-0.1, -0.1], "max": [1.7, 0.8], "origin": [0.0, 0.0]},
            "physics": {"kernel": kernel},
            "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.4, 0.3]}],
            "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.6, 0.75], "layers": 2},
                         {"type": "box", "min": [0.2, 0.0], "max": [0.3, 0.2]}]}), ([0.2, 0.0], [0.3, 0.2])
    return Scene.from_dict({
        "format": 1, "dim": 3, "dp": 0.04, "end_time": 1.0,
        "domain": {"min": [-0.1, -0.1, -0.1], "max": [1.7, 0.7, 0.8], "origin": [0.0, 0.0, 0.0]},
        "physics": {"kernel": kernel},
        "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [0.4, 0.6, 0.3]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [1.6, 0.6, 0.75], "layers": 1},
                     {"type": "box", "min": [0.2, 0.2, 0.0], "max": [0.32, 0.36, 0.4], "fill": "surface",
                      "layers": 1, "open_bottom": True}]}), ([0.2, 0.2, 0.0], [0.32, 0.36, 0.4])


@pytest.mark.parametrize("dim, kernel", [(2, "wendland"), (2, "cubic"), (3, "wendland")])
def test_cell_grid_force_equals_the_dense_sum(dim, kernel):
    scene, (lo, hi) = column_scene(dim, kernel)
    sim = Simulation(scene)
    for _ in range(40):     # a column standing in the collapsing water
        sim.step()
    s = ProbeSampler(scene, {"interval": 0.0, "points": [], "heights": [], "force_interval": 0.0,
                             "bodies": [("col", np.array(lo), np.array(hi))]})
    s.sample(sim)
    got = s.rows["forces"][-1]["col"]
    ref = dense_force(s, np.array(lo), np.array(hi), sim.frame_arrays())
    assert np.abs(ref).max() > 0
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
