"""The Riemann-solver pressure term (`[physics] riemann = "zhang2017"`) on numba-cuda
(backends/compute/cuda_riemann.py) against numba-cpu.

As tests/test_cuda_backend.py: the kernels run in numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`, float64, 239-387 particles, 2 Symplectic steps); the `gpu` test
runs on a real GPU. The `centred` entry is how far numba-cpu's Riemann run is from its
default (centred pressure) one: far above the tolerance.
"""
from __future__ import annotations

import textwrap

import pytest
from cudasim_helpers import check_equal, gpu, run_script

SCRIPT = textwrap.dedent('''
    import json
    import numpy as np
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation

    def scene(dim, riemann="zhang2017", laminar=0.0):
        if dim == 2:
            d = {"format": 1, "dim": 2, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
                 "domain": {"min": [-0.2, -0.2], "max": [1.7, 1.5]},
                 "physics": {},
                 "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.5, 0.8]}],
                 "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.5, 1.2], "layers": 1}]}
        else:
            d = {"format": 1, "dim": 3, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
                 "domain": {"min": [-0.2, -0.2, -0.2], "max": [0.6, 0.5, 0.6]},
                 "physics": {"cell_size": "h", "coefh": 1.1547005383792515},
                 "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [0.2, 0.3, 0.25]}],
                 "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.4], "layers": 1}]}
        d["physics"].update({"integrator": "symplectic", "riemann": riemann, "laminar_nu": laminar})
        return Scene.from_dict(d, source="<test>")

    def run(sc, backend, steps, ranks=1, transport="auto", precision="float64"):
        kw = {} if ranks == 1 else {"comm": "mock", "ranks": ranks, "comm_options": {"halo_transport": transport}}
        sim = Simulation(sc, backend=backend, precision=precision, **kw)
        for _ in range(steps):
            sim.step()
        f = sim.frame_arrays()
        i = np.argsort(f["id"])
        return {k: f[k][i] for k in ("id", "position", "density")}, sim.time

    def diff(sc, a, b):
        ext = float(np.max(sc.domain_max - sc.domain_min))
        return {"n": int(len(a[0]["id"])), "ids": bool(np.array_equal(a[0]["id"], b[0]["id"])),
                "pos": float(np.abs(a[0]["position"] - b[0]["position"]).max() / ext),
                "rho": float(np.abs(a[0]["density"] - b[0]["density"]).max()),
                "time": [a[1], b[1]]}

    def compare(dim, steps, laminar=0.0, ranks=1, transport="auto", precision="float64"):
        """numba-cuda on `ranks` (mock) against numba-cpu on one rank, and numba-cpu's
        centred pressure term against its Riemann one (the gap the tolerance must be far below)."""
        sc = scene(dim, laminar=laminar)
        cpu = run(sc, "numba-cpu", steps)
        out = diff(sc, cpu, run(sc, "numba-cuda", steps, ranks, transport, precision))
        out["centred"] = diff(sc, cpu, run(scene(dim, "none", laminar), "numba-cpu", steps))["rho"]
        if ranks > 1:      # numba-cpu on the same mock ranks
            out["cpu_ranks"] = diff(sc, cpu, run(sc, "numba-cpu", steps, ranks, "staged"))
        return out
''')


def test_simulator_riemann_matches_cpu_one_rank():
    """2D, and 3D with a laminar viscosity (riemann_pair keeps the laminar term): one rank, the
    force kernel writes the reduced sums itself."""
    out = run_script(SCRIPT + "\nprint(json.dumps([compare(2, 2), compare(3, 2, laminar=1e-3)]))", sim=True)
    for r in out:
        check_equal(r)
        assert r["centred"] > 1e-4, r


def test_simulator_riemann_matches_cpu_two_mock_ranks():
    """2 mock ranks: ipc halos (the default) and staged halos (host-binned: k_forces), against
    one CPU rank; numba-cpu on the same 2 ranks too."""
    out = run_script(SCRIPT + "\nprint(json.dumps([compare(2, 2, ranks=2), "
                     "compare(2, 2, ranks=2, transport='staged')]))", sim=True)
    for r in out:
        check_equal(r)
        check_equal(r["cpu_ranks"])
        assert r["centred"] > 1e-4, r


@pytest.mark.gpu
@gpu
def test_gpu_riemann_matches_cpu():
    """On a real GPU, float64: one rank and 2 mock ranks (ipc) against one CPU rank."""
    out = run_script(SCRIPT + "\nprint(json.dumps([compare(2, 5), compare(3, 5, laminar=1e-3), "
                     "compare(2, 5, ranks=2)]))", sim=False, timeout=600)
    for r in out:
        check_equal(r)
