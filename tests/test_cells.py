"""Neighbour search (cell lists, counting sort) against brute force, and forces against tests/naive.py."""
import numpy as np
import pytest

from sphgraph.backends.compute import cpu_kernels as K
from sphgraph.cells import axis_order, build_grid, counting_sort, grid_takes
from sphgraph.config import PhysicsConfig, derive
from sphgraph.particles import Particles
from sphgraph.state import RankState

import naive


def brute_counts(pos, support2):
    d = pos[:, None, :] - pos[None, :, :]
    r2 = (d * d).sum(-1)
    return ((r2 <= support2) & (r2 >= 1e-18)).sum(1)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("cell", ["2h", "h"])
@pytest.mark.parametrize("slow", [None, 0, 1])
def test_pairs_equal_brute_force(dim, cell, slow):
    rng = np.random.default_rng(dim * 10 + (slow or 0))
    pos = rng.uniform(-0.3, 0.7, (1500, dim)) * np.array([1.0, 0.6, 0.4][:dim])
    h = 0.05
    size = 2 * h if cell == "2h" else h
    reach = 1 if cell == "2h" else 2
    grid, perm = build_grid(pos, size, reach, axis_order(dim, slow))
    sp = np.ascontiguousarray(pos[perm])
    fluid = np.zeros(len(sp), np.int8)
    counts = np.zeros(len(sp), np.int64)
    K.count_pairs(sp, fluid, sp, fluid, *grid.kernel_args(), 4 * h * h, counts)
    np.testing.assert_array_equal(counts, brute_counts(sp, 4 * h * h))
    # a destination set that is not the source set (a halo as source)
    dst = rng.uniform(-0.3, 0.7, (300, dim)) * np.array([1.0, 0.6, 0.4][:dim])
    c2 = np.zeros(len(dst), np.int64)
    K.count_pairs(dst, np.zeros(len(dst), np.int8), sp, fluid, *grid.kernel_args(), 4 * h * h, c2)
    d = dst[:, None, :] - sp[None, :, :]
    near = ((d * d).sum(-1) <= 4 * h * h) & ((d * d).sum(-1) >= 1e-18)
    np.testing.assert_array_equal(c2, near.sum(1))
    # DualSPHysics' interaction count: boundary rows see fluid neighbours only
    kind = rng.integers(0, 2, len(sp)).astype(np.int8)
    c3 = np.zeros(len(sp), np.int64)
    K.count_pairs(sp, kind, sp, kind, *grid.kernel_args(), 4 * h * h, c3)
    d = sp[:, None, :] - sp[None, :, :]
    near = ((d * d).sum(-1) <= 4 * h * h) & ((d * d).sum(-1) >= 1e-18)
    near &= ~((kind[:, None] != 0) & (kind[None, :] != 0))
    np.testing.assert_array_equal(c3, near.sum(1))


def test_counting_sort_is_stable_and_complete():
    keys = np.random.default_rng(3).integers(0, 50, 1000)
    perm, start = counting_sort(keys, 50)
    assert sorted(perm) == list(range(1000))
    assert np.all(np.diff(keys[perm]) >= 0)
    for c in range(50):
        rows = perm[start[c]:start[c + 1]]
        assert np.all(keys[rows] == c) and np.all(np.diff(rows) > 0)


@pytest.mark.parametrize("seed", range(6))
def test_merge_equals_a_stable_sort_of_rows_and_arrivals(seed):
    """merge(stable_sort(rows), stable_sort(arrivals)), ties to the rows, is the stable sort
    of [rows, arrivals]: random keys with many ties, arrivals in any cell (empty ones, the
    first and the last included), no arrival, no row."""
    rng = np.random.default_rng(seed)
    ncells = int(rng.integers(1, 40))
    n, m = int(rng.integers(0, 300)), int(rng.integers(0, 30))
    if seed == 0:
        m = 0
    keys = rng.integers(0, ncells, n)
    akeys = rng.integers(0, ncells, m)
    if m > 1:
        akeys[:2] = (0, ncells - 1)
    perm, start = counting_sort(keys, ncells)
    mperm = np.empty(n + m, np.int64)
    mstart = np.empty(ncells + 1, np.int64)
    K.merge_sorted(start, akeys, mperm, mstart)
    # indices into [sorted rows, arrivals] -> indices into [rows, arrivals]
    merged = np.where(mperm < n, perm[np.minimum(mperm, max(n - 1, 0))], mperm)
    ref, ref_start = counting_sort(np.concatenate([keys, akeys]), ncells)
    np.testing.assert_array_equal(merged, ref)
    np.testing.assert_array_equal(mstart, ref_start)
    np.testing.assert_array_equal(merged, np.argsort(np.concatenate([keys, akeys]), kind="stable"))


