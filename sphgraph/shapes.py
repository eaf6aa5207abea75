"""Shapes beyond boxes on the scene lattice: cylinders (discs in 2D), slopes and closed STL meshes.

Boxes, tanks and walls (:mod:`sphgraph.geometry`) are unions of index boxes. The shapes
here are not, so each one is a small object that tests lattice points against the
shape in metres and hands back integer index vectors on the same lattice -- a fill never
lands between lattice points, and overlaps with other entries merge exactly as boxes do.

Where the particles go (``docs/scenes.md``, "Cylinders, slopes and STL meshes"):

* closed bodies (``cylinder``, ``stl``) take the lattice points *inside* the surface,
  low faces included and high faces excluded (every point is tested after a shift of
  1e-6 dp, which also keeps rays off mesh edges), so ``count * dp**dim`` estimates the
  enclosed volume (an aligned box gives it exactly). A boundary shell ``layers`` thick
  keeps the inside points closer than ``layers * dp`` to the surface;
* a ``slope`` is a wall: its first layer lies on the plane (nearest lattice point, as
  tank walls snap to the nearest plane) and further layers grow below it.

Fluid never stays inside a boundary body (cylinder or mesh, solid or surface) nor under a
slope. Each shape also gives, for mDBC (:mod:`sphgraph.physics.mdbc`), the ghost node of a
boundary particle: its mirror image across the shape's interface (the analytic surface of a
cylinder, the nearest triangle of a mesh, dp/2 above a slope's plane).
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from . import geometry as geo
from . import stl
from .files import FileRefused

SHAPE_TYPES = ("cylinder", "slope", "stl")
FLUID_SHAPES = ("cylinder", "stl")
FILLS = ("solid", "surface")
KEYS = {
    ("fluid", "cylinder"): ("type", "center", "radius", "axis", "length"),
    ("boundary", "cylinder"): ("type", "name", "center", "radius", "axis", "length", "fill", "layers"),
    ("boundary", "slope"): ("type", "name", "start", "end", "angle", "length", "width", "axis", "layers"),
    ("fluid", "stl"): ("type", "path", "scale", "offset"),
    ("boundary", "stl"): ("type", "name", "path", "scale", "offset", "fill", "layers"),
}
# shift of every tested point, in units of dp: irrational ratios keep vertical rays off
# mesh edges and vertices, and make faces on lattice planes half-open (low in, high out)
_SHIFT = 1e-6 * np.array([0.6180339887498949, 0.41421356237309503, 0.30102999566398120])
_CHUNK = 2_000_000  # lattice points tested at once


# --- validation -----------------------------------------------------------------------

def validate(c, key: str, e: dict, group: str, dim: int, base_dir: Path) -> dict:
    """Check one cylinder/slope/stl entry (``c`` is the scene's checker); the normalised entry."""
    t = e["type"]
    if t == "stl" and dim != 3:
        raise c.error(f"{key}.type", '"stl" only in 3D scenes (dim = 3)', t)
    c.table(key, e, KEYS[(group, t)])
    out = {"type": t}
    if "name" in e:
        out["name"] = e["name"]   # checked by the scene with the other names
    if t == "cylinder":
        out["center"] = c.vector(f"{key}.center", _req(c, key, e, "center", f"a list of {dim} numbers"),
                                 dim).tolist()
        out["radius"] = c.number(f"{key}.radius", _req(c, key, e, "radius", "a number > 0 [m]"), gt=0)
        if dim == 2:
            for k in ("axis", "length"):
                if k in e:
                    raise c.error(f"{key}.{k}", f"no {k} key in 2D (a 2D cylinder is a disc)", e[k])
        else:
            out["length"] = c.number(f"{key}.length", _req(c, key, e, "length", "a number > 0 [m]"), gt=0)
            ax = e.get("axis", "z")
            if isinstance(ax, str):
                out["axis"] = c.choice(f"{key}.axis", ax, ("x", "y", "z"))
            else:
                v = c.vector(f"{key}.axis", ax, 3)
                if not np.linalg.norm(v) > 0:
                    raise c.error(f"{key}.axis", '"x", "y", "z" or a non-zero vector', ax)
                out["axis"] = v.tolist()
    elif t == "slope":
        _validate_slope(c, key, e, dim, out)
    else:
        raw = e.get("path", None)
        if not isinstance(raw, str) or not raw:
            raise c.error(f"{key}.path", "an STL file name (relative to the scene file)", raw)
        path = (base_dir / raw).resolve()
        out["path"] = str(path)
        out["scale"] = c.number(f"{key}.scale", e.get("scale", 1.0), gt=0)
        out["offset"] = c.vector(f"{key}.offset", e.get("offset", [0.0, 0.0, 0.0]), 3).tolist()
        try:
            tris = _read(path)
        except OSError as err:
            raise c.error(f"{key}.path", "a readable STL file (relative to the scene file)",
                          f"{raw!r} ({type(err).__name__}: {err.strerror or err})", literal=True) from None
        except FileRefused as err:   # not a regular file, too large (sphgraph.files)
            raise c.error(f"{key}.path", err.expected, f"{raw!r}: {err.got}", literal=True) from None
        except stl.MeshError as err:
            raise c.error(f"{key}.path", "a binary or ASCII STL file", f"{raw!r}: {err}", literal=True) from None
        problem = stl.closure_problem(tris)
        if problem:
            raise c.error(f"{key}.path", "a closed (watertight) triangle mesh enclosing a volume",
                          f"{raw!r} with {problem}", literal=True)
    if group == "boundary" and t != "slope":
        out["fill"] = c.choice(f"{key}.fill", e.get("fill", "solid"), FILLS)
        if out["fill"] == "solid" and "layers" in e:
            raise c.error(f"{key}.layers", 'no layers key with fill = "solid" '
                          '(it is the shell thickness of fill = "surface")', e["layers"])
    if group == "boundary" and (t == "slope" or out["fill"] == "surface"):
        out["layers"] = c.integer(f"{key}.layers", e.get("layers", 1), ge=1)
    return out


def _validate_slope(c, key, e, dim, out) -> None:
    out["start"] = c.vector(f"{key}.start", _req(c, key, e, "start", f"a list of {dim} numbers"), dim).tolist()
    out["axis"] = c.choice(f"{key}.axis", e.get("axis", "x"), ("x", "y") if dim == 3 else ("x",))
    a = "xyz".index(out["axis"])
    given = [k for k in ("end", "angle") if k in e]
    if len(given) != 1:
        raise c.error(key, "either end, or angle and length" + (" and width" if dim == 3 else ""),
                      f"keys {', '.join(given) or 'neither'}", literal=True)
    if "end" in e:
        for k in ("length", "width"):
            if k in e:
                raise c.error(f"{key}.{k}", f"no {k} key with end (it goes with angle)", e[k])
        end = c.vector(f"{key}.end", e["end"], dim)
        if end[a] == out["start"][a]:
            raise c.error(f"{key}.end", f"a point whose {out['axis']} differs from start's", e["end"])
        if dim == 3 and end[1 - a] == out["start"][1 - a]:
            raise c.error(f"{key}.end", f"a point whose {'xy'[1 - a]} (the slope's width) differs "
                          "from start's", e["end"])
        out["end"] = end.tolist()
    else:
        out["angle"] = c.number(f"{key}.angle", e["angle"], gt=-90, le=90)
        if out["angle"] == 90:
            raise c.error(f"{key}.angle", "a number > -90 and < 90 [degrees]", e["angle"])
        out["length"] = c.number(f"{key}.length", _req(c, key, e, "length", "a number > 0 [m]"), gt=0)
        if dim == 3:
            out["width"] = c.number(f"{key}.width", _req(c, key, e, "width", "a number > 0 [m]"), gt=0)
        elif "width" in e:
            raise c.error(f"{key}.width", "no width key in 2D", e["width"])
    with np.errstate(all="ignore"):   # the fill's own arithmetic: a run lost next to start is no slope
        sl = Slope(out, dim)
    if not (np.isfinite(sl.slope) and sl.cos > 0 and np.all(np.isfinite(sl.e))):
        k = "end" if "end" in e else "length"
        raise c.error(f"{key}.{k}", f"a {k} giving a finite slope from start {out['start']} "
                      f"(a rise over a run along {out['axis']} that float64 resolves)", e[k])


def _req(c, key, e, name, form):
    if name not in e:
        raise c.error(f"{key}.{name}", form, "nothing (key missing)", literal=True)
    return e[name]


_MESHES: dict = {}


def _read(path: Path) -> np.ndarray:
    """Triangles of an STL file, cached by (path, mtime, size)."""
    st = os.stat(path)
    k = (str(path), st.st_mtime_ns, st.st_size)
    if k not in _MESHES:
        _MESHES.clear()   # one mesh per scene is the common case: keep memory bounded
        _MESHES[k] = stl.read_stl(path)
    return _MESHES[k]


def make(e: dict, dim: int):
    """The shape object of a normalised entry."""
    return {"cylinder": Cylinder, "slope": Slope, "stl": Mesh}[e["type"]](e, dim)


# --- common ---------------------------------------------------------------------------

def _box_points(box) -> np.ndarray:
    lo, hi = box
    axes = [np.arange(a, b + 1, dtype=np.int64) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lo))


