"""Particle shifting (issue 9 §6; sphgraph.shifting): scene keys, nothing when off,
less disorder on a perturbed lattice with the free surface held by the threshold,
1 and 3 mock ranks equal (Verlet, Symplectic, a periodic ring). CUDA: test_shifting_cuda.py."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sphgraph import InputError, Scene, Simulation
from sphgraph.graph.kinds import TaskKind


def tank(mode="full", tfs=1.5, integrator="verlet", **extra):
    """A 2D column (jittered lattice) in a tank: ~700 particles at dp = 0.02."""
    d = {"format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
         "domain": {"min": [-0.1, -0.1], "max": [1.1, 1.0], "origin": [0.0, 0.0]},
         "physics": {"integrator": integrator, "coefsound": 10.0},
         "initial": {"jitter": 0.1},
         "fluid": [{"type": "box", "min": [0.02, 0.02], "max": [0.4, 0.5]}],
         "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.7], "layers": 1}]}
    if mode is not None:
        d["physics"].update(shifting=mode, shifting_tfs=tfs)
    d.update(extra)
    return Scene.from_dict(d, source="<tank>")


def test_scene_keys_are_validated():
    base = tank(None).to_dict()

    def bad(match, **phys):
        d = {**base, "physics": {**base["physics"], **phys}}
        with pytest.raises(InputError, match=match):
            Scene.from_dict(d, source="s.toml")

    bad(r"s\.toml: physics\.shifting: expected one of \"none\", \"nobound\", \"nofixed\", \"full\"",
        shifting="nonfixed")
    bad(r"physics\.shifting_coef: expected a number >= -100 and <= 0", shifting="full", shifting_coef=2.0)
    bad(r"physics\.shifting_coef: expected a number < 0", shifting="full", shifting_coef=0.0)
    bad(r"physics\.shifting_tfs: expected a number >= 0 and < 2", shifting="full", shifting_tfs=2.0)
    bad(r"physics\.shifting_tfs: expected a number >= 0", shifting="full", shifting_tfs=-1.0)
    with pytest.raises(InputError, match=r"s\.toml: shifting: expected a known key"):
        Scene.from_dict({**base, "shifting": {"mode": 3}}, source="s.toml")   # the keys live in [physics]


def test_bad_key_on_the_command_line_is_one_line_exit_2(tmp_path):
    from sphgraph.scene import dumps_toml
    d = tank(None).to_dict()
    d["physics"]["shifting"] = "sometimes"
    (tmp_path / "s.toml").write_text(dumps_toml(d))
    r = subprocess.run([sys.executable, "-m", "sphgraph", "run", str(tmp_path / "s.toml"), "--out",
                        str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "s.toml: physics.shifting: expected one of" in lines[0]


def test_off_costs_nothing_and_changes_nothing():
    """shifting = "none" is the scene without the key: no shifting task, the same step
    graph as without the key (exclusion's end-of-step task only, on by default), bit-identical
    particles."""
    out = {}
    for mode in (None, "none"):
        sim = Simulation(tank(mode))
        assert sim.features.shifting is None and sim.features.kinds == {TaskKind.CHECK, TaskKind.EXCLUDE}
        assert [t.name for t in sim.scheduler.programs[0]] == [
            "build_cells", "forces_interior@1", "dt_local", "dt_allreduce", "integrate@1", "check", "exclude"]
        for _ in range(20):
            sim.step()
        assert "shift_parts" not in sim.contexts[0].state.extra
        out[mode] = sim
    graphs = [[t.name for t in s.scheduler.programs[0]] for s in out.values()]
    assert graphs[0] == graphs[1]
    a, b = out[None].frame_arrays(), out["none"].frame_arrays()
    for k in ("position", "velocity", "density"):
        assert np.array_equal(a[k], b[k])
    on = Simulation(tank("full"))
    for _ in range(20):
        on.step()
    assert np.abs(on.frame_arrays()["position"] - a["position"]).max() > 1e-7   # and on does shift


def _nn_spread(pos, rows):
    """std / mean of the nearest-neighbour distance of `rows` (brute force, a few hundred rows)."""
    d = np.linalg.norm(pos[rows][:, None, :] - pos[None, :, :], axis=2)
    d[d == 0] = np.inf
    m = d.min(axis=1)
    return m.std() / m.mean()


def _shift_only(sc, iters, speed, dt):
    """Apply only the shift `iters` times to the scene's particles moving at `speed` (no
    forces, no update): positions in id order, before and after."""
    sim = Simulation(sc)
    ctx, st = sim.contexts[0], sim.contexts[0].state
    st.particles.vel[:] = speed
    st.dt = dt
    p0 = st.particles.pos[np.argsort(st.particles.id)].copy()
    for _ in range(iters):
        sim.compute.build_cells(st)
        sim.features.shifting.sums(ctx, "interior")
        sim.features.shifting.displacement(ctx)
        sim.features.shifting.apply(ctx)
    p = st.particles
    return p0, p.pos[np.argsort(p.id)]


def test_shifting_evens_a_perturbed_lattice_and_the_threshold_holds_the_surface():
    box = {"domain": {"min": [-0.5, -0.5], "max": [1.5, 1.5], "origin": [0.0, 0.0]},
           "initial": {"jitter": 0.15}, "boundary": [],
           "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.6, 0.6]}]}
    dp = 0.02
    res = {}
    for tfs in (0.0, 1.5):
        p0, p = _shift_only(tank("full", tfs, **box), 60, (1.0, 0.0), 0.01 * dp)   # |v| dt = dp/100
        inner = np.all((p0 > 0.1) & (p0 < 0.5), axis=1)
        top = p0[:, 1] > 0.6 - 0.7 * dp      # the top row of the lattice (jitter 0.15 dp)
        assert top.sum() == 31
        res[tfs] = (_nn_spread(p0, inner), _nn_spread(p, inner), p[top, 1] - p0[top, 1])
    for tfs, (before, after, dy) in res.items():
        assert after < 0.6 * before, (tfs, before, after)      # measured 0.084 -> 0.043 / 0.045
    # without the threshold the truncated support pushes the surface out (by ~0.5 dp here);
    # with ShiftTFS = 1.5 the top row (div r < 1.5) does not move at all
    assert res[0.0][2].min() > 0.2 * dp
    assert np.all(res[1.5][2] == 0.0)


def test_displacement_is_clamped_to_a_tenth_of_dp():
    sc = tank("full", 0.0, initial={"jitter": 0.25})
    p0, p = _shift_only(sc, 1, (50.0, 0.0), 1e-2)       # far beyond the clamp
    d = np.abs(p - p0)
    assert d.max() == pytest.approx(0.1 * sc.dp, rel=1e-12)
    kind = sc.build_particles().kind
    assert np.all(d[kind != 0] == 0.0)                  # boundaries never shift


# a periodic channel: 1 rank sums the periodic images (part halo_3), 3 ranks a ring of halos
PERIODIC = {"domain": {"min": [0.0, -0.1], "max": [1.0, 1.0], "origin": [0.01, 0.0], "periodic": ["x"]},
            "fluid": [{"type": "box", "min": [0.0, 0.02], "max": [1.0, 0.3]}],
            "boundary": [{"type": "wall", "min": [0.01, 0.0], "max": [0.99, 0.0], "direction": "-"}]}


@pytest.mark.parametrize("integrator,mode,extra", [
    ("verlet", "full", {}),
    ("symplectic", "nobound", {}),
    ("verlet", "nofixed", PERIODIC),
])
def test_one_and_three_ranks_give_the_same_particles(integrator, mode, extra):
    sc = tank(mode, integrator=integrator, **extra)
    out = {}
    for ranks in (1, 3):
        sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks, decomposition_axis="x")
        for _ in range(25):
            sim.step()
        out[ranks] = sim.frame_arrays()
    ref = Simulation(tank("none", integrator=integrator, **extra))
    for _ in range(25):
        ref.step()
    shift = np.abs(out[1]["position"] - ref.frame_arrays()["position"]).max()
    assert shift > 1e-8, shift                           # the shift acted
    for k in ("position", "velocity", "density"):
        np.testing.assert_allclose(out[3][k], out[1][k], rtol=0, atol=1e-9)
