"""Scenes: a TOML file (or dict) -> a validated :class:`Scene` -> particles.

A scene says what to simulate: resolution ``dp``, run length, the domain the
particles must stay in, the physics options (:class:`~sphgraph.config.PhysicsConfig`)
and the geometry -- ``[[fluid]]`` boxes and ``[[boundary]]`` tanks, obstacles and
walls -- all on one lattice (see :mod:`sphgraph.geometry`). Every key is
documented in ``docs/scenes.md``.

Validation happens once, in :meth:`Scene.from_dict` (which :meth:`Scene.from_toml`
and :meth:`Scene.with_overrides` go through). Every problem raises
:class:`~sphgraph.errors.InputError` with one line of the form
``"{file}: {key}: expected {form}, got {value!r}"`` where ``key`` is a dotted path
(``fluid[0].max``, ``physics.kernel``) or a command-line flag (``--dp``).

Axes: 2D scenes use (x, y) with y vertical; 3D scenes (x, y, z) with z vertical.
"""
from __future__ import annotations

import copy
import json
import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from . import geometry as geo
from . import shapes, stl
from .config import BOUNDARIES, CELL_SIZES, DIFFUSIONS, INTEGRATORS, KERNELS, SHIFTINGS, PhysicsConfig, derive
from .errors import InputError
from .particles import FIXED, FLUID, MOVING, Particles

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

FORMAT_VERSION = 1
DEFAULT_MAX_PARTICLES = 200_000_000
_CHUNK = 1 << 20   # rows a float64 temporary of build_particles holds at a time
# Tables that later features read (load balancing, probes, force output, moving
# bodies). Accepted and kept raw in Scene.extra, unvalidated, until those
# features validate them; extend this tuple to reserve another table name.
EXTRA_TABLES = ("balance", "probes", "forces", "motion", "damping")
TOP_KEYS = ("format", "name", "dim", "dp", "end_time", "output_interval", "domain",
            "physics", "decomposition", "initial", "limits", "fluid", "boundary") + EXTRA_TABLES
AXES = ("x", "y", "z")
FLUID_TYPES = ("box",) + shapes.FLUID_SHAPES
BOUNDARY_TYPES = ("tank", "box", "wall") + shapes.SHAPE_TYPES  # shapes: sphgraph/shapes.py
BOX_FILLS = ("solid", "surface")
_ENTRY_KEYS = {
    ("fluid", "box"): ("type", "min", "max"),
    ("boundary", "tank"): ("type", "name", "min", "max", "open_top", "layers"),
    ("boundary", "box"): ("type", "name", "min", "max", "fill", "layers", "open_bottom"),
    ("boundary", "wall"): ("type", "name", "min", "max", "layers", "direction"),
}
# physics options with a fixed set of values, and lower bounds of numeric ones
_PHYS_CHOICES = {"kernel": KERNELS, "diffusion": DIFFUSIONS, "integrator": INTEGRATORS,
                 "cell_size": CELL_SIZES, "shifting": SHIFTINGS, "boundary": BOUNDARIES}
_PHYS_BOUNDS = {  # name: (bound, strict) -> value > bound (strict) or >= bound
    "coefh": (0, True), "coefsound": (0, True), "gamma": (0, True), "rho0": (0, True),
    "visc_alpha": (0, False), "visc_bound_factor": (0, False), "laminar_nu": (0, False),
    "delta": (0, False), "verlet_euler_every": (1, False), "cfl": (0, True),
    "hswl": (0, True), "rho_min": (0, False), "rho_max": (0, True), "shifting_tfs": (0, False),
}
_PHYS_VECTORS = ("gravity",)


def _is_real(v) -> bool:
    # bool is an int subclass in Python, but `true` is never a number in a scene
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


class _Missing:
    def __repr__(self):
        return "nothing (key missing)"


_MISSING = _Missing()


