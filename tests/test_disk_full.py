"""A full disk (issue 24 §2): exit 1 with one line naming the path and the free space, no
temporary file left, earlier frames and checkpoints intact, and `--restart` exact once space
returns. Twice: ENOSPC injected at the write calls (runs everywhere) and a real small
filesystem (a 300 KiB tmpfs where this machine lets us mount one); under mpiexec -n 2 a full
disk stops every rank."""
from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import uuid

import numpy as np
import pytest

from sphgraph import checkpoint as ck
from sphgraph import files
from sphgraph.cli import main
from sphgraph.io import list_frames, read_frame
from sphgraph.toml_writer import dumps_toml

SCENE = {
    "format": 1, "name": "full", "dim": 2, "dp": 0.02, "end_time": 0.04, "output_interval": 0.004,
    "domain": {"min": [-0.1, -0.1], "max": [1.1, 1.1]},
    "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.4, 0.5]}],
    "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8]}],
}
FLAGS = ["--quiet", "--checkpoint-every", "30"]   # 11 frames of 40 KB, checkpoints of 58 KB (2 kept)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    p = d / "full.toml"
    p.write_text(dumps_toml(SCENE))
    ref = d / "ref"
    assert main(["run", str(p), "--out", str(ref), *FLAGS]) == 0
    return p, ref


def _tmp_files(out):
    return [os.path.join(r, n) for r, _, fs in os.walk(out) for n in fs if n.endswith(".tmp")]


def _check_stopped_cleanly(out, lines):
    assert len(lines) == 1 and "disk full" in lines[0] and "bytes free" in lines[0], lines
    assert str(out) in lines[0]
    assert not _tmp_files(out)
    frames = list_frames(out)                      # every linked frame reads
    assert frames and [f[0] for f in frames] == list(range(len(frames)))
    for _, path in ck.list_checkpoints(out):
        ck.load(path)                              # checksums verify


def _check_restart_exact(scene_path, out, ref, capsys):
    capsys.readouterr()
    assert main(["run", str(scene_path), "--restart", str(out), *FLAGS]) == 0, capsys.readouterr().err
    a, b = list_frames(out), list_frames(ref)
    assert a == b
    x, y = read_frame(out), read_frame(ref)
    for k in ("id", "position", "velocity", "density", "pressure"):
        assert np.array_equal(x[k], y[k]), k


@pytest.mark.parametrize("target,nth,in_memory", [
    ("frame_", 3, True),          # the 3rd frame file (frames 0, 1 are written)
    ("ckpt_", 2, True),           # the 2nd checkpoint (one is on disk)
    ("output.h5", 4, True),       # the master, after a frame file was committed
    ("frame_", 4, False),         # a file too large for memory: HDF5 writes it directly
])
def test_enospc_injected_at_the_write_calls(scene, tmp_path, capsys, monkeypatch, target, nth, in_memory):
    scene_path, ref = scene
    out = tmp_path / "o"
    calls = {"n": 0}
    no_space = OSError(errno.ENOSPC, "No space left on device")

    def hit(path):     # the nth write of a file of the target kind
        if target in os.path.basename(path):
            calls["n"] += 1
            if calls["n"] >= nth:
                raise no_space

    real_write_all = files._write_all

    def write_all(path, data, fsync):
        hit(path)
        return real_write_all(path, data, fsync)
    monkeypatch.setattr(files, "_write_all", write_all)
    if not in_memory:
        import h5py
        monkeypatch.setattr(files, "IMAGE_LIMIT", -1)
        real_create = h5py.Group.create_dataset

        def create_dataset(self, name, *a, **kw):
            if name == "id":          # a frame's first dataset: one count a file
                hit(self.file.filename)
            return real_create(self, name, *a, **kw)
        monkeypatch.setattr(h5py.Group, "create_dataset", create_dataset)
    capsys.readouterr()
    rc = main(["run", str(scene_path), "--out", str(out), *FLAGS])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 1, lines
    _check_stopped_cleanly(out, lines)
    monkeypatch.undo()                             # space returns
    _check_restart_exact(scene_path, out, ref, capsys)


@pytest.fixture
def small_fs(tmp_path):
    """A 300 KiB tmpfs at tmp_path/fs (root on Linux), unmounted afterwards."""
    mnt = tmp_path / "fs"
    mnt.mkdir()
    if shutil.which("mount") is None or not sys.platform.startswith("linux"):
        pytest.skip("no mount command: a small filesystem cannot be made here")
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", f"sphgraph-{uuid.uuid4().hex[:8]}", str(mnt)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({p.stderr.strip() or 'not permitted'}); "
                    "the injected-ENOSPC test covers the write path")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_real_small_filesystem(scene, small_fs, capsys):
    scene_path, ref = scene
    out = small_fs / "o"
    capsys.readouterr()
    rc = main(["run", str(scene_path), "--out", str(out), *FLAGS])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 1, lines
    _check_stopped_cleanly(out, lines)
    subprocess.run(["mount", "-o", "remount,size=16m", str(small_fs)], check=True)   # space returns
    _check_restart_exact(scene_path, out, ref, capsys)


@pytest.mark.mpi
def test_a_full_disk_stops_every_mpi_rank(scene, small_fs):
    from test_multirank import mpiexec
    exe = mpiexec()
    if exe is None:
        pytest.skip("no mpiexec")
    scene_path, _ = scene
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    p = subprocess.run([exe, "-n", "2", sys.executable, "-m", "sphgraph", "run", str(scene_path), "--comm", "mpi",
                        "--watchdog", "30", "--out", str(small_fs / "o"), *FLAGS],
                       env=env, capture_output=True, text=True, timeout=120)
    full = [x for x in p.stderr.splitlines() if "disk full" in x]
    assert p.returncode == 1 and len(full) == 1 and "aborting all ranks" in full[0], p.stderr[-2000:]
    assert "Traceback" not in p.stderr
    assert not _tmp_files(small_fs / "o")
