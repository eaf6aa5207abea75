"""Particle sets: plain structure-of-arrays containers shared by every module.

A `Particles` holds the rows one rank owns (or a whole scene before it is split).
Rows are reordered by cell every step; `id` travels with them, so output is
always written in id order (see `io`).

Kinds follow DESIGN.md §5: 0 fluid, 1 fixed boundary, 2 moving boundary.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

FLUID = 0
FIXED = 1
MOVING = 2


@dataclass
class Particles:
    """Particle arrays of one set (N rows, `dim` columns for vectors).

    `vel_m1`/`rho_m1` are the Verlet history (values at step n-1); the Symplectic
    integrator keeps its stage-start values in `pos0`/`vel0`/`rho0`. Every array
    here is permuted together when rows are reordered or moved between ranks.
    """

    id: np.ndarray        # int64 [N]
    kind: np.ndarray      # int8 [N]
    pos: np.ndarray       # float [N, dim] (float64 also in float32 runs: no loss far from the origin)
    vel: np.ndarray       # float [N, dim]
    rho: np.ndarray       # float [N]
    vel_m1: np.ndarray    # float [N, dim]
    rho_m1: np.ndarray    # float [N]

    @classmethod
    def create(cls, ids, kind, pos, vel, rho, dtype=np.float64, pos_dtype=np.float64):
        pos = np.ascontiguousarray(pos, dtype=pos_dtype)
        vel = np.ascontiguousarray(vel, dtype=dtype)
        rho = np.ascontiguousarray(rho, dtype=dtype)
        return cls(
            id=np.ascontiguousarray(ids, dtype=np.int64),
            kind=np.ascontiguousarray(kind, dtype=np.int8),
            pos=pos, vel=vel, rho=rho,
            vel_m1=vel.copy(), rho_m1=rho.copy(),
        )

    @property
    def n(self) -> int:
        return int(self.id.shape[0])

    @property
    def dim(self) -> int:
        return int(self.pos.shape[1])

    @property
    def n_fluid(self) -> int:
        return int(np.count_nonzero(self.kind == FLUID))

    def arrays(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def take(self, index) -> "Particles":
        """Rows `index` (an index array or boolean mask) as a new set."""
        return Particles(**{k: np.ascontiguousarray(v[index]) for k, v in self.arrays().items()})

    def permute_(self, perm: np.ndarray) -> None:
        """Reorder rows in place by `perm` (new row i = old row perm[i])."""
        for k, v in self.arrays().items():
            setattr(self, k, np.ascontiguousarray(v[perm]))

    @staticmethod
    def concat(sets) -> "Particles":
        sets = [s for s in sets if s is not None]
        keys = sets[0].arrays().keys()
        return Particles(**{k: np.concatenate([getattr(s, k) for s in sets]) for k in keys})

    def nbytes(self) -> int:
        return sum(v.nbytes for v in self.arrays().values())


def in_id_order(parts: list) -> dict:
    """Output arrays of several ranks (`ComputeBackend.host_arrays` dicts, in rank order) as
    one set whose rows are in id order."""
    a = parts[0] if len(parts) == 1 else {k: np.concatenate([r[k] for r in parts]) for k in parts[0]}
    order = np.argsort(a["id"], kind="stable")
    if not np.array_equal(order, np.arange(len(order))):
        a = {k: v[order] for k, v in a.items()}
    return a
