"""Start-up checks of a run's choices, before anything is built: every flag applies to the
chosen comm and compute backends, the compute backend can run on this machine, and the
rank count fits the scene -- each answered in one line, in well under a second.

The order matters for hostile input: the rank count is refused from the scene's domain
(a few multiplications) before a communicator, an engine or a rank state of that count
exists, and a GPU backend says it cannot run from its declared
:meth:`~sphgraph.backends.compute.base.ComputeBackend.unavailable` before any device is
touched.
"""
from __future__ import annotations

import math

from .errors import InputError
from .ranges import check_flag
from .registry import get

# comm options that only the simulated ranks of --comm mock understand (message faults, speeds)
MOCK_ONLY = {"duplicate": "--duplicate", "loss": "--loss", "seed": "--seed", "rank_speed": "--rank-speed"}
# options of comm backends whose ranks wait on each other
WAITING = {"watchdog": "--watchdog"}


def check_comm(comm: str, ranks, options: dict | None) -> None:
    """Flags that do not apply to ``comm`` are refused with the reason; ``--ranks 1`` is always fine."""
    options = options or {}
    if not isinstance(ranks, int) or isinstance(ranks, bool):
        raise InputError(f"--ranks: expected an integer >= 1, got {ranks!r}")
    check_flag("--ranks", ranks, integer=True)
    if comm == "single" and ranks != 1:
        raise InputError(f"--ranks {ranks}: expected 1 with --comm single (one process, one rank): "
                         "use --comm mock for simulated ranks, or mpiexec -n N with --comm mpi")
    if comm == "mpi" and ranks != 1:
        raise InputError(f"--ranks {ranks}: expected no --ranks with --comm mpi (the rank count is "
                         "mpiexec -n N)")
    if comm != "mock":
        for key, flag in MOCK_ONLY.items():
            if options.get(key) is not None:
                raise InputError(f"{flag}: expected --comm mock (it drives the simulated ranks' "
                                 f"messages), got --comm {comm}")
    if comm == "single":
        for key, flag in WAITING.items():
            if options.get(key) is not None:
                raise InputError(f"{flag}: expected --comm mock or --comm mpi (ranks that wait on "
                                 f"each other), got --comm single")


def check_backend(backend) -> type:
    """The compute backend's class, refused in one line when it cannot run here (no GPU)."""
    cls = get("compute", backend, "--backend")
    why = cls.unavailable()
    if why is not None:
        raise InputError(f"--backend {cls.name}: expected a machine it can run on, got {why}")
    return cls


def check_ranks_fit(scene, ranks: int) -> None:
    """Refuse more ranks than slabs of 6h fit in the domain (an upper bound of what
    :func:`sphgraph.domain.equal_cuts` accepts), from the scene's numbers alone."""
    if ranks <= 1:
        return
    h = scene.physics.coefh * math.sqrt(scene.dim) * scene.dp
    widest = float((scene.domain_max - scene.domain_min).max())
    from .domain import MIN_SLAB_H
    most = max(1, int(widest / (MIN_SLAB_H * h)))
    if ranks > most:
        raise InputError(f"{scene.source}: decomposition: {ranks} ranks need a domain at least "
                         f"{ranks * MIN_SLAB_H * h:.4g} m wide (6h = {MIN_SLAB_H * h:.4g} m per subdomain), the domain's "
                         f"widest side is {widest:.4g} m: expected at most {most} ranks")
