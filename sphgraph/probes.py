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
  (half-full kernel), searched in steps of dp/4 from 2h below the lowest fluid particle
  within 2h of the line (horizontally) to 2h above the highest.
* body force: what the fluid's pressure exerts on the body's boundary particles,
  F = sum_{b in body} sum_{a fluid} m_a m_b (P_a + P_b)/(rho_a rho_b) (-grad_a W_ab),
  i.e. minus the pressure force the body puts on the fluid (artificial viscosity left out).

How: every one of these is a sum over fluid particles, and the ranks own disjoint sets of
them. Each rank sums over its own rows where they live (`ComputeBackend.probe_bounds` /
`probe_sums`: the cell grids of the rank, on the device for numba-cuda; the per-row maths
in `sphgraph.physics.probes`), only those sums cross to the host and to the root, which
adds them in rank order and divides (a point's value is a ratio of sums). The ``probes``
task (`sample_step`, a collective at the end of each step) samples what is due;
`sample(sim)` samples outside a step (`sphgraph.run`: the initial state). The series are
written with `OutputWriter.write_group` at the end.
"""
from __future__ import annotations

import json
import math

import numpy as np

from .config import K_WENDLAND, KERNELS, P_AW, P_BW
from .errors import InputError

__all__ = ["ProbeSampler", "parse", "kernel_w", "grad_factor", "EDGE_BAND_H"]

# A body's rows near a rank's edge that other ranks' fluid reaches, in units of h. A body row
# b of rank q within 2h of a fluid row a of rank r != q: the rows were split by the slab cuts
# at their last migration (this step's send_displaced) and have moved by some d since (a
# step's flow and shifting: far below h), so b lies within 2h + 2d of the end of q's rows'
# extent along the split axis that faces r. 3h holds for d up to h/2. The rows' extent, not
# the cuts: a rebalance in this step moved the cuts, and the rows follow only next step.
EDGE_BAND_H = 3.0


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
        self.mass_f, self.mass_b = k.mass_fluid, k.mass_bound
        self.dim = scene.dim
        self.dp = scene.dp
        self.zlo, self.zhi = float(scene.domain_min[-1]), float(scene.domain_max[-1])
        self.rows = {"probes": [], "forces": []}
        self.next = {"probes": 0.0, "forces": 0.0}
        self._last_time = {"probes": None, "forces": None}
        self.shared = True   # every rank's `probes` task uses this one sampler (one process)
        s = self.spec
        # what the backends take (sphgraph.physics.probes): points and columns as (x, y, z) /
        # (x, y) with zeros beyond the scene's axes; a body's rows are those within 1e-6 dp
        # (and 1e-9 m) of its box, inclusive
        self._points = np.zeros((len(s["points"]), 3))
        for i, (_name, x) in enumerate(s["points"]):
            self._points[i, :self.dim] = x
        self._columns = np.zeros((len(s["heights"]), 2))
        for i, (_name, x) in enumerate(s["heights"]):
            self._columns[i, :self.dim - 1] = x
        tol = 1e-9 + 1e-6 * self.dp
        self._boxes = np.zeros((len(s["bodies"]), 2, 3))
        for i, (_name, lo, hi) in enumerate(s["bodies"]):
            self._boxes[i, 0, :self.dim] = np.asarray(lo, np.float64) - tol
            self._boxes[i, 1, :self.dim] = np.asarray(hi, np.float64) + tol

    @property
    def active(self) -> bool:
        s = self.spec
        return bool(s["points"] or s["heights"] or s["bodies"])

    def due(self, t: float) -> bool:
        s = self.spec
        return ((bool(s["points"] or s["heights"]) and t >= self.next["probes"] - 1e-12)
                or (bool(s["bodies"]) and t >= self.next["forces"] - 1e-12))

    def sample(self, sim) -> None:
        """Sample what is due at `sim.time` outside a step (`sphgraph.run`: the initial
        state), every rank of this process at once; under MPI every process calls it."""
        if not self.due(sim.time):
            return
        comm = sim.comm

        def gather(mine):
            parts = comm.gather(mine)
            return None if parts is None else [x for p in parts for x in p]

        local = [(c.rank, c.state, c.compute) for c in sorted(sim.contexts, key=lambda c: c.rank)]
        self._sample(sim.time, sim.step_count, local, lambda mine: comm.bcast(gather(mine)), gather)

    def sample_step(self, ctx) -> None:
        """The ``probes`` task of one rank, at the end of a step (a collective): when a
        sample is due at the step's end time, the rank's partial sums
        (`ComputeBackend.probe_bounds` / `probe_sums`) go to the root (rank 0), which adds
        them and samples. Every rank decides from the same time and marks before any rank
        joins a collective, and only the root's task changes a shared sampler."""
        st = ctx.state
        t = st.time + st.dt   # as the solver counts it once the step ends
        if not self.due(t):
            return
        ep = ctx.comm

        def gather(mine):
            parts = ep.gather(mine)
            return None if parts is None else [x for p in parts for x in p]

        self._sample(t, st.step + 1, [(ctx.rank, st, ctx.compute)],
                     lambda mine: [x for p in ep.allgather(mine) for x in p], gather)

    def _sample(self, t, step, local, allgather, gather) -> None:
        """One sample at time `t` from the ranks `local` [(rank, state, compute)] of this
        process; `allgather(list)` / `gather(list)`: every rank's items in rank order on every
        rank / on the root (None elsewhere), through the comm's collectives.

        Each rank sums over the fluid rows it owns (a point's Shepard sums, a height
        column's kernel sums, the pressure force on a body's rows), so the sample is the sum
        of the ranks' parts, which the root adds in rank order. Two things need a first
        exchange: a height column searches from the lowest to the highest fluid row near it
        (every rank's extremes), and a body's rows near a rank's edge meet fluid rows of the
        next rank (each rank sends its body rows within EDGE_BAND_H h of its rows' extent
        along the split axis: see there why that is all of them)."""
        s = self.spec
        probes = bool(s["points"] or s["heights"]) and t >= self.next["probes"] - 1e-12
        forces = bool(s["bodies"]) and t >= self.next["forces"] - 1e-12
        nranks = local[0][1].nranks
        points = self._points if probes else self._points[:0]
        columns = self._columns if probes else self._columns[:0]
        boxes = self._boxes if forces else self._boxes[:0]
        band = EDGE_BAND_H * self.h if forces and nranks > 1 else 0.0
        every = None
        if len(columns) or band > 0:
            every = allgather([cp.probe_bounds(st, columns, boxes, band) for _, st, cp in local])
        grids = [self._column_grid(c, every) for c in range(len(columns))]
        pts = np.concatenate([points] + [self._column_points(c, zs) for c, zs in enumerate(grids)])
        sums = []
        for r, st, cp in local:
            extra = np.zeros((0, 5))
            if band > 0:
                extra = np.concatenate([extra] + [e["edge"] for q, e in enumerate(every) if q != r])
            sums.append(cp.probe_sums(st, pts, boxes, extra))
        parts = gather(sums)
        if parts is None:   # not the root
            if not self.shared:   # MPI: each process keeps its own marks in step with the root's
                self._advance_marks(t)
            return
        S = parts[0]["points"].copy()
        F = parts[0]["forces"].copy()
        for p in parts[1:]:
            S += p["points"]
            F += p["forces"]
        dim = self.dim
        if probes:
            row = {"time": t, "step": step}
            for i, (name, _x) in enumerate(s["points"]):
                sw = S[i, 0]
                if sw < 0.1:   # no fluid within reach: dry
                    row[name] = {"pressure": 0.0, "velocity": np.zeros(dim), "kernel_sum": sw}
                else:
                    row[name] = {"pressure": float(S[i, 1] / sw), "velocity": S[i, 2:2 + dim] / sw,
                                 "kernel_sum": sw}
            k = len(points)
            for (name, _x), zs in zip(s["heights"], grids):
                sw = S[k:k + len(zs), 0]
                k += len(zs)
                full = np.nonzero(sw >= 0.5)[0]
                row[name] = float(zs[full[-1]]) if len(full) else float(self.zlo)
            self.rows["probes"].append(row)
        if forces:
            row = {"time": t, "step": step}
            for k, (name, _lo, _hi) in enumerate(s["bodies"]):
                row[name] = F[k, :dim].copy()
            self.rows["forces"].append(row)
        self._advance_marks(t)

    def _column_grid(self, c, every) -> np.ndarray:
        """The heights searched over column c: from 2h below its lowest fluid row to 2h above
        its highest (within the domain), every dp/4; none without fluid near it."""
        zmin = min(float(e["zrange"][c, 0]) for e in every)
        zmax = max(float(e["zrange"][c, 1]) for e in every)
        if not zmin <= zmax:
            return np.zeros(0)
        return np.arange(max(self.zlo, zmin - 2 * self.h), min(self.zhi, zmax + 2 * self.h), 0.25 * self.dp)

    def _column_points(self, c, zs) -> np.ndarray:
        """The points (x, y, z) of column c at heights zs."""
        out = np.zeros((len(zs), 3))
        out[:, :self.dim - 1] = self._columns[c, :self.dim - 1]
        out[:, self.dim - 1] = zs
        return out

    def _advance_marks(self, t) -> None:
        s = self.spec
        if (s["points"] or s["heights"]) and t >= self.next["probes"] - 1e-12:
            self.next["probes"] = self._advance(self.next["probes"], s["interval"], t)
        if s["bodies"] and t >= self.next["forces"] - 1e-12:
            self.next["forces"] = self._advance(self.next["forces"], s["force_interval"], t)

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
