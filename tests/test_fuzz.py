"""Hostile input (issue 8 §4): property-based fuzzing of scene and schedule files.

Every input either runs (``--max-steps 1``, exit 0; a numerical failure at step 1,
exit 1 with one line, is a run too) or gives exit 2 with exactly one stderr line and no
traceback; nothing is written outside ``--out`` (and nothing at all on exit 2); exit 3
(an internal error) is always a bug. Scenes built by a generator of valid scenes must
run a step and exit 0. The CLI runs in process (`sphgraph.cli.main`) to stay fast.
Hypothesis runs derandomized, without an example database.
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


@st.composite
def mutated_scenes(draw):
    d = copy.deepcopy(BASE)
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
            parent[draw(st.sampled_from(["extra", "Ωmega", "limits", "physics", "periodic", "κ"]))] = draw(GARBAGE)
        elif op == "scale" and isinstance(parent[path[-1]], (int, float)) \
                and not isinstance(parent[path[-1]], bool):
            parent[path[-1]] = parent[path[-1]] * draw(st.sampled_from([1e-9, 1e-4, -1, 0, 1e4, 1e12]))
        else:
            parent[path[-1]] = draw(GARBAGE)
    return d


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
    ({"end_time": 1e308, "output_interval": 5e-324}, "output_interval"),
    ({"end_time": 1.0, "output_interval": 1e-12}, "output_interval"),
    # 3D, 10^15 points per axis: the int64 box count wrapped around and passed max_particles
    ({"dim": 3, "dp": 1e-9, "domain": {"min": [0.0, 0.0, 0.0], "max": [1e6, 1e6, 1e6]},
      "fluid": [{"type": "box", "min": [0.0, 0.0, 0.0], "max": [1e6, 1e6, 1e6]}], "boundary": []},
     "max_particles"),
])
def test_regression_extreme_numbers(capsys, patch, key):
    d = copy.deepcopy(BASE)
    d.update(copy.deepcopy(patch))
    rc, err = run_cli(capsys, dumps_toml(d))
    assert rc == 2 and key in err, err
