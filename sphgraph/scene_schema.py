"""Scene schema: a parsed TOML structure (dict) -> the checked fields of a Scene.

:func:`validate` checks every key of a scene before any arithmetic on it and returns
the keyword arguments of :class:`sphgraph.scene.Scene`. Every number goes through
:class:`_Checker`, which checks it is a real, finite number of the right type inside
its physical range (:mod:`sphgraph.ranges`). Every problem raises
:class:`~sphgraph.errors.InputError` with one line of the form
``"{file}: {key}: expected {form}, got {value!r}"`` where ``key`` is a dotted path
(``fluid[0].max``, ``physics.kernel``) or a command-line flag (``--dp``).
"""
from __future__ import annotations

import copy
import re
from dataclasses import fields
from pathlib import Path

import numpy as np

from . import geometry as geo
from . import shapes
from .config import (BOUNDARIES, CELL_SIZES, DIFFUSION_TIMES, DIFFUSIONS, INTEGRATORS, KERNELS, RIEMANNS,
                     RIEMANN_JUMPS, RIEMANN_WALLS, SHIFTINGS, PhysicsConfig)
from .errors import InputError
from .ranges import CHOICES, describe, expected, finite, in_range, is_real

FORMAT_VERSION = 1
DEFAULT_MAX_PARTICLES = 200_000_000
# Tables of features (load balancing, probes, force output, moving bodies, damping
# zones): validated here by the features' own checks, every number through the
# checker and its range, and kept in Scene.extra for the features to read.
EXTRA_TABLES = ("balance", "probes", "forces", "motion", "damping")
TOP_KEYS = ("format", "name", "dim", "dp", "end_time", "output_interval", "domain",
            "physics", "decomposition", "initial", "limits", "fluid", "boundary") + EXTRA_TABLES
SECTION_KEYS = {"domain": ("min", "max", "origin", "periodic", "exclude_outside", "exclude_max_share"),
                "decomposition": ("axis",), "initial": ("hydrostatic", "jitter"), "limits": ("max_particles",)}
AXES = ("x", "y", "z")
NAME_LENGTH = 128
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
                 "cell_size": CELL_SIZES, "shifting": SHIFTINGS, "boundary": BOUNDARIES,
                 "diffusion_time": DIFFUSION_TIMES, "riemann": RIEMANNS,
                 "riemann_wall": RIEMANN_WALLS, "riemann_jump": RIEMANN_JUMPS}
_PHYS_BOUNDS = {  # name: (bound, strict) -> value > bound (strict) or >= bound
    "coefh": (0, True), "coefsound": (0, True), "gamma": (0, True), "rho0": (0, True),
    "visc_alpha": (0, False), "visc_bound_factor": (0, False), "laminar_nu": (0, False),
    "delta": (0, False), "verlet_euler_every": (1, False), "cfl": (0, True),
    "hswl": (0, True), "rho_min": (0, False), "rho_max": (0, True), "shifting_tfs": (0, False),
}
_PHYS_VECTORS = ("gravity",)


_is_real = is_real   # bool is an int subclass in Python, but `true` is never a number in a scene


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
        """A real, finite number within ``gt``/``ge``/``le`` and the key's physical range
        (:mod:`sphgraph.ranges`), checked before any arithmetic on it."""
        form = expected(key, v, gt=gt, ge=ge, le=le)
        if form is not None:
            raise self.error(key, form, v)
        return float(v)

    def integer(self, key, v, ge=None) -> int:
        form = expected(key, v, integer=True, ge=ge)
        if form is not None:
            raise self.error(key, form, v)
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
        """A list of ``dim`` real, finite numbers, each within the key's physical range."""
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if (not isinstance(v, (list, tuple)) or len(v) != dim
                or not all(finite(x) and in_range(key, float(x)) for x in v)):
            raise self.error(key, f"a list of {dim} numbers, each " + describe(key)[2:], v)
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