def _scan(lat: geo.Lattice, box, keep) -> np.ndarray:
    """Index vectors of ``box`` whose shifted positions pass ``keep(x) -> mask``, in x-slabs."""
    lo, hi = (np.asarray(b, np.int64) for b in box)
    dim = len(lo)
    if geo.box_count((lo, hi)) == 0:
        return np.empty((0, dim), np.int64)
    per = max(geo.box_count((lo[1:], hi[1:])), 1)
    step = max(1, _CHUNK // per)
    out = []
    for a in range(int(lo[0]), int(hi[0]) + 1, step):
        sub_lo, sub_hi = lo.copy(), hi.copy()
        sub_lo[0], sub_hi[0] = a, min(a + step - 1, hi[0])
        idx = _box_points((sub_lo, sub_hi))
        out.append(idx[keep(lat.positions(idx) + _SHIFT[:dim] * lat.dp)])
    return np.concatenate(out)


def _outside_box(pos, lo, hi) -> np.ndarray:
    """Distance of each row of ``pos`` to the box [lo, hi] (0 inside)."""
    return np.sqrt((np.maximum(lo - pos, 0) ** 2 + np.maximum(pos - hi, 0) ** 2).sum(1))


# --- cylinder ---------------------------------------------------------------------------

class Cylinder:
    """A disc (2D) or a cylinder (3D) from ``center`` (the centre of its first end face)
    ``length`` along ``axis``."""

    def __init__(self, e: dict, dim: int):
        self.dim = dim
        self.c = np.asarray(e["center"], np.float64)
        self.R = float(e["radius"])
        self.L = float(e.get("length", 0.0))
        ax = e.get("axis", "z")
        a = np.eye(3)["xyz".index(ax)] if isinstance(ax, str) else np.asarray(ax, np.float64)
        self.a = a / np.linalg.norm(a)
        self.layers = int(e.get("layers", 0))   # 0: solid
        self.surface = e.get("fill") == "surface"

    def _tr(self, x):
        """(t along the axis, radial vector) of positions ``x``; 2D: t = 0."""
        d = x - self.c
        if self.dim == 2:
            return np.zeros(len(x)), d
        t = d @ self.a
        return t, d - t[:, None] * self.a

    def inside(self, x, dp) -> np.ndarray:
        tol = geo.TOL * dp
        t, rv = self._tr(x)
        m = np.sqrt((rv * rv).sum(1)) <= self.R + tol
        if self.dim == 3:
            m &= (t >= -tol) & (t < self.L - tol)
        return m

    def _keep(self, x, dp):
        m = self.inside(x, dp)
        if not self.surface:
            return m
        tol, thick = geo.TOL * dp, self.layers * dp
        t, rv = self._tr(x)
        shell = self.R - np.sqrt((rv * rv).sum(1)) < thick - tol
        if self.dim == 3:  # end faces: the first is in (t = 0), the second out (t = L)
            shell |= (t < thick - tol) | (self.L - t <= thick + tol)
        return m & shell

    def extent(self, dp) -> tuple:
        """(lo, hi) coordinates [m] holding every particle of the shape."""
        if self.dim == 2:
            return self.c - self.R, self.c + self.R
        ends = np.stack([self.c, self.c + self.L * self.a])
        ext = self.R * np.sqrt(np.maximum(1.0 - self.a ** 2, 0.0))
        return ends.min(0) - ext, ends.max(0) + ext

    def bounds(self, lat) -> geo.Box:
        return lat.inner_range(*self.extent(lat.dp))

    def points(self, lat) -> np.ndarray:
        return _scan(lat, self.bounds(lat), lambda x: self._keep(x, lat.dp))

    def solid(self, lat, idx) -> np.ndarray:
        return self.inside(lat.positions(idx) + _SHIFT[:self.dim] * lat.dp, lat.dp)

    def estimate(self, dp) -> int:
        dim = self.dim
        vol = math.pi * (self.R + dp) ** 2 * (1.0 if dim == 2 else self.L + 2 * dp)
        if self.surface:
            ri = max(self.R - (self.layers + 1) * dp, 0.0)
            li = max(self.L - 2 * (self.layers + 1) * dp, 0.0)
            vol -= math.pi * ri ** 2 * (1.0 if dim == 2 else li)
        return int(math.ceil(vol / dp ** dim))

    def ghosts(self, pos, dp):
        """(mirror image across the surface, distance to it) of boundary positions ``pos``."""
        t, rv = self._tr(pos)
        r = np.sqrt((rv * rv).sum(1))
        safe = np.where(r > 1e-12 * self.R, r, 1.0)
        u = rv / safe[:, None]
        u[r <= 1e-12 * self.R] = np.eye(self.dim)[0 if self.dim == 2 or abs(self.a[0]) < 0.9 else 1]
        cands = [(pos + ((self.R - r)[:, None] * u), np.abs(self.R - r))]
        if self.dim == 3:
            cands += [(pos - t[:, None] * self.a, np.abs(t)),
                      (pos + (self.L - t)[:, None] * self.a, np.abs(self.L - t))]
        return _nearest_mirror(pos, cands)


def _nearest_mirror(pos, cands):
    best_c, best_d = cands[0]
    best_c, best_d = best_c.copy(), best_d.copy()
    for cp, d in cands[1:]:
        take = d < best_d
        best_c[take], best_d[take] = cp[take], d[take]
    return 2.0 * best_c - pos, best_d


# --- slope ---------------------------------------------------------------------------------

class Slope:
    """A plane ramp (a beach) from ``start`` to ``end`` along ``axis``, solid below its plane.

    Its first particle layer lies on the plane (the lattice points within dp/2 of it,
    measured normal to it) and ``layers`` layers grow below; in 3D it spans the width
    between start and end on the other horizontal axis.
    """

    def __init__(self, e: dict, dim: int):
        self.dim = dim
        self.v = dim - 1
        self.u = "xyz".index(e.get("axis", "x"))
        self.layers = int(e.get("layers", 1))
        s = np.asarray(e["start"], np.float64)
        if "end" in e:
            end = np.asarray(e["end"], np.float64)
        else:
            end = s.copy()
            end[self.u] += e["length"]
            end[self.v] += e["length"] * math.tan(math.radians(e["angle"]))
            if dim == 3:
                end[1 - self.u] += e["width"]
        self.s, self.e = s, end
        self.slope = (end[self.v] - s[self.v]) / (end[self.u] - s[self.u])   # dz/du
        self.cos = 1.0 / math.sqrt(1.0 + self.slope ** 2)
        n = np.zeros(dim)   # unit normal, up out of the solid
        n[self.u], n[self.v] = -self.slope * self.cos, self.cos
        self.n = n
        self.lo, self.hi = np.minimum(s, end), np.maximum(s, end)

    def depth(self, x) -> np.ndarray:
        """Normal distance below the plane (negative above it)."""
        zs = self.s[self.v] + (x[:, self.u] - self.s[self.u]) * self.slope
        return (zs - x[:, self.v]) * self.cos

    def _extent(self, x, dp) -> np.ndarray:
        tol = geo.TOL * dp
        m = (x[:, self.u] >= self.lo[self.u] - tol) & (x[:, self.u] <= self.hi[self.u] + tol)
        if self.dim == 3:
            w = 1 - self.u
            m &= (x[:, w] >= self.lo[w] - tol) & (x[:, w] <= self.hi[w] + tol)
        return m

    def extent(self, dp) -> tuple:
        lo, hi = self.lo.copy(), self.hi.copy()
        lo[self.v] -= (self.layers + 1) * dp / self.cos
        hi[self.v] += dp / self.cos
        return lo, hi

    def bounds(self, lat) -> geo.Box:
        return lat.inner_range(*self.extent(lat.dp))

    def points(self, lat) -> np.ndarray:
        dp = lat.dp
        tol = geo.TOL * dp

        def keep(x):
            d = self.depth(x)
            return self._extent(x, dp) & (d >= -0.5 * dp - tol) & (d < (self.layers - 0.5) * dp - tol)
        return _scan(lat, self.bounds(lat), keep)

    def solid(self, lat, idx) -> np.ndarray:
        x = lat.positions(idx) + _SHIFT[:self.dim] * lat.dp
        return self._extent(x, lat.dp) & (self.depth(x) >= -0.5 * lat.dp - geo.TOL * lat.dp)

    def estimate(self, dp) -> int:
        ext = (self.hi - self.lo)[[a for a in range(self.dim) if a != self.v]]
        along = np.prod(ext + 2 * dp) / self.cos
        return int(math.ceil(along * (self.layers + 1) * dp / dp ** self.dim))

    def ghosts(self, pos, dp):
        d = self.depth(pos) + 0.5 * dp       # below the interface, dp/2 above the plane
        lo, hi = self.lo.copy(), self.hi.copy()
        lo[self.v], hi[self.v] = -np.inf, np.inf
        return pos + 2.0 * d[:, None] * self.n, np.abs(d) + _outside_box(pos, lo, hi)


# --- STL mesh ------------------------------------------------------------------------------

class Mesh:
    """A closed triangle mesh from an STL file (``scale * x + offset``), filled by ray parity.

    Inside test: a vertical ray through each lattice column (shifted by 1e-6 dp so it
    misses edges and vertices) crosses the closed surface an even number of times; the
    points between the 1st and 2nd, 3rd and 4th... crossings are inside. This is the
    scan-line fill of voxelizers (e.g. Nooruddin & Turk 2003, "Simplification and repair
    of polygonal models using volumetric techniques", parity count), vectorised over
    (triangle, column) pairs.
    """

    def __init__(self, e: dict, dim: int):
        self.dim = 3
        self.tris = _read(Path(e["path"])) * float(e["scale"]) + np.asarray(e["offset"], np.float64)
        self.surface = e.get("fill") == "surface"
        self.layers = int(e.get("layers", 0))
        self._memo = None

    def extent(self, dp) -> tuple:
        v = self.tris.reshape(-1, 3)
        return v.min(0), v.max(0)

    def bounds(self, lat) -> geo.Box:
        return lat.inner_range(*self.extent(lat.dp))

    def _mask(self, lat):
        """(index box, dense inside mask over it), computed once per lattice."""
        key = (tuple(lat.origin), lat.dp)
        if self._memo is None or self._memo[0] != key:
            box = self.bounds(lat)
            self._memo = (key, box, inside_mask(self.tris, lat, box))
        return self._memo[1], self._memo[2]

    def points(self, lat) -> np.ndarray:
        box, inside = self._mask(lat)
        keep = shell(inside, self.layers) if self.surface else inside
        return np.argwhere(keep).astype(np.int64) + box[0]

    def solid(self, lat, idx) -> np.ndarray:
        (lo, hi), inside = self._mask(lat)
        m = np.all((idx >= lo) & (idx <= hi), axis=1)
        out = np.zeros(len(idx), bool)
        k = idx[m] - lo
        out[m] = inside[k[:, 0], k[:, 1], k[:, 2]]
        return out

    def estimate(self, dp) -> int:
        a = stl.area(self.tris) / dp ** 2
        n = stl.volume(self.tris) / dp ** 3 + a
        if self.surface:
            n = min(n, a * (self.layers + 1))
        return int(math.ceil(n))

    def ghosts(self, pos, dp):
        c, d = closest_on_mesh(pos, self.tris)
        return 2.0 * c - pos, d


def inside_mask(tris: np.ndarray, lat: geo.Lattice, box) -> np.ndarray:
    """Boolean [nx, ny, nz] over the index ``box``: lattice points inside the closed mesh."""
    lo, hi = (np.asarray(b, np.int64) for b in box)
    shape = tuple(int(s) for s in hi - lo + 1)
    if min(shape) <= 0:
        return np.zeros((0, 0, 0), bool)
    dp = lat.dp
    base = lat.origin + lo * dp + _SHIFT * dp          # position of index `lo`, shifted
    p = (tris - base) / dp                              # mesh in shifted index units
    nx, ny, nz = shape
    # columns whose (x, y) may fall in each triangle's projection
    i0 = np.clip(np.ceil(p[:, :, 0].min(1)), 0, nx).astype(np.int64)
    i1 = np.clip(np.floor(p[:, :, 0].max(1)), -1, nx - 1).astype(np.int64)
    j0 = np.clip(np.ceil(p[:, :, 1].min(1)), 0, ny).astype(np.int64)
    j1 = np.clip(np.floor(p[:, :, 1].max(1)), -1, ny - 1).astype(np.int64)
    ni, nj = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
    cnt = ni * nj
    cols, zs = [], []
    t = 0
    while t < len(p):   # chunks of triangles with about _CHUNK candidate columns
        t1 = t + 1 + int(np.searchsorted(np.cumsum(cnt[t:]), _CHUNK))
        sel = np.arange(t, min(t1, len(p)))
        t = sel[-1] + 1
        c = cnt[sel]
        if c.sum() == 0:
            continue
        tri = np.repeat(sel, c)
        k = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)    # rank within the triangle
        ci = i0[tri] + k // nj[tri]
        cj = j0[tri] + k % nj[tri]
        v = p[tri]
        x, y = ci.astype(np.float64), cj.astype(np.float64)
        # edge functions (twice the signed sub-triangle areas) of the column in the projection
        w0 = (v[:, 2, 0] - v[:, 1, 0]) * (y - v[:, 1, 1]) - (v[:, 2, 1] - v[:, 1, 1]) * (x - v[:, 1, 0])
        w1 = (v[:, 0, 0] - v[:, 2, 0]) * (y - v[:, 2, 1]) - (v[:, 0, 1] - v[:, 2, 1]) * (x - v[:, 2, 0])
        w2 = (v[:, 1, 0] - v[:, 0, 0]) * (y - v[:, 0, 1]) - (v[:, 1, 1] - v[:, 0, 1]) * (x - v[:, 0, 0])
        hit = ((w0 > 0) & (w1 > 0) & (w2 > 0)) | ((w0 < 0) & (w1 < 0) & (w2 < 0))
        w = w0 + w1 + w2
        z = (w0 * v[:, 0, 2] + w1 * v[:, 1, 2] + w2 * v[:, 2, 2])[hit] / w[hit]
        cols.append(ci[hit] * ny + cj[hit])
        zs.append(z)
    mask = np.zeros(shape, bool)
    if not cols:
        return mask
    col, z = np.concatenate(cols), np.concatenate(zs)
    order = np.lexsort((z, col))
    col, z = col[order], z[order]
    if np.any(np.bincount(col, minlength=nx * ny) % 2):
        raise stl.MeshError("a mesh that a vertical line crosses an odd number of times (not closed)")
    c, za, zb = col[0::2], z[0::2], z[1::2]
    k0 = np.clip(np.ceil(za), 0, nz).astype(np.int64)        # first index >= entry
    k1 = np.clip(np.ceil(zb), 0, nz).astype(np.int64)        # first index >= exit (excluded)
    ok = k1 > k0
    diff = np.zeros((nx * ny, nz + 1), np.int8)
    np.add.at(diff, (c[ok], k0[ok]), 1)
    np.add.at(diff, (c[ok], k1[ok]), -1)
    return (np.cumsum(diff[:, :nz], axis=1, dtype=np.int8) > 0).reshape(shape)


