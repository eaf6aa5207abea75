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