class _Checker:
    """Builds the one-line errors of one source and checks plain values."""

    def __init__(self, source: str):
        self.source = source

    def error(self, key: str, form: str, value, literal: bool = False) -> InputError:
        """The error for ``key``; ``literal`` shows ``value`` (a str) without repr quotes."""
        text = value if literal else repr(value)
        if len(text) > 120:
            text = text[:117] + "..."
        return InputError(f"{self.source}: {key}: expected {form}, got {text}")

    def number(self, key, v, gt=None, ge=None, le=None) -> float:
        conds = [f"{op} {b}" for op, b in ((">", gt), (">=", ge), ("<=", le)) if b is not None]
        form = "a number" + (" " + " and ".join(conds) if conds else "")
        if (not _is_real(v) or not math.isfinite(v)
                or (gt is not None and not v > gt) or (ge is not None and not v >= ge)
                or (le is not None and not v <= le)):
            raise self.error(key, form, v)
        return float(v)

    def integer(self, key, v, ge=None) -> int:
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or (ge is not None and v < ge):
            raise self.error(key, "an integer" + (f" >= {ge}" if ge is not None else ""), v)
        return int(v)

    def boolean(self, key, v) -> bool:
        if not isinstance(v, bool):
            raise self.error(key, "true or false", v)
        return v

    def choice(self, key, v, choices) -> str:
        if not isinstance(v, str) or v not in choices:
            raise self.error(key, "one of " + ", ".join(f'"{c}"' for c in choices), v)
        return v

    def vector(self, key, v, dim) -> np.ndarray:
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if (not isinstance(v, (list, tuple)) or len(v) != dim
                or not all(_is_real(x) and math.isfinite(x) for x in v)):
            raise self.error(key, f"a list of {dim} numbers", v)
        return np.array(v, dtype=np.float64)

    def table(self, key, v, allowed) -> dict:
        if not isinstance(v, dict):
            raise self.error(key, "a table", v)
        for k in v:
            if k not in allowed:
                path = f"{key}.{k}" if key else k
                raise self.error(path, "a known key (one of: " + ", ".join(allowed) + ")", k)
        return v

    def require(self, key, table, name):
        if name not in table:
            raise self.error(f"{key}.{name}" if key else name, _FORMS.get(name, "a value"), _MISSING)
        return table[name]


_FORMS = {"format": f"{FORMAT_VERSION}", "dim": "2 or 3", "dp": "a number > 0",
          "end_time": "a number > 0", "domain": "a table with min and max",
          "min": "a list of numbers", "max": "a list of numbers", "type": "a geometry type",
          "fluid": "at least one [[fluid]] table"}


def _vlist(a) -> list:
    return [float(x) for x in a]


# --- the scene ------------------------------------------------------------------------

