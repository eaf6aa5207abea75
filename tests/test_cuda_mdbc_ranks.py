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

Under `mpiexec -n 2` (tests/mpi_driver.py's `cuda-mdbc`, the simulator in each rank, the
default halo transport of MPI ranks: staged) a smaller tank (`mpi_scene`: 0.5 x 0.3 m of
water in 0.8 x 0.4 m, 130 particles, the cut at x = 0.37 m through the fluid and the
bottom), hydrostatic start so that 2 steps suffice: the ghost sums differ with and without
the neighbour's fluid from the first stage (without a start's density gradient the first
two steps see uniform fields, which any subset of the rows interpolates alike). With ipc
halos between processes the event of the exchange cannot travel: the sender's host waits
for the copy before its message leaves (`MdbcDone.to_wire`), checked on a GPU under
`mpiexec -n 2` (IPC handles need a real device).
"""
from __future__ import annotations

import numpy as np
import pytest

import cudasim_helpers as H
from cudasim_helpers import check_equal, compare_in_subprocess, gpu

SCHEDULE = "bulk-synchronous"


def scene(dim=2, boundary="mdbc-noslip", integrator="verlet"):
    return H.tank(dim, {"integrator": integrator, "boundary": boundary}, layers=2, fluid_3d_top=(0.2, 0.25, 0.2))


def mpi_scene(ranks=2):
    """The MPI ranks' tank: as small as keeps each slab 6h wide and every cut through the
    fluid and the bottom (3 ranks: 1.0 x 0.3 m of water in 1.5 x 0.4 m, cuts at 0.33 and
    0.76 m)."""
    return H.tank(2, {"integrator": "verlet", "boundary": "mdbc-noslip"}, layers=2,
                  fluid_2d_top=(0.5 if ranks == 2 else 1.0, 0.3), tank_2d=(0.8 if ranks == 2 else 1.5, 0.4),
                  initial={"hydrostatic": True})


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

        def mdbc(self, state, boxes, det_min, noslip, moving=None):
            halos, state.halos = state.halos, {}
            try:
                super().mdbc(state, boxes, det_min, noslip, moving)
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


def test_mdbc_done_crosses_processes_without_its_event():
    """ipc's send_mdbc message between processes: the sender's host waits for the event
    before the message leaves, and the receiver's message carries none (nothing to wait
    for); mock ranks keep the event."""
    from sphgraph.backends.compute.cuda_mdbc import MdbcDone
    from sphgraph.wire import decode, encode

    class Event:
        waited = 0

        def synchronize(self):
            self.waited += 1
    ev = Event()
    code, buf = encode(MdbcDone(ev), 1)
    assert ev.waited == 1 and buf.dtype == np.uint8
    got = decode(code, buf)
    assert isinstance(got, MdbcDone) and got.event is None


def check_mpi(r, n):
    """A `cuda-mdbc` result of tests/mpi_driver.py on `n` ranks: equal to numba-cpu on one
    rank (`check`), the staged exchange run by every rank, and ghosts of every rank within
    2h of the neighbour's fluid."""
    check(r)
    assert r["ranks"] == n and r["transport"] == "staged", r
    for x in r["per_rank"]:
        assert x["d2h_mdbc"] > 0 and x["h2d_mdbc"] > 0, f"rank {x['rank']} exchanged no mDBC values: {r}"
        assert x["ghosts_near_halo_fluid"] > 0, f"rank {x['rank']}: no ghost sums the halo's fluid: {r}"


@pytest.mark.mpi
def test_simulator_mpi_ranks_match_cpu():
    """`mpiexec -n 2`, the simulator in each rank, 2 steps of `mpi_scene`. Measured: positions
    1e-17 of the domain apart, velocities 8e-15 m/s, densities 2e-12 kg/m^3; with the
    exchange left out of mdbc_halo positions 1.8e-9 of the domain and densities 4e-3 kg/m^3,
    without the halos in the ghost sums velocities 4e-4 m/s and densities 7e-4 kg/m^3."""
    from test_multirank import run_driver
    r = run_driver(2, ["cuda-mdbc"], timeout=300, env={"NUMBA_ENABLE_CUDASIM": "1"})["cuda-mdbc"]
    assert r["simulator"], r
    check_mpi(r, 2)


@pytest.mark.gpu
@pytest.mark.mpi
@gpu
def test_gpu_mpi_ipc_ranks_match_cpu():
    """On a real GPU under `mpiexec -n 2`, --halo-transport ipc, float64, 5 steps of
    `mpi_scene(2)`: the ipc mDBC exchange between processes (MdbcDone.to_wire)."""
    from test_multirank import run_driver
    r = run_driver(2, ["cuda-mdbc"], timeout=900, env={"SPHGRAPH_MDBC_STEPS": "5",
                                                       "SPHGRAPH_MDBC_TRANSPORT": "ipc"})["cuda-mdbc"]
    check(r)
    assert r["ranks"] == 2 and r["transport"] == "ipc", r
    assert all(x["ghosts_near_halo_fluid"] > 0 for x in r["per_rank"]), r


@pytest.mark.gpu
@gpu
def test_gpu_mock_ranks_match_cpu():
    """On a real GPU, float64, 5 steps: 2 and 3 mock ranks by both transports, the exchange's
    effect on 2 ranks."""
    out = compare_in_subprocess(__file__, "[compare(r, t, 5, off=(r == 2)) for r in (2, 3) for t in ('staged', 'ipc')]",
                                sim=False, timeout=900)
    for r in out:
        check(r)


@pytest.mark.gpu
@pytest.mark.mpi
@gpu
@pytest.mark.parametrize("n", [2, 3])
def test_gpu_mpi_ranks_match_cpu(n):
    """On a real GPU under `mpiexec -n 2` and `-n 3` (all ranks on one GPU, or one each),
    float64, 5 steps of `mpi_scene(n)`: the staged mDBC exchange between processes."""
    from test_multirank import run_driver
    r = run_driver(n, ["cuda-mdbc"], timeout=900, env={"SPHGRAPH_MDBC_STEPS": "5"})["cuda-mdbc"]
    assert not r["simulator"], r
    check_mpi(r, n)
