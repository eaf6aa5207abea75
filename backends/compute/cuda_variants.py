"""Variants of the force kernels for the optional terms (cuda_riemann: the Riemann pressure
term; cuda_dufort: the DuFort-Frankel K_a; cuda_rjump: the renormalised Riemann jump), made
from the code of the production kernels (cuda_forces: k_forces_fv, k_forces;
cuda_halo_kernels: k_halo_fv) so that the neighbour loops, sums and stores are written once.
The production kernels are compiled from their own code as they are; a variant is a copy of
it that differs in one of two ways:

* `with_globals(f, **subs)`: the copy's global names rebound, e.g. `fluid_pair` to another
  pair function of the same signature (the Riemann term);
* `with_sum(f, pair, store, nsum, **subs)`: the copy carries `nsum` more sums a row (`kk`,
  ...) beside the others, fed by a pair function that returns `nsum` values more than
  `fluid_pair`, and the kernel writes them through `store` into one more array argument
  (K_a: one sum; cuda_rjump's moments of the renormalised jump: twelve; see `with_sum`).

`ForceVariant` compiles a variant's kernels as cuda_kernels.force_kernels /
cuda_halo_kernels.force_kernels compile the production ones (cuda_forces.compile_forces:
the run's constants, fastmath and the register cap), cached per run's constants; the
boundary kernels of every variant are the production ones.
"""
from __future__ import annotations

import ast
import inspect
import textwrap
import types

import numpy as np
from numba import njit
from numba.core.dispatcher import Dispatcher

from . import cuda_forces as CF
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK


def _py(f):
    return f.py_func if isinstance(f, Dispatcher) else f


def with_globals(f, **subs):
    """A copy of the function `f` (plain, or @njit: then an inlined @njit copy) whose global
    names `subs` rebind: cuda_retarget then retargets the copy and what it calls."""
    py = _py(f)
    g = dict(py.__globals__)
    g.update(subs)
    fn = types.FunctionType(py.__code__, g, py.__name__, py.__defaults__, py.__closure__)
    return njit(inline="always")(fn) if isinstance(f, Dispatcher) else fn


# ----------------------------------------------------------------------------- more sums
# The production kernels' sums of a fluid row are the locals (axx, ayy, azz, arr, dd, cc,
# vmax), in that order wherever they are passed, returned or unpacked; the pair call is
# `fx, fy, fz, fr, fd, fc, fv = fluid_pair(...)`, the cancel is summed by `cc |= fc`, the
# sums start at `vmax = zero` and the kernel scales the viscous maximum last
# (`vmax = prm[P_H] * vmax`), after the row's stores. `with_sum` keys on exactly these.
_SUMS_END = ("cc", "vmax")
_PAIR_OUT_END = ("fc", "fv")


def _ends(nodes, names) -> bool:
    tail = nodes[-len(names):]
    return len(nodes) >= len(names) and all(isinstance(n, ast.Name) and n.id == m for n, m in zip(tail, names))


def _is_name(node, name) -> bool:
    return isinstance(node, ast.Name) and node.id == name


def sum_names(nsum) -> tuple:
    """The names of `with_sum`'s `nsum` sums a row (kk, kk1, kk2, ...) and of the pair's
    values that feed them (fk, fk1, ...): with one sum, kk and fk as ever."""
    return (tuple("kk" if k == 0 else f"kk{k}" for k in range(nsum)),
            tuple("fk" if k == 0 else f"fk{k}" for k in range(nsum)))