@dataclass(eq=False)
class Scene:
    """A validated scene. Build one with :meth:`from_toml` or :meth:`from_dict`.

    Attributes
    ----------
    name : str
        Run name (output goes to ``out/<name>`` by default); default: file stem.
    dim : int
        2 or 3. 2D uses (x, y) with y vertical; 3D (x, y, z) with z vertical.
    dp : float
        Particle spacing [m].
    end_time, output_interval : float
        Simulated time [s] and time between output frames [s].
    domain_min, domain_max : numpy.ndarray
        float64 [dim]: the region particles must stay inside (leaving it is a
        numerical failure).
    lattice_origin : numpy.ndarray
        float64 [dim]: anchor of the particle lattice (``domain.origin``,
        default ``domain_min``); particles sit at ``lattice_origin + k*dp``.
    physics : PhysicsConfig
        Physics options; ``gravity`` is always filled in.
    decomposition_axis : str
        "x", "y", "z" (3D only) or "auto".
    hydrostatic : bool
        Initialise fluid density hydrostatically instead of ``rho0``.
    jitter : float
        Random displacement of fluid particles, uniform in +-jitter*dp per axis
        (seeded, reproducible); 0 keeps the exact lattice.
    max_particles : int
        Refuse scenes whose estimated particle count exceeds this.
    fluid, boundary : list of dict
        Normalised geometry entries (every key present).
    extra : dict
        Raw tables named in :data:`EXTRA_TABLES`.
    text : str
        TOML text of the scene (the file itself, or an equivalent emitted text).
    source : str
        Where the scene came from (a path, or ``"<dict>"``).
    """

    name: str
    dim: int
    dp: float
    end_time: float
    output_interval: float
    domain_min: np.ndarray
    domain_max: np.ndarray
    physics: PhysicsConfig
    decomposition_axis: str = "auto"
    text: str = ""
    source: str = "<dict>"
    lattice_origin: np.ndarray | None = None
    hydrostatic: bool = False
    jitter: float = 0.0
    max_particles: int = DEFAULT_MAX_PARTICLES
    fluid: list = field(default_factory=list)
    boundary: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    periodic: tuple = ()            # axes ("x", "y", "z") that are periodic over [domain]
    exclude_outside: bool = False   # particles leaving the domain / density bounds are excluded
    _cache: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self):
        self.domain_min = np.asarray(self.domain_min, dtype=np.float64)
        self.domain_max = np.asarray(self.domain_max, dtype=np.float64)
        if self.lattice_origin is None:
            self.lattice_origin = self.domain_min.copy()
        self.lattice_origin = np.asarray(self.lattice_origin, dtype=np.float64)

    # --- construction ------------------------------------------------------------

    @classmethod
    def from_toml(cls, path) -> "Scene":
        """Read and validate a scene file.

        Parameters
        ----------
        path : str or os.PathLike
            A TOML scene file (format 1).

        Raises
        ------
        InputError
            Unreadable file, TOML syntax error, or any invalid key.
        """
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(f"{path}: file: expected a readable UTF-8 scene file, "
                             f"got {type(e).__name__}: {e}") from None
        try:
            d = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"{path}: TOML syntax: expected valid TOML, got {e}") from None
        return cls._validate(d, str(path), default_name=path.stem, text=text)

    @classmethod
    def from_dict(cls, d: dict, source: str = "<dict>") -> "Scene":
        """Validate a scene given as a dict (the parsed TOML structure).

        ``text`` becomes an equivalent TOML text (:func:`dumps_toml` of
        :meth:`to_dict`), so output files always carry a loadable scene.
        """
        stem = Path(source).stem if not source.startswith("<") else "scene"
        return cls._validate(d, source, default_name=stem or "scene", text=None)

    def with_overrides(self, dp=None, end_time=None, **physics_overrides) -> "Scene":
        """A new, re-validated scene with command-line style overrides.

        Parameters
        ----------
        dp, end_time : float, optional
            New spacing / end time (errors name ``--dp`` / ``--end-time``).
        **physics_overrides
            ``PhysicsConfig`` fields, e.g. ``visc_alpha=0.02``.
        """
        c = _Checker(self.source)
        d = self.to_dict()
        if dp is not None:
            d["dp"] = c.number("--dp", dp, gt=0)
        if end_time is not None:
            d["end_time"] = c.number("--end-time", end_time, gt=0)
        for k, v in physics_overrides.items():
            if v is None:  # back to the default (e.g. hswl=None: auto again)
                d["physics"].pop(k, None)
            else:
                d["physics"][k] = v
        return self._validate(d, self.source, default_name=self.name, text=None)

    @classmethod
    def _validate(cls, d, source, default_name, text) -> "Scene":
        c = _Checker(source)
        c.table("", d, TOP_KEYS)
        fmt = c.require("", d, "format")
        if type(fmt) is not int or fmt != FORMAT_VERSION:
            raise c.error("format", f"{FORMAT_VERSION} (the only scene format this version reads)", fmt)
        name = d.get("name", default_name)
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", name):
            raise c.error("name", "a name of letters, digits, '.', '_' or '-'", name)
        dim = c.require("", d, "dim")
        if not isinstance(dim, (int, np.integer)) or isinstance(dim, bool) or dim not in (2, 3):
            raise c.error("dim", "2 or 3", dim)
        dim = int(dim)
        dp = c.number("dp", c.require("", d, "dp"), gt=0)
        end_time = c.number("end_time", c.require("", d, "end_time"), gt=0)
        out_dt = c.number("output_interval", d.get("output_interval", end_time / 20), gt=0)
        if out_dt < end_time * 1e-8:   # else the next output time stops advancing (t + interval == t)
            raise c.error("output_interval", f"a number >= end_time * 1e-8 = {end_time * 1e-8:.6g} "
                          "(at most 10^8 frames)", out_dt)

        dom = c.table("domain", c.require("", d, "domain"),
                      ("min", "max", "origin", "periodic", "exclude_outside"))
        dmin = c.vector("domain.min", c.require("domain", dom, "min"), dim)
        dmax = c.vector("domain.max", c.require("domain", dom, "max"), dim)
        if not np.all(dmax > dmin):
            raise c.error("domain.max", f"every coordinate > domain.min {_vlist(dmin)}", dom["max"])
        origin = c.vector("domain.origin", dom.get("origin", _vlist(dmin)), dim)
        # lattice indices are int64 and exact in float64: at most 2**50 spacings from the origin
        if max(np.abs(dmax - origin).max(), np.abs(dmin - origin).max()) > 2.0 ** 50 * dp:
            raise c.error("dp", "a spacing giving at most 2**50 lattice points from domain.origin "
                          "to the domain's corners", dp)
        periodic = dom.get("periodic", [])
        if (not isinstance(periodic, list) or not all(isinstance(a, str) and a in AXES[:dim] for a in periodic)
                or len(set(periodic)) != len(periodic)):   # set() after the type check: [[]] is unhashable
            raise c.error("domain.periodic", "a list of distinct axes among "
                          + ", ".join(f'"{a}"' for a in AXES[:dim]), periodic)
        exclude = c.boolean("domain.exclude_outside", dom.get("exclude_outside", False))

        physics = _physics(c, d.get("physics", {}), dim)
        dec = c.table("decomposition", d.get("decomposition", {}), ("axis",))
        axis = c.choice("decomposition.axis", dec.get("axis", "auto"), AXES[:dim] + ("auto",))
        ini = c.table("initial", d.get("initial", {}), ("hydrostatic", "jitter"))
        hydro = c.boolean("initial.hydrostatic", ini.get("hydrostatic", False))
        jitter = c.number("initial.jitter", ini.get("jitter", 0.0), ge=0.0, le=0.25)
        lim = c.table("limits", d.get("limits", {}), ("max_particles",))
        maxp = int(c.number("limits.max_particles",
                            lim.get("max_particles", DEFAULT_MAX_PARTICLES), ge=1))

        tol = geo.TOL * dp
        base = Path(source).parent if not source.startswith("<") else Path.cwd()  # STL paths
        fluid = []
        for i, e in enumerate(_entries(c, d, "fluid", required=True)):
            key = f"fluid[{i}]"
            e = _entry(c, key, e, "fluid", FLUID_TYPES, dim, base)
            if e["type"] in shapes.SHAPE_TYPES:   # checked against the domain by lattice extent
                fluid.append(e)
                continue
            if np.any(e["_min"] < dmin - tol):
                raise c.error(f"{key}.min", f"a point inside the domain (>= {_vlist(dmin)})", e["min"])
            if np.any(e["_max"] > dmax + tol):
                raise c.error(f"{key}.max", f"a point inside the domain (<= {_vlist(dmax)})", e["max"])
            fluid.append(_public(e))
        raw = _entries(c, d, "boundary", required=False)
        boundary = [_public(_entry(c, f"boundary[{i}]", e, "boundary", BOUNDARY_TYPES, dim, base))
                    for i, e in enumerate(raw)]
        if any(e["type"] == "stl" and e["path"] != r.get("path")
               for e, r in zip(fluid + boundary, d["fluid"] + raw)):
            text = None   # a relative STL path: store the resolved one, loadable from anywhere
        extra = {k: copy.deepcopy(d[k]) for k in EXTRA_TABLES if k in d}
        names = [e["name"] for e in boundary if "name" in e]
        if len(set(names)) != len(names):
            raise c.error("boundary", "distinct names of [[boundary]] entries", names)
        if "motion" in extra:  # moving bodies (sphgraph.motion); [[damping]] zones (sphgraph.waves)
            from . import motion
            extra["motion"] = motion.validate(c, extra["motion"], dim, set(names))
        if "damping" in extra:
            from . import waves
            extra["damping"] = waves.validate_damping(c, extra["damping"], dim)

        scene = cls(name=name, dim=dim, dp=dp, end_time=end_time, output_interval=out_dt,
                    domain_min=dmin, domain_max=dmax, physics=physics,
                    decomposition_axis=axis, text="", source=source, lattice_origin=origin,
                    hydrostatic=hydro, jitter=jitter, max_particles=maxp, fluid=fluid, boundary=boundary,
                    extra=extra, periodic=tuple(periodic), exclude_outside=exclude)
        scene._check_extent(c)
        scene.text = text if text is not None else (
            f"# sphgraph scene, emitted from {source}\n" + dumps_toml(scene.to_dict()))
        return scene

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

    # --- serialisation -------------------------------------------------------------

    def to_dict(self) -> dict:
        """The scene as a plain dict with every default filled in.

        ``Scene.from_dict(scene.to_dict())`` gives an equivalent scene.
        """
        phys = {k: (list(v) if isinstance(v, tuple) else v)
                for k, v in self.physics.to_dict().items() if v is not None}
        d = {
            "format": FORMAT_VERSION, "name": self.name, "dim": self.dim, "dp": self.dp,
            "end_time": self.end_time, "output_interval": self.output_interval,
            "domain": {"min": _vlist(self.domain_min), "max": _vlist(self.domain_max),
                       "origin": _vlist(self.lattice_origin)},
            "physics": phys,
            "decomposition": {"axis": self.decomposition_axis},
            "initial": {"hydrostatic": self.hydrostatic, "jitter": self.jitter},
            "limits": {"max_particles": self.max_particles},
            "fluid": copy.deepcopy(self.fluid),
            "boundary": copy.deepcopy(self.boundary),
        }
        if self.periodic:
            d["domain"]["periodic"] = list(self.periodic)
        if self.exclude_outside:
            d["domain"]["exclude_outside"] = True
        d.update(copy.deepcopy(self.extra))
        return d

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

    @property
    def vertical(self) -> int:
        """Index of the vertical axis (y in 2D, z in 3D)."""
        return self.dim - 1

    @property
    def hswl(self) -> float:
        """Still-water depth used for the speed of sound c0 [m].

        ``physics.hswl`` if set; otherwise the height of the fluid particles,
        ``(z_top - z_bottom) + dp``: each particle stands for a layer dp thick,
        so a column of n layers is n*dp deep (the 2D dam break's 200 rows at
        dp = 0.01 give 2.0 m, the column's nominal height). DualSPHysics'
        ``<hswl auto="true">`` likewise measures the height of the generated
        fluid ("maximum still water level", CaseDambreak_Def.xml).
        """
        if self.physics.hswl is not None:
            return float(self.physics.hswl)
        lo, hi = self._fluid_last()
        return float(hi - lo + 1) * self.dp

    @property
    def constants(self):
        """Derived constants (:func:`sphgraph.config.derive`) at this scene's dp and hswl."""
        return derive(self.physics, self.dim, self.dp, self.hswl)

    def surface_level(self) -> float:
        """Free-surface height for the hydrostatic start: lowest fluid row - dp/2 + hswl."""
        z_bottom = self.lattice_origin[self.vertical] + self._fluid_last()[0] * self.dp
        return float(z_bottom - 0.5 * self.dp + self.hswl)

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
        if self.hydrostatic:    # in float64, a chunk at a time, rounded to dtype once
            k = self.constants
            g = abs(float(k.gravity[self.vertical]))
            zs = self.surface_level()
            for a in range(0, n, _CHUNK):
                depth = np.maximum(zs - pos[a:a + _CHUNK, self.vertical], 0.0)
                rho[a:a + _CHUNK] = rho0 * (1.0 + rho0 * g * depth / k.B) ** (1.0 / self.physics.gamma)
            rho_m1[:] = rho
        if self.jitter > 0:  # breaks lattice ties (e.g. for slab cuts); same seed, same scene
            rng = np.random.default_rng(12345)
            pos[nb:] += rng.uniform(-self.jitter, self.jitter, (nf, self.dim)) * self.dp
        # velocities at rest: zeroed pages that a device backend uploads without writing
        return Particles(id=ids, kind=kind, pos=pos, vel=np.zeros((n, self.dim), dtype), rho=rho,
                         vel_m1=np.zeros((n, self.dim), dtype), rho_m1=rho_m1)


