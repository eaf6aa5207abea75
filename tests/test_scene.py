"""Scene files -> validated Scene -> particles (sphgraph/scene.py, sphgraph/geometry.py)."""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from sphgraph.errors import InputError
from sphgraph.particles import FIXED, FLUID
from sphgraph.scene import EXTRA_TABLES, Scene, dumps_toml

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
EXAMPLE_FILES = ["dambreak2d", "dambreak3d", "yeh_petroff", "still_water", "spheric2"]


def dam2d(**top):
    """DualSPHysics' 2D dam break at its reference dp (as a dict)."""
    d = {"format": 1, "dim": 2, "dp": 0.01, "end_time": 1.0,
         "domain": {"min": [0.0, 0.0], "max": [4.0, 3.5]},
         "fluid": [{"type": "box", "min": [0, 0], "max": [1, 2]}],
         "boundary": [{"type": "tank", "min": [0, 0], "max": [4, 3]}]}
    d.update(top)
    return d


def write(tmp_path, d, name="case.toml") -> Path:
    p = tmp_path / name
    p.write_text(dumps_toml(d))
    return p


# --- calibration against DualSPHysics' own cases ---------------------------------------

def test_dambreak2d_count_matches_dualsphysics():
    s = Scene.from_dict(dam2d())
    assert s.count_particles() == (20_000, 1_001)
    p = s.build_particles()
    assert p.n == 21_001
    assert np.array_equal(p.id, np.arange(21_001))
    nb = 1_001
    assert np.all(p.kind[:nb] == FIXED) and np.all(p.kind[nb:] == FLUID)  # boundary first
    b = p.pos[:nb]
    assert np.count_nonzero(np.isclose(b[:, 1], 0.0)) == 401          # bottom row x = 0..4
    for x in (0.0, 4.0):                                               # side columns y = dp..3
        col = b[np.isclose(b[:, 0], x) & (b[:, 1] > 0.005)]
        assert len(col) == 300 and np.isclose(col[:, 1].max(), 3.0)
    f = p.pos[nb:]
    assert np.isclose(f[:, 0].min(), 0.01) and np.isclose(f[:, 0].max(), 1.0)
    assert np.isclose(f[:, 1].min(), 0.01) and np.isclose(f[:, 1].max(), 2.0)
    assert np.all(p.vel == 0) and np.all(p.rho == 1000.0)


def test_example_2d_at_reference_dp_and_casedambreak_counts():
    s2 = Scene.from_toml(EXAMPLES / "dambreak2d.toml").with_overrides(dp=0.01)
    assert s2.count_particles() == (20_000, 1_001)
    # DualSPHysics' CaseDambreak at its dp = 0.0085: 171,496 particles
    s3 = Scene.from_toml(EXAMPLES / "dambreak3d.toml").with_overrides(dp=0.0085)
    assert s3.count_particles() == (128_310, 43_186)


# --- examples ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", EXAMPLE_FILES)
def test_examples_load_and_build(name):
    path = EXAMPLES / f"{name}.toml"
    assert path.read_text().startswith("# ")  # first line says what it shows and how long
    s = Scene.from_toml(path)
    assert s.name == name and s.source == str(path)
    assert s.text == path.read_text()
    nf, nb = s.count_particles()
    p = s.build_particles(np.float32)
    assert p.n == nf + nb and p.n_fluid == nf and p.dim == s.dim
    assert p.rho.dtype == np.float32 and p.pos.dtype == np.float64
    assert np.all(p.pos >= s.domain_min) and np.all(p.pos <= s.domain_max)
    # one lattice: positions are origin + k*dp, no two particles share a point
    k = (p.pos - s.lattice_origin) / s.dp
    assert np.allclose(k, np.round(k), atol=1e-6)
    assert len(np.unique(np.round(k).astype(np.int64), axis=0)) == p.n
    assert s.hswl > 0 and s.constants.h > 0
    assert len(s.physics.gravity) == s.dim


