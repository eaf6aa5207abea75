"""Checkpoints and restart (docs/long-runs.md).

A checkpoint is the whole solver state, enough to continue a run bit-identically
(float64, CPU, same rank count): ``DIR/checkpoints/ckpt_<step>.h5`` holding

* one group per rank ``/rank_NNNN`` with every `Particles` field (``id``,
  ``kind``, ``pos``, ``vel``, ``rho`` and the Verlet history ``vel_m1``,
  ``rho_m1``) in the rows' *current* order on that rank (the cell sort is
  stable, so the order is part of the state), and ``/cuts`` (the slab cuts);
* root attributes: ``step``, ``time``, ``dt``, the output cadence (``next_out``,
  ``frames`` = next frame index, ``last_saved``), ``next_checkpoint``, the
  scene text, ``schedule``, ``precision``, ``backend``, ``comm``, ``ranks``,
  ``axis``, ``integrator``, the load balancer's state (JSON) and
  ``sha256``: a checksum over every array (dtype, shape, bytes) and every
  other attribute, verified on load;
* with ``[domain] exclude_outside``: ``/exclusions`` (``step``, ``time``, ``id``,
  ``cause``), every exclusion recorded up to the checkpoint's step, gathered from
  all ranks, so that a restart after a SIGKILL (which leaves no ``/exclusions`` in
  ``output.h5``) still ends with the complete table.

Writing is collective (every rank's rows are gathered to the root, which
writes) and atomic: a temporary file, fsync, ``os.replace``, fsync of the
directory. The last `KEEP` checkpoints are kept. Restart picks the newest one
whose checksum verifies, skipping (and reporting) damaged ones.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

import h5py
import numpy as np

from . import __version__
from .errors import InputError
from .files import CHECKPOINT_LIMIT, check_regular, disk_full, h5_atomic, is_no_space, parse_toml
from .particles import Particles
from .ranges import check_flag

CKPT_DIR = "checkpoints"
KEEP = 2
FORMAT = 1
FIELDS = ("id", "kind", "pos", "vel", "rho", "vel_m1", "rho_m1")
EXCLUSION_FIELDS = ("step", "time", "id", "cause", "position", "velocity", "density")   # /exclusions
# (sphgraph.features.Features.exclusions); checkpoints written before the last three had the first four
_NAME = re.compile(r"^ckpt_(\d+)\.h5$")
_EVERY_FORM = "N (steps, an integer >= 1) or Ts (simulated seconds, e.g. 0.05s)"


# --------------------------------------------------------------------------- cadence
def parse_every(text) -> tuple[str, float] | None:
    """``--checkpoint-every``: "200" -> ("steps", 200); "0.05s" -> ("time", 0.05); None -> None."""
    if text is None:
        return None
    if isinstance(text, bool):
        raise InputError(f"--checkpoint-every: expected {_EVERY_FORM}, got {text!r}")
    if isinstance(text, int):
        if text < 1:
            raise InputError(f"--checkpoint-every: expected {_EVERY_FORM}, got {text!r}")
        return ("steps", int(text))
    s = str(text).strip()
    try:
        if s.endswith("s"):
            t = float(s[:-1])
            if math.isfinite(t) and t > 0:
                return ("time", t)
        elif re.fullmatch(r"\d+", s) and int(s) >= 1:
            return ("steps", int(s))
    except ValueError:
        pass
    raise InputError(f"--checkpoint-every: expected {_EVERY_FORM}, got {text!r}")


def parse_walltime(value) -> float | None:
    if value is None:
        return None
    try:
        w = float(value)
    except (TypeError, ValueError):
        w = float("nan")
    if isinstance(value, bool) or not (math.isfinite(w) and w > 0):
        raise InputError(f"--walltime: expected a number of seconds > 0, got {value!r}")
    return check_flag("--walltime", w)


# --------------------------------------------------------------------------- file format
def _canon(v):
    """Attribute value as plain Python (for the checksum and the loaded meta)."""
    if isinstance(v, bytes):
        return v.decode("utf-8")
    if isinstance(v, np.generic):
        return v.item()
    return v


def _digest(meta: dict, blocks: list[dict], cuts: np.ndarray | None, exclusions: dict | None = None) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({k: meta[k] for k in sorted(meta) if k != "sha256"}, sort_keys=True).encode())
    for r, b in enumerate(blocks):
        for name in FIELDS:
            a = np.ascontiguousarray(b[name])
            h.update(f"{r}/{name}:{a.dtype.str}:{a.shape}".encode())
            h.update(a.tobytes())
    if cuts is not None:
        h.update(np.ascontiguousarray(cuts, np.float64).tobytes())
    if exclusions is not None:   # absent from checkpoints without exclude_outside: their sums are unchanged
        for name in (k for k in EXCLUSION_FIELDS if k in exclusions):
            a = np.ascontiguousarray(exclusions[name])
            h.update(f"exclusions/{name}:{a.dtype.str}:{a.shape}".encode())
            h.update(a.tobytes())
    return h.hexdigest()


def ckpt_dir(out_dir) -> str:
    return os.path.join(os.fspath(out_dir), CKPT_DIR)


def ckpt_path(out_dir, step: int) -> str:
    return os.path.join(ckpt_dir(out_dir), f"ckpt_{step:09d}.h5")


def list_checkpoints(out_dir) -> list[tuple[int, str]]:
    """(step, path) of every ``ckpt_<step>.h5`` (complete names only), oldest first."""
    d = ckpt_dir(out_dir)
    out = []
    if os.path.isdir(d):
        for name in os.listdir(d):
            m = _NAME.match(name)
            if m:
                out.append((int(m.group(1)), os.path.join(d, name)))
    return sorted(out)


def write(path: str, meta: dict, blocks: list[dict], cuts, fsync: bool = True,
          exclusions: dict | None = None) -> str:
    """Write one checkpoint file atomically (temp file, fsync, rename)."""
    meta = {k: _canon(v) for k, v in meta.items()}
    meta["sha256"] = _digest(meta, blocks, cuts, exclusions)
    d = os.path.dirname(path)
    try:
        os.makedirs(d, exist_ok=True)
    except OSError as e:
        if is_no_space(e):
            raise disk_full(d) from None
        raise
    size = sum(np.asarray(b[name]).nbytes for b in blocks for name in FIELDS)
    # a full disk: DiskFullError (exit 1), no temp file left, the older checkpoints intact
    with h5_atomic(path, fsync=fsync, size_hint=size, libver=("v110", "latest")) as f:
        for k, v in meta.items():
            f.attrs[k] = v
        for r, b in enumerate(blocks):
            g = f.create_group(f"rank_{r:04d}")
            for name in FIELDS:
                g.create_dataset(name, data=np.ascontiguousarray(b[name]))
        if cuts is not None:
            f.create_dataset("cuts", data=np.asarray(cuts, np.float64))
        if exclusions is not None:
            g = f.create_group("exclusions")
            for name in EXCLUSION_FIELDS:
                g.create_dataset(name, data=np.ascontiguousarray(exclusions[name]))
    return path


@dataclass
class Checkpoint:
    path: str
    meta: dict
    blocks: list            # Particles per rank, in stored row order
    cuts: np.ndarray | None
    exclusions: dict | None = None   # /exclusions columns up to `step` (exclude_outside scenes)

    @property
    def step(self) -> int:
        return int(self.meta["step"])

    @property
    def time(self) -> float:
        return float(self.meta["time"])


# what h5py raises for a damaged file: HDF5's errors by class (a failed metadata checksum
# is a RuntimeError), and a size field that asks for more than memory holds
_UNREADABLE = (OSError, KeyError, ValueError, TypeError, AttributeError, RuntimeError, IndexError,
               OverflowError, MemoryError)


def load(path) -> Checkpoint:
    """Read and verify one checkpoint; `InputError` when unreadable or the checksum fails."""
    path = os.fspath(path)
    check_regular(path, CHECKPOINT_LIMIT, "checkpoint file")   # not a FIFO or a device: h5py would block
    try:
        with h5py.File(path, "r") as f:
            meta = {k: _canon(v) for k, v in f.attrs.items()}
            _check_meta(path, meta)
            n = int(meta["ranks"])
            raw = [{name: f[f"rank_{r:04d}/{name}"][()] for name in FIELDS} for r in range(n)]
            cuts = f["cuts"][()] if "cuts" in f else None
            exclusions = ({name: f[f"exclusions/{name}"][()] for name in EXCLUSION_FIELDS
                           if name in f["exclusions"]} if "exclusions" in f else None)
    except _UNREADABLE as e:
        raise InputError(f"{path}: checkpoint: expected a complete sphgraph checkpoint, "
                         f"got an unreadable file ({type(e).__name__}: {e})") from None
    if meta.get("sha256") != _digest(meta, raw, cuts, exclusions):
        raise InputError(f"{path}: checkpoint: expected checksum {meta.get('sha256')}, "
                         "got different data (damaged file)")
    try:
        blocks = [Particles(**{k: np.ascontiguousarray(b[k]) for k in FIELDS}) for b in raw]
        if sum(b.n for b in blocks) != meta["n_total"] or any(b.dim != meta["dim"] for b in blocks):
            raise ValueError(f"{sum(b.n for b in blocks)} rows of dim {blocks[0].dim if blocks else '?'} "
                             f"where the attributes say {meta['n_total']} of dim {meta['dim']}")
    except (ValueError, TypeError, IndexError) as e:
        raise InputError(f"{path}: checkpoint: expected rows of one state, got {e}") from None
    return Checkpoint(path, meta, blocks, cuts, exclusions)


# attributes a checkpoint must hold, by type (a checkpoint of another format or a foreign file
# is refused in one line before any of its numbers is used)
_META = {"format": int, "step": int, "time": float, "dt": float, "next_out": float, "frames": int,
         "last_saved": int, "next_checkpoint": float, "scene": str, "schedule": str, "precision": str,
         "ranks": int, "axis": int, "integrator": str, "dim": int, "n_total": int, "sha256": str}


def _check_meta(path, meta: dict) -> None:
    if meta.get("format") != FORMAT or type(meta.get("format")) is not int:
        raise InputError(f"{path}: checkpoint: format: expected {FORMAT} (the checkpoints this version "
                         f"{__version__} writes), got {meta.get('format')!r} (version {meta.get('version')!r})")
    for key, kind in _META.items():
        v = meta.get(key)
        if kind is float:   # next_checkpoint is inf when no time cadence is set
            ok = (isinstance(v, (int, float)) and not isinstance(v, bool)
                  and (math.isfinite(v) or (key == "next_checkpoint" and v == math.inf)))
        else:
            ok = isinstance(v, kind) and not isinstance(v, bool)
        if not ok:
            raise InputError(f"{path}: checkpoint: {key}: expected {kind.__name__}, got {v!r}")
    if not (1 <= meta["ranks"] <= 4096 and meta["dim"] in (2, 3) and meta["precision"] in ("float32", "float64")
            and meta["step"] >= 0 and meta["n_total"] >= 1):
        raise InputError(f"{path}: checkpoint: expected ranks 1-4096, dim 2 or 3, a known precision, "
                         f"got ranks {meta['ranks']}, dim {meta['dim']}, precision {meta['precision']!r}")


def find_latest(out_dir, warn=True) -> Checkpoint:
    """The newest checkpoint in ``DIR/checkpoints`` whose checksum verifies.

    `out_dir` may also be a checkpoint file. Damaged newer ones are reported on
    stderr and skipped. Raises `InputError` when none is usable.
    """
    out_dir = os.fspath(out_dir)
    if os.path.isfile(out_dir):
        return load(out_dir)
    if not os.path.isdir(out_dir):
        raise InputError(f"{out_dir}: --restart: expected a run directory with {CKPT_DIR}/, got no directory")
    problems = []
    for step, path in reversed(list_checkpoints(out_dir)):
        try:
            return load(path)
        except InputError as e:
            problems.append(str(e))
            if warn:
                print(f"sphgraph: warning: skipping {e}", file=sys.stderr)
    raise InputError(f"{out_dir}: --restart: expected a valid checkpoint in {CKPT_DIR}/, got "
                     + (f"{len(problems)} damaged" if problems else "none"))


def run_dir_of(restart) -> str:
    """The run directory of ``--restart DIR`` (or of a checkpoint file given instead)."""
    restart = os.fspath(restart)
    if os.path.isfile(restart):
        return os.path.dirname(os.path.dirname(os.path.abspath(restart)))
    return restart


# --------------------------------------------------------------------------- state
def _balancer(sim):
    return next((c.balancer for c in sim.contexts if c.balancer is not None), None)


def _balancer_state(sim) -> str:
    b = _balancer(sim)
    if b is None:
        return "{}"
    rec = {k: [np.asarray(x).tolist() for x in v] for k, v in b.records.items()}
    return json.dumps({"speed": None if b.speed is None else np.asarray(b.speed).tolist(),
                       "force_s": {str(k): v for k, v in b.force_s.items()},
                       "steps_since": {str(k): v for k, v in b.steps_since.items()},
                       "records": rec, "check_s": b.check_s, "apply_s": b.apply_s})


def _sampler_state(sim) -> str:
    """/probes and /forces samples so far (root's `ProbeSampler` of a run that samples), or "{}"."""
    sampler = sim.probe_sampler
    return "{}" if sampler is None else sampler.state_json()


def _restore_balancer(sim, text: str, same_ranks: bool) -> None:
    d = json.loads(text or "{}")
    if not d:
        return
    for c in sim.contexts:
        b = c.balancer
        if b is None:
            continue
        if same_ranks:
            b.speed = None if d["speed"] is None else np.asarray(d["speed"])
            b.force_s = {int(k): v for k, v in d["force_s"].items() if int(k) == c.rank}
            b.steps_since = {int(k): v for k, v in d["steps_since"].items()}
        if c.rank == 0 and same_ranks:   # per-rank columns: only for the same rank count
            b.records = {k: list(v) for k, v in d["records"].items()}
            b.check_s, b.apply_s = d["check_s"], d["apply_s"]


def gather_state(sim) -> list[dict] | None:
    """Every rank's raw rows (current order) on the root, in rank order; None elsewhere."""
    per = {}
    for c in sim.contexts:
        sim.compute.sync_host(c.state)
        per[c.rank] = {k: v for k, v in c.state.particles.arrays().items() if k in FIELDS}
    return sim.comm.gather_rows(per)


def save(sim, out_dir, *, next_out: float, frames: int, last_saved: int, next_checkpoint: float,
         fsync: bool = True) -> str | None:
    """Collective: write ``ckpt_<step>.h5`` (root) and keep the newest `KEEP`. Returns its path."""
    blocks = gather_state(sim)
    # every exclusion so far (a gather under MPI: on every rank, like gather_state)
    exclusions = sim.features.exclusions(sim) if sim.features.exclude_outside else None
    path = ckpt_path(out_dir, sim.step_count)
    if blocks is not None:
        root_ctx = next(c for c in sim.contexts if c.rank == 0)
        cuts = root_ctx.domain.cuts if root_ctx.domain is not None else None
        meta = {"format": FORMAT, "version": __version__, "step": int(sim.step_count),
                "time": float(sim.time), "dt": float(root_ctx.state.dt),
                "next_out": float(next_out), "frames": int(frames), "last_saved": int(last_saved),
                "next_checkpoint": float(next_checkpoint), "scene": sim.scene.text,
                "schedule": sim.schedule.name, "precision": sim.precision, "backend": sim.compute.name,
                "comm": sim.comm.name, "ranks": int(sim.nranks),
                "axis": -1 if sim.axis is None else int(sim.axis), "integrator": sim.integrator,
                "dim": int(sim.dim), "n_total": int(sum(len(b["id"]) for b in blocks)), "balancer": _balancer_state(sim),
                "probes": _sampler_state(sim),
                "written_unix": time.time()}
        write(path, meta, blocks, cuts, fsync=fsync, exclusions=exclusions)
        prune(out_dir, keep=KEEP)
    if len(sim.comm.local_ranks) < sim.nranks:
        sim.comm.barrier()   # the file is complete before any rank goes on (a stop exits right after)
    return path


def prune(out_dir, keep: int = KEEP, after_step: int | None = None) -> None:
    """Delete all but the newest `keep` checkpoints (and, with `after_step`, every newer one)."""
    ck = list_checkpoints(out_dir)
    if after_step is not None:
        for step, path in ck:
            if step > after_step:
                os.remove(path)
        ck = [(s, p) for s, p in ck if s <= after_step]
    for _, path in ck[:-keep] if keep else ck:
        os.remove(path)
    d = ckpt_dir(out_dir)
    if os.path.isdir(d):
        for name in os.listdir(d):   # temp files of a write that was killed
            if name.startswith(".ckpt_") and name.endswith(".tmp"):
                try:
                    os.remove(os.path.join(d, name))
                except OSError:
                    pass


def check_scene(ckpt: Checkpoint, scene) -> None:
    """The run's scene must be the checkpoint's (end_time and name may differ)."""
    from .scene import Scene
    stored = Scene._validate(parse_toml(ckpt.meta["scene"], f"{ckpt.path}:scene"), f"{ckpt.path}:scene",
                             default_name=scene.name, text=ckpt.meta["scene"])
    a, b = stored.to_dict(), scene.to_dict()
    for d in (a, b):
        d.pop("end_time", None)
        d.pop("name", None)
    if a != b:
        key = next((k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)), "?")
        raise InputError(f"{scene.source}: {key}: expected the checkpoint's scene ({ckpt.path}; "
                         f"only end_time may change on restart), got {b.get(key)!r} instead of {a.get(key)!r}")


