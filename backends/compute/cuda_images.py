"""Periodic images made on the device, for the numba.cuda backend.

The images of a rank's rows across the faces of one periodic axis (sphgraph.periodic) are
the halo of force part halo_3. Made on the host, each stage copies the rows near a face to
the host, images and bins them there and uploads the halo: two waits for the device and the
host's binning in every stage (BENCHMARKS.md §20 has what that cost). Here they never leave
the device:

    k_near_faces   the rows within reach of a face, counted; the device scan places them
    k_pack_images  each one's image (+period below lo + reach, else -period), as an edge
                   row is packed (cuda_edges.k_pack_edge's records), up to a bound on their
                   count kept from the stage before
    k_edge_bounds  the images' count and bounding box: 72 bytes to the host, the grid's
                   size, the stage's one wait for the device
    k_edge_keys, the scan, k_scatter, k_sort_cells, k_edge_gather
                   binned by cell in the host's order and gathered into the arrays the
                   staged halos' kernels read (relative positions, velocity, density,
                   pressure, kind, cell starts)

That is the grid (`sphgraph.cells.build_grid` over the images' bounding box) and the row
order (cell, then row) of the host path, whose images of the lo band and of the hi band
never share a cell: the image force sums are the host path's bits. With two or three image
axes (a row near an edge or corner has several images) the host path runs.
"""
from __future__ import annotations

import numpy as np

from sphgraph.cells import CellGrid, reach_cells

from . import cuda_kernels as CK
from .cuda_cells import device_grid
from .cuda_memory import COUNTERS, VEC, count_bytes, dev_array, host_wait, layout, split


class DeviceImages:
    """The periodic images as a halo whose rows live on the device only: `press` holds the
    device arrays and `cells` the grid, as `prepare_halo` leaves a staged halo; n and
    n_fluid are counted on the device. `pos` and `kind` read the rows back (host-side pair
    counts of benchmarks)."""

    order = None

    def __init__(self, n: int, n_fluid: int, press: dict, cells, ref, dim: int):
        self.n, self.n_fluid = int(n), int(n_fluid)
        self.press, self.cells = press, cells
        self._ref, self._dim = np.asarray(ref, np.float64), int(dim)

    def nbytes(self) -> int:
        """Bytes the images moved between ranks or across the bus: none."""
        return 0

    @property
    def pos(self) -> np.ndarray:
        d = self.press
        return np.stack([d["r" + ax].copy_to_host()[:self.n].astype(np.float64) + self._ref[i]
                         for i, ax in enumerate(VEC[:self._dim])], axis=1)

    @property
    def kind(self) -> np.ndarray:
        return self.press["kind"].copy_to_host()[:self.n]


def _bound(m: int) -> int:
    """Room for m images and a margin (rows come and go near a face from stage to stage)."""
    return int(m * 1.25) + 1024


