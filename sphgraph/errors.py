"""Error types mapped to the exit codes of DESIGN.md §5.

InputError -> 2 (bad input or usage: one line naming file, key and expected form)
NumericalError -> 1 (blow-up or violated invariant: step, cause, particle id)
DiskFullError -> 1 (no space left for output: the path and the free space)
CommError -> 3 (a message duplicated or lost, or a wait past the watchdog: one line)
anything else -> 3 (internal error: short message, traceback to a log file)
"""


# the causes of a numerical failure, by the code that `ComputeBackend.check` and the
# invariants return (and that /exclusions stores): the solver's messages name them
CAUSES = {1: "NaN in position or density", 2: "particle left the domain",
          3: "density outside the bounds [rho_min, rho_max]", 4: "NaN in velocity"}


class SphgraphError(Exception):
    exit_code = 3


class InputError(SphgraphError):
    """Bad scene, schedule or command-line input. The message is one line."""

    exit_code = 2


class NumericalError(SphgraphError):
    """The run failed numerically; earlier output stays intact."""

    exit_code = 1

    def __init__(self, message, step=None, particle_id=None, cause=None):
        super().__init__(message)
        self.step = step
        self.particle_id = particle_id
        self.cause = cause


class DiskFullError(SphgraphError):
    """No space left to write output or a checkpoint. Nothing half-written stays behind,
    earlier frames and checkpoints are intact; the message names the path and the free bytes."""

    exit_code = 1

    def __init__(self, message, path=None, free=None):
        super().__init__(message)
        self.path = path
        self.free = free


class DeadlockError(SphgraphError):
    """Every simulated rank waits; the message says who waits on what."""

    exit_code = 3


class CommError(SphgraphError):
    """Ranks cannot go on talking: a message arrived twice or never, or a rank waited past
    the watchdog limit. The message is one line naming the ranks, the task (or tag) and the step."""

    exit_code = 3