def restore(sim, ckpt: Checkpoint) -> None:
    """Step count, time and balancer state of `ckpt` into a `Simulation` built from its rows."""
    sim.step_count = int(ckpt.meta["step"])
    sim.time = float(ckpt.meta["time"])
    for c in sim.contexts:
        c.state.time = sim.time
        c.state.step = sim.step_count
        c.state.dt = float(ckpt.meta["dt"])
    _restore_balancer(sim, ckpt.meta.get("balancer", "{}"), int(ckpt.meta["ranks"]) == sim.nranks)
    sampler = sim.probe_sampler
    text = ckpt.meta.get("probes", "{}")
    if sampler is not None and text not in (None, "", "{}"):
        sampler.restore_json(text)
    if ckpt.exclusions is not None and sim.features.exclude_outside:
        sim.features.restore_exclusions(ckpt.exclusions, sim.step_count,
                                        root=any(c.rank == 0 for c in sim.contexts))


def blocks_for(ckpt: Checkpoint, dtype) -> list[Particles]:
    """The checkpoint's per-rank rows with velocity and density in `dtype`."""
    out = []
    for b in ckpt.blocks:
        a = b.arrays()
        for k in ("vel", "rho", "vel_m1", "rho_m1"):
            a[k] = np.ascontiguousarray(a[k], dtype=dtype)
        out.append(Particles(**a))
    return out