def test_example_physics_as_documented():
    d3 = Scene.from_toml(EXAMPLES / "dambreak3d.toml").physics
    assert (d3.kernel, d3.coefh, d3.visc_alpha, d3.integrator) == ("cubic", 1.0, 0.1, "verlet")
    sp = Scene.from_toml(EXAMPLES / "spheric2.toml")
    assert math.isclose(sp.constants.h, 2 * sp.dp)  # h = 2 dp
    assert (sp.physics.integrator, sp.physics.diffusion) == ("symplectic", "fourtakas-full")
    d2 = Scene.from_toml(EXAMPLES / "dambreak2d.toml").physics
    assert (d2.visc_alpha, d2.diffusion, d2.verlet_euler_every) == (0.02, "fourtakas", 40)


# --- physics-facing properties ------------------------------------------------------------

def test_hswl_auto_is_fluid_height_and_feeds_c0():
    s = Scene.from_dict(dam2d())
    assert math.isclose(s.hswl, 2.0)  # rows y = 0.01..2.0: 200 layers of dp
    assert math.isclose(s.constants.c0, 20 * math.sqrt(9.81 * 2.0))
    s2 = s.with_overrides(hswl=1.5)
    assert s2.hswl == 1.5 and math.isclose(s2.constants.c0, 20 * math.sqrt(9.81 * 1.5))
    assert s2.with_overrides(hswl=None).hswl == 2.0  # None: back to auto
    assert s.physics.gravity == (0.0, -9.81)


def test_hydrostatic_initial_density():
    s = Scene.from_toml(EXAMPLES / "still_water.toml")
    assert s.hydrostatic
    p = s.build_particles()
    k, cfg = s.constants, s.physics
    fluid = p.kind == FLUID
    y = p.pos[fluid, 1]
    rho = p.rho[fluid]
    z_s = s.surface_level()
    assert math.isclose(z_s, 0.02 - 0.01 + 0.5)  # lowest row - dp/2 + hswl
    # Tait: p = B((rho/rho0)^gamma - 1) equals rho0 g depth
    pressure = k.B * ((rho / cfg.rho0) ** cfg.gamma - 1)
    assert np.allclose(pressure, cfg.rho0 * 9.81 * (z_s - y), rtol=1e-9)
    assert np.all(rho > cfg.rho0)
    # boundary particles below the surface start hydrostatic too, those above at rho0
    yb = p.pos[~fluid, 1]
    pb = k.B * ((p.rho[~fluid] / cfg.rho0) ** cfg.gamma - 1)
    assert np.allclose(pb, cfg.rho0 * 9.81 * np.maximum(z_s - yb, 0), rtol=1e-9, atol=1e-6)
    assert np.all(p.rho[~fluid][yb > z_s] == cfg.rho0)
    # density grows with depth
    order = np.argsort(y)
    assert np.all(np.diff(rho[order]) <= 1e-9)


# --- geometry rules -------------------------------------------------------------------------

def test_tank_layers_grow_outward_and_top_closes():
    d = dam2d(domain={"min": [-0.05, -0.05], "max": [4.05, 3.05], "origin": [0.0, 0.0]})
    d["boundary"][0].update(layers=3, open_top=False)
    s = Scene.from_dict(d)
    nf, nb = s.count_particles()
    assert nf == 20_000  # layers grow outward: the fluid is untouched
    assert nb == 405 * 305 - 399 * 299
    pos = s.build_particles().pos
    assert np.isclose(pos[:, 0].min(), -0.02) and np.isclose(pos[:, 1].max(), 3.02)


def test_lattice_anchors_at_domain_min_by_default():
    d = dam2d(domain={"min": [0.005, 0.005], "max": [4.5, 3.5]})
    d["fluid"][0]["min"] = [0.005, 0.005]
    d["boundary"] = []
    s = Scene.from_dict(d)
    pos = s.build_particles().pos
    assert np.isclose(pos[:, 0].min(), 0.005) and np.isclose(pos[:, 1].max(), 1.995)
    assert s.count_particles() == (100 * 200, 0)


