"""`[probes]` / `[forces]` from each rank's own rows (`ComputeBackend.probe_bounds` / `probe_sums`,
summed on the root): equal to the host sampler over every rank's gathered rows (tests/
probe_reference.py) within round-off, on one rank and on three mock ranks, numba-cpu and float64;
numba-cuda (numba's CUDA simulator, float64, one and two mock ranks) equal to numba-cpu's sums
of the same rows.

The scenes: a 2D dam break against a column (~1,000 particles), three point probes (one dry),
three height columns (one dry), three bodies (the column, the whole tank, its floor, which
every rank holds a part of); its 3D twin (~1,000 particles); and examples/platform_wave.toml
(3D, a wave maker, heights and forces on the legs). Measured: 3e-15 (one rank) and 2e-15
(three ranks) relative, heights equal; platform_wave's forces 3e-13 of the largest component
(its legs' net force is a small remainder of large opposite pressures). Each check also shows
that a result 1e-10 off fails it, and that the body rows near the ranks' ends matter (without
them the forces on three ranks are ~1e-2 off).
"""
from __future__ import annotations

import textwrap

import numpy as np
import pytest
from cudasim_helpers import gpu, run_script

import probe_reference as R
import sphgraph.probes as SP
from sphgraph import Scene, Simulation

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]
TOL = 1e-12

SCENE_2D = {
    "format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
    "domain": {"min": [-0.1, -0.1], "max": [1.7, 0.8], "origin": [0.0, 0.0]},
    "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.6, 0.3]}],
    "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.6, 0.75], "layers": 2},
                 {"type": "box", "min": [0.3, 0.0], "max": [0.4, 0.2]}],
    "probes": {"points": [{"name": "P1", "position": [0.2, 0.1]}, {"name": "Pdry", "position": [1.2, 0.5]},
                          {"name": "Pcol", "position": [0.45, 0.05]}],
               "heights": [{"name": "H1", "position": [0.1]}, {"name": "H2", "position": [0.5]},
                           {"name": "Hdry", "position": [1.4]}]},
    "forces": {"bodies": [{"name": "col", "min": [0.3, 0.0], "max": [0.4, 0.2]},
                          {"name": "tank", "min": [-1, -1], "max": [2, 2]},
                          {"name": "floor", "min": [-1, -1], "max": [2, 0.0]}]}}

# a 3D tank with a column, for the device kernels' third axis (~1,100 particles; long enough
# for two ranks of 6h)
SCENE_3D = {
    "format": 1, "dim": 3, "dp": 0.05, "end_time": 1.0,
    "domain": {"min": [-0.15, -0.15, -0.15], "max": [1.25, 0.45, 0.6], "origin": [0.0, 0.0, 0.0]},
    "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [0.5, 0.3, 0.25]}],
    "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [1.1, 0.3, 0.5], "layers": 1},
                 {"type": "box", "min": [0.6, 0.1, 0.0], "max": [0.7, 0.2, 0.2]}],
    "probes": {"points": [{"name": "P1", "position": [0.1, 0.15, 0.05]},
                          {"name": "Pdry", "position": [0.9, 0.15, 0.4]}],
               "heights": [{"name": "H1", "position": [0.1, 0.15]}, {"name": "Hdry", "position": [0.9, 0.25]}]},
    "forces": {"bodies": [{"name": "col", "min": [0.6, 0.1, 0.0], "max": [0.7, 0.2, 0.2]},
                          {"name": "tank", "min": [-1, -1, -1], "max": [2, 2, 2]},
                          {"name": "floor", "min": [-1, -1, -1], "max": [2, 2, 0.0]}]}}


