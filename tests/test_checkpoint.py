"""Checkpoint / restart, clean stops and run-time invariants (issue 8 §1, §5).

Restart from a checkpoint is bit-identical to an uninterrupted run (float64, CPU, same
rank count) -- also from a step with step mod 40 != 0 (the Verlet Euler cadence) and
with the load balancer's state -- and within 1e-9 of the domain size on another rank
count for a short continuation. Checkpoints are checksummed; a damaged newest one is
skipped. SIGTERM and --walltime write a checkpoint and exit 0.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from conftest import example
from sphgraph import Scene, Simulation
from sphgraph import checkpoint as ck
from sphgraph.cli import main
from sphgraph.errors import InputError, NumericalError
from sphgraph.invariants import check_memory
from sphgraph.io import list_frames, read_frame
from sphgraph.solver import run

FIELDS = ("id", "kind", "position", "velocity", "density", "pressure")


def small(end_time=0.06, output_interval=0.01):
    sc = Scene.from_toml(example("dambreak2d.toml"))
    d = sc.to_dict()
    d.update(dp=0.04, end_time=end_time, output_interval=output_interval)
    return Scene.from_dict(d, source="dambreak2d.toml")


def same_output(a, b, exact=True, tol=0.0):
    fa, fb = list_frames(a), list_frames(b)
    assert fa == fb, (fa, fb)
    for i, _, _ in fa:
        x, y = read_frame(a, i), read_frame(b, i)
        for k in FIELDS:
            if exact:
                assert np.array_equal(x[k], y[k]), (i, k)
            else:
                assert np.abs(x[k].astype(float) - y[k].astype(float)).max() <= tol, (i, k)
    return fa


@pytest.mark.parametrize("comm,ranks", [("single", 1), ("mock", 2)])
def test_restart_is_bit_identical(tmp_path, comm, ranks):
    sc = small()
    full = run(sc, out=tmp_path / "a", progress=False, comm=comm, ranks=ranks)
    # stop at step 63 (63 % 40 != 0: inside a Verlet Euler cycle), checkpoint, then continue
    part = run(sc, out=tmp_path / "b", progress=False, comm=comm, ranks=ranks, max_steps=63,
               checkpoint_every=63)
    assert part.steps == 63 and part.checkpoint.endswith("ckpt_000000063.h5")
    rest = run(sc, restart=tmp_path / "b", progress=False, comm=comm, ranks=ranks)
    assert rest.start_step == 63 and rest.steps == full.steps and rest.time == full.time
    frames = same_output(tmp_path / "a", tmp_path / "b")
    assert len(frames) == 7


def test_restart_keeps_balancer_state(tmp_path):
    """2 mock ranks, rebalanced every 20 steps; checkpoints every 30 (between checks)."""
    sc = small(end_time=0.04)
    opts = dict(comm="mock", ranks=2, progress=False, balance={"every": 20, "threshold": 0.0})
    run(sc, out=tmp_path / "a", **opts)
    run(sc, out=tmp_path / "b", max_steps=150, checkpoint_every=30, **opts)
    assert [s for s, _ in ck.list_checkpoints(tmp_path / "b")] == [120, 150]   # the last 2 kept
    run(sc, restart=tmp_path / "b", **opts)
    same_output(tmp_path / "a", tmp_path / "b")
    with h5py.File(tmp_path / "a" / "output.h5") as fa, h5py.File(tmp_path / "b" / "output.h5") as fb:
        assert np.array_equal(fa["balance/step"][()], fb["balance/step"][()])


@pytest.mark.parametrize("ranks_after", [1, 3])
def test_restart_on_another_rank_count(tmp_path, ranks_after):
    sc = small(end_time=1.0, output_interval=1.0)
    run(sc, out=tmp_path / "a", comm="mock", ranks=2, progress=False, max_steps=80)
    run(sc, out=tmp_path / "b", comm="mock", ranks=2, progress=False, max_steps=30, checkpoint_every=30)
    comm = "single" if ranks_after == 1 else "mock"
    r = run(sc, restart=tmp_path / "b", comm=comm, ranks=ranks_after, progress=False, max_steps=80)
    assert r.ranks == ranks_after and r.steps == 80
    span = float(np.max(sc.domain_max - sc.domain_min))
    a, b = read_frame(tmp_path / "a"), read_frame(tmp_path / "b")
    assert a["step"] == b["step"] == 80
    assert np.array_equal(a["id"], b["id"])
    assert np.abs(a["position"] - b["position"]).max() <= 1e-9 * span


def test_checksum_and_fallback(tmp_path, capsys):
    sc = small(end_time=0.02)
    run(sc, out=tmp_path / "o", progress=False, checkpoint_every=40)
    cks = ck.list_checkpoints(tmp_path / "o")
    assert len(cks) == 2
    ok = ck.load(cks[-1][1])
    assert ok.meta["sha256"] and ok.meta["precision"] == "float64" and ok.meta["ranks"] == 1
    assert ok.blocks[0].vel_m1.shape == ok.blocks[0].vel.shape
    with h5py.File(cks[-1][1], "r+") as f:   # flip one density: the checksum must catch it
        f["rank_0000/rho"][3] += 1e-12
    with pytest.raises(InputError, match="checksum"):
        ck.load(cks[-1][1])
    assert ck.find_latest(tmp_path / "o").step == cks[0][0]
    assert "skipping" in capsys.readouterr().err
    with open(cks[0][1], "r+b") as f:         # truncated file: unreadable, reported, not a crash
        f.truncate(100)
    with pytest.raises(InputError, match="valid checkpoint"):
        ck.find_latest(tmp_path / "o", warn=False)


def test_time_cadence_and_end_checkpoint(tmp_path):
    sc = small(end_time=0.03)
    r = run(sc, out=tmp_path / "o", progress=False, checkpoint_every="0.01s")
    cks = ck.list_checkpoints(tmp_path / "o")
    assert [s for s, _ in cks][-1] == r.steps        # the end state is checkpointed too
    t = [ck.load(p).time for _, p in cks]
    assert t[0] >= 0.02 - 1e-12 and t[0] < 0.0201
    assert not [n for n in os.listdir(tmp_path / "o" / "checkpoints") if n.endswith(".tmp")]


def test_walltime_stops_cleanly(tmp_path, capsys):
    sc = tmp_path / "s.toml"
    sc.write_text(small(end_time=5.0).text)
    rc = main(["run", str(sc), "--out", str(tmp_path / "o"), "--quiet", "--walltime", "0.5"])
    err = capsys.readouterr().err
    assert rc == 0 and "stopped by walltime" in err and "--restart" in err, err
    c = ck.find_latest(tmp_path / "o")
    assert c.step > 0 and c.time < 5.0
    rc = main(["run", str(sc), "--restart", str(tmp_path / "o"), "--quiet", "--end-time",
               str(c.time + 0.01)])
    assert rc == 0
    assert list_frames(tmp_path / "o")[-1][2] > c.step


def test_sigterm_checkpoints_and_restart_matches(tmp_path):
    sc = tmp_path / "s.toml"
    sc.write_text(small(end_time=0.3, output_interval=0.01).text)
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "sphgraph", "run", str(sc), "--quiet"]
    ref = subprocess.run(cmd + ["--out", str(tmp_path / "a")], capture_output=True, text=True, env=env,
                         timeout=300)
    assert ref.returncode == 0, ref.stderr
    p = subprocess.Popen(cmd + ["--out", str(tmp_path / "b")], stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 60
    while not os.path.exists(tmp_path / "b" / "frames" / "frame_000003.h5") and time.time() < deadline:
        time.sleep(0.02)
    p.send_signal(signal.SIGTERM)
    err = p.communicate(timeout=120)[1]
    assert p.returncode == 0 and "stopped by SIGTERM" in err, err
    c = ck.find_latest(tmp_path / "b")
    assert 0 < c.time < 0.3
    r = subprocess.run(cmd + ["--restart", str(tmp_path / "b")], capture_output=True, text=True, env=env,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    same_output(tmp_path / "a", tmp_path / "b")


def test_restart_refuses_other_input(tmp_path, capsys):
    sc = small(end_time=0.01)
    f = tmp_path / "s.toml"
    f.write_text(sc.text)
    assert main(["run", str(f), "--out", str(tmp_path / "o"), "--quiet", "--checkpoint-every", "10"]) == 0
    capsys.readouterr()
    cases = [
        (["--restart", str(tmp_path / "o"), "--dp", "0.05"], "dp"),                  # another scene
        (["--restart", str(tmp_path / "nowhere")], "--restart"),
        (["--restart", str(tmp_path / "o"), "--precision", "float32"], "--precision"),
        (["--restart", str(tmp_path / "o"), "--out", str(tmp_path / "x")], "--out"),
        (["--out", str(tmp_path / "p"), "--checkpoint-every", "0"], "--checkpoint-every"),
        (["--out", str(tmp_path / "p"), "--checkpoint-every", "fast"], "--checkpoint-every"),
        (["--out", str(tmp_path / "p"), "--walltime", "-1"], "--walltime"),
    ]
    for extra, key in cases:
        rc = main(["run", str(f), "--quiet", *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and key in err[0], (extra, err)
    assert not os.path.exists(tmp_path / "p") and not os.path.exists(tmp_path / "x")


# ------------------------------------------------------------------------------ invariants
def tiny_sim(**kw):
    return Simulation(small(end_time=0.01), **kw)


def test_invariant_lost_particle_names_it():
    sim = tiny_sim()
    sim.step()
    st = sim.contexts[0].state
    lost = int(st.particles.id[7])
    st.particles = st.particles.take(np.r_[0:7, 8:st.particles.n])
    sim.compute.prepare(st)
    with pytest.raises(NumericalError, match=f"particle id {lost} is missing") as e:
        sim.step()
    assert e.value.particle_id == lost and e.value.step == 2


def test_invariant_duplicate_and_nan_velocity():
    sim = tiny_sim(comm="mock", ranks=2)
    sim.step()
    st = sim.contexts[1].state
    dup = int(st.particles.id[0])
    st.particles.id[1] = dup
    with pytest.raises(NumericalError, match=f"particle id {dup} appears twice"):
        sim.check()
    sim = tiny_sim()
    sim.step()
    p = sim.contexts[0].state.particles
    fl = int(np.flatnonzero(p.kind == 0)[0])
    p.vel[fl, 0] = np.nan
    with pytest.raises(NumericalError, match="NaN in velocity") as e:
        sim.check()
    assert e.value.particle_id == int(p.id[fl])


def test_invariants_can_be_switched_off():
    sim = tiny_sim(invariants=False)
    sim.step()
    st = sim.contexts[0].state
    st.particles = st.particles.take(np.arange(1, st.particles.n))
    sim.compute.prepare(st)
    sim.step()     # nobody counts


def test_memory_guard_refuses_before_allocating(tmp_path, capsys):
    sc = small()
    with pytest.raises(InputError, match="fit in memory"):
        check_memory(sc, np.float64, available=1000)
    check_memory(sc, np.float64, available=10 ** 12)
    # 10^10 particles with limits.max_particles raised: refused by the memory estimate, at once
    d = sc.to_dict()
    d.update(dp=2e-5, limits={"max_particles": 10 ** 12})
    f = tmp_path / "huge.toml"
    from sphgraph.scene import dumps_toml
    f.write_text(dumps_toml(d))
    t0 = time.perf_counter()
    rc = main(["run", str(f), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "fit in memory" in err[0], err
    assert time.perf_counter() - t0 < 5 and not os.path.exists(tmp_path / "o")


def test_memory_guard_of_device_rows_and_row_fills():
    """With the rows on a device (numba-cuda) the host holds the particle arrays and what
    the upload stages, not the CPU backend's force buffers and sort copies; a box-only
    scene's row fill keeps no index vectors. SPHERIC 2 at float32 stays within ~110 B per
    particle of host memory then (issue 6 §6: the largest scene on one GPU)."""
    from sphgraph.invariants import bytes_per_particle
    sc = Scene.from_toml(example("spheric2.toml"))
    assert sc.uses_row_fill()
    dev = bytes_per_particle(3, 4, device_rows=True, row_fill=True)
    assert dev <= 110 < bytes_per_particle(3, 4, device_rows=True) < bytes_per_particle(3, 4)
    n = sc.estimated_particles()
    check_memory(sc, np.float32, available=n * dev, device_rows=True)
    with pytest.raises(InputError, match="fit in memory"):
        check_memory(sc, np.float32, available=n * dev)


def test_setup_seconds_by_phase():
    sim = Simulation(small(), invariants=True)
    assert list(sim.setup_seconds) == ["scene", "particles", "state", "rest"]
    assert all(v >= 0 for v in sim.setup_seconds.values())


def test_overwrite_drops_an_earlier_runs_checkpoints(tmp_path):
    """Found by test_crash: --overwrite kept old checkpoints, and a restart then mixed a stale
    state with the new output.h5."""
    sc = small(end_time=0.02)
    run(sc, out=tmp_path / "o", progress=False, checkpoint_every=20)
    assert ck.list_checkpoints(tmp_path / "o")
    run(sc, out=tmp_path / "o", progress=False, overwrite=True, max_steps=5)
    assert [s for s, _ in ck.list_checkpoints(tmp_path / "o")] == [5]   # only the new run's end state


def with_samplers(sc):
    """`small()` with a pressure probe, a height gauge and the force on the right wall."""
    d = sc.to_dict()
    d["probes"] = {"interval": 0.004, "points": [{"name": "P1", "position": [3.99, 0.1]}],
                   "heights": [{"name": "H1", "position": [0.5]}]}
    d["forces"] = {"interval": 0.004, "bodies": [{"name": "wall", "min": [3.96, -0.1], "max": [4.1, 3.1]}]}
    return Scene.from_dict(d, source="dambreak2d.toml")


def _groups(path):
    out = {}
    with h5py.File(path / "output.h5") as f:
        for g in ("probes", "forces"):
            f[g].visititems(lambda name, obj: out.__setitem__(f"{g}/{name}", obj[()])
                            if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.mark.parametrize("comm,ranks", [("single", 1), ("mock", 2)])
def test_restart_keeps_probe_and_force_samples(tmp_path, comm, ranks):
    """/probes and /forces of a restarted run equal an uninterrupted run's, bit for bit: the
    samples taken before the checkpoint travel in it (a SIGKILL leaves no /probes)."""
    sc = with_samplers(small(end_time=0.03))
    run(sc, out=tmp_path / "a", progress=False, comm=comm, ranks=ranks)
    run(sc, out=tmp_path / "b", progress=False, comm=comm, ranks=ranks, max_steps=37, checkpoint_every=37)
    with h5py.File(tmp_path / "b" / "output.h5", "a") as f:   # as a SIGKILL would leave it
        for g in ("probes", "forces"):
            del f[g]
    run(sc, restart=tmp_path / "b", progress=False, comm=comm, ranks=ranks)
    a, b = _groups(tmp_path / "a"), _groups(tmp_path / "b")
    assert sorted(a) == sorted(b) and len(a["probes/time"]) >= 6
    for k in a:
        assert np.array_equal(a[k], b[k]), k
