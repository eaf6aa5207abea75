"""The fine runs of issue 22 §1 on a GPU (numba-cuda, float32):
Yeh & Petroff at dp 0.0085 (181,280 particles) to 1.6 s and the 2D dam break onto a wall
(examples/dambreak_wall2d.toml, dp = H/120) to 1.25 s, each through benchmarks/fine_runs.py.

With the DuFort-Frankel diffusion step (`diffusion_time = "dufort-frankel"`, dambreak_wall2d's
own) both must reach their end with exclusion off. With DualSPHysics' leapfrog step a
particle's density may still leave its bounds (docs/validation.md, "Runs that stop for one
particle"): the default [domain] exclude_outside removes it, and the run reaches its end with
the exclusions within exclude_max_share (0.1 % of the fluid) or stops with the named failure.
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
    ("yeh_petroff", ["--dp", "0.0085", "--diffusion-time", "dufort-frankel", "--no-exclude"]),
    ("wall2d", ["--no-exclude"]),          # the example's own step: DuFort-Frankel
])
def test_fine_run_reaches_its_end_on_the_gpu(case, args):
    """The fix of the cause: the DuFort-Frankel diffusion step, exclusion off, the density
    bounds unchanged."""
    out = _fine(case, *args, "--backend", "numba-cuda", "--precision", "float32")
    assert out["reached_end"], out
    assert out["time"] >= out["end_time"] - 1e-9
    assert out["n_excluded"] is None, out
    print(json.dumps(out))


@pytest.mark.gpu
@pytest.mark.skipif(not gpu_available(), reason="no CUDA GPU (numba.cuda.is_available() is false)")
@pytest.mark.parametrize("case, args", [
    ("yeh_petroff", ["--dp", "0.0085"]),                  # the example's own step: leapfrog
    ("wall2d", ["--diffusion-time", "leapfrog"]),
])
def test_leapfrog_fine_run_ends_or_stops_at_the_exclusion_bound(case, args):
    """DualSPHysics' leapfrog step with the default exclusion: the run reaches its end with
    the exclusions within exclude_max_share, or stops with the named failure (step, share,
    the last particle and its cause) once they pass it -- never for one particle."""
    out = _fine(case, *args, "--backend", "numba-cuda", "--precision", "float32")
    if out["reached_end"]:
        assert out["n_excluded"] is None or out["n_excluded"] <= 1e-3 * out["fluid"], out
    else:
        assert out["n_excluded"] > 1e-3 * out["fluid"], out
        assert out["failure"].startswith("step ") and "exclude_max_share" in out["failure"], out
        assert "particle id" in out["failure"], out
    print(json.dumps(out))