def errors(s, got: dict, ref: dict, speed: float) -> dict:
    """Worst error of each kind of `got` (a sampler's probes and forces rows) against the
    reference: pressures relative to the largest probe pressure, velocities to the fastest
    fluid row, forces to the body's largest component; heights absolute (equal bits)."""
    p_scale = max([abs(v["pressure"]) for v in ref["probes"].values() if isinstance(v, dict)] + [1e-30])
    out = {"pressure": 0.0, "velocity": 0.0, "height": 0.0, "force": 0.0}
    for name, v in ref["probes"].items():
        g = got["probes"][name]
        if isinstance(v, dict):
            out["pressure"] = max(out["pressure"], abs(g["pressure"] - v["pressure"]) / p_scale)
            out["velocity"] = max(out["velocity"], float(np.abs(g["velocity"] - v["velocity"]).max()) / speed)
        else:
            out["height"] = max(out["height"], abs(g - v))
    for name, v in ref["forces"].items():
        out["force"] = max(out["force"], float(np.abs(got["forces"][name] - v).max() / max(np.abs(v).max(), 1e-30)))
    return out


def last_rows(s) -> dict:
    return {"probes": s.rows["probes"][-1], "forces": s.rows["forces"][-1]}


def float64_pressures(sim, a: dict) -> dict:
    """The gathered rows `a` with each row's pressure from its density in float64, as the sampler
    takes it (sphgraph.physics.probes). In a float32 run the gathered pressures come from the
    float32 equation of state, whose cancellation near rho0 leaves ~1e-2 Pa: 1e-3 of this scene's
    small probe pressures (measured on numba-cpu and on the H200 alike)."""
    from sphgraph.physics.eos import pressure
    if a["pressure"].dtype == np.float64:
        return a
    return dict(a, pressure=pressure(a["density"].astype(np.float64), np.asarray(sim.consts.prm, np.float64)))


def test_float32_sample_is_of_the_pressures_from_the_densities():
    """numba-cpu, float32, 3 steps: the sample equals the reference of float64 pressures from the
    float32 densities (measured 1e-17 pressure, 8e-9 force) and not the float32 ones (1.5e-3)."""
    sim = Simulation(Scene.from_dict(dict(SCENE_2D, dp=0.03)), precision="float32", sample=True)
    for _ in range(3):
        sim.step()
    s, a = sim.probe_sampler, sim.frame_arrays()
    speed = float(np.sqrt((a["velocity"][a["kind"] == 0] ** 2).sum(1)).max())
    assert max(errors(s, last_rows(s), R.sample(s, float64_pressures(sim, a)), speed).values()) < 1e-6
    assert errors(s, last_rows(s), R.sample(s, a), speed)["pressure"] > 1e-4


def perturbed(got: dict, rel=1e-10) -> dict:
    """`got` with every value 1e-10 off (relative; heights by 1e-10 m)."""
    out = {"probes": {}, "forces": {k: v * (1 + rel) for k, v in got["forces"].items() if k not in ("time", "step")}}
    for k, v in got["probes"].items():
        if isinstance(v, dict):
            out["probes"][k] = {"pressure": v["pressure"] * (1 + rel) + rel,
                                "velocity": v["velocity"] * (1 + rel) + rel}
        elif k not in ("time", "step"):
            out["probes"][k] = v + rel
    return out


def check_steps(scene, steps, **kw):
    """Run `steps` steps sampling each step's end (the probes task); each sample against the
    reference from the same state's gathered rows. Returns the worst errors."""
    sim = Simulation(scene, sample=True, **kw)
    s = sim.probe_sampler
    worst = {}
    for _ in range(steps):
        sim.step()
        a = sim.frame_arrays()
        ref = R.sample(s, a)
        got = last_rows(s)
        assert got["probes"]["time"] == sim.time and got["forces"]["step"] == sim.step_count
        speed = max(float(np.sqrt((a["velocity"][a["kind"] == 0] ** 2).sum(1)).max()), 1e-12)
        e = errors(s, got, ref, speed)
        for k, v in e.items():
            worst[k] = max(worst.get(k, 0.0), v)
        bad = errors(s, perturbed(got), ref, speed)     # the check sees a result 1e-10 off
        assert max(bad.values()) > 10 * TOL, bad
    return worst, sim


@pytest.mark.parametrize("dim, ranks", [(2, 1), (2, 3), (3, 1), (3, 2)])
def test_sums_of_ranks_equal_the_gathered_sample(dim, ranks):
    kw = {} if ranks == 1 else {"comm": "mock", "ranks": ranks}
    worst, sim = check_steps(Scene.from_dict(SCENE_2D if dim == 2 else SCENE_3D), 12 if dim == 2 else 6, **kw)
    assert max(worst.values()) < TOL, worst
    assert worst["height"] == 0.0, worst
    if ranks > 1:   # the floor crosses every cut
        assert sim.nranks == ranks and len({c.state.cut_lo for c in sim.contexts}) == ranks


