"""Plain Python and `@njit` functions retargeted to numba.cuda for one floating-point type.

The pair physics is not written for the GPU: `sphgraph.physics` holds it once, as plain
`@njit` functions, and `device_function` / `kernel` turn each of them (and each kernel of
the cuda_* modules) into a CUDA device function or kernel for one float type:

* the function's Python code is compiled again by the CUDA target, with every
  `@njit` function it calls replaced by its own retargeted copy;
* every float literal of the code (``0.5``, ``2.0``, ...) becomes a literal of the
  run's type. numba types a bare literal as float64, so in a float32 run
  ``0.5 * q`` would be computed in double precision (and ``1.0 / r`` with a
  double division): the float32 copies stay in float32.

In numba's CUDA simulator (`NUMBA_ENABLE_CUDASIM=1`, CI) the same copies run as
plain Python. Kernels must reach `cuda` as a module-level name (the simulator
swaps it in each kernel's globals).
"""
import os
import types

import numpy as np
from numba import cuda, njit
from numba.core.dispatcher import Dispatcher

SIMULATOR = os.environ.get("NUMBA_ENABLE_CUDASIM", "0") == "1"
if SIMULATOR:   # the simulator's block runner that waits instead of polling (cuda_simulator)
    from .cuda_simulator import install as _install_simulator
    _install_simulator()
RT = np.float64      # the run's float type: each kernel clone gets its own (_clone)

# float32 copies only: literal -> replacement. The Fourtakas hydrostatic term switches
# from its binomial series (4 terms) to pow() at |y| >= 1e-3; in float32 the series is
# exact to round-off up to |y| = 0.02 (next term C(1/7,5) y^5 = 6.7e-11 against
# y/7 = 2.9e-3: 2.3e-8 relative, below float32's 6e-8), and pow() in a branch that a
# part of each warp takes costs the whole warp.
F32_REMAP = {"fluid_pair": {1e-3: 2e-2}}


def _cast_consts(code, ft, remap=None):
    out = []
    remap = remap or {}
    for c in code.co_consts:
        if type(c) is float:
            c = ft(remap.get(c, c))
        elif isinstance(c, types.CodeType):
            c = _cast_consts(c, ft, remap)
        out.append(c)
    return code.replace(co_consts=tuple(out))


def _clone(f, dtype, memo, extra=None):
    """A copy of the Python function `f` (or of an @njit dispatcher's py_func) whose
    float literals are of `dtype` and whose @njit callees are CUDA device copies
    (`extra`: more globals, e.g. compile-time constants)."""
    f = getattr(f, "py_func", f)
    code = f.__code__
    if np.dtype(dtype) != np.float64:
        remap = F32_REMAP.get(f.__name__) if np.dtype(dtype) == np.float32 else None
        code = _cast_consts(code, np.dtype(dtype).type, remap)
    g = dict(f.__globals__)
    g["RT"] = np.dtype(dtype).type            # the run's float type (shared arrays)
    g.update(_DEVICE_ONLY)                    # intrinsics in place of their Python twins
    g.update(extra or {})
    for name in code.co_names:
        v = g.get(name)
        if isinstance(v, Dispatcher):
            g[name] = device_function(v, dtype, memo)
    return types.FunctionType(code, g, f.__name__, f.__defaults__, f.__closure__)



def _names_cuda(fn) -> bool:
    """Whether the code of `fn` (or of a function defined in it) reads a global bound to
    the `cuda` module (only asked in the simulator)."""
    from .cuda_simulator import names_in
    return any(fn.__globals__.get(n) is cuda for n in names_in(fn.__code__))


def device_function(f, dtype, memo=None):
    """CUDA device copy of the @njit (or plain) function `f` for float type `dtype`.

    In the simulator a `cuda.jit(device=True)` function is a wrapper that swaps the fake
    `cuda` module into the function's globals on every call, scanning all of them; a copy
    that never reads `cuda` runs the same as its plain Python function, which is what it
    gets there (the pair maths are called per pair, a third of the simulator's time)."""
    memo = {} if memo is None else memo
    key = (getattr(f, "py_func", f), np.dtype(dtype).str)
    if key not in memo:
        fn = _clone(f, dtype, memo)
        memo[key] = fn if SIMULATOR and not _names_cuda(fn) else cuda.jit(device=True)(fn)
    return memo[key]


def kernel(f, dtype, memo=None, fastmath=False):
    """CUDA kernel copy of the plain function `f` for float type `dtype`."""
    memo = {} if memo is None else memo
    fn = _clone(f, dtype, memo)
    if SIMULATOR:
        return cuda.jit(fn)
    return cuda.jit(fastmath=fastmath)(fn)


# ------------------------------------------------------------------------------- vector loads
# load4 and at are plain @njit functions (CPU, simulator, tests of the helpers); the CUDA
# copies of the kernels get the intrinsics of _DEVICE_ONLY in their place (_clone).
@njit(inline="always")
def _load4_py(a, i):
    return a[i], a[i + 1], a[i + 2], a[i + 3]


@njit(inline="always")
def _at_py(a, i):
    return a[i]



load4 = _load4_py
at = _at_py
_DEVICE_ONLY = {}

if not SIMULATOR:
    from llvmlite import ir as _ir
    from numba.core import cgutils as _cg, types as _nt
    from numba.core.extending import intrinsic as _intrinsic  # noqa: E402

    def _item_ptr(context, builder, aryty, ary_val, idx):
        """Pointer to element idx of an array argument, without the negative-index wraparound."""
        ary = context.make_array(aryty)(context, builder, ary_val)
        return _cg.get_item_pointer2(context, builder, data=ary.data,
                                     shape=_cg.unpack_tuple(builder, ary.shape),
                                     strides=_cg.unpack_tuple(builder, ary.strides),
                                     layout=aryty.layout, inds=[idx], wraparound=False)

    @_intrinsic
    def _load4_vec(typingctx, arr, idx):
        """a[i], a[i+1], a[i+2], a[i+3] in one 16-byte (float32) or two 16-byte (float64)
        loads; i a multiple of 4 in an array whose data is 16-byte aligned (device
        allocations are 256-byte aligned; the pos4/vel4 records start at 0)."""
        sig = _nt.UniTuple(arr.dtype, 4)(arr, idx)

        def codegen(context, builder, sig, args):
            aryty = sig.args[0]
            ptr = _item_ptr(context, builder, aryty, args[0], args[1])
            vty = _ir.VectorType(context.get_data_type(aryty.dtype), 4)
            vec = builder.load(builder.bitcast(ptr, vty.as_pointer()), align=16)
            vals = [builder.extract_element(vec, _ir.Constant(_ir.IntType(32), k)) for k in range(4)]
            return context.make_tuple(builder, sig.return_type, vals)
        return sig, codegen

    @_intrinsic
    def _at_nowrap(typingctx, arr, idx):
        """a[i] for an index known to be in range and >= 0: numba's a[i] also wraps a
        negative signed index around (a compare and an add on 64 bits at every load), which
        the bisections and cell ranges of the force kernels pay per step of their loops."""
        sig = arr.dtype(arr, idx)

        def codegen(context, builder, sig, args):
            return builder.load(_item_ptr(context, builder, sig.args[0], args[0], args[1]))
        return sig, codegen

    _DEVICE_ONLY.update(load4=_load4_vec, at=_at_nowrap)
