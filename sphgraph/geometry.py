"""Lattice fills for scene geometry: fluid boxes, tanks, obstacles, walls.

Every particle of a scene sits on one cubic lattice of spacing ``dp``: the
points ``origin + k*dp`` for integer index vectors ``k``. Shapes are therefore
computed on integer indices, never on floats, which makes the rules exact:

* two particles coincide only when their indices are equal (distinct lattice
  points are >= dp apart, so "within 0.5*dp" also means "equal");
* overlapping boundary shapes are merged by taking the union of indices;
* points are handled as int64 *keys* (row-major linear index inside a
  :class:`Grid` window), so a union is ``np.unique`` and membership is a
  ``searchsorted`` -- both vectorised, no Python loop over points;
* a scene of boxes only skips the keys: :class:`RowFill` cuts each lattice row
  (all indices but the last) into intervals and writes the same points in the
  same order, in parallel, with memory per row instead of per point (SPHERIC 2
  at hundreds of millions of particles).

Shapes are described as lists of inclusive index boxes ``(lo, hi)`` (int64
arrays of length dim). A box's point count is known without generating it,
which is what the scene's particle-count guard uses before allocating.

Snapping rules (how a face given in metres becomes a lattice plane):

* fluid boxes are *inclusive*: every lattice point p with
  ``min - 1e-9*dp <= p <= max + 1e-9*dp`` (:meth:`Lattice.inner_range`);
* boundary faces (tank walls, obstacle faces, walls) snap to the *nearest*
  lattice plane (:meth:`Lattice.nearest`), so the first wall layer lies exactly
  on the face whenever the face is on the lattice -- as in DualSPHysics'
  GenCase, whose CaseDambreak obstacle faces (x = 0.9 m with dp = 0.0085 m)
  are not on the lattice either.
"""
from __future__ import annotations

import numpy as np

TOL = 1e-9  # in units of dp: absorbs rounding in (x - origin)/dp

Box = tuple  # (lo, hi): inclusive int64 index bounds, each shape [dim]


class Lattice:
    """The lattice ``origin + k*dp`` and the snapping of metres to indices.

    Parameters
    ----------
    origin : array_like, shape (dim,)
        Lattice anchor (a lattice point), metres.
    dp : float
        Particle spacing, metres.
    """

    def __init__(self, origin, dp: float):
        self.origin = np.asarray(origin, dtype=np.float64)
        self.dp = float(dp)

    def _scaled(self, x):
        return (np.asarray(x, dtype=np.float64) - self.origin) / self.dp

    def inner_range(self, lo, hi) -> Box:
        """Index box of the lattice points inside ``[lo, hi]`` (inclusive)."""
        return (np.ceil(self._scaled(lo) - TOL).astype(np.int64),
                np.floor(self._scaled(hi) + TOL).astype(np.int64))

    def nearest(self, x) -> np.ndarray:
        """Index of the lattice plane nearest to each coordinate of ``x``."""
        return np.floor(self._scaled(x) + 0.5).astype(np.int64)

    def positions(self, idx: np.ndarray) -> np.ndarray:
        """Coordinates (float64, [n, dim]) of index vectors ``idx`` ([n, dim])."""
        return self.origin + idx.astype(np.float64) * self.dp


def box_count(box: Box) -> int:
    """Number of lattice points in an inclusive index box (0 if empty)."""
    lo, hi = box
    n = 1   # Python ints: a huge box must not wrap around int64 (and pass a particle limit)
    for a, b in zip(np.asarray(lo).tolist(), np.asarray(hi).tolist()):
        n *= max(int(b) - int(a) + 1, 0)
    return n


def boxes_count(boxes) -> int:
    """Sum of :func:`box_count` (an upper bound of the union's size)."""
    return sum(box_count(b) for b in boxes)


def bounding_box(boxes) -> Box | None:
    """Smallest index box holding every non-empty box of ``boxes`` (None if all empty)."""
    boxes = [b for b in boxes if box_count(b) > 0]
    if not boxes:
        return None
    return (np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0))


