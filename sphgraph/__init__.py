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


# the console script; python -m sphgraph sets it in __main__ (argv[0] is "-m" while importing)
COMMAND = _os.path.basename(_sys.argv[0]) == "sphgraph"
if COMMAND:   # a library import keeps Python's KeyboardInterrupt
    _signal.signal(_signal.SIGINT, _sigint_at_start)

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
