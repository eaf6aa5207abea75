"""Riemann-solver pressure term (issue 22 §3): `[physics] riemann = "zhang2017"` (Zhang, Hu &
Adams 2017), numba-cpu: the pair function's properties, the kernel against a direct O(N^2)
sum written from the formulas in `sphgraph.physics.interact`, still water, and the keys."""
from __future__ import annotations

import numpy as np
import pytest

from riemann_direct import interior_forces, pair_geometry, still_tank
from sphgraph import InputError, Scene, Simulation
from sphgraph.config import K_WENDLAND, P_C0, P_RHO0C0, P_RIEMANN_ETA


def still(riemann="zhang2017", integrator="symplectic", jitter=0.0, boundary="dbc", riemann_wall="skip"):
    return still_tank(jitter, riemann=riemann, integrator=integrator, boundary=boundary, riemann_wall=riemann_wall)


def _pair(prm, ra, rb, va, vb, rho_a, rho_b, pa, pb, m=1.0):
    from sphgraph.physics.interact import riemann_pair
    d = ra - rb
    dv = va - vb
    return np.array(riemann_pair(d[0], d[1], 0.0, float(d @ d), dv[0], dv[1], 0.0, vb[0], vb[1], 0.0, rho_a,
                                 1.0 / rho_a, rho_b,
                                 pa, pb, m, False, False, prm, K_WENDLAND, False))


