"""Dynamic load balancing on mock MPI (virtual times from the cost model: deterministic)."""
import numpy as np
import pytest

from types import SimpleNamespace

from sphgraph import Scene
from sphgraph.backends.compute import numba_cuda
from sphgraph.backends.compute.base import ComputeBackend
from sphgraph.backends.compute.numba_cpu import NumbaCPU
from sphgraph.backends.compute.base import device_capacity
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


@pytest.fixture(scope="module")
def unbalanced():
    """200 steps on 4 ranks, no balancing: the reference particles."""
    return run(steps=200, balance={"enabled": False}).frame_arrays()


def same_particles(a, b):
    np.testing.assert_array_equal(a["id"], b["id"])
    size = 4.0
    assert np.abs(a["position"] - b["position"]).max() < 1e-9 * size


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
            # the speeds are a weighted average over the checks, not the last window's
            a = sim.balance_cfg.smoothing
            assert 0 < a < 1
            avg = None
            for n, f in zip(d["fluid_count"], d["force_seconds"]):
                s = n / f / (n / f).sum()
                avg = s if avg is None else a * s + (1 - a) * avg
            np.testing.assert_allclose(sim.contexts[0].balancer.speed, avg, rtol=1e-12)
    assert t["time"] < t["particles"], t


def test_memory_policy_keeps_every_rank_under_its_cap(monkeypatch, unbalanced):
    """Rank 0 on a device that holds fewer particles than `particles` gives it."""
    caps = [1680, 4000, 4000, 4000]
    d = records(run(steps=60, balance={"every": 20}))
    first = int(np.argmax(d["applied"]))
    assert np.all(d["fluid_count"][first + 1:, 0] > caps[0]), d["fluid_count"]   # the cap bites
    monkeypatch.setattr(NumbaCPU, "particle_capacity",
                        lambda self, state, option=None, sharing=1: caps[state.rank])
    sim = run(steps=200, balance={"every": 20, "policy": "memory"})
    d = records(sim)
    assert d["applied"].any()
    np.testing.assert_array_equal(d["capacity"], np.tile(caps, (len(d["step"]), 1)))
    assert np.all(d["fluid_count"] <= caps), d["fluid_count"]        # at every check
    same_particles(sim.frame_arrays(), unbalanced)


def test_memory_policy_refuses_what_cannot_fit():
    with pytest.raises(InputError, match="cannot fit"):
        target_loads(BalanceConfig(policy="memory"), 10000.0, np.ones(4), [1000] * 4)
    with pytest.raises(InputError, match="max_particles_per_rank.*cannot fit"):
        Simulation(dambreak(), comm="mock", ranks=4,
                   balance={"policy": "memory", "max_particles_per_rank": 1000})   # 5,000 fluid


def test_capacity_cpu_option_and_gpu_free_memory(monkeypatch):
    assert ComputeBackend().particle_capacity(None, 1234) == 1234
    assert ComputeBackend().particle_capacity(None) is None
    # the pure function: held rows + 80 % of the free bytes at the measured size, less boundary
    assert device_capacity(free_bytes=1e9, bytes_per_particle=200.0, held_rows=10_000,
                           fixed_rows=1_000) == 10_000 + 4_000_000 - 1_000
    assert device_capacity(1e9, 0.0) is None
    assert device_capacity(0, 200.0, held_rows=10, fixed_rows=20) == 0
    # numba-cuda: free memory from the context, bytes per particle from the rank's arrays
    dev = SimpleNamespace(cap=10_000, n=9_000, nf=8_000, nbytes=lambda: 2_000_000)   # 200 B per row
    state = SimpleNamespace(extra={"dev": dev})
    monkeypatch.setattr(numba_cuda.cuda, "current_context",
                        lambda: SimpleNamespace(get_memory_info=lambda: (1e9, 2e9)))
    gpu = object.__new__(numba_cuda.NumbaCUDA)    # no device needed
    assert gpu.particle_capacity(state) == 10_000 + 4_000_000 - 1_000
    assert gpu.particle_capacity(state, sharing=2) == 10_000 + 2_000_000 - 1_000
    assert gpu.particle_capacity(state, max_particles_per_rank=50_000) == 50_000


def test_balanced_run_gives_the_same_particles(unbalanced):
    same_particles(run(steps=200, balance={"every": 20}).frame_arrays(), unbalanced)


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


@pytest.mark.parametrize("table,key", [
    ({"evry": 5}, "balance.evry: unknown key"), ({"every": 2.5}, "balance.every: expected an integer"),
    ({"every": True}, "balance.every"), ({"threshold": "low"}, "balance.threshold: expected a number"),
    ({"enabled": 1}, "balance.enabled: expected true or false"), ({"base": "memory"}, "balance.base"),
    ({"smoothing": 0}, "balance.smoothing"), ({"max_particles_per_rank": 0}, "balance.max_particles_per_rank"),
])
def test_scene_balance_table_is_validated(table, key):
    with pytest.raises(InputError, match=key) as e:
        BalanceConfig.resolve({}, table, {}, source="s.toml")
    assert str(e.value).startswith("s.toml: ") and "\n" not in str(e.value)
    with pytest.raises(InputError, match="s.toml: balance: expected a table"):
        BalanceConfig.resolve({}, 5, {}, source="s.toml")
