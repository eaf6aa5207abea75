"""Every scene feature at once on numba-cuda: tests/test_feature_tasks.py's scene (a periodic
channel along x over a floor, particle shifting, a bar moving down into the water, a damping
zone, exclusion; Symplectic) in numba's CUDA simulator on one rank (periodic images and
wrapping on the device rows) and 3 mock ranks (a ring along the periodic axis), against
numba-cpu on one rank: equal within 1e-9 of the domain (measured 1.1e-16).

The damping zone is a device task of its own (`ComputeBackend.damp`, cuda_integrate.k_damp):
numba-cuda damped the host copy of the rows before, which never reached the device (the
zone did nothing); with that backend back the run is 7.5e-8 of the domain apart, which the
check catches.
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_equal, compare_in_subprocess

STEPS = 4


def scene():
    from sphgraph import Scene
    from test_feature_tasks import everything
    d = everything("symplectic").to_dict()
    d.pop("probes")
    d.pop("forces")
    return Scene.from_dict(d, source="<test>")


def host_damping():
    """numba-cuda that damps the host copy of its rows, as before `damp` was a device task."""
    from sphgraph.backends.compute.base import ComputeBackend
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA

    class HostDamping(NumbaCUDA):
        name = "numba-cuda"
        damp = ComputeBackend.damp
    return HostDamping


def compare(ranks, gap=False) -> dict:
    sc = scene()
    cpu = H.run(sc, "numba-cpu", STEPS)
    transport = "staged" if ranks > 1 else "auto"
    out = H.diff(sc, cpu, H.run(sc, "numba-cuda", STEPS, ranks, transport))
    if gap:
        out["gap"] = H.diff(sc, cpu, H.run(sc, host_damping(), STEPS))["pos"]
    return out


@pytest.mark.parametrize("ranks,gap", [(1, True), (3, False)])
def test_simulator_every_feature_matches_cpu(ranks, gap):
    r = compare_in_subprocess(__file__, f"compare({ranks}, {gap})", sim=True, timeout=900)
    check_equal(r)
    assert r["vel"] < 1e-10, r
    if gap:
        assert r["gap"] > 1e-8, f"damping on the host rows changes the run by only {r['gap']:.3g}: {r}"


@H.gpu
@pytest.mark.gpu
@pytest.mark.parametrize("ranks", [1, 3])
def test_gpu_every_feature_matches_cpu(ranks):
    r = compare_in_subprocess(__file__, f"compare({ranks})", sim=False, timeout=600)
    check_equal(r)
    assert r["vel"] < 1e-10, r