class _AddSum(ast.NodeTransformer):
    """The edits of `with_sum` on one function's tree, counted (`n`) so that a production
    kernel whose code no longer has the expected shape fails at build time, not in a result."""

    def __init__(self, pair_name, store_name, kernel, nsum):
        self.pair_name = pair_name
        self.store_name = store_name
        self.kernel = kernel
        self.kk, self.fk = sum_names(nsum)
        self.n = dict.fromkeys(("args", "return", "pair", "add", "init", "store"), 0)

    def _names(self, ctx):
        return [ast.Name(k, ctx()) for k in self.kk]

    def visit_FunctionDef(self, node):
        node.decorator_list = []
        args = node.args.args
        names = [a.arg for a in args]
        for new in self.kk + self.fk + ("ddk_",):
            if new in names or any(_is_name(n, new) for n in ast.walk(node)):
                raise ValueError(f"with_sum: {node.name} already uses the name {new!r}")
        if names[-2:] == list(_SUMS_END):
            args.extend(ast.arg(k) for k in self.kk)
            self.n["args"] += 1
        self.generic_visit(node)
        if self.kernel:
            args.append(ast.arg("ddk_"))
            final = ast.Name("final", ast.Load()) if "final" in names else ast.Constant(False)
            store = ast.Expr(ast.Call(ast.Name(self.store_name, ast.Load()),
                                      [ast.Name("i", ast.Load()), final, ast.Name("cc", ast.Load()),
                                       *self._names(ast.Load), ast.Name("ddk_", ast.Load())], []))
            body = []
            for s in node.body:   # the row's stores are done where the viscous maximum is scaled
                if isinstance(s, ast.Assign) and _is_name(s.targets[0], "vmax") and not _is_name(s.value, "zero"):
                    body.append(store)
                    self.n["store"] += 1
                body.append(s)
            node.body = body
        return node

    def visit_Return(self, node):
        self.generic_visit(node)
        if isinstance(node.value, ast.Tuple) and _ends(node.value.elts, self.kk):
            self.n["return"] += 1
        return node

    def visit_Tuple(self, node):
        self.generic_visit(node)
        if _ends(node.elts, _SUMS_END):
            node.elts.extend(self._names(type(node.ctx)))
        return node

    def visit_Call(self, node):
        self.generic_visit(node)
        if _ends(node.args, _SUMS_END):
            node.args.extend(self._names(ast.Load))
        return node

    def visit_Assign(self, node):
        self.generic_visit(node)
        t = node.targets[0]
        v = node.value
        if isinstance(t, ast.Tuple) and _ends(t.elts, _PAIR_OUT_END) and isinstance(v, ast.Call) \
                and _is_name(v.func, "fluid_pair"):
            t.elts.extend(ast.Name(f, ast.Store()) for f in self.fk)
            v.func = ast.Name(self.pair_name, ast.Load())
            self.n["pair"] += 1
        if _is_name(t, "vmax") and _is_name(v, "zero"):
            self.n["init"] += 1
            return [node] + [ast.Assign([ast.Name(k, ast.Store())], ast.Name("zero", ast.Load())) for k in self.kk]
        return node

    def visit_AugAssign(self, node):
        if _is_name(node.target, "cc") and isinstance(node.op, ast.BitOr) and _is_name(node.value, "fc"):
            self.n["add"] += 1
            return [node] + [ast.AugAssign(ast.Name(k, ast.Store()), ast.Add(), ast.Name(f, ast.Load()))
                             for k, f in zip(self.kk, self.fk)]
        return node