def device_images(be, state, periodic):
    """The images of the device rows across `periodic`'s one image axis as a DeviceImages,
    or None where the host path must make them (not one image axis, or a period so short
    that a row lies within reach of both faces and has two images there)."""
    axes = list(periodic.image_axes)
    if len(axes) != 1:
        return None
    a = axes[0]
    lo, reach = float(periodic.lo[a]), float(periodic.reach)
    period = float(periodic.period[a])
    if not period > 2.0 * reach:
        return None
    dv = state.extra["dev"]
    k = be._k(state)
    s = be._s(state)
    n, dim, A = dv.n, dv.dim, dv.arrays
    c = state.consts
    # the rows near a face (cuda_rows._near_faces, the host path's too), placed by the scan
    keep, slot, cnt = be._near_faces(state, dv, k, periodic.lo, periodic.hi, reach, axes)
    tmp = dv.images_scan        # block sums of its own (the sort's may be live)
    be._scan(dv, k, keep, slot, n, tmp=tmp)
    # packed up to a bound on their count (the last stage's and a margin): the count comes to
    # the host with the images' bounding box, one wait a stage; a first stage, or more rows
    # than the bound, reads it first or packs again
    cap = dv.images_cap
    if cap is None:
        cap = _bound(be._read_count(state, dv, cnt, "images"))
    meta = A.get("images_meta")
    if meta is None:
        meta = A["images_meta"] = dev_array(9, np.float64)
    while True:
        lay, nb = layout([("pos", np.float64, cap * dim), ("v4", dv.dtype, 4 * cap), ("kind", np.int8, cap)])
        d = split(dv.dev_buf("images_rows", nb), lay)
        k.k_pack_images[CK.blocks(n), CK.BLOCK](keep, slot, n, cap, dim, A["px"], A["py"], A["pz"], A["vel4"],
                                               A["kind"], a, lo + reach, period, d["pos"], d["v4"], d["kind"])
        # count (meta[8]), packed rows' count and bounding box (each passes the cut: below a
        # threshold past them all)
        k.k_edge_init[1, 1](cnt, meta)
        k.k_edge_bounds[min(CK.blocks(cap, 256), CK.REDUCE_BLOCKS), 256](d["pos"], d["kind"], cap, cnt, dim, a,
                                                                        1e300, True, meta)
        hm = dv.pinned_meta
        meta.copy_to_host(hm, stream=s)
        host_wait(s)
        count_bytes(state, "d2h_bytes", "images", meta.nbytes)
        m = int(hm[8])
        if m <= cap:
            break
        COUNTERS["images_repacked"] += 1
        cap = _bound(m)
    dv.images_cap = _bound(m) if m > 0.8 * cap else cap
    if m == 0:
        return DeviceImages(0, 0, None, None, dv.ref, dim)
    n_fluid = int(hm[1])
    # the grid over the images' bounding box, as sphgraph.cells.build_grid
    g_axes = np.asarray(state.axes, np.int64)
    glo, ghi, dims, o_ax, n_ax, s_ax = device_grid(hm[2:5], hm[5:8], c.cell_size, g_axes)
    ncells = int(dims.prod())
    # the halo's arrays in a pooled buffer (prepare_halo's: it lives while tasks read it)
    out = DeviceImages(m, n_fluid, None, None, dv.ref, dim)
    names = ["r" + ax for ax in VEC[:dim]] + ["v" + ax for ax in VEC[:dim]] + ["rho", "press"]
    hl, hnb = layout([("start", np.int64, ncells + 1), ("kind", np.int8, m)] + [(x, dv.dtype, m) for x in names])
    dd = split(be._halo_buffer(state, dv, out, hnb), hl)
    for ax in VEC[dim:]:                    # 2D: one-element dummies (never read)
        dd["r" + ax] = dd["v" + ax] = A["az"]
    sl, snb = layout([("counts", np.int64, ncells + 1), ("keys", np.int32, m), ("perm", np.int32, m)])
    sc = split(dv.dev_buf("images_sort", snb), sl)
    counts, start = sc["counts"], dd["start"]
    k.k_fill[CK.blocks(ncells + 1), CK.BLOCK](counts, ncells + 1, 0)
    k.k_edge_keys[CK.blocks(m), CK.BLOCK](d["pos"], m, dim, a, 1e300, True, o_ax[0], o_ax[1], o_ax[2],
                                          1.0 / c.cell_size, n_ax[0], n_ax[1], n_ax[2], s_ax[0], s_ax[1],
                                          s_ax[2], ncells, sc["keys"], counts)
    be._scan(dv, k, counts, start, ncells + 1, tmp=tmp)     # start[ncells] = m
    k.k_copy[CK.blocks(ncells + 1), CK.BLOCK](start, ncells + 1, counts)   # fill pointers
    k.k_scatter[CK.blocks(m), CK.BLOCK](sc["keys"], m, counts, sc["perm"])
    k.k_sort_cells[CK.blocks(ncells), CK.BLOCK](start, ncells, sc["perm"])
    ref = np.zeros(3)
    ref[:dim] = dv.ref[:dim]
    k.k_edge_gather[CK.blocks(m), CK.BLOCK](d["pos"], d["v4"], d["kind"], sc["perm"], m, dim, float(ref[0]),
                                            float(ref[1]), float(ref[2]), dv.prm_d(state), dd["rx"], dd["ry"],
                                            dd["rz"], dd["vx"], dd["vy"], dd["vz"], dd["rho"], dd["press"], dd["kind"])
    out.press = dd
    out.cells = CellGrid(origin=glo, size=c.cell_size, dims=dims, axes=g_axes, start=None,
                         reach=reach_cells(c.h, c.cell_size), hi=ghi)
    return out
