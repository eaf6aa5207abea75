"""CLI contract under mpiexec (DESIGN.md §5): rank 0 prints a bad-input line once and every
rank exits 2, nothing written."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from test_multirank import mpiexec


@pytest.mark.mpi
def test_bad_input_under_mpiexec_is_printed_once_and_every_rank_exits_2(tmp_path):
    exe = mpiexec()
    if exe is None:
        pytest.skip("no mpiexec")
    bad = tmp_path / "bad.toml"
    bad.write_text('format = 1\nname = "bad"\ndim = 2\ndp = -1.0\nend_time = 1.0\n')
    out = tmp_path / "out"
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    p = subprocess.run([exe, "-n", "2", sys.executable, "-m", "sphgraph", "run", str(bad), "--comm", "mpi",
                        "--out", str(out)], env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    lines = [x for x in p.stderr.splitlines() if x.startswith("sphgraph: error:")]
    assert len(lines) == 1 and "dp" in lines[0], p.stderr
    assert not out.exists()


SAMPLERS = """
[probes]
interval = 0.004
points = [{name = "P1", position = [3.99, 0.1]}]
heights = [{name = "H1", position = [0.5]}]

[forces]
interval = 0.004
bodies = [{name = "wall", min = [3.96, -0.1], max = [4.1, 3.1]}]
"""


@pytest.mark.mpi
def test_probes_and_forces_under_mpiexec_match_one_rank(tmp_path):
    """Every rank joins the root's sampling gathers (a non-root rank once kept gathering every
    step and the run hung): /probes and /forces of 2 MPI ranks equal the single-rank series."""
    import h5py
    import numpy as np
    from conftest import example
    exe = mpiexec()
    if exe is None:
        pytest.skip("no mpiexec")
    scene = tmp_path / "db.toml"
    scene.write_text(open(example("dambreak2d.toml")).read() + SAMPLERS)
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    args = ["-m", "sphgraph", "run", str(scene), "--dp", "0.04", "--end-time", "0.03"]
    p1 = subprocess.run([sys.executable, *args, "--out", str(tmp_path / "one")], env=env,
                        capture_output=True, text=True, timeout=120)
    p2 = subprocess.run([exe, "-n", "2", sys.executable, *args, "--comm", "mpi", "--watchdog", "20",
                         "--out", str(tmp_path / "two")], env=env, capture_output=True, text=True, timeout=120)
    assert p1.returncode == 0 and p2.returncode == 0, p1.stderr[-1500:] + p2.stderr[-1500:]
    with h5py.File(tmp_path / "one" / "output.h5") as a, h5py.File(tmp_path / "two" / "output.h5") as b:
        for key in ("probes/time", "probes/P1/pressure", "probes/P1/velocity", "probes/H1/height",
                    "forces/time", "forces/wall/force"):
            x, y = a[key][()], b[key][()]
            assert x.shape == y.shape and len(x) >= 6, key
            np.testing.assert_allclose(y, x, rtol=1e-7, atol=1e-9 * max(1.0, np.abs(x).max()), err_msg=key)
