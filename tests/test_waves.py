"""Wave generation and absorption (issue 9 §1/§2).

* `test_flume_regular_wave_*_within_5_percent_at_one_wavelength` (issue 9 §8): the piston
  flume of benchmarks/wave_flume.py (H = 0.08 m, T = 1 s, d = 0.3 m, dp = 0.015, second-order
  generation, no artificial viscosity, water's laminar viscosity, mDBC walls and paddle) to
  8 s; at one wavelength from the paddle the zero up-crossing height and the period of waves
  3-6 are within 5 % of the target (numbers and the other settings in BENCHMARKS.md §7, §19
  and docs/features.md). Marked `long` with the damping zone's reflection: deselected by the
  default suite, `pytest -m long` runs them (README).
* damping zones: the relaxation factor, and a zone takes the kinetic energy out of the
  fluid inside it while the rest keeps moving; a zone across two slabs gives the same
  particles on 1 and 3 mock ranks; a flume's zone reflects < 5 % of a regular wave (the
  two-gauge separation is checked on a synthetic wave of known reflection).
* the flap wavemaker runs: its angle is r(t) atan(S / 2l) sin(2 pi t / T) with the stroke S
  of first-order wavemaker theory, and it makes a wave of period T at a gauge.
"""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from sphgraph import Scene, Simulation, waves
from sphgraph.particles import MOVING

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))


def test_damping_factor_follows_dualsphysics_form():
    d = waves.Damping([{"axis": "x", "start": 1.0, "end": 2.0, "overlimit": 0.5, "redumax": 10.0}])
    pos = np.array([[0.5, 0], [1.5, 0], [2.0, 0], [2.4, 0], [2.6, 0]])
    f = d.factor(pos, 0.01)
    np.testing.assert_allclose(f, [1.0, 1 - 0.01 * 10 * 0.25, 0.9, 0.9, 1.0])


