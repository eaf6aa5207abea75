"""numba-cuda backend against numba-cpu.

CI has no GPU: the kernels run in numba's CUDA simulator, which must be switched on
before numba is imported, so those checks run in a subprocess
(`NUMBA_ENABLE_CUDASIM=1`) and the rest of the suite keeps the real CPU target.
The simulator is slow (~6e4 pair evaluations/s): a few hundred particles, <= 3 steps,
float64. Tests marked `gpu` run on a real GPU (the lent GPU machine) and are skipped
with a reason elsewhere.
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

SCENES = textwrap.dedent('''
    from sphgraph.scene import Scene

    def scene(dim, integrator, dp=0.05, fluid_hi=None):
        if dim == 2:
            d = {"format": 1, "name": "t2", "dim": 2, "dp": dp, "end_time": 1.0, "output_interval": 1.0,
                 "domain": {"min": [-0.2, -0.2], "max": [1.7, 1.5]},
                 "physics": {"integrator": integrator, "verlet_euler_every": 2},
                 "fluid": [{"type": "box", "min": [0.0, 0.0], "max": fluid_hi or [0.5, 0.8]}],
                 "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.5, 1.2], "layers": 1}]}
        else:
            d = {"format": 1, "name": "t3", "dim": 3, "dp": dp, "end_time": 1.0, "output_interval": 1.0,
                 "domain": {"min": [-0.2, -0.2, -0.2], "max": [0.6, 0.5, 0.6]},
                 "physics": {"integrator": integrator, "verlet_euler_every": 2, "cell_size": "h",
                             "coefh": 1.1547005383792515, "diffusion": "fourtakas-full"},
                 "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": fluid_hi or [0.2, 0.3, 0.25]}],
                 "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.4], "layers": 1}]}
        return Scene.from_dict(d, source="<test>")

    def mock_sim(sc, ranks, shift=2, **kw):
        """The CUDA backend (float64) on `ranks` mock ranks with the inner cuts moved up by
        `shift` spacings: the rows between the old and the new cuts change rank in the first
        step (removed and appended on the device)."""
        from sphgraph.solver import Simulation
        g = Simulation(sc, backend="numba-cuda", precision="float64", comm="mock", ranks=ranks, **kw)
        for c in g.contexts:
            c.domain.cuts = c.domain.cuts.copy()
            c.domain.cuts[1:-1] += shift * sc.dp
        return g

    def rows_by_id(sim):
        """The gathered rows in id order (id, position, velocity, density)."""
        import numpy as np
        f = sim.frame_arrays()
        i = np.argsort(f["id"])
        return {k: f[k][i] for k in ("id", "position", "velocity", "density")}
''')

COMPARE = SCENES + textwrap.dedent('''
    import json, sys, time
    import numpy as np
    from sphgraph.solver import Simulation

    def compare(dim, integrator, steps, precision="float64", dp=0.05):
        sc = scene(dim, integrator, dp=dp)
        res = {}
        for b in ("numba-cpu", "numba-cuda"):
            sim = Simulation(sc, backend=b, precision="float64" if b == "numba-cpu" else precision)
            t0 = time.perf_counter()
            counts = []
            for _ in range(steps):
                st = sim.contexts[0].state
                before = (st.extra.get("h2d_bytes", 0), st.extra.get("d2h_bytes", 0))
                sim.step()
                counts.append((st.extra.get("h2d_bytes", 0) - before[0], st.extra.get("d2h_bytes", 0) - before[1]))
            res[b] = (sim.frame_arrays(), sim.time, time.perf_counter() - t0, counts,
                      dict(sim.contexts[0].state.extra.get("bytes_by_kind", {})))
        a, g = res["numba-cpu"][0], res["numba-cuda"][0]
        ext = float(np.max(sc.domain_max - sc.domain_min))
        return {"dim": dim, "integrator": integrator, "n": int(len(a["id"])),
                "ids": bool(np.array_equal(a["id"], g["id"])),
                "pos": float(np.abs(a["position"] - g["position"]).max() / ext),
                "vel": float(np.abs(a["velocity"] - g["velocity"]).max()),
                "rho": float(np.abs(a["density"] - g["density"]).max()),
                "time": [res["numba-cpu"][1], res["numba-cuda"][1]],
                "gpu_s": res["numba-cuda"][2], "step_bytes": res["numba-cuda"][3],
                "bytes_by_kind": res["numba-cuda"][4], "steps": steps}
''')


CASES = [(2, "verlet", 3), (2, "symplectic", 2), (3, "verlet", 2), (3, "symplectic", 2)]


def _check_case(r, tol=1e-9):
    where = f"{r['dim']}D {r['integrator']}"
    assert r["ids"], where
    assert r["time"][0] == pytest.approx(r["time"][1], rel=1e-9), where
    assert r["pos"] < tol, f"{where}: positions differ by {r['pos']:.3g} of the domain"
    assert r["rho"] < 1e-6, f"{where}: density differs by {r['rho']:.3g}"


@pytest.fixture(scope="module")
def simulated():
    script = COMPARE + "\nprint(json.dumps([compare(*c) for c in %r]))\n" % (CASES,)
    out = run_script(script, sim=True)
    return {(r["dim"], r["integrator"]): r for r in out}


@pytest.mark.parametrize("dim,integrator,steps", CASES)
def test_simulator_matches_cpu(simulated, dim, integrator, steps):
    """CUDA kernels in the simulator give the CPU result to 1e-9 of the domain (float64)."""
    _check_case(simulated[(dim, integrator)])


def test_simulator_bytes_per_step(simulated):
    """Single rank: per step only the dt terms and the check result (with the next
    grid's bounding box) come down, nothing goes up (their accumulators are set on the
    device); particle rows move only at upload and sync."""
    for r in simulated.values():
        stages_dt = 24          # 3 float64 dt terms, once per step
        check = 56              # 6 float64 box + 1 int64 first bad row
        for h2d, d2h in r["step_bytes"]:
            assert d2h == stages_dt + check, r["step_bytes"]
            assert h2d == 0, r["step_bytes"]
        kinds = set(r["bytes_by_kind"])
        assert kinds <= {"h2d:upload", "h2d:dt", "d2h:dt", "h2d:check", "d2h:check", "d2h:sync_host"}, kinds


def test_retarget_casts_float_literals():
    """Float literals of the physics become literals of the run's type (float32 runs
    stay in float32 instead of numba's float64 literals)."""
    script = textwrap.dedent('''
        import json, numpy as np
        from sphgraph.backends.compute.cuda_retarget import _clone
        from sphgraph.physics.kernels import grad_factor
        f32 = _clone(grad_factor, np.float32, {})
        f64 = _clone(grad_factor, np.float64, {})
        c32 = [type(c).__name__ for c in f32.__code__.co_consts if isinstance(c, (float, np.floating))]
        c64 = [type(c).__name__ for c in f64.__code__.co_consts if isinstance(c, (float, np.floating))]
        print(json.dumps({"c32": c32, "c64": c64}))
    ''')
    out = run_script(script, sim=True)
    assert out["c32"] and set(out["c32"]) == {"float32"}
    assert set(out["c64"]) == {"float"}


