"""The DuFort-Frankel diffusion step (`[physics] diffusion_time = "dufort-frankel"`) on numba-cuda
(backends/compute/cuda_dufort.py) against numba-cpu.

As tests/test_cuda_backend.py: the kernels run in numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`, float64, 239-387 particles, 2-3 steps); the `gpu` test runs on a
real GPU. The scenes take delta 0.3 and an Euler step every 40 (so every step here is a
DuFort-Frankel one): the two schemes then differ by ~1e-2 kg/m^3 in 3 steps (the
`gap` entry), far above the tolerance (Molteni: ~2e-4).
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_compared, compare_in_subprocess, gpu


def scene(dim, diffusion="fourtakas", diffusion_time="dufort-frankel"):
    return H.tank(dim, {"integrator": "verlet", "verlet_euler_every": 40, "delta": 0.3, "diffusion": diffusion,
                        "diffusion_time": diffusion_time})


def compare(dim, steps, diffusion="fourtakas", **run):
    """cudasim_helpers.compare; its "gap": numba-cpu's leapfrog against its DuFort-Frankel step."""
    return H.compare(scene, dim, steps, {"diffusion_time": "leapfrog"}, diffusion=diffusion, **run)


def test_simulator_dufort_frankel_matches_cpu_one_rank():
    """2D with the Fourtakas term (DBC neighbours cancel a row's diffusion and its K_a), 3D
    with fourtakas-full (boundary neighbours skipped): one rank, the force kernel writes the
    reduced K_a itself. Measured: densities 2e-13 to 5e-13 kg/m^3 apart, positions 0."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 3), compare(3, 2, 'fourtakas-full')]", sim=True),
                   gap=1e-4)


def test_simulator_dufort_frankel_matches_cpu_two_mock_ranks():
    """2 mock ranks: ipc halos (the default: k_halo_fv_df, k_reduce_ranged_ddk) and staged
    halos (host-binned: k_forces_df, k_reduce_ddk), against one CPU rank; numba-cpu on the
    same 2 ranks too. Measured: 3.4e-13 kg/m^3, 4e-18 of the domain."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 3, ranks=2), compare(2, 3, 'molteni', ranks=2, "
                                         "transport='staged')]", sim=True), gap=1e-4)


@pytest.mark.gpu
@gpu
def test_gpu_dufort_frankel_matches_cpu():
    """On a real GPU, float64: one rank and 2 mock ranks (ipc) against one CPU rank."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 5), compare(3, 5, 'fourtakas-full'), "
                                         "compare(2, 5, ranks=2)]", sim=False, timeout=600))


def test_with_sum_adds_k_a_and_leaves_the_production_sums():
    """cuda_variants.with_sum on cuda_forces._fv_pair, run by numba on the CPU: the seven
    production sums as `_fv_pair` gives them, and K_a grown by fluid_pair_df's k_ab (a fluid b;
    0 for a boundary b); code without the production shape is refused."""
    import numpy as np

    from sphgraph.backends.compute import cuda_forces as CF
    from sphgraph.backends.compute.cuda_variants import with_sum
    from sphgraph.config import O_DDT, O_KERNEL, P_MASS_F, P_SUPPORT2, PhysicsConfig, derive
    from sphgraph.physics.interact import fluid_pair_df

    c = derive(PhysicsConfig(diffusion="fourtakas", diffusion_time="dufort-frankel"), dp=0.05, dim=3, hswl=0.8)
    prm, kid, ddtk = c.prm, int(c.opt[O_KERNEL]), int(c.opt[O_DDT])
    pair_df = with_sum(CF._fv_pair, fluid_pair_df)
    vel4 = np.array([0.1, -0.2, 0.05, 1001.0])
    sums = (0.5, -0.25, 0.125, 3.0, 0.75, 0, 0.01)
    for b_bound in (False, True):
        a = (0.01, 0.02, 0.0, 1500.0, vel4, np.ones(1, np.int8), 0, b_bound, 0.04, 0.05, 0.03, 2000.0, 0.2, 0.1, 0.0, 1000.5,
             1.0 / 1000.5, prm[P_MASS_F], prm[P_SUPPORT2], prm, kid, ddtk, 0)
        plain = CF._fv_pair(*a, *sums)
        got = pair_df(*a, *sums, 2.0)
        d = (0.04 - 0.01, 0.05 - 0.02, 0.03 - 0.0)
        k_ab = fluid_pair_df(*d, d[0] * d[0] + d[1] * d[1] + d[2] * d[2], 0.2 - 0.1, 0.1 + 0.2, 0.0 - 0.05,
                             0.1, -0.2, 0.05, 1000.5,
                             1.0 / 1000.5, 1001.0, 2000.0, 1500.0, prm[P_MASS_F], b_bound, b_bound, prm, kid,
                             ddtk, 0)[-1]
        assert got[:7] == plain, (got, plain)
        assert got[7] == 2.0 + k_ab
        assert (k_ab == 0.0) == b_bound, k_ab

    def other(axx, dd, cc):
        return axx, dd, cc
    with pytest.raises(ValueError, match="shape of the production force code"):
        with_sum(other, fluid_pair_df)
