"""Hostile-input fuzzing at the grammar level: scenes, STL meshes, schedules, flags,
checkpoint and --restart folders, SIGINT -- each case one `sphgraph run`.

    python benchmarks/fuzz_hostile.py --cases 1000 [--seed 0] [--workers 2] [--json out.json]

Cases are drawn from a seeded generator (the same seed, the same cases):

- scene: a base scene (2D boxes, 3D shapes, a wavemaker flume) as TOML text, mutated at the
  grammar level: a table duplicated, moved into another, nested in itself, a key renamed,
  a value's type swapped at any depth (string, integer, float, bool, array, inline table,
  date, huge integer, nan, inf), the text re-encoded (UTF-16, Latin-1, a BOM, NUL bytes,
  CRLF, truncation);
- stl: a generated mesh (a closed cube, then: inf/nan vertices, degenerate or missing
  triangles, coordinates near float64's limit, a wrong binary count, ASCII junk, empty);
- schedule: the production schedule mutated the same way, or binary;
- flags: a random draw from every run flag's values, valid and hostile, and its switches
  (--no-rebalance, --overwrite, --no-invariants); one case in six runs `sphgraph bench`
  with the drawn flags that bench takes and its own --steps/--warmup;
- restart: a real run's folder damaged or not fitting the run: a truncated checkpoint, bytes
  flipped inside every one, one from another scene (or of another dimension), one of another
  format and version, a FIFO, a folder, a link to /dev/zero or a sparse file past the size
  limit named like a checkpoint, the checkpoints folder a file, no or a damaged output.h5,
  a missing folder; and flags that do not fit it (--precision, --dp, --out elsewhere, an
  end time before the checkpoint's, a checkpoint of 2 mock ranks continued on 1);
- sigint: a subprocess (python -m sphgraph or the console script) interrupted at a random
  moment (start-up, set-up, stepping): half started with SIGINT blocked across exec, from
  0.02 s on, the others plainly, from 0.5 s on (after the interpreter's own start-up).

The contract checked for every case (DESIGN.md §5, issue 24 §3): exit 0, 1 or 2 (3 only as
a communication error of the simulated faults, 130 for SIGINT), at most one stderr line
(warnings about skipped damaged checkpoints aside), never a traceback, never more than
2 GiB of memory (the worker's peak resident size), never longer than 120 s.

Cases run in process (`sphgraph.cli.main`) in worker processes, stderr captured at the file
descriptor. `fast_sample(n)` is the suite's small sample (tests/test_fuzz_hostile.py).
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import io
import json
import math
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

GIB = 1 << 30
CASE_SECONDS = 120
KINDS = ("scene", "scene", "scene", "stl", "schedule", "flags", "flags", "restart")

BASES = {
    "box2d": {
        "format": 1, "name": "fz", "dim": 2, "dp": 0.05, "end_time": 0.01, "output_interval": 0.005,
        "domain": {"min": [-0.1, -0.1], "max": [1.1, 1.1]},
        "physics": {"visc_alpha": 0.02, "cfl": 0.2, "coefsound": 20.0, "gravity": [0.0, -9.81]},
        "decomposition": {"axis": "auto"},
        "initial": {"hydrostatic": True, "jitter": 0.0},
        "limits": {"max_particles": 100000},
        "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.4, 0.4]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8], "layers": 1}],
    },
    "shapes3d": {
        "format": 1, "name": "fz3", "dim": 3, "dp": 0.1, "end_time": 0.01,
        "domain": {"min": [-0.3, -0.3, -0.3], "max": [1.3, 1.3, 1.3], "origin": [0.0, 0.0, 0.0]},
        "physics": {"shifting": "nofixed", "shifting_tfs": 2.75},
        "fluid": [{"type": "box", "min": [0.1, 0.1, 0.0], "max": [0.5, 0.9, 0.3]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.8]},
                     {"type": "cylinder", "name": "leg", "center": [0.7, 0.5, 0.0], "radius": 0.1,
                      "length": 0.5, "axis": "z", "fill": "surface", "layers": 1},
                     {"type": "slope", "start": [0.6, 0.0, 0.0], "angle": 20.0, "length": 0.35,
                      "width": 1.0, "axis": "x", "layers": 1}],
    },
    "flume": {
        "format": 1, "name": "fzw", "dim": 2, "dp": 0.05, "end_time": 0.01,
        "domain": {"min": [-0.4, -0.2], "max": [2.2, 1.0], "origin": [0.0, 0.0]},
        "physics": {"hswl": 0.3},
        "fluid": [{"type": "box", "min": [0.15, 0.0], "max": [2.0, 0.3]}],
        "boundary": [{"type": "tank", "min": [-0.2, 0.0], "max": [2.0, 0.8]},
                     {"type": "wall", "name": "paddle", "min": [0.1, 0.0], "max": [0.1, 0.6], "layers": 2}],
        "motion": [{"body": "paddle", "type": "piston", "height": 0.05, "period": 1.0}],
        "damping": [{"axis": "x", "start": 1.5, "end": 2.0}],
        "probes": {"interval": 0.005, "points": [{"name": "P1", "position": [0.5, 0.1]}]},
    },
}
SWAPS = ['"text"', '""', "0", "-1", "1", "2", "3", "7", "1e308", "-1e308", "5e-324", "1e-300", "nan", "inf",
         "-inf", "true", "false", "[]", "[1, 2]", "[[1.0, 2.0]]", '["x"]', "{}", "{a = 1}",
         "1979-05-27T07:32:00Z", "1" + "0" * 40, "0x7fffffffffffffff", "[1e309, 0.0]", "[nan, nan]",
         '"\u202e"', '"' + "a" * 300 + '"', "[[[[[[[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]]]]]]"]
KEYS = ["format", "name", "dim", "dp", "end_time", "physics", "domain", "fluid", "boundary", "type", "min",
        "max", "layers", "coefh", "gravity", "Ωmega", "dp ", "DP", "min.x", "\"quoted\"", "limits"]


# ------------------------------------------------------------------------------ TOML text
def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if not isinstance(v, float) or math.isfinite(v) else ("nan" if v != v else
                                                                            ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def sections(d: dict) -> list[tuple[str, list[str]]]:
    """The scene as TOML sections: (header, lines); header '' for the top-level keys."""
    top = [f"{k} = {toml_value(v)}" for k, v in d.items()
           if not isinstance(v, dict) and not (isinstance(v, list) and v and isinstance(v[0], dict))]
    out = [("", top)]
    for k, v in d.items():
        if isinstance(v, dict):
            out.append((f"[{k}]", [f"{a} = {toml_value(b)}" for a, b in v.items()]))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for e in v:
                out.append((f"[[{k}]]", [f"{a} = {toml_value(b)}" for a, b in e.items()]))
    return out


def render(secs) -> str:
    return "\n".join(((h + "\n") if h else "") + "\n".join(lines) for h, lines in secs) + "\n"


def mutate_text(rng: random.Random, secs) -> str:
    """One to three grammar-level edits of the sections, then maybe an encoding."""
    secs = [(h, list(lines)) for h, lines in secs]
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(len(secs))
        h, lines = secs[i]
        op = rng.choice(["duplicate", "move", "nest", "rename", "swap", "swap", "swap", "drop", "header"])
        if op == "duplicate":
            secs.insert(rng.randrange(len(secs) + 1), (h, list(lines)))
        elif op == "move" and len(secs) > 1:       # its keys under another header
            j = rng.randrange(len(secs))
            secs[j][1].extend(lines)
            del secs[i]
        elif op == "nest" and h:                   # a table inside itself, or as an inline table
            name = h.strip("[]")
            if rng.random() < 0.5:
                secs.append((f"[{name}.{rng.choice([name, 'inner', 'physics'])}]", list(lines)))
            else:
                secs[i] = (h, [f"{rng.choice(KEYS)} = {{{', '.join(lines)}}}"])
        elif op == "rename" and lines:
            k = rng.randrange(len(lines))
            key, _, val = lines[k].partition(" = ")
            lines[k] = f"{rng.choice(KEYS + [key.upper(), key + '_', key[:-1] or 'x'])} = {val}"
        elif op == "swap" and lines:               # a value of another type, at any depth
            k = rng.randrange(len(lines))
            key, _, val = lines[k].partition(" = ")
            if val.startswith("[") and rng.random() < 0.5:
                parts = val.strip("[]").split(", ")
                parts[rng.randrange(len(parts))] = rng.choice(SWAPS)
                val = "[" + ", ".join(parts) + "]"
            else:
                val = rng.choice(SWAPS)
            lines[k] = f"{key} = {val}"
        elif op == "drop" and lines:
            del lines[rng.randrange(len(lines))]
        elif op == "header":
            secs[i] = (rng.choice(["[physics]", "[[fluid]]", "[[boundary]]", "[domain]", "[limits]",
                                   "[[physics]]", "[fluid]", "[motion]", "[format]", "[a.b.c]"]), lines)
    return render(secs)


def encode(rng: random.Random, text: str) -> bytes:
    r = rng.random()
    if r < 0.75:
        return text.encode()
    op = rng.choice(["utf16", "latin1", "bom", "nul", "crlf", "truncate", "invalid"])
    if op == "utf16":
        return text.encode("utf-16")
    if op == "latin1":
        return (text + '\n# café ±\n').encode("latin-1", errors="replace")   # a key such as Ωmega: '?'
    if op == "bom":
        return b"\xef\xbb\xbf" + text.encode()
    if op == "nul":
        b = bytearray(text.encode())
        b.insert(rng.randrange(len(b)), 0)
        return bytes(b)
    if op == "crlf":
        return text.replace("\n", "\r\n").encode()
    if op == "truncate":
        return text.encode()[:rng.randrange(1, len(text))]
    return text.encode()[:40] + b"\xff\xfe\xc3\x28" + text.encode()[40:]


# ------------------------------------------------------------------------------ STL
def cube(scale=0.3, at=0.35) -> np.ndarray:
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    f = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5),
         (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    return v[np.array(f)] * scale + at


def stl_bytes(rng: random.Random) -> bytes:
    tris = cube()
    op = rng.choice(["good", "inf", "nan", "degenerate", "open", "huge", "flat", "count", "ascii", "junk",
                     "empty", "tiny"])
    if op == "inf":
        tris[rng.randrange(12), rng.randrange(3), rng.randrange(3)] = rng.choice([np.inf, -np.inf])
    elif op == "nan":
        tris[rng.randrange(12), rng.randrange(3), rng.randrange(3)] = np.nan
    elif op == "degenerate":
        tris[:, :, rng.randrange(3)] = 0.5
    elif op == "open":
        tris = np.delete(tris, rng.randrange(12), axis=0)
    elif op == "huge":
        tris = tris * 1e37
    elif op == "flat":
        tris[:, 2] = tris[:, 1]
    elif op == "tiny":
        tris = tris * 1e-30
    if op in ("ascii", "junk", "empty"):
        if op == "empty":
            return b""
        if op == "junk":
            return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 3000)))
        lines = ["solid x"] + [f"vertex {a:.17g} {b:.17g} {c:.17g}" for t in tris for a, b, c in t]
        if rng.random() < 0.5:
            lines.append("vertex 1 2")      # a broken vertex
        return ("\n".join(lines) + "\nendsolid x\n").encode()
    rec = np.zeros(len(tris), [("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    with np.errstate(all="ignore"):
        rec["v"] = tris
    n = len(tris) + (rng.choice([1, -1, 1000]) if op == "count" else 0)
    return b"x" * 80 + np.uint32(max(n, 0)).tobytes() + rec.tobytes()


# ------------------------------------------------------------------------------ cases
FLAG_VALUES = {
    "--comm": ["single", "mock", "mpi", "bogus"],
    "--ranks": ["-1", "0", "1", "2", "3", "1000000", "x", "1.5"],
    "--seed": ["-1", "0", "7", str(2 ** 64)],
    "--loss": ["0.1", "nan", "2", "5,17", "x", "0"],
    "--duplicate": ["0.01", "inf", "-0.5", "3", ""],
    "--rank-speed": ["1,2", "0,1", "nan,1", "1e300,1", "x"],
    "--watchdog": ["5", "-1", "nan", "0"],
    "--dp": ["nan", "-1", "1e-300", "0.05", "1e300", "0.08", "x"],
    "--end-time": ["0", "-1", "inf", "0.005", "1e300"],
    "--max-steps": ["0", "-1", "1", "2", "x"],
    "--backend": ["numba-cpu", "numba-cuda", "gpu"],
    "--precision": ["float32", "float64", "float16"],
    "--schedule": ["production", "bulk-synchronous", "missing.toml", "/dev/zero", "nope"],
    "--checkpoint-every": ["0", "-1", "1", "0.001s", "x", "nans", "1e-300s"],
    "--walltime": ["nan", "0", "1e9", "-5"],
    "--halo-transport": ["staged", "ipc", "x"],
    "--rebalance-every": ["0", "1", "x", "1" + "0" * 400, "1e3"],
    "--rebalance-threshold": ["nan", "0.03", "-1", "inf", "1e300", "0"],
    "--rebalance-policy": ["particles", "time", "memory", "bogus", ""],
    "--max-particles-per-rank": ["0", "-5", "10", "100000", "1e6", "1" + "0" * 30, "x"],
    "--out": ["", "{tmp}/file/o", "/proc/self/o", "{tmp}/" + "n" * 300, "{tmp}/o2", "/dev/null/o",
              "{tmp}/scene.toml"],
}
# flags without a value, drawn with the valued ones
SWITCHES = ["--no-rebalance", "--overwrite", "--no-invariants"]
# `sphgraph bench`'s own flags (a case of kind flags runs bench instead of run one time in six)
BENCH_VALUES = {
    "--steps": ["0", "-1", "1", "2", "x", "1e3", "1" + "0" * 30],
    "--warmup": ["0", "-1", "1", "x", "1" + "0" * 30],
}
# ways a --restart folder is damaged or does not fit the run (see _prepare_restart)
RESTARTS = ("truncate", "other_scene", "other_format", "fifo", "folder", "no_master", "bad_master", "file",
            "empty", "bitflip", "dev_zero_link", "sparse_huge", "ckpt_dir_file", "missing", "other_dim",
            "precision", "other_ranks", "finished", "out_elsewhere", "dp_override")


def case(seed: int, index: int) -> dict:
    """Case `index` of generator `seed`: {kind, files: {name: bytes}, argv, restart, delay}."""
    rng = random.Random(seed * 1_000_003 + index)
    kind = "sigint" if index % 50 == 49 else KINDS[rng.randrange(len(KINDS))]
    base = copy.deepcopy(BASES[rng.choice(sorted(BASES))])
    files, argv, restart = {}, [], None
    if kind == "scene":
        files["scene.toml"] = encode(rng, mutate_text(rng, sections(base)))
    elif kind == "stl":
        base = copy.deepcopy(BASES["shapes3d"])
        base["boundary"][2] = {"type": "stl", "path": rng.choice(["mesh.stl"] * 6 + ["/dev/zero", ".", "none.stl"]),
                               "scale": rng.choice([1.0, 1.0, 2.0, 1e-9]), "fill": rng.choice(["solid", "surface"])}
        if base["boundary"][2]["fill"] == "surface":
            base["boundary"][2]["layers"] = 1
        files["scene.toml"] = render(sections(base)).encode()
        files["mesh.stl"] = stl_bytes(rng)
    elif kind == "schedule":
        from importlib import resources
        text = resources.files("sphgraph.schedules").joinpath("production.toml").read_text()
        import tomllib
        d = tomllib.loads(text)
        files["scene.toml"] = render(sections(BASES["box2d"])).encode()   # wide enough for 2 ranks
        files["sched.toml"] = (bytes(rng.randrange(256) for _ in range(500)) if rng.random() < 0.1
                               else encode(rng, mutate_text(rng, sections(d))))
        argv += ["--schedule", "{tmp}/sched.toml", "--comm", "mock", "--ranks", rng.choice(["1", "2"])]
    elif kind == "flags":
        files["scene.toml"] = render(sections(base)).encode()
        files["file"] = b"x"
        for flag in rng.sample(sorted(FLAG_VALUES), rng.randint(1, 4)):
            argv += [flag, rng.choice(FLAG_VALUES[flag])]
        argv += [f for f in SWITCHES if rng.random() < 0.15]
        if rng.random() < 1 / 6:   # bench: its own step counts, and no --out/--overwrite/--checkpoint-every
            argv = _bench_argv(rng, argv)
    elif kind == "restart":
        base = copy.deepcopy(BASES["box2d"])
        files["scene.toml"] = render(sections(base)).encode()
        restart = rng.choice(RESTARTS)
        if restart == "other_scene":
            base["physics"]["visc_alpha"] = 0.05
            files["other.toml"] = render(sections(base)).encode()
        elif restart == "other_dim":
            files["other.toml"] = render(sections(copy.deepcopy(BASES["shapes3d"]))).encode()
    else:   # sigint
        base["end_time"] = 2.0
        files["scene.toml"] = render(sections(base)).encode()
    delay = rng.uniform(0.02, 4.0)
    # sigint: half the cases start the command with SIGINT blocked across exec, as a launcher
    # keeping the contract over the interpreter's own start-up does (site's .pth files, runpy:
    # no project code runs there), the others plainly, once that start-up is over (0.5 s)
    blocked = rng.random() < 0.5
    return {"index": index, "kind": kind, "files": files, "argv": argv, "restart": restart,
            "delay": delay if blocked else 0.5 + (delay - 0.02) * 3.5 / 3.98, "blocked": blocked,
            "entry": rng.choice(["module", "script"])}


def _bench_argv(rng: random.Random, argv: list[str]) -> list[str]:
    """The drawn run flags that bench takes too, as a `bench` case's extra flags (marked by a
    leading "bench"), with bench's own step counts."""
    run_only = {"--out", "--checkpoint-every", "--walltime", "--overwrite", "--no-invariants"}
    out, i = ["bench"], 0
    while i < len(argv):
        takes = argv[i] not in SWITCHES
        if argv[i] not in run_only:
            out += argv[i:i + 1 + takes]
        i += 1 + takes
    for flag in rng.sample(sorted(BENCH_VALUES), rng.randint(1, 2)):
        out += [flag, rng.choice(BENCH_VALUES[flag])]
    return out


