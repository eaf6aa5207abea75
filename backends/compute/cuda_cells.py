"""The device sort of the numba.cuda backend (`build_cells`): rows binned by
(kind, cell) with a device scan, each cell's rows ordered along the rows of cells,
every row array permuted in place through the pos4 scratch, and the pos4 records
rebuilt (`_pack`)."""
from __future__ import annotations

import os

import numpy as np

from sphgraph.cells import grid_dims, reach_cells

from . import cuda_kernels as CK
from .cuda_memory import VEC, dev_array

# Force rows trimmed to the sphere's chord along the rows of cells (cells sorted by that
# coordinate; k_forces_fv). SPHGRAPH_CUDA_TRIM=0: whole cells, as k_forces_f.
TRIM = os.environ.get("SPHGRAPH_CUDA_TRIM", "1") != "0"


def device_grid(box_lo, box_hi, cell_size, axes):
    """The grid over a bounding box given along the particle axes, as
    sphgraph.cells.build_grid makes it: origin, upper corner and cells along (fast, mid,
    slow), and per particle axis the origin, cell count and key stride the key kernels take
    (build_cells; the periodic images binned on the device, cuda_images)."""
    lo, hi = np.zeros(3), np.zeros(3)
    for kk in range(3):
        a = axes[kk]
        if a >= 0:
            lo[kk], hi[kk] = box_lo[a], box_hi[a]
    dims = grid_dims(lo, hi, cell_size, axes)
    stride = np.array([1, dims[0], dims[0] * dims[1]], np.int64)
    o_ax, n_ax, s_ax = np.zeros(3), np.ones(3, np.int64), np.zeros(3, np.int64)
    for kk in range(3):
        a = axes[kk]
        if a >= 0:
            o_ax[a], n_ax[a], s_ax[a] = lo[kk], dims[kk], stride[kk]
    return lo, hi, dims, o_ax, n_ax, s_ax