def test_pair_conserves_momentum_and_the_limiter_acts_in_compression_only():
    from sphgraph.physics.kernels import grad_factor
    prm = still().constants.prm
    dp = 0.04
    ra, rb = np.array([0.0, 0.0]), np.array([0.9 * dp, 0.3 * dp])
    rab = ra - rb
    r = float(np.linalg.norm(rab))
    e = rab / r
    F = grad_factor(r * r, prm, K_WENDLAND)
    rho_a, rho_b, pa, pb = 1003.0, 998.0, 450.0, -120.0

    def expected(va, vb, beta):
        du = -float((va - vb) @ rab) / r                      # U_L - U_R
        acc = -(pa + pb + prm[P_RHO0C0] * beta * du) / (rho_a * rho_b) * F * rab
        ar = rho_a / rho_b * F * (float((va - vb) @ rab) + r * (pa - pb) / prm[P_RHO0C0])
        return acc, ar

    cases = {"receding": (0.2 * e, -0.2 * e, 0.0),
             "compressed, below the cap": (-0.01 * e, 0.01 * e, prm[P_RIEMANN_ETA] * 0.02 / prm[P_C0]),
             "compressed, capped": (-10.0 * e, 10.0 * e, 1.0)}
    for name, (va, vb, beta) in cases.items():
        got = _pair(prm, ra, rb, va, vb, rho_a, rho_b, pa, pb)
        acc, ar = expected(va, vb, beta)
        np.testing.assert_allclose(got[:2], acc, rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(got[3] + got[4], ar, rtol=1e-12, err_msg=name)   # ar + the U* jump
        assert got[5] == 0                                    # a fluid b cancels nothing
        # momentum: equal masses, so a_a = -a_b (P* is the same from either side)
        back = _pair(prm, rb, ra, vb, va, rho_b, rho_a, pb, pa)
        np.testing.assert_allclose(back[:2], -got[:2], rtol=1e-12, err_msg=name)


@pytest.mark.parametrize("boundary,wall", [("dbc", "skip"), ("mdbc", "skip"), ("mdbc", "cancel")])
def test_kernel_against_a_direct_sum(boundary, wall):
    """The part's sums: continuity (ar) and the U* jump (ddt) apart; with riemann_wall = "cancel"
    a row with a boundary neighbour is marked to cancel its jump, and the reduction drops it."""
    c, st, buf = interior_forces(still(jitter=0.1, boundary=boundary, riemann_wall=wall))
    p = st.particles
    k = st.consts
    prm = k.prm
    d, r2, r, near, F = pair_geometry(st)
    v = p.vel
    dv = v[:, None, :] - v[None, :, :]
    dot = (dv * d).sum(-1)
    rs = np.where(near, r, 1.0)
    du = -dot / rs                                      # U_L - U_R
    P = st.press
    m = k.mass_fluid
    beta = np.minimum(prm[P_RIEMANN_ETA] * np.maximum(du, 0.0) / prm[P_C0], 1.0)
    p2 = P[:, None] + P[None, :] + prm[P_RHO0C0] * beta * du
    coef = -m * p2 / (p.rho[:, None] * p.rho[None, :]) * F
    acc = (coef[:, :, None] * d).sum(1)
    fl = p.kind == 0
    jump = r * (P[:, None] - P[None, :]) / prm[P_RHO0C0] * fl[None, :]   # none towards a wall
    ar = (m * p.rho[:, None] * F * dot / p.rho[None, :]).sum(1)
    ddt = (m * p.rho[:, None] * F * jump / p.rho[None, :]).sum(1)
    bound = ~fl
    ar_b = (m * p.rho[:, None] * F * dot / p.rho[None, :] * fl[None, :]).sum(1)   # DBC rows: fluid continuity
    np.testing.assert_allclose(buf.ace[fl], acc[fl], rtol=1e-9, atol=1e-9 * np.abs(acc[fl]).max())
    np.testing.assert_allclose(buf.ar[fl], ar[fl], rtol=1e-9, atol=1e-9 * np.abs(ar[fl]).max())
    np.testing.assert_allclose(buf.ddt[fl], ddt[fl], rtol=1e-9, atol=1e-9 * np.abs(ddt[fl]).max())
    np.testing.assert_allclose(buf.ar[bound], ar_b[bound], rtol=1e-9, atol=1e-9 * np.abs(ar_b).max())
    walled = fl & (near & bound[None, :]).any(1)
    assert walled.any() and (fl & ~walled).any()
    if wall == "skip":
        assert not buf.cancel.any()
        cut = np.zeros_like(walled)
    else:                                    # a wall in reach cancels the row's jump
        np.testing.assert_array_equal(buf.cancel[fl] != 0, walled[fl])
        cut = walled
    st.reduced_stage = None                  # reduce this evaluation, not the last step's
    c.reduce_forces(st, 0)
    want = ar + np.where(cut, 0.0, ddt)
    np.testing.assert_allclose(st.ar[fl], want[fl], rtol=1e-9, atol=1e-9 * np.abs(want[fl]).max())


def test_still_water_stays_at_rest():
    sim = Simulation(still(), invariants=False)
    for _ in range(300):
        sim.step()
    p = sim.contexts[0].state.particles
    fl = p.kind == 0
    # measured: 0.013 m/s and densities 1000.2-1002.4 kg/m^3 after 300 steps
    assert np.abs(p.vel[fl]).max() < 0.05
    assert np.abs(p.rho[fl] - 1001.0).max() < 5.0


def test_keys():
    with pytest.raises(InputError, match="physics.riemann"):
        still(riemann="hllc")
    with pytest.raises(InputError, match=r'physics.riemann.*integrator = "symplectic"'):
        still(integrator="verlet")
    with pytest.raises(InputError, match="physics.riemann_wall"):
        still(riemann_wall="mirror")
    with pytest.raises(InputError, match=r'physics.riemann_wall.*riemann = "zhang2017"'):
        still(riemann="none", riemann_wall="cancel")
    with pytest.raises(InputError, match="physics.riemann_eta"):
        d = still().to_dict()
        d["physics"]["riemann_eta"] = -1.0
        Scene.from_dict(d)
    # no diffusion term with the Riemann term (its U* carries the density dissipation)
    from sphgraph.config import D_NONE, O_DDT
    assert still().constants.opt[O_DDT] == D_NONE


def test_a_cancelling_wall_holds_the_jet_that_passes_an_mdbc_wall():
    """The penetration map's slab at 20 m/s onto four mDBC layers (dp 0.02, as
    benchmarks/riemann_wall_jet.py at a coarser dp): with the Riemann term and the wall adding no
    jump ("skip") fluid gets through (measured: 15 of 231); with the wall cancelling the rows'
    jump ("cancel") none does, as without the Riemann term."""
    from sphgraph.stability import penetration_map
    riemann = {"integrator": "symplectic", "riemann": "zhang2017", "riemann_eta": 0.3}
    skip = penetration_map([20.0], ["mdbc-4"], dp=0.02, physics=riemann)[0]
    cancel = penetration_map([20.0], ["mdbc-4"], dp=0.02, physics=dict(riemann, riemann_wall="cancel"))[0]
    assert skip["through"] > 0 and skip["verdict"] == "penetration"
    assert cancel["through"] == 0 and cancel["verdict"] == "stable"
