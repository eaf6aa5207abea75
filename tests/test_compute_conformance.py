"""One conformance suite every compute backend passes (DESIGN.md §2).

`ComputeConformance` holds the behaviour a compute backend must show on the
real kernels; each backend binds it in a class. numba-cuda runs it on a GPU when
one is present, and in CI through numba's CUDA simulator in a subprocess
(`NUMBA_ENABLE_CUDASIM` must be set before numba is imported), with sizes the
simulator can afford (<= 2k particles, <= 5 steps, float64).
"""
import os
import subprocess
import sys

import numpy as np
import pytest

from sphgraph import Scene
from sphgraph.registry import get
from sphgraph.solver import Simulation

import naive

SIM = os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"


def tiny_scene(dim=2, integrator="verlet"):
    d = {"format": 1, "name": "tiny", "dim": dim, "dp": 0.05 if dim == 2 else 0.1, "end_time": 1.0,
         "domain": {"min": [0.0] * dim, "max": [1.0] * (dim - 1) + [0.8], "origin": [0.0] * dim},
         "physics": {"integrator": integrator, "visc_alpha": 0.05},
         "fluid": [{"type": "box", "min": [0.0] * dim, "max": [0.3] * (dim - 1) + [0.4]}],
         "boundary": [{"type": "tank", "min": [0.0] * dim, "max": [1.0] * (dim - 1) + [0.8]}]}
    return Scene.from_dict(d)


def arrays_after(backend, steps, scene, precision="float64"):
    sim = Simulation(scene, backend=backend, precision=precision)
    for _ in range(steps):
        sim.step()
    return sim, sim.frame_arrays()


_STEPPED = {}


def tiny_after_steps(backend, integrator, steps=5):
    """The gathered rows after `steps` steps of `tiny_scene(integrator=...)` on `backend`, run
    once per process: test_steps_match_naive and TestNumbaCUDA.test_steps_match_numba_cpu
    check the same run (in the simulator each such run takes ~12 s). Read only."""
    key = (backend, integrator, steps)
    if key not in _STEPPED:
        _STEPPED[key] = arrays_after(backend, steps, tiny_scene(integrator=integrator))[1]
    return _STEPPED[key]