def test_sums_of_ranks_equal_the_gathered_sample_platform_wave():
    """examples/platform_wave.toml (3D: a wave maker, heights, forces on the legs), three ranks."""
    import tomllib
    with open(ROOT / "examples" / "platform_wave.toml", "rb") as f:
        d = tomllib.load(f)
    d["probes"]["interval"] = d["forces"]["interval"] = 0.0     # a sample every step
    scene = Scene.from_dict(d, source="platform_wave.toml")
    worst, _ = check_steps(scene, 4, comm="mock", ranks=3)
    assert max(worst.values()) < TOL, worst
    assert worst["height"] == 0.0, worst


def test_the_body_rows_near_the_ranks_ends_are_needed(monkeypatch):
    """Without the exchange of body rows near each rank's ends (band 0), the forces on a body
    that crosses a cut lose the pairs across it: far off (the check would catch that)."""
    monkeypatch.setattr(SP, "EDGE_BAND_H", 0.0)
    sim = Simulation(Scene.from_dict(SCENE_2D), sample=True, comm="mock", ranks=3)
    for _ in range(3):
        sim.step()
    ref = R.sample(sim.probe_sampler, sim.frame_arrays())
    got = last_rows(sim.probe_sampler)
    assert errors(sim.probe_sampler, got, ref, 1.0)["force"] > 1e-4


def test_one_rank_and_three_sample_the_same_state_alike():
    """`sample(sim)` (outside a step, as `sphgraph.run` samples the initial state) on one rank
    and on three: the same rows, the same sample within round-off."""
    scene = Scene.from_dict(dict(SCENE_2D, initial={"hydrostatic": True}))
    got = []
    for kw in ({}, {"comm": "mock", "ranks": 3}):
        sim = Simulation(scene, **kw)
        s = SP.ProbeSampler(scene)
        s.sample(sim)
        got.append(last_rows(s))
    ref = {"probes": {k: v for k, v in got[0]["probes"].items() if k not in ("time", "step")},
           "forces": {k: v for k, v in got[0]["forces"].items() if k not in ("time", "step")}}
    e = errors(None, got[1], ref, 1.0)
    assert max(e.values()) < TOL, e
    assert got[0]["probes"]["P1"]["pressure"] > 100 and np.abs(got[0]["forces"]["floor"]).max() > 1


