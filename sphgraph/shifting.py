"""Particle shifting (Lind et al. 2012, as DualSPHysics does it), switched on by the scene.

    [physics]
    shifting = "full"       # "none" | "nobound" | "nofixed" | "full" (DualSPHysics Shifting 0..3)
    shifting_coef = -2.0    # ShiftCoef
    shifting_tfs = 1.5      # ShiftTFS: free-surface threshold on div r (0 = off; 2.75 in 3D)

Fluid particles move by dr = ShiftCoef h |v| dt grad C (each component clamped to
0.1 dp), zero where a boundary neighbour cancels it (modes "nobound", "nofixed") and,
with a threshold, zero near the free surface (formulas: sphgraph.physics.shifting).

When, as DualSPHysics (JSph*Single::ComputeStep_Ver / ComputeStepSymplectic:
RunShifting(dt) before ComputeVerlet / ComputeSymplecticCorr; the predictor's shift is
not applied, ComputeSymplecticPreT<false>), in the last force stage of a step (Verlet:
the only one; Symplectic: the corrector), as tasks of the step graph:

* ``shift_interior``, ``shift_images``, ``shift_halo_1``, ``shift_halo_2`` (each after
  its source set's force task): the shifting neighbour pass of that source set, partial
  sums (datum ``shift_sums``) like the force parts, so any order of them gives the same
  result and 1 or N ranks see the same neighbours;
* ``shift_displacement`` (before ``integrate``): the parts summed in a fixed order and
  turned into displacements from the velocities the forces saw (before the update);
* ``shift_apply`` (after ``integrate``): the displacements added to the new positions.

The pass is the compute backend's (`shift_part`, `shift_displacement`, `shift_apply`:
numba-cpu in backends/compute/cpu_shifting.py, numba-cuda in cuda_shifting.py).
"""
from __future__ import annotations

from .config import SHIFTINGS


class Shifting:
    def __init__(self, mode: str, coef: float, tfs: float, dim: int, dp: float, h: float, stages: int):
        self.mode = mode
        self.mode_id = SHIFTINGS.index(mode)
        self.coef = float(coef)
        self.tfs = float(tfs)
        self.dim = dim
        self.h = float(h)
        self.maxdist = 0.1 * float(dp)      # DualSPHysics: max shifting distance 0.1 dp
        self.stage = stages                 # the stage whose shift is applied (its tasks' stage)

    @classmethod
    def from_scene(cls, scene, sim) -> "Shifting":
        ph = scene.physics
        return cls(ph.shifting, ph.shifting_coef, ph.shifting_tfs, scene.dim, scene.dp, sim.consts.h,
                   1 if ph.integrator == "verlet" else 2)

    # ------------------------------------------------------------------ task bodies
    def sums(self, ctx, part: str) -> None:
        """``shift_<part>``: the partial sums of source set `part` ("halo_3": the images)."""
        ctx.compute.shift_part(ctx.state, part, self.mode_id)

    def displacement(self, ctx) -> None:
        """``shift_displacement``: from the summed parts and the stage's velocities (before
        the update)."""
        st = ctx.state
        # JSphShifting::RunCpu: coefumagn = dt ShiftCoef KernelH, coeftfs = dim - ShiftTFS
        ctx.compute.shift_displacement(st, st.dt * self.coef * self.h, self.tfs, self.dim - self.tfs,
                                       self.maxdist)

    def apply(self, ctx) -> None:
        """``shift_apply``: the displacements added to the updated positions."""
        ctx.compute.shift_apply(ctx.state)
