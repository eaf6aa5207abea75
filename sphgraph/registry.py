"""Backend registries: one per plug-in kind, looked up by name (xarray style).

The core never imports a backend module directly: a backend module registers
itself when imported, and `get` imports the module named in the table on first use.
"""
from __future__ import annotations

import importlib

from .errors import InputError

# name -> module that registers it (imported lazily, so e.g. mpi4py loads only for --comm mpi)
_MODULES = {
    "compute": {
        "numba-cpu": "sphgraph.backends.compute.numba_cpu",
        "numba-cuda": "sphgraph.backends.compute.numba_cuda",
    },
    "comm": {
        "single": "sphgraph.backends.comm.single",
        "mock": "sphgraph.backends.comm.mock",
        "mpi": "sphgraph.backends.comm.mpi",
    },
}
_CLASSES: dict[str, dict[str, type]] = {"compute": {}, "comm": {}}


def register(kind: str, name: str):
    """Class decorator: `@register("compute", "numba-cpu")`."""
    def deco(cls):
        _CLASSES[kind][name] = cls
        cls.name = name
        return cls
    return deco


def names(kind: str) -> list[str]:
    return sorted(_MODULES[kind])


def get(kind: str, name_or_class, option: str | None = None):
    """The backend class for `name_or_class` (a registered name or a class)."""
    if isinstance(name_or_class, type):
        return name_or_class
    table = _MODULES[kind]
    if name_or_class not in table:
        flag = option or f"--{kind}"
        raise InputError(f"{flag}: unknown {kind} backend {name_or_class!r}: "
                         f"expected one of {', '.join(names(kind))}")
    if name_or_class not in _CLASSES[kind]:
        importlib.import_module(table[name_or_class])
    return _CLASSES[kind][name_or_class]
