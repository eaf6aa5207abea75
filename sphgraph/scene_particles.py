"""Particle generation of a scene: the lattice, its boxes and shapes -> `Particles`.

:class:`SceneParticles` is the half of :class:`sphgraph.scene.Scene` that turns the
validated geometry into particles: cheap extent checks on index boxes before anything
is allocated (:meth:`SceneParticles._check_extent`), the row-by-row fill of scenes
drawn with boxes only (:class:`sphgraph.geometry.RowFill`), the key path for scenes
with shapes, and :meth:`SceneParticles.build_particles`. Every result is cached on
the scene (``_cache``); a scene is immutable once validated.
"""
from __future__ import annotations

import numpy as np

from . import geometry as geo
from . import shapes, stl
from .lattice_kernels import hydrostatic_density
from .particles import FIXED, FLUID, MOVING, Particles
from .scene_schema import _Checker, _vlist


class SceneParticles:
    """The particles of a scene (a mixin of :class:`sphgraph.scene.Scene`, which holds the fields)."""

    def _check_extent(self, c: _Checker) -> None:
        """Cheap checks on index boxes (no allocation): boundary inside the
        domain, some fluid points, and the estimated count within the limit."""
        lat = self._lattice_def()
        tol = geo.TOL * self.dp
        entries = [("boundary", i, e) for i, e in enumerate(self.boundary)]
        entries += [("fluid", i, e) for i, e in enumerate(self.fluid) if e["type"] in shapes.SHAPE_TYPES]
        for group, i, e in entries:
            self._check_window(c, group, i, e)
            if e["type"] in shapes.SHAPE_TYPES:
                bb = self._shape(group, i).bounds(lat)
                if geo.box_count(bb) == 0:
                    continue
            else:
                bb = geo.bounding_box(_boundary_boxes(e, lat, self.dim))
            lo, hi = lat.positions(bb[0][None])[0], lat.positions(bb[1][None])[0]
            if np.any(lo < self.domain_min - tol) or np.any(hi > self.domain_max + tol):
                raise c.error(f"{group}[{i}]", f"particles inside the domain {_vlist(self.domain_min)}"
                              f" - {_vlist(self.domain_max)} (extend [domain])",
                              f"particles spanning {_vlist(np.round(lo, 12))} - {_vlist(np.round(hi, 12))}",
                              literal=True)
        fboxes = [lat.inner_range(e["min"], e["max"]) for e in self.fluid if e["type"] == "box"]
        fshape = sum(self._shape("fluid", i).estimate(self.dp) for i, e in enumerate(self.fluid)
                     if e["type"] in shapes.SHAPE_TYPES)
        if geo.boxes_count(fboxes) + fshape == 0:
            raise c.error("fluid", f"boxes holding lattice points (spacing dp = {self.dp})", 0)
        bslabs = [b for e in self.boundary if e["type"] not in shapes.SHAPE_TYPES
                  for b in _boundary_boxes(e, lat, self.dim)]
        bshape = sum(self._shape("boundary", i).estimate(self.dp) for i, e in enumerate(self.boundary)
                     if e["type"] in shapes.SHAPE_TYPES)
        estimate = geo.boxes_count(fboxes) + geo.boxes_count(bslabs) + fshape + bshape
        self._cache["estimate"] = estimate
        if estimate > self.max_particles:
            raise c.error("limits.max_particles",
                          f"an estimated particle count <= {self.max_particles} "
                          "(increase dp or raise limits.max_particles)", estimate)

    def _check_window(self, c: _Checker, group: str, i: int, e: dict) -> None:
        """An entry reaching beyond 2**50 spacings from the origin (where the domain ends,
        see the dp check) is outside the domain: say so before int64 lattice indices wrap."""
        if e["type"] in shapes.SHAPE_TYPES:
            with np.errstate(all="ignore"):
                lo, hi = self._shape(group, i).extent(self.dp)
        else:   # walls and tank layers reach at most `layers` spacings beyond min/max
            pad = min(int(e.get("layers", 1)), 2 ** 60) * self.dp
            lo = np.minimum(e["min"], e["max"]) - pad
            hi = np.maximum(e["min"], e["max"]) + pad
        with np.errstate(all="ignore"):
            off = np.abs(np.concatenate([lo, hi]) - np.concatenate([self.lattice_origin] * 2))
        if not np.all(off <= 2.0 ** 50 * self.dp):      # nan too
            raise c.error(f"{group}[{i}]", f"particles inside the domain {_vlist(self.domain_min)}"
                          f" - {_vlist(self.domain_max)} (extend [domain])",
                          f"an entry spanning {_vlist(lo)} - {_vlist(hi)}", literal=True)

    def estimated_particles(self) -> int:
        """Upper estimate of the particle count from index boxes (no allocation)."""
        if "estimate" not in self._cache:
            self._check_extent(_Checker(self.source))
        return int(self._cache["estimate"])

    # --- particles -------------------------------------------------------------------

    def _lattice_def(self) -> geo.Lattice:
        return geo.Lattice(self.lattice_origin, self.dp)

    def _shape(self, group: str, i: int):
        """The :mod:`sphgraph.shapes` object of entry ``group[i]`` (cylinder, slope, stl), cached."""
        k = ("shape", group, i)
        if k not in self._cache:
            self._cache[k] = shapes.make(getattr(self, group)[i], self.dim)
        return self._cache[k]

    def _shape_points(self, group: str, i: int) -> np.ndarray:
        """Index vectors of a shape entry's particles, cached."""
        k = ("points", group, i)
        if k not in self._cache:
            try:
                self._cache[k] = self._shape(group, i).points(self._lattice_def())
            except stl.MeshError as err:
                raise _Checker(self.source).error(f"{group}[{i}].path", "a closed triangle mesh",
                                                  str(err), literal=True) from None
        return self._cache[k]

    def _solids(self, lat) -> list:
        """Index boxes of the box obstacles: solid bodies, no fluid inside them even when
        drawn as a surface."""
        return [(lat.nearest(e["min"]), lat.nearest(e["max"])) for e in self.boundary if e["type"] == "box"]

    def _hollows(self, lat) -> list:
        """Index boxes emptied of boundary points: the hollow of a surface obstacle
        (DualSPHysics voids the box before drawing its faces); with open_bottom this also
        clears the floor under it."""
        return [geo.hollow_box(lat.nearest(e["min"]), lat.nearest(e["max"]), e["layers"], e["open_bottom"])
                for e in self.boundary if e["type"] == "box" and e["fill"] == "surface"]

    def _row_fill(self):
        """The :class:`~sphgraph.geometry.RowFill` of a scene drawn with boxes only (fluid
        boxes, tanks, box obstacles, walls), not yet counted, cached: the same particle set
        as :meth:`_lattice` without a key or an index vector per point. None for a scene
        with shapes (cylinder, slope, stl), or whose window has far more rows than points
        (those take the key path)."""
        if "rows" in self._cache:
            return self._cache["rows"]
        rows = None
        if not any(e["type"] in shapes.SHAPE_TYPES for e in self.fluid + self.boundary):
            lat = self._lattice_def()
            boxes = [(geo.BOUNDARY, b) for e in self.boundary for b in _boundary_boxes(e, lat, self.dim)]
            boxes += [(geo.HOLLOW, b) for b in self._hollows(lat)]
            boxes += [(geo.FLUID, lat.inner_range(e["min"], e["max"])) for e in self.fluid]
            boxes += [(geo.SOLID, b) for b in self._solids(lat)]
            try:
                rf = geo.RowFill(boxes)
            except OverflowError:
                raise _Checker(self.source).error(
                    "dp", "a spacing whose lattice over the geometry fits int64 keys", self.dp) from None
            if rf.nrows <= 4 * self.estimated_particles() + 2 ** 20:
                rows = rf
        self._cache["rows"] = rows
        return rows

    def uses_row_fill(self) -> bool:
        """Whether :meth:`build_particles` writes the rows without keys (boxes only); cheap."""
        return self._row_fill() is not None

    def _rows(self):
        """The counted row fill (None: the key path)."""
        rows = self._row_fill()
        if rows is not None:
            rows.count()
            if rows.n_fluid == 0:
                raise _Checker(self.source).error(
                    "fluid", "at least one fluid particle outside the boundaries", 0)
        return rows

    def _fluid_last(self) -> tuple:
        """Lowest and highest lattice index of the fluid along the vertical (last) axis."""
        rows = self._rows()
        if rows is not None:
            return rows.fluid_last
        kz = self._lattice()[1][:, self.vertical]
        return int(kz.min()), int(kz.max())

    def _lattice(self):
        """(boundary index vectors, fluid index vectors), cached: the particle set."""
        if "lattice" in self._cache:
            return self._cache["lattice"]
        lat = self._lattice_def()
        is_shape = [e["type"] in shapes.SHAPE_TYPES for e in self.fluid + self.boundary]
        fshapes = [i for i, e in enumerate(self.fluid) if is_shape[i]]
        bshapes = [i for i, e in enumerate(self.boundary) if is_shape[len(self.fluid) + i]]
        fboxes = [lat.inner_range(e["min"], e["max"]) for e in self.fluid if e["type"] == "box"]
        bslabs = [b for e in self.boundary if e["type"] not in shapes.SHAPE_TYPES
                  for b in _boundary_boxes(e, lat, self.dim)]
        solids = self._solids(lat)
        sbounds = [self._shape("fluid", i).bounds(lat) for i in fshapes]
        sbounds += [self._shape("boundary", i).bounds(lat) for i in bshapes]
        try:
            grid = geo.Grid(*geo.bounding_box(fboxes + bslabs + sbounds))
        except OverflowError:
            raise _Checker(self.source).error(
                "dp", "a spacing whose lattice over the geometry fits int64 keys", self.dp) from None
        bkeys = grid.union_keys(bslabs)
        if bshapes:
            bkeys = np.unique(np.concatenate(
                [bkeys] + [grid.point_keys(self._shape_points("boundary", i)) for i in bshapes]))
        hollows = self._hollows(lat)
        if hollows:
            bidx = grid.indices(bkeys)
            keep = np.ones(len(bidx), bool)
            for box in hollows:
                keep &= ~geo.in_box(bidx, box)
            bkeys = bkeys[keep]
        fkeys = grid.union_keys(fboxes)          # overlapping fluid boxes merge
        if fshapes:
            fkeys = np.unique(np.concatenate(
                [fkeys] + [grid.point_keys(self._shape_points("fluid", i)) for i in fshapes]))
        fkeys = fkeys[~geo.contains(bkeys, fkeys)]  # fluid on a boundary point is dropped
        fidx = grid.indices(fkeys)
        if solids or bshapes:   # nor inside a body (or under a slope)
            inside = np.zeros(len(fidx), bool)
            for box in solids:
                inside |= geo.in_box(fidx, box)
            for i in bshapes:
                inside |= self._shape("boundary", i).solid(lat, fidx)
            fidx = fidx[~inside]
        if len(fidx) == 0:
            raise _Checker(self.source).error(
                "fluid", "at least one fluid particle outside the boundaries", 0)
        self._cache["lattice"] = (grid.indices(bkeys), fidx)
        return self._cache["lattice"]

    def boundary_masks(self) -> dict:
        """{name: boolean mask over the boundary particles (ids 0..nb-1)} of named entries.

        A point shared by several entries belongs to each of them.
        """
        if "masks" in self._cache:
            return self._cache["masks"]
        bidx, _ = self._lattice()
        lat = self._lattice_def()
        out = {}
        if len(bidx):
            grid = geo.Grid(bidx.min(axis=0), bidx.max(axis=0))
            bkeys = grid.point_keys(bidx)
            hi_w = grid.lo + np.asarray(grid.shape) - 1
            for k, e in enumerate(self.boundary):
                if "name" not in e:
                    continue
                if e["type"] in shapes.SHAPE_TYPES:
                    pts = self._shape_points("boundary", k)
                    parts = [pts[np.all((pts >= grid.lo) & (pts <= hi_w), axis=1)]]
                else:
                    parts = _boundary_points(e, lat, self.dim, grid)
                ekeys = np.unique(np.concatenate(
                    [grid.point_keys(i) for i in parts] or [np.empty(0, np.int64)]))
                out[e["name"]] = geo.contains(ekeys, bkeys)
        self._cache["masks"] = out
        return out

    def count_particles(self) -> tuple:
        """(n_fluid, n_boundary) of :meth:`build_particles` (computed on indices only)."""
        rows = self._rows()
        if rows is not None:
            return rows.n_fluid, rows.n_boundary
        bidx, fidx = self._lattice()
        return int(len(fidx)), int(len(bidx))

    def build_particles(self, dtype=np.float64) -> Particles:
        """All particles of the scene at rest.

        Boundary particles come first, then fluid; ids are 0..N-1 in that
        order (each group sorted by lattice index, x slowest). Boundary density
        is rho0. Fluid density is rho0, or with ``initial.hydrostatic`` the Tait
        inverse of the hydrostatic pressure::

            rho = rho0 * (1 + rho0*g*(z_s - z)/B)**(1/gamma)

        with ``z_s`` = :meth:`surface_level` and B from :attr:`constants`.

        Parameters
        ----------
        dtype : numpy dtype
            Precision of velocity and density (positions are always float64).
        """
        dtype = np.dtype(dtype)
        rho0 = self.physics.rho0
        rows = self._rows()
        if rows is not None:    # boxes only: written row by row in parallel, nothing else of size N
            pos, ids, kind, rho, rho_m1 = rows.fill(self.lattice_origin, self.dp, dtype, rho0, (FIXED, FLUID))
            nb, nf = rows.n_boundary, rows.n_fluid
        else:
            bidx, fidx = self._lattice()
            lat = self._lattice_def()
            pos = np.concatenate([lat.positions(bidx), lat.positions(fidx)])
            nb, nf = len(bidx), len(fidx)
            ids = np.arange(nb + nf, dtype=np.int64)
            kind = np.concatenate([np.full(nb, FIXED, np.int8), np.full(nf, FLUID, np.int8)])
            rho = np.full(nb + nf, rho0, dtype)
            rho_m1 = rho.copy()
        n = nb + nf
        for m in self.extra.get("motion") or ():  # bodies moved by [[motion]] are kind 2
            kind[:nb][self.boundary_masks()[m["body"]]] = MOVING
        if self.hydrostatic:    # in float64, rounded to dtype once, the same on every CPU
            k = self.constants
            hydrostatic_density(pos, self.vertical, float(self.surface_level()), float(rho0),
                                abs(float(k.gravity[self.vertical])), float(k.B), 1.0 / self.physics.gamma, rho)
            rho_m1[:] = rho
        if self.jitter > 0:  # breaks lattice ties (e.g. for slab cuts); same seed, same scene
            rng = np.random.default_rng(12345)
            pos[nb:] += rng.uniform(-self.jitter, self.jitter, (nf, self.dim)) * self.dp
        # velocities at rest: zeroed pages that a device backend uploads without writing
        return Particles(id=ids, kind=kind, pos=pos, vel=np.zeros((n, self.dim), dtype), rho=rho,
                         vel_m1=np.zeros((n, self.dim), dtype), rho_m1=rho_m1)



