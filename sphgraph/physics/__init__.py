"""Pair physics shared by every compute backend (plain @njit functions).

numba's on-disk cache keys a kernel on its own file only: a kernel module that
inlines these functions would keep stale machine code after an edit here.
`drop_stale_cache(kernel_file)` removes the kernel module's cache entries when
the physics sources changed since they were written.
"""
from __future__ import annotations

import glob
import hashlib
import os

_HERE = os.path.dirname(__file__)


def source_hash() -> str:
    h = hashlib.sha256()
    for name in sorted(os.listdir(_HERE)) + ["../config.py", "../cells.py"]:
        path = os.path.join(_HERE, name)
        if path.endswith(".py") and os.path.isfile(path):
            with open(path, "rb") as f:
                h.update(f.read())
    return h.hexdigest()[:16]


def _cache_dirs(kernel_file: str) -> list:
    """Where numba keeps `kernel_file`'s cache: its __pycache__, or under NUMBA_CACHE_DIR
    (numba's user-provided locator: the source folder's name and a hash of its path)."""
    from numba.core import config
    from numba.core.caching import _CacheLocator
    out = [os.path.join(os.path.dirname(kernel_file), "__pycache__")]
    if config.CACHE_DIR:
        out.insert(0, os.path.join(config.CACHE_DIR, _CacheLocator.get_suitable_cache_subpath(kernel_file)))
    return out


def drop_stale_cache(kernel_file: str) -> None:
    for cache in _cache_dirs(kernel_file):
        _drop_stale(cache, kernel_file)


def _drop_stale(cache: str, kernel_file: str) -> None:
    stem = os.path.splitext(os.path.basename(kernel_file))[0]
    stamp = os.path.join(cache, f"{stem}.physics-hash")
    want = source_hash()
    try:
        with open(stamp) as f:
            if f.read() == want:
                return
    except OSError:
        pass
    try:
        for p in glob.glob(os.path.join(cache, f"{stem}.*.nb[ic]")):
            os.remove(p)
        os.makedirs(cache, exist_ok=True)
        with open(stamp, "w") as f:
            f.write(want)
    except OSError:  # read-only install: numba then compiles in memory or its own cache dir
        pass
