"""Every CUDA kernel and device helper passes numba's bytecode front end.

numba's CUDA simulator runs kernels as Python and never reads their bytecode, so a kernel
that numba cannot translate (e.g. a call of more than 30 arguments with a conditional
expression among them: CPython passes such arguments as one tuple, CALL_FUNCTION_EX) passes
every simulator test and fails only when a real GPU compiles it. numba's front end
(`run_frontend`: bytecode to numba IR, before typing) finds those on any machine."""
from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import pytest
from numba.core.compiler import run_frontend
from numba.core.registry import CPUDispatcher

ROOT = Path(__file__).resolve().parents[1]
MODULES = sorted("sphgraph.backends.compute." + p.stem for p in (ROOT / "backends" / "compute").glob("cuda_*.py")) + \
    sorted("sphgraph.physics." + p.stem for p in (ROOT / "sphgraph" / "physics").glob("*.py") if p.stem != "__init__")


def device_functions(mod):
    """The module's kernels (`k_*` functions, handed to cuda.jit by the module's builder) and
    its numba-compiled helpers (njit dispatchers, inlined into the kernels)."""
    out = []
    for name, obj in vars(mod).items():
        if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == mod.__name__:
            out.append((name, obj.py_func))
        elif inspect.isfunction(obj) and obj.__module__ == mod.__name__ and name.startswith("k_"):
            out.append((name, obj))
    return out


@pytest.mark.parametrize("module", MODULES)
def test_device_code_passes_numba_front_end(module):
    mod = importlib.import_module(module)
    funcs = device_functions(mod)
    failed = []
    for name, fn in funcs:
        try:
            run_frontend(fn)
        except Exception as e:  # noqa: BLE001 - any front-end error is a kernel a GPU cannot compile
            failed.append(f"{name}: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}")
    assert not failed, failed


def test_the_kernels_are_found():
    found = {m: len(device_functions(importlib.import_module(m))) for m in MODULES}
    assert found["sphgraph.backends.compute.cuda_shifting"] >= 2
    assert found["sphgraph.backends.compute.cuda_forces"] >= 5
    assert sum(found.values()) >= 60, found