# -------------------------------------------------------------------------- numba-cuda (simulator)
SCRIPT = textwrap.dedent('''
    import json, sys
    import numpy as np
    sys.path.insert(0, "tests")
    import probe_reference as R
    from test_probe_sums import SCENE_2D, SCENE_3D, errors, last_rows
    from sphgraph import Scene, Simulation
    from sphgraph.backends.compute.base import ComputeBackend
    from test_probe_sums import float64_pressures

    def compare(ranks, steps, precision="float64", dim=2):
        """numba-cuda's partial sums of each rank against numba-cpu's (ComputeBackend's host
        implementation) of the same rows, and the sample against the gathered reference."""
        scene = Scene.from_dict(dict(SCENE_2D, dp=0.03) if dim == 2 else SCENE_3D)
        kw = {} if ranks == 1 else {"comm": "mock", "ranks": ranks}
        sim = Simulation(scene, backend="numba-cuda", precision=precision, sample=True, **kw)
        for _ in range(steps):
            sim.step()
        s = sim.probe_sampler
        on_device = [c.state.extra.get("bytes_by_kind", {}).get("d2h:probes", 0) for c in sim.contexts]
        host = [c.state.extra.get("bytes_by_kind", {}).get("d2h:sync_host", 0) for c in sim.contexts]
        a = float64_pressures(sim, sim.frame_arrays())
        ref = R.sample(s, a)
        speed = float(np.sqrt((a["velocity"][a["kind"] == 0] ** 2).sum(1)).max())
        sample = errors(s, last_rows(s), ref, speed)
        # the same partial sums, device against host, rank by rank
        pts = np.concatenate([s._points, s._column_points(0, np.linspace(0.0, 0.4, 17))])
        boxes, band = s._boxes, 3.0 * s.h
        cols = s._columns
        band = band if ranks > 1 else 0.0
        bounds = [c.compute.probe_bounds(c.state, cols, boxes, band) for c in sim.contexts]
        extra = np.concatenate([np.zeros((0, 5))] + [b["edge"] for b in bounds])
        dev = [(b, c.compute.probe_sums(c.state, pts, boxes, extra)) for b, c in zip(bounds, sim.contexts)]
        cpu = []
        for c in sim.contexts:
            b = ComputeBackend.probe_bounds(c.compute, c.state, cols, boxes, band)
            cpu.append((b, ComputeBackend.probe_sums(c.compute, c.state, pts, boxes, extra)))
        rel = 0.0
        for (db, ds), (cb, cs) in zip(dev, cpu):
            assert np.array_equal(db["zrange"], cb["zrange"]) and np.array_equal(db["edge"], cb["edge"])
            # each sum against the largest of its kind over the rows (the velocity sums' three
            # components together, a force's three together, as `errors` scales a sample): a
            # component zero by the scene's symmetry holds only round-off, which on a GPU (other
            # summation order) is not that of the host
            for key, groups in (("points", ((0,), (1,), (2, 3, 4))), ("forces", ((0, 1, 2),))):
                for g in groups:
                    scale = max(float(np.abs(cs[key][:, list(g)]).max(initial=0.0)), 1e-30)
                    rel = max(rel, float(np.abs(ds[key][:, list(g)] - cs[key][:, list(g)]).max(initial=0.0)) / scale)
        nedge = sum(len(b["edge"]) for b in bounds)
        return {"sample": sample, "partial_rel": rel, "on_device": on_device, "host_bytes": host,
                "edge_rows": nedge, "samples": len(s.rows["forces"])}
''')


@pytest.mark.parametrize("ranks, dim", [(1, 2), (2, 2), (1, 3), (2, 3)])
def test_simulator_sums_equal_numba_cpu(ranks, dim):
    """Measured: each rank's partial sums 7e-16 from numba-cpu's (relative to the largest of
    each kind), the sample 2e-15 off the reference; on two ranks 236 edge rows exchanged."""
    steps = 2 if dim == 2 else 1
    r = run_script(SCRIPT + f"\nprint(json.dumps(compare({ranks}, {steps}, dim={dim})))", sim=True, timeout=600)
    assert r["samples"] == steps, r
    assert all(b > 0 for b in r["on_device"]) and not any(r["host_bytes"]), r   # sampled on the device
    assert r["partial_rel"] < TOL, r
    assert max(r["sample"].values()) < TOL and r["sample"]["height"] == 0.0, r
    if ranks > 1:
        assert r["edge_rows"] > 0, r


@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_gpu_sums_equal_numba_cpu(precision):
    """On a real GPU (lanes, fast launches), one and two mock ranks, 2D and 3D, 3 steps. The sums are
    float64 in both precisions; in float32 the device's pressures are float32 (the rows' packed
    pressure) where the host computes them from the density in float64: 1e-6 there for the
    partial sums (measured 6e-9 of the force) and for the sample against the reference of float64
    pressures (`float64_pressures`). Measured on the H200 in float64 (the per-kind scale above):
    8e-16 to 3e-13; the float32 sample against the float32 pressures was 1.5e-3 off there, as on
    numba-cpu (`test_float32_sample_is_of_the_pressures_from_the_densities`); against the
    float64 ones it is not yet run on a device."""
    out = run_script(SCRIPT + f"\nprint(json.dumps([compare(1, 3, {precision!r}), compare(2, 3, {precision!r}), "
                              f"compare(1, 3, {precision!r}, dim=3), compare(2, 3, {precision!r}, dim=3)]))",
                     sim=False, timeout=600)
    for r in out:
        assert all(b > 0 for b in r["on_device"]) and not any(r["host_bytes"]), r
        tol = TOL if precision == "float64" else 1e-6
        assert r["partial_rel"] < tol, r
        assert max(r["sample"].values()) < tol, r