# --- shapes as lists of index boxes ---------------------------------------------

def tank_boxes(lo, hi, layers: int = 1, open_top: bool = True) -> list:
    """Walls of a tank whose *inner* faces are the index planes ``lo`` and ``hi``.

    The bottom (lowest index on the last, vertical axis) and the side walls are
    always present, the top only when ``open_top`` is false. Each wall is
    ``layers`` thick and grows outward: layer 1 lies on the face, layer j at
    ``j-1`` spacings outside it. Side walls of an open tank stop at the top
    face's plane; their corners overlap the bottom slab (removed by the union).

    Parameters
    ----------
    lo, hi : array_like of int
        Inner face planes (indices), ``lo < hi`` on every axis.
    layers : int
        Wall thickness in particle layers (>= 1).
    open_top : bool
        Leave the top face open (default) or close it.

    Returns
    -------
    list of (lo, hi) index boxes, one slab per wall.
    """
    lo = np.asarray(lo, np.int64)
    hi = np.asarray(hi, np.int64)
    dim = lo.size
    v = dim - 1  # vertical axis
    t = layers - 1
    olo = lo - t
    ohi = hi + t
    if open_top:
        ohi[v] = hi[v]
    slabs = []
    for a in range(dim):
        if a == v and open_top:
            faces = ((olo[a], lo[a]),)
        else:
            faces = ((olo[a], lo[a]), (hi[a], ohi[a]))
        for f_lo, f_hi in faces:
            b_lo, b_hi = olo.copy(), ohi.copy()
            b_lo[a], b_hi[a] = f_lo, f_hi
            slabs.append((b_lo, b_hi))
    return slabs


def shell_boxes(lo, hi, layers: int = 1, open_bottom: bool = False) -> list:
    """Outer shell, ``layers`` thick and growing inward, of the index box ``[lo, hi]``.

    Used for obstacles drawn as a surface (DualSPHysics ``boxfill`` of faces);
    a shell as thick as the box is the solid box. ``open_bottom`` leaves out
    the bottom face (an obstacle standing on a floor, as CaseDambreak's
    ``top | left | right | front | back``).
    """
    lo = np.asarray(lo, np.int64)
    hi = np.asarray(hi, np.int64)
    t = layers - 1
    v = lo.size - 1
    slabs = []
    for a in range(lo.size):
        faces = [(lo[a], min(lo[a] + t, hi[a])), (max(hi[a] - t, lo[a]), hi[a])]
        if a == v and open_bottom:
            faces = faces[1:]
        for f_lo, f_hi in faces:
            b_lo, b_hi = lo.copy(), hi.copy()
            b_lo[a], b_hi[a] = f_lo, f_hi
            slabs.append((b_lo, b_hi))
    return slabs


def hollow_box(lo, hi, layers: int = 1, open_bottom: bool = False) -> Box:
    """The inside of :func:`shell_boxes` (may be empty); with ``open_bottom``
    it reaches down to the bottom face's plane."""
    lo = np.asarray(lo, np.int64) + layers
    hi = np.asarray(hi, np.int64) - layers
    if open_bottom:
        lo[-1] -= layers
    return (lo, hi)


def wall_boxes(lo, hi, axis: int, direction: int, layers: int = 1) -> list:
    """A flat wall (``lo[axis] == hi[axis]``) thickened to ``layers`` along ``direction`` (+1/-1)."""
    lo = np.asarray(lo, np.int64).copy()
    hi = np.asarray(hi, np.int64).copy()
    if direction > 0:
        hi[axis] = hi[axis] + layers - 1
    else:
        lo[axis] = lo[axis] - (layers - 1)
    return [(lo, hi)]


# --- keys -------------------------------------------------------------------------

