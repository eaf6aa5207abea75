"""numba.cuda backend: the whole step on the GPU, particle arrays resident between steps.

Device data of a rank live in `state.extra["dev"]` (a `DeviceState`); the host
`state.particles` is brought up to date only when asked (`host_arrays` for frames,
`sync_host` for the comm layer, a failed check). Per step, what crosses the bus is
the dt terms (3 float64), the check result with the rows' bounding box (8 numbers),
and, with several ranks, halos and displaced rows; the counters are
`state.extra["h2d_bytes"]` / `["d2h_bytes"]` (cumulative) and `["bytes_by_kind"]`.

Precision: positions are float64 on the device (no loss of resolution in a large
domain); velocities, densities, pressures and all force arithmetic are in the run's
type (float32 by default). The force loop reads float copies of the positions
relative to a per-rank reference point (the first bounding-box minimum), so a
float32 pair distance resolves ~6e-8 of the scene's extent, not of |x|.
"""
from __future__ import annotations

import os

import numpy as np
from numba import cuda

from sphgraph.config import O_DDT, O_KERNEL, O_LAMINAR, P_RHO0, P_SUPPORT2
from sphgraph.registry import register

from . import cuda_kernels as CK
from .base import ComputeBackend, dt_from_terms

_VEC = ("x", "y", "z")
# Symplectic: the corrector's forces see the pressure of the predicted density (as
# numba-cpu and DualSPHysics); False would keep the step-start pressure.
FRESH_PRESSURE = True


class DeviceState:
    """Device arrays of one rank (structure of arrays) and the pinned host buffers."""

    def __init__(self, n, dim, dtype, ref):
        self.n = n
        self.dim = dim
        self.dtype = np.dtype(dtype)
        self.ref = np.asarray(ref, np.float64)     # reference point of the float positions
        self.arrays = {}                            # name -> device array (owned, swapped on sort)
        self.grid = None                            # dict: origin(perm), dims, axes, inv, reach, ncells
        self.box = None                             # host bounding box [min3, max3] of the rows
        self.parts = {}
        self.cell_cap = 0
        self.scan_tmp = []
        self.pinned_dt = cuda.pinned_array(3, np.float64) if not CK.SIMULATOR else np.zeros(3)
        self.pinned_chk = cuda.pinned_array(7, np.float64) if not CK.SIMULATOR else np.zeros(7)
        self.host_stale = False
        self.final = True

    def __getattr__(self, name):
        try:
            return self.__dict__["arrays"][name]
        except KeyError:
            raise AttributeError(name) from None

    def nbytes(self) -> int:
        seen = set()
        total = 0
        for a in list(self.arrays.values()) + self.scan_tmp + \
                [x for b in self.parts.values() for x in b.values()]:
            if id(a) not in seen:
                seen.add(id(a))
                total += a.nbytes
        return total


def _count(state, direction, kind, nbytes):
    e = state.extra
    e[direction] = e.get(direction, 0) + int(nbytes)
    by = e.setdefault("bytes_by_kind", {})
    k = f"{direction[:3]}:{kind}"
    by[k] = by.get(k, 0) + int(nbytes)


