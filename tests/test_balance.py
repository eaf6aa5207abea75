"""Dynamic load balancing on mock MPI (virtual times from the cost model: deterministic)."""
import numpy as np
import pytest

from sphgraph import Scene
from sphgraph.balance import BalanceConfig, loads, solve_cuts, target_loads
from sphgraph.errors import InputError
from sphgraph.solver import Simulation

from conftest import example


def dambreak():
    """The 2D dam break with its lattice jittered: on a perfect lattice a whole column of
    particles shares one x, and no cut can split it (7 % of a rank's share at this dp)."""
    d = Scene.from_toml(example("dambreak2d.toml")).with_overrides(dp=0.02).to_dict()
    d["initial"]["jitter"] = 0.1
    return Scene.from_dict(d)


def run(steps=300, ranks=4, balance=None, rank_speed=None):
    opts = {"rank_speed": rank_speed} if rank_speed else {}
    sim = Simulation(dambreak(), comm="mock", ranks=ranks, balance=balance, comm_options=opts)
    for _ in range(steps):
        sim.step()
    return sim


def records(sim):
    return sim.contexts[0].balancer.datasets()


def test_particles_policy_keeps_ranks_within_5_percent():
    sim = run(balance={"every": 50, "policy": "particles"})
    d = records(sim)
    assert len(d["step"]) == 6 and d["applied"].any()
    first = int(np.argmax(d["applied"]))
    for k in range(first + 1, len(d["step"])):
        counts = d["fluid_count"][k]          # fluid processed per rank, halos included
        assert np.all(np.abs(counts / counts.mean() - 1) <= 0.05), (d["step"][k], counts)
    n = sum(c.state.particles.n_fluid for c in sim.contexts)
    assert n == sim.n_fluid


def test_time_policy_equalises_force_time_and_beats_particles():
    speed = [1, 2, 1, 0.5]
    t = {}
    for policy in ("particles", "time"):
        sim = run(steps=400, balance={"every": 50, "policy": policy}, rank_speed=speed)
        d = records(sim)
        t[policy] = max(sim.scheduler.times.end)
        if policy == "time":
            fs = d["force_seconds"][-1]
            assert np.all(np.abs(fs / fs.mean() - 1) <= 0.05), fs
    assert t["time"] < t["particles"], t


def test_memory_policy_respects_caps_and_refuses_what_cannot_fit():
    cap = 2000
    sim = run(balance={"every": 50, "policy": "memory", "max_particles_per_rank": cap})
    d = records(sim)
    first = int(np.argmax(d["applied"]))
    assert np.all(d["fluid_count"][first + 1:] <= cap)
    with pytest.raises(InputError, match="cannot fit|capacities"):
        target_loads(BalanceConfig(policy="memory"), 10000.0, np.ones(4), [1000] * 4)


def test_balanced_run_gives_the_same_particles():
    a = run(steps=200, balance={"every": 20}).frame_arrays()
    b = run(steps=200, balance={"enabled": False}).frame_arrays()
    np.testing.assert_array_equal(a["id"], b["id"])
    size = 4.0
    assert np.abs(a["position"] - b["position"]).max() < 1e-9 * size


def test_cuts_keep_6h_and_move_only_into_neighbour_slabs():
    edges = np.linspace(0, 10, 1001)
    hist = np.ones(1000)
    hist[:100] = 50          # dense on the left
    old = np.array([-np.inf, 2.5, 5.0, 7.5, np.inf])
    cuts = solve_cuts(edges, hist, old, np.full(4, (hist.sum() + 0) / 4), reach=0.1, min_width=0.6)
    inner = cuts[1:-1]
    assert np.all(np.diff(np.concatenate([[0], inner, [10]])) >= 0.6 - 1e-12)
    assert inner[0] > -np.inf and inner[0] < 5.0 and inner[1] < 7.5 and inner[1] > 2.5
    ld = loads(edges, hist, np.array([0, *inner, 10.0]), 0.1)
    assert ld.sum() > 0


def test_precedence_flag_over_scene_over_schedule():
    c = BalanceConfig.resolve({"every": 50, "threshold": 0.03}, {"every": 20}, {"every": 7, "threshold": None})
    assert c.every == 7 and c.threshold == 0.03
    with pytest.raises(InputError, match="balance.policy"):
        BalanceConfig.resolve({}, {"policy": "magic"}, {})