class Grid:
    """A window of the lattice in which index vectors map to int64 keys.

    Keys are row-major (C order) linear indices over the window
    ``[lo, hi]``, so the keys of a box come out sorted and ``np.unique`` of
    concatenated keys sorts points by (x, y[, z]) index.
    """

    def __init__(self, lo, hi):
        self.lo = np.asarray(lo, np.int64)
        self.shape = tuple(int(s) for s in (np.asarray(hi, np.int64) - self.lo + 1))
        if float(np.prod([float(s) for s in self.shape])) >= 2.0 ** 62:
            raise OverflowError("lattice window too large for int64 keys")
        strides = np.ones(len(self.shape), np.int64)
        for a in range(len(self.shape) - 2, -1, -1):
            strides[a] = strides[a + 1] * self.shape[a + 1]
        self.strides = strides

    def box_keys(self, box: Box) -> np.ndarray:
        """Sorted keys of every lattice point of ``box`` (which must lie in the window)."""
        lo, hi = box
        if box_count(box) == 0:
            return np.empty(0, np.int64)
        keys = np.zeros((), np.int64)
        # broadcast sum of per-axis offsets: memory is one int64 per point
        for a in range(len(self.shape)):
            ar = (np.arange(lo[a], hi[a] + 1, dtype=np.int64) - self.lo[a]) * self.strides[a]
            keys = np.add.outer(keys, ar)
        return keys.ravel()

    def union_keys(self, boxes) -> np.ndarray:
        """Sorted unique keys of the union of ``boxes``."""
        parts = [self.box_keys(b) for b in boxes]
        if not parts:
            return np.empty(0, np.int64)
        return np.unique(np.concatenate(parts))

    def point_keys(self, idx: np.ndarray) -> np.ndarray:
        """Keys of index vectors ``idx`` ([n, dim], inside the window)."""
        return ((np.asarray(idx, np.int64) - self.lo) * self.strides).sum(axis=1)

    def indices(self, keys: np.ndarray) -> np.ndarray:
        """Index vectors ([n, dim] int64) of ``keys``."""
        return np.stack(np.unravel_index(keys, self.shape), axis=1).astype(np.int64) + self.lo


