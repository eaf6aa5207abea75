"""Wave generation and absorption (issue 9 §1/§2).

* `test_flume_regular_wave_short`: a piston flume at coarse dp = 0.03 (H = 0.08 m,
  T = 1 s, d = 0.3 m) for 3.8 s; at one wavelength from the paddle the period is within
  5 % of T and the height within 25 % of H (measured at coefh 1.0: T -2.4 %, H -19 %; ~2.7
  particles per wave height damp the wave -- this is NOT the issue's 5 % height target,
  which the flume does not reach yet: dp = 0.02 gave H -24 %; the flume now uses coefh 1.2,
  which fixes the SPH dispersion and halves the deficit (-14 % at dp 0.03), see docs/features.md). The 5 % height check at finer dp and the
  reflection coefficient are in benchmarks/wave_flume.py (numbers in BENCHMARKS.md /
  docs/features.md).
* damping zones: the relaxation factor, and a zone takes the kinetic energy out of the
  fluid inside it while the rest keeps moving.
"""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from sphgraph import Scene, Simulation, waves

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))


def test_damping_factor_follows_dualsphysics_form():
    d = waves.Damping([{"axis": "x", "start": 1.0, "end": 2.0, "overlimit": 0.5, "redumax": 10.0}])
    pos = np.array([[0.5, 0], [1.5, 0], [2.0, 0], [2.4, 0], [2.6, 0]])
    f = d.factor(pos, 0.01)
    np.testing.assert_allclose(f, [1.0, 1 - 0.01 * 10 * 0.25, 0.9, 0.9, 1.0])


def test_damping_zone_removes_kinetic_energy_in_the_zone():
    base = {"format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
            "domain": {"min": [-0.1, -0.1], "max": [2.1, 0.8], "origin": [0.0, 0.0]},
            "physics": {"coefsound": 10.0}, "initial": {"hydrostatic": True},
            "fluid": [{"type": "box", "min": [0.02, 0.02], "max": [1.98, 0.2]}],
            "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [2.0, 0.4]}]}
    ke = {}
    for damp in (False, True):
        d = dict(base)
        if damp:
            d["damping"] = [{"axis": "x", "start": 1.2, "end": 1.6, "redumax": 50.0}]
        sim = Simulation(Scene.from_dict(d))
        for c in sim.contexts:   # a sloshing start: u = 0.3 sin(pi x / 2)
            p = c.state.particles
            fl = p.kind == 0
            p.vel[fl, 0] = 0.3 * np.sin(np.pi * p.pos[fl, 0] / 2.0)
            p.vel_m1[:] = p.vel
        for _ in range(150):
            sim.step()
        a = sim.frame_arrays()
        fl = a["kind"] == 0
        x = a["position"][fl, 0]
        e = 0.5 * (a["velocity"][fl] ** 2).sum(axis=1)
        ke[damp] = (e[x > 1.6].sum(), e[x < 0.8].sum())
    assert ke[True][0] < 0.25 * ke[False][0]      # the zone is (nearly) still
    assert ke[True][1] > 0.7 * ke[False][1]       # away from it the flow goes on


@pytest.mark.slow
def test_flume_regular_wave_short():
    import wave_flume
    r = wave_flume.flume(dp=0.03, end_time=3.8, height=0.08, period=1.0, depth=0.3)
    g = next(iter(r["eta"]))
    cg = waves.group_velocity(1.0, 0.3)
    st = waves.wave_stats(r["t"], r["eta"][g], r["L"] / cg + 0.3, 3.8)
    assert st["period"] == pytest.approx(1.0, rel=0.05)
    assert st["height"] == pytest.approx(0.08, rel=0.25)
