"""Compute backends: where the kernels of a step run.

A compute backend implements the compute tasks of a step on a `RankState`.
It knows nothing of ranks or messages: the comm backend moves `Halo` objects
and particle rows; the scheduler decides the order. Every backend passes the
shared conformance suite in `tests/test_compute_conformance.py`.
"""
from __future__ import annotations

import numpy as np


class ComputeBackend:
    """Base class. Subclasses register with `@register("compute", NAME)`."""

    name = "base"
    default_precision = "float64"

    def device_name(self) -> str:
        return "cpu"

    # -- set-up and transfers ----------------------------------------------------------
    def prepare(self, state) -> None:
        """Allocate what the kernels need for `state` (called after any change of N)."""
        raise NotImplementedError

    def host_arrays(self, state) -> dict:
        """Output arrays of the owned particles (host numpy): id, kind, position, velocity, density, pressure."""
        raise NotImplementedError

    # -- tasks -------------------------------------------------------------------------
    def build_cells(self, state) -> None:
        raise NotImplementedError

    def forces(self, state, part: str) -> None:
        raise NotImplementedError

    def prepare_halo(self, state, halo) -> None:
        raise NotImplementedError

    def reduce_forces(self, state, stage: int) -> None:
        raise NotImplementedError

    def dt_local(self, state) -> float:
        raise NotImplementedError

    def integrate(self, state, stage: int, integrator: str, euler: bool) -> None:
        raise NotImplementedError

    def check(self, state, lo, hi) -> tuple[int, int] | None:
        """(row, cause) of a bad particle or None: cause 1 NaN, 2 left domain, 3 density bounds."""
        raise NotImplementedError


CAUSES = {1: "NaN in position or density", 2: "particle left the domain",
          3: "density outside [rho_min, rho_max]"}


def dt_from_terms(a2max: float, v2max: float, viscmax: float, h: float, c0: float, cfl: float) -> float:
    """Variable dt (DualSPHysics JSphCpu::DtVariable, v5):

    dt1 = sqrt(h / max|a|),  dt2 = h / (max(c0, 10 max|v|) + h max ViscDt),
    dt = CFL min(dt1, dt2).
    """
    amax = float(np.sqrt(a2max))
    dt1 = np.sqrt(h / amax) if amax > 0 else np.inf
    dt2 = h / (max(c0, 10.0 * float(np.sqrt(v2max))) + h * viscmax)
    return float(cfl * min(dt1, dt2))