def test_obstacles_remove_fluid_and_surface_hollow():
    base = dam2d()
    solid = copy.deepcopy(base)
    solid["boundary"].append({"type": "box", "min": [0.5, 0.0], "max": [0.7, 0.5], "fill": "solid"})
    s = Scene.from_dict(solid)
    nf, nb = s.count_particles()
    # fluid inside or on the 21 x 51 obstacle is gone; the obstacle's bottom row is the floor
    assert nf == 20_000 - 21 * 50 and nb == 1_001 + 21 * 50
    surf = copy.deepcopy(base)
    surf["boundary"].append({"type": "box", "min": [0.5, 0.0], "max": [0.7, 0.5],
                             "fill": "surface", "open_bottom": True})
    nf2, nb2 = Scene.from_dict(surf).count_particles()
    assert nf2 == nf  # a hollow obstacle still excludes fluid
    # shell without bottom (2*50 + 19 on top), minus the 19 floor points under its hollow
    assert nb2 == 1_001 + 2 * 50 + 19 - 19


def test_wall_entry():
    d = dam2d()
    d["boundary"].append({"type": "wall", "min": [2.0, 0.0], "max": [2.0, 1.0], "layers": 2,
                          "direction": "+"})
    s = Scene.from_dict(d)
    assert s.count_particles()[1] == 1_001 + 2 * 100  # y = 0 row already in the floor
    pos = s.build_particles().pos
    assert np.any(np.isclose(pos[:, 0], 2.01) & np.isclose(pos[:, 1], 1.0))


def test_overlapping_fluid_boxes_merge():
    d = dam2d()
    d["fluid"].append({"type": "box", "min": [0.5, 0.0], "max": [1.5, 1.0]})
    nf, _ = Scene.from_dict(d).count_particles()
    assert nf == 20_000 + 50 * 100


# --- overrides, serialisation ------------------------------------------------------------------

def test_with_overrides_revalidates_and_keeps_original():
    s = Scene.from_toml(EXAMPLES / "dambreak2d.toml")
    s2 = s.with_overrides(dp=0.04, end_time=0.5, visc_alpha=0.05)
    assert (s2.dp, s2.end_time, s2.physics.visc_alpha) == (0.04, 0.5, 0.05)
    assert (s.dp, s.end_time, s.physics.visc_alpha) == (0.02, 1.0, 0.02)
    assert s2.count_particles() == (25 * 50, 101 + 2 * 75)
    assert tomllib.loads(s2.text)["dp"] == 0.04  # the text records what runs
    assert s2.name == "dambreak2d" and s2.source == s.source
    with pytest.raises(InputError, match=r"dambreak2d\.toml: --dp: expected a number >= 1e-06 and <= 100 \[m\] \(a particle spacing between 1 um and 100 m\), got -1"):
        s.with_overrides(dp=-1)
    with pytest.raises(InputError, match=r"--end-time: expected a number >= 1e-09 and <= 1e\+06 \[s\]"):
        s.with_overrides(end_time=0)
    with pytest.raises(InputError, match=r"physics\.kernel: expected one of"):
        s.with_overrides(kernel="gauss")
    with pytest.raises(InputError, match=r"physics\.viscosity: expected a known key"):
        s.with_overrides(viscosity=0.1)