def _boundary_boxes(e: dict, lat: geo.Lattice, dim: int) -> list:
    """Index boxes (slabs) of one normalised boundary entry; faces snap to the nearest plane."""
    lo, hi = lat.nearest(e["min"]), lat.nearest(e["max"])
    if e["type"] == "tank":
        return geo.tank_boxes(lo, hi, e["layers"], e["open_top"])
    if e["type"] == "box":
        if e["fill"] == "solid":
            return [(lo, hi)]
        return geo.shell_boxes(lo, hi, e["layers"], e["open_bottom"])
    axis = int(np.flatnonzero(np.asarray(e["max"]) == np.asarray(e["min"]))[0])
    return geo.wall_boxes(lo, hi, axis, 1 if e["direction"] == "+" else -1, e["layers"])


def _boundary_points(e: dict, lat: geo.Lattice, dim: int, grid: "geo.Grid") -> list:
    """Index arrays ([n, dim]) of one entry's points clipped to ``grid``'s window."""
    out = []
    hi_w = grid.lo + np.asarray(grid.shape) - 1
    for lo, hi in _boundary_boxes(e, lat, dim):
        lo, hi = np.maximum(lo, grid.lo), np.minimum(hi, hi_w)
        if geo.box_count((lo, hi)):
            out.append(grid.indices(grid.box_keys((lo, hi))))
    return out
