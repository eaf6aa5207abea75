"""Files the user names, read and written defensively: bounded reads, the output folder
checked before any work, and a full disk reported as one line.

Reading: every file a run reads goes through :func:`read_bytes` (or :func:`read_text`),
which refuses anything but a regular file (``/dev/zero``, a FIFO, a folder) and
anything above the limit of its kind before reading a byte of it, so a hostile path
can neither hang a run nor exhaust its memory. TOML is parsed by :func:`parse_toml`,
which also bounds the nesting depth (tomllib recurses; so do the checks after it).

Writing: :func:`check_out_dir` proves at start-up that the output folder can be
made (a folder, a sane name, writable), and :func:`guard_write` turns a write that
runs out of space (ENOSPC, EDQUOT; h5py reports them as OSError text) into
:class:`~sphgraph.errors.DiskFullError` (exit 1) naming the path and the free space,
after removing the half-written temporary file. Finished files are never modified in
place (:mod:`sphgraph.io`), so earlier frames and checkpoints stay intact.
"""
from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
from contextlib import contextmanager

from .errors import DiskFullError, InputError

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

MiB = 1 << 20
SCENE_LIMIT = 4 * MiB        # the largest shipped scene is 3 KiB
SCHEDULE_LIMIT = 1 * MiB     # a schedule is a few dozen lines
STL_LIMIT = 256 * MiB        # 5 M binary triangles (50 B each)
CHECKPOINT_LIMIT = 1 << 40   # 1 TiB: a state of 2**32 particles at ~120 B each, and more
TOML_DEPTH = 16              # tables and arrays nested this deep at most; scenes use 4
NAME_MAX = 255               # bytes of one path component (Linux, macOS, Windows)
PATH_MAX = 4096
IMAGE_LIMIT = 1 << 30        # HDF5 files up to 1 GiB are built in memory, then written (h5_atomic)
_NOSPACE = (errno.ENOSPC, errno.EDQUOT)


class FileRefused(InputError):
    """A file that cannot be read as asked; ``expected`` and ``got`` let a caller name its own key
    (``fluid[0].path``) instead of the file."""

    def __init__(self, path, expected: str, got: str):
        super().__init__(f"{path}: file: expected {expected}, got {got}")
        self.expected, self.got = expected, got


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "folder"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISFIFO, "FIFO"), (stat.S_ISSOCK, "socket")):
        if test(mode):
            return name
    return "special file"


def check_regular(path, limit: int, what: str) -> int:
    """The size of ``path``; InputError unless it is a regular file of at most ``limit`` bytes."""
    try:
        st = os.stat(path)
    except (OSError, ValueError) as e:
        raise FileRefused(path, f"a readable {what}",
                          f"{type(e).__name__}: {getattr(e, 'strerror', None) or e}") from None
    if not stat.S_ISREG(st.st_mode):
        raise FileRefused(path, f"a regular {what}", f"a {_kind(st.st_mode)}")
    if st.st_size > limit:
        raise FileRefused(path, f"a {what} of at most {limit} bytes", f"{st.st_size} bytes")
    return st.st_size


