"""Hostile input (issue 24 §1): every number in range before arithmetic, bounded file reads,
the output folder checked first, flags that do not apply refused, the GPU check, STL meshes,
SIGINT. Each bad input is exit 2 with one line naming file, key and expected form."""
from __future__ import annotations

import copy
import dataclasses
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sphgraph.cli import main
from sphgraph.config import PhysicsConfig
from sphgraph.errors import InputError
from sphgraph.ranges import CHOICES, FLAG_RANGES, RANGES, canonical
from sphgraph.scene import Scene
from sphgraph.scene_schema import _PHYS_CHOICES, FORMAT_VERSION, schema_keys
from sphgraph.toml_writer import dumps_toml

ROOT = Path(__file__).resolve().parents[1]
BASE = {
    "format": 1, "name": "lim", "dim": 2, "dp": 0.05, "end_time": 0.01,
    "domain": {"min": [0.0, 0.0], "max": [1.0, 1.0]},
    "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.3, 0.4]}],
    "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8]}],
}


def cli(capsys, argv):
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, err.strip().splitlines()


def scene_file(tmp_path, d=None, text=None, name="s.toml"):
    p = tmp_path / name
    p.write_text(text if text is not None else dumps_toml(d))
    return p


def one_error(capsys, argv, *needles):
    rc, lines = cli(capsys, argv)
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("sphgraph: error: "), lines
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------------------ the table
def test_docs_table_lists_every_range():
    text = (ROOT / "docs" / "scenes.md").read_text()
    section = text[text.index("## Ranges of numbers"):text.index("## Examples")]
    listed = re.findall(r"^\| `([^`]+)` \|", section, re.M)
    assert sorted(listed) == sorted(list(RANGES) + list(FLAG_RANGES))
    assert len(listed) == len(set(listed))


def test_every_numeric_physics_option_has_a_range():
    for f in dataclasses.fields(PhysicsConfig):
        if f.type in ("float", "int", "tuple | None", "float | None") or isinstance(f.default, (int, float)) \
                and not isinstance(f.default, bool):
            assert f"physics.{f.name}" in RANGES, f.name


# keys of the schema that hold no number (names, choices, booleans, paths, tables): every
# other key needs a row of sphgraph.ranges (or CHOICES), so adding a key to any of the
# schema's tables without a range fails test_every_schema_key_has_a_range
NOT_NUMBERS = {
    "name", "domain", "domain.periodic", "domain.exclude_outside", "physics", "decomposition",
    "decomposition.axis", "initial", "initial.hydrostatic", "limits", "fluid", "boundary",
    "fluid[].type", "fluid[].path", "boundary[].type", "boundary[].name", "boundary[].path",
    "boundary[].fill", "boundary[].open_top", "boundary[].open_bottom", "boundary[].direction",
    "motion", "motion[].body", "motion[].type", "motion[].direction", "damping", "damping[].axis",
    "balance", "balance.enabled", "balance.policy", "balance.base",
    "probes", "probes.points", "probes.points[].name", "probes.heights", "probes.heights[].name",
    "forces", "forces.bodies", "forces.bodies[].name",
} | {f"physics.{k}" for k in _PHYS_CHOICES} | {
    f"physics.{f.name}" for f in dataclasses.fields(PhysicsConfig) if isinstance(f.default, bool)}


def test_every_schema_key_has_a_range():
    """Every key a scene can hold (read from the tables the checks take their keys from) is a
    number with a row in sphgraph.ranges, an integer choice, or no number; and every row is
    a key of the schema."""
    keys = schema_keys()
    missing = [k for k in keys if k not in RANGES and k + "[]" not in RANGES and k not in CHOICES
               and k not in NOT_NUMBERS]
    assert not missing, f"no range in sphgraph.ranges for {missing}"
    stale = [k for k in list(RANGES) + list(CHOICES) + sorted(NOT_NUMBERS)
             if k not in keys and k.removesuffix("[]") not in keys]
    assert not stale, f"rows for keys no scene can hold: {stale}"
    assert CHOICES["format"] == (FORMAT_VERSION,)


