"""Periodic images made on the device (backends/compute/cuda_images.py) against the host path
they replace (ComputeBackend.periodic_images: the rows near a face copied to the host, imaged
and binned there, uploaded): the same grid and row order, so the same bits, in numba's CUDA
simulator; and what crossed the bus for them (the 72-byte count and bounding box and the
4-byte row count, against every near-face row)."""
from __future__ import annotations

import pytest

from cudasim_helpers import compare_in_subprocess, gpu


def host_images_backend():
    """numba-cuda making its images on the host, as before cuda_images."""
    from sphgraph.backends.compute.base import ComputeBackend
    from sphgraph.backends.compute.numba_cuda import NumbaCUDA

    class HostImages(NumbaCUDA):
        name = "numba-cuda"
        periodic_images = ComputeBackend.periodic_images
    return HostImages


def run(backend, steps, boundary, precision):
    """The driven channel of test_mdbc_periodic (rows cross the seam), `steps` steps: rows in
    id order, the images' halo type and the bytes a stage brought to the host for images."""
    import numpy as np

    from sphgraph.solver import Simulation
    from test_mdbc_periodic import drift_scene
    sim = Simulation(drift_scene(boundary), backend=backend, precision=precision)
    for _ in range(steps):
        sim.step()
    st = sim.contexts[0].state
    f = sim.frame_arrays()
    i = np.argsort(f["id"])
    return ({k: f[k][i] for k in ("position", "velocity", "density")}, type(st.halos.get(3)).__name__,
            st.extra.get("bytes_by_kind", {}).get("d2h:images", 0) / max(sim.step_count, 1))


def compare(steps, boundary="mdbc", precision="float64", tight=False) -> dict:
    """`tight`: the images packed to half their first count, then to exactly the count (no
    margin), so that the first stage and any stage with more rows near a face than the last
    packs them again ("repacked": how many times)."""
    import numpy as np

    from sphgraph.backends.compute import cuda_images
    from sphgraph.backends.compute.cuda_memory import COUNTERS
    if tight:
        calls = []

        def bound(m):
            calls.append(m)
            return max(m // 2, 1) if len(calls) == 1 else m
        cuda_images._bound = bound
    dev, dev_kind, dev_bytes = run("numba-cuda", steps, boundary, precision)
    repacked = COUNTERS["images_repacked"]
    host, host_kind, host_bytes = run(host_images_backend(), steps, boundary, precision)
    return {"gap": max(float(np.abs(dev[k] - host[k]).max()) for k in dev), "kinds": [dev_kind, host_kind],
            "bytes": [dev_bytes, host_bytes], "repacked": repacked, "steps": steps}


def check(r):
    assert r["kinds"] == ["DeviceImages", "Halo"], r
    assert r["gap"] == 0.0, r
    # the device path's: the count and box (72 B) each time images are made (twice a step
    # with mDBC), the row count (4 B) once, and the count and box again for each packing
    # redone; the host path's: every near-face row
    limit = 2 * 72 + (4 + 72 * r["repacked"]) / r["steps"]
    assert 0 < r["bytes"][0] <= limit < r["bytes"][1], r


def test_simulator_device_images_are_the_host_images():
    """mDBC in float64 (images made twice a stage), packed to tight bounds: the first stage
    packs again. float32 runs in the gpu variant."""
    r = compare_in_subprocess(__file__, "compare(3, 'mdbc', 'float64', tight=True)", sim=True, timeout=900)
    assert r["repacked"] > 0, r
    check(r)


@gpu
@pytest.mark.gpu
def test_gpu_device_images_are_the_host_images():
    check(compare_in_subprocess(__file__, "compare(100, 'mdbc-noslip', 'float32')", sim=False, timeout=600))
