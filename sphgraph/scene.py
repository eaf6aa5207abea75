"""Scenes: a TOML file (or dict) -> a validated :class:`Scene` -> particles.

A scene says what to simulate: resolution ``dp``, run length, the domain the
particles must stay in, the physics options (:class:`~sphgraph.config.PhysicsConfig`)
and the geometry -- ``[[fluid]]`` boxes and ``[[boundary]]`` tanks, obstacles and
walls -- all on one lattice (see :mod:`sphgraph.geometry`). Every key is
documented in ``docs/scenes.md``.

Three modules by concern: :mod:`sphgraph.scene_schema` checks every key (each
number against :mod:`sphgraph.ranges`), :mod:`sphgraph.scene_particles` turns the
geometry into particles, :mod:`sphgraph.toml_writer` writes the TOML text stored in
output files. Validation happens once, in :meth:`Scene.from_dict` (which
:meth:`Scene.from_toml` and :meth:`Scene.with_overrides` go through).

Axes: 2D scenes use (x, y) with y vertical; 3D scenes (x, y, z) with z vertical.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import PhysicsConfig, derive
from .files import SCENE_LIMIT, parse_toml, read_text
from .scene_particles import SceneParticles
from .scene_schema import (_ENTRY_KEYS, AXES, BOUNDARY_TYPES, BOX_FILLS, DEFAULT_MAX_PARTICLES,  # noqa: F401
                           EXTRA_TABLES, FLUID_TYPES, FORMAT_VERSION, TOP_KEYS, _Checker, _vlist, validate)
from .toml_writer import dumps_toml  # noqa: F401 - part of this module's API

# --- the scene ------------------------------------------------------------------------

@dataclass(eq=False)
class Scene(SceneParticles):
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
    exclude_outside: bool = True    # particles leaving the domain / density bounds are excluded
    exclude_max_share: float = 1e-3  # ... until they pass this share of the fluid particles
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
        text = read_text(path, SCENE_LIMIT, "scene file")
        d = parse_toml(text, path, "TOML syntax")
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
        kwargs, text_ok = validate(d, source, default_name)
        scene = cls(text="", **kwargs)
        scene._check_extent(_Checker(source))
        scene.text = text if text is not None and text_ok else (
            f"# sphgraph scene, emitted from {source}\n" + dumps_toml(scene.to_dict()))
        return scene

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
        d["domain"]["exclude_outside"] = bool(self.exclude_outside)
        d["domain"]["exclude_max_share"] = float(self.exclude_max_share)
        d.update(copy.deepcopy(self.extra))
        return d

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

