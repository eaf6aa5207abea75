"""Where the method fails: each failure provoked on a small run, detected from the run's
state (NaN/density checks, energy, density spread, particle spacing, wall crossing,
pressure noise: never from the parameters) and named; the recommended setting stays stable."""
import pytest

from sphgraph.solver import Simulation
from sphgraph.stability import (THRESHOLDS, drop_scene, jet_scene, set_drop_velocity, set_jet_velocity,
                                stability_map, tank_scene, watch)


def sim_of(scene):
    try:
        return Simulation(scene, invariants=False)
    except TypeError:
        return Simulation(scene)


def test_cfl_too_large_blows_up_within_a_few_steps():
    sim = sim_of(drop_scene(cfl=2.0, end_time=10.0))
    set_drop_velocity(sim, 5.0)
    v = watch(sim, 50, every=1, energy_growth=1.5)
    assert v.name == "blow-up" and v.step <= 20, v
    sim = sim_of(drop_scene(cfl=0.2, end_time=10.0))      # DualSPHysics' CFL 0.2
    set_drop_velocity(sim, 5.0)
    assert watch(sim, 100, every=1, energy_growth=1.5).stable


def test_blow_up_is_a_numerical_error_with_step_and_cause():
    """Past the energy detector, the solver itself stops with NumericalError (exit 1)."""
    sim = sim_of(drop_scene(cfl=4.0, end_time=10.0))
    set_drop_velocity(sim, 5.0)
    v = watch(sim, 200, every=1)
    assert v.name == "blow-up" and v.step is not None and v.step < 200, v
    assert any(c in v.detail for c in ("NaN", "domain", "density")), v


def test_speed_of_sound_too_low_density_varies_more_than_one_percent():
    """Elliptical drop, |v| up to 1 m/s: coefsound 1 (c0 3.1 m/s, Mach 0.3) compresses the
    fluid by > 1 %; coefsound 20 (Mach 0.016) stays far below."""
    sim = sim_of(drop_scene(coefsound=1.0, end_time=10.0))
    set_drop_velocity(sim, 5.0)
    v = watch(sim, 200, every=10, density_bound=THRESHOLDS["density_variation"])
    assert v.name == "compressibility" and v.value > 0.01, v
    sim = sim_of(drop_scene(coefsound=20.0, end_time=10.0))
    set_drop_velocity(sim, 5.0)
    v = watch(sim, 300, every=10, density_bound=THRESHOLDS["density_variation"])
    assert v.stable and v.value < 0.002, v


def _expanding_drop(**kw):
    sim = sim_of(drop_scene(end_time=10.0, coefsound=5.0, **kw))
    set_drop_velocity(sim, -3.0)
    p = sim.contexts[0].state.particles
    p.vel[:, 1] = 3.0 * p.pos[:, 1]           # radial expansion: the fluid goes into tension
    p.vel_m1[:] = p.vel
    return sim


def test_tensile_instability_clumps_particles_under_negative_pressure():
    """An expanding patch (negative pressure): with alpha = 0.02 particles pair up (< dp/2
    apart) within 0.15 s; artificial viscosity alpha = 1 keeps them > 0.8 dp apart over 0.2 s."""
    v = watch(_expanding_drop(visc_alpha=0.02), 500, every=20, clump_fraction=THRESHOLDS["clump_fraction"])
    assert v.name == "clumping", v
    sim = _expanding_drop(visc_alpha=1.0)
    v = watch(sim, 500, every=50, clump_fraction=THRESHOLDS["clump_fraction"])
    assert v.stable and sim.time > 0.15, v


def test_dbc_penetration_at_high_impact_speed():
    """A slab hitting the floor at 20 m/s (Mach 0.7 for c0 = 28 m/s): one DBC layer lets
    fluid through; three layers (the kernel's support) hold it."""
    dp = 0.02
    sim = sim_of(jet_scene(dp=dp, layers=1))
    set_jet_velocity(sim, 20.0)
    v = watch(sim, 300, every=5, wall=(1, 0.0, -1))
    assert v.name == "penetration", v
    sim = sim_of(jet_scene(dp=dp, layers=3))
    set_jet_velocity(sim, 20.0)
    assert watch(sim, 300, every=5, wall=(1, -2 * dp, -1)).stable