def _cube_stl(path):
    from sphgraph.stl import write_stl
    write_stl(path, _cube())


def _full_scenes(tmp_path):
    """Scenes that hold every key of sphgraph.ranges at least once (every motion type, shape,
    feature table), valid as they stand."""
    _cube_stl(tmp_path / "m.stl")
    full2d = {
        "format": 1, "name": "full", "dim": 2, "dp": 0.05, "end_time": 0.02, "output_interval": 0.01,
        "domain": {"min": [-0.3, -0.2], "max": [3.0, 1.2], "origin": [0.0, 0.0], "exclude_max_share": 1e-3},
        "physics": {"coefh": 1.0, "coefsound": 20.0, "gamma": 7.0, "rho0": 1000.0, "gravity": [0.0, -9.81],
                    "visc_alpha": 0.01, "visc_bound_factor": 1.0, "laminar_nu": 0.0, "delta": 0.1,
                    "verlet_euler_every": 40, "cfl": 0.2, "hswl": 0.3, "rho_min": 700.0, "rho_max": 1300.0,
                    "shifting_coef": -2.0, "shifting_tfs": 1.5, "riemann_eta": 3.0},
        "initial": {"jitter": 0.0}, "limits": {"max_particles": 100000},
        "fluid": [{"type": "box", "min": [0.1, 0.0], "max": [1.9, 0.3]},
                  {"type": "cylinder", "center": [1.0, 0.6], "radius": 0.1}],
        "boundary": [{"type": "tank", "min": [-0.25, 0.0], "max": [2.8, 1.0], "layers": 1},
                     {"type": "wall", "name": "paddle", "min": [0.05, 0.05], "max": [0.05, 0.5]},
                     {"type": "wall", "name": "flap", "min": [2.6, 0.05], "max": [2.6, 0.5]},
                     {"type": "wall", "name": "gate", "min": [2.3, 0.0], "max": [2.3, 0.4]},
                     {"type": "box", "name": "block", "min": [1.4, 0.45], "max": [1.6, 0.55]},
                     {"type": "cylinder", "name": "rotor", "center": [0.6, 0.7], "radius": 0.08},
                     {"type": "slope", "start": [1.6, 0.0], "end": [2.0, 0.2], "layers": 2},
                     {"type": "slope", "start": [2.0, 0.0], "angle": 10.0, "length": 0.2}],
        "motion": [{"body": "paddle", "type": "piston", "height": 0.02, "period": 1.0, "depth": 0.3,
                    "ramp": 1.0, "phase": 0.0, "start": 0.0},
                   {"body": "block", "type": "rectilinear", "times": [0.0, 0.01],
                    "velocity": [[0.0, 0.0], [0.1, 0.0]]},
                   {"body": "rotor", "type": "rotation", "times": [0.0, 0.01], "omega": [0.0, 1.0],
                    "center": [0.6, 0.7]},
                   {"body": "gate", "type": "gate", "speed": 1.0, "lift": 0.5, "start": 0.0},
                   {"body": "flap", "type": "flap", "height": 0.02, "period": 1.0, "hinge": [2.6, 0.0]}],
        "damping": [{"axis": "x", "start": 1.4, "end": 1.9, "redumax": 10.0, "overlimit": 1.0}],
        "probes": {"interval": 0.005, "points": [{"name": "P1", "position": [0.5, 0.1]}],
                   "heights": [{"name": "H1", "position": [1.0]}]},
        "forces": {"interval": 0.0, "bodies": [{"name": "rotor", "min": [0.4, 0.4], "max": [0.8, 0.8]}]},
        "balance": {"every": 50, "threshold": 0.03, "max_particles_per_rank": 10000, "smoothing": 0.5},
    }
    full3d = {
        "format": 1, "name": "full3", "dim": 3, "dp": 0.1, "end_time": 0.01,
        "domain": {"min": [-0.3, -0.3, -0.3], "max": [1.3, 1.3, 1.3]},
        "fluid": [{"type": "cylinder", "center": [0.2, 0.2, 0.0], "radius": 0.1, "length": 0.3,
                   "axis": [0.0, 0.0, 1.0]},
                  {"type": "stl", "path": "m.stl", "scale": 1.0, "offset": [0.0, 0.0, 0.2]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.8]},
                     {"type": "cylinder", "name": "leg", "center": [0.7, 0.5, 0.0], "radius": 0.1,
                      "length": 0.5, "axis": [0.0, 0.0, 1.0]},
                     {"type": "slope", "start": [0.6, 0.0, 0.0], "angle": 20.0, "length": 0.35, "width": 1.0},
                     {"type": "stl", "name": "hull", "path": "m.stl", "scale": 0.5, "offset": [0.3, 0.3, 0.3]}],
        "motion": [{"body": "leg", "type": "rotation", "times": [0.0], "omega": [0.5], "center": [0.7, 0.5, 0.0],
                    "axis": [0.0, 0.0, 1.0]}],
    }
    return {"full2d": full2d, "full3d": full3d}


