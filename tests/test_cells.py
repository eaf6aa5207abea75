"""Neighbour search (cell lists, counting sort) against brute force, and forces against tests/naive.py."""
import numpy as np
import pytest

from sphgraph.backends.compute import cpu_kernels as K
from sphgraph.cells import axis_order, build_grid, counting_sort
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
