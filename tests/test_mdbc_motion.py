"""mDBC with moving bodies (issue 22 §2, "mDBC everywhere"): a moving body's ghost nodes are
mirrored once across the interfaces at rest and then carried with the body
(`Mdbc.moving_ghosts`), and the body's rows keep the body's velocity.

The check that can fail is Galilean invariance: a tank of still water carried at a constant
U = 0.3 m/s, the water given U as well, must be the still tank shifted by U t -- to round-off
(measured: positions 4.4e-16 m, densities 2.5e-12 kg/m^3 after 50 steps). With the ghosts left
where the interfaces are at rest the same run is 9.0e-3 m and 27 kg/m^3 apart; with the
body's rows given mDBC's velocity (zero) 9.0e-3 m and 31 kg/m^3. On 2 and 3 mock ranks (the
tank crossing the cuts, both integrators) the run equals one rank within 1e-9 of the domain.
No-slip walls with a moving body: the body's rows keep its velocity for every term (a carried
no-slip tank is the tank at rest moved, to round-off), the still walls mirror the fluid's.
"""
from __future__ import annotations

import numpy as np
import pytest

from sphgraph import Scene, Simulation
from sphgraph.backends.compute.numba_cpu import NumbaCPU
from sphgraph.features import Mdbc
from sphgraph.motion import Motion
from sphgraph.particles import MOVING

U = 0.3
STEPS = 50


def scene(moving=True, boundary="mdbc", integrator="verlet", width=0.4, motion=None):
    d = {"format": 1, "name": "carried", "dim": 2, "dp": 0.02, "end_time": 1.0,
         "domain": {"min": [-0.1, -0.1], "max": [width + 0.6, 0.6], "origin": [0.0, 0.0]},
         "physics": {"coefsound": 10.0, "boundary": boundary, "integrator": integrator},
         "initial": {"hydrostatic": True},
         "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [width, 0.2]}],
         "boundary": [{"type": "tank", "name": "tank", "min": [0.0, 0.0], "max": [width, 0.3], "layers": 3}]}
    if moving:
        d["motion"] = [motion or {"body": "tank", "type": "rectilinear", "times": [0.0, 1.0],
                                  "velocity": [[U, 0.0], [U, 0.0]]}]
    return Scene.from_dict(d)


class RestGhosts(NumbaCPU):
    """numba-cpu whose moving rows take the ghosts of the interfaces at rest."""
    name = "numba-cpu"

    def mdbc(self, state, boxes, det_min, noslip, moving=None):
        super().mdbc(state, boxes, det_min, noslip, None)


class StillRows(NumbaCPU):
    """numba-cpu whose moving rows take mDBC's slip velocity (zero) instead of the body's."""
    name = "numba-cpu"

    def mdbc(self, state, boxes, det_min, noslip, moving=None):
        super().mdbc(state, boxes, det_min, noslip, moving)
        p = state.particles
        p.vel[p.kind == MOVING] = 0.0


def run(sc, backend="numba-cpu", ranks=1, carried=True):
    sim = Simulation(sc, backend=backend, comm="single" if ranks == 1 else "mock", ranks=ranks,
                     decomposition_axis="x", schedule="bulk-synchronous")
    if carried:   # the water moves with the tank from the start, the tank's rows too
        for c in sim.contexts:
            p = c.state.particles
            p.vel[:, 0] += U
            p.vel_m1[:, 0] += U
    for _ in range(STEPS):
        sim.step()
    return sim.time, sim.frame_arrays()


def galilean_gap(backend):
    _, still = run(scene(moving=False), carried=False)
    t, moved = run(scene(), backend)
    assert np.array_equal(still["id"], moved["id"])
    rel = moved["position"].copy()
    rel[:, 0] -= U * t
    f = still["kind"] == 0
    return (float(np.abs(rel[f] - still["position"][f]).max()),
            float(np.abs(moved["density"] - still["density"]).max()), moved)


def test_a_carried_tank_is_the_still_tank_moved():
    pos, rho, moved = galilean_gap("numba-cpu")
    assert pos <= 1e-12 and rho <= 1e-9, (pos, rho)
    m = moved["kind"] == MOVING
    np.testing.assert_array_equal(moved["velocity"][m], np.broadcast_to([U, 0.0], (int(m.sum()), 2)))


@pytest.mark.parametrize("backend", [RestGhosts, StillRows])
def test_each_part_of_the_moving_mdbc_matters(backend):
    pos, rho, _ = galilean_gap(backend)
    assert pos > 1e-4 and rho > 1.0, (pos, rho)


def test_a_turning_body_turns_its_ghosts():
    """A rotating tank: each moving row's ghost keeps its offset from the row, turned by the
    body's angle (the rows' own positions come from the same Motion)."""
    w = 1.5
    sc = scene(motion={"body": "tank", "type": "rotation", "times": [0.0, 1.0], "omega": [w, w],
                       "center": [0.2, 0.1]})
    particles = sc.build_particles()
    motion = Motion.from_scene(sc, particles)
    mdbc = Mdbc(sc, motion=motion)

    class State:
        extra = {"motion_time": 0.4}
        time = 0.0
    ids, ghosts = mdbc.moving_ghosts(State)
    rows, _ = motion.table(0.4)
    c, s = np.cos(w * 0.4), np.sin(w * 0.4)
    turned = (mdbc.ghost_ref - motion.ref) @ np.array([[c, -s], [s, c]]).T
    np.testing.assert_allclose(ghosts - rows, turned, rtol=0, atol=1e-12)
    assert np.abs(turned - (mdbc.ghost_ref - motion.ref)).max() > 1e-3    # it did turn


