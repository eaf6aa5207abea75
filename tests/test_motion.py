"""Moving boundaries (kind 2): [[motion]] entries, the motion task, wavemaker strokes.

Issue 9 §1/§8: motion follows its table (rectilinear, rotation, gate); 1 and 3 mock ranks
give the same particles; the motion task is in the graph only when a scene asks for it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from sphgraph import InputError, Scene, Schedule, Simulation
from sphgraph.motion import Table
from sphgraph.particles import MOVING
from sphgraph.schedule import shipped
from sphgraph.waves import flap_ratio, piston_ratio, wavenumber


def tank_scene(motion, body=None, integrator="verlet"):
    body = body or {"type": "wall", "name": "paddle", "min": [0.0, 0.02], "max": [0.0, 0.5],
                    "layers": 2, "direction": "+"}
    return Scene.from_dict({
        "format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
        "domain": {"min": [-0.3, -0.1], "max": [2.3, 1.0], "origin": [0.0, 0.0]},
        "physics": {"coefsound": 10.0, "integrator": integrator},
        "initial": {"hydrostatic": True},
        "fluid": [{"type": "box", "min": [0.06, 0.02], "max": [2.0, 0.3]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [2.0, 0.6], "layers": 1}, body],
        "motion": [motion]})


RECT = {"body": "paddle", "type": "rectilinear", "times": [0.0, 0.02, 0.04, 0.04, 1.0],
        "velocity": [[0.0, 0.0], [0.5, 0.0], [0.5, 0.1], [-0.2, 0.0], [-0.2, 0.0]]}


def moved(sim):
    a = sim.frame_arrays()
    m = a["kind"] == MOVING
    return a, m


def test_rectilinear_follows_its_table_on_1_and_3_ranks():
    sc = tank_scene(RECT)
    p0 = sc.build_particles()
    m0 = p0.kind == MOVING
    assert m0.sum() == 2 * 25 and np.all(p0.pos[m0, 0] <= 0.02 + 1e-12)
    table = Table(RECT["times"], RECT["velocity"])
    out = {}
    for ranks in (1, 3):
        sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks,
                         decomposition_axis="x")
        for _ in range(150):
            sim.step()
        a, m = moved(sim)
        v, x = table(sim.time)
        assert sim.time > 0.04   # past the jump
        np.testing.assert_allclose(a["position"][m], p0.pos[m0] + x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a["velocity"][m], np.broadcast_to(v, (m.sum(), 2)), atol=1e-12)
        out[ranks] = a
    for k in ("position", "velocity", "density"):
        np.testing.assert_allclose(out[3][k], out[1][k], rtol=0, atol=1e-9)


def test_table_integral_is_exact_for_piecewise_linear_velocity():
    t = Table([0.0, 1.0, 1.0, 3.0], [[0.0], [2.0], [-1.0], [-1.0]])
    assert t(0.5)[1][0] == pytest.approx(0.25)          # 1/2 * 0.5 * 1.0
    assert t(1.0)[1][0] == pytest.approx(1.0)
    assert t(2.0)[1][0] == pytest.approx(0.0)           # jump to -1 m/s
    assert t(5.0)[1][0] == pytest.approx(-3.0)          # held after the last time
    assert t(5.0)[0][0] == -1.0


def test_rotation_and_gate_follow_their_motion():
    box = {"type": "box", "name": "paddle", "min": [1.0, 0.4], "max": [1.2, 0.5]}
    rot = {"body": "paddle", "type": "rotation", "times": [0.0, 1.0], "omega": [2.0, 2.0],
           "center": [1.1, 0.45]}
    sc = tank_scene(rot, box)
    sim = Simulation(sc)
    p0 = sc.build_particles()
    m0 = p0.kind == MOVING
    for _ in range(40):
        sim.step()
    a, m = moved(sim)
    ang = 2.0 * sim.time
    R = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
    want = np.array([1.1, 0.45]) + (p0.pos[m0] - [1.1, 0.45]) @ R.T
    np.testing.assert_allclose(a["position"][m], want, atol=1e-12)
    r = a["position"][m] - [1.1, 0.45]
    np.testing.assert_allclose(a["velocity"][m], 2.0 * np.stack([-r[:, 1], r[:, 0]], 1), atol=1e-12)

    gate = {"body": "paddle", "type": "gate", "speed": 1.5, "lift": 0.03, "start": 0.01}
    sim = Simulation(tank_scene(gate, box))
    for _ in range(120):
        sim.step()
    a, m = moved(sim)
    assert sim.time > 0.01 + 0.03 / 1.5
    np.testing.assert_allclose(a["position"][m], p0.pos[m0] + [0.0, 0.03], atol=1e-12)
    assert np.all(a["velocity"][m] == 0)


def test_wavemaker_transfer_functions_match_dean_dalrymple_limits():
    # shallow water: piston H/S -> kd, flap -> kd/2; deep water: piston -> 2, flap -> 2(1 - 1/kd)
    assert piston_ratio(0.01) == pytest.approx(0.01, rel=1e-3)
    assert flap_ratio(0.01) == pytest.approx(0.005, rel=1e-3)
    assert piston_ratio(20.0) == pytest.approx(2.0, rel=1e-6)
    assert flap_ratio(20.0) == pytest.approx(2.0 * (1 - 1 / 20.0), rel=1e-6)
    k = wavenumber(1.0, 0.3)
    assert (2 * math.pi) ** 2 == pytest.approx(9.81 * k * math.tanh(0.3 * k), rel=1e-12)


def test_piston_stroke_and_ramp():
    pis = {"body": "paddle", "type": "piston", "height": 0.05, "period": 1.0, "depth": 0.3}
    sc = tank_scene(pis)
    sim = Simulation(sc)
    body = sim.features.motion.bodies[0]
    kd = wavenumber(1.0, 0.3) * 0.3
    assert body.stroke == pytest.approx(0.05 / piston_ratio(kd))
    assert body.displacement(0.0) == 0.0
    assert body.displacement(1.25) == pytest.approx(0.5 * body.stroke, rel=1e-12)   # after the ramp
    assert abs(body.displacement(0.25)) < 0.5 * 0.5 * body.stroke                   # within it


def test_motion_task_only_when_the_scene_asks():
    sc = tank_scene(RECT)
    sim = Simulation(sc)
    assert "motion" in sim.scheduler.task_kinds()
    plain = Scene.from_dict({k: v for k, v in sc.to_dict().items() if k != "motion"})
    assert "motion" not in Simulation(plain).scheduler.task_kinds()
    assert not np.any(plain.build_particles().kind == MOVING)


@pytest.mark.parametrize("name", shipped())
def test_shipped_schedules_validate_with_motion(name):
    s = Schedule.load(name)
    for ranks in (1, 3):
        for stages in (1, 2):
            s.validate(ranks, stages, motion=True)
            names = [t.name for t in s.program(1 % ranks, ranks, stages, motion=True)]
            for st in range(1, stages + 1):
                assert names.index(f"motion@{st}") == names.index(f"integrate@{st}") + 1


def test_symplectic_moves_bodies_each_half_step():
    sim = Simulation(tank_scene(RECT, integrator="symplectic"), comm="mock", ranks=3,
                     decomposition_axis="x")
    p0 = sim.scene.build_particles()
    for _ in range(30):
        sim.step()
    a, m = moved(sim)
    np.testing.assert_allclose(a["position"][m], p0.pos[p0.kind == MOVING] + Table(
        RECT["times"], RECT["velocity"])(sim.time)[1], atol=1e-12)


@pytest.mark.parametrize("motion,msg", [
    ({"body": "nope", "type": "gate", "speed": 1.0, "lift": 0.1}, "motion[0].body"),
    ({"body": "paddle", "type": "spin"}, "motion[0].type"),
    ({"body": "paddle", "type": "rectilinear", "times": [0, 1], "velocity": [[0, 0]]}, "motion[0].velocity"),
    ({"body": "paddle", "type": "piston", "height": -1.0, "period": 1.0}, "motion[0].height"),
    ({"body": "paddle", "type": "gate", "speed": 1.0, "lift": 0.1, "colour": 1}, "motion[0].colour"),
])
def test_motion_entries_are_validated(motion, msg):
    with pytest.raises(InputError, match=msg.replace("[", r"\[").replace("]", r"\]")):
        tank_scene(motion)