def contains(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Boolean mask: which of ``keys`` occur in ``sorted_keys`` (sorted, unique)."""
    if sorted_keys.size == 0:
        return np.zeros(keys.shape, bool)
    pos = np.searchsorted(sorted_keys, keys)
    pos = np.minimum(pos, sorted_keys.size - 1)
    return sorted_keys[pos] == keys


def in_box(idx: np.ndarray, box: Box) -> np.ndarray:
    """Boolean mask: which index vectors ``idx`` ([n, dim]) lie in ``box`` (inclusive)."""
    lo, hi = box
    return np.all((idx >= lo) & (idx <= hi), axis=1)


# --- the row fill: box-only scenes without keys ---------------------------------------

BOUNDARY, HOLLOW, FLUID, SOLID = 0, 1, 2, 3   # roles of a RowFill's boxes (lattice_kernels)


class RowFill:
    """The particles of a scene drawn with index boxes only, made row by row in parallel
    (numba kernels in :mod:`sphgraph.lattice_kernels`) instead of through keys.

    Boundary points are the union of the BOUNDARY boxes less the HOLLOW boxes; fluid
    points the union of the FLUID boxes less the boundary points and the SOLID boxes. The
    points and their order are those of the key path (``union_keys``, ``contains``,
    ``in_box``): boundary first, then fluid, each in key (row-major) order over the window
    of the BOUNDARY and FLUID boxes. Memory is a few int64 per row of that window, not per
    point; :meth:`fill` writes the particle arrays and nothing else of their size.

    Parameters
    ----------
    boxes : list of (role, Box)
        role one of BOUNDARY, HOLLOW, FLUID, SOLID.

    Raises
    ------
    OverflowError
        The window's keys would not fit int64 (as :class:`Grid`).
    """

    def __init__(self, boxes):
        boxes = [(int(r), (np.asarray(b[0], np.int64), np.asarray(b[1], np.int64))) for r, b in boxes]
        self.dim = len(boxes[0][1][0])
        self.lo = np.array([b[0] for _, b in boxes], np.int64).reshape(-1, self.dim)
        self.hi = np.array([b[1] for _, b in boxes], np.int64).reshape(-1, self.dim)
        self.role = np.array([r for r, _ in boxes], np.int8)
        win = bounding_box([b for r, b in boxes if r in (BOUNDARY, FLUID)])
        if win is None:
            win = (np.zeros(self.dim, np.int64), np.full(self.dim, -1, np.int64))
            self.wlo, self.rshape = win[0], np.zeros(self.dim - 1, np.int64)
        else:
            grid = Grid(*win)
            self.wlo, self.rshape = grid.lo, np.array(grid.shape[:-1], np.int64)
        self.window = win     # inclusive index box: every point lies in it
        self.nrows = 1
        for s in self.rshape.tolist():
            self.nrows *= int(s)
        self.counted = False

    def count(self) -> None:
        """Points per row (both kinds) and the fluid's lowest / highest last index."""
        if self.counted:
            return
        from . import lattice_kernels as LK
        n = self.nrows
        self.nb_row = np.zeros(n, np.int64)
        self.nf_row = np.zeros(n, np.int64)
        fmin = np.empty(n, np.int64)
        fmax = np.empty(n, np.int64)
        with _all_threads() as threads:
            if n:
                LK.row_counts(self.lo, self.hi, self.role, self.wlo, self.rshape, self.nb_row,
                              self.nf_row, fmin, fmax, max(min(n, 64 * threads), 1))
        self.n_boundary = int(self.nb_row.sum())
        self.n_fluid = int(self.nf_row.sum())
        has = self.nf_row > 0
        self.fluid_last = (int(fmin[has].min()), int(fmax[has].max())) if self.n_fluid else None
        self.counted = True

    def fill(self, origin, dp: float, dtype, rho0: float, kinds):
        """(pos float64 [n, dim], ids int64, kind int8, rho, rho_m1 in `dtype`) of every
        point: boundary rows first (kind kinds[0]), then fluid (kinds[1]), density rho0."""
        from . import lattice_kernels as LK
        self.count()
        nb, n = self.n_boundary, self.n_boundary + self.n_fluid
        first = np.empty((2, self.nrows), np.int64)
        if self.nrows:
            first[0, 0] = 0
            np.cumsum(self.nb_row[:-1], out=first[0, 1:])
            first[1, 0] = nb
            np.cumsum(self.nf_row[:-1], out=first[1, 1:])
            first[1, 1:] += nb
        pos = np.empty((n, self.dim), np.float64)
        ids = np.empty(n, np.int64)
        kind = np.empty(n, np.int8)
        rho = np.empty(n, dtype)
        rho_m1 = np.empty(n, dtype)
        with _all_threads() as threads:
            if self.nrows:
                # chunks of about equal point counts: fluid fills only part of the window's rows
                work = np.cumsum(self.nb_row + self.nf_row + 1)
                nch = max(min(self.nrows, 16 * threads), 1)
                bounds = np.searchsorted(work, np.linspace(0, work[-1], nch + 1)[1:-1], side="right")
                bounds = np.concatenate([[0], bounds, [self.nrows]]).astype(np.int64)
                LK.fill_rows(self.lo, self.hi, self.role, self.wlo, self.rshape, first, bounds,
                             np.asarray(origin, np.float64), float(dp), np.asarray(kinds, np.int8),
                             float(rho0), pos, ids, kind, rho, rho_m1)
        return pos, ids, kind, rho, rho_m1


class _all_threads:
    """Every numba thread for the block (the CPU backend lowers the count for small
    ranks); the previous count after it. Yields the count."""

    def __enter__(self):
        import numba
        self.keep = numba.get_num_threads()
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        return numba.config.NUMBA_NUM_THREADS

    def __exit__(self, *exc):
        import numba
        numba.set_num_threads(self.keep)
        return False