FORCES_SCRIPT = textwrap.dedent('''
    import json, sys, numpy as np
    sys.path.insert(0, ROOT)
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    from benchmarks import cuda_force_variants as V
    d = {"format": 1, "name": "q3", "dim": 3, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
         "domain": {"min": [-0.2, -0.2, -0.2], "max": [0.6, 0.5, 0.6]},
         "physics": {"integrator": "verlet", "cell_size": "h", "coefh": 1.1547005383792515,
                     "diffusion": "fourtakas-full"},
         "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [0.15, 0.15, 0.15]}],
         "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [0.2, 0.2, 0.2], "layers": 1}]}
    d["physics"]["integrator"] = INTEGRATOR
    V.select(forces="f")
    sim = Simulation(Scene.from_dict(d, source="<t>"), backend="numba-cuda", precision="float64")
    sim.step()
    st = sim.contexts[0].state
    dv = st.extra["dev"]
    sim.compute.build_cells(st)              # freshly sorted: rows trimmed with no slack
    if INTEGRATOR == "symplectic":           # after the predictor: trimmed with its slack
        sim.compute.forces(st, "interior")
        st.dt = sim.compute.dt_local(st)
        sim.compute.integrate(st, 1, "symplectic", False)
    res = {}
    for v in ("f", "fv"):
        V.select(forces=v)
        dv.A()["ar"].copy_to_device(np.full(dv.n, np.nan))   # poison: every row must be written
        dv.A()["visc"].copy_to_device(np.zeros(1))           # the viscous maximum, from this call only
        sim.compute.forces(st, "interior")
        A = dv.A()
        res[v] = [A[k].copy_to_host()[:dv.n] for k in ("ax", "ay", "az", "ar", "visc")]
    print(json.dumps({"n": dv.n, "nf": dv.nf, "moved": float(dv.moved),
                      "diff": [float(np.abs(a - b).max()) for a, b in zip(res["f"], res["fv"])],
                      "scale": [float(np.abs(a).max()) for a in res["f"]],
                      "nan": {k: int(np.isnan(r[3]).sum()) for k, r in res.items()}}))
''')


