"""Kernel launches without numba-cuda's per-launch typing and argument marshalling.

numba-cuda types every argument, wraps it, checks the context and builds a launch
configuration on every launch: ~50-100 us of host time for a kernel of 30 arguments,
while a GPU step launches ~45 kernels, many of them far shorter than that. `fast(ns)`
wraps a namespace of kernels (`cuda_kernels.build`, `force_kernels`) so that
`ns.k[grid, block, stream](*args)` launches as follows:

* the first launch of each combination of argument types goes through numba (which
  compiles, checks the arguments and launches);
* later launches reuse that overload and pass the arguments flattened exactly as
  numba-cuda 0.30 flattens them (`_Kernel._prepare_args`: an array is meminfo, parent,
  size, itemsize, data pointer, shape, strides) to cuda.core's `launch`, with the
  stream wrapper and the launch configuration cached.

Only device arrays and int / float / bool scalars take the fast path; anything else
(host arrays, records, tuples) always goes through numba. Off in the simulator and with
SPHGRAPH_CUDA_FAST_LAUNCH=0.
"""
import ctypes
import os

import numpy as np

from . import cuda_kernels as CK

ENABLED = os.environ.get("SPHGRAPH_CUDA_FAST_LAUNCH", "1") != "0" and not CK.SIMULATOR
_SCALARS = frozenset((int, float, bool, np.float32, np.float64, np.int8, np.int16, np.int32, np.int64,
                      np.uint8, np.uint32, np.uint64, np.bool_))
_ARRAY, _RAW = 0, 1          # plan entries other than a ctypes class
_MISS = object()
_STREAMS: dict = {}          # id(numba stream or 0) -> (stream, cuda.core stream)
_CONFIGS: dict = {}          # (grid, block) -> cuda.core LaunchConfig
_NS: dict = {}               # id(namespace) -> (namespace, fast namespace)
launches = {"fast": 0, "numba": 0}   # counters (tests, benchmarks)


_TYPES: dict = {}            # id -> numba type of the arrays seen, kept alive: plans are keyed by these ids


def _argkey(v):
    """What picks an argument's overload: the type of a scalar; for a device array the id
    of its numba type (interned; kept alive in _TYPES, so an id names one type), cached on
    the array. Hashing numba types themselves runs Python code on every launch."""
    t = type(v)
    if t in _SCALARS:
        return t
    if not getattr(v, "__cuda_memory__", False):
        return None
    d = v.__dict__
    k = d.get("_sg_key")
    if k is None:
        ty = v._numba_type_
        k = d["_sg_key"] = id(ty)
        _TYPES.setdefault(k, ty)
    return k


def _flat(a):
    """An array argument as numba-cuda passes it (cached on the array object)."""
    d = a.__dict__
    f = d.get("_sg_flat")
    if f is None:
        sh = a._strided_memory_view_shim
        f = d["_sg_flat"] = (0, 0, sh.size, sh.dtype.itemsize, sh.ptr) + tuple(sh.shape) + \
            tuple(sh._layout.strides_in_bytes)
    return f


_LAUNCH = []


def _launch():
    if not _LAUNCH:
        from cuda.core import launch
        _LAUNCH.append(launch)
    return _LAUNCH[0]


def _core_stream(stream):
    e = _STREAMS.get(id(stream))
    if e is None or e[0] is not stream:
        from numba.cuda.cudadrv import driver
        e = _STREAMS[id(stream)] = (stream, driver._to_core_stream(stream))
    return e[1]


def _config(grid, block):
    """The cuda.core launch configuration of (grid, block) as the launch gave them (ints or
    tuples), built once."""
    c = _CONFIGS.get((grid, block))
    if c is None:
        from cuda.core import LaunchConfig
        g = (grid, 1, 1) if isinstance(grid, int) else tuple(grid)
        b = (block, 1, 1) if isinstance(block, int) else tuple(block)
        try:
            c = LaunchConfig(grid=g, block=b, shmem_size=0, is_cooperative=False)
        except TypeError:        # cuda.core < 1.0
            c = LaunchConfig(grid=g, block=b, shmem_size=0, cooperative_launch=False)
        _CONFIGS[(grid, block)] = c
    return c


class FastKernel:
    """One kernel (a numba CUDA dispatcher) with the fast launch path."""

    __slots__ = ("disp", "plans")

    def __init__(self, disp):
        self.disp = disp
        self.plans = {}

    def __getitem__(self, cfg):
        return _Configured(self, cfg)

    def _plan(self, args):
        """(cuda.core kernel, per-argument converter) of the overload numba chose for
        `args`, or None when an argument needs numba's own marshalling."""
        from numba.core import types as T
        sig = tuple(self.disp.typeof_pyval(a) for a in args)
        kern = self.disp.overloads.get(sig)
        if kern is None or getattr(kern, "debug", False) or getattr(kern, "cooperative", False):
            return None
        conv = []
        for ty, v in zip(kern.argument_types, args):
            if isinstance(ty, T.Array):
                if not getattr(v, "__cuda_memory__", False):
                    return None
                conv.append(_ARRAY)
            elif isinstance(ty, T.Integer):
                conv.append(getattr(ctypes, "c_%s" % ty))
            elif ty == T.float64:
                conv.append(ctypes.c_double)
            elif ty == T.float32:
                conv.append(ctypes.c_float)
            elif ty == T.boolean:
                conv.append(_RAW)
            else:
                return None
        return kern._codelibrary.get_cufunc().kernel, tuple(conv)

    def launch(self, cfg, args):
        key = tuple(map(_argkey, args))
        plan = self.plans.get(key, _MISS)
        if plan is _MISS or plan is None:
            self.disp[cfg](*args)
            launches["numba"] += 1
            if plan is _MISS:
                self.plans[key] = self._plan(args) if None not in key else None
            return
        kernel, conv = plan
        kargs = []
        for c, v in zip(conv, args):
            if c is _ARRAY:
                kargs.extend(_flat(v))
            elif c is _RAW:
                kargs.append(v)
            else:
                kargs.append(c(v))
        _launch()(_core_stream(cfg[2] if len(cfg) > 2 else 0), _config(cfg[0], cfg[1]), kernel, *kargs)
        launches["fast"] += 1


class _Configured:
    __slots__ = ("k", "cfg")

    def __init__(self, k, cfg):
        self.k, self.cfg = k, cfg

    def __call__(self, *args):
        self.k.launch(self.cfg, args)


class _FastNamespace:
    def __init__(self, ns):
        self._ns = ns

    def __getattr__(self, name):
        v = getattr(self._ns, name)
        if hasattr(v, "overloads") and hasattr(v, "typeof_pyval"):
            v = FastKernel(v)
        setattr(self, name, v)        # cached: later lookups skip __getattr__
        return v


def fast(ns):
    """`ns` with every kernel on the fast launch path (the same object when disabled)."""
    if not ENABLED:
        return ns
    e = _NS.get(id(ns))
    if e is None or e[0] is not ns:
        e = _NS[id(ns)] = (ns, _FastNamespace(ns))
    return e[1]
