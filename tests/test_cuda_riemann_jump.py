"""The renormalised Riemann jump (`[physics] riemann_jump = "renormalised"`) on numba-cuda
(backends/compute/cuda_rjump.py) against numba-cpu.

As tests/test_cuda_riemann.py: the kernels run in numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`, float64, 2 Symplectic steps); the `gpu` test runs on a real GPU.
The option needs mDBC walls: the scenes are test_cuda_mdbc's tanks (2 wall layers, a
hydrostatic start, so that the pressure has a gradient for the jump's linear part from the
first step; 322 particles in 2D, 790 in 3D). The `gap` entry is how far numba-cpu's
renormalised run is from its plain-jump one, measured 0.047 (2D) and 0.23 kg/m^3 (3D) after
2 steps, 0.15 and 0.36 after 5: GAP = 1e-3 kg/m^3 is 45x below the smallest, and 1000x above
check_equal's density tolerance (1e-6; the runs agree to ~4e-12), so a GPU path that left the
correction out, or summed the moments of only some parts, fails the comparison by far.
Several ranks take test_cuda_mdbc_ranks' schedule (mDBC needs both halos before the forces).
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_compared, compare_in_subprocess, gpu

GAP = 1e-3
SCHEDULE = "bulk-synchronous"


def scene(dim, riemann_jump="renormalised", wall="skip"):
    return H.tank(dim, {"integrator": "symplectic", "riemann": "zhang2017", "riemann_jump": riemann_jump,
                        "riemann_wall": wall, "boundary": "mdbc"}, layers=2, fluid_3d_top=(0.2, 0.25, 0.2),
                  initial={"hydrostatic": True})


def compare(dim, steps, ranks=1, transport="auto", wall="skip"):
    """cudasim_helpers.compare (numba-cuda on `ranks` mock ranks against numba-cpu on one rank,
    "gap": numba-cpu's plain jump against its renormalised one, "cpu_ranks": numba-cpu on the
    same mock ranks), with test_cuda_mdbc_ranks' schedule on several ranks: mDBC there needs
    both halos before the forces."""
    sc = scene(dim, wall=wall)
    sched = SCHEDULE if ranks > 1 else None
    cpu = H.run(sc, "numba-cpu", steps)
    out = H.diff(sc, cpu, H.run(sc, "numba-cuda", steps, ranks, transport, schedule=sched))
    out["gap"] = H.diff(sc, cpu, H.run(scene(dim, "plain", wall), "numba-cpu", steps))["rho"]
    if ranks > 1:
        out["cpu_ranks"] = H.diff(sc, cpu, H.run(sc, "numba-cpu", steps, ranks, "staged", schedule=sched))
    return out


def test_simulator_riemann_jump_matches_cpu_one_rank():
    """2D and 3D, one rank: the interior is a part (never written reduced), k_reduce_jm adds the
    correction. Measured: densities 1.5e-12 (2D) and 1.8e-12 kg/m^3 (3D) apart, positions
    < 2e-17 of the domain; gap 0.047 (2D, 322 particles) and 0.23 kg/m^3 (3D, 790)."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 2), compare(3, 2)]", sim=True), gap=GAP)


def test_simulator_riemann_jump_matches_cpu_two_mock_ranks():
    """2 mock ranks: ipc halos (the default: k_halo_fv with the moments, k_reduce_ranged_jm) and
    staged halos (host-binned: k_forces_rj, k_reduce_jm), against one CPU rank; numba-cpu on
    the same 2 ranks too. riemann_wall = "cancel", so that the reductions' cancel matters
    (one rank, the cancels ignored: 0.06 kg/m^3 apart). Measured: densities 3.3e-12 kg/m^3
    apart, gap 0.046 kg/m^3; the halos' moments left out of the sums (riemann_wall = "skip"):
    0.043 kg/m^3 (both transports)."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 2, ranks=2, wall='cancel'), "
                                         "compare(2, 2, ranks=2, transport='staged', wall='cancel')]", sim=True),
                   gap=GAP)


def test_with_sum_carries_twelve_moments():
    """cuda_variants.with_sum(nsum=12) on cuda_forces._fv_pair with cuda_rjump's pair, run by
    numba on the CPU: the seven sums of the Riemann pair and the twelve sums grown by
    `jump_moments` (a fluid b; nothing for a boundary b)."""
    import numpy as np

    from sphgraph.backends.compute import cuda_forces as CF
    from sphgraph.backends.compute.cuda_riemann import riemann_fluid_pair
    from sphgraph.backends.compute.cuda_rjump import rjump_fluid_pair
    from sphgraph.backends.compute.cuda_variants import with_globals, with_sum
    from sphgraph.config import O_KERNEL, P_MASS_F, P_SUPPORT2, PhysicsConfig, derive
    from sphgraph.physics.riemann_jump import jump_moments

    c = derive(PhysicsConfig(riemann="zhang2017", riemann_jump="renormalised", boundary="mdbc"), dp=0.05, dim=3,
               hswl=0.8)
    prm, kid = c.prm, int(c.opt[O_KERNEL])
    pair_rj = with_sum(CF._fv_pair, rjump_fluid_pair, nsum=12)
    pair_r = with_globals(CF._fv_pair, fluid_pair=riemann_fluid_pair)
    vel4 = np.array([0.1, -0.2, 0.05, 1001.0])
    sums = (0.5, -0.25, 0.125, 3.0, 0.75, 0, 0.01)
    before = tuple(0.25 * k for k in range(12))
    d = (0.04 - 0.01, 0.05 - 0.02, 0.03 - 0.0)
    r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    for b_bound in (False, True):
        a = (0.01, 0.02, 0.0, 1500.0, vel4, np.ones(1, np.int8), 0, b_bound, 0.04, 0.05, 0.03, 2000.0, 0.2, 0.1, 0.0,
             1000.5, 1.0 / 1000.5, prm[P_MASS_F], prm[P_SUPPORT2], prm, kid, 0, 0)
        got = pair_rj(*a, *sums, *before)
        assert got[:7] == pair_r(*a, *sums), got
        m = (0.0,) * 12 if b_bound else jump_moments(*d, r2, np.sqrt(r2), 1000.5, 1001.0, 2000.0, 1500.0,
                                                     prm[P_MASS_F], prm, kid)
        assert got[7:] == tuple(x + y for x, y in zip(before, m)), (got[7:], m)
        assert b_bound or all(x != 0.0 for x in m[:3] + m[6:])


@pytest.mark.gpu
@gpu
def test_gpu_riemann_jump_matches_cpu():
    """On a real GPU, float64, 5 steps: one rank (2D, 3D) and 2 mock ranks (ipc) against one CPU
    rank. Measured on an H100: densities 1.3e-12, 3.8e-12 and 1.9e-12 kg/m^3 apart, positions
    < 7e-17 of the domain (38 s with the kernels' compilation)."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 5), compare(3, 5), compare(2, 5, ranks=2)]",
                                         sim=False, timeout=600), gap=GAP)