@pytest.mark.parametrize("integrator", ["verlet", "symplectic"])
def test_simulator_fluid_force_kernels_sum_alike(integrator):
    """k_forces_fv / k_forces_bv (16-byte record loads, cell ranges from the relative
    positions in the run's type, rows trimmed to the sphere's chord) against
    benchmarks/cuda_force_variants.py's k_forces_f / k_forces_b (whole cells) on one 3D state in the simulator, right after a sort and
    (Symplectic) after the predictor moved the rows: the same sums in the same order
    (bit-identical), every row written."""
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    script = f"INTEGRATOR = {integrator!r}\nROOT = {root!r}\n" + FORCES_SCRIPT
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-4000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["nf"] > 20 and min(out["scale"][:4]) > 0
    assert set(out["nan"].values()) == {0}
    assert out["diff"] == [0.0] * 5, out
    # trimmed with a finite slack: none right after the sort, dt/2 |v|max after the predictor
    if integrator == "verlet":
        assert out["moved"] == 0.0, out
    else:
        assert 0.0 < out["moved"] < 1e-3, out


def test_trimmed_row_holds_exactly_the_chord():
    """_trimmed (bisection in the first and the last cell of a row of cells, each sorted
    along the row) returns exactly the rows whose coordinate lies in [lo, hi] when lo
    lies in or below the first cell and hi in or above the last (as the force kernels
    ask: the row's cells come from the same chord)."""
    from sphgraph.backends.compute.cuda_forces import _trimmed
    trimmed = getattr(_trimmed, "py_func", _trimmed)
    rng = np.random.default_rng(3)
    for trial in range(300):
        ncell = int(rng.integers(1, 7))
        counts = rng.integers(0, 6, ncell)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        x = np.concatenate([np.sort(rng.uniform(c, c + 1, k)) for c, k in enumerate(counts)])
        if trial % 3 == 0:
            x = np.round(x * 2) / 2                      # ties, and values on the bounds
        pos4 = np.zeros(4 * max(len(x), 1))
        comp = int(rng.integers(0, 3))
        pos4[comp::4][:len(x)] = x
        clo = int(rng.integers(0, ncell))
        chi = int(rng.integers(clo, ncell))
        # as the kernel asks: lo in or below the first cell (cells are [c, c + 1]), hi in
        # or above the last, lo <= hi
        lo = float(rng.uniform(clo - 0.5, clo + 1))
        hi = float(rng.uniform(max(lo, chi), chi + 1.5))
        if trial % 3 == 0:
            lo, hi = np.floor(lo * 2) / 2, np.ceil(hi * 2) / 2
        j0, j1 = trimmed(pos4, start, 0, clo, chi, comp, lo, hi)
        whole = np.arange(start[clo], start[chi + 1])
        want = whole[(x[whole] >= lo) & (x[whole] <= hi)]
        assert list(range(j0, j1)) == list(want), (trial, j0, j1, want)