# --- validation helpers ------------------------------------------------------------------

def _physics(c: _Checker, p, dim) -> PhysicsConfig:
    names = PhysicsConfig.field_names()
    c.table("physics", p, names)
    defaults = {f.name: f.default for f in fields(PhysicsConfig)}
    vals = {}
    for k, v in p.items():
        key = f"physics.{k}"
        default = defaults[k]
        if k in _PHYS_CHOICES:
            vals[k] = c.choice(key, v, _PHYS_CHOICES[k])
        elif k in _PHYS_VECTORS:
            vals[k] = tuple(float(x) for x in c.vector(key, v, dim))
        elif isinstance(default, bool):
            vals[k] = c.boolean(key, v)
        elif isinstance(default, int):
            bound = _PHYS_BOUNDS.get(k, (None, False))[0]
            vals[k] = c.integer(key, v, ge=bound)
        elif isinstance(default, str):
            if not isinstance(v, str):
                raise c.error(key, "a string", v)
            vals[k] = v
        else:  # float, or a number that defaults to None (auto)
            bound, strict = _PHYS_BOUNDS.get(k, (None, False))
            vals[k] = c.number(key, v, gt=bound if strict else None,
                               ge=None if strict else bound, le=10 if k == "cfl" else None)
    cfg = PhysicsConfig(**vals)
    if cfg.rho_max <= cfg.rho_min:
        raise c.error("physics.rho_max", f"a number > physics.rho_min = {cfg.rho_min}", cfg.rho_max)
    if cfg.shifting_coef >= 0:   # DualSPHysics ShiftCoef: negative moves particles down grad C
        raise c.error("physics.shifting_coef", "a number < 0 (DualSPHysics ShiftCoef, default -2)",
                      cfg.shifting_coef)
    if cfg.shifting_tfs >= dim:  # the shift is scaled by (div r - tfs)/(dim - tfs)
        raise c.error("physics.shifting_tfs", f"a number >= 0 and < {dim} (0 = off; typically 1.5 "
                      "in 2D, 2.75 in 3D)", cfg.shifting_tfs)
    if cfg.gravity is None:
        cfg.gravity = tuple([0.0] * (dim - 1) + [-9.81])
    return cfg


