"""Particle shifting on numba-cuda (backends/compute/cuda_shifting.py) against numba-cpu.

As tests/test_cuda_backend.py: the kernels run in numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`, float64, 64-200 particles, 2 steps of fixed dt); the `gpu` test runs on a
real GPU.
"""
from __future__ import annotations

import textwrap

import pytest

from cudasim_helpers import gpu, run_script

SCRIPT = textwrap.dedent('''
    import json
    import numpy as np
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA as CUDA

    def scene(dim, mode, dp, extra=None):
        if dim == 2:
            d = {"format": 1, "dim": 2, "dp": dp, "end_time": 1.0,
                 "domain": {"min": [-0.2, -0.2], "max": [1.2, 1.2], "origin": [0.0, 0.0]},
                 "physics": {"shifting": mode, "shifting_tfs": 1.5},
                 "initial": {"jitter": 0.1},
                 "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.6, 0.6]}],
                 "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8], "layers": 1}]}
        else:   # a block on a floor
            d = {"format": 1, "dim": 3, "dp": dp, "end_time": 1.0,
                 "domain": {"min": [-0.2, -0.2, -0.2], "max": [0.4, 0.4, 0.4], "origin": [0.0, 0.0, 0.0]},
                 "physics": {"shifting": mode, "shifting_tfs": 2.75, "cell_size": "h"},
                 "initial": {"jitter": 0.1},
                 "fluid": [{"type": "box", "min": [0.0, 0.0, 0.05], "max": [0.15, 0.15, 0.15]}],
                 "boundary": [{"type": "wall", "min": [0.0, 0.0, 0.0], "max": [0.15, 0.15, 0.0]}]}
        d["physics"].update(extra or {})
        return Scene.from_dict(d, source="<test>")

    def run(sc, backend, steps, ranks=1, precision="float64", fixed_dt=None):
        # a fixed dt spares the simulator the dt reduction (a quarter of its time)
        sim = Simulation(sc, backend=backend, precision=precision, comm="single" if ranks == 1 else "mock",
                         ranks=ranks, decomposition_axis="x", fixed_dt=fixed_dt)
        for _ in range(steps):
            sim.step()
        return sim.frame_arrays()

    def compare(dim, mode, dp, steps, ranks, precision="float64", extra=None, fixed_dt=None):
        sc = scene(dim, mode, dp, extra)
        cpu = run(sc, "numba-cpu", steps, fixed_dt=fixed_dt)
        gpu = run(sc, CUDA, steps, ranks, precision, fixed_dt)
        off = run(scene(dim, "none", dp, extra), "numba-cpu", steps, fixed_dt=fixed_dt)
        ext = float(np.max(sc.domain_max - sc.domain_min))
        return {"n": int(len(cpu["id"])), "ids": bool(np.array_equal(cpu["id"], gpu["id"])),
                "pos": float(np.abs(cpu["position"] - gpu["position"]).max() / ext),
                "shift": float(np.abs(cpu["position"] - off["position"]).max() / ext)}
''')


def _check(r, tol=1e-9):
    assert r["ids"], r
    assert r["shift"] > 1e-8, r                 # the shift acted (~1e-7 of the domain in 2 steps)
    assert r["pos"] < tol, r                    # CPU and CUDA agree to 1e-9 of the domain ...
    assert r["pos"] < 1e-3 * r["shift"], r      # ... and to 1e-3 of the shift itself


CASES = [
    # 2D, 2 mock ranks (interior on the kind-split grid, a halo), fixed walls cancel ("nofixed")
    (2, "nofixed", 0.05, 2, 2, "float64", None, 2e-4),
    # 3D, 1 rank, boundary neighbours summed ("full"); a block this small is all surface
    # for ShiftTFS = 2.75 (div r < 2.75 everywhere): threshold off
    (3, "full", 0.05, 2, 1, "float64", {"shifting_tfs": 0.0}, 2e-4),
]


def test_simulator_matches_cpu():
    out = run_script(SCRIPT + "\nprint(json.dumps([compare(*c) for c in %r]))\n" % (CASES,), sim=True)
    for r in out:
        _check(r)


@pytest.mark.gpu
@gpu
def test_gpu_matches_cpu():
    """Real GPU: a 2D tank at dp = 0.01 (~4,700 particles), 30 steps, float64 on 1 and 2
    ranks to 1e-9 of the domain; float32 (the GPU default) to 1e-5."""
    cases = [(2, "full", 0.01, 30, 1), (2, "nobound", 0.01, 30, 2)]
    out = run_script(SCRIPT + "\nprint(json.dumps([compare(*c) for c in %r] + [compare(2, 'full', 0.01, 30, 1, "
               "'float32')]))\n" % (cases,), sim=False, timeout=600)
    for r in out[:2]:
        _check(r)
    assert out[2]["ids"] and out[2]["pos"] < 1e-5, out[2]
