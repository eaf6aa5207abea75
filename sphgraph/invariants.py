"""Invariants checked while running (issue 8 §5), and the memory guard of a scene.

Cheap, on by default, switched off with ``--no-invariants`` /
``run(..., invariants=False)``. `Simulation.check` already stops on NaN in
position or density, a particle leaving the domain and a density outside
``[rho_min, rho_max]`` (always on: that is the numerical failure check); this
module adds, per step:

* the global particle count and two checksums of the id set (sum and sum of
  squares of the ids, mod 2**64) against their values at start -- O(N) on the
  host, one small allreduce under MPI. On device backends (numba-cuda, whose
  rows live on the GPU) only the count is checked per step;
* NaN / inf in a velocity (host backends);

and, at every output frame (where the rows are gathered to the root anyway), the
full id set: strictly increasing after the id sort (no duplicate), the same
count, smallest, largest and sum as at start. A per-step checksum mismatch runs
the full check at once to name the particle.

A violation raises `NumericalError` (exit 1) naming the step and a particle id,
the same on every rank (the root's finding is broadcast).
"""
from __future__ import annotations

import os

import numpy as np

from .errors import InputError, NumericalError

_U = np.uint64


def _id_sums(ids: np.ndarray) -> tuple[int, int]:
    u = ids.astype(_U, copy=False)
    with np.errstate(over="ignore"):
        return int(np.sum(u, dtype=_U)), int(np.sum(u * u, dtype=_U))


class Invariants:
    """Conservation checks of one `Simulation` (created by it)."""

    def __init__(self, sim):
        self.n_excluded = 0
        self.host = not sim.compute.device_resident
        self.n0, self.s10, self.s20 = self._global(sim)
        self.min0 = self.max0 = None   # of the id set, known at the first full check (root)

    # -- global sums ------------------------------------------------------------------
    def _global(self, sim):
        """(count, id sum, id sum of squares) over every rank, counting particles that a
        scene's ``domain.exclude_outside`` removed (``state.extra["excluded_ids"]``) too."""
        n, s1, s2, nx = 0, 0, 0, 0
        for c in sim.contexts:
            p = c.state.particles
            ex = c.state.extra.get("excluded_ids")
            nx += 0 if ex is None else len(ex)
            n += p.n + (0 if ex is None else len(ex))
            if self.host:
                for ids in (p.id, ex):
                    if ids is not None and len(ids):
                        a, b = _id_sums(np.asarray(ids))
                        s1, s2 = (s1 + a) % 2 ** 64, (s2 + b) % 2 ** 64
        if len(sim.comm.local_ranks) < sim.nranks:     # MPI: one rank per process
            tot = sim.comm.allreduce(np.array([n, s1, s2, nx], dtype=_U), "sum")
            n, s1, s2, nx = (int(x) for x in np.asarray(tot, dtype=_U))
        self.n_excluded = nx
        return n, s1, s2

    # -- per step ---------------------------------------------------------------------
    def local_problem(self, state):
        """(row, cause) of a non-finite velocity on this rank (cause 4), or None."""
        if not self.host:
            return None
        v = state.particles.vel
        if v.size and not np.isfinite(v).all():
            row = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0])
            return row, 4
        return None

    def check_step(self, sim) -> None:
        n, s1, s2 = self._global(sim)
        if n == self.n0 and (not self.host or (s1 == self.s10 and s2 == self.s20)):
            return
        # something changed: the full id set names the particle (collective on every rank)
        arrays = sim.frame_arrays()
        self.check_frame(sim, arrays)
        what = f"particle count {n}, expected {self.n0}" if n != self.n0 else "the id checksum changed"
        raise NumericalError(f"step {sim.step_count} (t = {sim.time:.6g} s): invariant violated: {what}",
                             step=sim.step_count, cause="invariant")

    # -- at frames --------------------------------------------------------------------
    def check_frame(self, sim, arrays) -> None:
        """Full id-set check on the gathered rows (root), agreed on every rank."""
        msg = None
        if arrays is not None:
            msg = self._frame_problem(arrays["id"])
        if len(sim.comm.local_ranks) < sim.nranks:
            msg = sim.comm.bcast(msg)
        if msg is not None:
            text, pid = msg
            raise NumericalError(f"step {sim.step_count} (t = {sim.time:.6g} s): invariant violated: {text}",
                                 step=sim.step_count, particle_id=pid, cause="invariant")

    def _frame_problem(self, ids: np.ndarray):
        ids = np.asarray(ids)
        if len(ids) > 1:
            d = np.diff(ids)
            if np.any(d <= 0):
                if np.any(d < 0):
                    ids = np.sort(ids, kind="stable")
                    d = np.diff(ids)
                dup = np.flatnonzero(d == 0)
                if len(dup):
                    return f"particle id {int(ids[dup[0]])} appears twice", int(ids[dup[0]])
        if self.n_excluded:     # some rows were removed on purpose: count them, no id sums
            if len(ids) + self.n_excluded != self.n0:
                return f"{len(ids)} particles and {self.n_excluded} excluded, expected {self.n0}", None
            return None
        if self.min0 is None and len(ids) == self.n0:
            self.min0, self.max0 = int(ids[0]), int(ids[-1])
        s1, s2 = _id_sums(ids)
        if len(ids) != self.n0 or (self.host and (s1, s2) != (self.s10, self.s20)) or \
                (self.min0 is not None and (int(ids[0]), int(ids[-1])) != (self.min0, self.max0)):
            pid = _missing_id(ids, self.n0, self.s10, self.min0, self.max0)
            text = f"{len(ids)} particles, expected {self.n0}"
            if pid is not None:
                text += f": particle id {pid} is missing" if len(ids) < self.n0 else \
                    f": particle id {pid} is unexpected"
            return text, pid
        return None


