"""mDBC across a periodic face (one rank): the ghosts near the face sum the fluid beyond it,
from images of the rank's rows made by the mdbc task itself (`features.Mdbc.apply`), not the
images datum, which at that point holds the previous stage's rows.

The check that can fail is translation invariance across the seam: a periodic channel over a
3-layer no-slip floor, the water stirred by a velocity field periodic in x, run twice with the
field moved by 7 dp; the second run must be the first moved by 7 dp -- to round-off (measured
5.6e-16 m and 6.1e-12 kg/m^3 after 40 steps). With the previous stage's images in the ghost
sums (before this task made its own) it was 1.7e-5 m and 0.28 kg/m^3 apart.

numba-cuda runs the channel, driven along x so that rows cross the seam (images from its
device rows, `k_wrap` on them), equal to numba-cpu within 1e-9 of the domain (the CUDA
simulator; `gpu`).
"""
from __future__ import annotations

import numpy as np
import pytest

from sphgraph import Scene, Simulation
from sphgraph.features import Mdbc

L, DP, K = 0.6, 0.02, 7


def scene(boundary="mdbc-noslip"):
    return Scene.from_dict({
        "format": 1, "name": "seam", "dim": 2, "dp": DP, "end_time": 1.0,
        "domain": {"min": [0.0, -0.1], "max": [L, 0.5], "origin": [0.01, 0.0], "periodic": ["x"]},
        "physics": {"coefsound": 10.0, "boundary": boundary},
        "initial": {"hydrostatic": True},
        "fluid": [{"type": "box", "min": [0.0, 0.02], "max": [L, 0.2]}],
        "boundary": [{"type": "wall", "min": [0.01, 0.0], "max": [L - 0.01, 0.0], "direction": "-", "layers": 3}]},
        source="<test>")


def stirred(sim, shift):
    """The water's velocity field, periodic in x, moved by `shift` spacings."""
    for c in sim.contexts:
        p = c.state.particles
        f = p.kind == 0
        ph = 2 * np.pi * (p.pos[f, 0] - shift * DP) / L
        for v in (p.vel, p.vel_m1):
            v[f, 1] += 0.3 * np.sin(ph) * np.sin(np.pi * p.pos[f, 1] / 0.2)
            v[f, 0] += 0.3 * np.cos(ph)


def run(shift, steps, sc=None):
    sim = Simulation(sc or scene())
    stirred(sim, shift)
    a0 = sim.frame_arrays()
    for _ in range(steps):
        sim.step()
    return a0, sim.frame_arrays()


def seam_gap(steps=40):
    """How far the run with the field moved by K dp is from the first run moved by K dp."""
    a0, a = run(0, steps)
    b0, b = run(K, steps)
    cells = round(L / DP * 2)

    def key(pos):   # the start lattice in half spacings, x wrapped
        k = np.round(pos / DP * 2).astype(np.int64)
        k[:, 0] %= cells
        return [tuple(x) for x in k]
    of_a = dict(zip(key(a0["position"]), a0["id"]))
    moved = b0["position"].copy()
    moved[:, 0] -= K * DP
    a_of_b = dict(zip(b0["id"], (of_a[k] for k in key(moved))))
    row_a = {i: n for n, i in enumerate(a["id"])}
    ra = np.array([row_a[a_of_b[i]] for i in b["id"]])
    d = b["position"] - a["position"][ra]
    d[:, 0] -= K * DP
    d[:, 0] = (d[:, 0] + L / 2) % L - L / 2
    f = a["kind"][ra] == 0
    return float(np.abs(d[f]).max()), float(np.abs(b["density"] - a["density"][ra]).max())


def test_the_seam_does_not_show():
    pos, rho = seam_gap()
    assert pos <= 1e-12 and rho <= 1e-9, (pos, rho)


def test_without_fresh_images_the_seam_shows(monkeypatch):
    """The same check with the previous stage's images in the ghost sums, as before the
    task made its own: far apart (so the check above can fail)."""
    def stale(self, ctx):
        ctx.compute.mdbc(ctx.state, self.boxes, self.det_min, self.noslip, self.moving_ghosts(ctx.state))
    monkeypatch.setattr(Mdbc, "apply", stale)
    pos, rho = seam_gap()
    assert pos > 1e-7 and rho > 1e-3, (pos, rho)


def plate_scene():
    """A periodic channel 0.6 m deep split across its depth (y): a floor, and a plate of 2
    layers at x = 0.03 m standing through the water and every cut, within reach of the
    periodic face, so the edges towards the neighbours carry images (along x) of boundary
    rows whose new values send_mdbc must bring."""
    return Scene.from_dict({
        "format": 1, "name": "plate", "dim": 2, "dp": DP, "end_time": 1.0,
        "domain": {"min": [0.0, -0.1], "max": [L, 0.9], "origin": [0.01, 0.0], "periodic": ["x"]},
        "physics": {"coefsound": 10.0, "boundary": "mdbc-noslip"},
        "initial": {"hydrostatic": True},
        "decomposition": {"axis": "y"},
        "fluid": [{"type": "box", "min": [0.0, 0.02], "max": [L, 0.6]}],
        "boundary": [{"type": "wall", "min": [0.01, 0.0], "max": [L - 0.01, 0.0], "direction": "-", "layers": 3},
                     {"type": "wall", "min": [0.03, 0.02], "max": [0.03, 0.7], "direction": "-", "layers": 2}]},
        source="<test>")