SLOSH = {"format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
         "domain": {"min": [-0.1, -0.1], "max": [2.1, 0.8], "origin": [0.0, 0.0]},
         "physics": {"coefsound": 10.0}, "initial": {"hydrostatic": True},
         "fluid": [{"type": "box", "min": [0.02, 0.02], "max": [1.98, 0.2]}],
         "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [2.0, 0.4]}]}


def slosh(sim):
    """A sloshing start: u = 0.3 sin(pi x / 2) in the fluid, on every rank."""
    for c in sim.contexts:
        p = c.state.particles
        fl = p.kind == 0
        p.vel[fl, 0] = 0.3 * np.sin(np.pi * p.pos[fl, 0] / 2.0)
        p.vel_m1[:] = p.vel


def test_damping_zone_removes_kinetic_energy_in_the_zone():
    ke = {}
    for damp in (False, True):
        d = dict(SLOSH)
        if damp:
            d["damping"] = [{"axis": "x", "start": 1.2, "end": 1.6, "redumax": 50.0}]
        sim = Simulation(Scene.from_dict(d))
        slosh(sim)
        for _ in range(150):
            sim.step()
        a = sim.frame_arrays()
        fl = a["kind"] == 0
        x = a["position"][fl, 0]
        e = 0.5 * (a["velocity"][fl] ** 2).sum(axis=1)
        ke[damp] = (e[x > 1.6].sum(), e[x < 0.8].sum())
    assert ke[True][0] < 0.25 * ke[False][0]      # the zone is (nearly) still
    assert ke[True][1] > 0.7 * ke[False][1]       # away from it the flow goes on


@pytest.fixture(scope="module")
def flume_waves():
    """Issue 9 §8's flume to 8 s: order-2 stroke, no artificial viscosity, water's laminar
    viscosity, mDBC walls and paddle (`boundary = "mdbc"`: the paddle's ghost nodes move with
    it); the zero up-crossing statistics of waves 3-6 one wavelength from the paddle (after the
    ramp's waves). At the example's dp 0.015 (7,076 particles, ~6 minutes on one core)."""
    import wave_flume
    end, dp = 8.0, 0.015
    r = wave_flume.flume(dp=dp, end_time=end, height=0.08, period=1.0, depth=0.3, order=2,
                         physics={"visc_alpha": 0.0, "laminar_nu": 1e-6, "boundary": "mdbc"})
    g = next(iter(r["eta"]))                       # one wavelength from the paddle's face
    assert g == pytest.approx(1.5 * dp + r["L"])
    cg = waves.group_velocity(1.0, 0.3)
    st = waves.wave_stats(r["t"], r["eta"][g], r["L"] / cg + 2.0, end)
    assert len(st["heights"]) >= 2
    return st


@pytest.mark.slow
@pytest.mark.long
def test_flume_regular_wave_period_within_5_percent_at_one_wavelength(flume_waves):
    """The period of waves 3-6 at one wavelength within 5 % of the paddle's (measured with
    mDBC: -0.21 ... -0.53 % over twelve round-off-perturbed runs of benchmarks/flume_spread.py
    on two CPUs)."""
    assert flume_waves["period"] == pytest.approx(1.0, rel=0.05)


@pytest.mark.slow
@pytest.mark.long
def test_flume_regular_wave_height_within_5_percent_at_one_wavelength(flume_waves):
    """The mean zero up-crossing height of waves 3-6 at one wavelength within 5 % of the
    paddle's H. Particle chaos moves it with round-off, so it was measured over starts a few
    ulps apart (benchmarks/flume_spread.py --boundary mdbc, 2026-12-06): -1.48 ... -2.44 %
    (mean -1.91 %, six starts, the GPU host's Xeon) and -0.88 ... -2.61 % (mean -1.84 %, six
    starts, the AMD vm); at dp 0.02 -2.25 ... -3.40 % (mean -2.82 %, six starts, the AMD vm,
    2026-12-07). With DBC walls and paddle the same flume gave -4.05 ... -6.53 % (mean
    -5.38 %): not within 5 % whatever the round-off (BENCHMARKS.md §18)."""
    assert flume_waves["height"] == pytest.approx(0.08, rel=0.05)


def test_two_gauge_separation_recovers_a_known_reflection():
    """benchmarks/wave_flume.reflection (Goda & Suzuki 1976) on a synthetic incident wave of
    amplitude 0.02 m plus a reflected one of 0.006 m (Kr = 0.3), gauges L/4 apart."""
    import wave_flume
    L = waves.wavelength(1.0, 0.3)
    k, w = 2 * np.pi / L, 2 * np.pi
    t = np.arange(0.0, 8.0, 0.02)
    x1, x2 = 1.0, 1.0 + 0.25 * L
    eta = lambda x: 0.02 * np.cos(k * x - w * t) + 0.006 * np.cos(k * x + w * t + 0.7)
    assert wave_flume.reflection(t, eta(x1), eta(x2), 0.25 * L, 1.0, 3.0, 8.0) == pytest.approx(0.3, rel=1e-3)
    assert wave_flume.reflection(t, eta(x1) - 0.006 * np.cos(k * x1 + w * t + 0.7),
                                 eta(x2) - 0.006 * np.cos(k * x2 + w * t + 0.7),
                                 0.25 * L, 1.0, 3.0, 8.0) < 1e-3


@pytest.mark.slow
@pytest.mark.long
def test_damping_zone_reflects_below_5_percent_of_a_regular_wave():
    """Issue 9 §2: a 2.4 L flume (dp 0.03, H = 0.04 m) with the damping zone over its last
    1.2 L reflects < 5 % of the wave (Goda & Suzuki, gauges at 0.5 L and 0.75 L, 5-8 s, when
    the far wall's reflection is back at the gauges; measured 1.2 %; without the zone the same
    gauges saw 32 %, and the separation itself is checked on a known reflection above)."""
    import wave_flume
    L = waves.wavelength(1.0, 0.3)
    x1 = 1.5 * 0.03 + 0.5 * L
    r = wave_flume.flume(dp=0.03, end_time=8.0, height=0.04, gauges=[x1, x1 + 0.25 * L],
                         damping=True, length=round(2.4 * L / 0.03) * 0.03)
    kr = wave_flume.reflection(r["t"], r["eta"][x1], r["eta"][x1 + 0.25 * L], 0.25 * L, 1.0, 5.0, 8.0)
    assert kr < 0.05


def test_damping_zone_across_slabs_agrees_on_1_and_3_ranks():
    d = dict(SLOSH, dp=0.04, fluid=[{"type": "box", "min": [0.04, 0.04], "max": [1.96, 0.2]}],
             damping=[{"axis": "x", "start": 1.0, "end": 1.8, "redumax": 50.0}])
    sc = Scene.from_dict(d)
    zone = waves.Damping.from_scene(sc)
    out = {}
    for ranks in (1, 3):
        sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks, decomposition_axis="x")
        slosh(sim)
        damped = {c.rank for c in sim.contexts
                  if np.any(zone.factor(c.state.particles.pos[c.state.particles.kind == 0], 1e-3) < 1)}
        for _ in range(100):
            sim.step()
        out[ranks] = (sim.frame_arrays(), damped)
    assert len(out[3][1]) >= 2          # the zone holds fluid of two slabs
    a, b = out[1][0], out[3][0]
    assert np.array_equal(a["id"], b["id"])
    size = float(np.max(sc.domain_max - sc.domain_min))
    np.testing.assert_allclose(b["position"], a["position"], rtol=0, atol=1e-9 * size)
    np.testing.assert_allclose(b["velocity"], a["velocity"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(b["density"], a["density"], rtol=1e-12, atol=0)


def test_flap_follows_wavemaker_theory_and_makes_a_wave_of_its_period():
    """Flap (H = 0.06 m, T = 1 s, d = 0.3 m, ramp T/2) in a 2.4 m flume at dp = 0.05:
    the paddle turns rigidly about its hinge by theta r(t) sin(wt), theta = atan(S / 2l),
    S = H / (H/S) (Dean & Dalrymple eq. 6.17), l the hinge's depth below the still-water
    level; at a gauge 0.6 m away the wave's period is T within 5 % (measured -0.5 %) and
    its height H within 25 % (measured -6 %: ~6 particles per depth)."""
    import wave_flume
    dp, H, T, depth, end, xg = 0.05, 0.06, 1.0, 0.3, 4.5, 0.6
    d, _ = wave_flume.flume_scene(dp=dp, depth=depth, height=H, period=T, paddle="flap",
                                  end_time=end, length=2.4)
    d["motion"][0]["ramp"] = 0.5
    d["damping"][0]["start"] = 1.6
    sc = Scene.from_dict(d)
    p0 = sc.build_particles()
    ref = p0.pos[p0.kind == MOVING]
    hinge = np.array([ref[:, 0].mean(), ref[:, 1].min()])   # the default: the body's lowest point
    arm = (dp - 0.5 * dp + depth) - hinge[1]                 # still-water level - hinge
    k = waves.wavenumber(T, depth)
    kd = k * depth
    ratio = 4 * np.sinh(kd) / kd * (kd * np.sinh(kd) - np.cosh(kd) + 1) / (np.sinh(2 * kd) + 2 * kd)
    S = H / ratio
    theta = np.arctan(S / (2 * arm))
    sim = Simulation(sc)
    r0 = ref - hinge
    t, ang, eta = [], [], []
    while sim.time < end:
        sim.step()
        if sim.step_count % 10:
            continue
        a = sim.frame_arrays()
        r1 = a["position"][a["kind"] == MOVING] - hinge
        # clockwise angle of each row about the hinge (the top moving towards +x is positive)
        turn = -np.arctan2(r0[:, 0] * r1[:, 1] - r0[:, 1] * r1[:, 0], (r0 * r1).sum(axis=1))
        np.testing.assert_allclose(np.linalg.norm(r1, axis=1), np.linalg.norm(r0, axis=1), atol=1e-12)
        assert np.ptp(turn) < 1e-12                                 # one rigid rotation
        t.append(sim.time)
        ang.append(turn[0])
        eta.append(waves.surface_elevation(a["position"], a["kind"], xg, dp, sim.consts.h,
                                           0.5 * depth, depth + 3 * H) - depth)
    t, ang = np.array(t), np.array(ang)
    ramp = np.where(t < 0.5 * T, 0.5 * (1 - np.cos(np.pi * t / (0.5 * T))), 1.0)
    np.testing.assert_allclose(ang, theta * ramp * np.sin(2 * np.pi * t / T), rtol=0, atol=1e-12)
    after = t > 0.5 * T
    assert np.abs(ang[after]).max() == pytest.approx(theta, rel=1e-3)
    assert arm * np.tan(np.abs(ang[after]).max()) == pytest.approx(0.5 * S, rel=1e-3)  # stroke at the SWL
    st = waves.wave_stats(t, ang, 0.5 * T, end)
    assert st["period"] == pytest.approx(T, rel=1e-4) and len(st["periods"]) >= 3
    gauge = waves.wave_stats(t, eta, 1.5, end)
    assert len(gauge["periods"]) >= 2
    assert gauge["period"] == pytest.approx(T, rel=0.05)
    assert gauge["height"] == pytest.approx(H, rel=0.25)
