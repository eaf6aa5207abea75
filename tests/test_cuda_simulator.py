"""The block runner that backends/compute/cuda_simulator.py puts into numba's CUDA simulator:
a kernel whose threads meet (a shared-memory reduction with syncthreads, directly or in a
device function it calls) runs each thread on its own lane; one whose threads never meet runs
them one after the other on one lane. Both give the kernel's result, and an exception in one
thread is raised from the launch naming that thread."""
from __future__ import annotations

import textwrap

from cudasim_helpers import run_script

SCRIPT = textwrap.dedent('''
    import json
    import numpy as np
    from numba import cuda
    from sphgraph.backends.compute import cuda_retarget, cuda_simulator as S

    def block_sum(a, out):
        sh = cuda.shared.array(64, np.float64)
        t = cuda.threadIdx.x
        i = cuda.grid(1)
        sh[t] = a[i] if i < a.size else 0.0
        cuda.syncthreads()
        s = 32
        while s > 0:
            if t < s:
                sh[t] += sh[t + s]
            cuda.syncthreads()
            s //= 2
        if t == 0:
            cuda.atomic.add(out, 0, sh[0])

    def wait_here():
        cuda.syncthreads()

    def calls_a_barrier(a):
        i = cuda.grid(1)
        wait_here()
        if i < a.size:
            a[i] = 2.0 * a[i]

    def twice(v):
        return 2.0 * v

    def scale(a, out):
        i = cuda.grid(1)
        if i < a.size:
            out[i] = twice(a[i]) + cuda.threadIdx.x

    def fails_at(a, k):
        i = cuda.grid(1)
        if i == k:
            raise ValueError("row " + str(k))
        if i < a.size:
            a[i] = 1.0

    dev = {"twice": cuda_retarget.device_function(twice, np.float64),
           "wait_here": cuda.jit(device=True)(wait_here)}
    kern = {}
    for f in (block_sum, calls_a_barrier, scale, fails_at):
        f.__globals__.update(dev)
        kern[f.__name__] = cuda.jit(f)

    a = np.arange(200, dtype=np.float64)
    out = np.zeros(1)
    kern["block_sum"][4, 64](a, out)
    b = a.copy()
    kern["calls_a_barrier"][4, 64](b)
    c = np.zeros(200)
    kern["scale"][4, 64](a, c)
    errors = []
    for k in (70, 199):
        try:
            kern["fails_at"][4, 64](np.zeros(200), k)
            errors.append(None)
        except ValueError as e:
            errors.append(str(e))
    print(json.dumps({
        "independent": {f.__name__: S._independent(f) for f in (block_sum, calls_a_barrier, scale, fails_at)},
        "sum": float(out[0]), "doubled": bool(np.array_equal(b, 2 * a)),
        "scaled": bool(np.array_equal(c, 2 * a + np.arange(200) % 64)),
        "errors": errors}))
''')


def test_simulator_runs_meeting_threads_on_lanes_and_the_rest_one_after_another():
    r = run_script(SCRIPT, sim=True, timeout=300)
    assert r["independent"] == {"block_sum": False, "calls_a_barrier": False, "scale": True,
                                "fails_at": True}, r
    assert r["sum"] == sum(range(200)), r
    assert r["doubled"] and r["scaled"], r
    # the failing thread is named: thread 70 is block 1's thread 6; row 199 block 3's thread 7
    assert r["errors"][0] is not None and "tid=[6, 0, 0] ctaid=[1, 0, 0]" in r["errors"][0], r
    assert r["errors"][1] is not None and "tid=[7, 0, 0] ctaid=[3, 0, 0]" in r["errors"][1], r