def with_sum(f, pair, store=None, nsum=1, **subs):
    """A copy of the production kernel or device function `f` (cuda_forces' `_fv_pair`,
    `_fv_part`, `k_forces_fv`, `k_forces`; cuda_halo_kernels' `k_halo_fv`) that carries `nsum`
    more sums a row, `kk` (and `kk1`, `kk2`, ... with nsum > 1: `sum_names`), beside `vmax`,
    every other line as it is:

    * the pair call `fx, .., fv = fluid_pair(...)` becomes `fx, .., fv, fk, .. = pair(...)`
      (`pair`: fluid_pair's arguments, its results and `nsum` more), and `kk += fk`, ...
      follow `cc |= fc`;
    * wherever the sums are passed, returned or unpacked (`..., cc, vmax`), `kk, ..` follow;
      `kk = zero`, ... follow `vmax = zero`;
    * a kernel (`store` given) takes one more array argument, `ddk_`, last, and calls
      `store(i, final, cc, kk, .., ddk_)` after the row's stores (`final`: False where the
      kernel has no such argument, as k_halo_fv, whose sums are always a part's).

    The sums are separate scalars, not an array: a per-thread local array would live in
    local (off-chip) memory, the scalars in registers. `subs` rebinds global names of the
    copy as `with_globals` (e.g. `_fv_part` to its own copy with the sums). Source line
    numbers are the production function's. Raises ValueError where `f`'s code has not the
    shape these edits key on."""
    py = _py(f)
    lines, first = inspect.getsourcelines(py)
    tree = ast.parse(textwrap.dedent("".join(lines)))
    ast.increment_lineno(tree, first - 1)
    edit = _AddSum(_py(pair).__name__, _py(store).__name__ if store is not None else "", store is not None, nsum)
    tree = ast.fix_missing_locations(edit.visit(tree))
    n = edit.n
    device = not edit.kernel
    if n["pair"] != n["add"] or (device and (n["args"] != 1 or n["return"] != 1)) or \
            (edit.kernel and (n["init"] != 1 or n["store"] != 1)):
        raise ValueError(f"with_sum: {py.__name__} has not the shape of the production force code "
                         f"(edits made: {n})")
    g = dict(py.__globals__)
    g.update(subs)
    g[edit.pair_name] = pair
    if store is not None:
        g[edit.store_name] = store
    loc: dict = {}
    exec(compile(tree, py.__code__.co_filename, "exec"), g, loc)
    fn = loc[py.__name__]
    return njit(inline="always")(fn) if isinstance(f, Dispatcher) else fn


# -------------------------------------------------------------------------------- compilation
class ForceVariant:
    """The force kernels of one variant, compiled and cached as the production ones:
    `fluid` / `halo_fluid` (copies of k_forces_fv / k_halo_fv) with the production boundary
    kernels k_forces_bv / k_halo_bv, and `binned` (a copy of k_forces, host-binned halos)
    under the name `binned_name`, with the variant's element-wise kernels `plain`
    (functions, under their own names) beside it (`build`)."""

    def __init__(self, fluid, halo_fluid, binned, binned_name="k_forces", plain=()):
        self.fluid = fluid
        self.halo_fluid = halo_fluid
        self.binned = binned
        self._runs: dict = {}
        self._fast = (binned_name,)
        self._kernels = {binned_name: binned, **{f.__name__: f for f in plain}}
        self._names = tuple(self._kernels)

    def _compile(self, fluid, boundary, dtype, prm, kernel_id, ddt_kind, laminar):
        dt = np.dtype(dtype)
        fm = dt == np.float32
        mr = CK.MAXREG if fm else 0
        pc = np.ascontiguousarray(prm, dt)
        key = (fluid.__name__, dt.str, pc.tobytes(), int(kernel_id), int(ddt_kind), int(laminar))
        if key not in self._runs:
            self._runs[key] = CF.compile_forces(fluid, boundary, dt, pc, kernel_id, ddt_kind, laminar, fm, mr)
        return self._runs[key]

    def force_kernels(self, dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
        """cuda_kernels.force_kernels' namespace (k_forces_f / k_forces_b, `relative`)."""
        return self._compile(self.fluid, CF.k_forces_bv, dtype, prm, kernel_id, ddt_kind, laminar)

    def halo_force_kernels(self, dtype, prm, kernel_id, ddt_kind, laminar) -> types.SimpleNamespace:
        """cuda_halo_kernels.force_kernels' namespace (k_halo_fv / k_halo_bv): one object a
        compiled pair (the launch layer caches per object)."""
        ns = self._compile(self.halo_fluid, HK.k_halo_bv, dtype, prm, kernel_id, ddt_kind, laminar)
        key = ("halo", id(ns))
        if key not in self._runs or self._runs[key][0] is not ns:
            self._runs[key] = (ns, types.SimpleNamespace(k_halo_fv=ns.k_forces_f, k_halo_bv=ns.k_forces_b))
        return self._runs[key][1]

    def build(self, dtype) -> types.SimpleNamespace:
        """The copy of k_forces as `binned_name`, fastmath in float32 as cuda_kernels.build
        compiles k_forces, and the element-wise kernels `plain`, for float type `dtype`
        (cached)."""
        dt = np.dtype(dtype)
        return CK.kernel_set(self._kernels, self._names, dt, self._fast if dt == np.float32 else ())
