"""mDBC with a moving body on numba-cuda (backends/compute/cuda_mdbc.py: `k_set_ghosts` puts the
body's carried ghost nodes in the device table each mdbc, and the body's rows keep their
velocity) against numba-cpu on one rank, in numba's CUDA simulator in a subprocess (as
tests/test_cuda_mdbc.py): one rank, and 2 mock ranks by both halo transports. The scene: the
feature tests' 2D tank (dp 0.05, 2 wall layers, hydrostatic start) with a paddle of 2 layers
driven into the water at 2 m/s from t = 0 (350 particles), 4 steps. The paddle's own effect
on the check: numba-cpu with the paddle's ghosts left at rest is visibly apart (`gap`,
densities), so the equality can fail. The physics of the carried ghosts (a carried tank is
the still tank moved): tests/test_mdbc_motion.py."""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_equal, compare_in_subprocess

SCHEDULE = "bulk-synchronous"
STEPS = 4


def scene(integrator="verlet", boundary="mdbc"):
    """`boundary` "mdbc-noslip" adds a laminar viscosity: the still walls' rows then carry the
    mirrored velocity and the paddle's its own, and the kernels tell them apart by kind."""
    from sphgraph.scene import Scene
    physics = {"boundary": boundary, "integrator": integrator}
    if boundary == "mdbc-noslip":
        physics["laminar_nu"] = 1e-3
    d = H.tank(2, physics, layers=2, initial={"hydrostatic": True}).to_dict()
    d["boundary"].append({"type": "wall", "name": "paddle", "min": [0.6, 0.05], "max": [0.6, 0.7], "layers": 2,
                          "direction": "+"})
    d["motion"] = [{"body": "paddle", "type": "rectilinear", "times": [0.0, 1.0],
                    "velocity": [[-2.0, 0.0], [-2.0, 0.0]]}]
    return Scene.from_dict(d, source="<test>")


def rest_ghosts():
    from sphgraph.backends.compute.numba_cpu import NumbaCPU

    class RestGhosts(NumbaCPU):
        name = "numba-cpu"

        def mdbc(self, state, boxes, det_min, noslip, moving=None):
            super().mdbc(state, boxes, det_min, noslip, None)
    return RestGhosts


def compare(ranks, transport, integrator="verlet", gap=False, boundary="mdbc") -> dict:
    sc = scene(integrator, boundary)
    cpu = H.run(sc, "numba-cpu", STEPS)
    out = H.diff(sc, cpu, H.run(sc, "numba-cuda", STEPS, ranks, transport, schedule=SCHEDULE))
    if gap:
        out["gap"] = H.diff(sc, cpu, H.run(sc, rest_ghosts(), STEPS))["rho"]
    return out


@pytest.mark.parametrize("ranks,transport,integrator,gap,boundary", [
    (1, "auto", "verlet", True, "mdbc"), (2, "staged", "verlet", False, "mdbc"),
    (2, "ipc", "symplectic", False, "mdbc"), (2, "ipc", "verlet", False, "mdbc-noslip")])
def test_simulator_moving_mdbc_matches_cpu(ranks, transport, integrator, gap, boundary):
    r = compare_in_subprocess(__file__, f"compare({ranks}, {transport!r}, {integrator!r}, {gap}, {boundary!r})",
                              sim=True, timeout=900)
    check_equal(r)
    assert r["vel"] < 1e-10, r
    if gap:
        assert r["gap"] > 1e-3, f"the carried ghosts change the densities by only {r['gap']:.3g} kg/m^3: {r}"


@H.gpu
@pytest.mark.gpu
@pytest.mark.parametrize("ranks,transport,boundary", [(1, "auto", "mdbc"), (2, "staged", "mdbc"), (2, "ipc", "mdbc"),
                                                      (1, "auto", "mdbc-noslip"), (2, "ipc", "mdbc-noslip")])
def test_gpu_moving_mdbc_matches_cpu(ranks, transport, boundary):
    r = compare_in_subprocess(__file__, f"compare({ranks}, {transport!r}, 'symplectic', {ranks == 1}, {boundary!r})",
                              sim=False, timeout=900)
    check_equal(r)
    assert r["vel"] < 1e-10, r
