"""Verlet's step of the density-diffusion term (issue 22 §1): `[physics] diffusion_time`.

DualSPHysics' leapfrog rho^{n+1} = rho^{n-1} + 2 dt ar^n integrates the diffusion term, a decay
of each density towards its neighbours', with an odd-even mode that grows by (1 + dt K_a) a step
between the Euler steps; it is what stops the fine runs (docs/validation.md, "Runs that stop for
one particle"). In still water at rest the same mode shows at delta 0.3 in tens of steps; the
DuFort-Frankel step holds the water at rest there and equals the leapfrog where dt K_a is small.
"""
from __future__ import annotations

import numpy as np
import pytest

from sphgraph import InputError, NumericalError, Scene, Simulation
from sphgraph.config import P_BW, P_C0, P_DDT_KH, P_ETA2


def still(mode="leapfrog", delta=0.3, diffusion="fourtakas", dp=0.04):
    # water at rest, hydrostatic start, a tank of 3 layers; 390 fluid + 381 boundary particles
    return Scene.from_dict({
        "format": 1, "dim": 2, "dp": dp, "end_time": 1.0,
        "domain": {"min": [-0.2, -0.2], "max": [1.8, 0.8], "origin": [0.0, 0.0], "exclude_outside": False},
        "physics": {"delta": delta, "diffusion": diffusion, "diffusion_time": mode},
        "initial": {"hydrostatic": True},
        "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [1.6, 0.4]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.6, 0.6], "layers": 3}]})


@pytest.mark.parametrize("diffusion", ["fourtakas", "molteni", "fourtakas-full"])
def test_leapfrog_diffusion_grows_odd_even_and_dufort_frankel_holds_still_water(diffusion):
    sim = Simulation(still("leapfrog", diffusion=diffusion), invariants=False)
    change = []     # each step's density change, by particle id
    with pytest.raises(NumericalError, match="density outside") as err:
        for _ in range(120):
            p = sim.contexts[0].state.particles
            before = p.rho[np.argsort(p.id)].copy()
            sim.step()
            p = sim.contexts[0].state.particles
            change.append(p.rho[np.argsort(p.id)] - before)
    assert sim.step_count < 100
    # the particle that stops the run: its density change flips sign every step (a two-step
    # period) and grows ~1.4x a step (1 + dt K_a), measured; the Euler step (every 40) resets it
    pid = err.value.particle_id
    last = [c[pid] for c in change[-9:]]
    assert all(a * b < 0 for a, b in zip(last, last[1:]))
    assert abs(last[-1]) > 10 * abs(last[0])

    sim = Simulation(still("dufort-frankel", diffusion=diffusion), invariants=False)
    for _ in range(400):
        sim.step()
    p = sim.contexts[0].state.particles
    fl = p.kind == 0
    # at rest: one step changes a density by ~2.5e-3 kg/m^3 (measured); the leapfrog's mode: > 100
    assert np.abs(p.rho - p.rho_m1)[fl].max() < 1e-2


def test_dufort_frankel_equals_leapfrog_where_dt_K_is_small():
    out = {}
    for mode in ("leapfrog", "dufort-frankel"):
        sim = Simulation(still(mode, delta=0.1), invariants=False)
        for _ in range(200):
            sim.step()
        out[mode] = sim.frame_arrays()
    a, b = out["leapfrog"], out["dufort-frankel"]
    assert np.array_equal(a["id"], b["id"])
    # measured: 7.8e-4 kg/m^3 and 4.2e-7 m after 200 steps
    assert np.abs(a["density"] - b["density"]).max() < 5e-3
    assert np.abs(a["position"] - b["position"]).max() < 1e-5


def test_K_of_each_particle_against_numpy():
    """K_a = sum_b k_ab over the fluid neighbours whose term counts, 0 where a boundary
    neighbour cancels the diffusion (fourtakas, DBC), from the kernel against a direct sum."""
    from sphgraph.probes import grad_factor
    sim = Simulation(still("dufort-frankel", delta=0.1), invariants=False)
    for _ in range(3):
        sim.step()
    st = sim.contexts[0].state
    c = sim.compute
    c.build_cells(st)
    c.forces(st, "interior")
    c.reduce_forces(st, 99)
    p = st.particles
    k = st.consts
    prm = k.prm
    d = p.pos[:, None, :] - p.pos[None, :, :]
    r2 = (d * d).sum(-1)
    r = np.sqrt(r2)
    near = (r2 <= 4 * k.h ** 2) & (r2 >= 1e-18)
    F = np.where(near, grad_factor(r, k.h, float(prm[P_BW]), "wendland"), 0.0)
    kab = -prm[P_DDT_KH] * prm[P_C0] * k.mass_fluid * F * r2 / ((r2 + prm[P_ETA2]) * p.rho[None, :])
    fluid = p.kind == 0
    K = (kab * fluid[None, :]).sum(1)
    cancelled = (near & ~fluid[None, :]).any(1)
    K = np.where(fluid & ~cancelled, K, 0.0)
    assert cancelled.any() and (K > 0).any()
    np.testing.assert_allclose(st.ddk, K, rtol=1e-12, atol=1e-12 * K.max())


def test_diffusion_time_errors():
    with pytest.raises(InputError, match="physics.diffusion_time"):
        still("crank-nicolson")
    d = still("dufort-frankel").to_dict()
    d["physics"]["integrator"] = "symplectic"
    with pytest.raises(InputError, match="physics.diffusion_time.*symplectic"):
        Scene.from_dict(d)
