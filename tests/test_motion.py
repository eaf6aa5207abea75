"""Moving boundaries (kind 2): [[motion]] entries, the motion task, wavemaker strokes.

Issue 9 §1/§8: motion follows its table (rectilinear, rotation with a table, gate); the
rotation, gate, piston and flap run on 1 and 3 mock ranks with equal results, their bodies
spread over more than one slab; the motion task is in the graph only when a scene asks for it.
(The flap's angle against wavemaker theory and its wave: tests/test_waves.py.)
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


def test_second_order_piston_adds_madsens_double_frequency_stroke():
    """order = 2: x(t) = S/2 sin(wt) + a2 sin(2wt) after the ramp, a2 = H^2/(32 d)
    (3 cosh kd / sinh^3 kd - 2 / (H/S)) (Madsen 1971); velocity its exact derivative."""
    H, d, T = 0.08, 0.3, 1.0
    pis = {"body": "paddle", "type": "piston", "height": H, "period": T, "depth": d}
    one = Simulation(tank_scene(pis)).features.motion.bodies[0]
    two = Simulation(tank_scene({**pis, "order": 2})).features.motion.bodies[0]
    kd = wavenumber(T, d) * d
    a2 = H * H / (32 * d) * (3 * math.cosh(kd) / math.sinh(kd) ** 3 - 2 / piston_ratio(kd))
    assert one.a2 == 0.0 and two.a2 == pytest.approx(a2, rel=1e-12)
    assert two.a2 == pytest.approx(-3.596e-4, rel=1e-3)     # this flume: ~1 % of S/2 = 0.0308 m
    w = 2 * math.pi / T
    for t in (1.1, 1.37, 2.0, 2.9):                           # after the one-period ramp
        assert two.displacement(t) == pytest.approx(
            0.5 * two.stroke * math.sin(w * t) + a2 * math.sin(2 * w * t), abs=1e-12)
        _, x, v = two.state(t)
        eps = 1e-6
        fd = (two.state(t + eps)[1][0] - two.state(t - eps)[1][0]) / (2 * eps)
        assert v[0] == pytest.approx(fd, rel=1e-6)
    assert two.state(0.0)[1][0] == 0.0
    with pytest.raises(InputError, match=r"motion\[0\]\.order: expected 1 .* or 2"):
        tank_scene({**pis, "order": 3})


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


def piston_in_tank(tank_x0, kind="piston"):
    """H = 0.08 m, T = 1 s, d = 0.3 m: S/2 = 0.031 m > dp = 0.02 m, so a fixed end wall
    at the paddle (tank from x = 0, 2 layers: the outer one at x = -dp) is in the stroke
    (a flap's top reaches further back than S/2)."""
    d = tank_scene({"body": "paddle", "type": kind, "height": 0.08, "period": 1.0,
                    "depth": 0.3}).to_dict()
    d["boundary"][0].update(min=[tank_x0, 0.0], layers=2)
    return Scene.from_dict(d, source="flume.toml")


@pytest.mark.parametrize("kind,behind", [("piston", -0.08), ("flap", -0.16)])
def test_a_fixed_wall_in_the_wavemakers_stroke_is_refused(kind, behind):
    with pytest.raises(InputError, match=rf"flume.toml: motion\[0\].body: .*stroke of {kind} "
                                         r"'paddle' \(x from -0.0\d* to 0.\d* m\), got \d+ fixed"):
        Simulation(piston_in_tank(0.0, kind))
    sim = Simulation(piston_in_tank(behind, kind))     # the end wall behind the back stroke
    sim.step()
    a, m = moved(sim)
    fixed = (a["kind"] == 1) & (a["position"][:, 1] > 0.03)
    assert not (np.abs(a["position"][fixed, 0]) < 0.06).any()   # nothing fixed near the paddle


# --------------------------------------------------------------------------- 1 vs 3 mock ranks

def scene2d(dp, size, fluid, bodies, motion, hswl=None):
    """A tank [0, size] with fluid box ``fluid`` and named ``bodies`` moved by ``motion``."""
    phys = {"coefsound": 10.0}
    if hswl is not None:
        phys["hswl"] = hswl
    return Scene.from_dict({
        "format": 1, "dim": 2, "dp": dp, "end_time": 1.0,
        "domain": {"min": [-0.1, -0.1], "max": [size[0] + 0.1, size[1] + 0.1], "origin": [0.0, 0.0]},
        "physics": phys, "initial": {"hydrostatic": True},
        "fluid": [{"type": "box", "min": fluid[0], "max": fluid[1]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": list(size)}] + bodies,
        "motion": [motion]})


def owners(sim):
    """{id: rank} of the moving rows."""
    return {int(i): c.rank for c in sim.contexts
            for i in c.state.particles.id[c.state.particles.kind == MOVING]}


def run_ranks(scene, ranks, axis, steps, each_step=None):
    """Run `steps` steps on 1 (single) or `ranks` mock ranks; (sim, owners at the start, at the end)."""
    sim = Simulation(scene, comm="single" if ranks == 1 else "mock", ranks=ranks, decomposition_axis=axis)
    start = owners(sim)
    for _ in range(steps):
        sim.step()
        if each_step is not None:
            each_step(sim)
    return sim, start, owners(sim)


def assert_same_particles(a, b, scene):
    """Same ids; positions to 1e-9 of the domain size; velocity and density to round-off."""
    assert np.array_equal(a["id"], b["id"])
    size = float(np.max(scene.domain_max - scene.domain_min))
    np.testing.assert_allclose(b["position"], a["position"], rtol=0, atol=1e-9 * size)
    np.testing.assert_allclose(b["velocity"], a["velocity"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(b["density"], a["density"], rtol=1e-12, atol=0)


# omega held at 1 rad/s before 0.005 s, up to 6 rad/s at 0.015 s, held, a jump to -4 rad/s at 0.03 s
ROT_TIMES = [0.005, 0.015, 0.03, 0.03, 1.0]
ROT_OMEGA = [1.0, 6.0, 6.0, -4.0, -4.0]


def rot_table(t):
    """(omega, angle) of ROT_TIMES/ROT_OMEGA at t, the angle integrated by hand segment by segment."""
    if t <= 0.005:
        return 1.0, 1.0 * t
    if t <= 0.015:
        w = 1.0 + 5.0 * (t - 0.005) / 0.01
        return w, 0.005 + 0.5 * (1.0 + w) * (t - 0.005)
    a = 0.005 + 0.5 * (1.0 + 6.0) * 0.01               # 0.04 rad at 0.015 s
    if t < 0.03:
        return 6.0, a + 6.0 * (t - 0.015)
    return -4.0, a + 6.0 * 0.015 - 4.0 * (t - 0.03)     # 0.13 rad at 0.03 s, then -4 rad/s


def test_rotation_follows_its_table_on_1_and_3_ranks():
    # a submerged stirrer plate (0.36 m x 0.06 m) across the first slab cut, turning by a table
    c = np.array([0.51, 0.15])
    sc = scene2d(0.03, (1.5, 0.5), ([0.03, 0.03], [1.47, 0.3]),
                 [{"type": "box", "name": "stirrer", "min": [0.33, 0.12], "max": [0.69, 0.18]}],
                 {"body": "stirrer", "type": "rotation", "times": ROT_TIMES, "omega": ROT_OMEGA,
                  "center": list(c)})
    p0 = sc.build_particles()
    m0 = p0.kind == MOVING
    seen = []

    def follows(sim):
        a, m = moved(sim)
        w, ang = rot_table(sim.time)
        R = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
        np.testing.assert_allclose(a["position"][m], c + (p0.pos[m0] - c) @ R.T, rtol=0, atol=1e-12)
        r = a["position"][m] - c
        np.testing.assert_allclose(a["velocity"][m], w * np.stack([-r[:, 1], r[:, 0]], 1), rtol=0, atol=1e-12)
        seen.append(sim.time)

    one, _, _ = run_ranks(sc, 1, "x", 80, follows)
    assert min(seen) < 0.005 and any(0.005 < t < 0.015 for t in seen) and max(seen) > 0.035
    three, start, end = run_ranks(sc, 3, "x", 80)
    follows(three)
    assert len(set(start.values())) >= 2 and len(set(end.values())) >= 2   # the plate spans a cut
    assert_same_particles(one.frame_arrays(), three.frame_arrays(), sc)


def flume2d(kind):
    # d = 0.4 m deep, so that 3 slabs along y (>= 6h wide each) all hold water and paddle rows
    return scene2d(0.02, (1.2, 0.6), ([0.06, 0.02], [1.18, 0.4]),
                   [{"type": "wall", "name": "paddle", "min": [0.0, 0.02], "max": [0.0, 0.6],
                     "layers": 2, "direction": "+"}],
                   {"body": "paddle", "type": kind, "height": 0.04, "period": 0.5, "ramp": 0.0}, hswl=0.4)


GATE = {"body": "gate", "type": "gate", "speed": 1.5, "lift": 0.1, "start": 0.002}


@pytest.mark.parametrize("case", ["gate", "piston", "flap"])
def test_gate_and_wavemakers_agree_on_1_and_3_ranks(case):
    """Slabs along y: the vertical gate / paddle has rows in all three slabs (and the lifted
    gate's rows move from one slab into the next)."""
    if case == "gate":   # a dam break: the column behind the gate, lifted at 1.5 m/s
        sc = scene2d(0.02, (1.0, 0.7), ([0.02, 0.02], [0.4, 0.5]),
                     [{"type": "wall", "name": "gate", "min": [0.42, 0.02], "max": [0.42, 0.62],
                       "layers": 2, "direction": "+"}], GATE)
        steps = 100
    else:
        sc, steps = flume2d(case), 150
    p0 = sc.build_particles()
    m0 = p0.kind == MOVING
    one, _, _ = run_ranks(sc, 1, "y", steps)
    three, start, end = run_ranks(sc, 3, "y", steps)
    assert set(start.values()) == {0, 1, 2} and set(end.values()) == {0, 1, 2}
    a, b = one.frame_arrays(), three.frame_arrays()
    assert_same_particles(a, b, sc)
    t = one.time
    m = a["kind"] == MOVING
    if case == "gate":
        assert GATE["start"] < t < GATE["start"] + GATE["lift"] / GATE["speed"]
        np.testing.assert_allclose(a["position"][m], p0.pos[m0] + [0.0, 1.5 * (t - 0.002)], atol=1e-12)
        assert any(start[i] != end[i] for i in start)     # gate rows crossed a slab cut
    elif case == "piston":   # ramp 0: x = S/2 sin(w t) from t = 0
        S = 0.04 / piston_ratio(wavenumber(0.5, 0.4) * 0.4)
        dx = 0.5 * S * math.sin(2 * math.pi * t / 0.5)
        assert dx > 1e-3
        np.testing.assert_allclose(a["position"][m], p0.pos[m0] + [dx, 0.0], atol=1e-12)
    else:
        assert np.abs(a["position"][m] - p0.pos[m0]).max() > 1e-3   # the flap has turned
