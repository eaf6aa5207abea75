"""Hostile input (issue 8 §4): property-based fuzzing of scene and schedule files.

Every input either runs (``--max-steps 1``, exit 0; a numerical failure at step 1,
exit 1 with one line, is a run too) or gives exit 2 with exactly one stderr line and no
traceback; nothing is written outside ``--out`` (and nothing at all on exit 2); exit 3
(an internal error) is always a bug. Scenes built by a generator of valid scenes must
run a step and exit 0. The CLI runs in process (`sphgraph.cli.main`) to stay fast.
Hypothesis runs derandomized, without an example database.

Two kinds of base scene are mutated: `BASE` (boxes and a tank) and `FEATURE_BASES`
(moving bodies, damping zones, periodic and open boundaries, cylinders and slopes,
shifting, probes and forces), the latter also with the keys and values of those features.
"""
from __future__ import annotations

import copy
import math
import os
import tempfile
from importlib import resources

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from sphgraph.cli import main
from sphgraph.scene import dumps_toml

# SPHGRAPH_FUZZ_RANDOM=1 explores new random examples (for a longer hunt; CI stays derandomized)
SETTINGS = dict(deadline=None, derandomize=not os.environ.get("SPHGRAPH_FUZZ_RANDOM"), database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

BASE = {
    "format": 1, "name": "fz", "dim": 2, "dp": 0.05, "end_time": 0.02, "output_interval": 0.01,
    "domain": {"min": [0.0, 0.0], "max": [1.0, 1.0]},
    "physics": {"visc_alpha": 0.02, "cfl": 0.2},
    "decomposition": {"axis": "auto"},
    "initial": {"hydrostatic": False, "jitter": 0.0},
    "limits": {"max_particles": 100000},
    "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.3, 0.4]}],
    "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8], "layers": 1}],
}


def tree(root):
    out = set()
    for d, _, files in os.walk(root):
        for f in files:
            out.add(os.path.relpath(os.path.join(d, f), root))
    return out


def run_cli(capsys, text: str | bytes, extra=(), scene_text=None):
    """Run `sphgraph run` on `text` (a scene) in a fresh temp dir; check the contract."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "scene.toml")
        mode = "wb" if isinstance(text, bytes) else "w"
        with open(path, mode, **({} if isinstance(text, bytes) else {"encoding": "utf-8"})) as f:
            f.write(text)
        extra = [a.replace("{tmp}", tmp) for a in extra]
        out = os.path.join(tmp, "out")
        before = tree(tmp)
        capsys.readouterr()
        rc = main(["run", path, "--out", out, "--max-steps", "1", "--quiet", *extra])
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert rc in (0, 1, 2), f"exit {rc}: {err}"
        assert "Traceback" not in err
        after = tree(tmp)
        written = {p for p in after - before if not p.startswith("out" + os.sep)}
        assert not written, f"written outside --out: {written}"
        if rc == 2:
            assert len(lines) == 1 and lines[0].startswith("sphgraph: error: "), err
            assert not os.path.exists(out), "exit 2 must write nothing"
        elif rc == 1:
            assert len(lines) == 1 and "numerical failure" in lines[0], err
        else:
            assert os.path.exists(os.path.join(out, "output.h5"))
        try:
            event(f"exit {rc}")
        except Exception:   # noqa: BLE001 - outside a hypothesis test (parametrized cases)
            pass
        return rc, err


# ------------------------------------------------------------------------------ valid scenes
@st.composite
def valid_scenes(draw):
    dim = draw(st.sampled_from([2, 2, 2, 3]))
    dp = draw(st.sampled_from([0.04, 0.05, 0.08]) if dim == 2 else st.sampled_from([0.08, 0.1]))
    size = [draw(st.floats(0.6, 1.5)) for _ in range(dim)]
    fl = [draw(st.floats(0.2, 0.45)) * s for s in size]
    layers = draw(st.integers(1, 2))
    d = {
        "format": 1, "name": draw(st.from_regex(r"[A-Za-z0-9][A-Za-z0-9._-]{0,12}", fullmatch=True)),
        "dim": dim, "dp": dp, "end_time": draw(st.floats(0.005, 1.0)),
        "domain": {"min": [-0.2] * dim, "max": [s + 0.2 for s in size]},
        "physics": {
            "integrator": draw(st.sampled_from(["verlet", "symplectic"])),
            "kernel": draw(st.sampled_from(["wendland", "cubic"])),
            "diffusion": draw(st.sampled_from(["none", "molteni", "fourtakas", "fourtakas-full"])),
            "visc_alpha": draw(st.floats(0.0, 0.1)),
            "cfl": draw(st.floats(0.05, 0.4)),
        },
        "initial": {"hydrostatic": draw(st.booleans()), "jitter": draw(st.floats(0.0, 0.2))},
        "fluid": [{"type": "box", "min": [0.0] * dim, "max": fl}],
        "boundary": [{"type": "tank", "min": [0.0] * dim, "max": size, "layers": layers,
                      "open_top": draw(st.booleans())}],
    }
    if draw(st.booleans()):
        d["output_interval"] = draw(st.floats(0.001, 0.5))
    return d


@settings(max_examples=25, **SETTINGS)
@given(d=valid_scenes())
def test_generator_valid_scenes_run(capsys, d):
    rc, err = run_cli(capsys, dumps_toml(d))
    assert rc == 0, err


# ------------------------------------------------------------------------------ mutated scenes
GARBAGE = st.one_of(
    st.none(), st.booleans(), st.integers(-2 ** 70, 2 ** 70),
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e308, 5e-324, 1e-300, 1e300]),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
    st.sampled_from(["", "Ω∂π", "\u202e", "a" * 500, "nan", "box", "tank", "x", "z"]),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.lists(st.integers(-10, 10), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=3),
    st.lists(st.dictionaries(st.sampled_from(["type", "min", "max", "x"]), st.integers()), max_size=2),
)


def _paths(d, prefix=()):
    """Every (path) to a value in nested dicts/lists."""
    out = []
    if isinstance(d, dict):
        for k, v in d.items():
            out.append(prefix + (k,))
            out += _paths(v, prefix + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            out.append(prefix + (i,))
            out += _paths(v, prefix + (i,))
    return out


def _parent(d, path):
    for k in path[:-1]:
        d = d[k]
    return d


def _mutate(draw, d, keys, values):
    """1-3 random edits of scene dict `d` in place: replace, delete, add a key from `keys`,
    or scale a number; new values drawn from the strategy `values`."""
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(d)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = _parent(d, path)
        op = draw(st.sampled_from(["replace", "replace", "delete", "add", "scale"]))
        if op == "delete":
            del parent[path[-1]]
        elif op == "add" and isinstance(parent, dict):
            parent[draw(st.sampled_from(keys))] = draw(values)
        elif op == "scale" and isinstance(parent[path[-1]], (int, float)) \
                and not isinstance(parent[path[-1]], bool):
            parent[path[-1]] = parent[path[-1]] * draw(st.sampled_from([1e-9, 1e-4, -1, 0, 1e4, 1e12]))
        else:
            parent[path[-1]] = draw(values)
    return d


@st.composite
def mutated_scenes(draw):
    return _mutate(draw, copy.deepcopy(BASE), ["extra", "Ωmega", "limits", "physics", "periodic", "κ"], GARBAGE)


def toml_text(d) -> str | None:
    try:
        return dumps_toml(d)
    except TypeError:   # None inside a list (TOML has no null): not a file anyone can write
        return None


@settings(max_examples=400, **SETTINGS)
@given(d=mutated_scenes())
def test_mutated_scenes_run_or_fail_cleanly(capsys, d):
    text = toml_text(d)
    if text is None:
        event("not writable as TOML")
    else:
        run_cli(capsys, text)


@settings(max_examples=60, **SETTINGS)
@given(cut=st.integers(0, 400), junk=st.binary(max_size=12), pos=st.integers(0, 400))
def test_damaged_scene_text(capsys, cut, junk, pos):
    """Truncated files, inserted bytes (also invalid UTF-8)."""
    raw = dumps_toml(BASE).encode()
    raw = raw[:max(cut, 1)] if cut < len(raw) else raw
    raw = raw[:pos] + junk + raw[pos:]
    run_cli(capsys, raw)


# ------------------------------------------------------------------------------ scene features
# Bases using what BASE predates: [[motion]] (piston, rectilinear table with a jump), [[damping]],
# [domain] periodic / exclude_outside, cylinder (disc) / slope shapes, [physics] shifting,
# [probes], [forces]. Each runs as it is (test_feature_bases_run).
FEATURE_BASES = {
    "flume": {
        "format": 1, "name": "fzf", "dim": 2, "dp": 0.05, "end_time": 0.02, "output_interval": 0.01,
        "domain": {"min": [-0.2, -0.2], "max": [2.2, 1.0], "origin": [0.0, 0.0], "exclude_outside": True},
        "physics": {"visc_alpha": 0.02, "cfl": 0.2, "shifting": "nobound", "shifting_coef": -2.0,
                    "shifting_tfs": 1.5},
        "fluid": [{"type": "box", "min": [0.1, 0.0], "max": [1.9, 0.3]},
                  {"type": "cylinder", "center": [1.0, 0.6], "radius": 0.1}],
        # the tank's end wall behind the paddle's longest drawn stroke (S/2 <= ~0.12 m): a
        # fixed wall inside a piston's stroke is refused (sphgraph.motion)
        "boundary": [{"type": "tank", "min": [-0.15, 0.0], "max": [2.0, 0.8], "layers": 1},
                     {"type": "wall", "name": "paddle", "min": [0.05, 0.05], "max": [0.05, 0.5]},
                     {"type": "box", "name": "block", "min": [1.4, 0.45], "max": [1.6, 0.55]},
                     {"type": "slope", "start": [1.6, 0.0], "end": [2.0, 0.2], "layers": 2},
                     {"type": "cylinder", "name": "pile", "center": [0.6, 0.6], "radius": 0.08}],
        "motion": [{"body": "paddle", "type": "piston", "height": 0.02, "period": 1.0, "depth": 0.3,
                    "ramp": 1.0, "phase": 0.0, "start": 0.0, "direction": "x"},
                   {"body": "block", "type": "rectilinear", "times": [0.0, 0.01, 0.01, 0.02],
                    "velocity": [[0.0, 0.0], [0.1, 0.0], [0.0, -0.1], [0.0, 0.0]]}],
        "damping": [{"axis": "x", "start": 1.4, "end": 1.9, "redumax": 10.0, "overlimit": 1.0}],
        "probes": {"interval": 0.005, "points": [{"name": "P1", "position": [0.5, 0.1]}],
                   "heights": [{"name": "H1", "position": [1.0]}]},
        "forces": {"interval": 0.0, "bodies": [{"name": "pile", "min": [0.4, 0.4], "max": [0.8, 0.8]}]},
    },
    "channel": {
        "format": 1, "name": "fzp", "dim": 2, "dp": 0.05, "end_time": 0.02,
        "domain": {"min": [0.0, -0.1], "max": [1.0, 0.6], "origin": [0.0, 0.0], "periodic": ["x"]},
        "physics": {"shifting": "full", "hswl": 0.3, "coefsound": 10.0, "integrator": "symplectic"},
        "decomposition": {"axis": "x"},
        "fluid": [{"type": "box", "min": [0.0, 0.05], "max": [0.95, 0.3]}],
        "boundary": [{"type": "wall", "min": [0.0, 0.0], "max": [0.95, 0.0], "layers": 2, "direction": "-"}],
        "damping": [{"axis": "y", "start": 0.2, "end": 0.3}],
        "probes": {"heights": [{"name": "H", "position": [0.5]}]},
    },
    "flume3d": {
        "format": 1, "name": "fz3", "dim": 3, "dp": 0.1, "end_time": 0.02,
        "domain": {"min": [-0.4, -0.2, -0.2], "max": [2.2, 0.9, 1.0], "origin": [0.0, 0.0, 0.0],
                   "exclude_outside": False},
        "physics": {"shifting": "nofixed", "shifting_tfs": 2.75},
        "fluid": [{"type": "box", "min": [0.2, 0.0, 0.0], "max": [1.2, 0.7, 0.3]}],
        "boundary": [{"type": "tank", "min": [-0.2, 0.0, 0.0], "max": [2.0, 0.7, 0.8]},
                     {"type": "wall", "name": "paddle", "min": [0.1, 0.0, 0.1], "max": [0.1, 0.7, 0.5]},
                     {"type": "cylinder", "name": "leg", "center": [0.8, 0.35, 0.0], "radius": 0.1,
                      "length": 0.6, "axis": "z", "fill": "surface", "layers": 1},
                     {"type": "slope", "start": [1.3, 0.0, 0.0], "angle": 20.0, "length": 0.7, "width": 0.7,
                      "axis": "x", "layers": 1}],
        "motion": [{"body": "paddle", "type": "piston", "height": 0.05, "period": 1.2, "direction": "x"},
                   {"body": "leg", "type": "rectilinear", "times": [0.0], "velocity": [[0.0, 0.05, 0.0]]}],
        "damping": [{"axis": "x", "start": 1.5, "end": 2.0}],
        "forces": {"interval": 0.01, "bodies": [{"name": "leg", "min": [0.6, 0.1, -0.1], "max": [1.0, 0.6, 0.7]}]},
    },
}
# keys and values of those features, for "add" and "replace" (plus the generic GARBAGE)
FEATURE_KEYS = ("periodic", "exclude_outside", "shifting", "shifting_coef", "shifting_tfs", "motion",
                "damping", "probes", "forces", "interval", "points", "heights", "bodies", "position",
                "body", "type", "times", "velocity", "omega", "height", "period", "depth", "ramp", "phase",
                "start", "direction", "axis", "end", "redumax", "overlimit", "center", "radius", "length",
                "angle", "width", "layers", "fill", "name", "min", "max", "hinge", "speed", "lift", "gravity")
FEATURE_VALUES = st.one_of(
    GARBAGE,
    st.sampled_from(["piston", "rectilinear", "rotation", "flap", "gate", "cylinder", "slope", "wall",
                     "paddle", "block", "pile", "leg", "none", "nobound", "nofixed", "full", "surface",
                     "solid", "-", "+", "y", "tank"]),
    st.sampled_from([["x"], ["y"], ["x", "y"], ["x", "x"], ["z"], [], [0.0, 0.01, 0.005], [0.02, 0.0],
                     [math.nan, 1.0], [0.0, math.inf], [[0.0, 0.0]], [[0.1, 0.0], [0.0, math.nan]],
                     [[1e300, 0.0]], [0.5, 0.1], [0.5, 0.9], [0.5, math.nan], [math.inf], [-1.0], [0.0, 0.0]]),
    st.sampled_from([math.nan, math.inf, -math.inf, 5e-324, 1e-300, 1e300, -2.0, 0.0, 90.0, -90.0, 89.999]),
    st.lists(st.fixed_dictionaries({"name": st.sampled_from(["P", "Q", "time", "a/b", ""]),
                                    "position": st.lists(st.floats(-1, 3), min_size=1, max_size=3)}),
             max_size=2),
    st.sampled_from([copy.deepcopy(v[k]) for v in FEATURE_BASES.values() for k in
                     ("motion", "damping", "probes", "forces", "boundary", "domain") if k in v]),
).map(copy.deepcopy)   # a fresh copy: mutating a drawn list or table must not change the next draw


@st.composite
def mutated_feature_scenes(draw):
    d = copy.deepcopy(FEATURE_BASES[draw(st.sampled_from(sorted(FEATURE_BASES)))])
    return _mutate(draw, d, FEATURE_KEYS, FEATURE_VALUES)


@pytest.mark.parametrize("name", sorted(FEATURE_BASES))
def test_feature_bases_run(capsys, name):
    for ranks in (1, 2) if name != "flume3d" else (1,):   # 3D at dp 0.1: too narrow for 2 slabs
        rc, err = run_cli(capsys, dumps_toml(FEATURE_BASES[name]), extra=["--comm", "mock", "--ranks", str(ranks)])
        assert rc == 0, err


@settings(max_examples=700, **SETTINGS)
@given(d=mutated_feature_scenes())
def test_mutated_feature_scenes_run_or_fail_cleanly(capsys, d):
    text = toml_text(d)
    if text is None:
        event("not writable as TOML")
    else:
        run_cli(capsys, text)


@st.composite
def valid_feature_scenes(draw):
    """Random but valid values of every feature key on the flume / channel bases."""
    name = draw(st.sampled_from(["flume", "flume", "channel"]))
    d = copy.deepcopy(FEATURE_BASES[name])
    ph = d["physics"]
    ph["shifting"] = draw(st.sampled_from(["none", "nobound", "nofixed", "full"]))
    ph["shifting_coef"] = draw(st.floats(-5.0, -0.1))
    ph["shifting_tfs"] = draw(st.sampled_from([0.0, draw(st.floats(0.0, 1.99))]))
    ph["integrator"] = draw(st.sampled_from(["verlet", "symplectic"]))
    for t in ("probes", "forces"):
        d.setdefault(t, {})["interval"] = draw(st.sampled_from([0.0, 5e-324, draw(st.floats(1e-6, 0.05))]))
    d["probes"]["points"] = [{"name": f"P{i}", "position": [draw(st.floats(0.0, 0.9)), draw(st.floats(0.0, 0.5))]}
                             for i in range(draw(st.integers(0, 2)))]
    d["damping"][0]["redumax"] = draw(st.floats(0.1, 100.0))
    d["damping"][0]["overlimit"] = draw(st.sampled_from([0.0, 0.3, 1e30]))
    if name == "channel":
        d["domain"]["exclude_outside"] = draw(st.booleans())
        return d
    d["domain"]["exclude_outside"] = draw(st.booleans())
    pis = d["motion"][0]
    pis.update(height=draw(st.floats(0.001, 0.05)), period=draw(st.floats(0.3, 3.0)),
               depth=draw(st.floats(0.1, 0.6)), ramp=draw(st.floats(0.0, 3.0)),
               phase=draw(st.floats(-math.pi, math.pi)), start=draw(st.floats(0.0, 0.05)))
    times = sorted(draw(st.lists(st.floats(0.0, 0.05), min_size=1, max_size=4)))
    if draw(st.booleans()):
        times = times + times[-1:]                 # a jump
    d["motion"][1]["times"] = times
    d["motion"][1]["velocity"] = [[draw(st.floats(-0.3, 0.3)), draw(st.floats(-0.3, 0.3))] for _ in times]
    return d


@settings(max_examples=30, **SETTINGS)
@given(d=valid_feature_scenes(), ranks=st.sampled_from([1, 1, 2]))
def test_generator_valid_feature_scenes_run(capsys, d, ranks):
    rc, err = run_cli(capsys, dumps_toml(d), extra=["--comm", "mock", "--ranks", str(ranks)])
    assert rc == 0, err


HUGE = [
    {"dp": 1e-6},                                                    # 10^12 particles: max_particles
    {"dp": 2e-5, "limits": {"max_particles": 10 ** 15}},             # limit lifted: memory refuses
    {"dp": 1e-300}, {"dp": 5e-324},
    {"domain": {"min": [-1e300, -1e300], "max": [1e300, 1e300]}},
    {"domain": {"min": [0.0, 0.0], "max": [1e300, 1e300]},
     "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [1e299, 1e299]}]},
    {"fluid": [{"type": "box", "min": [0.0, 0.0], "max": [1.0, 1.0]}] * 500},
    {"limits": {"max_particles": 0}}, {"limits": {"max_particles": 2 ** 80}},
    {"end_time": 1e308, "output_interval": 5e-324},
]


@pytest.mark.parametrize("patch", HUGE, ids=range(len(HUGE)))
def test_extreme_scenes(capsys, patch):
    d = copy.deepcopy(BASE)
    d.update(copy.deepcopy(patch))
    rc, err = run_cli(capsys, dumps_toml(d))
    if "dp" in patch:
        assert rc == 2 and ("max_particles" in err or "memory" in err or "dp" in err), err


# ------------------------------------------------------------------------------ schedules
def shipped_text(name="production"):
    return resources.files("sphgraph.schedules").joinpath(f"{name}.toml").read_text(encoding="utf-8")


@st.composite
def mutated_schedules(draw):
    import tomllib
    d = tomllib.loads(shipped_text(draw(st.sampled_from(["production", "bulk-synchronous", "halo-first"]))))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(d)
        path = draw(st.sampled_from(paths))
        parent = _parent(d, path)
        op = draw(st.sampled_from(["replace", "delete", "swap", "add"]))
        if op == "delete":
            del parent[path[-1]]
        elif op == "swap" and isinstance(parent, list) and len(parent) > 1:
            i = draw(st.integers(0, len(parent) - 1))
            parent[path[-1]], parent[i] = parent[i], parent[path[-1]]
        elif op == "add" and isinstance(parent, dict):
            parent[draw(st.sampled_from(["extra", "lanes", "rebalance", "Ω"]))] = draw(GARBAGE)
        else:
            parent[path[-1]] = draw(GARBAGE)
    return d


@settings(max_examples=150, **SETTINGS)
@given(d=mutated_schedules(), ranks=st.sampled_from([1, 2]))
def test_mutated_schedules(capsys, d, ranks):
    text = toml_text(d)
    if text is None:
        return
    with tempfile.TemporaryDirectory() as tmp:
        sched = os.path.join(tmp, "s.toml")
        with open(sched, "w", encoding="utf-8") as f:
            f.write(text)
        run_cli(capsys, dumps_toml(BASE), extra=["--schedule", sched, "--comm", "mock", "--ranks", str(ranks)])


def test_shipped_schedules_as_files_run(capsys):
    for name in ("production", "bulk-synchronous", "halo-first"):
        with tempfile.TemporaryDirectory() as tmp:
            sched = os.path.join(tmp, "s.toml")
            with open(sched, "w", encoding="utf-8") as f:
                f.write(shipped_text(name))
            rc, err = run_cli(capsys, dumps_toml(BASE), extra=["--schedule", sched, "--comm", "mock",
                                                               "--ranks", "2"])
            assert rc == 0, err


# ------------------------------------------------------------------------------ regressions
# Inputs fuzzing found that crashed (exit 3) or hung before they were fixed.
def test_regression_halo_order_of_mixed_types(capsys):
    """schedule.py sorted() a halo_order of mixed types before checking them: TypeError."""
    import tomllib
    d = tomllib.loads(shipped_text())
    d["halo_order"] = ["", 2]
    with tempfile.TemporaryDirectory() as tmp:
        sched = os.path.join(tmp, "s.toml")
        with open(sched, "w", encoding="utf-8") as f:
            f.write(dumps_toml(d))
        rc, err = run_cli(capsys, dumps_toml(BASE), extra=["--schedule", sched])
    assert rc == 2 and "halo_order" in err


@pytest.mark.parametrize("patch,key", [
    # dp = 1e-300: lattice indices overflowed int64 (bounding box None: TypeError)
    ({"dp": 1e-300}, "dp"),
    # output_interval below the time's resolution: the next output time never advanced (hang)
    # (end_time's range now stops 1e308 first: the longest end_time in range keeps the case)
    ({"end_time": 1e6, "output_interval": 1e-12}, "output_interval"),
    ({"end_time": 1e308, "output_interval": 5e-324}, "end_time"),
    ({"end_time": 1.0, "output_interval": 1e-12}, "output_interval"),
    # 3D, 10^15 points per axis: the int64 box count wrapped around and passed max_particles
    ({"dim": 3, "dp": 1e-6, "domain": {"min": [0.0, 0.0, 0.0], "max": [1e6, 1e6, 1e6]},
      "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [1e6, 1e6, 1e6]}], "boundary": []},
     "max_particles"),
])
def test_regression_extreme_numbers(capsys, patch, key):
    d = copy.deepcopy(BASE)
    d.update(copy.deepcopy(patch))
    rc, err = run_cli(capsys, dumps_toml(d))
    assert rc == 2 and key in err, err


def _patch(name, *edits):
    """FEATURE_BASES[name] with edits (("a.0.b", value), ...)."""
    d = copy.deepcopy(FEATURE_BASES[name])
    for path, value in edits:
        keys = [int(k) if k.isdigit() else k for k in path.split(".")]
        _parent(d, keys)[keys[-1]] = value
    return d


@pytest.mark.parametrize("edits,key,form", [
    # [probes]/[forces] interval = nan / inf passed `iv < 0` and ran
    ((("probes.interval", math.nan),), "probes.interval", "a number >= 0 and <= 1e+06 [s]"),
    ((("probes.interval", math.inf),), "probes.interval", "a number >= 0 and <= 1e+06 [s]"),
    ((("forces.interval", math.nan),), "forces.interval", "a number >= 0 and <= 1e+06 [s]"),
    ((("forces.interval", -math.inf),), "forces.interval", "a number >= 0 and <= 1e+06 [s]"),
    ((("probes.points.0.position", [math.nan, 0.1]),), "probes.points[0].position", "a list of 2 numbers, each"),
    ((("probes.heights.0.position", [math.inf]),), "probes.heights[0].position", "a list of 1 numbers, each"),
    ((("forces.bodies.0.max", [math.inf, 0.8]),), "forces.bodies[0].max", "a list of 2 numbers, each"),
])
def test_regression_probe_and_force_keys_reject_nan_and_inf(capsys, edits, key, form):
    rc, err = run_cli(capsys, dumps_toml(_patch("flume", *edits)))
    assert rc == 2 and f"scene.toml: {key}: expected {form}" in err, err


def test_regression_tiny_probe_interval_does_not_hang(capsys):
    """interval = 5e-324: stepping the next sample time by the interval never got past t (a hang)."""
    rc, err = run_cli(capsys, dumps_toml(_patch("flume", ("probes.interval", 5e-324),
                                                ("forces.interval", 1e-300))))
    assert rc == 0, err


@pytest.mark.parametrize("name,edits,key", [
    # set() of an unhashable axis: TypeError
    ("channel", (("domain.periodic", [[]]),), "domain.periodic"),
    # wavemaker: cosh(2kd) overflow (tiny period), a zero wave number (huge period), w^2 overflow, g = 0
    ("flume", (("motion.0.period", 1e-9),), "motion[0].period"),   # below its range (sphgraph.ranges)
    ("flume", (("motion.0.period", 1e-6),), None),                 # the shortest period in range runs
    ("flume", (("motion.0.period", 1e300),), "motion[0].period"),
    ("flume", (("motion.0.period", 1e-300),), "motion[0].period"),
    ("flume", (("motion.0.depth", 1e-300),), "motion[0].depth"),
    ("flume", (("motion.0.depth", 1e-9),), "motion[0].body"),   # in range: the stroke check answers
    ("flume", (("physics.gravity", [0.0, 0.0]),), "motion[0].type"),
    # a flap hinged above the still-water level: ValueError (exit 3)
    ("flume", (("motion.0.type", "flap"), ("motion.0.hinge", [0.05, 0.9])), "motion[0].hinge"),
    # rectilinear times nan / inf passed the non-decreasing check
    ("flume", (("motion.1.times", [math.nan, 0.01, 0.01, 0.02]),), "motion[1].times"),
    ("flume", (("motion.1.times", [0.0, 0.01, 0.01, math.inf]),), "motion[1].times"),
    # a slope's run lost next to a huge start: division by zero
    ("flume3d", (("boundary.3.start", [2.0 ** 53, 0.0, 0.0]),), "boundary[3].start"),   # beyond the range
    # entries 10^24 spacings away: int64 lattice indices wrapped (TypeError; for a shape, an
    # error quoting wrapped coordinates -9.2e17 instead of the entry's own)
    ("flume3d", (("boundary.1.max", [0.1, 7e23, 0.5]),), "boundary[1].max"),
    ("flume3d", (("boundary.1.max", [0.1, 1e7, 0.5]),), "boundary[1]"),   # in range, far outside the domain
    ("flume3d", (("boundary.2.radius", 1e300),), "boundary[2].radius"),
    ("flume3d", (("boundary.2.radius", 1e7),), "boundary[2]: expected particles inside the domain "
     "[-0.4, -0.2, -0.2] - [2.2, 0.9, 1.0] (extend [domain]), got particles spanning"),
])
def test_regression_feature_keys_found_by_fuzzing(capsys, name, edits, key):
    """Inputs the feature fuzzer found that crashed (exit 3) or ran when they should not."""
    rc, err = run_cli(capsys, dumps_toml(_patch(name, *edits)))
    if key is None:          # a valid (if extreme) wave: it runs
        assert rc in (0, 1), err
    else:                    # key, or the error's text from the key on
        assert rc == 2 and f"scene.toml: {key if ': expected' in key else key + ': expected '}" in err, err
