"""Helpers of the numba-cuda feature tests (test_cuda_dufort, test_cuda_riemann, test_cuda_mdbc):
a script run in a subprocess, in numba's CUDA simulator or on the real GPU, and the checks of a
GPU result against numba-cpu's."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest


def run_script(script: str, sim: bool, timeout=300):
    """The last stdout line of `script` as JSON; `sim`: in numba's CUDA simulator
    (`NUMBA_ENABLE_CUDASIM=1`, which must be set before numba is imported)."""
    env = dict(os.environ)
    if sim:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    else:
        env.pop("NUMBA_ENABLE_CUDASIM", None)
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-4000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def gpu_available() -> bool:
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return False
    try:
        from numba import cuda
        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001
        return False


gpu = pytest.mark.skipif(not gpu_available(), reason="no CUDA GPU (numba.cuda.is_available() is false)")


def check_equal(r, tol=1e-9):
    """A `diff` entry of the scripts: the same ids and time, positions within `tol` of the
    domain, densities within 1e-6 kg/m^3."""
    assert r["ids"], r
    assert r["time"][0] == pytest.approx(r["time"][1], rel=1e-9), r
    assert r["pos"] < tol, f"positions differ by {r['pos']:.3g} of the domain: {r}"
    assert r["rho"] < 1e-6, f"densities differ by {r['rho']:.3g} kg/m^3: {r}"
