"""The fine runs of issue 22 §1 on a GPU (numba-cuda, float32, the defaults a user gets):
Yeh & Petroff at dp 0.0085 (181,280 particles) to 1.6 s and the 2D dam break onto a wall
(examples/dambreak_wall2d.toml, dp = H/120) to 1.25 s, each through benchmarks/fine_runs.py.

With DualSPHysics' leapfrog diffusion step a particle's density may still leave its bounds
(docs/validation.md, "Runs that stop for one particle"): the default [domain] exclude_outside
removes it, and the run must reach its end with the exclusions within exclude_max_share (0.1 %
of the fluid), else the run stops and the test fails. With the DuFort-Frankel step
(`diffusion_time = "dufort-frankel"`) Yeh & Petroff must reach its end with exclusion off.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cudasim_helpers import gpu_available

ROOT = Path(__file__).resolve().parents[1]


def _fine(*args, timeout=1500):
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "fine_runs.py"), *args],
                       capture_output=True, text=True, timeout=timeout)
    lines = [line for line in r.stdout.splitlines() if line.startswith("{")]
    assert lines, r.stderr[-2000:]
    return json.loads(lines[-1])


@pytest.mark.gpu
@pytest.mark.skipif(not gpu_available(), reason="no CUDA GPU (numba.cuda.is_available() is false)")
@pytest.mark.parametrize("case, args", [
    ("yeh_petroff", ["--dp", "0.0085"]),
    ("wall2d", ["--diffusion-time", "leapfrog"]),
    ("yeh_petroff", ["--dp", "0.0085", "--diffusion-time", "dufort-frankel", "--no-exclude"]),
])
def test_fine_run_reaches_its_end_on_the_gpu(case, args):
    out = _fine(case, *args, "--backend", "numba-cuda", "--precision", "float32")
    assert out["reached_end"], out
    assert out["time"] >= out["end_time"] - 1e-9
    assert out["n_excluded"] is None or out["n_excluded"] <= 1e-3 * out["fluid"], out
    print(json.dumps(out))
