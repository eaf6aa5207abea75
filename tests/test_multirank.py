"""Many ranks: equivalence with one rank, conservation of ids, schedules, on mock and real MPI.

Issue 4 §6: 2D and 3D dam breaks, 1 rank against 2, 3 and 4 mock ranks and 2 and 3
`mpiexec` ranks: positions agree to 1e-9 of the domain size after 200 steps in
float64, and every step the gathered ids are exactly the initial ids; delayed and
reordered messages give bit-identical particles; every shipped schedule, with the
halo order reversed too, gives bit-identical particles on 3 ranks.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import example
from sphgraph import Scene, Schedule, Simulation
from sphgraph.schedule import shipped

STEPS = 200
TOL = 1e-9
FIELDS = ("id", "kind", "position", "velocity", "density", "pressure")


def scene(kind):
    if kind == "2d":
        return Scene.from_toml(example("dambreak2d.toml")).with_overrides(dp=0.04)
    return Scene.from_toml(example("dambreak3d.toml")).with_overrides(dp=0.03)


def axis_of(sc):
    # 3D: split along x, the flow direction (`auto` picks the longest fluid extent, y here)
    return "x" if sc.dim == 3 else None


def kick(sim, vx):
    """Add `vx` to every fluid particle's x velocity (and its Verlet history) on every rank.

    From rest the dam break barely moves in 200 steps (no row crosses a cut); a uniform
    push of 2 m/s moves the rows near the cuts across them, so migration is exercised."""
    for c in sim.contexts:
        p = c.state.particles
        fl = p.kind == 0
        p.vel[fl, 0] += vx
        p.vel_m1[fl, 0] += vx


def run_sim(sc, ranks=1, comm=None, steps=STEPS, schedule="production", check_ids=True, push=0.0,
            **options):
    comm = comm or ("single" if ranks == 1 else "mock")
    sim = Simulation(sc, comm=comm, ranks=ranks, schedule=schedule, comm_options=options or None,
                     decomposition_axis=axis_of(sc))
    if push:
        kick(sim, push)
    ids0 = sim.frame_arrays()["id"].copy()
    assert np.array_equal(ids0, np.arange(sim.n_total))
    for i in range(steps):
        sim.step()
        if check_ids:
            ids = sim.frame_arrays()["id"]
            assert np.array_equal(ids, ids0), f"step {i + 1}: global id set changed"
    return sim, sim.frame_arrays()


_REF = {}


def reference(kind, push=0.0):
    if (kind, push) not in _REF:
        _REF[kind, push] = run_sim(scene(kind), 1, check_ids=False, push=push)[1]
    return _REF[kind, push]


def span(sc):
    return float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))


@pytest.mark.parametrize("kind,push", [("2d", 0.0), ("3d", 0.0), ("2d", 2.0)], ids=["2d", "3d", "2d-migrating"])
@pytest.mark.parametrize("ranks", [2, 3, 4])
def test_mock_ranks_match_one_rank(kind, push, ranks):
    sc = scene(kind)
    sim, a = run_sim(sc, ranks, push=push)
    ref = reference(kind, push)
    assert all(c.state.particles.n > 0 for c in sim.contexts)
    assert np.array_equal(a["id"], ref["id"])
    err = np.abs(a["position"] - ref["position"]).max()
    assert err <= TOL * span(sc), f"{ranks} ranks: max position difference {err:.3e} m"
    assert np.abs(a["velocity"] - ref["velocity"]).max() < 1e-6
    assert np.isfinite(a["density"]).all()


def test_rows_migrate_between_ranks():
    """The pushed equivalence runs exercise migration: rows cross cuts within 200 steps."""
    sc = scene("2d")
    sim = Simulation(sc, comm="mock", ranks=3)
    kick(sim, 2.0)
    first = [set(c.state.particles.id.tolist()) for c in sim.contexts]
    for _ in range(STEPS):
        sim.step()
    moved = sum(len(first[c.rank] - set(c.state.particles.id.tolist())) for c in sim.contexts)
    assert moved > 0


@pytest.mark.parametrize("kind,ranks", [("2d", 3), ("3d", 4)])
def test_delay_and_reorder_are_bit_identical(kind, ranks):
    sc = scene(kind)
    steps = STEPS if kind == "2d" else 100
    push = 2.0 if kind == "2d" else 0.0
    _, plain = run_sim(sc, ranks, steps=steps, check_ids=False, push=push)
    sim, shaken = run_sim(sc, ranks, steps=steps, delay=5e-4, reorder=True, seed=11, push=push,
                          rank_speed=[1.0, 0.5, 2.0, 1.3][:ranks])
    for k in FIELDS:
        assert np.array_equal(plain[k], shaken[k]), k
    assert sim.comm.engine.messages > 0


def _reversed(s: Schedule) -> Schedule:
    d = {"format": 1, "order": list(s.order), "halo_order": [2, 1], "lanes": dict(s.lanes),
         "rebalance": dict(s.rebalance)}
    return Schedule.from_dict(d, name=f"{s.name}-reversed")


def test_every_shipped_schedule_bit_identical_on_3_mock_ranks():
    sc = scene("2d")
    names = shipped()
    assert {"production", "bulk-synchronous"} <= set(names)
    results = {}
    for name in names:
        s = Schedule.load(name)
        for sched in (s, _reversed(s)):
            results[sched.name] = run_sim(sc, 3, schedule=sched, check_ids=False, push=2.0)[1]
    ref = results["production"]
    for name, a in results.items():
        for k in FIELDS:
            assert np.array_equal(a[k], ref[k]), f"{name}: {k} differs from production"


def _pre_order(s: Schedule, pre) -> Schedule:
    rest = [x for x in s.order if x not in ("send_displaced", "recv_displaced", "build_cells")]
    return Schedule.from_dict({"format": 1, "order": list(pre) + rest, "lanes": dict(s.lanes)},
                              name="-".join(pre))


@pytest.mark.parametrize("kind,ranks,fallback", [("2d", 2, False), ("2d", 3, True), ("3d", 3, False)],
                         ids=["2d-2-merge", "2d-3-rebuild", "3d-3-merge"])
def test_recv_displaced_after_build_cells_is_bit_identical(kind, ranks, fallback, monkeypatch):
    """Issue 4 §2: the displaced rows received while the cells are built (production: merged
    into the sorted rows) give the particles, bit for bit, of receiving them before the build
    -- with the merge, and with every arrival forced through the rebuild path."""
    from sphgraph.backends.compute import numba_cpu
    sc = scene(kind)
    steps = STEPS if kind == "2d" else 60
    prod = Schedule.load("production")
    before = _pre_order(prod, ("send_displaced", "recv_displaced", "build_cells"))
    after = _pre_order(prod, ("send_displaced", "build_cells", "recv_displaced"))
    _, ref = run_sim(sc, ranks, steps=steps, schedule=before, check_ids=False, push=2.0)
    calls = {"merged": 0, "rebuilt": 0}
    takes = numba_cpu.grid_takes

    def spy(grid, pos):
        ok, hi = (False, None) if fallback else takes(grid, pos)
        calls["merged" if ok else "rebuilt"] += 1
        return ok, hi
    monkeypatch.setattr(numba_cpu, "grid_takes", spy)
    _, got = run_sim(sc, ranks, steps=steps, schedule=after, check_ids=False, push=2.0)
    for k in FIELDS:
        assert np.array_equal(got[k], ref[k]), k
    assert calls["merged" if not fallback else "rebuilt"] > 0, calls
    if not fallback:
        assert calls["rebuilt"] == 0, calls


def test_output_under_mock_ranks(tmp_path):
    import sphgraph
    from sphgraph.io import read_frame
    res = sphgraph.run(scene("2d"), comm="mock", ranks=3, out=tmp_path / "o", max_steps=5, progress=False)
    f = read_frame(res.out_dir, 0)
    assert np.array_equal(f["id"], np.arange(res.particles))
    last = read_frame(res.out_dir, res.frames - 1)
    assert np.array_equal(last["id"], np.arange(res.particles))
    cols = res.timing.columns()
    assert set(cols["rank"].tolist()) == {0, 1, 2}
    assert (cols["end"] >= cols["start"]).all()
    # /timing's bytes: what each task sent; the edges carry the halos, nothing else sends
    from sphgraph.io import read_timing
    t = read_timing(res.out_dir)
    kind = np.array([str(x).split("@")[0] for x in t["task"]])
    edges = t["bytes"][kind == "send_edges"]
    assert len(edges) and (edges > 0).all()
    assert (t["bytes"][~np.isin(kind, ["send_edges", "send_displaced"])] == 0).all()
    rank1 = t["bytes"][(kind == "send_edges") & (t["rank"] == 1)]
    assert len(rank1) and rank1.min() > 0      # the middle rank sends both ways


# --------------------------------------------------------------------------- real MPI
def mpiexec():
    exe = os.path.join(sys.prefix, "bin", "mpiexec")
    return exe if os.path.exists(exe) else shutil.which("mpiexec")


def run_driver(n, checks, timeout=300, env=None):
    """`mpiexec -n n` of tests/mpi_driver.py's `checks` (`env`: variables set on top of
    this process's); their results by name, each asserted ok."""
    exe = mpiexec()
    if exe is None:
        pytest.skip("no mpiexec (install the mpi extra: pip install sphgraph[mpi])")
    pytest.importorskip("mpi4py")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", **(env or {})}
    driver = os.path.join(os.path.dirname(__file__), "mpi_driver.py")
    p = subprocess.run([exe, "-n", str(n), sys.executable, driver, *checks], env=env, capture_output=True,
                       text=True, timeout=timeout)
    results = {}
    for line in p.stdout.splitlines():
        if line.startswith("{"):
            r = json.loads(line)
            results[r["check"]] = r
    assert p.returncode == 0, f"mpiexec -n {n} exited {p.returncode}:\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    for c in checks:
        assert c in results, f"{c}: no result\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}"
        assert results[c]["ok"], results[c]
    return results