def _number_paths(v, path):
    """(concrete key, value) of every number or vector of a scene whose key has a range."""
    if canonical(path) in RANGES:
        yield path, v
    elif isinstance(v, dict):
        for k, x in v.items():
            yield from _number_paths(x, f"{path}.{k}" if path else k)
    elif isinstance(v, list):
        for i, x in enumerate(v):
            yield from _number_paths(x, f"{path}[{i}]")


def _set_path(d, path, value):
    """d with the value at `path` (``motion[1].velocity[0]``) replaced."""
    parts = [int(p) if p.isdigit() else p for p in re.findall(r"[^.\[\]]+", path)]
    parent = d
    for p in parts[:-1]:
        parent = parent[p]
    parent[parts[-1]] = value


def test_every_range_is_enforced_when_the_scene_is_read(tmp_path):
    """Each key of sphgraph.ranges, in a scene that holds it: nan, and a value beyond either end
    of its range, is one line naming the key -- checked when the scene is read, before any
    arithmetic on it (a key no full scene holds fails the test: add it to _full_scenes)."""
    scenes = _full_scenes(tmp_path)
    source = str(tmp_path / "s.toml")
    for name, d in scenes.items():
        Scene.from_dict(copy.deepcopy(d), source=source)   # valid as they stand
    seen = set()
    for name, d in scenes.items():
        for path, v in _number_paths(d, ""):
            key = canonical(path)
            seen.add(key)
            lo, hi, _, _ = RANGES[key]
            for bad in (math.nan, hi + max(1, abs(hi)), lo - max(1, abs(lo))):
                e = copy.deepcopy(d)
                _set_path(e, path, [bad] + list(v[1:]) if isinstance(v, list) else bad)
                with pytest.raises(InputError) as err:
                    Scene.from_dict(e, source=source)
                msg = str(err.value)
                assert f"{source}: {path}: expected " in msg and ", got " in msg and "\n" not in msg, \
                    (name, path, bad, msg)
    assert seen == set(RANGES), f"no full scene holds {sorted(set(RANGES) - seen)}"


def _all_scenes():
    paths = sorted((ROOT / "examples").glob("*.toml"))
    paths += sorted((ROOT / "sphgraph" / "validation" / "cases").glob("*.toml"))
    return [p for p in paths if "format = 1" in p.read_text() and "[[fluid]]" in p.read_text()]


@pytest.mark.parametrize("path", _all_scenes(), ids=lambda p: p.stem)
def test_every_key_the_checker_meets_has_a_range(path):
    """A number without a row in sphgraph.ranges raises LookupError (an internal error): every
    shipped scene, with every feature they use (shapes, motion, damping), validates."""
    Scene.from_toml(path)


