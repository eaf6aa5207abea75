"""Per-rank solver state: what the tasks of one rank read and write.

The names of the attributes are the data names that tasks declare in
`sphgraph.graph.tasks` ("particles", "cells", "halo_1", "forces", "dt", ...).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .config import Constants
from .particles import Particles
from .physics.riemann_jump import RJ_SUMS


@dataclass
class Halo:
    """What a neighbour sends of its edge: only what the forces need.

    Position, velocity and density (seed paper §III-A), and the kind, which
    the DBC formulation needs to tell boundary from fluid neighbours.
    Pressure is derived from density on receipt; cells are built on receipt.
    """

    pos: np.ndarray
    vel: np.ndarray
    rho: np.ndarray
    kind: np.ndarray
    press: np.ndarray | None = None
    cells: object = None
    order: np.ndarray | None = None   # on receipt: the sender's edge row of each (binned) row

    @property
    def n(self) -> int:
        return int(self.rho.shape[0])

    @property
    def n_fluid(self) -> int:
        """Fluid rows (a device halo says the same of its rows: cuda_halo.DeviceEdge)."""
        return int(np.count_nonzero(self.kind == 0))

    def nbytes(self) -> int:
        return self.pos.nbytes + self.vel.nbytes + self.rho.nbytes + self.kind.nbytes


@dataclass
class ForceBuffers:
    """One partial force buffer (interior, halo 1 or halo 2): accumulate target."""

    ace: np.ndarray
    ar: np.ndarray
    ddt: np.ndarray
    cancel: np.ndarray
    visc: np.ndarray
    ddk: np.ndarray = None    # K_a of the DuFort-Frankel diffusion step (n rows), else empty
    jm: np.ndarray = None     # the renormalised jump's moments (12 x n, physics.riemann_jump), else 12 x 0

    @classmethod
    def empty(cls, n, dim, dtype, ddk=False, jm=False):
        return cls(ace=np.zeros((n, dim), dtype), ar=np.zeros(n, dtype), ddt=np.zeros(n, dtype),
                   cancel=np.zeros(n, np.int8), visc=np.zeros(n, dtype),
                   ddk=np.zeros(n if ddk else 0, dtype), jm=np.zeros((RJ_SUMS, n if jm else 0), dtype))


PARTS = ("interior", "halo_1", "halo_2", "halo_3")  # fixed summation order (halo_3: the periodic images)


@dataclass
class RankState:
    particles: Particles
    consts: Constants
    dtype: type
    rank: int = 0
    nranks: int = 1
    prm: np.ndarray = None
    opt: np.ndarray = None
    cells: object = None
    press: np.ndarray = None
    halos: dict = field(default_factory=dict)      # 1 / 2 -> Halo
    parts: dict = field(default_factory=dict)      # part name -> ForceBuffers (this stage)
    ace: np.ndarray = None                          # reduced forces of the current stage
    ar: np.ndarray = None
    visc: np.ndarray = None
    ddk: np.ndarray = None                          # reduced K_a (DuFort-Frankel diffusion step)
    reduced_stage: int = -1
    dt_local: float = np.inf
    dt: float = 0.0
    time: float = 0.0
    step: int = 0
    stage0: tuple = None                            # Symplectic stage-start arrays
    # slab decomposition (multi-rank): split axis and this rank's [lo, hi) cut coordinates
    axis: int = 0
    axes: np.ndarray = None                         # cell axis order (fast, mid, slow)
    cfl: float = 0.2
    rho_min: float = 0.0
    rho_max: float = np.inf
    cut_lo: float = -np.inf
    cut_hi: float = np.inf
    bytes_sent: int = 0
    # reference point of a device backend's float positions: the same on every rank of a
    # multi-rank run (a rank's position records are valid on its neighbours); None: its own
    ref: np.ndarray = None
    # build_cells of this step already ran (recv_displaced then merges the arrivals into
    # the sorted rows): the step it ran in, None once send_displaced changed the rows
    cells_step: int | None = None
    sort_perm: np.ndarray = None                    # that build's order: sorted row i = row sort_perm[i]
    # the end-of-step check of the `exclude` task (sphgraph.features): its (row, cause) or None,
    # the step it ran in, and the (step, time, id, cause) rows it removed, until the solver
    # collects them
    check: tuple | None = None
    check_step: int = -1
    pending_check: tuple | None = None              # started by check_begin, read by check_end
    excluded: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)      # data of user-defined tasks

    def __post_init__(self):
        self.prm = self.consts.prm.astype(self.dtype)
        self.opt = self.consts.opt.copy()
