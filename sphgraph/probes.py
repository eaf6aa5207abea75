"""Probes and body forces sampled while a run steps (`/probes`, `/forces`; DESIGN.md §5).

A scene asks for them with two tables (kept raw in `Scene.extra`, validated here)::

    [probes]
    interval = 0.001                                   # s between samples; 0 (default) = every step
    points = [{name = "P1", position = [3.22, 0.12]}]  # pressure and velocity at a point
    heights = [{name = "H1", position = [1.0]}]        # free-surface height over a horizontal point

    [forces]
    interval = 0.001
    bodies = [{name = "tank", min = [-1, -1], max = [2, 2]}]   # boundary particles inside the box

What is measured (DualSPHysics MeasureTool / ComputeForces conventions):

* point value: Shepard-normalised kernel interpolation of the fluid particles within 2h,
  f(x) = sum_b f_b V_b W(x - x_b) / sum_b V_b W(x - x_b), V_b = m_b / rho_b; a point with
  no fluid within reach (sum V W < 0.1) reads pressure 0 and velocity 0 (dry).
* height: the highest z on the vertical line over the point where sum_b V_b W >= 0.5
  (half-full kernel), searched in steps of dp/4.
* body force: what the fluid's pressure exerts on the body's boundary particles,
  F = sum_{b in body} sum_{a fluid} m_a m_b (P_a + P_b)/(rho_a rho_b) (-grad_a W_ab),
  i.e. minus the pressure force the body puts on the fluid (artificial viscosity left out);
  summed over a cell grid of the fluid near the body (`sphgraph.probe_kernels`).

`ProbeSampler.sample(sim)` takes the gathered particles (`Simulation.frame_arrays`, so any
rank count works): `sphgraph.run` samples the initial state so; after each step the
``probes`` task (`sample_step`, end of the step) gathers the rows on the root and samples
those that are due. The series are written with `OutputWriter.write_group` at the end.
"""
from __future__ import annotations

import json
import math

import numpy as np

from .config import K_WENDLAND, KERNELS, P_AW, P_BW
from .errors import InputError
from .particles import in_id_order

__all__ = ["ProbeSampler", "parse", "kernel_w", "grad_factor"]


# --------------------------------------------------------------------------- kernels (numpy)
def kernel_w(r, h, aw, kernel="wendland"):
    q = np.asarray(r) / h
    if KERNELS.index(kernel) == K_WENDLAND:
        w = np.clip(1.0 - 0.5 * q, 0.0, None)
        return aw * w ** 4 * (2.0 * q + 1.0)
    out = np.where(q < 1.0, aw * (1.0 - 1.5 * q * q + 0.75 * q ** 3), 0.25 * aw * np.clip(2.0 - q, 0, None) ** 3)
    return np.where(q < 2.0, out, 0.0)


def grad_factor(r, h, bw, kernel="wendland"):
    """F with grad_a W_ab = F (r_a - r_b) (see sphgraph.physics.kernels)."""
    q = np.asarray(r) / h
    if KERNELS.index(kernel) == K_WENDLAND:
        w = np.clip(1.0 - 0.5 * q, 0.0, None)
        return bw / h * w ** 3
    qs = np.maximum(q, 1e-12)
    f = np.where(q < 1.0, bw / h * (-3.0 + 2.25 * q), bw / h * (-0.75 * np.clip(2.0 - q, 0, None) ** 2) / qs)
    return np.where(q < 2.0, f, 0.0)


# --------------------------------------------------------------------------- scene tables
TABLE_KEYS = {"probes": ("interval", "points", "heights"), "forces": ("interval", "bodies")}
ITEM_KEYS = {"probes.points": ("position",), "probes.heights": ("position",), "forces.bodies": ("min", "max")}


def _named(c, key, items, fields):
    if not isinstance(items, list) or not all(isinstance(e, dict) for e in items):
        raise c.error(key, "a list of tables", items)
    names = set()
    for i, e in enumerate(items):
        extra = set(e) - set(fields) - {"name"}
        if extra:
            raise c.error(f"{key}[{i}]", f"keys name, {', '.join(fields)}", sorted(extra))
        name = e.get("name", f"{key.split('.')[-1]}{i}")
        if not isinstance(name, str) or not name or "/" in name or name in ("time", "step", "attrs") or name in names:
            raise c.error(f"{key}[{i}].name", "a unique name without '/'", name)
        names.add(name)
    return items


