"""Force dispatch of the numba.cuda backend: which force kernels (cuda_forces) a part
launches, with what grid and into which buffers (`forces`), and the sum of the parts
(`reduce_forces`). An ipc halo's part goes to cuda_halo_dispatch."""
from __future__ import annotations

import numpy as np

from sphgraph.config import O_DDT, O_KERNEL, O_LAMINAR, P_SUPPORT2
from sphgraph.state import PARTS

from . import cuda_dufort as CD
from . import cuda_halo as CH
from . import cuda_halo_kernels as HK
from . import cuda_kernels as CK
from . import cuda_riemann as CR
from . import cuda_rjump as CJ

TRIM_OFF = 1e30          # tpad that keeps every row whole (finite: fastmath assumes no inf)


class CudaForceDispatch:
    """NumbaCUDA's forces and their reduction."""

    def forces(self, state, part: str) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        n, dim = dv.n, dv.dim
        halos_exist = any(h is not None and h.n for h in state.halos.values())
        # one part only: the interior, written reduced -- not where periodic images come after
        # it (forces_images), which at a run's first stage have not been made yet, nor with the
        # renormalised jump, whose correction is made where the parts are summed (cuda_rjump)
        final = part == "interior" and not halos_exist and state.nranks == 1 and not state.extra.get("images") \
            and not CJ.enabled(state)
        A = dv.A()
        if part == "interior":
            g = dv.grid
            src = (A["rx"], A["ry"], A["rz"], A["vx"], A["vy"], A["vz"], A["rho"], A["press"], A["kind"])
            start, origin, inv, dims, axes, reach = A["start"], g["origin"], g["inv"], g["dims"], g["axes"], g["reach"]
        else:
            halo = state.halos.get(int(part[-1]))
            if isinstance(halo, CH.DeviceEdge):
                self._halo_forces(state, dv, part, halo)
                return
            if halo is None or halo.cells is None:
                dv.parts.pop(part, None)
                return
            hd = halo.press
            src = (hd["rx"], hd["ry"], hd["rz"], hd["vx"], hd["vy"], hd["vz"], hd["rho"], hd["press"], hd["kind"])
            gr = halo.cells
            self._read_halo(state, dv, halo)
            start, origin, inv, dims, axes, reach = hd["start"], gr.origin, 1.0 / gr.size, gr.dims, gr.axes, gr.reach
        if final:
            out = (A["ax"], A["ay"], A["az"], A["ar"], A["ar"], A["kind"], A["visc"])
            dv.parts = {}
        else:
            buf = dv.part_buffer(part, max(n, 1))
            out = (buf["x"], buf["y"], buf["z"], buf["ar"], buf["ddt"], buf["cancel"], A["visc"])
        dfa = CD.ddk_out(self, state, dv, part, final)      # K_a out (the DuFort-Frankel step), else ()
        jma = CJ.jm_out(self, state, dv, part, final)       # the jump's moments (cuda_rjump), else ()
        gvec = np.zeros(3)
        gvec[:dim] = state.consts.gravity
        ft = dv.dtype.type
        if n and part == "interior":
            g = dv.grid
            nf, FB = dv.nf, CK.FORCE_BLOCK
            built = (CD.force_kernels if dfa else CJ.force_kernels if jma else
                     CR.force_kernels if CR.enabled(state) else CK.force_kernels)(
                dv.dtype, state.prm, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]))
            kf = self._on(state, built)
            if built.relative:
                # cell ranges from the relative positions: origin less the reference point,
                # support radius padded by the rounding of both (k_forces_fv)
                rel = [float(origin[k]) - float(dv.ref[axes[k]]) if axes[k] >= 0 else 0.0 for k in range(3)]
                span = max([abs(x) for x in rel] + [float(dims[k]) / float(inv) for k in range(3)])
                pad = np.sqrt(state.prm[P_SUPPORT2]) * (1 + 1e-6) + 16 * np.finfo(dv.dtype).eps * span
                # rows trimmed along the cell rows with the sort order stale by at most
                # 2 * moved (the Symplectic predictor), or not at all (TRIM_OFF)
                tpad = 2.0 * dv.moved * (1 + 1e-6) + 16 * np.finfo(dv.dtype).eps * span
                tpad = TRIM_OFF if not np.isfinite(tpad) or tpad > TRIM_OFF else tpad
                rel_args = (ft(rel[0]), ft(rel[1]), ft(rel[2]), ft(inv), ft(pad), ft(tpad),
                            int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]),
                            1 if final else 0, ft(gvec[0]), ft(gvec[1]), ft(gvec[2]))
                if nf:
                    kf.k_forces_f[CK.blocks(nf, FB), FB](A["pos4"], A["vel4"], A["kind"], 0, nf, start, int(g["ncells"]),
                                                         *rel_args, *out, *dfa, *jma)
                if n > nf:
                    kf.k_forces_b[CK.blocks(n - nf, FB), FB](A["pos4"], A["vel4"], A["kind"], nf, n, start,
                                                             int(g["ncells"]), *rel_args, *out)
            else:           # k_forces_f / k_forces_b (SPHGRAPH_CUDA_FORCES=f)
                geo = (start, int(g["ncells"]), float(origin[0]), float(origin[1]), float(origin[2]), float(inv),
                       int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]),
                       int(reach), dv.prm_d(state), dim, int(state.opt[O_KERNEL]))
                if nf:
                    kf.k_forces_f[CK.blocks(nf, FB), FB](
                        A["px"], A["py"], A["pz"], A["pos4"], A["vel4"], A["kind"], 0, nf, *geo,
                        int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]), 1 if final else 0,
                        ft(gvec[0]), ft(gvec[1]), ft(gvec[2]), *out)
                if n > nf:
                    kf.k_forces_b[CK.blocks(n - nf, FB), FB](
                        A["px"], A["py"], A["pz"], A["pos4"], A["vel4"], A["kind"], nf, n, *geo, 1 if final else 0,
                        *out)
        elif n:
            kh = (self._on(state, CD.build(dv.dtype)).k_forces_df if dfa else
                  self._on(state, CJ.build(dv.dtype)).k_forces_rj if jma else
                  self._on(state, CR.build(dv.dtype)).k_forces if CR.enabled(state) else k.k_forces)
            kh[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
                A["px"], A["py"], A["pz"], A["rx"], A["ry"], A["rz"], A["vx"], A["vy"], A["vz"],
                A["rho"], A["press"], A["kind"], n, *src,
                start, float(origin[0]), float(origin[1]), float(origin[2]), float(inv),
                int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), int(reach),
                dv.prm_d(state), dim, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]),
                1 if final else 0, ft(gvec[0]), ft(gvec[1]), ft(gvec[2]), *out, *dfa, *jma)
        dv.final = final
        self._sync()

    def reduce_forces(self, state, stage: int) -> None:
        if state.reduced_stage == (state.step, stage):
            return
        dv = state.extra["dev"]
        state.reduced_stage = (state.step, stage)
        if not dv.parts:      # single part written reduced by the force kernel
            return
        k = self._k(state)
        if dv.halo_ranges and dv.n:
            self._reduce_ranged(state, dv)
            CD.reduce(self, state, dv, True)
            CJ.reduce(self, state, dv, True)      # after k_reduce_ranged wrote ar
            self._sync()
            return
        bufs = [dv.parts[p] for p in PARTS if p in dv.parts]
        nparts = len(bufs)
        while len(bufs) < 4:
            bufs.append(bufs[0])
        flat = []
        for b in bufs:
            flat += [b["x"], b["y"], b["z"], b["ar"], b["ddt"], b["cancel"]]
        gvec = np.zeros(3)
        gvec[:dv.dim] = state.consts.gravity
        ft = dv.dtype.type
        A = dv.A()
        if dv.n:
            k.k_reduce[CK.blocks(dv.n), CK.BLOCK](nparts, dv.n, dv.dim, A["kind"], ft(gvec[0]), ft(gvec[1]),
                                                 ft(gvec[2]), *flat, A["ax"], A["ay"], A["az"], A["ar"])
        CD.reduce(self, state, dv, False)
        CJ.reduce(self, state, dv, False)         # after k_reduce wrote ar
        self._sync()

    def _reduce_ranged(self, state, dv) -> None:
        """reduce_forces with ipc halo parts, each added at its target rows only."""
        inner = dv.parts["interior"]
        flat = []
        for used, r, b in CH.ranged_parts(dv):
            flat += [used, r, b["x"], b["y"], b["z"], b["ar"], b["ddt"], b["cancel"]]
        gvec = np.zeros(3)
        gvec[:dv.dim] = state.consts.gravity
        ft = dv.dtype.type
        A = dv.A()
        hk = self._on(state, HK.build(dv.dtype))
        hk.k_reduce_ranged[CK.blocks(dv.n), CK.BLOCK](
            dv.n, dv.dim, A["kind"], ft(gvec[0]), ft(gvec[1]), ft(gvec[2]),
            inner["x"], inner["y"], inner["z"], inner["ar"], inner["ddt"], inner["cancel"], A["pick8"], *flat,
            A["ax"], A["ay"], A["az"], A["ar"])