def test_feature_scenes_of_the_fuzzer_validate():
    sys.path.insert(0, str(ROOT / "tests"))
    from test_fuzz import FEATURE_BASES
    for name, d in FEATURE_BASES.items():
        Scene.from_dict(copy.deepcopy(d), source=f"<{name}>")


# ------------------------------------------------------------------------------ numbers
@pytest.mark.parametrize("patch,key", [
    ({"physics": {"coefh": 1e308}}, "physics.coefh"),
    ({"physics": {"coefh": 1e-300}}, "physics.coefh"),
    ({"physics": {"coefsound": 5e-324}}, "physics.coefsound"),
    ({"physics": {"coefsound": 2 ** 63}}, "physics.coefsound"),
    ({"physics": {"gravity": [0.0, -1e30]}}, "physics.gravity"),
    ({"physics": {"hswl": 1e300}}, "physics.hswl"),
    ({"physics": {"rho0": float("nan")}}, "physics.rho0"),
    ({"physics": {"verlet_euler_every": 10 ** 30}}, "physics.verlet_euler_every"),
    ({"boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8], "layers": 10 ** 6}]},
     "boundary[0].layers"),
    ({"domain": {"min": [0.0, 0.0], "max": [1e300, 1.0]}}, "domain.max"),
    ({"dp": 2.0}, "dp"),                         # larger than the domain's smallest side
    ({"name": "n" * 5000}, "name"),
])
def test_numbers_out_of_range_are_one_line(tmp_path, capsys, patch, key):
    d = copy.deepcopy(BASE)
    d.update(patch)
    line = one_error(capsys, ["run", scene_file(tmp_path, d), "--out", tmp_path / "o"], f": {key}: expected")
    assert len(line) < 400
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("key,value", [("threshold", float("nan")), ("threshold", 1e300),
                                       ("every", 10 ** 12), ("every", 0)])
def test_a_schedules_rebalance_numbers_have_the_balance_ranges(tmp_path, capsys, key, value):
    """The schedule's [rebalance] shares the rows balance.* of sphgraph.ranges (nan passed `v < 0`)."""
    import tomllib
    from importlib import resources
    d = tomllib.loads(resources.files("sphgraph.schedules").joinpath("production.toml").read_text())
    d.setdefault("rebalance", {})[key] = value
    sched = tmp_path / "sched.toml"
    sched.write_text(dumps_toml(d))
    one_error(capsys, ["run", scene_file(tmp_path, BASE), "--schedule", sched, "--out", tmp_path / "o"],
              f"sched.toml: rebalance.{key}: expected ", "(a balance check" if key == "every" else "(the drop")


def test_a_400_digit_dp_is_refused(tmp_path, capsys):
    text = dumps_toml(BASE).replace("dp = 0.05", "dp = 1" + "0" * 400)
    one_error(capsys, ["run", scene_file(tmp_path, text=text), "--out", tmp_path / "o"], ": dp: expected a number")


# ------------------------------------------------------------------------------ files
@pytest.mark.parametrize("what", ["scene", "schedule", "stl"])
def test_dev_zero_is_refused_before_reading(tmp_path, capsys, what):
    d = copy.deepcopy(BASE)
    argv = ["run", scene_file(tmp_path, d), "--out", tmp_path / "o"]
    if what == "scene":
        argv[1] = "/dev/zero"
    elif what == "schedule":
        argv += ["--schedule", "/dev/zero"]
    else:
        d.update(dim=3, domain={"min": [0.0] * 3, "max": [1.0] * 3},
                 fluid=[{"type": "box", "min": [0.0] * 3, "max": [0.3] * 3}], boundary=[])
        d["boundary"] = [{"type": "stl", "path": "/dev/zero"}]
        argv[1] = scene_file(tmp_path, d)
    t0 = time.perf_counter()
    one_error(capsys, argv, "expected a regular", "character device")
    assert time.perf_counter() - t0 < 5


def test_a_fifo_scene_does_not_block(tmp_path, capsys):
    fifo = tmp_path / "s.toml"
    os.mkfifo(fifo)
    one_error(capsys, ["run", fifo, "--out", tmp_path / "o"], "FIFO")


def test_toml_nested_5000_deep_and_binary_files(tmp_path, capsys):
    deep = "format = 1\nx = " + "[" * 5000 + "]" * 5000 + "\n"
    one_error(capsys, ["run", scene_file(tmp_path, text=deep), "--out", tmp_path / "o"], "nested")
    mid = "format = 1\nx = " + "[" * 40 + "]" * 40 + "\n"     # parses, then refused by depth
    one_error(capsys, ["run", scene_file(tmp_path, text=mid, name="m.toml"), "--out", tmp_path / "o"], "nested")
    binary = tmp_path / "b.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    one_error(capsys, ["run", scene_file(tmp_path, BASE), "--schedule", binary, "--out", tmp_path / "o"],
              "expected a UTF-8 schedule file")
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:
        f.truncate(5 << 20)
    one_error(capsys, ["run", big, "--out", tmp_path / "o"], "at most 4194304 bytes")


