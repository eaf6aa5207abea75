"""Periodic boundaries: images, wrapping, the slab ring across ranks (issue 9 §4/§8).

A fully periodic box (no walls) conserves particles and momentum: x momentum to round-off,
y momentum = N g t (Symplectic: v = v0 + dt a, interior forces sum to zero); 1 rank and 3
mock ranks (split along the periodic x axis: a ring) agree.
"""
from __future__ import annotations

import numpy as np
import pytest

from sphgraph import InputError, Scene, Schedule, Simulation
from sphgraph.periodic import Periodic
from sphgraph.schedule import shipped


def box_scene(axes=("x", "y"), walls=False, integrator="symplectic", fluid_max=(0.78, 0.38)):
    d = {"format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
         "domain": {"min": [0.0, -0.04 if walls else 0.0], "max": [0.8, 0.44 if walls else 0.4],
                    "origin": [0.0, 0.0], "periodic": list(axes)},
         "physics": {"hswl": 0.4, "coefsound": 10.0, "integrator": integrator},
         "decomposition": {"axis": "x"},
         "fluid": [{"type": "box", "min": [0.0, 0.02 if walls else 0.0], "max": list(fluid_max)}]}
    if walls:
        d["boundary"] = [{"type": "wall", "min": [0.0, 0.0], "max": [0.78, 0.0]},
                         {"type": "wall", "min": [0.0, 0.4], "max": [0.78, 0.4]}]
    return Scene.from_dict(d)


def stir(sim):
    for c in sim.contexts:
        p = c.state.particles
        fl = p.kind == 0
        p.vel[fl, 0] = 0.5 * np.sin(2 * np.pi * p.pos[fl, 1] / 0.4) + 0.3
        p.vel[fl, 1] = 0.2 * np.cos(2 * np.pi * p.pos[fl, 0] / 0.8)
        p.vel_m1[:] = p.vel


def run(sc, ranks, steps):
    sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks)
    stir(sim)
    a0 = {k: v.copy() for k, v in sim.frame_arrays().items()}
    for _ in range(steps):
        sim.step()
    return sim, a0, sim.frame_arrays()


def test_periodic_box_conserves_particles_and_momentum_on_1_and_3_ranks():
    sc = box_scene()
    out = {}
    for ranks in (1, 3):
        sim, a0, a = run(sc, ranks, 80)
        n = len(a0["id"])
        assert np.array_equal(a["id"], a0["id"]) and n == 800
        p = a["position"]
        assert np.all(p >= [0.0, 0.0]) and np.all(p < [0.8, 0.4])
        # particles crossed both seams (x moves 0.3 m/s on average, y falls)
        moved = np.abs(p - a0["position"]).max(axis=0)
        assert moved[0] > 0.5 and moved[1] > 0.3
        dv = a["velocity"].sum(axis=0) - a0["velocity"].sum(axis=0)
        assert abs(dv[0]) < 1e-10 * np.abs(a0["velocity"]).sum()
        assert dv[1] == pytest.approx(-9.81 * sim.time * n, rel=1e-10)
        out[ranks] = a
    for k in ("position", "velocity", "density"):
        np.testing.assert_allclose(out[3][k], out[1][k], rtol=0, atol=1e-9)


def test_periodic_channel_with_walls_on_1_and_3_ranks_verlet():
    sc = box_scene(axes=("x",), walls=True, integrator="verlet", fluid_max=(0.78, 0.36))
    res = [run(sc, r, 60)[2] for r in (1, 3)]
    assert np.array_equal(res[0]["id"], res[1]["id"])
    for k in ("position", "velocity", "density"):
        np.testing.assert_allclose(res[1][k], res[0][k], rtol=0, atol=1e-9)
    fl = res[0]["kind"] == 0
    assert np.all(res[0]["position"][fl, 0] >= 0) and np.all(res[0]["position"][fl, 0] < 0.8)


def test_images_cover_faces_and_corners():
    per = Periodic([0, 1], [0, 0], [1, 1], reach=0.1)
    pos = np.array([[0.05, 0.05], [0.5, 0.5], [0.95, 0.5]])
    r, s = per.image_rows(pos)
    got = sorted(map(tuple, np.round(pos[r] + s, 12)))
    assert got == sorted([(1.05, 0.05), (0.05, 1.05), (1.05, 1.05), (-0.05, 0.5)])


def test_periodic_scene_checks():
    with pytest.raises(InputError, match="domain.periodic"):
        box_scene(axes=("q",))
    with pytest.raises(InputError, match=r"\[min, max\)"):
        Simulation(box_scene(fluid_max=(0.8, 0.38)))


@pytest.mark.parametrize("name", shipped())
def test_shipped_schedules_validate_as_a_ring(name):
    s = Schedule.load(name)
    for ranks in (2, 3, 4):
        for stages in (1, 2):
            s.validate(ranks, stages, motion=True, ring=True)
            prog = s.program(0, ranks, stages, ring=True)
            assert f"recv_halo_1@1" in [t.name for t in prog]   # rank 0's lower neighbour: the last rank