def shell(inside: np.ndarray, layers: int) -> np.ndarray:
    """Inside points with an outside lattice point within ``layers`` spacings (Euclidean):
    the ``layers`` outermost layers of a voxel body -- exactly ``layers`` on faces along
    the lattice axes; on curved or inclined faces the distance to the nearest outside
    point exceeds the depth, so the shell is up to ~10 % thinner (measured on spheres)."""
    L = int(layers)
    out = np.pad(~inside, L, constant_values=True)
    near = np.zeros(inside.shape, bool)
    n = inside.shape
    rng = range(-L, L + 1)
    for o in ((a, b, c) for a in rng for b in rng for c in rng):
        if 0 < o[0] ** 2 + o[1] ** 2 + o[2] ** 2 <= L * L:
            near |= out[L + o[0]:L + o[0] + n[0], L + o[1]:L + o[1] + n[1], L + o[2]:L + o[2] + n[2]]
    return inside & near


def closest_on_mesh(pos: np.ndarray, tris: np.ndarray, chunk: int = 200_000):
    """(closest surface point, distance) of each row of ``pos`` over all triangles.

    Ericson, Real-Time Collision Detection (2005) §5.1.5 ClosestPtPointTriangle, written
    for arrays: the Voronoi region of the point (vertex, edge or face) picks the formula.
    """
    best_c = np.zeros_like(pos)
    best_d = np.full(len(pos), np.inf)
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    step = max(1, chunk // max(len(tris), 1))
    for s in range(0, len(pos), step):
        p = pos[s:s + step, None, :]
        q = _closest_pt_triangle(p, a[None], b[None], c[None])
        d = np.sqrt(((q - p) ** 2).sum(-1))
        k = d.argmin(1)
        r = np.arange(len(k))
        best_c[s:s + step] = q[r, k]
        best_d[s:s + step] = d[r, k]
    return best_c, best_d


def _closest_pt_triangle(p, a, b, c):
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        v_f, w_f = vb / den, vc / den                                    # face
        t_ab = d1 / (d1 - d3)                                            # edge ab
        t_ac = d2 / (d2 - d6)                                            # edge ac
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))                       # edge bc
    # regions applied from the lowest priority to the highest (Ericson's order: a, b, ab, c, ac, bc, face)
    q = a + v_f[..., None] * ab + w_f[..., None] * ac
    q = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[..., None],
                 b + t_bc[..., None] * (c - b), q)
    q = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[..., None], a + t_ac[..., None] * ac, q)
    q = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, q)
    q = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[..., None], a + t_ab[..., None] * ab, q)
    q = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, q)
    return np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, q)