class ComputeConformance:
    backend = None

    def test_registered_and_named(self):
        cls = get("compute", self.backend)
        assert cls.name == self.backend and cls.default_precision in ("float32", "float64")

    def test_host_arrays_contract(self):
        sim, a = arrays_after(self.backend, 0, tiny_scene())
        n = sim.n_total
        assert a["id"].dtype == np.int64 and a["kind"].dtype == np.int8
        assert a["position"].shape == (n, 2) and a["velocity"].shape == (n, 2)
        assert a["density"].shape == (n,) and a["pressure"].shape == (n,)
        np.testing.assert_array_equal(np.sort(a["id"]), np.arange(n))

    def test_first_step_forces_match_naive(self):
        """After build_cells + forces, the reduced acceleration equals the O(N^2) reference."""
        sc = tiny_scene()
        sim = Simulation(sc, backend=self.backend, precision="float64")
        ctx = sim.contexts[0]
        be, st = sim.compute, ctx.state
        be.build_cells(st)
        be.forces(st, "interior")
        be.reduce_forces(st, 1)
        st.dt = 1e-5
        be.integrate(st, 1, "verlet", True)     # Euler step: v1 = v0 + dt a, with v0 = 0
        a = be.host_arrays(st)
        order = np.argsort(a["id"])
        p0 = sc.build_particles()
        ace, _ = naive.forces(p0.pos, p0.vel, p0.rho, p0.kind, sc.constants, sc.physics)
        fl = p0.kind == 0
        expect = (ace + sc.constants.gravity)[fl] * 1e-5
        got = a["velocity"][order][fl]
        np.testing.assert_allclose(got, expect, rtol=1e-8, atol=1e-12)

    @pytest.mark.parametrize("integrator", ["verlet", "symplectic"])
    def test_steps_match_naive(self, integrator):
        """5 steps (forces, dt, integration) against tests/naive.py's O(N^2) stepping."""
        sc = tiny_scene(integrator=integrator)
        got = tiny_after_steps(self.backend, integrator, 5)
        pos, vel, rho = naive.steps(sc.build_particles(), sc.constants, sc.physics, 5, integrator)
        np.testing.assert_array_equal(got["id"], np.arange(len(rho)))
        assert np.abs(got["position"] - pos).max() <= 1e-9 * 1.0
        assert np.abs(got["position"] - sc.build_particles().pos).max() > 1e-6   # the fluid moved
        np.testing.assert_allclose(got["velocity"], vel, rtol=0, atol=1e-9)
        np.testing.assert_allclose(got["density"], rho, rtol=1e-9)

    def test_check_names_the_bad_particle(self):
        sim = Simulation(tiny_scene(), backend=self.backend, precision="float64")
        sim.step()
        st = sim.contexts[0].state
        lo, hi = np.array([0.5, 0.5]), np.array([0.6, 0.6])      # most particles are outside this box
        bad = sim.compute.check(st, lo, hi)
        assert bad is not None and bad[1] == 2
        assert sim.compute.check(st, sim.lo, sim.hi) is None


    # -- the rows protocol and the balancing queries (ComputeBackend's declared interface) --
    def _stepped(self, steps=2):
        sim = Simulation(tiny_scene(), backend=self.backend, precision="float64")
        for _ in range(steps):
            sim.step()
        return sim, sim.contexts[0].state

    def test_balancing_queries_match_the_rows(self):
        sim, st = self._stepped()
        be = sim.compute
        a = be.host_arrays(st)
        fl = a["kind"] == 0
        assert be.fluid_count(st) == int(fl.sum()) > 0
        for axis in (0, 1):
            x = a["position"][:, axis]
            assert be.axis_extent(st, axis) == (float(x.min()), float(x.max()))
            edges = np.linspace(-0.1, 1.1, 13)
            np.testing.assert_array_equal(be.fluid_histogram(st, axis, edges),
                                          np.histogram(x[fl], bins=edges)[0])

    def test_sync_host_brings_the_host_rows_up_to_date(self):
        sim, st = self._stepped()
        sim.compute.sync_host(st)
        a = sim.compute.host_arrays(st)
        p = st.particles
        order = np.argsort(p.id)
        np.testing.assert_array_equal(p.id[order], np.sort(a["id"]))
        np.testing.assert_array_equal(p.pos[order], a["position"][np.argsort(a["id"])])

    def test_rows_that_leave_the_slab_come_back_whole(self):
        """take_displaced removes exactly the rows past the cut (their ids and positions as
        the host sees them); add_displaced puts them back: the same rows, forces as before."""
        from sphgraph.domain import Slabs
        sim, st = self._stepped()
        be = sim.compute
        before = be.host_arrays(st)
        cut = 0.15
        up = before["position"][:, 0] >= cut
        assert 0 < up.sum() < len(up)
        be.check(st, sim.lo, sim.hi)            # a device backend learns its rows' box here
        slab = Slabs(0, 0, np.array([-np.inf, cut]), reach=0.1)
        out = be.take_displaced(st, slab)
        assert out[-1].n == 0 and out[1].n == int(up.sum())
        np.testing.assert_array_equal(np.sort(out[1].id), np.sort(before["id"][up]))
        left = be.host_arrays(st)
        np.testing.assert_array_equal(np.sort(left["id"]), np.sort(before["id"][~up]))
        whole = Slabs(0, 0, np.array([-np.inf, np.inf]), reach=0.1)
        be.add_displaced(st, whole, [out[1]], built=False)
        after = be.host_arrays(st)
        i, j = np.argsort(after["id"]), np.argsort(before["id"])
        np.testing.assert_array_equal(after["id"][i], before["id"][j])
        np.testing.assert_array_equal(after["position"][i], before["position"][j])
        np.testing.assert_array_equal(after["density"][i], before["density"][j])

    def test_edge_holds_the_rows_within_reach_of_the_cut(self):
        sim, st = self._stepped()
        be = sim.compute
        a = be.host_arrays(st)
        cut, reach = 0.15, 0.1
        be.check(st, sim.lo, sim.hi)
        be.build_cells(st)
        slab = Slabs_for(0, cut, reach)
        h = be.edge(st, slab, 1)
        x = a["position"][:, 0]
        want = np.sort(x[x >= cut - reach])
        got = np.sort(np.asarray(h.pos)[:, 0])
        # a device edge may send whole cell planes (a superset); never fewer rows
        assert len(got) >= len(want)
        assert np.isin(np.round(want, 12), np.round(got, 12)).all()

    def test_counters_are_a_dict_of_numbers(self):
        c = get("compute", self.backend)().counters()
        assert isinstance(c, dict) and all(isinstance(v, (int, float)) for v in c.values())


def Slabs_for(rank, cut, reach):
    from sphgraph.domain import Slabs
    return Slabs(rank, 0, np.array([-np.inf, cut]), reach=reach)


class TestNumbaCPU(ComputeConformance):
    backend = "numba-cpu"


def _cuda_usable():
    try:
        from numba import cuda
        return SIM or cuda.is_available()
    except Exception:  # noqa: BLE001 - no CUDA target at all
        return False


@pytest.mark.skipif(not _cuda_usable(), reason="no CUDA GPU (and not under NUMBA_ENABLE_CUDASIM=1)")
class TestNumbaCUDA(ComputeConformance):
    backend = "numba-cuda"

    @pytest.mark.parametrize("integrator", ["verlet", "symplectic"])
    def test_steps_match_numba_cpu(self, integrator):
        ref = tiny_after_steps("numba-cpu", integrator, 5)
        got = tiny_after_steps(self.backend, integrator, 5)
        np.testing.assert_array_equal(got["id"], ref["id"])
        assert np.abs(got["position"] - ref["position"]).max() <= 1e-9 * 1.0
        np.testing.assert_allclose(got["density"], ref["density"], rtol=1e-9)


@pytest.mark.skipif(SIM, reason="already inside the simulator")
def test_numba_cuda_passes_the_suite_in_the_simulator():
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", __file__,
                        "-k", "TestNumbaCUDA"], env=env, capture_output=True, text=True, timeout=900,
                       cwd=os.path.dirname(__file__))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and "skipped" not in r.stdout.splitlines()[-1], r.stdout[-500:]
