"""Moving bodies (`[[motion]]`) on numba-cuda (backends/compute/cuda_motion.py) against
numba-cpu: a gate lifted out of the water and a paddle turning in it, the device rows set by
id from the host's motion table.

As tests/test_cuda_riemann.py: numba's CUDA simulator in a subprocess, float64, Verlet and
Symplectic (whose corrector reads the bodies moved between the stages), one rank and 2 mock
ranks. The `gap` entry is how far numba-cpu's run with the bodies held still is from the moving
one: the bodies' own effect, far above the tolerance (a backend that does not move them fails).
"""
from __future__ import annotations

import pytest

import cudasim_helpers as H
from cudasim_helpers import check_compared, compare_in_subprocess, gpu


def _with_bodies(dim, integrator, still):
    from sphgraph.scene import Scene
    speed = 1e-9 if still else 3.0      # m/s; "still": the same particles, held (nearly) in place
    omega = 0.0 if still else 6.0       # rad/s
    if dim == 2:
        d = {"format": 1, "dim": 2, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
             "domain": {"min": [-0.2, -0.2], "max": [1.7, 1.5]},
             "physics": {"integrator": integrator},
             "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.5, 0.8]}],
             "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.5, 1.2], "layers": 1},
                          {"type": "box", "name": "gate", "min": [0.55, 0.05], "max": [0.6, 0.9]},
                          {"type": "box", "name": "paddle", "min": [1.0, 0.1], "max": [1.3, 0.15]}],
             "motion": [{"body": "gate", "type": "gate", "speed": speed, "lift": 0.3, "start": 0.0},
                        {"body": "paddle", "type": "rotation", "times": [0.0, 1.0], "omega": [omega, omega],
                         "center": [1.15, 0.125]}]}
    else:
        d = {"format": 1, "dim": 3, "dp": 0.05, "end_time": 1.0, "output_interval": 1.0,
             "domain": {"min": [-0.2, -0.2, -0.2], "max": [0.6, 0.5, 0.9]},
             "physics": {"cell_size": "h", "coefh": 1.1547005383792515, "integrator": integrator},
             "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [0.2, 0.3, 0.25]}],
             "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.4], "layers": 1},
                          {"type": "box", "name": "gate", "min": [0.25, 0.05, 0.05], "max": [0.3, 0.25, 0.35]}],
             "motion": [{"body": "gate", "type": "gate", "speed": speed, "lift": 0.3, "start": 0.0}]}
    return Scene.from_dict(d, source="<test>")


def compare(dim, steps, integrator="symplectic", **run):
    """cudasim_helpers.compare; its "gap": numba-cpu with the bodies held still."""
    return H.compare(_with_bodies, dim, steps, {"still": True}, integrator=integrator, still=False, **run)


def test_simulator_motion_matches_cpu_one_rank():
    check_compared(compare_in_subprocess(__file__, "[compare(2, 4), compare(2, 4, integrator='verlet'), "
                                         "compare(3, 3)]", sim=True), gap=1e-4)


def test_simulator_motion_matches_cpu_two_mock_ranks():
    """2 mock ranks (staged halos): the bodies' rows spread over both ranks' slabs."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 4, ranks=2, transport='staged')]", sim=True),
                   gap=1e-4)


@pytest.mark.gpu
@gpu
def test_gpu_motion_matches_cpu():
    """On a real GPU, float64: one rank and 2 mock ranks against one CPU rank."""
    check_compared(compare_in_subprocess(__file__, "[compare(2, 20), compare(3, 10), compare(2, 20, ranks=2)]",
                                         sim=False, timeout=600))