# ----------------------------------------------------------------------------- real GPU
@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("dim,integrator,steps", CASES)
def test_gpu_float64_matches_cpu(dim, integrator, steps):
    script = COMPARE + "\nprint(json.dumps(compare(%d, %r, %d)))\n" % (dim, integrator, steps)
    _check_case(run_script(script, sim=False))


@pytest.mark.gpu
@gpu
def test_gpu_float32_close_to_cpu():
    """float32 arithmetic (float64 positions) against CPU float64 over 40 steps of a
    2D dam break: positions within 1e-5 of the domain."""
    script = COMPARE + "\nprint(json.dumps(compare(2, 'verlet', 40, 'float32', 0.02)))\n"
    r = run_script(script, sim=False)
    assert r["ids"]
    assert r["pos"] < 1e-5, r["pos"]


FAST_LAUNCH = SCENES + textwrap.dedent('''
    import json, os
    import numpy as np
    from sphgraph.solver import Simulation
    from sphgraph.backends.compute import cuda_launch as CL
    out = {}
    for integ in ("verlet", "symplectic"):
        sim = Simulation(scene(3, integ), backend="numba-cuda", precision="float32")
        for _ in range(6):
            sim.step()
        a = sim.frame_arrays()
        out[integ] = {k: np.asarray(v).tolist() for k, v in a.items() if k in ("position", "velocity", "density")}
    out["launches"] = dict(CL.launches)
    out["enabled"] = CL.ENABLED
    print(json.dumps(out))
''')


@pytest.mark.gpu
@gpu
def test_gpu_fast_launch_bit_identical_to_numba_launch():
    """cuda_launch's path (numba's overload, arguments flattened as numba flattens them,
    cuda.core launch) against numba-cuda's own launch: 6 steps of 3D Verlet and
    Symplectic, float32, bit-identical; most launches took the fast path."""
    env = dict(os.environ)
    env.pop("NUMBA_ENABLE_CUDASIM", None)
    res = {}
    for flag in ("1", "0"):
        env["SPHGRAPH_CUDA_FAST_LAUNCH"] = flag
        r = subprocess.run([sys.executable, "-c", FAST_LAUNCH], env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-4000:]
        res[flag] = json.loads(r.stdout.strip().splitlines()[-1])
    fast, slow = res["1"], res["0"]
    assert fast["enabled"] and not slow["enabled"]
    assert fast["launches"]["fast"] > 4 * fast["launches"]["numba"], fast["launches"]
    assert slow["launches"]["fast"] == 0
    for integ in ("verlet", "symplectic"):
        for k in fast[integ]:
            assert fast[integ][k] == slow[integ][k], (integ, k)


MULTI = SCENES + textwrap.dedent('''
    import json
    import numpy as np
    from sphgraph.solver import Simulation

    def multi(dim, integrator, steps, ranks, schedule="production", precision="float64", shift=0):
        sc = scene(dim, integrator)
        ref = Simulation(sc, backend="numba-cpu", precision="float64")
        gpu = Simulation(sc, backend="numba-cuda", precision=precision, comm="mock", ranks=ranks,
                         schedule=schedule)
        # move the inner cuts by `shift` spacings: the rows between the old and the new cut
        # change rank in the first step (removed and appended on the device)
        for c in gpu.contexts:
            c.domain.cuts = c.domain.cuts.copy()
            c.domain.cuts[1:-1] += shift * sc.dp
        kinds = lambda: [dict(c.state.extra.get("bytes_by_kind", {})) for c in gpu.contexts]
        before = kinds()
        for _ in range(steps):
            ref.step()
            gpu.step()
        after = kinds()
        a, g = ref.frame_arrays(), gpu.frame_arrays()
        ia, ig = np.argsort(a["id"]), np.argsort(g["id"])
        ext = float(np.max(sc.domain_max - sc.domain_min))
        delta = lambda key: [x.get(key, 0) - y.get(key, 0) for x, y in zip(after, before)]
        return {"ids": bool(np.array_equal(a["id"][ia], g["id"][ig])),
                "pos": float(np.abs(a["position"][ia] - g["position"][ig]).max() / ext),
                "rho": float(np.abs(a["density"][ia] - g["density"][ig]).max()),
                "displaced_out": delta("d2h:displaced"), "displaced_in": delta("h2d:displaced"),
                "uploads": delta("h2d:upload"), "syncs": delta("d2h:sync_host")}
''')