def test_no_density_diffusion_pressure_noise():
    """Dam break at dp = 0.05, t = 0.064 s: without density diffusion the interior pressure
    noise (each particle against its neighbours' Shepard mean) is ~10 % of rho g H, above the
    5 % bound; with Fourtakas diffusion (delta 0.1) it is ~2 %."""
    scale = 1000.0 * 9.81 * 2.0
    v = watch(sim_of(tank_scene(dp=0.05, diffusion="none", delta=0.0)), 400, every=80, p_scale=scale,
              noise_bound=THRESHOLDS["pressure_noise"])
    assert v.name == "pressure-noise", v
    v = watch(sim_of(tank_scene(dp=0.05, diffusion="fourtakas", delta=0.1)), 400, every=80, p_scale=scale,
              noise_bound=THRESHOLDS["pressure_noise"])
    assert v.stable and v.value < 0.04, v


def test_stability_map_cells():
    cells = stability_map([0.2, 2.0], [1.0, 20.0], steps=60)
    got = {(c["cfl"], c["coefsound"]): c["verdict"] for c in cells}
    assert got[(0.2, 20.0)] == "stable"
    assert got[(2.0, 20.0)] == "blow-up"
    assert got[(0.2, 1.0)] == "compressibility"


def test_cli_plot_stability(tmp_path, capsys):
    from sphgraph.cli import main
    png = tmp_path / "map.png"
    assert main(["plot", "stability", "--cfl", "0.2,3.2", "--coefsound", "20", "--steps", "20",
                 "-o", str(png)]) == 0
    out = capsys.readouterr().out
    assert "cfl 0.2 coefsound 20: stable" in out and "cfl 3.2 coefsound 20: blow-up" in out
    assert png.stat().st_size > 1000


def test_penetration_map_cells_come_from_the_state(monkeypatch):
    """Coarse slab-on-floor map (dp 0.04): one DBC layer at 40 m/s lets fluid through, three
    layers at 10 m/s hold; with the velocity never set (same speed parameter, fluid at rest)
    the same cell holds: the count is read from the particle positions."""
    from sphgraph import stability
    cells = stability.penetration_map([10.0, 40.0], ["dbc-1", "dbc-3"], dp=0.04)
    got = {(c["model"], c["speed"]): c for c in cells}
    bad, held = got[("dbc-1", 40.0)], got[("dbc-3", 10.0)]
    assert bad["verdict"] == "penetration" and bad["through"] > 0 and bad["step"] is not None, bad
    assert held["verdict"] == "stable" and held["through"] == 0 and held["time"] >= 0.3 / 10.0, held
    assert all(c["ms_per_step"] > 0 for c in cells)
    monkeypatch.setattr(stability, "set_jet_velocity", lambda sim, speed: None)
    still = stability.penetration_map([40.0], ["dbc-1"], dp=0.04)[0]
    assert still["verdict"] == "stable" and still["through"] == 0, still


def test_cli_plot_stability_penetration(tmp_path, capsys):
    from sphgraph.cli import main
    png = tmp_path / "pen.png"
    assert main(["plot", "stability", "--map", "penetration", "--speeds", "40", "--models", "dbc-1,mdbc-3",
                 "--dp", "0.04", "-o", str(png)]) == 0
    out = capsys.readouterr().out
    assert "dbc-1 40 m/s: penetration (" in out and "mdbc-3: " in out and "ms/step" in out
    assert png.stat().st_size > 1000
    assert main(["plot", "stability", "--map", "penetration", "--models", "dbc-2", "-o", str(png)]) == 2
    assert "expected some of dbc-1, dbc-3, mdbc-1, mdbc-3" in capsys.readouterr().err
