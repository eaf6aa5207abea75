"""sphgraph: SPH free-surface flow where every timestep is an explicit task graph."""
__version__ = "0.1.0"

from .errors import InputError, NumericalError  # noqa: E402
from .graph.task import UserTask  # noqa: E402
from .scene import Scene  # noqa: E402
from .schedule import Schedule  # noqa: E402
from .solver import RunResult, Simulation, run  # noqa: E402

__all__ = ["Scene", "Schedule", "UserTask", "run", "Simulation", "RunResult", "InputError",
           "NumericalError", "__version__"]