def _entries(c: _Checker, d, name, required) -> list:
    v = d.get(name, _MISSING)
    if v is _MISSING:
        if required:
            raise c.error(name, f"at least one [[{name}]] table", v)
        return []
    if not isinstance(v, list) or not all(isinstance(e, dict) for e in v):
        raise c.error(name, f"an array of tables ([[{name}]] entries)", v)
    if required and not v:
        raise c.error(name, f"at least one [[{name}]] table", v)
    return v


def _entry(c: _Checker, key, e, group, types, dim, base=Path(".")) -> dict:
    """Validate one geometry entry; returns it normalised (+ '_min'/'_max' arrays for boxes)."""
    t = c.choice(f"{key}.type", c.require(key, e, "type"), types)
    if t in shapes.SHAPE_TYPES:   # cylinder, slope, stl (relative paths from `base`)
        out = shapes.validate(c, key, e, group, dim, base)
        if "name" in e:
            _name(c, key, e)
        return out
    c.table(key, e, _ENTRY_KEYS[(group, t)])
    lo = c.vector(f"{key}.min", c.require(key, e, "min"), dim)
    hi = c.vector(f"{key}.max", c.require(key, e, "max"), dim)
    out = {"type": t, "min": _vlist(lo), "max": _vlist(hi), "_min": lo, "_max": hi}
    if "name" in e:
        out["name"] = _name(c, key, e)
    if t == "wall":
        flat = np.flatnonzero(hi == lo)
        if len(flat) != 1 or np.any(np.delete(hi, flat) <= np.delete(lo, flat)):
            raise c.error(f"{key}.max", "max == min on exactly one axis (the wall's normal) "
                          f"and max > min on the others (min = {_vlist(lo)})", e["max"])
        out["direction"] = c.choice(f"{key}.direction", e.get("direction", "-"), ("-", "+"))
    elif not np.all(hi > lo):
        raise c.error(f"{key}.max", f"every coordinate > {key}.min {_vlist(lo)}", e["max"])
    if t == "tank":
        out["open_top"] = c.boolean(f"{key}.open_top", e.get("open_top", True))
    if t == "box" and group == "boundary":
        out["fill"] = c.choice(f"{key}.fill", e.get("fill", "solid"), BOX_FILLS)
        for k in ("layers", "open_bottom"):
            if out["fill"] == "solid" and k in e:
                raise c.error(f"{key}.{k}", f'no {k} key with fill = "solid" '
                              '(it shapes the shell of fill = "surface")', e[k])
        if out["fill"] == "surface":
            out["open_bottom"] = c.boolean(f"{key}.open_bottom", e.get("open_bottom", False))
    if group == "boundary" and not (t == "box" and out["fill"] == "solid"):
        out["layers"] = c.integer(f"{key}.layers", e.get("layers", 1), ge=1)
    return out


