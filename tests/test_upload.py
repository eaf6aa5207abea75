"""The numba-cuda upload (cuda_upload.prepare): its host kernels (upload_kernels) give numpy's
values to the bit, and a chunked upload through the staging buffer puts the same rows on the
device as one chunk (CUDA simulator)."""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np

from sphgraph.backends.compute import upload_kernels as UK


def test_column_bounds_are_numpys_min_and_max():
    rng = np.random.default_rng(3)
    for n, dim in ((1, 2), (3, 3), (255, 3), (257, 2), (100_003, 3)):
        pos = rng.normal(size=(n, dim)) * 10.0
        lo, hi = np.empty(dim), np.empty(dim)
        UK.column_bounds(pos, lo, hi)
        assert np.array_equal(lo, pos.min(axis=0)) and np.array_equal(hi, pos.max(axis=0))
        if n > 1:
            pos[n // 2, dim - 1] = np.nan        # NaN propagates, as in ndarray.min / max
            UK.column_bounds(pos, lo, hi)
            assert np.isnan(lo[dim - 1]) and np.isnan(hi[dim - 1])
            assert np.array_equal(lo[:dim - 1], pos.min(axis=0)[:dim - 1])


def test_fills_are_numpys_casts_and_records():
    rng = np.random.default_rng(4)
    n = 1001
    for dim in (2, 3):
        vel = rng.normal(size=(n, dim))
        rho = 1000.0 + rng.normal(size=n)
        out = np.full(4 * 300, 9.0, np.float32)
        UK.records_into(vel, rho, 17, out)
        v4 = np.zeros((n, 4), np.float32)
        v4[:, :dim] = vel
        v4[:, 3] = rho
        assert np.array_equal(out, v4[17:317].reshape(-1))
        col = np.empty(500, np.float32)
        UK.column_into(vel, dim - 1, 9, col)
        assert np.array_equal(col, vel[9:509, dim - 1].astype(np.float32))
    ids = rng.integers(0, 2 ** 31 - 2, size=n)
    assert UK.int_max(ids) == ids.max()
    i32 = np.empty(n - 5, np.int32)
    UK.flat_into(ids, 5, i32)
    assert np.array_equal(i32, ids[5:].astype(np.int32))


CHUNKS = textwrap.dedent('''
    import json, numpy as np
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    from sphgraph.backends.compute import cuda_upload as NC
    d = {"format": 1, "name": "u3", "dim": DIM, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
         "domain": {"min": [-0.2] * DIM, "max": [0.6] * DIM},
         "fluid": [{"type": "box", "min": [0.0] * DIM, "max": [0.15] * DIM}],
         "boundary": [{"type": "tank", "min": [0.0] * DIM, "max": [0.2] * DIM, "layers": 1}]}
    out = {}
    for rows in (1 << 23, 7):
        NC.UPLOAD_ROWS = rows
        sim = Simulation(Scene.from_dict(d, source="<t>"), backend="numba-cuda", precision=PREC)
        dv = sim.contexts[0].state.extra["dev"]
        out[rows] = {k: a.copy_to_host()[:(4 if k == "vel4" else 1) * dv.n].tolist()
                     for k, a in dv.arrays.items()
                     if k in [p + ax for p in ("p", "vm") for ax in "xyz"[:DIM]] + ["vel4", "rhom", "kind", "id"]}
        out[rows]["box"] = dv.box.tolist()
        out[rows]["ref"] = np.asarray(dv.ref).tolist()
        out[rows]["n"] = dv.n
    print(json.dumps({"same": out[1 << 23] == out[7], "n": out[7]["n"], "keys": sorted(out[7])}))
''')


def test_chunked_upload_puts_the_same_rows_on_the_device():
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    for dim, prec in ((2, "float32"), (3, "float32"), (3, "float64")):
        r = subprocess.run([sys.executable, "-c", f"DIM = {dim}\nPREC = {prec!r}\n" + CHUNKS], env=env,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-4000:]
        out = json.loads(r.stdout.strip().splitlines()[-1])
        assert out["n"] > 7 * 3 and out["same"], out
        assert {"px", "py", "vel4", "kind", "id"} <= set(out["keys"])