@pytest.mark.parametrize("integrator,schedule,shift", [("verlet", "production", 2),
                                                        ("symplectic", "bulk-synchronous", -2)])
def test_simulator_multirank_matches_cpu(integrator, schedule, shift):
    """2 mock ranks on the CUDA kernels (edges sliced on the device, halo forces, partial
    buffers, reduce, kind-split interior launches, rows changing rank) against 1 rank on
    the CPU, float64, 2D. (Before the edges and displaced rows were read from the device,
    the ranks sent stale host rows and re-uploaded them every step: 8e-7 of the domain,
    1e-2 in density.) The cut is moved by 2 spacings (up, then down), so rows change rank
    in the first step: they must be removed and appended on the device, with no whole
    re-upload and no whole download. Two steps: the step the rows change rank in and one
    after it."""
    r = run_script(MULTI + f"\nprint(json.dumps(multi(2, {integrator!r}, 2, 2, {schedule!r}, shift={shift})))",
             sim=True, timeout=600)
    assert r["ids"]
    assert r["pos"] < 1e-9, r
    assert r["rho"] < 1e-6, r
    giver, taker = (1, 0) if shift > 0 else (0, 1)
    assert r["displaced_out"][giver] > 0 and r["displaced_in"][taker] > 0, r
    assert r["uploads"] == [0, 0] and r["syncs"] == [0, 0], r


@gpu
def test_gpu_multirank_matches_cpu():
    """The same 2 mock ranks on the GPU (float64) against 1 CPU rank."""
    r = run_script(MULTI + "\nprint(json.dumps(multi(2, 'symplectic', 3, 2)))", sim=False, timeout=600)
    assert r["ids"]
    assert r["pos"] < 1e-9, r


# ----------------------------------------------------------------------------- lanes
LANES = MULTI + textwrap.dedent('''
    def lanes(runs):
        """CPU reference (1 rank) and, per (ranks, steps), the production and bulk-synchronous
        schedules on the CUDA backend (lane streams and events), inner cuts moved up by 2
        spacings so rows change rank in the first step; every event record / wait logged."""
        sc = scene(2, "verlet")
        ext = float(np.max(sc.domain_max - sc.domain_min))
        ref = Simulation(sc, backend="numba-cpu", precision="float64")
        refs = []
        for _ in range(max(s for _, s in runs)):
            ref.step()
            a = ref.frame_arrays()
            i = np.argsort(a["id"])
            refs.append({k: a[k][i] for k in ("id", "position", "density")})
        out = []
        for ranks, steps in runs:
            got = {}
            for sch in ("production", "bulk-synchronous"):
                g = mock_sim(sc, ranks, schedule=sch)
                g.compute.lane_log = []
                for _ in range(steps):
                    g.step()
                got[sch] = (rows_by_id(g), g.compute.lane_log, g.compute.uses_lanes,
                            [len(c.state.extra.get("bytes_by_kind", {})) for c in g.contexts],
                            [dict(c.state.extra.get("bytes_by_kind", {})) for c in g.contexts])
            r = refs[steps - 1]
            p, b = got["production"][0], got["bulk-synchronous"][0]
            out.append({"ranks": ranks, "steps": steps,
                        "ids": bool(np.array_equal(r["id"], p["id"]) and np.array_equal(r["id"], b["id"])),
                        "pos": max(float(np.abs(r["position"] - x["position"]).max()) / ext for x in (p, b)),
                        "rho": max(float(np.abs(r["density"] - x["density"]).max()) for x in (p, b)),
                        "same": all(bool(np.array_equal(p[k], b[k])) for k in p),
                        "uses_lanes": [got[s][2] for s in got],
                        "moved": [x.get("d2h:displaced", 0) for x in got["production"][4]],
                        "logs": {s: got[s][1] for s in got}})
        return out
''')