def _prepare_restart(c: dict, tmp: str) -> list[str]:
    """A real 40-step run with checkpoints in {tmp}/run, then damaged as the case says."""
    from sphgraph import checkpoint as ck
    from sphgraph.cli import main
    run = os.path.join(tmp, "run")
    ranks = ["--comm", "mock", "--ranks", "2"] if c["restart"] == "other_ranks" else []
    with contextlib.redirect_stderr(io.StringIO()):
        rc = main(["run", os.path.join(tmp, "scene.toml"), "--out", run, "--max-steps", "40",
                   "--checkpoint-every", "20", "--quiet", *ranks])
    assert rc == 0, "the restart case's base run failed"
    cks = ck.list_checkpoints(run)
    newest = cks[-1][1]
    how, scene = c["restart"], os.path.join(tmp, "scene.toml")
    if how == "truncate":
        with open(newest, "r+b") as f:
            f.truncate(os.path.getsize(newest) // 2)
    elif how == "other_scene":
        scene = os.path.join(tmp, "other.toml")
    elif how == "other_format":
        for _, p in cks:
            x = ck.load(p)
            meta = dict(x.meta)
            meta.pop("sha256")
            meta["format"], meta["version"] = 2, "9.9"
            ck.write(p, meta, [b.arrays() for b in x.blocks], x.cuts)
    elif how == "fifo":
        for _, p in cks:
            os.remove(p)
            os.mkfifo(p)
    elif how == "folder":
        for _, p in cks:
            os.remove(p)
            os.mkdir(p)
    elif how == "no_master":
        os.remove(os.path.join(run, "output.h5"))
    elif how == "bad_master":
        with open(os.path.join(run, "output.h5"), "r+b") as f:
            f.seek(100)
            f.write(b"\0" * 200)
    elif how == "file":
        return ["run", scene, "--restart", os.path.join(run, "output.h5"), "--quiet"]
    elif how == "empty":
        for _, p in cks:
            os.remove(p)
    elif how == "bitflip":         # every checkpoint damaged inside (digest or HDF5 structure)
        rng = random.Random(c["index"])
        for _, p in cks:
            with open(p, "r+b") as f:
                size = os.path.getsize(p)
                for at in sorted(rng.randrange(size) for _ in range(rng.choice([1, 4, 16]))):
                    f.seek(at)
                    b = f.read(1)
                    f.seek(-1, os.SEEK_CUR)
                    f.write(bytes([(b[0] if b else 0) ^ 0xFF]))
    elif how == "dev_zero_link":   # the newest a link to a device, the others gone
        for _, p in cks:
            os.remove(p)
        os.symlink("/dev/zero", newest)
    elif how == "sparse_huge":     # the newest grown (sparsely) past the checkpoint size limit
        from sphgraph.files import CHECKPOINT_LIMIT
        for _, p in cks[:-1]:
            os.remove(p)
        try:
            with open(newest, "r+b") as f:
                f.truncate(CHECKPOINT_LIMIT + 1)
        except OSError:           # a filesystem without files that large: the same as truncate
            with open(newest, "r+b") as f:
                f.truncate(os.path.getsize(newest) // 2)
    elif how == "ckpt_dir_file":   # the checkpoints folder a file
        shutil.rmtree(ck.ckpt_dir(run))
        with open(ck.ckpt_dir(run), "wb") as f:
            f.write(b"x")
    elif how == "missing":
        return ["run", scene, "--restart", os.path.join(tmp, "nowhere"), "--quiet"]
    elif how == "other_dim":
        scene = os.path.join(tmp, "other.toml")
    elif how == "precision":
        return ["run", scene, "--restart", run, "--quiet", "--max-steps", "45", "--precision", "float32"]
    elif how == "finished":        # nothing left to run: end_time at or before the checkpoint's time
        return ["run", scene, "--restart", run, "--quiet", "--end-time", "1e-6"]
    elif how == "out_elsewhere":
        return ["run", scene, "--restart", run, "--quiet", "--max-steps", "45", "--out", os.path.join(tmp, "o")]
    elif how == "dp_override":     # a spacing other than the checkpoint's
        return ["run", scene, "--restart", run, "--quiet", "--max-steps", "45", "--dp", "0.04"]
    return ["run", scene, "--restart", run, "--quiet", "--max-steps", "45"]


@contextlib.contextmanager
def _captured_stderr(path):
    """fd 2 and sys.stderr into `path` (C libraries' messages too)."""
    sys.stderr.flush()
    saved = os.dup(2)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    os.dup2(fd, 2)
    os.close(fd)
    old = sys.stderr
    sys.stderr = open(path, "a", buffering=1)
    try:
        yield
    finally:
        sys.stderr.close()
        sys.stderr = old
        os.dup2(saved, 2)
        os.close(saved)


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def run_case(c: dict) -> dict:
    """Run one case in a fresh folder; the outcome and whether it kept the contract."""
    from sphgraph.cli import main
    with tempfile.TemporaryDirectory() as tmp:
        for name, data in c["files"].items():
            with open(os.path.join(tmp, name), "wb") as f:
                f.write(data)
        t0 = time.perf_counter()
        if c["kind"] == "sigint":
            script = os.path.join(os.path.dirname(sys.executable), "sphgraph")
            entry = [script] if c["entry"] == "script" and os.path.exists(script) else [sys.executable, "-m",
                                                                                          "sphgraph"]
            block = (lambda: signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})) if c["blocked"] else None
            p = subprocess.Popen([*entry, "run", os.path.join(tmp, "scene.toml"), "--out", os.path.join(tmp, "o"),
                                  "--quiet"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                                 preexec_fn=block)
            time.sleep(c["delay"])
            p.send_signal(signal.SIGINT)
            _, err = p.communicate(timeout=CASE_SECONDS)
            rc = p.returncode
        else:
            extra = [a.replace("{tmp}", tmp) for a in c["argv"]]
            if extra[:1] == ["bench"]:
                argv = ["bench", os.path.join(tmp, "scene.toml")] + extra[1:]
            elif c["kind"] == "restart":
                argv = _prepare_restart(c, tmp) + extra
            else:
                argv = ["run", os.path.join(tmp, "scene.toml"), "--out", os.path.join(tmp, "o"), "--quiet",
                        "--max-steps", "2"] + extra
            errpath = os.path.join(tmp, "stderr.txt")
            old = signal.signal(signal.SIGALRM, _alarm)
            signal.alarm(CASE_SECONDS)
            try:
                with _captured_stderr(errpath), contextlib.redirect_stdout(io.StringIO()):   # bench's JSON
                    rc = main(argv)
            except _Timeout:
                rc = "timeout"
            finally:
                signal.alarm(0)
                signal.signal(signal.SIGALRM, old)
            with open(errpath, errors="replace") as f:
                err = f.read()
        wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    if c["kind"] == "sigint":
        rss = max(rss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024)
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("sphgraph: warning:")]
    problems = []
    allowed = {0, 1, 2, 130} if c["kind"] == "sigint" else {0, 1, 2}
    if rc == 3 and lines and lines[0].startswith("sphgraph: communication error"):
        allowed.add(3)   # a simulated message fault (--loss, --duplicate): a contracted exit
    if rc not in allowed:
        problems.append(f"exit {rc}")
    if "Traceback" in err:
        problems.append("traceback")
    if len(lines) > 1 or (rc not in (0, 130) and len(lines) != 1):
        problems.append(f"{len(lines)} stderr lines")
    if rss > 2 * GIB:
        problems.append(f"peak memory {rss / GIB:.2f} GiB")
    return {"index": c["index"], "kind": c["kind"], "rc": rc, "wall_s": round(wall, 3), "rss": rss,
            "first_line": lines[0][:300] if lines else "", "problems": problems}


