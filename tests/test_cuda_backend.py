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


def _run(script: str, sim: bool, timeout=300) -> dict:
    env = dict(os.environ)
    if sim:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    else:
        env.pop("NUMBA_ENABLE_CUDASIM", None)
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-4000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _gpu_available() -> bool:
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return False
    try:
        from numba import cuda
        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001
        return False


gpu = pytest.mark.skipif(not _gpu_available(), reason="no CUDA GPU (numba.cuda.is_available() is false)")

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
    out = _run(script, sim=True)
    return {(r["dim"], r["integrator"]): r for r in out}


@pytest.mark.parametrize("dim,integrator,steps", CASES)
def test_simulator_matches_cpu(simulated, dim, integrator, steps):
    """CUDA kernels in the simulator give the CPU result to 1e-9 of the domain (float64)."""
    _check_case(simulated[(dim, integrator)])


def test_simulator_bytes_per_step(simulated):
    """Single rank: per step only the dt terms and the check result (with the next
    grid's bounding box) cross the bus; particle rows move only at upload and sync."""
    for r in simulated.values():
        stages_dt = 24          # 3 float64 dt terms, once per step
        check = 56              # 6 float64 box + 1 int64 first bad row
        for h2d, d2h in r["step_bytes"]:
            assert d2h == stages_dt + check, r["step_bytes"]
            assert h2d == stages_dt + check, r["step_bytes"]
        kinds = set(r["bytes_by_kind"])
        assert kinds <= {"h2d:upload", "h2d:dt", "d2h:dt", "h2d:check", "d2h:check", "d2h:sync_host"}, kinds


def test_retarget_casts_float_literals():
    """Float literals of the physics become literals of the run's type (float32 runs
    stay in float32 instead of numba's float64 literals)."""
    script = textwrap.dedent('''
        import json, numpy as np
        from sphgraph.backends.compute import cuda_kernels as CK
        from sphgraph.physics.kernels import grad_factor
        f32 = CK._clone(grad_factor, np.float32, {})
        f64 = CK._clone(grad_factor, np.float64, {})
        c32 = [type(c).__name__ for c in f32.__code__.co_consts if isinstance(c, (float, np.floating))]
        c64 = [type(c).__name__ for c in f64.__code__.co_consts if isinstance(c, (float, np.floating))]
        print(json.dumps({"c32": c32, "c64": c64}))
    ''')
    out = _run(script, sim=True)
    assert out["c32"] and set(out["c32"]) == {"float32"}
    assert set(out["c64"]) == {"float"}


# ----------------------------------------------------------------------------- real GPU
@pytest.mark.gpu
@gpu
@pytest.mark.parametrize("dim,integrator,steps", CASES)
def test_gpu_float64_matches_cpu(dim, integrator, steps):
    script = COMPARE + "\nprint(json.dumps(compare(%d, %r, %d)))\n" % (dim, integrator, steps)
    _check_case(_run(script, sim=False))


@pytest.mark.gpu
@gpu
def test_gpu_float32_close_to_cpu():
    """float32 arithmetic (float64 positions) against CPU float64 over 40 steps of a
    2D dam break: positions within 1e-5 of the domain."""
    script = COMPARE + "\nprint(json.dumps(compare(2, 'verlet', 40, 'float32', 0.02)))\n"
    r = _run(script, sim=False)
    assert r["ids"]
    assert r["pos"] < 1e-5, r["pos"]


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
    re-upload and no whole download."""
    r = _run(MULTI + f"\nprint(json.dumps(multi(2, {integrator!r}, 3, 2, {schedule!r}, shift={shift})))",
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
    r = _run(MULTI + "\nprint(json.dumps(multi(2, 'symplectic', 3, 2)))", sim=False, timeout=600)
    assert r["ids"]
    assert r["pos"] < 1e-9, r
