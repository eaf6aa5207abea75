"""mDBC on several ranks (numba-cpu, mock MPI; real MPI in test_multirank's driver): the ghosts
near a cut sum the halos' fluid, and `send_mdbc` / `recv_mdbc_1/2` carry the edge's boundary
rows' new densities and velocities to the neighbours' halos. Equal to one rank within 1e-9 of
the domain; without either part the result differs (the tests below can fail)."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import example
from sphgraph import Scene, Simulation
from sphgraph.backends.compute.numba_cpu import NumbaCPU
from sphgraph.cli import main
from sphgraph.errors import InputError
from sphgraph.toml_writer import dumps_toml

STEPS = 60


def mdbc_scene(boundary="mdbc-noslip", integrator=None):
    sc = Scene.from_toml(example("dambreak2d.toml")).with_overrides(dp=0.04)
    d = sc.to_dict()
    d["physics"] = dict(d.get("physics", {}), boundary=boundary)
    if integrator:
        d["physics"]["integrator"] = integrator
    return Scene.from_dict(d)


class NoExchange(NumbaCPU):
    """numba-cpu whose halos keep the boundary values from before the neighbour's mdbc."""
    name = "numba-cpu"

    def mdbc_halo(self, state, halo, values):
        pass


class NoHaloSums(NumbaCPU):
    """numba-cpu whose ghosts sum the owned fluid only."""
    name = "numba-cpu"

    def mdbc(self, state, boxes, det_min, noslip, moving=None):
        halos, state.halos = state.halos, {}
        try:
            super().mdbc(state, boxes, det_min, noslip, moving)
        finally:
            state.halos = halos


def run(sc, ranks, backend="numba-cpu", schedule="bulk-synchronous", push=2.0):
    sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks, schedule=schedule, backend=backend)
    for c in sim.contexts:        # a uniform push: rows cross the cuts, boundary rows near them see it
        p = c.state.particles
        p.vel[p.kind == 0, 0] += push
        p.vel_m1[p.kind == 0, 0] += push
    for _ in range(STEPS):
        sim.step()
    return sim, sim.frame_arrays()


def span(sc):
    return float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))


@pytest.mark.parametrize("boundary,integrator,ranks", [
    ("mdbc-noslip", None, 2), ("mdbc-noslip", None, 3), ("mdbc", "symplectic", 2), ("mdbc", "symplectic", 3)])
def test_mock_ranks_match_one_rank(boundary, integrator, ranks):
    sc = mdbc_scene(boundary, integrator)
    _, one = run(sc, 1)
    sim, many = run(sc, ranks)
    assert np.array_equal(many["id"], one["id"])
    assert np.abs(many["position"] - one["position"]).max() <= 1e-9 * span(sc)
    np.testing.assert_allclose(many["density"], one["density"], rtol=1e-9, atol=0)
    np.testing.assert_allclose(many["velocity"], one["velocity"], rtol=0, atol=1e-9)
    # the exchange is tasks of the graph, seen by the timers, and it moved bytes
    cols = sim.scheduler.times.columns()
    names = {str(x) for x in cols["task"]}
    assert {"mdbc@1", "send_mdbc@1", "recv_mdbc_1@1", "recv_mdbc_2@1"} <= names
    assert ("mdbc@2" in names) == (integrator == "symplectic")


@pytest.mark.parametrize("backend", [NoExchange, NoHaloSums])
def test_each_part_of_the_exchange_matters(backend):
    sc = mdbc_scene()
    _, one = run(sc, 1)
    _, bad = run(sc, 2, backend=backend)
    assert np.abs(bad["position"] - one["position"]).max() > 1e-7 * span(sc)


def test_a_schedule_with_forces_before_the_halos_is_refused():
    with pytest.raises(InputError, match=r"production.toml: order: .*recv_halo_1 and recv_halo_2 before"):
        Simulation(mdbc_scene(), comm="mock", ranks=2, schedule="production")
    with pytest.raises(InputError, match="recv_halo_2 before"):
        Simulation(mdbc_scene(), comm="mock", ranks=3, schedule="halo-first")
    Simulation(mdbc_scene(), comm="single", schedule="production")     # one rank: no halos to wait for


def test_cli_runs_mdbc_on_mock_ranks(tmp_path, capsys):
    from sphgraph.io import read_frame
    path = tmp_path / "m.toml"
    path.write_text(dumps_toml(mdbc_scene().to_dict()))
    out = tmp_path / "o"
    rc = main(["run", str(path), "--out", str(out), "--max-steps", "20", "--quiet", "--comm", "mock", "--ranks", "2",
               "--schedule", "bulk-synchronous"])
    assert rc == 0, capsys.readouterr()
    assert read_frame(out)["step"] == 20
    rc = main(["run", str(path), "--out", str(tmp_path / "bad"), "--quiet", "--comm", "mock", "--ranks", "2"])
    assert rc == 2 and not (tmp_path / "bad").exists()
    assert "bulk-synchronous" in capsys.readouterr().err


@pytest.mark.mpi
@pytest.mark.parametrize("n", [2, 3])
def test_mpi_ranks_match_one_rank(n):
    from test_multirank import run_driver
    r = run_driver(n, ["mdbc2d"])
    assert r["mdbc2d"]["ranks"] == n and r["mdbc2d"]["rel_err"] <= 1e-9