def fast_sample(n: int, seed: int = 0) -> list[dict]:
    """The suite's sample: the first `n` non-SIGINT cases of `seed`, run in this process."""
    out, i = [], 0
    while len(out) < n:
        c = case(seed, i)
        i += 1
        if c["kind"] != "sigint":
            out.append(run_case(c))
    return out


def _worker(args):
    seed, index = args
    return run_case(case(seed, index))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", help="write every outcome here")
    a = ap.parse_args(argv)
    import multiprocessing as mp
    t0 = time.perf_counter()
    results = []
    with mp.get_context("spawn").Pool(a.workers, maxtasksperchild=200) as pool:
        for r in pool.imap_unordered(_worker, [(a.seed, i) for i in range(a.cases)]):
            results.append(r)
            if r["problems"]:
                print(f"case {r['index']} ({r['kind']}): {', '.join(r['problems'])}: {r['first_line']}", flush=True)
    wall = time.perf_counter() - t0
    tally: dict = {}
    for r in results:
        tally.setdefault(r["kind"], {}).setdefault(str(r["rc"]), 0)
        tally[r["kind"]][str(r["rc"])] += 1
    bad = [r for r in results if r["problems"]]
    summary = {"cases": len(results), "seed": a.seed, "wall_s": round(wall, 1), "broken": len(bad),
               "peak_rss_gib": round(max(r["rss"] for r in results) / GIB, 3),
               "slowest_s": max(r["wall_s"] for r in results), "exits_by_kind": tally}
    print(json.dumps(summary, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"summary": summary, "results": results}, f)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
