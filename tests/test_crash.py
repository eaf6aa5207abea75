"""Crash safety (issue 8 §2): SIGKILL at >= 20 random moments, reopen, restart, finish.

A chain of `sphgraph run` processes on a tiny scene with a frame every few steps and a
checkpoint every 7 steps (so many kills land inside a write): each is SIGKILLed at a
random moment after its time loop started, then

* ``output.h5`` opens with h5py and every listed frame reads, with no damaged link;
* the newest checkpoint file on disk loads and its checksum verifies;
* the next process restarts from it (``--restart``) -- and is killed again.

The chain's last process runs to the end; its output is compared with an uninterrupted
run: the same frames, bit for bit.
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
import warnings

import h5py
import pytest
import numpy as np

from sphgraph import checkpoint as ck
from sphgraph.io import list_frames, read_frame

SCENE = """format = 1
name = "crash"
dim = 2
dp = 0.05
end_time = 0.1
output_interval = 0.002
[domain]
min = [0.0, 0.0]
max = [1.0, 1.0]
[[fluid]]
type = "box"
min = [0.0, 0.0]
max = [0.3, 0.4]
[[boundary]]
type = "tank"
min = [0.0, 0.0]
max = [1.0, 0.8]
"""
KILLS = 20
FIELDS = ("id", "kind", "position", "velocity", "density", "pressure")


def start(args, env):
    cmd = [sys.executable, "-m", "sphgraph", "run", *map(str, args), "--checkpoint-every", "7"]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)


def wait_loop_started(p, timeout=60):
    """Block until the process reports its first step (its time loop runs), or ends."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        line = p.stderr.readline()
        if not line:
            return False          # the process ended
        if line.startswith("first step"):
            return True
    raise AssertionError("no first step within the timeout")


def check_after_kill(out):
    with h5py.File(out / "output.h5", "r") as f:
        assert "frames" in f and f.attrs["scene"] == SCENE
    with warnings.catch_warnings():
        warnings.simplefilter("error")        # a dangling or damaged frame link would warn
        frames = list_frames(out)
        for i, _, _ in frames:
            a = read_frame(out, i)
            assert len(a["id"]) == len(np.unique(a["id"]))
    cks = ck.list_checkpoints(out)
    if cks:
        c = ck.load(cks[-1][1])               # the newest on disk: complete and checksum ok
        assert c.step == cks[-1][0]
        assert c.meta["frames"] <= len(frames) + 1   # its frames were written before it
    return len(cks) > 0


def test_sigkill_anywhere_leaves_readable_output_and_restartable_checkpoints(tmp_path):
    scene = tmp_path / "crash.toml"
    scene.write_text(SCENE)
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    # the reference runs in its own process as the chain does: in the test's process numba may
    # reuse overloads other tests compiled, and a fastmath kernel's last bits differ with them
    ref = start([scene, "--out", tmp_path / "ref"], env)
    ref.stderr.read()
    assert ref.wait(timeout=120) == 0
    rng = random.Random(8)
    out = tmp_path / "o"
    kills, chains, restarts = 0, 0, 0
    t0 = time.time()
    finished = False
    while kills < KILLS or not finished:
        chains += 1
        have_ckpt = False
        args = [scene, "--out", out, "--overwrite"]
        while True:
            p = start(args, env)
            started = wait_loop_started(p)
            if started and kills < KILLS:
                time.sleep(rng.uniform(0.0, 0.3))
                p.send_signal(signal.SIGKILL)
            p.stderr.read()
            rc = p.wait(timeout=120)
            if rc == -signal.SIGKILL:
                kills += 1
                have_ckpt = check_after_kill(out)
            else:
                assert rc == 0, f"exit {rc}"
                finished = kills >= KILLS
                break
            if have_ckpt:
                args = [scene, "--restart", out]
                restarts += 1
            else:                             # killed before its first checkpoint: start again
                args = [scene, "--out", out, "--overwrite"]
        if finished:
            break
    assert kills >= KILLS and restarts >= KILLS // 2, (kills, restarts)
    # the run that finished after all the kills equals the uninterrupted one, bit for bit
    fa, fb = list_frames(tmp_path / "ref"), list_frames(out)
    assert fa == fb
    for i, _, _ in fa:
        a, b = read_frame(tmp_path / "ref", i), read_frame(out, i)
        for k in FIELDS:
            assert np.array_equal(a[k], b[k]), (i, k)
    assert time.time() - t0 < 120


# ------------------------------------------------------------------------------ faults under MPI
FAULT_DRIVER = r'''
import sys, time
import numpy as np
from mpi4py import MPI
import sphgraph.graph.tasks as T
from sphgraph.cli import main
kind, scene, out, stamp = sys.argv[1:5]
rank = MPI.COMM_WORLD.rank
orig = T.run_integrate

def faulty(ctx, task):
    orig(ctx, task)
    if ctx.rank == 1 and ctx.state.step == 3:
        with open(stamp, "w") as f:                # when the fault hits (start-up and compilation are over)
            f.write(repr(time.time()))
        if kind == "exception":
            raise RuntimeError("injected fault")
        ctx.state.particles.vel[0, 0] = np.nan     # numerical: found by the check on rank 1

T.run_integrate = faulty
sys.exit(main(["run", scene, "--comm", "mpi", "--out", out, "--quiet", "--max-steps", "20"]))
'''


def _mpiexec():
    import shutil
    exe = shutil.which("mpiexec") or os.path.join(os.path.dirname(sys.executable), "mpiexec")
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        return None
    return exe if os.path.exists(exe) else None


@pytest.mark.parametrize("kind,code,text", [("exception", None, "injected fault"),
                                            ("numerical", 1, "NaN in velocity")])
def test_fault_on_one_rank_stops_all_ranks(tmp_path, kind, code, text):
    exe = _mpiexec()
    if exe is None:
        pytest.skip("mpi4py / mpiexec not installed")
    from conftest import example
    scene = tmp_path / "s.toml"
    d = __import__("sphgraph").Scene.from_toml(example("dambreak2d.toml")).with_overrides(dp=0.04)
    scene.write_text(d.text)
    drv = tmp_path / "drv.py"
    drv.write_text(FAULT_DRIVER)
    env = dict(os.environ, NUMBA_NUM_THREADS="1")
    t0 = time.time()
    stamp = tmp_path / "fault_time"
    r = subprocess.run([exe, "-n", "3", sys.executable, str(drv), kind, str(scene), str(tmp_path / "o"),
                        str(stamp)], capture_output=True, text=True, env=env, timeout=120)
    t_end = time.time()       # mpiexec has returned: every rank has stopped
    took = t_end - t0
    assert r.returncode != 0 if code is None else r.returncode == code, (r.returncode, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if text in ln]
    assert len(lines) == 1, r.stderr          # printed once, naming the rank and the step
    assert "rank 1" in lines[0] and ("step 4" in lines[0] or "step 3" in lines[0]), lines[0]
    assert took < 60, took
    # issue 8 §3: every rank stops within 10 s of the fault (measured from the injection, after start-up)
    assert stamp.exists(), f"the fault was never injected: {r.stderr}"
    since_fault = t_end - float(stamp.read_text())
    assert 0 <= since_fault < 10, (since_fault, took)
