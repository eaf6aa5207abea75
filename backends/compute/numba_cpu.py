"""numba CPU backend: prange kernels (OpenMP-like threads), arrays in host memory."""
from __future__ import annotations

import numba
import numpy as np

from sphgraph.cells import build_grid, cell_keys, grid_takes, reach_cells
from sphgraph.config import O_DDT_DF, O_RIEMANN, P_RHO0
from sphgraph.particles import MOVING
from sphgraph.registry import register
from sphgraph.physics.riemann_jump import RJ_SUMS, renormalised
from sphgraph.state import ForceBuffers, PARTS

from . import cpu_kernels as K
from .base import SHIFT_PARTS, ComputeBackend, dt_from_terms


# Rows per thread below which a parallel region costs more than it saves: a
# prange launch is ~10-20 us idle and milliseconds on a loaded machine, which
# small ranks (mock MPI, halos) would pay many times per step.
ROWS_PER_THREAD_LIGHT = 20000   # O(N) kernels: sort, gather, integrate, reductions
ROWS_PER_THREAD_FORCES = 1000   # the pair loop: ~20-150 pairs per row


def _threads(n: int, rows_per_thread: int) -> None:
    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS, n // rows_per_thread)))


@register("compute", "numba-cpu")
class NumbaCPU(ComputeBackend):
    default_precision = "float64"
    scene_features = frozenset({"shifting", "mdbc", "mdbc-ranks", "riemann", "riemann_jump", "diffusion_time",
                                "motion"})

    def device_name(self) -> str:
        return f"cpu ({numba.config.NUMBA_NUM_THREADS} threads)"

    def prepare(self, state) -> None:
        p = state.particles
        state.press = np.empty(p.n, state.dtype)
        state.ace = np.zeros((p.n, p.dim), state.dtype)
        state.ar = np.zeros(p.n, state.dtype)
        state.visc = np.zeros(p.n, state.dtype)
        state.ddk = np.zeros(p.n if state.opt[O_DDT_DF] else 0, state.dtype)
        state.parts = {}
        state.reduced_stage = -1

    def host_arrays(self, state) -> dict:
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        p = state.particles
        press = np.empty_like(p.rho)
        K.pressure_into(p.rho, state.prm, press)
        return {"id": p.id, "kind": p.kind, "position": p.pos, "velocity": p.vel,
                "density": p.rho, "pressure": press}

    # -- cells -------------------------------------------------------------------------
    def _grid(self, state, pos, slow_span=None):
        c = state.consts
        reach = reach_cells(c.h, c.cell_size)
        return build_grid(pos, c.cell_size, reach, state.axes, slow_span)

    def build_cells(self, state) -> None:
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        p = state.particles
        # owned rows: the grid spans the slab along the split axis (the slow one), so rows
        # arriving from the neighbours after this build fall in it (merge_displaced)
        span = (state.cut_lo, state.cut_hi) if state.axes[2] == state.axis and state.nranks > 1 else None
        grid, perm = self._grid(state, p.pos, span)
        for name, arr in p.arrays().items():
            out = np.empty_like(arr)
            (K.gather_rows2 if arr.ndim == 2 else K.gather_rows)(arr, perm, out)
            setattr(p, name, out)
        state.cells = grid
        state.sort_perm = perm
        if state.press is None or state.press.shape[0] != p.n:
            self.prepare(state)
        K.pressure_into(p.rho, state.prm, state.press)

    def merge_displaced(self, state, domain, rows) -> None:
        """recv_displaced after this step's build_cells: the arriving rows are merged into
        the sorted rows (`cpu_kernels.merge_sorted`), the cell offsets and pressures updated,
        giving bit for bit what appending them before build_cells gives (the sort is stable
        and a grid that takes the arrivals is the grid of the rows and arrivals together).
        An arrival outside the grid would change its origin or extent: the rows go back to
        their order before the sort, the arrivals are appended and the cells rebuilt."""
        from sphgraph.domain import Slabs
        from sphgraph.particles import Particles
        rows = [r for r in rows if r is not None and r.n]
        p = state.particles
        if rows:
            a = Particles.concat(rows)
            grid = state.cells
            ok, hi = grid_takes(grid, a.pos) if type(domain).add_rows is Slabs.add_rows else (False, None)
            if not ok:
                self._unsort(state)
                domain.add_rows(state, rows)
                self.prepare(state)
                self.build_cells(state)
                return
            _threads(p.n + a.n, ROWS_PER_THREAD_LIGHT)
            n = p.n
            keys = np.empty(a.n, np.int64)
            cell_keys(a.pos, grid.origin, 1.0 / grid.size, grid.dims, grid.axes, keys)
            perm = np.empty(n + a.n, np.int64)
            start = np.empty_like(grid.start)
            K.merge_sorted(grid.start, keys, perm, start)
            for name, arr in p.arrays().items():
                both = np.concatenate([arr, getattr(a, name)])
                out = np.empty_like(both)
                (K.gather_rows2 if both.ndim == 2 else K.gather_rows)(both, perm, out)
                setattr(p, name, out)
            grid.start, grid.hi = start, hi
            # the order relative to [rows before the sort, arrivals]
            state.sort_perm = np.where(perm < n, state.sort_perm[np.minimum(perm, n - 1)], perm)
        # as recv_displaced then build_cells leave it: buffers for N rows, pressures
        self.prepare(state)
        K.pressure_into(state.particles.rho, state.prm, state.press)

    def _unsort(self, state) -> None:
        """The rows back in their order before this step's build_cells."""
        p, perm = state.particles, state.sort_perm
        _threads(p.n, ROWS_PER_THREAD_LIGHT)
        inv = np.empty_like(perm)
        inv[perm] = np.arange(perm.shape[0])
        for name, arr in p.arrays().items():
            out = np.empty_like(arr)
            (K.gather_rows2 if arr.ndim == 2 else K.gather_rows)(arr, inv, out)
            setattr(p, name, out)

    def prepare_halo(self, state, halo) -> None:
        _threads(halo.n, ROWS_PER_THREAD_LIGHT)
        if halo.n == 0:
            halo.press = np.empty(0, state.dtype)
            halo.cells = None
            return
        grid, perm = self._grid(state, halo.pos)
        halo.pos, halo.vel = halo.pos[perm], halo.vel[perm]
        halo.rho, halo.kind = halo.rho[perm], halo.kind[perm]
        halo.press = np.empty_like(halo.rho)
        K.pressure_into(halo.rho, state.prm, halo.press)
        halo.cells = grid
        halo.order = perm

    # -- forces ------------------------------------------------------------------------
    def forces(self, state, part: str) -> None:
        p = state.particles
        buf = state.parts.get(part)
        df = bool(state.opt[O_DDT_DF])
        rj = renormalised(state.opt)
        if buf is None or buf.ar.shape[0] != p.n or (df and buf.ddk.shape[0] != p.n) or \
                (rj and buf.jm.shape[1] != p.n):
            buf = state.parts[part] = ForceBuffers.empty(p.n, p.dim, state.dtype, ddk=df, jm=rj)
        if part == "interior":
            src = (p.pos, p.vel, p.rho, state.press, p.kind)
            grid = state.cells
        else:
            halo = state.halos.get(int(part[-1]))
            if halo is None or halo.cells is None:  # empty halo: contributes nothing
                for a in (buf.ace, buf.ar, buf.ddt, buf.visc, buf.ddk, buf.jm):
                    a[...] = 0
                buf.cancel[...] = 0
                return
            src = (halo.pos, halo.vel, halo.rho, halo.press, halo.kind)
            grid = halo.cells
        _threads(p.n, ROWS_PER_THREAD_FORCES)
        args = (p.pos, p.vel, p.rho, state.press, p.kind, *src, *grid.kernel_args(),
                state.prm, state.opt, buf.ace, buf.ar, buf.ddt, buf.cancel, buf.visc)
        if df:
            K.forces_df(*args, buf.ddk)
        elif state.opt[O_RIEMANN]:
            K.forces_riemann(*args, buf.jm)       # 12 x 0 without the renormalised jump
        else:
            K.forces(*args)

    def reduce_forces(self, state, stage: int) -> None:
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        if state.reduced_stage == (state.step, stage):
            return
        names = [k for k in PARTS if k in state.parts] + sorted(k for k in state.parts if k not in PARTS)
        bufs = [state.parts[k] for k in names if state.parts[k].ar.shape[0] == state.particles.n]
        K.reduce_parts(tuple(b.ace for b in bufs), tuple(b.ar for b in bufs),
                       tuple(b.ddt for b in bufs), tuple(b.cancel for b in bufs),
                       tuple(b.visc for b in bufs), state.particles.kind,
                       state.consts.gravity.astype(state.dtype), state.ace, state.ar, state.visc,
                       tuple(self._ddk(b, state) for b in bufs), state.ddk,
                       tuple(self._jm(b, state) for b in bufs))
        state.reduced_stage = (state.step, stage)

    @staticmethod
    def _ddk(buf, state):
        """A part's K_a for the DuFort-Frankel step; a user task's buffer (ForceBuffers.empty
        without ddk) adds no diffusion, so zeros."""
        n = state.ddk.shape[0]
        if buf.ddk is None or buf.ddk.shape[0] != n:
            buf.ddk = np.zeros(n, state.dtype)
        return buf.ddk

    @staticmethod
    def _jm(buf, state):
        """A part's moments of the renormalised jump (12 x n; 12 x 0 without it); a user
        task's buffer adds none, so zeros."""
        n = state.particles.n if renormalised(state.opt) else 0
        if buf.jm is None or buf.jm.shape[1] != n:
            buf.jm = np.zeros((RJ_SUMS, n), state.dtype)
        return buf.jm

    def dt_local(self, state) -> float:
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        out = np.zeros((numba.get_num_threads(), 3))
        K.dt_terms(state.ace, state.particles.vel, state.visc, state.particles.kind, out)
        a2, v2, vm = out.max(axis=0)
        c = state.consts
        return dt_from_terms(a2, v2, vm, c.h, c.c0, state.cfl)

    def integrate(self, state, stage: int, integrator: str, euler: bool) -> None:
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        p = state.particles
        dt = state.dtype(state.dt)
        rho0 = state.dtype(state.consts.prm[P_RHO0])
        if integrator == "verlet":
            K.verlet(p.pos, p.vel, p.rho, p.vel_m1, p.rho_m1, p.kind, state.ace, state.ar, dt, euler, rho0,
                     state.ddk)
        elif stage == 1:
            if state.stage0 is None or state.stage0[0].shape != p.pos.shape:
                state.stage0 = (np.empty_like(p.pos), np.empty_like(p.vel), np.empty_like(p.rho))
            K.symplectic_predict(p.pos, p.vel, p.rho, *state.stage0, p.kind, state.ace, state.ar, dt, rho0)
            K.pressure_into(p.rho, state.prm, state.press)  # stage 2 forces see the predicted density
        else:
            K.symplectic_correct(p.pos, p.vel, p.rho, *state.stage0, p.kind, state.ace, state.ar, dt, rho0)

    # -- particle shifting (sphgraph.shifting), only called when the scene asks ------------
    def shift_part(self, state, part: str, mode: int) -> None:
        from . import cpu_shifting as S
        p = state.particles
        if part == "interior":
            src, grid = (p.pos, p.rho, p.kind), state.cells
        else:
            halo = state.halos.get(int(part[-1]))
            if halo is None or halo.cells is None:   # empty halo: contributes nothing
                return
            src, grid = (halo.pos, halo.rho, halo.kind), halo.cells
        bufs = state.extra.setdefault("shift_parts", {})
        b = bufs.get(part)
        if b is None or b[1].shape[0] != p.n:
            b = (np.zeros((p.n, p.dim), state.dtype), np.zeros(p.n, state.dtype), np.zeros(p.n, np.int8))
        _threads(p.n, ROWS_PER_THREAD_FORCES)
        spos, srho, skind = src
        S.shift_sums(p.pos, p.kind, np.ascontiguousarray(spos).reshape(-1), srho, skind, *grid.kernel_args(),
                     state.prm, state.opt, mode, *b)
        bufs[part] = b
        state.extra.setdefault("shift_done", set()).add(part)

    def shift_displacement(self, state, coefumagn, tfs, coeftfs, maxdist) -> None:
        from . import cpu_shifting as S
        p = state.particles
        bufs = state.extra.get("shift_parts", {})
        done = state.extra.pop("shift_done", set())
        parts = [bufs[k] for k in SHIFT_PARTS if k in done]
        out = np.zeros((p.n, p.dim), state.dtype)
        if parts:
            _threads(p.n, ROWS_PER_THREAD_LIGHT)
            S.shift_reduce(tuple(b[0] for b in parts), tuple(b[1] for b in parts), tuple(b[2] for b in parts),
                           p.vel, p.kind, coefumagn, tfs, coeftfs, maxdist, out)
        state.extra["shift"] = out

    def shift_apply(self, state) -> None:
        from . import cpu_shifting as S
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        S.shift_add(state.particles.pos, state.extra.pop("shift"))

    def mdbc(self, state, boxes, det_min, noslip, moving=None) -> None:
        from sphgraph.physics.mdbc import ghost_positions

        from .cpu_mdbc import mdbc_boundary
        p = state.particles
        rows = np.nonzero(p.kind != 0)[0]
        if len(rows) == 0:
            return
        ghost = ghost_positions(np.asarray(p.pos[rows], np.float64), boxes)
        mv = np.nonzero(p.kind[rows] == MOVING)[0] if moving is not None else rows[:0]
        if len(mv):     # a moving body's ghosts are carried with it (Mdbc.moving_ghosts)
            ids, carried = moving
            ghost[mv] = carried[np.searchsorted(ids, p.id[rows[mv]])]
        rho_out = np.empty(len(rows))
        vel_out = np.zeros((len(rows), p.dim))
        halos = [h for h in state.halos.values() if h is not None and h.n]
        if not halos:
            mdbc_boundary(rows, ghost, p.pos, p.vel, p.rho, p.kind, *state.cells.kernel_args(), state.prm,
                          state.opt, det_min, noslip, rho_out, vel_out)
        else:   # the ghosts near a cut reach into the halos: the owned and halo rows binned as one set
            pos = np.concatenate([p.pos] + [h.pos for h in halos])
            grid, perm = self._grid(state, pos)
            at = np.empty_like(perm)
            at[perm] = np.arange(len(perm))
            pick = (lambda name: np.ascontiguousarray(
                np.concatenate([getattr(p, name)] + [getattr(h, name) for h in halos])[perm]))
            mdbc_boundary(at[rows], ghost, pos[perm], pick("vel"), pick("rho"), pick("kind"), *grid.kernel_args(),
                          state.prm, state.opt, det_min, noslip, rho_out, vel_out)
        vel_out[mv] = p.vel[rows[mv]]      # a moving body's rows keep the body's velocity
        p.rho[rows] = rho_out
        p.vel[rows] = vel_out
        K.pressure_into(p.rho, state.prm, state.press)

    def mdbc_edge(self, state, domain, direction: int):
        p = state.particles
        sel = domain.edge_sources(state, direction)
        b = sel[p.kind[sel] != 0]
        out = np.empty((len(b), 1 + p.dim), p.rho.dtype)
        out[:, 0] = p.rho[b]
        out[:, 1:] = p.vel[b]
        return out

    def mdbc_halo(self, state, halo, values) -> None:
        if halo is None or halo.n == 0:
            return
        rows = np.nonzero(halo.kind != 0)[0]
        src = halo.order[rows]                  # the sender's edge rows, whose values come in edge order
        if len(rows) != len(values):
            raise ValueError(f"mDBC halo: {len(values)} boundary values for {len(rows)} boundary rows")
        k = np.searchsorted(np.sort(src), src)
        halo.rho[rows] = values[k, 0]
        halo.vel[rows] = values[k, 1:]
        K.pressure_into(halo.rho, state.prm, halo.press)

    def check(self, state, lo, hi):
        _threads(state.particles.n, ROWS_PER_THREAD_LIGHT)
        p = state.particles
        bad = np.zeros((numba.get_num_threads(), 2), np.int64)
        K.check_state(p.pos, p.rho, p.kind, lo, hi, state.rho_min, state.rho_max, bad)
        rows = bad[bad[:, 0] >= 0]
        if len(rows) == 0:
            return None
        return int(rows[0, 0]), int(rows[0, 1])