NOSLIP = {"boundary": "mdbc-noslip", "laminar_nu": 1e-3}


def noslip_scene(u, integrator="verlet", width=0.4):
    """The tank of `scene` with no-slip mDBC walls and a laminar viscosity (the terms that take
    the rows' velocities), carried at u (a moving body, also at u = 0)."""
    sc = scene(integrator=integrator, width=width,
               motion={"body": "tank", "type": "rectilinear", "times": [0.0, 1.0], "velocity": [[u, 0.0], [u, 0.0]]})
    d = sc.to_dict()
    d["physics"].update(NOSLIP)
    return Scene.from_dict(d)


class StillMovingRows(NumbaCPU):
    """numba-cpu whose no-slip continuity takes a still wall for the moving rows too (the
    moving rows' velocity zeroed for the continuity only, as a still wall's mirror is)."""
    name = "numba-cpu"

    def forces(self, state, part):
        p = state.particles
        m = p.kind == MOVING
        held = p.vel[m].copy()
        p.vel[m] = 0.0
        try:
            super().forces(state, part)
        finally:
            p.vel[m] = held


def noslip_gap(backend="numba-cpu"):
    """(positions, densities) apart: the tank carried at U with its water, moved back by U t,
    against the same tank as a body at rest, both with no-slip walls."""
    _, rest = run(noslip_scene(0.0), carried=False)
    t, moved = run(noslip_scene(U), backend)
    assert np.array_equal(rest["id"], moved["id"])
    rel = moved["position"].copy()
    rel[:, 0] -= U * t
    f = rest["kind"] == 0
    return float(np.abs(rel[f] - rest["position"][f]).max()), float(np.abs(moved["density"] - rest["density"]).max())


def test_no_slip_walls_on_a_carried_tank_are_the_tank_at_rest_moved():
    """No-slip mDBC with a moving body: the body's rows keep its velocity, which the
    continuity (the wall's own velocity) and the viscous terms take, so a carried tank with
    no-slip walls and a laminar viscosity is the same tank at rest, moved -- to round-off.
    With the continuity of a still wall on the moving rows (the no-slip walls' term for a
    still wall) the same run is far apart."""
    pos, rho = noslip_gap()
    assert pos <= 1e-12 and rho <= 1e-9, (pos, rho)
    pos, rho = noslip_gap(StillMovingRows)
    assert pos > 1e-5 and rho > 1.0, (pos, rho)


def test_no_slip_walls_still_mirror_beside_a_moving_body():
    """A scene with a moving body and no-slip walls: the still walls' rows take mDBC's
    mirrored velocity, the moving body's rows the body's own (one mdbc task)."""
    d = scene(moving=False, width=0.6).to_dict()
    d["physics"].update(NOSLIP)
    d["boundary"].append({"type": "wall", "name": "paddle", "min": [0.45, 0.02], "max": [0.45, 0.25], "layers": 2,
                          "direction": "+"})
    d["motion"] = [{"body": "paddle", "type": "rectilinear", "times": [0.0, 1.0], "velocity": [[-U, 0.0], [-U, 0.0]]}]
    sim = Simulation(Scene.from_dict(d))
    for c in sim.contexts:
        c.state.particles.vel[c.state.particles.kind == 0, 0] = 0.2     # fluid along the walls
    for _ in range(3):
        sim.step()
    a = sim.frame_arrays()
    m, fixed = a["kind"] == MOVING, a["kind"] == 1
    np.testing.assert_array_equal(a["velocity"][m], np.broadcast_to([-U, 0.0], (int(m.sum()), 2)))
    # the floor's first rows mirror the fluid's tangential velocity (about -0.2 m/s)
    floor = fixed & (np.abs(a["position"][:, 1]) < 1e-3) & (a["position"][:, 0] > 0.1) & (a["position"][:, 0] < 0.3)
    assert floor.sum() >= 5
    assert np.all(a["velocity"][floor, 0] < -0.1), a["velocity"][floor, 0]
    assert np.abs(a["velocity"][floor, 1]).max() < 1e-12


@pytest.mark.parametrize("noslip", [False, True])
@pytest.mark.parametrize("integrator,ranks", [("verlet", 2), ("symplectic", 3)])
def test_mock_ranks_match_one_rank(integrator, ranks, noslip):
    sc = noslip_scene(U, integrator=integrator, width=0.6) if noslip else scene(integrator=integrator, width=0.6)
    _, one = run(sc)
    _, many = run(sc, ranks=ranks)
    assert np.array_equal(many["id"], one["id"])
    span = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    assert np.abs(many["position"] - one["position"]).max() <= 1e-9 * span
    np.testing.assert_allclose(many["density"], one["density"], rtol=1e-9, atol=0)
    np.testing.assert_allclose(many["velocity"], one["velocity"], rtol=0, atol=1e-9)


@pytest.mark.mpi
@pytest.mark.parametrize("n", [2, 3])
def test_mpi_ranks_match_one_rank(n):
    from test_multirank import run_driver
    r = run_driver(n, ["mdbc-motion2d", "mdbc-noslip-motion2d"])
    for name in ("mdbc-motion2d", "mdbc-noslip-motion2d"):
        assert r[name]["ranks"] == n and r[name]["rel_err"] <= 1e-9, r[name]