def test_from_dict_text_round_trip(tmp_path):
    d = dam2d(name="rt", physics={"kernel": "cubic", "coefh": 1.2},
              initial={"hydrostatic": True},
              probes={"interval": 0.01, "points": [{"name": 'a "quoted" é', "position": [0.5, 0.1]},
                                                   {"position": [1.0, 0.2]}]})
    s = Scene.from_dict(d)
    assert s.extra == {"probes": d["probes"]}
    p = tmp_path / "rt.toml"
    p.write_text(s.text)
    s2 = Scene.from_toml(p)
    a, b = s.build_particles(), s2.build_particles()
    for k in ("id", "kind", "pos", "vel", "rho"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert s2.to_dict() == s.to_dict()
    assert Scene.from_dict(s.to_dict()).to_dict() == s.to_dict()


@pytest.mark.parametrize("name", EXAMPLE_FILES)
def test_examples_round_trip_through_to_dict(name):
    s = Scene.from_toml(EXAMPLES / f"{name}.toml")
    s2 = Scene.from_dict(tomllib.loads(s.with_overrides().text))
    assert s2.count_particles() == s.count_particles()
    assert s2.to_dict() == s.to_dict()


def test_dumps_toml_plain_types():
    d = {"a": 1, "b": -2.5e-7, "c": True, "s": "x\ny\t\"z\"\\", "key with space": [1, 2],
         "inf": float("inf"), "nested": {"t": {"u": [[1, 2], [3.0]]}, "v": "w"},
         "arr": [{"x": 1, "sub": {"y": 2}}, {"x": 2}], "empty": [], "inline": [{"p": 1}, 3],
         "none": None}
    back = tomllib.loads(dumps_toml(d))
    d.pop("none")
    assert back == d


def test_extra_tables_are_validated_when_read_and_kept():
    assert set(EXTRA_TABLES) >= {"balance", "probes", "forces", "motion"}
    d = dam2d(balance={"every": 50, "smoothing": 0.5},
              forces={"bodies": [{"name": "tank", "min": [0.0, 0.0], "max": [4.0, 3.0]}]})
    s = Scene.from_dict(d)
    assert s.extra == {"balance": d["balance"], "forces": d["forces"]}
    # each feature's checks answer when the scene is read, every number by its range
    for bad, match in ((dict(balance={"every": 50, "anything": ["goes"]}), r"balance\.anything: unknown key"),
                       (dict(balance={"every": 10 ** 400}), r"balance\.every: expected an integer >= 1"),
                       (dict(forces=[{"body": 1}]), r": forces: expected a table"),
                       (dict(probes={"interval": 1e300}), r"probes\.interval: expected a number >= 0"),
                       (dict(motion=[{"body": 1}]), r"motion\[0\]\.type")):
        with pytest.raises(InputError, match=match):
            Scene.from_dict(dam2d(**bad))


def test_default_name_and_output_interval(tmp_path):
    s = Scene.from_toml(write(tmp_path, dam2d(), "my_case.toml"))
    assert s.name == "my_case" and s.output_interval == pytest.approx(0.05)
    assert Scene.from_dict(dam2d()).name == "scene"


def test_particle_limit_refuses_before_allocating():
    with pytest.raises(InputError, match=r"limits\.max_particles: expected an estimated particle count <= 1000"):
        Scene.from_dict(dam2d(limits={"max_particles": 1000}))
    # a tiny --dp is refused from box sizes alone (4e12 points are never generated)
    s = Scene.from_toml(EXAMPLES / "dambreak2d.toml")
    with pytest.raises(InputError, match=r"limits\.max_particles"):
        s.with_overrides(dp=1e-6)


# --- bad input: one line naming the file and the key ------------------------------------------

def _set(path, value):
    """A mutation of dam2d() setting a dotted path ('fluid.0.max') to value (None deletes)."""
    def f(d):
        *head, last = path.split(".")
        t = d
        for k in head:
            t = t[int(k)] if isinstance(t, list) else t.setdefault(k, {})
        if isinstance(t, list):
            t[int(last)] = value
        elif value is None:
            del t[last]
        else:
            t[last] = value
    return f


BAD = [
    ("format missing", _set("format", None), "format", "expected 1"),
    ("format 2", _set("format", 2), "format", "got 2"),
    ("unknown top key", _set("dq", 0.1), "dq", "one of: format, name"),
    ("dim 4", _set("dim", 4), "dim", "expected 2 or 3"),
    ("dim float", _set("dim", 2.0), "dim", "got 2.0"),
    ("format float", _set("format", 1.0), "format", "got 1.0"),
    ("dp bool", _set("dp", True), "dp", "got True"),
    ("dp string", _set("dp", "0.01"), "dp", "a number >= 1e-06 and <= 100 [m]"),
    ("dp zero", _set("dp", 0), "dp", "got 0"),
    ("dp missing", _set("dp", None), "dp", "got nothing"),
    ("end_time negative", _set("end_time", -1.0), "end_time", "a number >= 1e-09 and <= 1e+06 [s]"),
    ("output_interval 0", _set("output_interval", 0), "output_interval", "a number >= 1e-12"),
    ("name with slash", _set("name", "a/b"), "name", "a name of at most 128 letters"),
    ("domain min length", _set("domain.min", [0, 0, 0]), "domain.min", "a list of 2 numbers"),
    ("domain min >= max", _set("domain.max", [4.0, -1.0]), "domain.max", "every coordinate > domain.min"),
    ("domain unknown", _set("domain.size", [1, 1]), "domain.size", "one of: min, max, origin"),
    ("fluid max length", _set("fluid.0.max", [1.0]), "fluid[0].max", "a list of 2 numbers"),
    ("fluid min >= max", _set("fluid.0.max", [1.0, 0.0]), "fluid[0].max", "every coordinate > fluid[0].min"),
    ("fluid outside domain", _set("fluid.0.max", [5.0, 2.0]), "fluid[0].max", "inside the domain"),
    ("fluid below domain", _set("fluid.0.min", [-1.0, 0.0]), "fluid[0].min", "inside the domain"),
    ("fluid type", _set("fluid.0.type", "sphere"), "fluid[0].type", 'one of "box"'),
    ("fluid unknown key", _set("fluid.0.fill", "solid"), "fluid[0].fill", "one of: type, min, max"),
    ("fluid missing", _set("fluid", None), "fluid", "at least one [[fluid]]"),
    ("fluid not array", _set("fluid", {"type": "box"}), "fluid", "an array of tables"),
    ("boundary type", _set("boundary.0.type", "sphere"), "boundary[0].type", '"tank", "box", "wall"'),
    ("tank layers 0", _set("boundary.0.layers", 0), "boundary[0].layers", "an integer >= 1"),
    ("tank layers float", _set("boundary.0.layers", 1.5), "boundary[0].layers", "an integer"),
    ("tank open_top int", _set("boundary.0.open_top", 1), "boundary[0].open_top", "true or false"),
    ("tank outside domain", _set("boundary.0.layers", 2), "boundary[0]", "inside the domain"),
    ("box fill", _set("boundary.0", {"type": "box", "min": [2, 0], "max": [3, 1], "fill": "hollow"}),
     "boundary[0].fill", '"solid", "surface"'),
    ("solid with layers", _set("boundary.0", {"type": "box", "min": [2, 0], "max": [3, 1], "layers": 2}),
     "boundary[0].layers", "fill = \"solid\""),
    ("wall not flat", _set("boundary.0", {"type": "wall", "min": [2, 0], "max": [3, 1]}),
     "boundary[0].max", "max == min on exactly one axis"),
    ("physics unknown", _set("physics.kernal", "cubic"), "physics.kernal", "one of: kernel, coefh"),
    ("kernel enum", _set("physics.kernel", "gauss"), "physics.kernel", '"wendland", "cubic"'),
    ("diffusion enum", _set("physics.diffusion", "full"), "physics.diffusion", '"fourtakas-full"'),
    ("integrator enum", _set("physics.integrator", "euler"), "physics.integrator", '"verlet", "symplectic"'),
    ("cell_size enum", _set("physics.cell_size", "3h"), "physics.cell_size", '"2h", "h"'),
    ("coefh negative", _set("physics.coefh", -1.0), "physics.coefh", "a number >= 0.1 and <= 10"),
    ("visc negative", _set("physics.visc_alpha", -0.1), "physics.visc_alpha", "a number >= 0"),
    ("cfl > 10", _set("physics.cfl", 20.0), "physics.cfl", "<= 10"),
    ("verlet every 0", _set("physics.verlet_euler_every", 0), "physics.verlet_euler_every", ">= 1"),
    ("gravity length", _set("physics.gravity", [0, 0, -9.81]), "physics.gravity", "a list of 2 numbers"),
    ("rho bounds", _set("physics.rho_max", 600.0), "physics.rho_max", "> physics.rho_min"),
    ("hswl zero", _set("physics.hswl", 0.0), "physics.hswl", "a number >= 1e-06 and <= 12000 [m]"),
    ("axis z in 2D", _set("decomposition.axis", "z"), "decomposition.axis", '"x", "y", "auto"'),
    ("hydrostatic str", _set("initial.hydrostatic", "yes"), "initial.hydrostatic", "true or false"),
    ("limits unknown", _set("limits.max_memory", 1), "limits.max_memory", "one of: max_particles"),
    ("no fluid particles", _set("fluid.0", {"type": "box", "min": [0.001, 0.001], "max": [0.009, 0.009]}),
     "fluid", "lattice points"),
    ("fluid all on walls", _set("fluid.0", {"type": "box", "min": [0.0, 0.0], "max": [4.0, 0.001]}),
     "fluid", "at least one fluid particle"),
    ("fluid all in obstacle", _set("boundary.0", {"type": "box", "min": [0, 0], "max": [1.5, 2.5]}),
     "fluid", "at least one fluid particle"),
]


@pytest.mark.parametrize("label, mutate, key, expected", BAD, ids=[b[0] for b in BAD])
def test_bad_input_names_file_and_key(tmp_path, label, mutate, key, expected):
    d = dam2d()
    mutate(d)
    path = write(tmp_path, d)
    with pytest.raises(InputError) as ei:
        Scene.from_toml(path).count_particles()  # the emptiness check needs the lattice
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: ")
    assert f": {key}: expected" in msg
    assert expected in msg


def test_malformed_toml_and_missing_file(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text("format = 1\ndim = = 2\n")
    with pytest.raises(InputError, match=r"broken\.toml: TOML syntax: expected valid TOML, got .*line 2"):
        Scene.from_toml(p)
    with pytest.raises(InputError, match=r"nope\.toml: file: expected a readable"):
        Scene.from_toml(tmp_path / "nope.toml")


def test_from_dict_accepts_numpy_values():
    d = dam2d(dp=np.float64(0.01), domain={"min": np.zeros(2), "max": np.array([4.0, 3.5])})
    d["boundary"][0]["layers"] = np.int64(1)
    s = Scene.from_dict(d)
    assert s.count_particles() == (20_000, 1_001)
    assert "np." not in s.text and tomllib.loads(s.text)["dp"] == 0.01


def test_from_dict_errors_name_the_source():
    with pytest.raises(InputError, match=r"^<dict>: dim: expected 2 or 3, got 1$"):
        Scene.from_dict(dam2d(dim=1))
    with pytest.raises(InputError, match=r"^cli-scene: dp:"):
        Scene.from_dict(dam2d(dp=-1), source="cli-scene")


def test_every_key_is_documented():
    from sphgraph.config import PhysicsConfig
    from sphgraph.scene import _ENTRY_KEYS, TOP_KEYS
    doc = (Path(__file__).resolve().parents[1] / "docs" / "scenes.md").read_text()
    keys = set(TOP_KEYS) | set(PhysicsConfig.field_names()) | {k for v in _ENTRY_KEYS.values() for k in v}
    keys |= {"origin", "axis", "hydrostatic", "max_particles"}
    missing = sorted(k for k in keys if f"`{k}`" not in doc and f"[{k}]" not in doc and f"[[{k}]]" not in doc)
    assert not missing, f"docs/scenes.md lacks {missing}"
