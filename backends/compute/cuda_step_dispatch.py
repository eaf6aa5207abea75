"""The rest of the numba.cuda step: the dt terms (`dt_local`), the integration
(`integrate`) and the check of the rows (`check`, with the rows' bounding box and the
next sort's edge bounds in the same host wait)."""
from __future__ import annotations

import numpy as np
from numba import cuda

from sphgraph.config import P_RHO0
from sphgraph.physics.damping import ZONE

from . import cuda_dufort as CD
from . import cuda_halo as CH
from . import cuda_kernels as CK
from .base import dt_from_terms
from .cuda_memory import count_bytes, dev_array

# Symplectic: the corrector's forces see the pressure of the predicted density (as
# numba-cpu and DualSPHysics); False would keep the step-start pressure.
FRESH_PRESSURE = True


class CudaStepDispatch:
    """NumbaCUDA's dt terms, integration and check (a mixin, as the others)."""

    def dt_local(self, state) -> float:
        self.dt_local_begin(state)
        return self.dt_local_end(state)

    def dt_local_begin(self, state) -> None:
        """The dt terms reduced and copied to pinned memory, an event after them; no wait."""
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        s = self._s(state)
        k.k_fill[1, 32](A["dtout"], 3, 0.0)       # on the device: no host copy, no host wait
        if dv.n:
            k.k_dt_terms[min(CK.REDUCE_BLOCKS, CK.blocks(dv.n)), 256](
                A["ax"], A["ay"], A["az"], A["vx"], A["vy"], A["vz"], A["visc"], A["kind"], dv.n, dv.dim, A["dtout"])
        A["dtout"].copy_to_host(dv.pinned_dt, stream=s)     # after the compute lane's forces and reduce
        over = A.get("edge_over")
        if over is not None:                     # an edge outgrew its bound (ipc halos): never silent
            over.copy_to_host(dv.pinned_over, stream=s)
        dv.start_read("dt", s, over is not None)

    def dt_local_end(self, state) -> float:
        dv = state.extra["dev"]
        pending, over = dv.wait_read("dt")
        if not pending:                          # read already (a second call of the same step)
            return state.dt_local
        if over and int(dv.pinned_over[0]):
            from sphgraph.errors import SphgraphError
            raise SphgraphError(f"rank {state.rank}: an edge of {int(dv.pinned_over[0])} rows outgrew the bound "
                                f"counted at the last check (cuda_halo.band_counts)")
        CH.check_generations(state, dv)          # ipc halos from other processes
        count_bytes(state, "d2h_bytes", "dt", 24)
        a2, v2, vm = (float(x) for x in dv.pinned_dt)
        dv.vmax = (state.step, np.sqrt(v2))       # the fluid rows' fastest speed (trim slack)
        c = state.consts
        return dt_from_terms(a2, v2, vm, c.h, c.c0, state.cfl)

    @staticmethod
    def _stage_start(dv):
        """The Symplectic stage-start float64 positions (px0, py0, pz0) of the rows'
        capacity: written by the predictor, read by the corrector of the same step (no
        sort or migration between them), allocated on first use."""
        A = dv.arrays
        m = max(dv.n, dv.cap, 1)
        if "px0" not in A or A["px0"].shape[0] < m:
            for ax in "xyz":
                A["p" + ax + "0"] = dev_array(m if (ax != "z" or dv.dim == 3) else 1, np.float64)
        return A["px0"], A["py0"], A["pz0"]

    def damp(self, state, damping, dt: float) -> None:
        """The relaxation zones on the device rows (cuda_integrate.k_damp; the zones' table
        uploaded once a run)."""
        dv = state.extra["dev"]
        if not dv.n:
            return
        have = state.extra.get("damping_dev")
        if have is None or have[0] is not damping:
            have = state.extra["damping_dev"] = (damping, cuda.to_device(damping.table))
        A = dv.A()
        self._k(state).k_damp[CK.blocks(dv.n), CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"],
                                                         A["kind"], dv.n, dv.dim, have[1],
                                                         len(damping.table) // ZONE, float(dt))
        dv.host_stale = True

    def wrap_periodic(self, state, lo, hi, axes) -> None:
        """The device rows' positions along `axes` wrapped (cuda_integrate.k_wrap); the next
        build_cells sorts and packs them again."""
        dv = state.extra["dev"]
        if not dv.n or not len(axes):
            return
        A = dv.A()
        lo3, hi3, p3, w3 = [0.0] * 3, [1.0] * 3, [1.0] * 3, [0] * 3
        for a in axes:
            lo3[a], hi3[a], p3[a], w3[a] = float(lo[a]), float(hi[a]), float(hi[a] - lo[a]), 1
        self._k(state).k_wrap[CK.blocks(dv.n), CK.BLOCK](A["px"], A["py"], A["pz"], dv.n, *lo3, *hi3, *p3, *w3)
        dv.moved = np.inf
        dv.host_stale = True

    def integrate(self, state, stage: int, integrator: str, euler: bool) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        n, dim = dv.n, dv.dim
        ft = dv.dtype.type
        dt = ft(state.dt)
        rho0 = ft(state.consts.prm[P_RHO0])
        dv.integrator = integrator
        if n:
            b = CK.blocks(n)
            if integrator == "verlet":
                dk = CD.ddk_in(state, dv)          # K_a of the DuFort-Frankel step, else None
                k.k_verlet[b, CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"], A["rho"],
                                        A["vmx"], A["vmy"], A["vmz"], A["rhom"], A["kind"],
                                        A["ax"], A["ay"], A["az"], A["ar"], A["ar"] if dk is None else dk, n, dim,
                                        dt, bool(euler), rho0, dk is not None)
            else:
                # Symplectic stage-start velocity and density reuse the Verlet history slots;
                # the stage-start positions live only from the predictor to the corrector
                p0 = self._stage_start(dv)
                kern = k.k_sym_predict if stage == 1 else k.k_sym_correct
                kern[b, CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"], A["rho"], *p0,
                                  A["vmx"], A["vmy"], A["vmz"], A["rhom"], A["kind"],
                                  A["ax"], A["ay"], A["az"], A["ar"], n, dim, dt, rho0)
            # how far a row may have moved since the sort (k_forces_fv's trim slack): the
            # predictor moves fluid rows by dt/2 v, the fastest speed known from dt_local
            if integrator != "verlet" and stage == 1 and dv.vmax is not None and dv.vmax[0] == state.step:
                dv.moved += 0.5 * float(state.dt) * dv.vmax[1]
            else:
                dv.moved = np.inf
            if integrator != "verlet" and stage == 1:
                # the corrector's forces see the predicted positions (build_cells refreshes
                # them for the next step); pressure: see FRESH_PRESSURE
                self._pack(state, dv, k, FRESH_PRESSURE)
        k.k_fill[1, 32](A["visc"], 1, 0.0)   # the next stage's forces start the viscous maximum anew
        dv.host_stale = True
        self._sync()

    def check(self, state, lo, hi):
        self.check_begin(state, lo, hi)
        return self.check_end(state)

    def check_begin(self, state, lo, hi) -> None:
        """The check and the next sort's band counts launched and copied to pinned memory, an
        event after them; no wait."""
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.A()
        n, dim = dv.n, dv.dim
        k.k_check_init[1, 1](A["chk_bad"], A["chk_box"])   # on the device: no host copy, no host wait
        lo3 = np.zeros(3)
        hi3 = np.zeros(3)
        lo3[:dim] = lo
        hi3[:dim] = hi
        if n:
            k.k_check_bounds[min(CK.REDUCE_BLOCKS, CK.blocks(n)), 256](
                A["px"], A["py"], A["pz"], A["rho"], A["kind"], n, dim, *lo3, *hi3,
                float(state.rho_min), float(min(state.rho_max, 1e300)), A["chk_bad"], A["chk_box"])
        band = CH.band_counts(self, state, dv, k)     # the next sort's edge bounds, in the same wait
        s = self._s(state)
        A["chk_box"].copy_to_host(dv.pinned_chk[:6], stream=s)
        A["chk_bad"].copy_to_host(dv.pinned_bad, stream=s)
        dv.start_read("check", s, band)

    def check_end(self, state):
        dv = state.extra["dev"]
        n, dim = dv.n, dv.dim
        pending, band = dv.wait_read("check")
        if not pending:
            raise RuntimeError(f"rank {state.rank}: check_end without a check started (check_begin)")
        if band:
            CH.take_band(dv)
        box = dv.pinned_chk[:6].copy()
        bad = int(dv.pinned_bad[0])
        count_bytes(state, "d2h_bytes", "check", 56)
        if n:
            dv.box = np.array([box[:3], box[3:]])
            dv.box[:, dim:] = 0.0
        if bad == np.iinfo(np.int64).max:
            return None
        dv.host_stale = True
        self.sync_host(state)
        return bad // 4, bad % 4