def test_a_checkpoint_damaged_inside_is_refused_in_one_line(tmp_path, capsys):
    """Bytes flipped in a checkpoint's HDF5 metadata: h5py's RuntimeError (a failed metadata
    checksum) was an internal error, exit 3; now the damaged checkpoint is skipped, exit 2."""
    s, run = scene_file(tmp_path, BASE), tmp_path / "run"
    rc, _ = cli(capsys, ["run", s, "--out", run, "--max-steps", "10", "--checkpoint-every", "10", "--quiet"])
    ckpt = next((run / "checkpoints").glob("ckpt_*.h5"))
    data = bytearray(ckpt.read_bytes())
    for k in range(8):             # bytes at odd sixteenths: an attribute's metadata among them
        data[len(data) * (2 * k + 1) // 16] ^= 0xFF
    ckpt.write_bytes(bytes(data))
    rc, lines = cli(capsys, ["run", s, "--restart", run, "--quiet"])
    lines = [ln for ln in lines if not ln.startswith("sphgraph: warning:")]
    assert rc == 2 and len(lines) == 1 and "expected a valid checkpoint" in lines[0], (rc, lines)


# ------------------------------------------------------------------------------ output folder
def test_output_folder_checked_before_any_work(tmp_path, capsys):
    s = scene_file(tmp_path, BASE)
    one_error(capsys, ["run", s, "--out", ""], "--out: expected an output folder path")
    (tmp_path / "f").write_text("x")
    one_error(capsys, ["run", s, "--out", tmp_path / "f" / "o"], "under the file")
    one_error(capsys, ["run", s, "--out", tmp_path / "f"], "expected a folder")
    one_error(capsys, ["run", s, "--out", tmp_path / ("n" * 300)], "at most 255 bytes")
    if os.path.isdir("/proc/self"):
        one_error(capsys, ["run", s, "--out", "/proc/self/sphgraph-out"], "can be created")
    assert sorted(os.listdir(tmp_path)) == ["f", "s.toml"]   # no probe folder left


# ------------------------------------------------------------------------------ flags
@pytest.mark.parametrize("flags,needle", [
    (["--seed", "-1", "--comm", "mock", "--ranks", "2"], "--seed: expected an integer >= 0"),
    (["--loss", "0.1"], "--loss: expected --comm mock"),
    (["--duplicate", "0.1", "--comm", "mpi"], "--duplicate: expected --comm mock"),
    (["--ranks", "2"], "--ranks 2: expected 1 with --comm single"),
    (["--watchdog", "5"], "--watchdog: expected --comm mock or --comm mpi"),
    (["--ranks", "1000000", "--comm", "mock"], "--ranks: expected an integer >= 1 and <= 4096"),
    (["--ranks", "500", "--comm", "mock"], "expected at most"),
    (["--loss", "nan", "--comm", "mock", "--ranks", "2"], "--loss: expected a number >= 0"),
    (["--max-steps", "0"], "--max-steps: expected an integer >= 1"),
    (["--dp", "inf"], "--dp: expected a number >= 1e-06"),
])
def test_flags_that_do_not_apply_or_are_out_of_range(tmp_path, capsys, flags, needle):
    t0 = time.perf_counter()
    one_error(capsys, ["run", scene_file(tmp_path, BASE), "--out", tmp_path / "o", *flags], needle)
    assert time.perf_counter() - t0 < 5
    assert not (tmp_path / "o").exists()


def test_ranks_1_with_comm_single_runs(tmp_path, capsys):
    rc, lines = cli(capsys, ["run", scene_file(tmp_path, BASE), "--out", tmp_path / "o", "--ranks", "1",
                             "--comm", "single", "--max-steps", "1", "--quiet"])
    assert rc == 0, lines


def test_no_gpu_is_one_line_within_a_second(tmp_path):
    """On a machine without a GPU (the CI's), `--backend numba-cuda` is refused by the backend's
    declared capability check at start-up, without initialising CUDA."""
    from numba import cuda
    if cuda.is_available() or os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        pytest.skip("a GPU (or the simulator) is here: the backend can run")
    s = scene_file(tmp_path, BASE)
    cmd = [sys.executable, "-m", "sphgraph", "run", str(s), "--backend", "numba-cuda", "--out", str(tmp_path / "o")]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "--backend numba-cuda: expected a machine" in lines[0], p.stderr
    assert not (tmp_path / "o").exists()
    from sphgraph.errors import InputError
    from sphgraph.preflight import check_backend
    t0 = time.perf_counter()
    with pytest.raises(InputError):
        check_backend("numba-cuda")   # the module is imported: the check itself
    assert time.perf_counter() - t0 < 1.0


# ------------------------------------------------------------------------------ STL
def _cube():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    f = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5),
         (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    return v[np.array(f)] * 0.3 + 0.3


def _stl_scene(tmp_path, tris):
    from sphgraph.stl import write_stl
    with np.errstate(all="ignore"):   # the normals of a hostile mesh (the reader ignores them)
        write_stl(tmp_path / "m.stl", tris)
    d = copy.deepcopy(BASE)
    d.update(dim=3, domain={"min": [0.0] * 3, "max": [1.0] * 3},
             fluid=[{"type": "box", "min": [0.0] * 3, "max": [0.2] * 3}],
             boundary=[{"type": "stl", "path": "m.stl"}])
    return scene_file(tmp_path, d)


def test_stl_with_inf_vertices_is_one_line_without_numpy_warnings(tmp_path, capfd):
    tris = _cube()
    tris[3, 1, 2] = np.inf
    s = _stl_scene(tmp_path, tris)
    capfd.readouterr()
    rc = main(["run", str(s), "--out", str(tmp_path / "o")])
    err = capfd.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "non-finite coordinates" in err[0], err


def test_stl_of_degenerate_triangles_is_refused(tmp_path, capsys):
    tris = _cube()
    flat = tris.copy()
    flat[..., 2] = 0.3            # every vertex in one plane: combinatorially closed, no area inside
    one_error(capsys, ["run", _stl_scene(tmp_path, flat), "--out", tmp_path / "o"], "enclosing")
    a, b, c, e = ([x, 0.5, 0.5] for x in (0.3, 0.4, 0.5, 0.6))   # a tetrahedron on one line
    line = np.array([[a, b, c], [a, e, b], [a, c, e], [b, e, c]], float)   # closed, zero area
    (tmp_path / "m.stl").unlink()
    one_error(capsys, ["run", _stl_scene(tmp_path, line), "--out", tmp_path / "o"], "zero area")
    (tmp_path / "m.stl").unlink()
    rc, lines = cli(capsys, ["run", _stl_scene(tmp_path, tris), "--out", tmp_path / "ok", "--max-steps", "1",
                             "--quiet"])
    assert rc in (0, 1), lines   # the closed cube itself is accepted (and runs; the water may leave)


# ------------------------------------------------------------------------------ SIGINT
def _sigint_run(tmp_path, cmd, after, blocked):
    """Start `cmd` on a 5 s run, SIGINT it `after` seconds later: (exit code, stderr)."""
    d = copy.deepcopy(BASE)
    d.update(end_time=5.0, dp=0.02)
    s = scene_file(tmp_path, d)
    out = tmp_path / "o"
    p = subprocess.Popen([*cmd, "run", str(s), "--out", str(out), "--quiet"], stderr=subprocess.PIPE,
                         stdout=subprocess.DEVNULL, text=True,
                         preexec_fn=(lambda: signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}))
                         if blocked else None)
    time.sleep(after)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    if (out / "frames").exists():
        assert not [n for n in os.listdir(out / "frames") if n.endswith(".tmp")]
    return p.returncode, err


