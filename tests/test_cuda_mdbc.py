"""mDBC (`[physics] boundary = "mdbc" | "mdbc-noslip"`) on numba-cuda (backends/compute/cuda_mdbc.py)
against numba-cpu (cpu_mdbc), one rank.

As tests/test_cuda_backend.py: the kernels run in numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`, float64, a 2D tank of 322 and a 3D one of 790 particles with 2
boundary layers, a hydrostatic start, 2 steps); the `gpu` test runs on a real GPU. The `gap` entry is how far
numba-cpu's mDBC run is from its DBC one (2.7 kg/m^3): far above the tolerance.
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_compared, compare_in_subprocess, gpu


def scene(dim, boundary="mdbc", integrator="verlet"):
    return H.tank(dim, {"integrator": integrator, "boundary": boundary}, layers=2, fluid_3d_top=(0.2, 0.25, 0.2),
                  initial={"hydrostatic": True})


def compare(dim, steps, boundary="mdbc", integrator="verlet", precision="float64"):
    """cudasim_helpers.compare, one rank; its "gap": numba-cpu's DBC run against its mDBC one."""
    return H.compare(scene, dim, steps, {"boundary": "dbc"}, precision=precision, boundary=boundary,
                     integrator=integrator)


@pytest.mark.parametrize("dim,boundary,integrator", [(2, "mdbc", "verlet"), (2, "mdbc-noslip", "symplectic"),
                                                      (3, "mdbc-noslip", "verlet")])
def test_simulator_mdbc_matches_cpu(dim, boundary, integrator):
    """Measured (2D): densities 1e-13 (Verlet) and 9e-13 kg/m^3 (Symplectic, no-slip) apart,
    velocities 1e-14 m/s, positions 6e-17 of the domain. 3D: a tank of 790 particles."""
    check_compared(compare_in_subprocess(__file__, f"compare({dim}, 2, {boundary!r}, {integrator!r})", sim=True),
                   gap=1e-2)


@pytest.mark.gpu
@gpu
def test_gpu_mdbc_matches_cpu():
    """On a real GPU, float64, 5 steps of each."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 5), compare(2, 5, 'mdbc-noslip', 'symplectic')]",
                                         sim=False, timeout=600), gap=1e-2)
