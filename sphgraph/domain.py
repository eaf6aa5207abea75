"""Slab decomposition (seed paper §III-A): cuts along one axis, edges, halos, migration.

Rank r owns the fluid and boundary particles with cut[r] <= x_axis < cut[r+1]
(the end cuts are +-inf). Its *edge* towards a neighbour is its rows within
`reach` of that neighbour's slab; the neighbour keeps them as a *halo* holding
only position, velocity, density and kind. Cuts are coordinates (any position).
"""
from __future__ import annotations

import numpy as np

from .errors import InputError
from .particles import FLUID, Particles
from .state import Halo

AXES = {"x": 0, "y": 1, "z": 2}


# in units of the smoothing length h: edge rows are those within REACH_H of a cut (the 2h
# support and room for a step's motion), and no slab is narrower than MIN_SLAB_H, so that a
# halo comes from the next slab alone
REACH_H = 2.2
MIN_SLAB_H = 6.0

def choose_axis(axis: str, particles: Particles, gravity) -> int:
    """`auto`: the longest fluid extent perpendicular to gravity (DESIGN.md §5)."""
    if axis != "auto":
        return AXES[axis]
    fl = particles.pos[particles.kind == FLUID]
    ext = fl.max(axis=0) - fl.min(axis=0)
    g = np.abs(np.asarray(gravity, float))
    vertical = int(np.argmax(g)) if g.any() else -1
    cand = [a for a in range(particles.dim) if a != vertical] or list(range(particles.dim))
    return max(cand, key=lambda a: ext[a])


def equal_cuts(particles: Particles, axis: int, nranks: int, h: float, weights=None) -> np.ndarray:
    """Cuts giving each rank an equal share of fluid particles, each slab >= 6h wide."""
    x = np.sort(particles.pos[particles.kind == FLUID, axis])
    lo, hi = float(particles.pos[:, axis].min()), float(particles.pos[:, axis].max())
    min_width = MIN_SLAB_H * h
    if (hi - lo) < nranks * min_width:
        raise InputError(f"scene: decomposition: {nranks} ranks need a domain at least "
                         f"{nranks * min_width:.4g} m wide along axis {'xyz'[axis]} (6h = {min_width:.4g} m "
                         f"per subdomain), the particles span {hi - lo:.4g} m: use fewer ranks")
    w = np.ones(nranks) if weights is None else np.asarray(weights, float)
    frac = np.cumsum(w)[:-1] / w.sum()
    # each cut midway between the quantile's coordinate and the next lower one: a cut on a
    # lattice plane would have its rows cross back and forth with round-off every step
    cuts = [_between(x, x[min(len(x) - 1, int(round(f * len(x))))]) for f in frac]
    cuts = np.array([lo] + cuts + [hi + 1e-9])
    # enforce the 6h minimum width by sweeping forward, then backward
    for r in range(1, nranks):
        cuts[r] = max(cuts[r], cuts[r - 1] + min_width)
    for r in range(nranks - 1, 0, -1):
        cuts[r] = min(cuts[r], cuts[r + 1] - min_width)
    cuts[0], cuts[-1] = -np.inf, np.inf
    return cuts


def _between(x, c) -> float:
    """Midway between c and the largest coordinate of sorted x below it (c if none)."""
    j = int(np.searchsorted(x, c, side="left"))
    return 0.5 * (float(x[j - 1]) + float(c)) if j > 0 else float(c)


def split(particles: Particles, axis: int, cuts: np.ndarray) -> list[Particles]:
    x = particles.pos[:, axis]
    owner = np.searchsorted(cuts[1:-1], x, side="right")
    return [particles.take(np.nonzero(owner == r)[0]) for r in range(len(cuts) - 1)]


class Slabs:
    """One rank's view of the decomposition (used by the multi-rank tasks)."""

    def __init__(self, rank: int, axis: int, cuts: np.ndarray, reach: float):
        self.rank = rank
        self.axis = axis
        self.cuts = np.asarray(cuts, float)
        self.reach = reach  # how far from a cut edge rows are sent (>= 2h)

    @property
    def lo(self):
        return self.cuts[self.rank]

    @property
    def hi(self):
        return self.cuts[self.rank + 1]

    def take_displaced(self, state) -> dict:
        """Remove and return rows that left this slab: {-1: lower, +1: upper}."""
        p = state.particles
        x = p.pos[:, self.axis]
        down = x < self.lo
        up = x >= self.hi
        out = {-1: p.take(np.nonzero(down)[0]), 1: p.take(np.nonzero(up)[0])}
        if down.any() or up.any():
            state.particles = p.take(np.nonzero(~(down | up))[0])
        return out

    def add_rows(self, state, rows) -> None:
        rows = [r for r in rows if r is not None and r.n]
        if rows:
            state.particles = Particles.concat([state.particles] + rows)

    def edge_rows(self, state, direction: int) -> np.ndarray:
        """The owned rows within `reach` of the neighbour's slab in `direction` (-1 lower,
        +1 upper), in row order: the edge's rows, in the edge's order."""
        x = state.particles.pos[:, self.axis]
        return np.nonzero(x < self.lo + self.reach)[0] if direction < 0 else np.nonzero(x >= self.hi - self.reach)[0]

    def edge_sources(self, state, direction: int) -> np.ndarray:
        """The owned row each row of `edge(state, direction)` is (a copy of), in the edge's
        order: what the edge's rows' later values (mDBC's send_mdbc) are read from."""
        return self.edge_rows(state, direction)

    def edge(self, state, direction: int) -> Halo:
        """Rows within `reach` of the neighbour's slab in `direction` (-1 lower, +1 upper)."""
        p = state.particles
        sel = self.edge_rows(state, direction)
        h = Halo(pos=p.pos[sel], vel=p.vel[sel], rho=p.rho[sel], kind=p.kind[sel])
        state.bytes_sent += h.nbytes()
        return h
