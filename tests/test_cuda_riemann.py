"""The Riemann-solver pressure term (`[physics] riemann = "zhang2017"`) on numba-cuda
(backends/compute/cuda_riemann.py) against numba-cpu.

As tests/test_cuda_backend.py: the kernels run in numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`, float64, 239-387 particles, 2 Symplectic steps); the `gpu` test
runs on a real GPU. The `gap` entry is how far numba-cpu's Riemann run is from its
default (centred pressure) one: far above the tolerance.
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_compared, compare_in_subprocess, gpu


def scene(dim, riemann="zhang2017", laminar=0.0):
    return H.tank(dim, {"integrator": "symplectic", "riemann": riemann, "laminar_nu": laminar})


def compare(dim, steps, laminar=0.0, **run):
    """cudasim_helpers.compare; its "gap": numba-cpu's centred pressure term against its Riemann one."""
    return H.compare(scene, dim, steps, {"riemann": "none"}, laminar=laminar, **run)


def test_simulator_riemann_matches_cpu_one_rank():
    """2D, and 3D with a laminar viscosity (riemann_pair keeps the laminar term): one rank, the
    force kernel writes the reduced sums itself."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 2), compare(3, 2, laminar=1e-3)]", sim=True),
                   gap=1e-4)


def test_simulator_riemann_matches_cpu_two_mock_ranks():
    """2 mock ranks: ipc halos (the default) and staged halos (host-binned: k_forces), against
    one CPU rank; numba-cpu on the same 2 ranks too."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 2, ranks=2), "
                                         "compare(2, 2, ranks=2, transport='staged')]", sim=True), gap=1e-4)


@pytest.mark.gpu
@gpu
def test_gpu_riemann_matches_cpu():
    """On a real GPU, float64: one rank and 2 mock ranks (ipc) against one CPU rank."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 5), compare(3, 5, laminar=1e-3), "
                                         "compare(2, 5, ranks=2)]", sim=False, timeout=600))
