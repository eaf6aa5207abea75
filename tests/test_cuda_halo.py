"""`--halo-transport ipc`: halos device to device (backends/compute/cuda_halo.py).

CI (no GPU): mock ranks on the CUDA kernels in numba's simulator, where the message
carries the sender's device buffer itself (one process); the wire form of the message
(MPI) on the CPU; the flag's errors. On a GPU: `mpiexec -n 2` with CUDA IPC handles.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from cudasim_helpers import gpu, run_script
from test_cuda_backend import SCENES

IPC_SIM = SCENES + textwrap.dedent('''
    import json
    import numpy as np
    from sphgraph.backends.compute import cuda_halo as CH
    from sphgraph.errors import CommError
    from sphgraph.solver import Simulation

    def ipc_vs_staged(dim, integrator, ranks, steps):
        """Both transports on `ranks` mock ranks (inner cuts moved by 2 spacings: rows change
        rank in the first step) and one CPU rank, then a slot rewritten before its receiver
        read it, as between processes (no event: the generation number decides)."""
        sc = scene(dim, integrator)
        ref = Simulation(sc, backend="numba-cpu", precision="float64")
        for _ in range(steps):
            ref.step()
        one = rows_by_id(ref)
        got, kinds, edges, sorts = {}, {}, {}, {}
        for tr in ("staged", "ipc"):
            g = mock_sim(sc, ranks, comm_options={"halo_transport": tr})
            for _ in range(steps):
                g.step()
            got[tr] = rows_by_id(g)
            kinds[tr] = [dict(c.state.extra.get("bytes_by_kind", {})) for c in g.contexts]
            edges[tr] = [len(c.state.extra["dev"].edge_slots) for c in g.contexts]
            sorts[tr] = [c.state.extra["dev"].sort_gen for c in g.contexts]
        ext = float(np.max(sc.domain_max - sc.domain_min))
        c0, c1 = g.contexts[0], g.contexts[1]
        e1 = g.compute.edge(c0.state, c0.domain, 1, slot=99)
        e2 = g.compute.edge(c0.state, c0.domain, 1, slot=99)
        e1.event = e2.event = None
        g.compute.prepare_halo(c1.state, e1)
        try:
            CH.check_generations(c1.state, c1.state.extra["dev"])
            caught = None
        except CommError as e:
            caught = str(e)
        g.compute.prepare_halo(c1.state, e2)          # the current one is accepted
        CH.check_generations(c1.state, c1.state.extra["dev"])
        return {"ids": all(bool(np.array_equal(one["id"], got[t]["id"])) for t in got),
                "pos": {t: float(np.abs(one["position"] - got[t]["position"]).max() / ext) for t in got},
                "kinds": kinds, "slots": edges["ipc"], "sorts": sorts["ipc"], "caught": caught,
                "m2": int(e2.m), "gens": [e1.gen, e2.gen]}
''')


@pytest.fixture(scope="module")
def ipc_sim():
    return run_script(IPC_SIM + "\nprint(json.dumps(ipc_vs_staged(2, 'symplectic', 3, 1)))", sim=True, timeout=600)


def test_simulator_ipc_and_staged_halos_match_one_rank(ipc_sim):
    """3 mock ranks, Symplectic (both stages' slots), rows changing rank: both transports
    give one CPU rank's particles within 1e-9 of the domain (the ipc halo's rows come in
    the sender's order, so the sums differ from staged in round-off only)."""
    assert ipc_sim["ids"], ipc_sim
    assert max(ipc_sim["pos"].values()) < 1e-9, ipc_sim["pos"]
    # one slot per message tag: the middle rank sends both ways in both stages
    assert ipc_sim["slots"] == [2, 4, 2], ipc_sim["slots"]


def test_simulator_ipc_halos_do_not_cross_the_bus(ipc_sim):
    """With ipc no halo row goes up or down: per sort, one 32-byte read of the edges' row
    ranges (both cuts) comes to the host, where staged copies every edge row down and every
    halo row up."""
    staged, ipc = ipc_sim["kinds"]["staged"], ipc_sim["kinds"]["ipc"]
    for r, (s, i) in enumerate(zip(staged, ipc)):
        assert s.get("h2d:halo", 0) > 0 and s.get("d2h:edge", 0) > 32, (r, s)
        assert "h2d:halo" not in i and "d2d:halo" not in i, (r, i)
        assert i["d2h:edge"] == 32 * ipc_sim["sorts"][r] or i["d2h:edge"] == 32 * (ipc_sim["sorts"][r] - 1), (r, i)


def test_simulator_ipc_slot_rewritten_before_read_is_reported(ipc_sim):
    """Between processes (no event), a slot written twice before its receiver read the
    first message: CommError naming the ranks, the tag and both generation numbers, found
    at the receiver's next host wait; the newer message is accepted."""
    msg = ipc_sim["caught"]
    g1, g2 = ipc_sim["gens"]
    assert msg is not None and "rank 0" in msg and "rank 1" in msg and "tag 99" in msg, msg
    assert f"generation {g2}, expected {g1}" in msg, msg
    assert ipc_sim["m2"] > 0


def test_device_edge_wire_round_trip_sends_the_handle_once_per_peer():
    """The MPI wire form (backends.comm.mpi.pack / unpack): every field back, the buffer's
    IPC handle only in the first message to each peer."""
    from sphgraph.backends.comm import mpi as M
    from sphgraph.backends.compute.cuda_halo import DeviceEdge
    owner = {"buf": None, "handle": {"stand-in": "a picklable handle"}, "sent": set()}
    e = DeviceEdge(2, 13, 3, 7, 1000, 1234, 96, (4, 8, 3), (0.25, -1.5, 2.0), 0.0625, 1e-4, 3, np.float32, 98765,
                   owner=owner)
    first = M.unpack(M.pack(e, seq=5, dest=1))
    again = M.unpack(M.pack(e, seq=6, dest=1))
    other = M.unpack(M.pack(e, seq=7, dest=3))
    for x in (first, again, other):
        assert (x.src, x.slot, x.version, x.gen, x.m0, x.m, x.ncells, x.dim, x.nb) == \
               (2, 13, 3, 7, 1000, 1234, 96, 3, 98765)
        assert list(x.dims) == [4, 8, 3] and list(x.origin) == [0.25, -1.5, 2.0]
        assert x.size == 0.0625 and x.moved == 1e-4
        assert x.dtype == np.float32 and x.array is None and x.event is None
    assert first.handle == owner["handle"] and other.handle == owner["handle"]
    assert again.handle is None
    assert M.seq_of(M.pack(e, seq=9, dest=1)) == 9


@pytest.mark.parametrize("args,expect", [
    (["--halo-transport", "pigeon", "--comm", "mock", "--ranks", "2"], "--halo-transport: expected one of auto, staged, ipc"),
    (["--halo-transport", "ipc", "--comm", "mock", "--ranks", "2"], "--halo-transport ipc: needs --backend numba-cuda"),
])
def test_halo_transport_bad_input_exits_2(tmp_path, args, expect):
    scene = os.path.join(os.path.dirname(__file__), "..", "examples", "dambreak2d.toml")
    out = tmp_path / "out.h5"
    p = subprocess.run([sys.executable, "-m", "sphgraph", "run", scene, "--max-steps", "1", "--out", str(out),
                        "--quiet", *args], capture_output=True, text=True, timeout=300)
    assert p.returncode == 2, p.stderr
    lines = [x for x in p.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and expect in lines[0], p.stderr
    assert not out.exists()


@pytest.mark.gpu
@pytest.mark.mpi
@gpu
@pytest.mark.parametrize("n", [2, 4])
def test_gpu_mpiexec_ipc_halos_match_staged_and_one_rank(n):
    """`mpiexec -n 2` and `-n 4` on the GPU machine (all ranks on one GPU, or one each):
    CUDA IPC handles exchanged over MPI, halos device to device; both transports equal to
    the single-rank run within 1e-9 of the domain (tests/mpi_driver.py)."""
    from test_multirank import run_driver
    r = run_driver(n, ["cuda-ipc"], timeout=900)["cuda-ipc"]
    assert r["ok"] and r["rel_err"] <= 1e-9, r
    assert min(r["edge_reads"]) > 0 and min(r["staged_h2d_halo"]) > 0, r
    print(json.dumps(r))
