"""HDF5 output that survives SIGKILL, its XDMF companion, and readers.

Layout of an output directory (DESIGN.md §5 is the contract)::

    DIR/output.h5                 master: root attrs, /frames links, /timing, groups
    DIR/output.xmf                XDMF 2 temporal collection (ParaView, vtkXdmfReader)
    DIR/frames/frame_NNNNNN.h5    one file per frame; group /frame holds the data

Master ``output.h5``
    Root attributes from the caller (``scene``, ``version``, ``backend``, ``comm``,
    ``ranks``, ``schedule``, ``precision``, ``dim``, ``dp``, ``h``) plus
    ``output_format`` (= 1). ``/frames/NNNNNN`` is an HDF5 *external link* to
    ``frames/frame_NNNNNN.h5:/frame``, so ``f["/frames/000003"]["position"]`` and
    ``f["/frames/000003"].attrs["time"]`` work through h5py transparently.
    ``/timing`` holds parallel datasets ``rank`` (int32), ``step`` (int64),
    ``task`` and ``lane`` (fixed-length UTF-8 strings), ``start`` and ``end``
    (float64 seconds). Other groups (``/probes``, ``/forces``, ``/balance``...)
    are written by `OutputWriter.write_group`.

Frame file ``frames/frame_NNNNNN.h5``
    Group ``/frame`` with attrs ``index``, ``time``, ``step`` and datasets ``id``
    (int64), ``kind`` (int8), ``position`` and ``velocity`` (N x dim), ``density``,
    ``pressure``; rows in id order.

Why it survives SIGKILL: nothing is ever modified in place. A frame is written to
a temporary file, fsynced and renamed over its final name (rename is atomic on
POSIX; :func:`sphgraph.files.h5_atomic`, which also turns a full disk into one clean
error). The master is small (links, attrs, timing), so it is rebuilt from the
writer's memory into a temporary file and renamed over ``output.h5`` after each
frame; the XDMF likewise. A kill at any moment leaves the previous complete
master, which links only frames that were complete before it was written. The
rename alone is enough for a killed process (the page cache survives it); the
fsyncs extend that to a power loss or an OS crash.

Readers open frame files directly (the link's target), not through the master's
links, so a missing or damaged frame file is reported as a warning and skipped
instead of failing the whole read.
"""
from __future__ import annotations

import os
import shutil
import warnings

import h5py
import numpy as np

from .errors import InputError
from .files import CHECKPOINT_LIMIT, check_regular, guard_write, h5_atomic
from .xdmf import FieldSpec, FrameSpec, write_xdmf

__all__ = [
    "OutputWriter", "OutputWarning", "prepare_out_dir", "list_frames", "read_frame",
    "read_attrs", "read_timing", "read_group",
    "MASTER_NAME", "XDMF_NAME", "FRAMES_DIR", "FRAME_GROUP", "FRAME_FIELDS", "TIMING_FIELDS",
]

MASTER_NAME = "output.h5"
XDMF_NAME = "output.xmf"
FRAMES_DIR = "frames"
FRAME_GROUP = "/frame"
OUTPUT_FORMAT = 1
FRAME_FIELDS = ("id", "kind", "position", "velocity", "density", "pressure")
TIMING_FIELDS = ("rank", "step", "task", "lane", "start", "end", "bytes")
_TIMING_DTYPES = {"rank": np.int32, "step": np.int64, "start": np.float64, "end": np.float64, "bytes": np.int64}
_PRECISIONS = {"float32": np.float32, "float64": np.float64}
# names the master reserves for itself; write_group may not replace them
_RESERVED = {"frames", "timing"}


class OutputWarning(UserWarning):
    """A damaged or missing piece of output was skipped while reading."""


def _frame_name(index: int) -> str:
    return f"{index:06d}"


def _frame_relpath(index: int) -> str:
    return f"{FRAMES_DIR}/frame_{index:06d}.h5"


def _to_attr(value):
    """Root attribute values as HDF5 understands them (str, numbers, arrays)."""
    if value is None:
        raise ValueError("output attribute values may not be None")
    if isinstance(value, (str, bytes, bool, int, float, np.generic, np.ndarray)):
        return value
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, str) for v in value):
            return np.array(value, dtype=h5py.string_dtype("utf-8"))
        return np.asarray(value)
    return str(value)


