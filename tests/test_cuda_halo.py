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

from test_cuda_backend import SCENES, _run, gpu

IPC_SIM = SCENES + textwrap.dedent('''
    import json
    import numpy as np
    from sphgraph.errors import CommError

    def ipc_vs_staged(dim, integrator, ranks, steps):
        """Both transports on `ranks` mock ranks (inner cuts moved by 2 spacings: rows change
        rank in the first step), then a slot rewritten before its receiver read it."""
        sc = scene(dim, integrator)
        got, kinds, edges = {}, {}, {}
        for tr in ("staged", "ipc"):
            g = mock_sim(sc, ranks, comm_options={"halo_transport": tr})
            for _ in range(steps):
                g.step()
            got[tr] = rows_by_id(g)
            kinds[tr] = [dict(c.state.extra.get("bytes_by_kind", {})) for c in g.contexts]
            edges[tr] = [len(c.state.extra["dev"].__dict__.get("edge_slots", {})) for c in g.contexts]
        # rank 0 writes its upward slot twice before rank 1 reads the first message
        c0, c1 = g.contexts[0], g.contexts[1]
        e1 = g.compute.edge(c0.state, c0.domain, 1, slot=99)
        e2 = g.compute.edge(c0.state, c0.domain, 1, slot=99)
        try:
            g.compute.prepare_halo(c1.state, e1)
            caught = None
        except CommError as e:
            caught = str(e)
        g.compute.prepare_halo(c1.state, e2)          # the current one is accepted
        return {"same": {k: bool(np.array_equal(got["staged"][k], got["ipc"][k])) for k in got["ipc"]},
                "kinds": kinds, "slots": edges["ipc"], "caught": caught, "n2": int(e2.n), "m2": int(e2.m),
                "gens": [e1.gen, e2.gen]}
''')


@pytest.fixture(scope="module")
def ipc_sim():
    return _run(IPC_SIM + "\nprint(json.dumps(ipc_vs_staged(2, 'symplectic', 3, 1)))", sim=True, timeout=600)


def test_simulator_ipc_halos_bit_identical_to_staged(ipc_sim):
    """3 mock ranks, Symplectic (both stages' slots), rows changing rank: the halos binned on
    the device give the staged path's bits (same grid, same rows in the same order)."""
    assert ipc_sim["same"] == {"id": True, "position": True, "velocity": True, "density": True}, ipc_sim
    # one slot per message tag: the middle rank sends both ways in both stages
    assert ipc_sim["slots"] == [2, 4, 2], ipc_sim["slots"]


def test_simulator_ipc_halos_do_not_cross_the_bus(ipc_sim):
    """With ipc no halo row is uploaded and only the edge's range ends (16 B) and the halo's
    count and box (72 B) come down; the rows go device to device."""
    staged, ipc = ipc_sim["kinds"]["staged"], ipc_sim["kinds"]["ipc"]
    for r, (s, i) in enumerate(zip(staged, ipc)):
        assert s.get("h2d:halo", 0) > 0 and "d2d:halo" not in s, (r, s)
        assert "h2d:halo" not in i and i.get("d2d:halo", 0) > 0, (r, i)
        sends = ipc_sim["slots"][r]                         # one edge message per slot (1 step)
        assert i["d2h:edge"] == 16 * sends, (r, i)
        assert i["d2h:halo_meta"] == 72 * sends, (r, i)    # one receive per message sent to it
        assert s["d2h:edge"] > i["d2h:edge"], (r, s, i)


def test_simulator_ipc_slot_rewritten_before_read_is_reported(ipc_sim):
    """A slot written twice before its receiver read the first message: CommError naming
    the ranks, the tag and both generation numbers; the newer message is accepted."""
    msg = ipc_sim["caught"]
    g1, g2 = ipc_sim["gens"]
    assert msg is not None and "rank 0" in msg and "rank 1" in msg and "tag 99" in msg, msg
    assert f"generation {g2}, expected {g1}" in msg, msg
    assert 0 < ipc_sim["n2"] <= ipc_sim["m2"]


def test_device_edge_wire_round_trip_sends_the_handle_once_per_peer():
    """The MPI wire form (backends.comm.mpi.pack / unpack): every field back, the buffer's
    IPC handle only in the first message to each peer."""
    from sphgraph.backends.comm import mpi as M
    from sphgraph.backends.compute.cuda_halo import DeviceEdge
    owner = {"buf": None, "handle": {"stand-in": "a picklable handle"}, "sent": set()}
    e = DeviceEdge(2, 13, 3, 7, 1234, 3, np.float32, 0.3125, True, 2, 98765, owner=owner)
    first = M.unpack(M.pack(e, seq=5, dest=1))
    again = M.unpack(M.pack(e, seq=6, dest=1))
    other = M.unpack(M.pack(e, seq=7, dest=3))
    for x in (first, again, other):
        assert (x.src, x.slot, x.version, x.gen, x.m, x.dim, x.below, x.axis, x.nb) == \
               (2, 13, 3, 7, 1234, 3, True, 2, 98765)
        assert x.dtype == np.float32 and x.thr == 0.3125 and x.array is None
    assert first.handle == owner["handle"] and other.handle == owner["handle"]
    assert again.handle is None
    assert M.seq_of(M.pack(e, seq=9, dest=1)) == 9


@pytest.mark.parametrize("args,expect", [
    (["--halo-transport", "pigeon", "--comm", "mock", "--ranks", "2"], "--halo-transport: expected one of staged, ipc"),
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
def test_gpu_mpiexec_ipc_halos_match_staged_and_one_rank():
    """`mpiexec -n 2` on the GPU machine (two ranks on one GPU or one each): CUDA IPC
    handles exchanged over MPI, halos device to device; bit-identical to the staged
    transport, and to the single-rank run within 1e-9 of the domain (tests/mpi_driver.py)."""
    from test_multirank import run_driver
    r = run_driver(2, ["cuda-ipc"], timeout=900)["cuda-ipc"]
    assert r["ipc_equals_staged"] and r["rel_err"] <= 1e-9, r
    assert min(r["d2d_halo"]) > 0 and min(r["staged_h2d_halo"]) > 0, r
    print(json.dumps(r))
