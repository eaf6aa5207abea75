"""numba.cuda backend: the whole step on the GPU, particle arrays resident between steps.

`NumbaCUDA` (the registry's "numba-cuda") is composed of one mixin a concern, each in its
own module:

    cuda_memory          DeviceState (a rank's device arrays and pinned buffers), counted
                         allocations and host waits (COUNTERS), bus byte counters
    cuda_lanes           CudaLanes: a CUDA stream per schedule lane, events, device trace
    cuda_upload          CudaUpload: prepare (the upload), sync_host, host_arrays
    cuda_cells           CudaCells: build_cells (the device sort), scan, permute, pack
    cuda_rows            CudaRows: displaced rows (take/add_displaced) and edges
    cuda_halo_dispatch   CudaHaloDispatch: prepare_halo, the halo buffer pool, ipc halo forces
    cuda_force_dispatch  CudaForceDispatch: forces, reduce_forces
    cuda_step_dispatch   CudaStepDispatch: dt_local, integrate, check
    cuda_balance         CudaBalance: fluid_count, axis_extent, fluid_histogram, capacity
    cuda_probes          CudaProbes: probe_bounds, probe_sums ([probes] / [forces] sums)
    cuda_motion          CudaMotion: move_bodies ([[motion]] bodies' rows set by id)
    cuda_halo            the ipc halo transport (device to device edges)

The kernels themselves are behind cuda_kernels (and cuda_halo_kernels, cuda_shifting).
"""
from __future__ import annotations

import os

import numpy as np
from numba import cuda

from sphgraph.config import P_SUPPORT2
from sphgraph.registry import register

from . import cuda_kernels as CK
from .base import ComputeBackend
from .cuda_balance import CudaBalance
from .cuda_cells import CudaCells
from .cuda_force_dispatch import CudaForceDispatch
from .cuda_halo_dispatch import CudaHaloDispatch
from .cuda_lanes import CudaLanes, per_thread_default_stream
from .cuda_mdbc import CudaMdbc
from .cuda_motion import CudaMotion
from .cuda_probes import CudaProbes
from .cuda_memory import COUNTERS, dev_array
from .cuda_rows import CudaRows
from .cuda_shifting import CudaShifting
from .cuda_step_dispatch import CudaStepDispatch
from .cuda_upload import CudaUpload

_SELECTED = []


def _select_device():
    """Under mpiexec, one rank per GPU: the node-local rank (MPICH's MPI_LOCALRANKID,
    Open MPI's OMPI_COMM_WORLD_LOCAL_RANK, else the global rank) picks GPU rank % ngpu,
    before any other CUDA call of this process. SPHGRAPH_CUDA_DEVICE overrides."""
    if _SELECTED or CK.SIMULATOR:
        return
    _SELECTED.append(True)
    v = os.environ.get("SPHGRAPH_CUDA_DEVICE")
    if v is None:
        for var in ("MPI_LOCALRANKID", "OMPI_COMM_WORLD_LOCAL_RANK", "PMI_RANK", "OMPI_COMM_WORLD_RANK"):
            if os.environ.get(var) is not None:
                v = os.environ[var]
                break
    if v is None:
        return
    ngpu = len(cuda.gpus)
    if ngpu > 1:
        cuda.select_device(int(v) % ngpu)


@register("compute", "numba-cuda")
class NumbaCUDA(CudaLanes, CudaUpload, CudaCells, CudaRows, CudaHaloDispatch, CudaForceDispatch,
                CudaStepDispatch, CudaBalance, CudaShifting, CudaMdbc, CudaProbes, CudaMotion, ComputeBackend):
    """The ComputeBackend on one GPU a rank; its methods come from the mixins above, one
    module each (see the module doc)."""

    default_precision = "float32"
    device_resident = True
    scene_features = frozenset({"shifting", "mdbc", "mdbc-ranks", "riemann", "riemann_jump", "diffusion_time",
                                "motion"})

    def __init__(self):
        self.sync_tasks = os.environ.get("SPHGRAPH_CUDA_SYNC", "0") == "1"  # profile: time kernels per task
        # schedule lanes as CUDA streams (the scheduler calls lane_begin / lane_end)
        self.uses_lanes = os.environ.get("SPHGRAPH_CUDA_STREAMS", "1") != "0" and not per_thread_default_stream()
        self.lanes: dict = {}          # rank -> Lanes
        self.lane_log = None           # a list: every event record / wait appended (tests)
        self.trace = None              # a list: timing events per task and copy (start_device_trace)
        self.task_clock = None         # {(rank, task): timing events} (start_task_clock)
        self.has_device_clock = self.uses_lanes and not CK.SIMULATOR   # the clock's events ride the lane hooks
        _select_device()

    @classmethod
    def unavailable(cls) -> str | None:
        # is_available() loads the driver library and, only where there is one, initialises it
        if CK.SIMULATOR or cuda.is_available():
            return None
        return ("no usable CUDA GPU or driver (numba.cuda.is_available() is False; "
                "NUMBA_ENABLE_CUDASIM=1 runs the simulator)")

    def device_name(self) -> str:
        if CK.SIMULATOR:
            return "cuda simulator"
        d = cuda.get_current_device()
        name = d.name.decode() if isinstance(d.name, bytes) else str(d.name)
        return f"cuda {name} (cc {d.compute_capability[0]}.{d.compute_capability[1]})"

    def counters(self) -> dict:
        return dict(COUNTERS)

    # -- benchmarks --------------------------------------------------------------------
    def count_pairs(self, state) -> int:
        """Interior pairs within 2h counted on the device as DualSPHysics counts them
        (every neighbour of a fluid row, the fluid neighbours of a boundary row; halos:
        the host count)."""
        if any(h is not None and h.n for h in state.halos.values()):
            return super().count_pairs(state)
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        n = dv.n
        if not n:
            return 0
        g = dv.grid
        counts = dev_array(n, np.int32)
        sup2 = dv.dtype.type(state.prm[P_SUPPORT2])
        k.k_count_pairs2[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
            A["px"], A["py"], A["pz"], A["pos4"], n, dv.nf, A["start"], int(g["ncells"]),
            *(float(x) for x in g["origin"]), float(g["inv"]), *(int(x) for x in g["dims"]),
            *(int(x) for x in g["axes"]), int(g["reach"]), sup2, counts)
        return int(counts.copy_to_host().astype(np.int64).sum())