def ranks_run(sc, ranks, steps=40):
    sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks, schedule="bulk-synchronous")
    for c in sim.contexts:      # sheared along x, so that rows cross the periodic face
        p = c.state.particles
        f = p.kind == 0
        for v in (p.vel, p.vel_m1):
            v[f, 0] += 0.3 * np.sin(2 * np.pi * p.pos[f, 1] / 0.6)
    for _ in range(steps):
        sim.step()
    return sim.frame_arrays()


@pytest.mark.parametrize("case,ranks", [("ring", 2), ("ring", 3), ("images", 2), ("images", 3)])
def test_mock_ranks_match_one_rank(case, ranks):
    """mDBC on several ranks with a periodic axis: the split axis itself (a ring of slabs,
    the seam channel split along x) or another one (the plate channel split along y, whose
    edges carry images; `PeriodicSlabs.edge_sources` names the rows they copy). Equal to one
    rank within 1e-9 of the domain (measured 2.2e-16 m)."""
    if case == "ring":
        d = scene().to_dict()
        d["decomposition"] = {"axis": "x"}
        sc = Scene.from_dict(d, source="<test>")
    else:
        sc = plate_scene()
    one, many = ranks_run(sc, 1), ranks_run(sc, ranks)
    assert np.array_equal(many["id"], one["id"])
    span = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    assert np.abs(many["position"] - one["position"]).max() <= 1e-9 * span
    np.testing.assert_allclose(many["density"], one["density"], rtol=1e-9, atol=0)


def test_images_in_the_edge_need_their_values(monkeypatch):
    """Without edge_sources' image rows the edge's boundary values fall short of its rows."""
    from sphgraph.domain import Slabs
    from sphgraph.periodic import PeriodicSlabs
    monkeypatch.setattr(PeriodicSlabs, "edge_sources", Slabs.edge_sources)
    with pytest.raises(ValueError, match="boundary values for .* boundary rows"):
        ranks_run(plate_scene(), 2, steps=2)


def compare_ranks(steps=3) -> dict:
    """The plate channel on numba-cuda, 2 mock ranks, against numba-cpu on one rank; "device":
    how many times the ranks made their images on the device (cuda_images)."""
    import cudasim_helpers as H
    from sphgraph.backends.compute import cuda_images
    made = []
    make = cuda_images.device_images
    cuda_images.device_images = lambda *a: made.append(1) or make(*a)
    sc = plate_scene()
    cpu = H.run(sc, "numba-cpu", steps)
    out = H.diff(sc, cpu, H.run(sc, "numba-cuda", steps, 2, "staged", schedule="bulk-synchronous"))
    return out | {"device": len(made)}


def test_simulator_mock_ranks_match_cpu():
    from cudasim_helpers import check_equal, compare_in_subprocess
    r = compare_in_subprocess(__file__, "compare_ranks(3)", sim=True, timeout=900)
    check_equal(r)
    assert r["vel"] < 1e-10, r
    assert r["device"] > 0, r      # the images along x made on the device on both ranks


def drift_scene(boundary="mdbc-noslip"):
    """The channel driven along x by a body force of 20 m/s^2, its water's lattice starting
    1e-6 m short of the seam: rows cross it from the first steps."""
    d = scene(boundary).to_dict()
    d["physics"]["gravity"] = [20.0, -9.81]
    d["domain"]["origin"] = [0.019999, 0.0]    # the lattice's x: 0.019999 + k dp, up to 0.599999
    return Scene.from_dict(d, source="<test>")


def compare(steps, boundary="mdbc-noslip") -> dict:
    """The driven channel on numba-cuda against numba-cpu, one rank: a cudasim_helpers.diff,
    and how many rows crossed the seam (wrapped) in the run."""
    import cudasim_helpers as H
    sc = drift_scene(boundary)
    cpu = H.run(sc, "numba-cpu", steps)
    r = H.diff(sc, cpu, H.run(sc, "numba-cuda", steps))
    p0 = sc.build_particles()
    x0 = dict(zip(p0.id, p0.pos[:, 0]))
    a = cpu[0]
    r["wrapped"] = int(sum(abs(x - x0[j]) > L / 2 for j, x in zip(a["id"], a["position"][:, 0])))
    return r


def check(r):
    from cudasim_helpers import check_equal
    check_equal(r)
    assert r["vel"] < 1e-10, r
    assert r["wrapped"] > 0, f"no row crossed the seam: {r}"


def test_simulator_matches_cpu():
    """numba-cuda's images (from the device rows) and wrap (k_wrap) against numba-cpu, in
    numba's CUDA simulator: 6 steps of the driven channel, rows crossing the seam."""
    from cudasim_helpers import compare_in_subprocess
    check(compare_in_subprocess(__file__, "compare(6)", sim=True, timeout=900))


@pytest.mark.gpu
def test_gpu_matches_cpu():
    from cudasim_helpers import compare_in_subprocess, gpu_available
    if not gpu_available():
        pytest.skip("no CUDA GPU")
    check(compare_in_subprocess(__file__, "compare(200)", sim=False, timeout=600))
