"""sphgraph: SPH free-surface flow where every timestep is an explicit task graph.

The public names are imported on first use (PEP 562), so ``import sphgraph.cli`` is
cheap: the command line installs its SIGINT handling before numba and numpy load.
"""
__version__ = "0.1.0"

import os as _os
import signal as _signal
import sys as _sys


def _sigint_at_start(signum, frame):
    # start-up of the command (imports, before cli.main's handler): nothing is written yet
    _os.write(2, b"sphgraph: interrupted (SIGINT) during start-up\n")
    _os._exit(130)


def _is_command() -> bool:
    """Whether this process is the command: the console script, or ``python -m sphgraph``.

    Under ``-m`` the package is imported before ``__main__`` with ``sys.argv[0] == "-m"``,
    so the interpreter's own arguments (``sys.orig_argv``) say which module runs: the
    handler goes in here, at the first line of project code either way, not after the
    package's imports."""
    if _os.path.basename(_sys.argv[0]) == "sphgraph":
        return True
    if _sys.argv[:1] != ["-m"]:
        return False
    args = list(getattr(_sys, "orig_argv", ()))[1:]
    while args:
        a = args.pop(0)
        if a == "--" or not a.startswith("-"):
            return False                      # a script (or stdin) runs, not a module
        if a.startswith("--"):                # --check-hash-based-pycs MODE
            if a == "--check-hash-based-pycs" and args:
                args.pop(0)
            continue
        for j, ch in enumerate(a[1:], 1):     # short options, combined as in -Bm
            if ch == "m":
                return (a[j + 1:] or (args[0] if args else "")) == "sphgraph"
            if ch in "cXW":                   # options with an argument (-c ends the options)
                if ch == "c":
                    return False
                if not a[j + 1:] and args:
                    args.pop(0)
                break
    return False


# the command (console script or python -m sphgraph); a library import keeps Python's KeyboardInterrupt
COMMAND = _is_command()
if COMMAND:
    _signal.signal(_signal.SIGINT, _sigint_at_start)
    # a launcher may block SIGINT across exec, over the interpreter's own start-up (site's
    # .pth files, runpy: no project code runs there, and Python prints a traceback for a
    # SIGINT in it); a SIGINT held pending meanwhile is delivered to the handler here
    if hasattr(_signal, "pthread_sigmask"):
        _signal.pthread_sigmask(_signal.SIG_UNBLOCK, {_signal.SIGINT})

from .errors import InputError, NumericalError  # noqa: E402

_LAZY = {"Scene": ".scene", "Schedule": ".schedule", "UserTask": ".graph.task", "run": ".solver",
         "Simulation": ".solver", "RunResult": ".solver"}

__all__ = ["Scene", "Schedule", "UserTask", "run", "Simulation", "RunResult", "InputError",
           "NumericalError", "__version__"]


def __getattr__(name):
    if name in _LAZY:
        import importlib
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'sphgraph' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