@pytest.mark.mpi
def test_mpi_2_ranks_match_one_rank():
    r = run_driver(2, ["equiv2d", "equiv3d", "equiv2d-migrating"])
    assert r["equiv2d"]["ranks"] == 2 and r["equiv2d"]["steps"] == STEPS
    assert r["equiv3d"]["rel_err"] <= TOL


@pytest.mark.mpi
def test_mpi_3_ranks_match_one_rank_schedules_and_conformance():
    r = run_driver(3, ["equiv2d", "equiv3d", "equiv2d-migrating", "schedules", "conformance"])
    assert r["schedules"]["ranks"] == 3 and len(r["schedules"]["schedules"]) == 2 * len(shipped())
    assert r["conformance"]["failures"] == []


@pytest.mark.mpi
def test_mpi_cli_run_writes_one_output(tmp_path):
    """`mpiexec -n 2 sphgraph run SCENE --comm mpi`: one output.h5, rows in id order."""
    exe = mpiexec()
    if exe is None:
        pytest.skip("no mpiexec")
    from sphgraph.io import list_frames, read_frame
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    out = tmp_path / "run"
    p = subprocess.run([exe, "-n", "2", sys.executable, "-m", "sphgraph", "run", example("dambreak2d.toml"),
                        "--dp", "0.04", "--max-steps", "20", "--comm", "mpi", "--out", str(out)],
                       env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    frames = list_frames(out)
    assert len(frames) >= 2
    f = read_frame(out, frames[-1][0])
    assert np.array_equal(f["id"], np.arange(len(f["id"])))
    from sphgraph.io import read_timing
    t = read_timing(out)
    assert set(np.asarray(t["rank"]).tolist()) == {0, 1}       # every rank's timings, gathered
    assert "recv_halo_1@1" in {str(x) for x in t["task"][np.asarray(t["rank"]) == 1]}
    sent = np.asarray(t["bytes"])[np.char.startswith(np.asarray(t["task"]).astype(str), "send_edges")]
    assert len(sent) and (sent > 0).all()                      # the halo bytes of every rank, gathered
