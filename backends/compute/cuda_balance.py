"""Load balancing queries of the numba.cuda backend, from the device rows with no
download: fluid rows, extent along an axis, histogram of the fluid rows, and the rows
the device has room for (`particle_capacity`)."""
from __future__ import annotations

import numpy as np
from numba import cuda

from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from .cuda_memory import VEC, host_wait


class CudaBalance:
    """NumbaCUDA's balancing and capacity queries."""

    def fluid_count(self, state) -> int:
        return state.extra["dev"].nf

    def axis_extent(self, state, axis: int) -> tuple[float, float]:
        """From the bounding box of the last check (the rows have not moved since)."""
        dv = state.extra["dev"]
        return (float(dv.box[0, axis]), float(dv.box[1, axis])) if dv.n else (np.inf, -np.inf)

    def fluid_histogram(self, state, axis: int, edges) -> np.ndarray:
        """One atomic-add pass over the fluid rows (k_axis_hist), one copy to the host."""
        dv = state.extra["dev"]
        nb = len(edges) - 1
        out = dv.dev_buf("hist", 8 * nb).view(np.int64)
        k = self._k(state)
        k.k_fill[CK.blocks(nb), CK.BLOCK](out, nb, 0)
        if dv.nf:
            hk = self._on(state, HK.build(dv.dtype))
            e0, e1 = float(edges[0]), float(edges[-1])
            hk.k_axis_hist[CK.blocks(dv.nf), CK.BLOCK](dv.arrays["p" + VEC[axis]], dv.nf, e0, e1,
                                                       nb / (e1 - e0), nb, out)
        h = dv.host_buf(8 * nb).view(np.int64)
        s = self._s(state)
        out.copy_to_host(h, stream=s)
        host_wait(s)
        return h.copy()

    def state_bytes(self, state) -> int:
        dv = state.extra.get("dev")
        return 0 if dv is None else dv.nbytes()

    def particle_capacity(self, state, max_particles_per_rank=None, sharing=1) -> int | None:
        """Free device memory (split among the `sharing` ranks on this device) at the rank's
        measured bytes per allocated row, plus the rows it holds, less its boundary rows
        (sphgraph.balance.device_capacity); never above `max_particles_per_rank`."""
        from sphgraph.balance import device_capacity
        dv = state.extra.get("dev")
        if dv is None or CK.SIMULATOR:
            return max_particles_per_rank
        free, _total = cuda.current_context().get_memory_info()
        rows = max(dv.cap, 1)
        cap = device_capacity(free / max(sharing, 1), dv.nbytes() / rows, held_rows=rows,
                              fixed_rows=dv.n - dv.nf)
        if cap is None or max_particles_per_rank is None:
            return cap if cap is not None else max_particles_per_rank
        return min(cap, max_particles_per_rank)
