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
not applied, ComputeSymplecticPreT<false>):

* in the last force stage of a step (Verlet: the only one; Symplectic: the corrector),
  each force task also runs the shifting neighbour pass of its source set (interior +
  periodic images, halo 1, halo 2): partial sums, like the force parts, so any order of
  the force tasks gives the same result and 1 or N ranks see the same neighbours;
* in ``integrate``: the parts are summed in a fixed order and turned into displacements
  from the velocities the forces saw (before the update), the update runs, and the
  displacements are added to the new positions.

The pass is the compute backend's (`shift_part`, `shift_displacement`, `shift_apply`:
numba-cpu in backends/compute/cpu_shifting.py, numba-cuda in cuda_shifting.py).
"""
from __future__ import annotations

from .config import SHIFTINGS
from .errors import InputError

IMAGES = "halo_3"   # periodic images (sphgraph.periodic.IMAGE_SIDE)


class Shifting:
    def __init__(self, mode: str, coef: float, tfs: float, dim: int, dp: float, h: float, stages: int):
        self.mode = mode
        self.mode_id = SHIFTINGS.index(mode)
        self.coef = float(coef)
        self.tfs = float(tfs)
        self.dim = dim
        self.h = float(h)
        self.maxdist = 0.1 * float(dp)      # DualSPHysics: max shifting distance 0.1 dp
        self.stage = stages                 # the stage whose shift is applied

    @classmethod
    def from_scene(cls, scene, sim) -> "Shifting":
        ph = scene.physics
        for hook in ("shift_part", "shift_displacement", "shift_apply"):
            if not callable(getattr(sim.compute, hook, None)):
                raise InputError(f"{scene.source}: physics.shifting: expected \"none\" with --backend "
                                 f"{sim.compute.name} (it has no particle shifting; use numba-cpu), "
                                 f"got {ph.shifting!r}")
        return cls(ph.shifting, ph.shifting_coef, ph.shifting_tfs, scene.dim, scene.dp, sim.consts.h,
                   1 if ph.integrator == "verlet" else 2)

    # ------------------------------------------------------------------ hooks
    def accumulate(self, ctx, part: str, stage: int) -> None:
        """After the force task of `part` in `stage`: that source set's partial sums."""
        if stage != self.stage:
            return
        ctx.compute.shift_part(ctx.state, part, self.mode_id)
        if part == "interior" and ctx.state.halos.get(3) is not None:   # periodic images, own rows
            ctx.compute.shift_part(ctx.state, IMAGES, self.mode_id)

    def before_integrate(self, ctx, stage: int) -> None:
        """Displacements from the summed parts and the stage's velocities (before the update)."""
        if stage != self.stage:
            return
        st = ctx.state
        # JSphShifting::RunCpu: coefumagn = dt ShiftCoef KernelH, coeftfs = dim - ShiftTFS
        ctx.compute.shift_displacement(st, st.dt * self.coef * self.h, self.tfs, self.dim - self.tfs,
                                       self.maxdist)

    def after_integrate(self, ctx, stage: int) -> None:
        if stage == self.stage:
            ctx.compute.shift_apply(ctx.state)