def _entries():
    script = Path(sys.executable).with_name("sphgraph")   # the console script of this environment
    return {"module": [sys.executable, "-m", "sphgraph"], "script": [str(script)] if script.exists() else None}


@pytest.mark.parametrize("entry", ["module", "script"])
@pytest.mark.parametrize("after", [0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.2, 2.0])
def test_sigint_from_the_start_is_130_and_one_line(tmp_path, entry, after):
    """SIGINT 0.02-2 s after the start -- the package's first line, imports, scene and
    compilation, stepping -- through both entries: exit 130 and one line, no traceback.

    The child starts as a launcher would start it to keep the contract over the
    interpreter's own start-up (site's .pth files, runpy, before any project code, where
    no handler can exist yet): with SIGINT blocked across exec. The package's first line
    installs the handler and unblocks SIGINT, so a signal sent before it is delivered
    there, and every one after it arrives as usual."""
    cmd = _entries()[entry]
    if cmd is None:
        pytest.skip("no console script next to this interpreter")
    rc, err = _sigint_run(tmp_path, cmd, after, blocked=True)
    lines = err.strip().splitlines()
    assert rc == 130 and len(lines) == 1 and "interrupted (SIGINT)" in lines[0] and "Traceback" not in err, \
        (rc, err)


@pytest.mark.parametrize("after", [0.4, 0.8, 2.5])   # earlier: the interpreter's own start-up
def test_sigint_at_any_moment_is_130_and_one_line(tmp_path, after):
    """Started plainly (SIGINT not blocked): once the interpreter runs the package, exit 130 and one line."""
    rc, err = _sigint_run(tmp_path, [sys.executable, "-m", "sphgraph"], after, blocked=False)
    lines = err.strip().splitlines()
    assert rc == 130 and len(lines) == 1 and "interrupted" in lines[0], (rc, err)


@pytest.mark.parametrize("orig,command", [
    (["-m", "sphgraph"], True), (["-B", "-m", "sphgraph"], True), (["-Bm", "sphgraph"], True),
    (["-msphgraph"], True), (["-X", "importtime", "-m", "sphgraph"], True), (["-W", "error", "-m", "sphgraph"], True),
    (["--check-hash-based-pycs", "always", "-m", "sphgraph"], True),
    (["-m", "sphgraph.ranges"], False), (["-m", "pytest"], False), (["-c", "import sphgraph"], False),
])
def test_the_command_is_recognised_at_the_package_first_line(monkeypatch, orig, command):
    """Under python -m the package runs before __main__, with argv[0] == "-m": the
    interpreter's arguments say whether the module is the command."""
    import sphgraph
    monkeypatch.setattr(sys, "argv", ["-m", "run"])
    monkeypatch.setattr(sys, "orig_argv", [sys.executable, *orig, "run"])
    assert sphgraph._is_command() is command
