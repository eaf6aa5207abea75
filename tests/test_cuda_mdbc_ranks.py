"""mDBC on numba-cuda with several mock ranks (backends/compute/cuda_mdbc.py) against numba-cpu
on one rank: the device ghost sums go on over the halos' fluid rows, and send_mdbc /
recv_mdbc_1/2 put the new densities and velocities of the edge's boundary rows on the
neighbours' device halos, by both halo transports (`staged`: host values uploaded into the
halo's buffer; `ipc`: the boundary rows copied again into the sender's edge slot, which
the neighbour's halo views).

As tests/test_cuda_mdbc.py: the kernels run in numba's CUDA simulator in a subprocess
(float64, the 2D tank of 322 particles with 2 boundary layers; no hydrostatic start, so
the column starts to fall and the boundary rows' values change every stage), 3 steps,
`--schedule bulk-synchronous` (mDBC on several ranks needs both halos before the forces).
Cuts along x at 0.37 m (2 ranks) and 0.37 / 0.80 m (3 ranks): the first crosses the
fluid and the tank's bottom. "off": the same run with the exchange left out (the halos
keep the boundary values from before the neighbour's mdbc), which must be visibly apart;
"nohalo": the ghosts sum the owned fluid only, whose velocities must be visibly apart.
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_equal, compare_in_subprocess, gpu

SCHEDULE = "bulk-synchronous"


def scene(dim=2, boundary="mdbc-noslip", integrator="verlet"):
    return H.tank(dim, {"integrator": integrator, "boundary": boundary}, layers=2, fluid_3d_top=(0.2, 0.25, 0.2))


def no_exchange():
    """numba-cuda whose send_mdbc / recv_mdbc leave the neighbours' halos as they came:
    staged, the values are not put on the halo; ipc, the slot is not packed again."""
    import numpy as np

    from sphgraph.backends.compute.cuda_lanes import new_event
    from sphgraph.backends.compute.cuda_mdbc import MdbcDone
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA

    class NoExchange(NumbaCUDA):
        name = "numba-cuda"

        def mdbc_edge(self, state, domain, direction):
            if state.extra["dev"].mdbc_edges.get(direction, ("host",))[0] == "slot":
                ev = new_event(False)
                ev.record()
                return MdbcDone(ev)
            return super().mdbc_edge(state, domain, direction)

        def mdbc_halo(self, state, halo, values):
            if not isinstance(values, np.ndarray):
                super().mdbc_halo(state, halo, values)

    return NoExchange


def no_halo_sums():
    """numba-cuda whose ghosts sum the owned fluid only."""
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA

    class NoHaloSums(NumbaCUDA):
        name = "numba-cuda"

        def mdbc(self, state, boxes, det_min, noslip):
            halos, state.halos = state.halos, {}
            try:
                super().mdbc(state, boxes, det_min, noslip)
            finally:
                state.halos = halos

    return NoHaloSums


def compare(ranks, transport, steps=3, boundary="mdbc-noslip", integrator="verlet", off=False) -> dict:
    """numba-cuda on `ranks` mock ranks against numba-cpu on one rank (a cudasim_helpers.diff);
    with `off`, "off": the diff of the run without the exchange, "nohalo": without the
    halos in the ghost sums."""
    sc = scene(2, boundary, integrator)
    cpu = H.run(sc, "numba-cpu", steps)
    out = H.diff(sc, cpu, H.run(sc, "numba-cuda", steps, ranks, transport, schedule=SCHEDULE))
    if off:
        out["off"] = H.diff(sc, cpu, H.run(sc, no_exchange(), steps, ranks, transport, schedule=SCHEDULE))
        out["nohalo"] = H.diff(sc, cpu, H.run(sc, no_halo_sums(), steps, ranks, transport, schedule=SCHEDULE))
    return out


def check(r):
    check_equal(r)
    assert r["vel"] < 1e-10, f"velocities differ by {r['vel']:.3g} m/s: {r}"
    if "off" in r:   # without the exchange the run fails check_equal's 1e-9 of the domain
        assert r["off"]["pos"] > 2e-9, f"the exchange changes the positions by only {r['off']['pos']:.3g}: {r}"
    if "nohalo" in r:   # without the halos' fluid in the ghost sums the velocities are off
        assert r["nohalo"]["vel"] > 1e-7, f"the halo sums change the velocities by only {r['nohalo']['vel']:.3g}: {r}"


@pytest.mark.parametrize("ranks,transport,boundary,integrator,off", [
    # the runs with a part left out show that this check can fail; each costs a simulator run
    # more, so they run on one transport (the equality itself fails far past its tolerance
    # without either part: 6e-9 of the domain, 2.4e-6 m/s)
    (2, "staged", "mdbc-noslip", "verlet", False), (3, "staged", "mdbc-noslip", "verlet", False),
    (2, "ipc", "mdbc-noslip", "verlet", True), (3, "ipc", "mdbc-noslip", "verlet", False),
    (2, "ipc", "mdbc", "symplectic", False)])
def test_simulator_mock_ranks_match_cpu(ranks, transport, boundary, integrator, off):
    """Measured: positions 4e-18 of the domain apart, velocities 1e-14 m/s, densities 3e-12
    kg/m^3; without the exchange 6e-9 of the domain and 5e-5 kg/m^3, without the halos in the
    ghost sums velocities 2.4e-6 m/s (positions 8e-11 of the domain; 2 ranks, measured on both
    transports, checked on ipc)."""
    check(compare_in_subprocess(__file__, f"compare({ranks}, {transport!r}, 3, {boundary!r}, {integrator!r}, {off})",
                                sim=True, timeout=900))


def test_mdbc_on_mpi_ranks_is_refused_on_numba_cuda():
    """The device exchange runs between ranks of one process (mock); MPI ranks are refused
    with one line."""
    from sphgraph import InputError
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA
    from sphgraph.features import Features
    f = Features(scene())
    with pytest.raises(InputError, match=r"physics.boundary.*--comm mock ranks.*got 2 MPI ranks on --backend "
                                         r"numba-cuda"):
        f.check_backend(NumbaCUDA, 2, one_process=False)
    f.check_backend(NumbaCUDA, 2, one_process=True)
    f.check_backend(NumbaCUDA, 1, one_process=False)


@pytest.mark.gpu
@gpu
def test_gpu_mock_ranks_match_cpu():
    """On a real GPU, float64, 5 steps: 2 and 3 mock ranks by both transports, the exchange's
    effect on 2 ranks."""
    out = compare_in_subprocess(__file__, "[compare(r, t, 5, off=(r == 2)) for r in (2, 3) for t in ('staged', 'ipc')]",
                                sim=False, timeout=900)
    for r in out:
        check(r)
