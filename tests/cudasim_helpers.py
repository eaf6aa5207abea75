"""Helpers of the numba-cuda tests: a script run in a subprocess, in numba's CUDA simulator or
on the real GPU (`run_script`), and for the feature tests (test_cuda_dufort, test_cuda_riemann,
test_cuda_mdbc) their scene, run and comparison with numba-cpu (`tank`, `compare`, run in a
subprocess by `compare_in_subprocess`; `check_compared`): each feature's test file states its
physics, the run that shows the feature's own effect, and the calls."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest


def run_script(script: str, sim: bool, timeout=300):
    """The last stdout line of `script` as JSON; `sim`: in numba's CUDA simulator
    (`NUMBA_ENABLE_CUDASIM=1`, which must be set before numba is imported)."""
    env = dict(os.environ)
    if sim:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    else:
        env.pop("NUMBA_ENABLE_CUDASIM", None)
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-4000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def gpu_available() -> bool:
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return False
    try:
        from numba import cuda
        return bool(cuda.is_available())
    except Exception:  # noqa: BLE001
        return False


gpu = pytest.mark.skipif(not gpu_available(), reason="no CUDA GPU (numba.cuda.is_available() is false)")


def check_equal(r, tol=1e-9):
    """A `diff` entry of the scripts: the same ids and time, positions within `tol` of the
    domain, densities within 1e-6 kg/m^3."""
    assert r["ids"], r
    assert r["time"][0] == pytest.approx(r["time"][1], rel=1e-9), r
    assert r["pos"] < tol, f"positions differ by {r['pos']:.3g} of the domain: {r}"
    assert r["rho"] < 1e-6, f"densities differ by {r['rho']:.3g} kg/m^3: {r}"


def check_compared(out, gap=None):
    """Each `compare` result in `out` (one, or a list): numba-cuda's run equal to numba-cpu's
    (`check_equal`), numba-cpu's on mock ranks too where it ran, and the feature's own effect
    (its "gap") above `gap` where given."""
    for r in out if isinstance(out, list) else [out]:
        check_equal(r)
        if "cpu_ranks" in r:
            check_equal(r["cpu_ranks"])
        if gap is not None:
            assert r["gap"] > gap, f"the feature changes the densities by only {r['gap']:.3g} kg/m^3: {r}"


# ------------------------------------------------------------------ the feature tests' runs
def tank(dim, physics, layers=1, fluid_3d_top=(0.2, 0.3, 0.25), initial=None, fluid_2d_top=(0.5, 0.8),
         tank_2d=(1.5, 1.2)):
    """The feature tests' scene, dp 0.05: a water column in a tank with `layers` wall layers
    (2D: up to `fluid_2d_top` in a tank of `tank_2d`, by default 0.5 x 0.8 m in 1.5 x 1.2 m, the
    domain 0.2 m beyond it, 0.3 m above; 3D: up to `fluid_3d_top` in 0.4 x 0.3 x 0.4 m, cells of
    h), `physics` over the defaults, `initial` the [initial] table if any."""
    from sphgraph.scene import Scene
    if dim == 2:
        d = {"format": 1, "dim": 2, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
             "domain": {"min": [-0.2, -0.2], "max": [tank_2d[0] + 0.2, tank_2d[1] + 0.3]},
             "physics": {},
             "fluid": [{"type": "box", "min": [0.0, 0.0], "max": list(fluid_2d_top)}],
             "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": list(tank_2d), "layers": layers}]}
    else:
        d = {"format": 1, "dim": 3, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
             "domain": {"min": [-0.2, -0.2, -0.2], "max": [0.6, 0.5, 0.6]},
             "physics": {"cell_size": "h", "coefh": 1.1547005383792515},
             "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": list(fluid_3d_top)}],
             "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.4], "layers": layers}]}
    d["physics"].update(physics)
    if initial is not None:
        d["initial"] = initial
    return Scene.from_dict(d, source="<test>")


def run(sc, backend, steps, ranks=1, transport="auto", precision="float64", schedule=None):
    """`steps` steps of the scene `sc` on `backend` (a name or a ComputeBackend class; `ranks`
    mock ranks, halos by `transport`, the `schedule` if given): the rows in id order (id,
    position, velocity, density) and the time reached."""
    import numpy as np

    from sphgraph.solver import Simulation
    kw = {} if ranks == 1 else {"comm": "mock", "ranks": ranks, "comm_options": {"halo_transport": transport}}
    if schedule is not None:
        kw["schedule"] = schedule
    sim = Simulation(sc, backend=backend, precision=precision, **kw)
    for _ in range(steps):
        sim.step()
    f = sim.frame_arrays()
    i = np.argsort(f["id"])
    return {k: f[k][i] for k in ("id", "position", "velocity", "density")}, sim.time


def diff(sc, a, b) -> dict:
    """How far run b is from run a: the largest position gap (of the domain's extent), velocity
    and density gaps; whether the ids agree; both times."""
    import numpy as np
    ext = float(np.max(sc.domain_max - sc.domain_min))
    return {"n": int(len(a[0]["id"])), "ids": bool(np.array_equal(a[0]["id"], b[0]["id"])),
            "pos": float(np.abs(a[0]["position"] - b[0]["position"]).max() / ext),
            "vel": float(np.abs(a[0]["velocity"] - b[0]["velocity"]).max()),
            "rho": float(np.abs(a[0]["density"] - b[0]["density"]).max()),
            "time": [a[1], b[1]]}


def compare(scene, dim, steps, gap, ranks=1, transport="auto", precision="float64", **kw) -> dict:
    """numba-cuda on `ranks` (mock) against numba-cpu on one rank, for the scene `scene(dim, **kw)`
    (a `diff`). "gap": how far numba-cpu's run of the scene with the options `gap` in place is
    from it (densities): the feature's own effect, which the tolerance must be far below.
    "cpu_ranks" (ranks > 1): numba-cpu on the same mock ranks (staged halos)."""
    sc = scene(dim, **kw)
    cpu = run(sc, "numba-cpu", steps)
    out = diff(sc, cpu, run(sc, "numba-cuda", steps, ranks, transport, precision))
    out["gap"] = diff(sc, cpu, run(scene(dim, **{**kw, **gap}), "numba-cpu", steps))["rho"]
    if ranks > 1:
        out["cpu_ranks"] = diff(sc, cpu, run(sc, "numba-cpu", steps, ranks, "staged"))
    return out


def compare_in_subprocess(test_file: str, calls: str, sim: bool, timeout=300):
    """The JSON value of `calls`, a Python expression over the names of the test module
    `test_file` (its `compare`, say), evaluated by `run_script`."""
    folder, name = os.path.split(os.path.abspath(test_file))
    return run_script(f"import json, sys\nsys.path.insert(0, {folder!r})\nfrom {name[:-3]} import *\n"
                      f"print(json.dumps({calls}))", sim, timeout)
