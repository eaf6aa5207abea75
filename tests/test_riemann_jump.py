"""The Riemann term's pressure jump with its linear part removed (`[physics] riemann_jump =
"renormalised"`, sphgraph.physics.riemann_jump), numba-cpu: the row's correction against its
formulas (a linear field loses its whole jump, on a half support too), the kernel and the
reduction against a direct O(N^2) sum, mock ranks against one rank, the wall it holds, the
keys. numba-cuda: tests/test_cuda_riemann_jump.py; real MPI: test_multirank's driver."""
from __future__ import annotations

import numpy as np
import pytest

from riemann_direct import interior_forces, pair_geometry, still_tank
from sphgraph import InputError, Scene, Simulation
from sphgraph.config import K_WENDLAND, P_RHO0C0


def still(jump="renormalised", boundary="mdbc", riemann="zhang2017", jitter=0.1, wall="skip"):
    return still_tank(jitter, riemann=riemann, boundary=boundary, riemann_jump=jump, riemann_wall=wall)


def _row_sums(prm, ra, pa, rbs, pbs, rho_a=1000.0, rho_b=1000.0, m=1.6):
    """The plain jump of row a over neighbours rbs (summed as riemann_pair's) and its correction."""
    from sphgraph.physics.kernels import grad_factor
    from sphgraph.physics.riemann_jump import jump_correction, jump_moments
    mom = np.zeros(12)
    plain = 0.0
    for rb, pb in zip(rbs, pbs):
        d = ra - rb
        r2 = float(d @ d)
        r = np.sqrt(r2)
        mom += np.array(jump_moments(d[0], d[1], 0.0, r2, r, rho_a, rho_b, pa, pb, m, prm, K_WENDLAND))
        plain += m * rho_a / rho_b * grad_factor(r2, prm, K_WENDLAND) * r * (pa - pb) / prm[P_RHO0C0]
    return plain, jump_correction(*mom, 2)


def test_a_linear_field_loses_its_jump_and_a_curved_one_keeps_the_rest():
    """A row on a flat wall (its fluid neighbours on one side: the plain jump is the first-order
    term that drains such rows) and a row in the bulk: the renormalised gradient is exact for a
    linear pressure, so the corrected jump is zero to round-off; a quadratic field keeps a jump of
    its curvature's size; a row with too few neighbours (a corner: det M below the bound) keeps the
    plain jump."""
    prm = still().constants.prm
    dp = 0.04
    rng = np.random.default_rng(3)
    grid = np.array([(i * dp, j * dp) for i in range(-4, 5) for j in range(-4, 5)], float)
    grid += rng.uniform(-0.1, 0.1, grid.shape) * dp
    ra = np.array([0.0, 0.0])
    near = lambda pts: pts[(((pts - ra) ** 2).sum(1) <= 4 * (1.2 * np.sqrt(2) * dp) ** 2)  # noqa: E731
                           & (((pts - ra) ** 2).sum(1) > 1e-18)]
    grad = np.array([350.0, -9810.0])
    for name, pts in (("bulk", near(grid)), ("on a wall", near(grid[grid[:, 1] >= 0.0]))):
        lin = 1000.0 + (pts - ra) @ grad
        plain, corr = _row_sums(prm, ra, 1000.0, pts, lin)
        assert abs(plain) > 1e-3, name
        assert abs(plain + corr) < 1e-9 * abs(plain), (name, plain, corr)
        curved = lin + 2.0e5 * ((pts - ra) ** 2).sum(1)
        plain_c, corr_c = _row_sums(prm, ra, 1000.0, pts, curved)
        assert abs(plain_c + corr_c) > 1e-3 * abs(plain), name
    corner = near(grid[(grid[:, 0] >= 0.0) & (grid[:, 1] >= 0.0)])
    plain, corr = _row_sums(prm, ra, 1000.0, corner, 1000.0 + (corner - ra) @ grad)
    assert corr == 0.0 and plain != 0.0


