"""Smoothing kernels: normalisation in 2D and 3D, gradient consistency and antisymmetry."""
import math

import numpy as np
import pytest

from sphgraph.config import PhysicsConfig, derive, KERNELS
from sphgraph.physics.kernels import grad_factor, kernel_w


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", KERNELS)
def test_normalisation(dim, kernel):
    """sum_j W(r_j) dx^dim over a fine lattice = 1 (the integral of W over its support)."""
    dp = 0.1
    c = derive(PhysicsConfig(kernel=kernel), dim, dp, 1.0)
    h = c.h
    dx = h / 12
    k = np.arange(-int(2 * h / dx) - 1, int(2 * h / dx) + 2) * dx
    grids = np.meshgrid(*([k] * dim), indexing="ij")
    r = np.sqrt(sum(g * g for g in grids)).ravel()
    w = np.array([kernel_w(x, c.prm, c.opt[1]) for x in r])
    assert abs(w.sum() * dx ** dim - 1.0) < 2e-3


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", KERNELS)
def test_gradient_matches_derivative(dim, kernel):
    """F r = dW/dr (central differences) over the support."""
    c = derive(PhysicsConfig(kernel=kernel), dim, 0.01, 1.0)
    h = c.h
    for r in np.linspace(0.05 * h, 1.95 * h, 40):
        e = 1e-7 * h
        dwdr = (kernel_w(r + e, c.prm, c.opt[1]) - kernel_w(r - e, c.prm, c.opt[1])) / (2 * e)
        assert grad_factor(r * r, c.prm, c.opt[1]) * r == pytest.approx(dwdr, rel=1e-5, abs=1e-9 / h ** (dim + 1))


@pytest.mark.parametrize("kernel", KERNELS)
def test_gradient_antisymmetry(kernel):
    """grad_a W_ab = -grad_b W_ba for random pairs (F depends on r only)."""
    c = derive(PhysicsConfig(kernel=kernel), 3, 0.01, 1.0)
    rng = np.random.default_rng(1)
    for _ in range(50):
        ra, rb = rng.uniform(0, 2 * c.h / math.sqrt(3), (2, 3))
        d = ra - rb
        r2 = float(d @ d)
        ga = grad_factor(r2, c.prm, c.opt[1]) * d
        gb = grad_factor(r2, c.prm, c.opt[1]) * (-d)
        np.testing.assert_array_equal(ga, -gb)
        assert np.all(ga * d <= 0)  # points from b towards a, with a negative factor: attraction-free kernel