class CudaCells:
    """NumbaCUDA's sort: build_cells and the scan, permutation and packing it uses (also
    used by the migration, cuda_rows, and the integration, cuda_step_dispatch)."""

    def _scan(self, dv, k, counts, out, n, level=0, tmp=None):
        """Exclusive scan of counts[0:n] into out[0:n] (device, recursive over block sums);
        `tmp` the list of block-sum buffers (default the rank's; a halo binned on another
        stream brings its own)."""
        per = 2048
        nb = (n + per - 1) // per
        tmp = dv.scan_tmp if tmp is None else tmp
        while len(tmp) < 2 * level + 2:
            tmp.append(dev_array(1, np.int64))
        if tmp[2 * level].shape[0] < nb:
            tmp[2 * level] = dev_array(int(nb * 1.25) + 1, np.int64)
            tmp[2 * level + 1] = dev_array(int(nb * 1.25) + 1, np.int64)
        sums, offs = tmp[2 * level], tmp[2 * level + 1]
        k.k_scan_blocks[nb, 256](counts, n, out, sums)
        if nb > 1:
            self._scan(dv, k, sums, offs, nb, level + 1, tmp)
            k.k_scan_add[CK.blocks(n), CK.BLOCK](out, n, offs)

    def build_cells(self, state) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        n, dim = dv.n, dv.dim
        c = state.consts
        reach = reach_cells(c.h, c.cell_size)
        axes = np.asarray(state.axes, np.int64)
        # grid over the rows' bounding box (from the last check)
        box = dv.box if n else np.zeros((2, 3))
        lo, _, dims, o_ax, n_ax, s_ax = device_grid(box[0], box[1], c.cell_size, axes)
        ncells = int(dims.prod())
        # kind-split keys: fluid cells 0..ncells-1, boundary cells ncells..2 ncells-1
        nk = 2 * ncells
        if dv.cell_cap < nk + 1:
            cap = int((nk + 1) * 1.05) + 16    # room for a grid that grows a little (5 %: memory counts)
            dv.arrays["start"] = dev_array(cap, np.int32)
            dv.cell_cap = cap
            dv.arrays.pop("counts", None)
        start = dv.start
        counts = dv.scratch(np.int32, nk)            # the histogram in the (dead) pos4 records
        koff = nk
        if counts is None:
            if "counts" not in dv.arrays or dv.arrays["counts"].shape[0] < nk:
                dv.arrays["counts"] = dev_array(dv.cell_cap, np.int32)
            counts = dv.arrays["counts"]
            koff = 0
        keys = dv.scratch(np.int32, n, koff)          # the cell keys after it (dead once scattered)
        if keys is None:
            if "keys" not in dv.arrays or dv.arrays["keys"].shape[0] < n:
                dv.arrays["keys"] = dev_array(max(dv.cap, 1), np.int32)
            keys = dv.arrays["keys"]
        inv = 1.0 / c.cell_size
        if n:
            k.k_fill[CK.blocks(nk), CK.BLOCK](counts, nk, 0)
            k.k_keys_hist2[CK.blocks(n), CK.BLOCK](dv.px, dv.py, dv.pz, dv.kind, n, dim, o_ax[0], o_ax[1],
                                                    o_ax[2], inv, n_ax[0], n_ax[1], n_ax[2],
                                                    s_ax[0], s_ax[1], s_ax[2], ncells, keys, counts)
            self._scan(dv, k, counts, start, nk)
            k.k_set_last[1, 1](start, nk, n)
            # scatter: counts becomes the fill pointer (a copy of start)
            k.k_copy[CK.blocks(nk), CK.BLOCK](start, nk, counts)
            k.k_scatter[CK.blocks(n), CK.BLOCK](keys, n, counts, dv.perm)
            # each cell's rows in increasing coordinate along the rows of cells (axes[0]):
            # the force kernels trim every row of cells to the sphere's chord by bisection
            key = (dv.px, dv.py, dv.pz)[int(axes[0])] if axes[0] >= 0 and TRIM else None
            if key is not None:
                k.k_sort_cells_by[CK.blocks(nk), CK.BLOCK](start, nk, dv.perm, key)
            else:
                k.k_sort_cells[CK.blocks(nk), CK.BLOCK](start, nk, dv.perm)
            self._permute(state, dv, k)
        else:
            k.k_fill[CK.blocks(nk + 1), CK.BLOCK](start, nk + 1, 0)
        dv.sort_gen += 1
        # "rows": the row set sorted (rows that come or go after it are not in the grid)
        dv.grid = {"origin": lo, "dims": dims, "axes": axes, "inv": inv, "reach": reach,
                   "ncells": ncells, "size": c.cell_size, "rows": (n, dv.nf)}
        # rows sorted along the cell rows just now (or trimming off until they are)
        dv.moved = 0.0 if (TRIM and axes[0] >= 0) else np.inf
        if n:
            self._pack(state, dv, k, True)
        dv.host_stale = True
        self._sync()

    def _permute(self, state, dv, k):
        """Every row array reordered by perm: gathered into the pos4 buffer (dead until
        _pack rebuilds it) and copied back, so no array needs a twin. Up to three arrays
        go in one gather and one copy (k_gather3 / k_copy3), as many as fit the buffer's
        16 bytes a row, widest first so each view is aligned: 3D Symplectic, positions x
        and y, then z with kind and id (4 launches and one read of perm each, where one
        array a pass took 10)."""
        n, perm = dv.n, dv.perm
        b = CK.blocks(n)
        A = dv.arrays
        k.k_gather4[b, CK.BLOCK](A["vel4"], perm, n, A["pos4"])
        k.k_copy[CK.blocks(4 * n), CK.BLOCK](A["pos4"], 4 * n, A["vel4"])
        hist = dv.integrator in (None, "verlet")   # Symplectic: history rewritten each step
        for g in self._permute_groups(dv, hist):
            arrs = [A[nm] for nm in g]
            views, off = [], 0               # bytes into the buffer, a multiple of each width
            for a in arrs:
                w = a.dtype.itemsize
                views.append(dv.scratch(a.dtype, n, off * n // w))
                off += w
            m = len(arrs)
            arrs += [arrs[0]] * (3 - m)      # unused slots (m tells the kernels)
            views += [views[0]] * (3 - m)
            k.k_gather3[b, CK.BLOCK](*arrs, m, perm, n, *views)
            k.k_copy3[b, CK.BLOCK](*views, m, n, *arrs)

    @staticmethod
    def _permute_groups(dv, hist):
        """_permute's arrays in groups of at most three and 16 bytes a row, widest first
        (cached per device state: the same every sort)."""
        cache = dv.permute_groups
        if hist not in cache:
            A = dv.arrays
            names = ["p" + VEC[d] for d in range(dv.dim)]
            if hist:
                names += ["vm" + VEC[d] for d in range(dv.dim)] + ["rhom"]
            names += ["kind", "id"]
            names.sort(key=lambda nm: -A[nm].dtype.itemsize)        # stable: the order above within a width
            groups, cur, width = [], [], 0
            for nm in names:
                w = A[nm].dtype.itemsize
                if len(cur) == 3 or width + w > 16:
                    groups.append(cur)
                    cur, width = [], 0
                cur.append(nm)
                width += w
            groups.append(cur)
            cache[hist] = groups
        return cache[hist]

    def _pack(self, state, dv, k, with_press):
        """pos4 records from the float64 positions (and the pressure of rho)."""
        ref = np.zeros(3)
        ref[:dv.dim] = dv.ref
        A = dv.arrays
        k.k_pack[CK.blocks(dv.n), CK.BLOCK](A["px"], A["py"], A["pz"], A["vel4"], dv.n, dv.dim,
                                             float(ref[0]), float(ref[1]), float(ref[2]), dv.prm_d(state),
                                             bool(with_press), A["pos4"])