@pytest.mark.parametrize("wall", ["skip", "cancel"])
def test_kernel_and_reduction_against_a_direct_sum(wall):
    """The interior part's moments and the reduced continuity term against the formulas summed
    over all pairs (numpy, O(N^2)): ar + jump + (-grad P . S where det M > RJ_DET_MIN_2D); with
    "cancel" the jump and its correction dropped where a wall neighbour cancels the jump of a row
    whose gradient cannot be renormalised, kept where it can."""
    from sphgraph.physics.riemann_jump import RJ_DET_MIN_2D
    c, st, buf = interior_forces(still(wall=wall))
    p = st.particles
    k = st.consts
    prm = k.prm
    d, r2, r, near, F = pair_geometry(st)
    fl = p.kind == 0
    pair = near & fl[None, :]                          # moments: fluid neighbours only
    m, P, rho = k.mass_fluid, st.press, p.rho
    V = np.where(pair, m / rho[None, :] * F, 0.0)
    M = -np.einsum("ab,abi,abj->aij", V, d, d)
    g = np.einsum("ab,abi->ai", V * (P[None, :] - P[:, None]), d)
    S = np.einsum("ab,abi->ai", np.where(pair, m * rho[:, None] / rho[None, :] * F * r / prm[P_RHO0C0], 0.0), d)
    got = buf.jm
    for c_, want in enumerate([M[:, 0, 0], M[:, 0, 1], M[:, 1, 1], g[:, 0], g[:, 1], S[:, 0], S[:, 1]]):
        row = [0, 1, 3, 6, 7, 9, 10][c_]
        np.testing.assert_allclose(got[row][fl], want[fl], rtol=1e-9, atol=1e-9 * np.abs(want[fl]).max())
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] ** 2
    ok = fl & (det > RJ_DET_MIN_2D)
    assert ok.sum() > 0.5 * fl.sum() and (fl & ~ok).any()        # both branches are exercised
    gp = np.zeros((p.n, 2))
    gp[ok] = np.linalg.solve(M[ok][:, :2, :2], g[ok][:, :2, None])[..., 0]
    corr = -(gp * S[:, :2]).sum(1)
    st.reduced_stage = None
    c.reduce_forces(st, 0)
    cut = buf.cancel != 0
    keep = ~cut | ok           # "cancel" drops the jump of the rows next to a wall it cannot renormalise
    want = buf.ar + np.where(keep, buf.ddt + corr, 0.0)
    np.testing.assert_allclose(st.ar[fl], want[fl], rtol=1e-9, atol=1e-9 * np.abs(want[fl]).max())
    assert np.abs(corr[fl & keep]).max() > 1e-3 * np.abs(buf.ddt[fl]).max()   # the correction acts
    if wall == "cancel":       # both kinds of wall row are there: one keeps its jump, one loses it
        assert (fl & cut & ok).any() and (fl & cut & ~ok).any()


def test_mock_ranks_match_one_rank():
    """2 and 3 mock ranks (halos as parts: every part sums its moments) against one rank."""
    from test_mdbc_ranks import mdbc_scene, run, span
    d = mdbc_scene("mdbc", "symplectic").to_dict()
    d["physics"].update(riemann="zhang2017", riemann_jump="renormalised")
    sc = Scene.from_dict(d)
    _, one = run(sc, 1)
    d["physics"]["riemann_jump"] = "plain"
    _, plain = run(Scene.from_dict(d), 1)
    for ranks in (2, 3):
        _, many = run(sc, ranks)
        assert np.array_equal(many["id"], one["id"])
        assert np.abs(many["position"] - one["position"]).max() <= 1e-9 * span(sc)
        np.testing.assert_allclose(many["density"], one["density"], rtol=1e-9, atol=0)
    # the option changes the run (measured: 3.9 kg/m^3 after 60 steps)
    assert np.abs(plain["density"] - one["density"]).max() > 0.1


def test_keys():
    assert still().constants.opt[__import__("sphgraph.config").config.O_RIEMANN_JUMP] == 1
    with pytest.raises(InputError, match="physics.riemann_jump"):
        still(jump="linear")
    with pytest.raises(InputError, match=r'physics.riemann_jump.*riemann = "zhang2017"'):
        still(riemann="none")
    with pytest.raises(InputError, match=r'physics.riemann_jump.*boundary = "dbc"'):
        still(boundary="dbc")


def test_the_renormalised_jump_holds_the_jet_that_passes_an_mdbc_wall():
    """The penetration map's slab at 20 m/s onto four and three mDBC layers (dp 0.02, as
    tests/test_riemann.py): the plain jump with "skip" lets fluid through (measured: 15 and 17
    rows), the renormalised one none, with the wall still adding no jump, and none with the walls
    cancelling the jump of the rows it cannot renormalise ("cancel")."""
    from sphgraph.stability import penetration_map
    riemann = {"integrator": "symplectic", "riemann": "zhang2017", "riemann_eta": 0.3}
    plain = penetration_map([20.0], ["mdbc-4", "mdbc-3"], dp=0.02, physics=riemann)
    renorm = penetration_map([20.0], ["mdbc-4", "mdbc-3"], dp=0.02, physics=dict(riemann, riemann_jump="renormalised"))
    hybrid = penetration_map([20.0], ["mdbc-4", "mdbc-3"], dp=0.02,
                             physics=dict(riemann, riemann_jump="renormalised", riemann_wall="cancel"))
    assert all(r["through"] > 0 for r in plain)
    assert [(r["through"], r["verdict"]) for r in renorm] == [(0, "stable"), (0, "stable")]
    assert [(r["through"], r["verdict"]) for r in hybrid] == [(0, "stable"), (0, "stable")]


@pytest.mark.mpi
@pytest.mark.parametrize("n", [2, 3])
def test_mpi_ranks_match_one_rank(n):
    """Under `mpiexec -n 2/3` (tests/mpi_driver.py's rjump2d: the 2D dam break, 60 steps)
    against the single-rank run, to 1e-9 of the domain."""
    from test_multirank import run_driver
    r = run_driver(n, ["rjump2d"])
    assert r["rjump2d"]["ranks"] == n and r["rjump2d"]["rel_err"] <= 1e-9