def check(c, extra: dict, dim: int) -> dict:
    """The [probes] / [forces] tables of a scene (``extra``: the raw tables), checked with the
    scene's checker ``c`` -- every number a number in its range (sphgraph.ranges) -- into
    {'interval', 'points', 'heights', 'bodies', 'force_interval'}; empty lists when the scene
    asks for nothing."""
    out = {"interval": 0.0, "points": [], "heights": [], "bodies": [], "force_interval": 0.0}
    for table, allowed in TABLE_KEYS.items():
        t = extra.get(table)
        if t is None:
            continue
        if not isinstance(t, dict):
            raise c.error(table, "a table", t)
        bad = set(t) - set(allowed)
        if bad:
            raise c.error(table, f"keys {', '.join(allowed)}", sorted(bad))
        iv = c.number(f"{table}.interval", t.get("interval", 0.0), ge=0)
        if table == "probes":
            out["interval"] = iv
            for i, e in enumerate(_named(c, "probes.points", t.get("points", []), ITEM_KEYS["probes.points"])):
                out["points"].append((e.get("name", f"points{i}"),
                                      c.vector(f"probes.points[{i}].position", e.get("position"), dim)))
            for i, e in enumerate(_named(c, "probes.heights", t.get("heights", []), ITEM_KEYS["probes.heights"])):
                out["heights"].append((e.get("name", f"heights{i}"),
                                       c.vector(f"probes.heights[{i}].position", e.get("position"), dim - 1)))
        else:
            out["force_interval"] = iv
            for i, e in enumerate(_named(c, "forces.bodies", t.get("bodies", []), ITEM_KEYS["forces.bodies"])):
                lo = c.vector(f"forces.bodies[{i}].min", e.get("min"), dim)
                hi = c.vector(f"forces.bodies[{i}].max", e.get("max"), dim)
                if not np.all(hi >= lo):
                    raise c.error(f"forces.bodies[{i}].max", "every coordinate >= min", e.get("max"))
                out["bodies"].append((e.get("name", f"bodies{i}"), lo, hi))
    return out


def parse(scene) -> dict:
    """Validated [probes] / [forces] of a scene (:func:`check`; the scene checked them when
    it was read, so this finds nothing new)."""
    from .scene_schema import _Checker
    return check(_Checker(scene.source), scene.extra, scene.dim)