def _state(pos, axes, cut_lo, cut_hi, axis, seed=0):
    rng = np.random.default_rng(seed)
    n, dim = pos.shape
    p = Particles.create(np.arange(n), rng.integers(0, 2, n), pos, rng.normal(0, 1, (n, dim)),
                         1000 + rng.normal(0, 2, n))
    p.rho_m1 = p.rho_m1 + rng.normal(0, 1, n)
    c = derive(PhysicsConfig(), dim, 0.02, 0.3)
    return RankState(particles=p, consts=c, dtype=np.float64, axes=axes, nranks=2, axis=axis,
                     cut_lo=cut_lo, cut_hi=cut_hi)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("where", ["inside", "below", "above", "none", "lattice"])
def test_build_then_merge_is_bit_identical_to_append_then_build(dim, where):
    """NumbaCPU: build_cells then merge_displaced (recv after build) leaves the rows, cells
    and pressures bit for bit as add_rows + prepare + build_cells (recv before build) --
    arrivals inside the grid (merged, ties with rows on a lattice), or outside it along a
    non-split axis (rows restored to their order before the sort, then rebuilt)."""
    from sphgraph.backends.compute.numba_cpu import NumbaCPU
    from sphgraph.domain import Slabs
    rng = np.random.default_rng(dim + len(where))
    axis = 0
    lo, hi = 0.3, 0.9
    n, m = 700, 25
    ext = np.array([1.0, 0.6, 0.4][:dim])
    pos = rng.uniform(0, 1, (n, dim)) * ext
    pos[:, axis] = rng.uniform(lo, hi, n)
    apos = rng.uniform(0.05, 0.95, (m, dim)) * ext
    apos[:, axis] = np.concatenate([rng.uniform(lo, lo + 0.02, m // 2), rng.uniform(hi - 0.02, hi, m - m // 2)])
    if where == "below":
        apos[3, 1] = -0.2
    elif where == "above":
        apos[4, 1] = ext[1] + 0.2
    elif where == "lattice":     # rows and arrivals on one lattice: many equal cells and positions
        pos = np.round(pos / 0.02) * 0.02
        apos = np.round(apos / 0.02) * 0.02
        pos[:, axis] = np.clip(pos[:, axis], lo, hi - 1e-9)
        apos[:, axis] = np.clip(apos[:, axis], lo, hi - 1e-9)
    axes = axis_order(dim, axis)
    be = NumbaCPU()
    dom = Slabs(0, axis, np.array([-np.inf, lo, hi, np.inf]), 0.05)
    dom.rank = 1
    arr = _state(apos, axes, lo, hi, axis, seed=5).particles
    rows = [] if where == "none" else [arr.take(np.arange(m // 2)), arr.take(np.arange(m // 2, m))]
    a = _state(pos, axes, lo, hi, axis)             # recv before build
    be.prepare(a)
    dom.add_rows(a, rows)
    be.prepare(a)
    be.build_cells(a)
    b = _state(pos, axes, lo, hi, axis)             # build before recv
    be.prepare(b)
    be.build_cells(b)
    took = grid_takes(b.cells, arr.pos)[0]
    assert took == (where in ("inside", "lattice", "none")), where
    be.merge_displaced(b, dom, rows)
    for k, v in a.particles.arrays().items():
        np.testing.assert_array_equal(getattr(b.particles, k), v, err_msg=k)
    np.testing.assert_array_equal(b.cells.start, a.cells.start)
    np.testing.assert_array_equal(b.cells.dims, a.cells.dims)
    np.testing.assert_array_equal(b.cells.origin, a.cells.origin)
    np.testing.assert_array_equal(b.press, a.press)
    assert b.press.shape == b.ace.shape[:1] == (a.particles.n,)


def test_owned_grid_spans_the_slab_along_the_split_axis():
    pos = np.array([[0.41, 0.1], [0.5, 0.25], [0.7, 0.2]])
    axes = axis_order(2, 0)
    grid, _ = build_grid(pos, 0.1, 1, axes, slow_span=(0.4, 0.8))
    assert grid.origin[2] == 0.4 and grid.hi[2] == 0.8 and grid.origin[0] == 0.1
    g2, _ = build_grid(pos, 0.1, 1, axes, slow_span=(-np.inf, 0.8))
    assert g2.origin[2] == 0.41 and g2.hi[2] == 0.8
    g3, _ = build_grid(pos, 0.1, 1, axes, slow_span=(0.45, 0.6))   # rows beyond the cuts stay in it
    assert g3.origin[2] == 0.41 and g3.hi[2] == 0.7
    # (x split, y): anywhere in the slab, and within the grid's cells across it
    assert grid_takes(grid, np.array([[0.79, 0.15], [0.4, 0.22]]))[0]
    assert grid_takes(grid, np.array([[0.5, 0.28]]))[0]             # beyond the rows, in the last cell
    assert not grid_takes(grid, np.array([[0.5, 0.05]]))[0]         # below the origin across the split axis
    assert not grid_takes(grid, np.array([[0.5, 0.45]]))[0]         # one more cell across it


def test_grid_spans_only_the_particles():
    pos = np.array([[10.0, 5.0], [10.3, 5.1], [10.1, 5.25]])
    grid, _ = build_grid(pos, 0.1, 1, axis_order(2))
    assert grid.origin[0] == 10.0 and grid.origin[1] == 5.0
    assert grid.ncells == 4 * 3


@pytest.mark.parametrize("dim", [2, 3])
def test_forces_equal_naive(dim):
    """The prange kernel (fluid + DBC boundary, Fourtakas) equals the O(N^2) reference."""
    rng = np.random.default_rng(7 + dim)
    dp = 0.02
    n_side = 12 if dim == 2 else 6
    grid_pts = np.stack(np.meshgrid(*[np.arange(n_side) * dp] * dim, indexing="ij"), -1).reshape(-1, dim)
    pos = grid_pts + rng.normal(0, 0.1 * dp, grid_pts.shape)
    kind = (grid_pts[:, -1] < dp / 2).astype(np.int8)        # bottom row: boundary
    vel = rng.normal(0, 0.3, pos.shape) * (kind == 0)[:, None]
    rho = 1000 + rng.normal(0, 2, len(pos))
    phys = PhysicsConfig(diffusion="fourtakas", visc_alpha=0.05)
    c = derive(phys, dim, dp, 0.3)
    p = Particles.create(np.arange(len(pos)), kind, pos, vel, rho)
    st = RankState(particles=p, consts=c, dtype=np.float64, axes=axis_order(dim))
    from sphgraph.backends.compute.numba_cpu import NumbaCPU
    be = NumbaCPU()
    be.prepare(st)
    be.build_cells(st)
    be.forces(st, "interior")
    be.reduce_forces(st, 1)
    p = st.particles
    ace, ar = naive.forces(p.pos, p.vel, p.rho, p.kind, c, phys)
    fl = p.kind == 0
    ace_k = st.ace - np.where(fl[:, None], c.gravity, 0)
    np.testing.assert_allclose(ace_k[fl], ace[fl], rtol=1e-9, atol=1e-9 * np.abs(ace).max())
    np.testing.assert_allclose(st.ar, ar, rtol=1e-9, atol=1e-9 * np.abs(ar).max())