# --------------------------------------------------------------------------- the run loop's helper
@dataclass
class Keeper:
    """Checkpoint cadence and clean stops (SIGTERM, --walltime) inside `sphgraph.run`."""

    sim: object
    out_dir: object
    every: tuple | None = None
    walltime: float | None = None
    next_time: float = math.inf
    t_start: float = field(default_factory=time.perf_counter)
    signal_name: str | None = None
    last_step: int = -1
    last_path: str | None = None
    _old: dict = field(default_factory=dict)
    agree_every: int = 10     # MPI: steps between agreements on a stop (one tiny allreduce)

    def __post_init__(self):
        if self.every is not None and self.every[0] == "time" and not math.isfinite(self.next_time):
            p = self.every[1]
            self.next_time = (math.floor(self.sim.time / p + 1e-9) + 1) * p

    # signals: only the main thread may install handlers (in-process callers elsewhere skip it)
    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGTERM,):
            try:
                self._old[sig] = signal.signal(sig, self._on_signal)
            except (ValueError, OSError):
                pass

    def uninstall(self) -> None:
        for sig, old in self._old.items():
            try:
                signal.signal(sig, old)
            except (ValueError, OSError, TypeError):
                pass
        self._old.clear()

    def _on_signal(self, signum, frame):
        self.signal_name = signal.Signals(signum).name

    def due(self) -> bool:
        if self.every is None:
            return False
        kind, v = self.every
        if kind == "steps":
            return self.sim.step_count % int(v) == 0
        return self.sim.time >= self.next_time - 1e-12

    def save(self, next_out, frames, last_saved) -> str:
        if self.every is not None and self.every[0] == "time":
            p = self.every[1]   # no loop: a tiny period must not stall (t + p == t)
            if self.next_time <= self.sim.time + 1e-12:
                self.next_time = max(self.next_time + p, (math.floor(self.sim.time / p + 1e-9) + 1) * p)
                if self.next_time <= self.sim.time:
                    self.next_time = math.inf
        self.last_path = save(self.sim, self.out_dir, next_out=next_out, frames=frames,
                              last_saved=last_saved, next_checkpoint=self.next_time)
        self.last_step = self.sim.step_count
        return self.last_path

    def stop_reason(self) -> str | None:
        """Why to stop now ("SIGTERM", "walltime") or None; the same on every rank."""
        reason = self.signal_name
        if reason is None and self.walltime is not None and time.perf_counter() - self.t_start >= self.walltime:
            reason = "walltime"
        sim = self.sim
        if len(sim.comm.local_ranks) < sim.nranks:      # MPI: agree (every few steps)
            if sim.step_count % self.agree_every:
                return None
            code = {None: 0, "walltime": 1}.get(reason, 2)
            code = int(sim.comm.allreduce(code, "max"))
            reason = {0: None, 1: "walltime"}.get(code, "SIGTERM")
        return reason