def validate(d, source: str, default_name: str) -> tuple[dict, bool]:
    """Check a parsed scene; returns (keyword arguments of Scene, whether the source text
    may be kept: False when a relative STL path was resolved and the text must be re-emitted)."""
    text_ok = True
    c = _Checker(source)
    c.table("", d, TOP_KEYS)
    fmt = c.require("", d, "format")
    if type(fmt) is not int or fmt != FORMAT_VERSION:
        raise c.error("format", f"{FORMAT_VERSION} (the only scene format this version reads)", fmt)
    name = d.get("name", default_name)
    # the name is the default output folder (out/<name>): one path component, well below NAME_MAX
    if (not isinstance(name, str) or len(name) > NAME_LENGTH
            or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", name)):
        raise c.error("name", f"a name of at most {NAME_LENGTH} letters, digits, '.', '_' or '-'", name)
    dim = c.require("", d, "dim")
    if not isinstance(dim, (int, np.integer)) or isinstance(dim, bool) or dim not in CHOICES["dim"]:
        raise c.error("dim", "2 or 3", dim)
    dim = int(dim)
    dp = c.number("dp", c.require("", d, "dp"), gt=0)
    end_time = c.number("end_time", c.require("", d, "end_time"), gt=0)
    out_dt = c.number("output_interval", d.get("output_interval", end_time / 20), gt=0)
    if out_dt < end_time * 1e-8:   # else the next output time stops advancing (t + interval == t)
        raise c.error("output_interval", f"a number >= end_time * 1e-8 = {end_time * 1e-8:.6g} "
                      "(at most 10^8 frames)", out_dt)

    dom = c.table("domain", c.require("", d, "domain"), SECTION_KEYS["domain"])
    dmin = c.vector("domain.min", c.require("domain", dom, "min"), dim)
    dmax = c.vector("domain.max", c.require("domain", dom, "max"), dim)
    if not np.all(dmax > dmin):
        raise c.error("domain.max", f"every coordinate > domain.min {_vlist(dmin)}", dom["max"])
    if dp > float((dmax - dmin).min()):
        raise c.error("dp", f"a spacing <= the domain's smallest side ({float((dmax - dmin).min()):g} m)", dp)
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
    exclude = c.boolean("domain.exclude_outside", dom.get("exclude_outside", True))
    share = c.number("domain.exclude_max_share", dom.get("exclude_max_share", 1e-3), ge=0, le=1)

    physics = _physics(c, d.get("physics", {}), dim)
    dec = c.table("decomposition", d.get("decomposition", {}), SECTION_KEYS["decomposition"])
    axis = c.choice("decomposition.axis", dec.get("axis", "auto"), AXES[:dim] + ("auto",))
    ini = c.table("initial", d.get("initial", {}), SECTION_KEYS["initial"])
    hydro = c.boolean("initial.hydrostatic", ini.get("hydrostatic", False))
    jitter = c.number("initial.jitter", ini.get("jitter", 0.0), ge=0.0, le=0.25)
    lim = c.table("limits", d.get("limits", {}), SECTION_KEYS["limits"])
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
        text_ok = False   # a relative STL path: store the resolved one, loadable from anywhere
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
    if "probes" in extra or "forces" in extra:   # sampled while the run steps (sphgraph.probes)
        from . import probes
        probes.check(c, extra, dim)
    if "balance" in extra:   # load balancing (sphgraph.balance); the schedule's and flags' layers at set-up
        from .balance import check_layer
        check_layer(extra["balance"], f"{source}: balance.")

    kwargs = dict(name=name, dim=dim, dp=dp, end_time=end_time, output_interval=out_dt,
                  domain_min=dmin, domain_max=dmax, physics=physics,
                  decomposition_axis=axis, source=source, lattice_origin=origin,
                  hydrostatic=hydro, jitter=jitter, max_particles=maxp, fluid=fluid, boundary=boundary,
                  extra=extra, periodic=tuple(periodic), exclude_outside=exclude,
                  exclude_max_share=share)
    return kwargs, text_ok


def schema_keys() -> list[str]:
    """Every key a scene can hold, as a canonical dotted path (``fluid[].min``), read from
    the tables the checks themselves take their keys from -- so a key added to any of them
    is listed here, and the suite asks it for a range (sphgraph.ranges)."""
    from . import balance, motion, probes, waves
    keys = list(TOP_KEYS)
    keys += [f"{t}.{k}" for t, ks in SECTION_KEYS.items() for k in ks]
    keys += [f"physics.{k}" for k in PhysicsConfig.field_names()]
    for (group, _), ks in list(_ENTRY_KEYS.items()) + list(shapes.KEYS.items()):
        keys += [f"{group}[].{k}" for k in ks]
    keys += [f"motion[].{k}" for ks in motion.KEYS.values() for k in ks]
    keys += [f"damping[].{k}" for k in waves.DAMPING_KEYS]
    keys += [f"balance.{k}" for k in balance.KEYS]
    keys += [f"{t}.{k}" for t, ks in probes.TABLE_KEYS.items() for k in ks]
    keys += [f"{t}[].{k}" for t, ks in probes.ITEM_KEYS.items() for k in ("name",) + ks]
    return sorted(set(keys))


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
    if cfg.riemann != "none" and cfg.integrator != "symplectic":
        raise c.error("physics.riemann", '"none" with integrator = "verlet" (the Riemann term\'s pressure '
                      'jump is a diffusion of the density, which the Verlet leapfrog integrates unstably: '
                      'set integrator = "symplectic")', cfg.riemann)
    if cfg.riemann_wall != "skip" and cfg.riemann == "none":
        raise c.error("physics.riemann_wall", '"skip" with riemann = "none" (the option is what a wall does '
                      'to the Riemann term\'s pressure jump; set riemann = "zhang2017")', cfg.riemann_wall)
    if cfg.riemann_jump != "plain" and cfg.riemann == "none":
        raise c.error("physics.riemann_jump", '"plain" with riemann = "none" (the option is how the Riemann '
                      'term\'s pressure jump is formed; set riemann = "zhang2017")', cfg.riemann_jump)
    if cfg.riemann_jump != "plain" and cfg.boundary == "dbc":
        raise c.error("physics.riemann_jump", '"plain" with boundary = "dbc" (the renormalised jump keeps '
                      'mDBC walls against an impact; next to dynamic boundary particles it let a jet through '
                      'the wall, docs/validation.md: set boundary = "mdbc")', cfg.riemann_jump)
    if cfg.diffusion_time != "leapfrog" and cfg.integrator != "verlet":
        raise c.error("physics.diffusion_time", '"leapfrog" with integrator = "symplectic" (the option '
                      'is how the Verlet step advances the diffusion term)', cfg.diffusion_time)
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

