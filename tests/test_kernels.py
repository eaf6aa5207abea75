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
    """grad_a W_ab = F r_ab = -grad_b W_ab for random pairs in 3D: each side against central
    differences of W(|r_a - r_b|) moving a, then b, one coordinate at a time."""
    c = derive(PhysicsConfig(kernel=kernel), 3, 0.01, 1.0)
    h, k = c.h, c.opt[1]
    rng = np.random.default_rng(1)
    e = 1e-7 * h

    def w(d):
        return kernel_w(math.sqrt(float(d @ d)), c.prm, k)

    for _ in range(50):
        ra = rng.uniform(0, 1, 3)
        rb = ra + rng.normal(size=3) / math.sqrt(3) * rng.uniform(0.05, 1.95) * h / 1.2
        if not 0.05 * h < np.linalg.norm(ra - rb) < 1.95 * h:
            continue
        d = ra - rb
        ga = grad_factor(float(d @ d), c.prm, k) * d
        step = np.eye(3) * e
        fd_a = np.array([(w(ra + s - rb) - w(ra - s - rb)) / (2 * e) for s in step])
        fd_b = np.array([(w(ra - (rb + s)) - w(ra - (rb - s))) / (2 * e) for s in step])
        tol = dict(rel=1e-5, abs=1e-9 / h ** 4)
        assert ga == pytest.approx(fd_a, **tol)
        assert -ga == pytest.approx(fd_b, **tol)
        assert ga @ d < 0  # W falls with r: grad_a W points from a towards b