LANE_RUNS = [(2, 2), (3, 1)]


@pytest.fixture(scope="module")
def lane_runs():
    script = LANES + "\nprint(json.dumps(lanes(%r)))\n" % (LANE_RUNS,)
    return {r["ranks"]: r for r in run_script(script, sim=True, timeout=600)}


@pytest.mark.parametrize("ranks", [r for r, _ in LANE_RUNS])
def test_simulator_lanes_production_and_bulk_synchronous_agree(lane_runs, ranks):
    """With one stream per lane and events for the cross-lane edges, the production and
    bulk-synchronous schedules give bit-identical particles on 2 and 3 mock ranks (rows
    change rank in the first step), and match 1 CPU rank to 1e-9 of the domain."""
    r = lane_runs[ranks]
    assert r["uses_lanes"] == [True, True], r["uses_lanes"]
    assert r["ids"], r
    assert r["same"], "production and bulk-synchronous differ"
    assert r["pos"] < 1e-9, r["pos"]
    assert r["rho"] < 1e-6, r["rho"]
    assert any(m > 0 for m in r["moved"]), r["moved"]


def _expected_lane_events(schedule, rank, nranks):
    """Cross-lane edges of one rank's step, from the rank graph (independent of the
    scheduler's lane_edges), plus the accumulate-order edges between lanes. The scene's feature
    tasks are `check` and `exclude` (exclusion is on by default): the end-of-step check, started
    and read."""
    import networkx as nx   # noqa: F401  (rank_graph's)
    from sphgraph import Schedule
    from sphgraph.graph.build import rank_graph
    S = Schedule.load(schedule)
    prog = S.program(rank, nranks, 1, features=("check", "exclude"))
    lane = {t.name: t.lane for t in prog}
    g = rank_graph(S.canonical(rank, nranks, 1, features=("check", "exclude")))
    cross = {(u, v) for u, v in g.edges() if u in lane and v in lane and lane[u] != lane[v]}
    acc = {(a.name, b.name) for i, a in enumerate(prog) for b in prog[i + 1:]
           if a.lane != b.lane and set(a.accumulates) & set(b.accumulates)}
    return prog, cross, acc


@pytest.mark.parametrize("ranks", [r for r, _ in LANE_RUNS])
@pytest.mark.parametrize("schedule", ["production", "bulk-synchronous"])
def test_simulator_lane_events_are_the_cross_lane_edges(lane_runs, ranks, schedule):
    """The backend records an event at the end of every task that a task on another lane
    depends on, and the consumer's stream waits for exactly those: the cross-lane edges
    of the rank graph, plus build_cells -- recv_displaced in issue order (both accumulate
    into the rows: they commute, but must not run at once). forces_interior waits for nothing on the comm
    lane but the displaced rows (it overlaps the edge copy and the halo receive); each
    halo force waits for its receive. The first task of a lane in a step waits for the
    other lanes' previous step."""
    r = lane_runs[ranks]
    log = r["logs"][schedule]
    for rank in range(ranks):
        prog, cross, acc = _expected_lane_events(schedule, rank, ranks)
        pre = ("build_cells", "recv_displaced")   # in issue order
        assert acc == {pre if schedule == "production" else pre[::-1]}, acc
        want = cross | acc
        lanes_of = {t.name: t.lane for t in prog}
        for step in range(r["steps"]):
            mine = [e[2:] for e in log if e[0] == rank and e[1] == step]
            waits = {(u, v) for op, v, u in mine if op == "wait"}
            records = [v for op, v, _ in mine if op == "record"]
            assert waits == want, (rank, step, sorted(waits ^ want))
            assert sorted(records) == sorted({u for u, _ in want}), (rank, step, records)
            order = [(op, v, u) for op, v, u in mine if op in ("wait", "record")]
            for i, (op, v, u) in enumerate(order):   # every wait comes after its record
                if op == "wait":
                    assert ("record", u, lanes_of[u]) in order[:i], (rank, step, v, u)
            assert ("send_edges@1", "forces_interior@1") not in waits
            assert {u for u, v in waits if v == "forces_interior@1"} == {"send_displaced", "recv_displaced"}
            for side in (1, 2):
                if f"forces_halo_{side}@1" in lanes_of:
                    assert (f"recv_halo_{side}@1", f"forces_halo_{side}@1") in waits
            tails = [(op, v, u) for op, v, u in mine if op.endswith("_tail")]
            last = prog[-1].name
            rec = {("record_tail", last, lane) for lane in set(lanes_of.values())}
            first = {}
            for t in prog:
                first.setdefault(t.lane, t.name)
            wt = set() if step == 0 else {("wait_tail", first[a], b) for a in first for b in first if a != b}
            assert set(tails) == rec | wt, (rank, step, tails)