# --------------------------------------------------------------------------- sampling
class ProbeSampler:
    """Samples a scene's probes and body forces; `datasets()` gives the /probes and /forces trees."""

    def __init__(self, scene, spec: dict | None = None):
        self.spec = spec if spec is not None else parse(scene)
        k = scene.constants
        self.kernel = scene.physics.kernel
        self.h, self.aw, self.bw = k.h, float(k.prm[P_AW]), float(k.prm[P_BW])
        self.prm = np.asarray(k.prm, np.float64)
        self.mass_f, self.mass_b = k.mass_fluid, k.mass_bound
        self.dim = scene.dim
        self.dp = scene.dp
        self.zlo, self.zhi = float(scene.domain_min[-1]), float(scene.domain_max[-1])
        self.rows = {"probes": [], "forces": []}
        self.next = {"probes": 0.0, "forces": 0.0}
        self._last_time = {"probes": None, "forces": None}
        self.shared = True   # every rank's `probes` task uses this one sampler (one process)

    @property
    def active(self) -> bool:
        s = self.spec
        return bool(s["points"] or s["heights"] or s["bodies"])

    def due(self, t: float) -> bool:
        s = self.spec
        return ((bool(s["points"] or s["heights"]) and t >= self.next["probes"] - 1e-12)
                or (bool(s["bodies"]) and t >= self.next["forces"] - 1e-12))

    def sample(self, sim, arrays=None) -> None:
        """Sample what is due at `sim.time` (arrays: `sim.frame_arrays()` when not given)."""
        if not self.due(sim.time):
            return
        if arrays is None:
            arrays = sim.frame_arrays()
        if arrays is None:   # not the root rank under MPI: its marks advance as the root's do,
            self._advance_marks(sim.time)   # so every rank joins the same gathers
            return
        self.sample_arrays(sim.time, sim.step_count, arrays)

    def sample_step(self, ctx) -> None:
        """The ``probes`` task of one rank, at the end of a step (a collective): when a
        sample is due at the step's end time, every rank's rows go to the root (rank 0),
        which samples them in id order, as `Simulation.frame_arrays` gives them. Every
        rank decides from the same time and marks before any rank joins the gather, and
        only the root's task changes a shared sampler."""
        st = ctx.state
        t = st.time + st.dt   # as the solver counts it once the step ends
        if not self.due(t):
            return
        rows = ctx.comm.gather(ctx.compute.host_arrays(st))
        if ctx.rank != 0:
            if not self.shared:   # MPI: each process keeps its own marks in step with the root's
                self._advance_marks(t)
            return
        self.sample_arrays(t, st.step + 1, in_id_order(rows))

    def _advance_marks(self, t) -> None:
        s = self.spec
        if (s["points"] or s["heights"]) and t >= self.next["probes"] - 1e-12:
            self.next["probes"] = self._advance(self.next["probes"], s["interval"], t)
        if s["bodies"] and t >= self.next["forces"] - 1e-12:
            self.next["forces"] = self._advance(self.next["forces"], s["force_interval"], t)

    def sample_arrays(self, t, step, a) -> None:
        s = self.spec
        fl = a["kind"] == 0
        pos, vel, rho, p = a["position"][fl], a["velocity"][fl], a["density"][fl], a["pressure"][fl]
        if (s["points"] or s["heights"]) and t >= self.next["probes"] - 1e-12:
            row = {"time": t, "step": step}
            for name, x in s["points"]:
                row[name] = self.point(x, pos, vel, rho, p)
            for name, x in s["heights"]:
                row[name] = self.height(x, pos, rho)
            self.rows["probes"].append(row)
        if s["bodies"] and t >= self.next["forces"] - 1e-12:
            row = {"time": t, "step": step}
            bd = ~fl
            for name, lo, hi in s["bodies"]:
                row[name] = self.force(lo, hi, a["position"][bd], a["density"][bd], a["pressure"][bd],
                                       pos, rho, p)
            self.rows["forces"].append(row)
        self._advance_marks(t)

    @staticmethod
    def _advance(nxt, interval, t):
        """The first mark nxt + k interval after t. Many marks passed in one step (an interval
        far below dt, down to 5e-324) are skipped at once: a loop over them would not end."""
        if interval <= 0:
            return t + 1e-300
        k = (t + 1e-12 - nxt) / interval
        if k > 64:
            nxt = nxt + (math.floor(k) - 1) * interval if math.isfinite(k) else t + 1e-12
        while nxt <= t + 1e-12:
            if nxt + interval == nxt:   # below the time's resolution: every step
                return math.nextafter(t + 1e-12, math.inf)
            nxt += interval
        return nxt

    # -- measurements
    def _near(self, x, pos):
        d = pos - x
        r = np.sqrt((d * d).sum(1))
        m = r < 2.0 * self.h
        return m, r[m]

    def point(self, x, pos, vel, rho, p):
        m, r = self._near(x, pos)
        w = kernel_w(r, self.h, self.aw, self.kernel) * self.mass_f / rho[m]
        sw = w.sum()
        if sw < 0.1:
            return {"pressure": 0.0, "velocity": np.zeros(self.dim), "kernel_sum": sw}
        return {"pressure": float((p[m] * w).sum() / sw), "velocity": (vel[m] * w[:, None]).sum(0) / sw,
                "kernel_sum": sw}

    def height(self, xh, pos, rho):
        hor = pos[:, :-1]
        m = np.all(np.abs(hor - xh) < 2.0 * self.h, axis=1)
        if not m.any():
            return float(self.zlo)
        sub, vol = pos[m], self.mass_f / rho[m]
        zs = np.arange(max(self.zlo, sub[:, -1].min() - 2 * self.h), min(self.zhi, sub[:, -1].max() + 2 * self.h),
                       0.25 * self.dp)
        pts = np.concatenate([np.broadcast_to(xh, (len(zs), self.dim - 1)), zs[:, None]], axis=1)
        d = pts[:, None, :] - sub[None, :, :]
        r = np.sqrt((d * d).sum(-1))
        sw = (kernel_w(r, self.h, self.aw, self.kernel) * vol[None, :]).sum(1)
        full = np.nonzero(sw >= 0.5)[0]
        return float(zs[full[-1]]) if len(full) else float(self.zlo)

    def force(self, lo, hi, bpos, brho, bp, fpos, frho, fp):
        tol = 1e-9 + 1e-6 * self.dp
        inb = np.all((bpos >= lo - tol) & (bpos <= hi + tol), axis=1)
        F = np.zeros(self.dim)
        if not inb.any():
            return F
        bpos, brho, bp = bpos[inb], brho[inb], bp[inb]
        reach = 2.0 * self.h
        nearf = np.all((fpos >= bpos.min(0) - reach) & (fpos <= bpos.max(0) + reach), axis=1)
        fpos, frho, fp = fpos[nearf], frho[nearf], fp[nearf]
        if not len(fpos):
            return F
        # the fluid near the body in a cell grid of 2h cells: each body particle visits the
        # cells within reach (O(body x neighbours), not dense body x fluid pair matrices)
        from .cells import axis_order, build_grid
        from .probe_kernels import body_force_rows
        f64 = np.float64
        fpos = np.ascontiguousarray(fpos, f64)
        grid, perm = build_grid(fpos, reach, 1, axis_order(self.dim))
        rows = np.zeros((len(bpos), self.dim))
        body_force_rows(np.ascontiguousarray(bpos, f64), np.ascontiguousarray(brho, f64),
                        np.ascontiguousarray(bp, f64), fpos[perm], np.ascontiguousarray(frho[perm], f64),
                        np.ascontiguousarray(fp[perm], f64), *grid.kernel_args(), self.prm,
                        KERNELS.index(self.kernel), float(self.mass_f), float(self.mass_b), rows)
        return rows.sum(0)

    # -- output
    def datasets(self) -> dict:
        """{'probes': tree, 'forces': tree} for `OutputWriter.write_group` (only non-empty ones)."""
        out = {}
        s = self.spec
        rows = self.rows["probes"]
        if rows:
            tree = {"time": np.array([r["time"] for r in rows]), "step": np.array([r["step"] for r in rows])}
            attrs = {"interval": s["interval"], "method": "Shepard kernel interpolation of fluid within 2h"}
            for name, x in s["points"]:
                tree[name] = {"pressure": np.array([r[name]["pressure"] for r in rows]),
                              "velocity": np.array([r[name]["velocity"] for r in rows]),
                              "position": np.asarray(x)}
            for name, x in s["heights"]:
                tree[name] = {"height": np.array([r[name] for r in rows]), "position": np.asarray(x)}
            out["probes"] = (tree, attrs)
        rows = self.rows["forces"]
        if rows:
            tree = {"time": np.array([r["time"] for r in rows]), "step": np.array([r["step"] for r in rows])}
            for name, lo, hi in s["bodies"]:
                tree[name] = {"force": np.array([r[name] for r in rows]), "min": lo, "max": hi}
            out["forces"] = (tree, {"interval": s["force_interval"],
                                    "method": "pressure force of the fluid on the body's boundary particles"})
        return out

    def series(self, name: str, field: str = "pressure"):
        """(time, values) of one probe/body, e.g. ("P1", "pressure"), ("H1", "height"), ("tank", "force")."""
        for group in ("probes", "forces"):
            rows = self.rows[group]
            if rows and name in rows[0]:
                t = np.array([r["time"] for r in rows])
                v = rows[0][name]
                if isinstance(v, dict):
                    return t, np.array([r[name][field] for r in rows])
                return t, np.array([r[name] for r in rows])
        raise KeyError(name)

    # -- checkpoint state: the samples so far and the next sampling marks, as JSON text
    #    (floats round-trip exactly through json), so a restart continues the series
    def state_json(self) -> str:
        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, (np.ndarray, list, tuple)):
                return [plain(x) for x in v]
            return v.item() if isinstance(v, np.generic) else v
        return json.dumps({"rows": plain(self.rows), "next": self.next, "last_time": self._last_time})

    def restore_json(self, text: str) -> None:
        d = json.loads(text)
        self.rows = {k: list(v) for k, v in d["rows"].items()}
        self.next = {k: float(v) for k, v in d["next"].items()}
        self._last_time = d.get("last_time", self._last_time)

    def write(self, writer) -> None:
        for group, (tree, attrs) in self.datasets().items():
            writer.write_group(group, tree, attrs=attrs)