def _missing_id(ids, n0, s10, lo, hi):
    """The id that explains the difference, where one does (one id lost, or one foreign id)."""
    if len(ids) == n0 - 1:
        return int((s10 - int(np.sum(ids.astype(_U), dtype=_U))) % 2 ** 64)
    if lo is not None and len(ids) and hi - lo + 1 == n0:    # contiguous ids at start
        out = ids[(ids < lo) | (ids > hi)]
        if len(out):
            return int(out[0])
        full = np.arange(lo, hi + 1)
        miss = np.setdiff1d(full, ids, assume_unique=True)
        if len(miss):
            return int(miss[0])
    return None


# --------------------------------------------------------------------------- memory guard
def bytes_per_particle(dim: int, itemsize: int, device_rows: bool = False, row_fill: bool = False) -> int:
    """Host bytes one particle needs while running (generous): the `Particles` rows
    (positions float64) and the lattice indices and positions while the scene is built
    (none with the row fill of a box-only scene, `Scene.uses_row_fill`); on a host backend
    also pressure, reduced forces, three partial force buffers and the cell sort's copies;
    with the rows on a device (`device_rows`: numba-cuda) instead what the upload stages
    (velocity-density records, one float64 column, 32-bit ids)."""
    s = itemsize
    particles = 8 + 1 + 8 * dim + s * (2 * dim + 2)
    build = 0 if row_fill else 2 * 8 * dim + 8 * dim
    if device_rows:
        return particles + build + 4 * s + 8 + 4
    state = s * (1 + dim + 2) + 3 * (s * (dim + 3) + 1)
    sort_copy = 8 + 1 + 8 * dim + s * (2 * dim + 2)
    return particles + state + sort_copy + build


def available_memory() -> int | None:
    """Bytes the OS reports as available (Linux MemAvailable; sysconf elsewhere); None when unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(scene, dtype, available: int | None = None, device_rows: bool = False) -> None:
    """Refuse a scene whose particles would not fit in memory, before allocating them.

    Uses the scene's cheap count estimate (index boxes, no allocation) and
    `bytes_per_particle` (`device_rows`: the compute backend keeps the rows on a device);
    raises `InputError` (exit 2) naming dp and the limit.
    """
    n = scene.estimated_particles()
    need = n * bytes_per_particle(scene.dim, np.dtype(dtype).itemsize, device_rows, scene.uses_row_fill())
    avail = available_memory() if available is None else available
    if avail is not None and need > avail:
        raise InputError(f"{scene.source}: dp: expected a spacing whose particles fit in memory "
                         f"(about {n} particles need {need / 2**30:.3g} GiB, {avail / 2**30:.3g} GiB "
                         f"available): increase dp, got {scene.dp!r}")