def read_bytes(path, limit: int, what: str) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (InputError otherwise)."""
    check_regular(path, limit, what)
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)    # a file growing after the stat is still bounded
    except OSError as e:
        raise FileRefused(path, f"a readable {what}", f"{type(e).__name__}: {e.strerror or e}") from None
    if len(data) > limit:
        raise FileRefused(path, f"a {what} of at most {limit} bytes", "more")
    return data


def read_text(path, limit: int, what: str) -> str:
    """A bounded regular file as UTF-8 text (a BOM is allowed and dropped)."""
    data = read_bytes(path, limit, what)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise FileRefused(path, f"a UTF-8 {what}", f"byte 0x{data[e.start]:02x} at offset {e.start}") from None


def _depth(v) -> int:
    """Nesting depth of tables and arrays, without recursion."""
    deepest, todo = 0, [(v, 0)]
    while todo:
        x, d = todo.pop()
        if isinstance(x, dict):
            todo += [(y, d + 1) for y in x.values()]
        elif isinstance(x, list):
            todo += [(y, d + 1) for y in x]
        else:
            continue
        deepest = max(deepest, d + 1)
        if deepest > TOML_DEPTH:
            break
    return deepest


def parse_toml(text: str, source, key: str = "TOML syntax") -> dict:
    """``tomllib.loads`` with one-line errors: syntax, nesting too deep (RecursionError)."""
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{source}: {key}: expected valid TOML, got {e}") from None
    except RecursionError:
        raise InputError(f"{source}: {key}: expected tables and arrays nested at most "
                         f"{TOML_DEPTH} deep, got a nesting too deep to parse") from None
    if _depth(d) > TOML_DEPTH:
        raise InputError(f"{source}: {key}: expected tables and arrays nested at most {TOML_DEPTH} deep, "
                         f"got deeper nesting")
    return d


# ----------------------------------------------------------------------------- writing
def _existing_ancestor(path: str) -> str:
    p = os.path.abspath(path)
    while not os.path.lexists(p):
        parent = os.path.dirname(p)
        if parent == p:
            break
        p = parent
    return p


def check_out_dir(out, flag: str = "--out") -> str:
    """Prove before any work that ``out`` is or can become an output folder.

    Refuses an empty path, a component longer than NAME_MAX bytes, a path under a file,
    and a place where no folder can be made (read-only, /proc): the nearest existing
    ancestor must be a folder in which a probe folder can be created (and is removed).
    """
    text = os.fspath(out)
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"{flag}: expected an output folder path, got {text!r}")
    if "\x00" in text:
        raise InputError(f"{flag}: expected a path without NUL characters, got {text!r}")
    parts = [p for p in text.split(os.sep) if p]
    long = next((p for p in parts if len(p.encode("utf-8", "surrogateescape")) > NAME_MAX), None)
    if long is not None or len(text) > PATH_MAX:
        shown = (long or text)[:40] + "..."
        raise InputError(f"{text[:60]}...: {flag}: expected path components of at most {NAME_MAX} bytes "
                         f"and a path of at most {PATH_MAX}, got {shown!r} "
                         f"({len(long or text)} characters)")
    if os.path.lexists(text) and not os.path.isdir(text):
        raise InputError(f"{text}: {flag}: expected a folder, got an existing file (change {flag})")
    anc = _existing_ancestor(text)
    if not os.path.isdir(anc):
        raise InputError(f"{text}: {flag}: expected a folder that can be created, got a path under "
                         f"the file {anc}")
    try:
        probe = tempfile.mkdtemp(prefix=".sphgraph-probe-", dir=anc)
        os.rmdir(probe)
    except OSError as e:
        raise InputError(f"{text}: {flag}: expected a folder that can be created, got "
                         f"{e.strerror or e} in {anc}") from None
    return text


def free_bytes(path) -> int | None:
    try:
        return shutil.disk_usage(_existing_ancestor(os.fspath(path))).free
    except OSError:
        return None


def is_no_space(e: BaseException) -> bool:
    """An error of a full disk or quota (HDF5 keeps errno only in its message, and reports
    some failed flushes as RuntimeError)."""
    if not isinstance(e, (OSError, RuntimeError)):
        return False
    if isinstance(e, OSError) and e.errno in _NOSPACE:
        return True
    text = str(e)
    return ("No space left" in text or f"errno = {errno.ENOSPC}," in text
            or f"errno = {errno.EDQUOT}," in text or "Disk quota exceeded" in text)


def disk_full(path) -> DiskFullError:
    free = free_bytes(path)
    return DiskFullError(f"{path}: disk full: expected room to write it, got "
                         f"{'unknown' if free is None else free} bytes free on its filesystem "
                         f"(free space, then continue with --restart)", path=os.fspath(path), free=free)


def _remove(path) -> None:
    try:
        os.remove(path)
    except OSError:
        pass


# temporary files being written now: the command's SIGINT handler removes them before it exits
IN_FLIGHT: set = set()


def remove_in_flight() -> None:
    for tmp in list(IN_FLIGHT):
        _remove(tmp)


@contextmanager
def guard_write(tmp, final=None):
    """Around the writing of temporary file ``tmp``: on any failure (and on SIGINT) ``tmp``
    is removed; a full disk becomes :class:`DiskFullError` naming ``final`` (or ``tmp``)."""
    IN_FLIGHT.add(tmp)
    try:
        yield
    except BaseException as e:
        _remove(tmp)
        if is_no_space(e):
            raise disk_full(final or tmp) from None
        raise
    finally:
        IN_FLIGHT.discard(tmp)


def _write_all(path: str, data: bytes, fsync: bool) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        if fsync:
            os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(path: str) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextmanager
def h5_atomic(final, *, fsync: bool = True, size_hint: int = 0, **kwargs):
    """An ``h5py.File`` to fill; on leaving the block its bytes land at ``final`` atomically
    (a temporary file, fsync, rename, fsync of the folder).

    HDF5 that meets a full disk half-way fails again in every later flush, close and
    deallocation, and can crash the process at exit; so a file of up to ``IMAGE_LIMIT``
    bytes (``size_hint``: the bytes of its arrays) is built in memory (the core driver)
    and written with plain writes, whose ENOSPC is one clean error. A larger one is
    written by HDF5 directly after a check that the filesystem has room for it. Either
    way a full disk raises :class:`DiskFullError` and leaves no temporary file.
    """
    import h5py
    final = os.fspath(final)
    folder = os.path.dirname(final) or "."
    tmp = os.path.join(folder, "." + os.path.basename(final) + ".tmp")
    in_memory = size_hint <= IMAGE_LIMIT
    if not in_memory:
        free = free_bytes(folder)
        if free is not None and free < size_hint + size_hint // 16 + MiB:
            raise disk_full(final)
    with guard_write(tmp, final):
        if in_memory:
            f = h5py.File(f"{tmp}.image", "w", driver="core", backing_store=False, **kwargs)
        else:
            f = h5py.File(tmp, "w", **kwargs)
        try:
            yield f
            if in_memory:
                f.flush()
                image = f.id.get_file_image()
        finally:
            f.close()
        if in_memory:
            _write_all(tmp, image, fsync)
            del image
        elif fsync:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, final)
        if fsync:
            _fsync_dir(folder)