@register("compute", "numba-cuda")
class NumbaCUDA(ComputeBackend):
    default_precision = "float32"

    def __init__(self):
        self.sync_tasks = os.environ.get("SPHGRAPH_CUDA_SYNC", "0") == "1"  # profile: time kernels per task

    def device_name(self) -> str:
        if CK.SIMULATOR:
            return "cuda simulator"
        d = cuda.get_current_device()
        name = d.name.decode() if isinstance(d.name, bytes) else str(d.name)
        return f"cuda {name} (cc {d.compute_capability[0]}.{d.compute_capability[1]})"

    def _k(self, state):
        return CK.build(state.dtype)

    def _sync(self):
        if self.sync_tasks:
            cuda.synchronize()

    # -- set-up and transfers ----------------------------------------------------------
    def prepare(self, state) -> None:
        """Upload the host particles (all of them: called at set-up and after rows moved)."""
        p = state.particles
        dim = p.dim
        dt = np.dtype(state.dtype)
        old = state.extra.get("dev")
        ref = old.ref if old is not None else (p.pos.min(axis=0) if p.n else np.zeros(dim))
        dv = DeviceState(p.n, dim, dt, ref)
        n = max(p.n, 1)
        up = 0

        def put(name, host, dtype):
            nonlocal up
            h = np.ascontiguousarray(host, dtype=dtype)
            if h.shape[0] == 0:
                h = np.zeros(1, dtype)
            dv.arrays[name] = cuda.to_device(h)
            up += h.nbytes

        for d in range(3):
            ax = _VEC[d]
            if d < dim:
                put("p" + ax, p.pos[:, d], np.float64)
                put("v" + ax, p.vel[:, d], dt)
                put("vm" + ax, p.vel_m1[:, d], dt)
            else:   # 2D: one-element dummies
                for pre in ("p", "v", "vm"):
                    dv.arrays[pre + ax] = cuda.device_array(1, np.float64 if pre == "p" else dt)
        put("rho", p.rho, dt)
        put("rhom", p.rho_m1, dt)
        put("kind", p.kind, np.int8)
        put("id", p.id, np.int64 if p.n and int(p.id.max()) >= 2 ** 31 else np.int32)
        # work arrays (not uploaded)
        for ax in _VEC[:dim]:
            dv.arrays["r" + ax] = cuda.device_array(n, dt)       # float positions rel. to ref
            dv.arrays["a" + ax] = cuda.device_array(n, dt)       # reduced acceleration
        for ax in _VEC[dim:]:
            dv.arrays["r" + ax] = cuda.device_array(1, dt)
            dv.arrays["a" + ax] = cuda.device_array(1, dt)
        dv.arrays["press"] = cuda.device_array(n, dt)
        dv.arrays["ar"] = cuda.device_array(n, dt)
        dv.arrays["visc"] = cuda.device_array(n, dt)
        dv.arrays["keys"] = cuda.device_array(n, np.int32)
        dv.arrays["perm"] = cuda.device_array(n, np.int32)
        dv.arrays["tmp64"] = cuda.device_array(n, np.float64)
        dv.arrays["tmp8"] = cuda.device_array(n, np.int8)
        dv.arrays["tmpid"] = cuda.device_array(n, dv.arrays["id"].dtype)
        dv.arrays["dtout"] = cuda.device_array(3, np.float64)
        dv.arrays["chk_bad"] = cuda.device_array(1, np.int64)
        dv.arrays["chk_box"] = cuda.device_array(6, np.float64)
        dv.box = np.zeros((2, 3))
        if p.n:
            dv.box[0, :dim] = p.pos.min(axis=0)
            dv.box[1, :dim] = p.pos.max(axis=0)
        state.extra["dev"] = dv
        _count(state, "h2d_bytes", "upload", up)
        state.parts = {}
        state.reduced_stage = -1
        # the solver's stage-0 / press / ace slots stay None: the device holds them

    def sync_host(self, state) -> None:
        """Bring the host `state.particles` up to the device rows (order included)."""
        dv = state.extra.get("dev")
        if dv is None or not dv.host_stale:
            return
        p = state.particles
        n, dim = dv.n, dv.dim
        down = 0

        def get(name):
            nonlocal down
            a = dv.arrays[name].copy_to_host()[:n]
            down += a.nbytes
            return a

        pos = np.empty((n, dim), np.float64)
        vel = np.empty((n, dim), dv.dtype)
        vm = np.empty((n, dim), dv.dtype)
        for d in range(dim):
            ax = _VEC[d]
            pos[:, d] = get("p" + ax)
            vel[:, d] = get("v" + ax)
            vm[:, d] = get("vm" + ax)
        p.pos = pos.astype(p.pos.dtype, copy=False)
        p.vel = vel.astype(p.vel.dtype, copy=False)
        p.vel_m1 = vm.astype(p.vel_m1.dtype, copy=False)
        p.rho = get("rho").astype(p.rho.dtype, copy=False)
        p.rho_m1 = get("rhom").astype(p.rho_m1.dtype, copy=False)
        p.kind = get("kind")
        p.id = get("id").astype(np.int64)
        dv.host_stale = False
        _count(state, "d2h_bytes", "sync_host", down)

    def device_rows_to_host(self, state, rows) -> dict:
        """Position, velocity, density, kind of device rows `rows` (host index array), as a
        halo/edge would carry them (phase 2 of multi-GPU: gathered on the device, pinned)."""
        self.sync_host(state)
        p = state.particles
        return {"pos": p.pos[rows], "vel": p.vel[rows], "rho": p.rho[rows], "kind": p.kind[rows]}

    def host_arrays(self, state) -> dict:
        self.sync_host(state)
        p = state.particles
        from sphgraph.physics.eos import pressure
        press = pressure(np.asarray(p.rho), state.prm.astype(p.rho.dtype))
        return {"id": p.id, "kind": p.kind, "position": p.pos, "velocity": p.vel,
                "density": p.rho, "pressure": press}

    # -- cells -------------------------------------------------------------------------
    def _scan(self, dv, k, counts, out, n, level=0):
        """Exclusive scan of counts[0:n] into out[0:n] (device, recursive over block sums)."""
        per = 2048
        nb = (n + per - 1) // per
        while len(dv.scan_tmp) < 2 * level + 2:
            dv.scan_tmp.append(cuda.device_array(1, np.int64))
        if dv.scan_tmp[2 * level].shape[0] < nb:
            dv.scan_tmp[2 * level] = cuda.device_array(int(nb * 1.25) + 1, np.int64)
            dv.scan_tmp[2 * level + 1] = cuda.device_array(int(nb * 1.25) + 1, np.int64)
        sums, offs = dv.scan_tmp[2 * level], dv.scan_tmp[2 * level + 1]
        k.k_scan_blocks[nb, 256](counts, n, out, sums)
        if nb > 1:
            self._scan(dv, k, sums, offs, nb, level + 1)
            k.k_scan_add[CK.blocks(n), CK.BLOCK](out, n, offs)

    def build_cells(self, state) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        n, dim = dv.n, dv.dim
        c = state.consts
        reach = int(np.ceil(2.0 * c.h / c.cell_size - 1e-9))
        axes = np.asarray(state.axes, np.int64)
        # grid over the rows' bounding box (from the last check), as sphgraph.cells.build_grid
        lo = np.zeros(3)
        hi = np.zeros(3)
        for kk in range(3):
            a = axes[kk]
            if a >= 0 and n:
                lo[kk] = dv.box[0, a]
                hi[kk] = dv.box[1, a]
        dims = np.maximum(np.floor((hi - lo) / c.cell_size).astype(np.int64) + 1, 1)
        dims[axes < 0] = 1
        ncells = int(dims.prod())
        # per particle axis: origin, cells, key stride
        stride_perm = np.array([1, dims[0], dims[0] * dims[1]], np.int64)
        o_ax = np.zeros(3)
        n_ax = np.ones(3, np.int64)
        s_ax = np.zeros(3, np.int64)
        for kk in range(3):
            a = axes[kk]
            if a >= 0:
                o_ax[a], n_ax[a], s_ax[a] = lo[kk], dims[kk], stride_perm[kk]
        if dv.cell_cap < ncells + 1:
            cap = int((ncells + 1) * 1.25) + 16
            dv.arrays["start"] = cuda.device_array(cap, np.int64)
            dv.arrays["counts"] = cuda.device_array(cap, np.int64)
            dv.cell_cap = cap
        start, counts = dv.start, dv.counts
        inv = 1.0 / c.cell_size
        if n:
            k.k_fill[CK.blocks(ncells), CK.BLOCK](counts, ncells, 0)
            k.k_keys_hist[CK.blocks(n), CK.BLOCK](dv.px, dv.py, dv.pz, n, dim, o_ax[0], o_ax[1], o_ax[2], inv,
                                                   n_ax[0], n_ax[1], n_ax[2], s_ax[0], s_ax[1], s_ax[2],
                                                   dv.keys, counts)
            self._scan(dv, k, counts, start, ncells)
            k.k_set_last[1, 1](start, ncells, n)
            # scatter: counts becomes the fill pointer (a copy of start)
            k.k_copy[CK.blocks(ncells), CK.BLOCK](start, ncells, counts)
            k.k_scatter[CK.blocks(n), CK.BLOCK](dv.keys, n, counts, dv.perm)
            k.k_sort_cells[CK.blocks(ncells), CK.BLOCK](start, ncells, dv.perm)
            self._permute(state, dv, k)
        else:
            k.k_fill[CK.blocks(ncells + 1), CK.BLOCK](start, ncells + 1, 0)
        dv.grid = {"origin": lo, "dims": dims, "axes": axes, "inv": inv, "reach": reach,
                   "ncells": ncells, "size": c.cell_size}
        if n:
            k.k_pressure[CK.blocks(n), CK.BLOCK](dv.rho, n, dv.prm_d(state), dv.press)
        dv.host_stale = True
        self._sync()

    def _permute(self, state, dv, k):
        n, perm = dv.n, dv.perm
        b = CK.blocks(n)
        A = dv.arrays
        for d in range(dv.dim):       # float64 positions, and their float copies (no scratch)
            ax = _VEC[d]
            k.k_gather_pos[b, CK.BLOCK](A["p" + ax], perm, n, dv.ref[d], A["tmp64"], A["r" + ax])
            A["p" + ax], A["tmp64"] = A["tmp64"], A["p" + ax]
        # run-type arrays through the acceleration slots (dead until the forces)
        hist = getattr(dv, "integrator", "verlet") == "verlet"   # Symplectic: history rewritten each step
        names = [pre + _VEC[d] for pre in (("v", "vm") if hist else ("v",)) for d in range(dv.dim)] + \
            (["rho", "rhom"] if hist else ["rho"])
        scratch = ["a" + _VEC[d] for d in range(dv.dim)] + ["ar", "visc"]
        for name in names:
            s = scratch[0]
            k.k_gather[b, CK.BLOCK](A[name], perm, n, A[s])
            A[name], A[s] = A[s], A[name]
        k.k_gather[b, CK.BLOCK](A["kind"], perm, n, A["tmp8"])
        A["kind"], A["tmp8"] = A["tmp8"], A["kind"]
        k.k_gather[b, CK.BLOCK](A["id"], perm, n, A["tmpid"])
        A["id"], A["tmpid"] = A["tmpid"], A["id"]

    def prepare_halo(self, state, halo) -> None:
        """Halo rows to the device, sorted by cell (host-staged; phase 2 sorts on the device)."""
        from sphgraph.cells import build_grid
        dv = state.extra["dev"]
        dt = dv.dtype
        c = state.consts
        if halo.n == 0:
            halo.cells = None
            halo.press = None
            return
        reach = int(np.ceil(2.0 * c.h / c.cell_size - 1e-9))
        grid, perm = build_grid(np.asarray(halo.pos, np.float64), c.cell_size, reach, state.axes)
        halo.pos, halo.vel = halo.pos[perm], halo.vel[perm]
        halo.rho, halo.kind = halo.rho[perm], halo.kind[perm]
        d = {}
        up = 0
        for i in range(3):
            ax = _VEC[i]
            if i < dv.dim:
                d["r" + ax] = np.ascontiguousarray(halo.pos[:, i] - dv.ref[i], dt)
                d["v" + ax] = np.ascontiguousarray(halo.vel[:, i], dt)
            else:
                d["r" + ax] = np.zeros(1, dt)
                d["v" + ax] = np.zeros(1, dt)
        d["rho"] = np.ascontiguousarray(halo.rho, dt)
        d["kind"] = np.ascontiguousarray(halo.kind, np.int8)
        d["start"] = grid.start
        dd = {}
        for key, v in d.items():
            dd[key] = cuda.to_device(v)
            up += v.nbytes
        dd["press"] = cuda.device_array(halo.n, dt)
        self._k(state).k_pressure[CK.blocks(halo.n), CK.BLOCK](dd["rho"], halo.n, dv.prm_d(state), dd["press"])
        halo.press = dd
        halo.cells = grid
        _count(state, "h2d_bytes", "halo", up)

    # -- forces ------------------------------------------------------------------------
    def forces(self, state, part: str) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        n, dim = dv.n, dv.dim
        halos_exist = any(h is not None and h.n for h in state.halos.values())
        final = part == "interior" and not halos_exist and state.nranks == 1
        A = dv.arrays
        if part == "interior":
            g = dv.grid
            src = (A["rx"], A["ry"], A["rz"], A["vx"], A["vy"], A["vz"], A["rho"], A["press"], A["kind"])
            start, origin, inv, dims, axes, reach = A["start"], g["origin"], g["inv"], g["dims"], g["axes"], g["reach"]
        else:
            halo = state.halos.get(int(part[-1]))
            if halo is None or halo.cells is None:
                dv.parts.pop(part, None)
                return
            hd = halo.press
            src = (hd["rx"], hd["ry"], hd["rz"], hd["vx"], hd["vy"], hd["vz"], hd["rho"], hd["press"], hd["kind"])
            gr = halo.cells
            start, origin, inv, dims, axes, reach = hd["start"], gr.origin, 1.0 / gr.size, gr.dims, gr.axes, gr.reach
        if final:
            out = (A["ax"], A["ay"], A["az"], A["ar"], A["ar"], A["kind"], A["visc"])
            dv.parts = {}
        else:
            buf = dv.parts.get(part)
            if buf is None or buf["ar"].shape[0] != max(n, 1):
                m = max(n, 1)
                buf = {"x": cuda.device_array(m, dv.dtype), "y": cuda.device_array(m, dv.dtype),
                       "z": cuda.device_array(m if dim == 3 else 1, dv.dtype),
                       "ar": cuda.device_array(m, dv.dtype), "ddt": cuda.device_array(m, dv.dtype),
                       "cancel": cuda.device_array(m, np.int8), "visc": cuda.device_array(m, dv.dtype)}
                dv.parts[part] = buf
            out = (buf["x"], buf["y"], buf["z"], buf["ar"], buf["ddt"], buf["cancel"], buf["visc"])
        gvec = np.zeros(3)
        gvec[:dim] = state.consts.gravity
        ft = dv.dtype.type
        if n:
            k.k_forces[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
                A["px"], A["py"], A["pz"], A["rx"], A["ry"], A["rz"], A["vx"], A["vy"], A["vz"],
                A["rho"], A["press"], A["kind"], n, *src,
                start, float(origin[0]), float(origin[1]), float(origin[2]), float(inv),
                int(dims[0]), int(dims[1]), int(dims[2]), int(axes[0]), int(axes[1]), int(axes[2]), int(reach),
                dv.prm_d(state), dim, int(state.opt[O_KERNEL]), int(state.opt[O_DDT]), int(state.opt[O_LAMINAR]),
                1 if final else 0, ft(gvec[0]), ft(gvec[1]), ft(gvec[2]), *out)
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
        bufs = [dv.parts[p] for p in ("interior", "halo_1", "halo_2") if p in dv.parts]
        while len(bufs) < 3:
            bufs.append(bufs[0])
        nparts = len([p for p in ("interior", "halo_1", "halo_2") if p in dv.parts])
        flat = []
        for b in bufs:
            flat += [b["x"], b["y"], b["z"], b["ar"], b["ddt"], b["cancel"], b["visc"]]
        gvec = np.zeros(3)
        gvec[:dv.dim] = state.consts.gravity
        ft = dv.dtype.type
        A = dv.arrays
        if dv.n:
            k.k_reduce[CK.blocks(dv.n), CK.BLOCK](nparts, dv.n, dv.dim, A["kind"], ft(gvec[0]), ft(gvec[1]),
                                                 ft(gvec[2]), *flat, A["ax"], A["ay"], A["az"], A["ar"], A["visc"])
        self._sync()

    def dt_local(self, state) -> float:
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.arrays
        zero = np.zeros(3)
        A["dtout"].copy_to_device(zero)
        if dv.n:
            k.k_dt_terms[min(CK.REDUCE_BLOCKS, CK.blocks(dv.n)), 256](
                A["ax"], A["ay"], A["az"], A["vx"], A["vy"], A["vz"], A["visc"], A["kind"], dv.n, dv.dim, A["dtout"])
        A["dtout"].copy_to_host(dv.pinned_dt)
        _count(state, "h2d_bytes", "dt", 24)
        _count(state, "d2h_bytes", "dt", 24)
        a2, v2, vm = (float(x) for x in dv.pinned_dt)
        c = state.consts
        return dt_from_terms(a2, v2, vm, c.h, c.c0, state.cfl)

    def integrate(self, state, stage: int, integrator: str, euler: bool) -> None:
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.arrays
        n, dim = dv.n, dv.dim
        ft = dv.dtype.type
        dt = ft(state.dt)
        rho0 = ft(state.consts.prm[P_RHO0])
        dv.__dict__["integrator"] = integrator
        if n:
            b = CK.blocks(n)
            if integrator == "verlet":
                k.k_verlet[b, CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"], A["rho"],
                                        A["vmx"], A["vmy"], A["vmz"], A["rhom"], A["kind"],
                                        A["ax"], A["ay"], A["az"], A["ar"], n, dim, dt, bool(euler), rho0)
            else:
                # Symplectic stage-start velocity and density reuse the Verlet history slots
                kern = k.k_sym_predict if stage == 1 else k.k_sym_correct
                kern[b, CK.BLOCK](A["px"], A["py"], A["pz"], A["vx"], A["vy"], A["vz"], A["rho"],
                                  A["vmx"], A["vmy"], A["vmz"], A["rhom"], A["kind"],
                                  A["ax"], A["ay"], A["az"], A["ar"], n, dim, dt, rho0)
            if integrator != "verlet" and stage == 1:
                # the corrector's forces see the predicted positions (build_cells refreshes
                # them for the next step); pressure: see FRESH_PRESSURE
                for d in range(dim):
                    ax = _VEC[d]
                    k.k_rel[b, CK.BLOCK](A["p" + ax], n, dv.ref[d], A["r" + ax])
                if FRESH_PRESSURE:
                    k.k_pressure[b, CK.BLOCK](A["rho"], n, dv.prm_d(state), A["press"])
        dv.host_stale = True
        self._sync()

    def check(self, state, lo, hi):
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.arrays
        n, dim = dv.n, dv.dim
        init = np.array([np.inf] * 3 + [-np.inf] * 3)
        A["chk_box"].copy_to_device(init)
        A["chk_bad"].copy_to_device(np.array([np.iinfo(np.int64).max], np.int64))
        lo3 = np.zeros(3)
        hi3 = np.zeros(3)
        lo3[:dim] = lo
        hi3[:dim] = hi
        if n:
            k.k_check_bounds[min(CK.REDUCE_BLOCKS, CK.blocks(n)), 256](
                A["px"], A["py"], A["pz"], A["rho"], A["kind"], n, dim, *lo3, *hi3,
                float(state.rho_min), float(min(state.rho_max, 1e300)), A["chk_bad"], A["chk_box"])
        box = A["chk_box"].copy_to_host()
        bad = int(A["chk_bad"].copy_to_host()[0])
        _count(state, "h2d_bytes", "check", 56)
        _count(state, "d2h_bytes", "check", 56)
        if n:
            dv.box = np.array([box[:3], box[3:]])
            dv.box[:, dim:] = 0.0
        if bad == np.iinfo(np.int64).max:
            return None
        dv.host_stale = True
        self.sync_host(state)
        return bad // 4, bad % 4

    # -- benchmarks --------------------------------------------------------------------
    def count_pairs(self, state) -> int:
        """Interior pairs within 2h counted on the device (plus halos on the host)."""
        if any(h is not None and h.n for h in state.halos.values()):
            return super().count_pairs(state)
        dv = state.extra["dev"]
        k = self._k(state)
        A = dv.arrays
        n = dv.n
        if not n:
            return 0
        g = dv.grid
        counts = cuda.device_array(n, np.int32)
        sup2 = dv.dtype.type(state.prm[P_SUPPORT2])
        k.k_count_pairs[CK.blocks(n, CK.FORCE_BLOCK), CK.FORCE_BLOCK](
            A["px"], A["py"], A["pz"], A["rx"], A["ry"], A["rz"], n, A["rx"], A["ry"], A["rz"],
            A["start"], *(float(x) for x in g["origin"]), float(g["inv"]), *(int(x) for x in g["dims"]),
            *(int(x) for x in g["axes"]), int(g["reach"]), sup2, dv.dim, counts)
        return int(counts.copy_to_host().astype(np.int64).sum())

    def state_bytes(self, state) -> int:
        dv = state.extra.get("dev")
        return 0 if dv is None else dv.nbytes()


def _prm_d(self, state):
    d = self.arrays.get("prm")
    if d is None:
        d = self.arrays["prm"] = cuda.to_device(np.ascontiguousarray(state.prm, self.dtype))
    return d


DeviceState.prm_d = _prm_d