def _name(c: _Checker, key, e) -> str:
    if not isinstance(e["name"], str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", e["name"]):
        raise c.error(f"{key}.name", "a name of letters, digits, '.', '_' or '-'", e["name"])
    return e["name"]


def _public(e: dict) -> dict:
    return {k: v for k, v in e.items() if not k.startswith("_")}


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


# --- a tiny TOML writer (tomllib only reads) ------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else _toml_str(k)


def _toml_str(s: str) -> str:
    # JSON string escapes are a subset of TOML basic-string escapes; DEL must be escaped too
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_value(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # shortest round-trip form; '1e-05' is valid TOML
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}"
                               for k, x in v.items() if x is not None) + "}"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(isinstance(x, dict) for x in v)


def _emit(table: dict, path: list, lines: list) -> None:
    for k, v in table.items():  # plain key/values first: they belong to this table's header
        if v is not None and not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        p = path + [_toml_key(k)]
        if isinstance(v, dict):
            lines += ["", f"[{'.'.join(p)}]"]
            _emit(v, p, lines)
        elif _is_table_array(v):
            for item in v:
                lines += ["", f"[[{'.'.join(p)}]]"]
                _emit(item, p, lines)


def dumps_toml(d: dict) -> str:
    """TOML text for a dict of plain values (str, int, float, bool, lists, dicts).

    ``None`` values are left out (TOML has no null). ``tomllib.loads`` of the
    result equals ``d`` up to those omissions and tuples read back as lists.
    """
    lines: list = []
    _emit(d, [], lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _boundary_points(e: dict, lat: geo.Lattice, dim: int, grid: "geo.Grid") -> list:
    """Index arrays ([n, dim]) of one entry's points clipped to ``grid``'s window."""
    out = []
    hi_w = grid.lo + np.asarray(grid.shape) - 1
    for lo, hi in _boundary_boxes(e, lat, dim):
        lo, hi = np.maximum(lo, grid.lo), np.minimum(hi, hi_w)
        if geo.box_count((lo, hi)):
            out.append(grid.indices(grid.box_keys((lo, hi))))
    return out