def _from_attr(value):
    """HDF5 attribute values as plain Python (str, int, float) where they are scalars."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OS":
            return [v.decode("utf-8") if isinstance(v, bytes) else v for v in value.tolist()]
        return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def _encode_strings(values: np.ndarray) -> np.ndarray:
    """str array -> fixed-length UTF-8 bytes array (via the few distinct names: fast).

    Arrays that are already bytes pass through unchanged."""
    values = np.asarray(values)
    if values.dtype.kind == "S":
        return values
    if values.dtype.kind == "O":  # e.g. TaskKind members: store their value, not repr
        values = np.array([str(getattr(v, "value", v)) for v in values.ravel().tolist()],
                          dtype=str).reshape(values.shape)
    values = values.astype(str)
    if values.size == 0:
        return np.zeros(values.shape, "S1")
    uniq, inv = np.unique(values, return_inverse=True)
    enc = np.array([u.encode("utf-8") for u in uniq.tolist()])
    return enc[inv.reshape(values.shape)]


def _create_strings(g: h5py.Group, name: str, values: np.ndarray) -> None:
    """Dataset of fixed-length UTF-8 strings (h5py/HDF5 2 cannot convert bytes to a
    UTF-8 file type, so the file type is also used as the memory type)."""
    enc = _encode_strings(values)
    dt = h5py.string_dtype("utf-8", max(1, enc.dtype.itemsize))
    d = g.create_dataset(name, shape=enc.shape, dtype=dt)
    if enc.size:
        d.id.write(h5py.h5s.ALL, h5py.h5s.ALL, np.ascontiguousarray(enc.astype(dt)),
                   mtype=d.id.get_type())


def _decode_strings(values: np.ndarray) -> np.ndarray:
    """bytes/object array from HDF5 -> numpy str array."""
    values = np.asarray(values)
    if values.dtype.kind not in "SO":
        return values
    if values.size == 0:
        return np.zeros(values.shape, dtype=str)
    uniq, inv = np.unique(values, return_inverse=True)
    dec = np.array([u.decode("utf-8") if isinstance(u, bytes) else str(u) for u in uniq.tolist()],
                   dtype=str)
    return dec[inv.reshape(values.shape)]


def _write_tree(g: h5py.Group, datasets: dict, attrs: dict | None) -> None:
    """Datasets (nested dicts become subgroups) and attrs into group `g`."""
    for key, value in datasets.items():
        if isinstance(value, dict):
            _write_tree(g.create_group(key), value, None)
            continue
        arr = np.asarray(value)
        if arr.dtype.kind == "U":
            _create_strings(g, key, arr)
        else:
            g.create_dataset(key, data=arr)
    for key, value in (attrs or {}).items():
        g.attrs[key] = _to_attr(value)


def _read_tree(g: h5py.Group) -> dict:
    out: dict = {}
    for key, obj in g.items():
        if isinstance(obj, h5py.Group):
            out[key] = _read_tree(obj)
        else:
            arr = obj[()]
            out[key] = _decode_strings(arr) if isinstance(arr, np.ndarray) else _from_attr(arr)
    attrs = {k: _from_attr(v) for k, v in g.attrs.items()}
    if attrs:
        out["attrs"] = attrs
    return out


def _split_group(tree: dict) -> tuple[dict, dict]:
    tree = dict(tree)
    attrs = tree.pop("attrs", {})
    return tree, attrs


class OutputWriter:
    """Crash-safe HDF5 output of one run (master file + one file per frame).

    Parameters
    ----------
    out_dir : str or os.PathLike
        Output directory; call `prepare_out_dir` first (it refuses to clobber a
        previous run). The constructor refuses an existing ``output.h5`` too.
    root_attrs : dict
        Root attributes of ``output.h5`` (DESIGN.md §5: ``scene``, ``version``,
        ``backend``, ``comm``, ``ranks``, ``schedule``, ``precision``, ``dim``,
        ``dp``, ``h``). ``dim`` and ``precision`` are filled in from the arguments
        when missing and must agree with them when present.
    dim : int
        2 or 3.
    precision : {"float32", "float64"}
        Run precision: dtype of ``velocity``, ``density`` and ``pressure``.
        ``position`` keeps float64 when it is given in float64 (particle positions
        are held in float64 in float32 runs too).
    fsync : bool, optional
        fsync every file before its rename (default True). Renames alone already
        survive SIGKILL; fsync also survives a power loss.

    Notes
    -----
    Creates ``DIR/frames/`` and an initial ``DIR/output.h5`` (root attrs, no
    frames), so the directory is marked as used from the start. Usable as a
    context manager; leaving the block closes the writer even on an exception,
    so earlier frames of a failed run stay readable.
    """

    def __init__(self, out_dir, root_attrs: dict, dim: int, precision: str, *,
                 fsync: bool = True, _existing: bool = False):
        if dim not in (2, 3):
            raise ValueError(f"OutputWriter: dim must be 2 or 3, got {dim!r}")
        if precision not in _PRECISIONS:
            raise ValueError(f"OutputWriter: precision must be one of {sorted(_PRECISIONS)}, "
                             f"got {precision!r}")
        self.out_dir = os.fspath(out_dir)
        self.dim = int(dim)
        self.precision = precision
        self.dtype = np.dtype(_PRECISIONS[precision])
        self.fsync = fsync
        attrs = dict(root_attrs)
        for key, value in (("dim", self.dim), ("precision", precision)):
            if key in attrs and _from_attr(attrs[key]) != value:
                raise ValueError(f"OutputWriter: root attr {key}={attrs[key]!r} "
                                 f"disagrees with argument {value!r}")
            attrs[key] = value
        attrs.setdefault("output_format", OUTPUT_FORMAT)
        self.root_attrs = {k: _to_attr(v) for k, v in attrs.items()}
        self._frames: dict[int, FrameSpec] = {}
        self._frame_meta: dict[int, tuple[float, int]] = {}   # index -> (time, step)
        self._timing_done: dict[str, np.ndarray] = _empty_timing()
        self._timing_pending: list[dict[str, np.ndarray]] = []
        self._groups: dict[str, tuple[dict, dict]] = {}
        self.closed = False
        if _existing:
            return
        master = os.path.join(self.out_dir, MASTER_NAME)
        if os.path.exists(master):
            raise InputError(f"{self.out_dir}: output exists: expected an empty or new "
                             f"directory (use --overwrite or --restart)")
        os.makedirs(os.path.join(self.out_dir, FRAMES_DIR), exist_ok=True)
        self._write_master()

    # ------------------------------------------------------------------ paths
    @property
    def master_path(self) -> str:
        """Path of ``output.h5``."""
        return os.path.join(self.out_dir, MASTER_NAME)

    @property
    def xdmf_path(self) -> str:
        """Path of ``output.xmf``."""
        return os.path.join(self.out_dir, XDMF_NAME)

    def frame_path(self, index: int) -> str:
        """Path of the file holding frame `index`."""
        return os.path.join(self.out_dir, _frame_relpath(index))

    @property
    def frames(self) -> list[tuple[int, float, int]]:
        """Frames written so far as ``(index, time, step)``, sorted by index."""
        return [(i, *self._frame_meta[i]) for i in sorted(self._frame_meta)]

    # ------------------------------------------------------------------ writing
    def write_frame(self, index: int, time: float, step: int, arrays: dict) -> None:
        """Write one frame atomically and link it from the master.

        Parameters
        ----------
        index : int
            Frame index >= 0 (frame 0 = the initial state). Writing an index
            again replaces that frame.
        time : float
            Physical time [s].
        step : int
            Step number of the frame.
        arrays : dict of ndarray
            ``id`` (N, int), ``kind`` (N, int), ``position`` (N, dim),
            ``velocity`` (N, dim), ``density`` (N,), ``pressure`` (N,), gathered
            from all ranks by the caller. Extra per-particle arrays (leading
            dimension N) are stored too. Rows are sorted by id when they are not
            already in id order.

        Raises
        ------
        ValueError
            Missing field, wrong shape, non-integer ids or a duplicate id (all
            programming errors, hence exit code 3).
        """
        self._check_open()
        index = int(index)
        if index < 0:
            raise ValueError(f"write_frame: index must be >= 0, got {index}")
        data = self._validate_frame(arrays)
        final = self.frame_path(index)
        # a full disk: DiskFullError (exit 1), no temp file, the earlier frames untouched
        with h5_atomic(final, fsync=self.fsync, size_hint=sum(a.nbytes for a in data.values())) as f:
            g = f.create_group(FRAME_GROUP)
            g.attrs["index"] = np.int64(index)
            g.attrs["time"] = np.float64(time)
            g.attrs["step"] = np.int64(step)
            for name, arr in data.items():
                g.create_dataset(name, data=arr)
        n = len(data["id"])
        self._frames[index] = FrameSpec(
            index=index, time=float(time), file=_frame_relpath(index), group=FRAME_GROUP, n=n,
            fields=tuple(FieldSpec(k, v.dtype, v.shape[1:]) for k, v in data.items()))
        self._frame_meta[index] = (float(time), int(step))
        # The frame file is complete before the master links it: a crash between
        # the two leaves an unlinked (harmless) frame file, never a dangling link.
        self._write_master()
        self._write_xdmf()

    def _validate_frame(self, arrays: dict) -> dict[str, np.ndarray]:
        missing = [k for k in FRAME_FIELDS if k not in arrays]
        if missing:
            raise ValueError(f"write_frame: missing arrays {missing}; expected {list(FRAME_FIELDS)}")
        ids = np.asarray(arrays["id"])
        if ids.ndim != 1 or ids.dtype.kind not in "iu":
            raise ValueError(f"write_frame: id must be a 1-D integer array, got "
                             f"{ids.dtype} with shape {ids.shape}")
        n = ids.shape[0]
        expect = {"id": (n,), "kind": (n,), "position": (n, self.dim),
                  "velocity": (n, self.dim), "density": (n,), "pressure": (n,)}
        data: dict[str, np.ndarray] = {}
        for name, value in arrays.items():
            arr = np.asarray(value)
            want = expect.get(name)
            if want is not None and arr.shape != want:
                raise ValueError(f"write_frame: {name} has shape {arr.shape}, expected {want}")
            if want is None and (arr.ndim == 0 or arr.shape[0] != n):
                raise ValueError(f"write_frame: extra array {name} has shape {arr.shape}; "
                                 f"per-particle arrays need {n} rows")
            data[name] = arr
        data["id"] = ids.astype(np.int64, copy=False)
        data["kind"] = data["kind"].astype(np.int8, copy=False)
        pos = data["position"]
        pos_dtype = np.float64 if pos.dtype == np.float64 else self.dtype
        data["position"] = pos.astype(pos_dtype, copy=False)
        for name in ("velocity", "density", "pressure"):
            data[name] = data[name].astype(self.dtype, copy=False)
        # The caller gathers rows in id order; sorting here is cheap insurance
        # (and skipped when they already are).
        d = np.diff(data["id"])
        if d.size and not np.all(d > 0):
            order = np.argsort(data["id"], kind="stable")
            data = {k: v[order] for k, v in data.items()}
            d = np.diff(data["id"])
            if np.any(d == 0):
                dup = data["id"][1:][d == 0][0]
                raise ValueError(f"write_frame: particle id {dup} appears more than once")
        return {k: np.ascontiguousarray(v) for k, v in data.items()}

    def write_timing(self, rank, step, task, lane, start, end, nbytes=0) -> None:
        """Append task timings (parallel arrays, or scalars broadcast to them).

        Parameters
        ----------
        rank, step : array_like of int
        task, lane : array_like of str
            Task name (a ``TaskKind`` value) and lane (compute / comm / copy).
        start, end : array_like of float
            Seconds from run start (virtual seconds under mock MPI).
        nbytes : array_like of int, optional
            Bytes the task posted to other ranks (halo edges, displaced rows, periodic
            images: the payloads' ``nbytes``); 0 for tasks that send nothing.

        Notes
        -----
        Rows are buffered in memory and stored in ``/timing`` of the master with
        the next `write_frame`, `flush` or `close`.
        """
        self._check_open()
        cols = np.broadcast_arrays(np.asarray(rank), np.asarray(step), np.asarray(task),
                                   np.asarray(lane), np.asarray(start), np.asarray(end), np.asarray(nbytes))
        cols = [np.atleast_1d(c).ravel() for c in cols]
        chunk = {}
        for name, col in zip(TIMING_FIELDS, cols):
            if name in ("task", "lane"):
                # encoded once here, so rewriting the master costs only the write
                chunk[name] = _encode_strings(col)
            else:
                chunk[name] = col.astype(_TIMING_DTYPES[name])
        self._timing_pending.append(chunk)

    def write_group(self, name: str, datasets: dict, attrs: dict | None = None) -> None:
        """Store (or replace) group `name` of the master, e.g. ``probes``, ``forces``.

        Parameters
        ----------
        name : str
            Group path under the root (``"probes"`` or ``"forces/body1"``);
            ``frames`` and ``timing`` are reserved.
        datasets : dict
            Name -> array (str arrays are stored as UTF-8 strings); a nested dict
            becomes a subgroup. The name ``attrs`` is reserved for `read_group`.
        attrs : dict, optional
            Attributes of the group.

        Notes
        -----
        The whole group is replaced, and the master is rewritten at once (its
        cost grows with the master's size): call it at output intervals, not
        every step.
        """
        self._check_open()
        key = name.strip("/")
        if not key or key.split("/")[0] in _RESERVED:
            raise ValueError(f"write_group: {name!r} is reserved or empty")
        if "attrs" in datasets:
            raise ValueError("write_group: 'attrs' is reserved as a dataset name")
        # Copy now: the caller may reuse its buffers before the master is written.
        self._groups[key] = (_copy_tree(datasets), dict(attrs or {}))
        self._write_master()

    def flush(self) -> None:
        """Rewrite the master (timing, groups) and the XDMF now."""
        self._check_open()
        self._write_master()
        self._write_xdmf()

    def close(self) -> None:
        """Final master and ``output.xmf``; the writer cannot be used afterwards."""
        if self.closed:
            return
        self._write_master()
        self._write_xdmf()
        self.closed = True

    def truncate(self, after_step: int) -> None:
        """Forget frames and timing rows later than `after_step` (for a restart).

        Frame files of dropped frames are deleted; groups written with
        `write_group` are left to their owners to rewrite.
        """
        self._check_open()
        for index in [i for i, (_, s) in self._frame_meta.items() if s > after_step]:
            del self._frames[index], self._frame_meta[index]
        timing = self._timing()
        keep = timing["step"] <= after_step
        self._timing_done = {k: v[keep] for k, v in timing.items()}
        self._write_master()
        self._write_xdmf()
        for index_file in _frame_files_on_disk(self.out_dir):
            if index_file[0] not in self._frames:
                os.remove(index_file[1])

    def __enter__(self) -> "OutputWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    # ------------------------------------------------------------------ restart
    @classmethod
    def open_existing(cls, out_dir, *, fsync: bool = True) -> "OutputWriter":
        """Reopen a previous run's output to append to it (restart).

        Root attrs, frame links, timing and groups are loaded from the master;
        linked frames whose file is missing or damaged are dropped with an
        `OutputWarning`.

        Raises
        ------
        InputError
            No readable ``output.h5`` in `out_dir`.
        """
        try:
            with _open_master(out_dir) as f:
                attrs = {k: _from_attr(v) for k, v in f.attrs.items()}
                timing = _read_timing_group(f, decode=False)
                groups = {k: _split_group(_read_tree(f[k])) for k in f.keys() if k not in _RESERVED}
        except (OSError, KeyError, ValueError, TypeError, RuntimeError) as e:   # a damaged master
            raise InputError(f"{out_dir}: {MASTER_NAME}: expected a readable sphgraph output, got "
                             f"{type(e).__name__}: {e}") from None
        try:
            dim, precision = int(attrs["dim"]), str(attrs["precision"])
        except KeyError as e:
            raise InputError(f"{out_dir}: {MASTER_NAME}: root attr {e.args[0]} missing: "
                             f"expected sphgraph output") from None
        w = cls(out_dir, attrs, dim, precision, fsync=fsync, _existing=True)
        for index, time, step in list_frames(out_dir):
            try:
                with h5py.File(w.frame_path(index), "r") as ff:
                    g = ff[FRAME_GROUP]
                    fields = tuple(FieldSpec(k, g[k].dtype, g[k].shape[1:]) for k in g.keys())
                    n = g["id"].shape[0]
            except (OSError, KeyError, ValueError, RuntimeError) as e:
                raise InputError(f"{w.frame_path(index)}: frame {index}: expected a readable frame, got "
                                 f"{type(e).__name__}: {e}") from None
            w._frames[index] = FrameSpec(index, time, _frame_relpath(index), FRAME_GROUP, n, fields)
            w._frame_meta[index] = (time, step)
        w._timing_done = timing
        w._groups = groups
        os.makedirs(os.path.join(w.out_dir, FRAMES_DIR), exist_ok=True)
        return w

    # ------------------------------------------------------------------ internals
    def _check_open(self) -> None:
        if self.closed:
            raise ValueError(f"OutputWriter for {self.out_dir} is closed")

    def _timing(self) -> dict[str, np.ndarray]:
        if self._timing_pending:
            parts = [self._timing_done] + self._timing_pending
            self._timing_done = {k: np.concatenate([p[k] for p in parts]) for k in TIMING_FIELDS}
            self._timing_pending = []
        return self._timing_done

    def _write_master(self) -> None:
        """Rebuild output.h5 from memory into a temp file and rename it into place."""
        timing = self._timing()
        size = sum(v.nbytes for v in timing.values()) + sum(
            np.asarray(v).nbytes for d, _ in self._groups.values() for v in _leaves(d))
        # libver v110: dense attribute storage, so a long scene text fits in an attr.
        with h5_atomic(self.master_path, fsync=self.fsync, size_hint=size, libver=("v110", "latest")) as f:
            for key, value in self.root_attrs.items():
                f.attrs[key] = value
            frames = f.create_group("frames")
            for index in sorted(self._frames):
                frames[_frame_name(index)] = h5py.ExternalLink(_frame_relpath(index), FRAME_GROUP)
            timing = self._timing()
            tg = f.create_group("timing")
            for name in TIMING_FIELDS:
                col = timing[name]
                if name in ("task", "lane"):
                    _create_strings(tg, name, col)
                else:
                    tg.create_dataset(name, data=col)
            for key in sorted(self._groups):
                datasets, attrs = self._groups[key]
                _write_tree(f.require_group(key), datasets, attrs)

    def _write_xdmf(self) -> None:
        tmp = os.path.join(self.out_dir, f".{XDMF_NAME}.tmp")   # the name write_xdmf writes first
        with guard_write(tmp, self.xdmf_path):
            write_xdmf(self.xdmf_path, self._frames.values(), self.dim, fsync=self.fsync)


def _empty_timing() -> dict[str, np.ndarray]:
    return {k: (np.zeros(0, dtype="S1") if k in ("task", "lane") else
                np.zeros(0, dtype=_TIMING_DTYPES[k])) for k in TIMING_FIELDS}


def _leaves(d: dict):
    for v in d.values():
        if isinstance(v, dict):
            yield from _leaves(v)
        else:
            yield v


def _copy_tree(d: dict) -> dict:
    return {k: (_copy_tree(v) if isinstance(v, dict) else np.array(v)) for k, v in d.items()}


def _frame_files_on_disk(out_dir: str) -> list[tuple[int, str]]:
    d = os.path.join(out_dir, FRAMES_DIR)
    out = []
    if os.path.isdir(d):
        for name in os.listdir(d):
            if name.startswith("frame_") and name.endswith(".h5"):
                try:
                    out.append((int(name[6:-3]), os.path.join(d, name)))
                except ValueError:
                    pass
    return out


# ---------------------------------------------------------------------- out dir
def prepare_out_dir(out_dir, overwrite: bool, restart: bool = False) -> str:
    """Make `out_dir` ready for a run; refuse to clobber a previous one.

    Call it only after the run's input is validated: it is the first thing that
    touches the disk.

    Parameters
    ----------
    out_dir : str or os.PathLike
    overwrite : bool
        Remove a previous run's ``output.h5``, ``output.xmf`` and ``frames/``
        (and the writer's temp files) — only those; other files stay.
    restart : bool, optional
        Keep the previous output (a restart appends to it).

    Returns
    -------
    str
        The directory path.

    Raises
    ------
    InputError
        A previous run is there and neither flag is set, or `out_dir` exists
        and is not a directory.
    """
    out_dir = os.fspath(out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise InputError(f"{out_dir}: output path exists and is not a directory: "
                         f"expected a directory (change --out)")
    master = os.path.join(out_dir, MASTER_NAME)
    if os.path.exists(master) and not (overwrite or restart):
        raise InputError(f"{out_dir}: output exists: expected an empty or new directory "
                         f"(use --overwrite or --restart)")
    if overwrite and not restart:
        for name in (MASTER_NAME, XDMF_NAME, f".{MASTER_NAME}.tmp", f".{XDMF_NAME}.tmp"):
            p = os.path.join(out_dir, name)
            if os.path.lexists(p):
                os.remove(p)
        frames = os.path.join(out_dir, FRAMES_DIR)
        if os.path.islink(frames):
            os.remove(frames)
        elif os.path.isdir(frames):
            shutil.rmtree(frames)
    os.makedirs(os.path.join(out_dir, FRAMES_DIR), exist_ok=True)
    return out_dir


# ---------------------------------------------------------------------- readers
def _open_master(out_dir) -> h5py.File:
    path = os.path.join(os.fspath(out_dir), MASTER_NAME)
    if not os.path.exists(path):
        raise InputError(f"{out_dir}: no {MASTER_NAME}: expected a sphgraph output directory")
    check_regular(path, CHECKPOINT_LIMIT, "HDF5 output file")   # a FIFO would block h5py
    try:
        return h5py.File(path, "r")
    except OSError as e:
        raise InputError(f"{path}: unreadable HDF5 file: {e}") from None


def _linked_frames(f: h5py.File) -> list[tuple[int, str, str]]:
    """(index, file, group path) of every link under /frames, sorted by index."""
    out = []
    frames = f.get("frames")
    if frames is None:
        return out
    for name in frames.keys():
        link = frames.get(name, getlink=True)
        if isinstance(link, h5py.ExternalLink):
            out.append((int(name), link.filename, link.path))
        else:  # a frame stored inside the master itself (not written by sphgraph)
            out.append((int(name), "", f"/frames/{name}"))
    return sorted(out)


def _open_frame_group(out_dir: str, master: h5py.File, file: str, path: str):
    """(file handle or None, group) of one frame; raises OSError/KeyError when damaged."""
    if not file:
        return None, master[path]
    fh = h5py.File(os.path.join(out_dir, file), "r")
    try:
        g = fh[path]
        g.attrs["time"], g.attrs["step"]  # noqa: B018 - a complete frame has both
        return fh, g
    except Exception:
        fh.close()
        raise


def _valid_frames(out_dir: str, f: h5py.File) -> list[tuple[int, float, int, str, str]]:
    out = []
    for index, file, path in _linked_frames(f):
        try:
            fh, g = _open_frame_group(out_dir, f, file, path)
            try:
                out.append((index, float(g.attrs["time"]), int(g.attrs["step"]), file, path))
            finally:
                if fh is not None:
                    fh.close()
        except (OSError, KeyError) as e:
            warnings.warn(f"{out_dir}: frame {index:06d} ({file or 'master'}) is missing or "
                          f"unreadable, skipped: {e}", OutputWarning, stacklevel=3)
    return out


def list_frames(out_dir) -> list[tuple[int, float, int]]:
    """Frames of a run as ``(index, time, step)``, sorted by index.

    Linked frames whose file is missing or damaged are skipped with an
    `OutputWarning` (a crashed or partly deleted run still reads).

    Raises
    ------
    InputError
        `out_dir` holds no readable ``output.h5``.
    """
    out_dir = os.fspath(out_dir)
    with _open_master(out_dir) as f:
        return [(i, t, s) for i, t, s, _, _ in _valid_frames(out_dir, f)]


def read_frame(out_dir, index: int | None = None, time: float | None = None) -> dict:
    """Read one frame.

    Parameters
    ----------
    out_dir : str or os.PathLike
    index : int, optional
        Frame index.
    time : float, optional
        Physical time: the nearest frame is read (the earlier one on a tie).
        With neither `index` nor `time`, the last frame is read.

    Returns
    -------
    dict
        Every dataset of the frame (``id``, ``kind``, ``position``, ``velocity``,
        ``density``, ``pressure``...) plus ``index``, ``time`` and ``step``.

    Raises
    ------
    InputError
        No such frame, no readable frame at all, or both `index` and `time` given.
    """
    out_dir = os.fspath(out_dir)
    if index is not None and time is not None:
        raise InputError("read_frame: give index or time, not both")
    with _open_master(out_dir) as f:
        frames = _valid_frames(out_dir, f)
        if not frames:
            raise InputError(f"{out_dir}: no readable frame in {MASTER_NAME}")
        if index is not None:
            match = [fr for fr in frames if fr[0] == int(index)]
            if not match:
                raise InputError(f"{out_dir}: frame {index}: expected one of the frame indices "
                                 f"{frames[0][0]}..{frames[-1][0]} ({len(frames)} readable)")
            chosen = match[0]
        elif time is not None:
            times = np.array([fr[1] for fr in frames])
            chosen = frames[int(np.argmin(np.abs(times - float(time))))]
        else:
            chosen = frames[-1]
        idx, t, step, file, path = chosen
        fh, g = _open_frame_group(out_dir, f, file, path)
        try:
            out = {k: g[k][()] for k in g.keys() if isinstance(g[k], h5py.Dataset)}
        finally:
            if fh is not None:
                fh.close()
    out.update(index=idx, time=t, step=step)
    return out


def read_attrs(out_dir) -> dict:
    """Root attributes of ``output.h5`` as plain Python values (str, int, float)."""
    with _open_master(out_dir) as f:
        return {k: _from_attr(v) for k, v in f.attrs.items()}


def _read_timing_group(f: h5py.File, decode: bool = True) -> dict[str, np.ndarray]:
    """/timing columns; task and lane as str arrays, or as stored UTF-8 bytes."""
    g = f.get("timing")
    empty = _empty_timing()
    out = {}
    for name in TIMING_FIELDS:
        arr = g[name][()] if g is not None and name in g else empty[name]
        if name == "bytes" and g is not None and name not in g and "rank" in g:   # written before the column
            arr = np.zeros(len(g["rank"]), _TIMING_DTYPES[name])
        if name in ("task", "lane"):
            arr = _decode_strings(arr) if decode else np.asarray(arr, dtype="S")
        out[name] = arr
    return out


def read_timing(out_dir) -> dict[str, np.ndarray]:
    """``/timing`` as parallel arrays ``rank``, ``step``, ``task``, ``lane``, ``start``, ``end``,
    ``bytes`` (what the task sent to other ranks).

    ``task`` and ``lane`` are numpy str arrays; empty arrays when nothing was timed.
    """
    with _open_master(out_dir) as f:
        return _read_timing_group(f)


def read_group(out_dir, name: str) -> dict:
    """A group written by `OutputWriter.write_group` (``probes``, ``forces``...).

    Returns
    -------
    dict
        Dataset name -> array (str arrays decoded), subgroups as nested dicts,
        and the group's attributes under the key ``"attrs"`` when it has any.

    Raises
    ------
    InputError
        The master has no such group.
    """
    with _open_master(out_dir) as f:
        key = name.strip("/")
        g = f.get(key)
        if not isinstance(g, h5py.Group) or key.split("/")[0] == "frames":
            groups = sorted(k for k in f.keys() if k != "frames")
            raise InputError(f"{out_dir}: {MASTER_NAME}: no group {name!r}: expected one of "
                             f"{groups}")
        return _read_tree(g)