LANES_GPU = MULTI + textwrap.dedent('''
    import os

    def streams_vs_default(ranks, steps):
        """Production on `ranks` mock ranks, float64, with one stream per lane and with the
        default stream only: bit-identical rows?"""
        sc = scene(2, "verlet")
        res = {}
        for streams in ("1", "0"):
            os.environ["SPHGRAPH_CUDA_STREAMS"] = streams
            g = mock_sim(sc, ranks)
            for _ in range(steps):
                g.step()
            res[streams] = (rows_by_id(g), g.compute.uses_lanes)
        a, b = res["1"][0], res["0"][0]
        return {"lanes": [res["1"][1], res["0"][1]], "same": all(bool(np.array_equal(a[k], b[k])) for k in a)}
''')


@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("ranks", [2, 3])
def test_gpu_lane_streams_bit_identical_to_the_default_stream(ranks):
    """On the GPU, one stream per lane with events (production, rows changing rank, float64)
    gives the bits of the default-stream path (SPHGRAPH_CUDA_STREAMS=0): no event missing."""
    r = run_script(LANES_GPU + f"\nprint(json.dumps(streams_vs_default({ranks}, 5)))", sim=False, timeout=600)
    assert r["lanes"] == [True, False], r
    assert r["same"], r


@pytest.mark.gpu
@gpu
def test_gpu_lanes_overlap_interior_forces_with_the_edge_copy(tmp_path):
    """~1 M particles (SPHERIC 2 at dp 0.01, float32) on 2 mock ranks sharing the GPU:
    production and bulk-synchronous timed by benchmarks/gpu_lanes.py, then traced on the
    device (timing events per task and copy). In production forces_interior is launched
    right after the edge sends are posted, so on the device it runs while edges are copied
    (on an H200, 2026-12-01: 2 of 8 interior tasks at 1.1 M, all 8 at 4.4 M, against the
    neighbour's edge copy down; bulk-synchronous none)."""
    out = tmp_path / "lanes.json"
    cmd = [sys.executable, os.path.join(os.path.dirname(__file__), "..", "benchmarks", "gpu_lanes.py"),
           "--dp", "0.01", "--ranks", "2", "--steps", "5", "--warmup", "3", "--trace-steps", "3",
           "--json", str(out)]
    env = dict(os.environ)
    env.pop("NUMBA_ENABLE_CUDASIM", None)
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-4000:]
    runs = {r["schedule"]: r for r in json.loads(out.read_text())["runs"]}
    keys = ("particles", "steps_per_s", "interior_s", "own_edge_d2h_s", "own_halo_h2d_s", "nb_edge_d2h_s",
            "nb_halo_h2d_s", "interior_overlapping_edges", "interior_tasks")
    print(json.dumps({s: {k: r[k] for k in keys} for s, r in runs.items()}))
    prod = runs["production"]
    assert prod["uses_lanes"] and prod["particles"] > 900_000, prod["particles"]
    assert prod["interior_tasks"] == 2 * 2 * 3 and prod["interior_s"] > 0, prod["overlap"]
    assert prod["interior_overlapping_edges"] > 0, prod["overlap"]
    assert runs["bulk-synchronous"]["steps_per_s"] > 0
