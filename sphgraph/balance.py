"""Dynamic load balancing: new slab cuts from the ranks' particles or measured times.

The seed paper (§III-C) checks every 50 steps and applies new cuts only when
they reduce the imbalance by more than 3 % (here: percentage points of
max_r |N_r - mean| / mean of the balanced quantity). Policies:

  particles  equal fluid particles per rank, halo particles included
  time       shares proportional to each rank's measured speed: fluid particles it
             processed (halos included) per second of force computation over the
             last window, exponentially averaged over the checks (`smoothing` = the
             newest window's weight, default 0.5: weights 0.5, 0.25, 0.125...), so
             ranks of different speed finish together
  memory     the shares of `base` (particles or time) capped by each rank's
             fluid-particle capacity, asked of the compute backend at every check
             (`ComputeBackend.particle_capacity`: the `max_particles_per_rank` option
             on CPU and mock; free device memory / measured bytes per particle on
             GPU, see `backends.compute.base.device_capacity`); a scene that cannot fit is an InputError

Cuts are coordinates along the split axis, found on a global histogram of the
fluid positions with bins much finer than dp (particle granularity up to ties
of lattice columns). Every slab stays >= 6h wide, and a cut moves at most into
its neighbours' old slabs, so applying it only moves rows between neighbours
(the next step's send_displaced / recv_displaced carry them).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .domain import MIN_SLAB_H
from .errors import InputError
from .ranges import expected

POLICIES = ("particles", "time", "memory")
CAP_SLACK = 0.01     # memory: plan loads this fraction under the caps (see Balancer._within_caps)
BASES = ("particles", "time")


# key -> (valid?, expected form) of the keys that hold no number; the numbers' forms and
# ranges are rows ``balance.KEY`` of sphgraph.ranges. The scene's [balance] table, the
# schedule's [rebalance] table (its every/threshold/policy) and the command-line flags share these
KEYS = {
    "enabled": (lambda v: isinstance(v, bool), "true or false"),
    "every": None,
    "threshold": None,
    "policy": (lambda v: isinstance(v, str) and v in POLICIES, f"one of {', '.join(POLICIES)}"),
    "base": (lambda v: isinstance(v, str) and v in BASES, f"one of {', '.join(BASES)}"),
    "max_particles_per_rank": None,
    "smoothing": None,
}
# numbers: key -> keyword arguments of sphgraph.ranges.expected
_NUMBERS = {"every": {"integer": True}, "threshold": {"ge": 0.0},
            "max_particles_per_rank": {"integer": True}, "smoothing": {"gt": 0.0}}


def expected_form(key: str, value) -> str | None:
    """None when `value` is valid for `key`, else the expected form (for one-line errors)."""
    if key in _NUMBERS:
        return expected(f"balance.{key}", value, **_NUMBERS[key])
    ok, form = KEYS[key]
    return None if ok(value) else form


def check_layer(layer, where: str) -> dict:
    """One layer of the balance settings (``where``: ``FILE: balance.`` and the like): a table
    of known keys, each valid, before any arithmetic on them."""
    if not isinstance(layer, dict):
        raise InputError(f"{where.rstrip('.=')}: expected a table of {', '.join(KEYS)}, got {layer!r}")
    for k, v in layer.items():
        if k not in KEYS:
            raise InputError(f"{where}{k}: unknown key: expected one of {', '.join(KEYS)}")
        form = expected_form(k, v)
        if form is not None:
            raise InputError(f"{where}{k}: expected {form}, got {v!r}")
    return layer


@dataclass
class BalanceConfig:
    enabled: bool = True
    every: int = 50
    threshold: float = 0.03
    policy: str = "particles"
    base: str = "particles"                 # what `memory` caps
    max_particles_per_rank: int | None = None
    smoothing: float = 0.5                  # weight of the newest window's speeds in their exponential average

    @classmethod
    def resolve(cls, schedule: dict, scene: dict, flags: dict, source="scene",
                schedule_source="schedule") -> "BalanceConfig":
        """Precedence: command-line flag > scene [balance] > schedule [rebalance].

        Each layer is validated on its own, so an error names where the value came from:
        `SCHEDULE: rebalance.KEY`, `SCENE: balance.KEY`, or `balance=` (the Python API's
        dict; the CLI checks its flags before, naming them)."""
        layers = ((schedule, f"{schedule_source}: rebalance."), (scene, f"{source}: balance."),
                  ({k: v for k, v in (flags or {}).items() if v is not None} if isinstance(flags, dict)
                   else flags, "balance="))
        merged = {}
        for layer, where in layers:
            if layer is None:
                continue
            check_layer(layer, where)
            merged.update(layer)
        return cls(**merged)


def imbalance(values) -> float:
    v = np.asarray(values, float)
    m = v.mean()
    return float(np.abs(v - m).max() / m) if m > 0 else 0.0


def loads(hist_edges, hist, cuts, reach, cum=None) -> np.ndarray:
    """Fluid particles each rank processes for `cuts`: its own plus its halos (within reach).
    `cum`: the histogram's running sum with a leading 0, when the caller holds it."""
    if cum is None:
        cum = np.concatenate([[0.0], np.cumsum(hist)])
    cuts = np.asarray(cuts, float)
    n = len(cuts) - 1
    # particles with coordinate < x at every point the loads need, in one interpolation
    b = np.interp(np.concatenate([cuts, cuts - reach, cuts + reach]), hist_edges, cum)
    at, below_r, above_r = b[:n + 1], b[n + 1:2 * n + 2], b[2 * n + 2:]
    halo = np.zeros(n)
    halo[1:] = at[1:n] - below_r[1:n]            # below the rank's lower cut
    halo[:-1] += above_r[1:n] - at[1:n]          # above its upper cut
    return (at[1:] - at[:-1]) + halo


def solve_cuts(hist_edges, hist, old_cuts, targets, reach, min_width, iters=60) -> np.ndarray:
    """Interior cuts giving rank r a load of `targets[r]` (same sum as the loads), kept
    >= min_width apart and each within its neighbours' old slabs."""
    n = len(old_cuts) - 1
    cum = np.concatenate([[0.0], np.cumsum(hist)])
    lo_x, hi_x = hist_edges[0], hist_edges[-1]
    cuts = old_cuts.copy()
    cuts[0], cuts[-1] = lo_x, hi_x
    inner_old = old_cuts.copy()
    inner_old[0], inner_old[-1] = lo_x, hi_x
    for _ in range(iters):
        load = loads(hist_edges, hist, cuts, reach, cum)
        # move each cut by half the excess of the heavier side, in particle-count space
        excess = (load[:-1] - targets[:-1]) - (load[1:] - targets[1:])
        c = np.interp(cuts[1:n], hist_edges, cum) - 0.5 * excess
        cuts[1:n] = np.interp(np.clip(c, 0, cum[-1]), cum, hist_edges)
        cuts = _constrain(cuts, inner_old, min_width)
    out = cuts.copy()
    out[0], out[-1] = -np.inf, np.inf
    return out


def _constrain(cuts, old, min_width):
    n = len(cuts) - 1
    for r in range(1, n):
        cuts[r] = min(max(cuts[r], old[r - 1] + 1e-12), old[r + 1] - 1e-12)  # migrate to neighbours only
    for r in range(1, n):
        cuts[r] = max(cuts[r], cuts[r - 1] + min_width)
    for r in range(n - 1, 0, -1):
        cuts[r] = min(cuts[r], cuts[r + 1] - min_width)
    return cuts


def target_loads(cfg: BalanceConfig, total: float, speed, caps) -> np.ndarray:
    """Load per rank: equal, or proportional to speed; then capped (water-filling)."""
    n = len(speed)
    use_speed = cfg.policy == "time" or (cfg.policy == "memory" and cfg.base == "time")
    share = np.asarray(speed, float) if use_speed else np.ones(n)
    share = share / share.sum()
    if cfg.policy != "memory":
        return total * share
    caps = np.asarray(caps, float)
    if caps.sum() < total:
        raise InputError(f"balance: memory: the scene cannot fit: it needs {int(total)} fluid particles "
                         f"(halos included) on {n} ranks, their capacities sum to {int(caps.sum())} (per rank "
                         f"{', '.join(str(int(c)) for c in caps)}: max_particles_per_rank, or free device "
                         f"memory on GPU): use more ranks or raise max_particles_per_rank")
    t = np.zeros(n)
    free = np.ones(n, bool)
    left = total
    for _ in range(n):
        t[free] = left * share[free] / share[free].sum()
        over = free & (t > caps)
        if not over.any():
            break
        t[over] = caps[over]
        free &= ~over
        left = total - t[~free].sum()
    return t


@dataclass
class Balancer:
    """Runs inside the collective `rebalance` task of every rank (same inputs → same cuts)."""

    cfg: BalanceConfig
    axis: int
    h: float
    dp: float
    # rank state -> its fluid-particle capacity (memory policy), or None = unbounded; set by
    # Simulation from ComputeBackend.particle_capacity. Unset: max_particles_per_rank.
    capacity: Callable | None = None
    records: dict = field(default_factory=lambda: {"step": [], "applied": [], "fluid_count": [],
                                                   "force_seconds": [], "imbalance_before": [],
                                                   "imbalance_after": []})
    check_s: float = 0.0        # wall seconds in the rebalance task up to the decision (host sync included)
    apply_s: float = 0.0        # wall seconds setting the new cuts (rows move in the next step)
    move_s: float = 0.0         # seconds of the send/recv_displaced tasks that carried them (/timing clock)
    move_step: int = -1         # the step whose displaced tasks carry the rows of the last application
    speed: np.ndarray | None = None   # relative speeds (sum 1), exponentially averaged over the checks
    force_s: dict = field(default_factory=dict)   # rank -> force seconds since the last check
    steps_since: dict = field(default_factory=dict)

    def note_force_time(self, rank, seconds):
        self.force_s[rank] = self.force_s.get(rank, 0.0) + seconds

    def due(self, step: int) -> bool:
        return (step + 1) % self.cfg.every == 0

    def step(self, ctx) -> None:
        st = ctx.state
        t0 = time.perf_counter()
        dom = ctx.domain
        be = ctx.compute
        n_own = be.fluid_count(st)
        n_halo = sum(int(h.n_fluid) for h in st.halos.values() if h is not None)
        steps = max(self.steps_since.get(ctx.rank, self.cfg.every), 1)
        fsec = self.force_s.pop(ctx.rank, 0.0) / steps
        self.steps_since[ctx.rank] = self.cfg.every
        lo, hi = be.axis_extent(st, self.axis)   # the slabs span all particles, fluid or not
        cap = None
        if self.cfg.policy == "memory":
            cap = self.capacity(st) if self.capacity is not None else self.cfg.max_particles_per_rank
        info = ctx.comm.allgather((n_own, n_halo, fsec, lo, hi, cap))
        counts = np.array([i[0] + i[1] for i in info], float)
        fsecs = np.array([i[2] for i in info])
        caps = np.array([np.inf if i[5] is None else float(i[5]) for i in info])
        gl, gh = min(i[3] for i in info), max(i[4] for i in info)
        bins = max(int((gh - gl) / (self.dp / 16)) + 1, 1)
        edges = np.linspace(gl, gh + 1e-9, bins + 1)
        hist = be.fluid_histogram(st, self.axis, edges)
        hist = np.sum(ctx.comm.allgather(hist), axis=0).astype(float)
        reach = dom.reach
        if fsecs.min() > 0:   # every rank measured: fold this window's speeds into the average
            speed = counts / fsecs
            speed = speed / speed.sum()
            if self.speed is None or len(self.speed) != len(speed):
                self.speed = speed
            else:
                a = self.cfg.smoothing
                old = np.asarray(self.speed, float)
                self.speed = a * speed + (1 - a) * old / old.sum()
        speeds = self.speed if self.speed is not None else np.ones(len(counts))
        cur = loads(edges, hist, dom.cuts, reach)
        total = cur.sum()
        targets = target_loads(self.cfg, total, speeds, caps)
        cuts = solve_cuts(edges, hist, dom.cuts, targets, reach, MIN_SLAB_H * self.h)
        new = loads(edges, hist, cuts, reach)
        if self.cfg.policy == "memory":
            targets, cuts, new = self._within_caps(edges, hist, dom.cuts, reach, total, speeds, caps, cuts, new)
        # the balanced quantity: load relative to target (1 = on target)
        before = imbalance_vs(cur, targets)
        after = imbalance_vs(new, targets)
        over_cap = self.cfg.policy == "memory" and bool(np.any(cur > caps + 0.5))
        apply = (before - after) > self.cfg.threshold or over_cap
        t1 = time.perf_counter()
        if apply:
            dom.cuts = cuts
            st.cut_lo, st.cut_hi = cuts[ctx.rank], cuts[ctx.rank + 1]
            self.move_step = st.step + 1
        t2 = time.perf_counter()
        self.check_s += t1 - t0
        self.apply_s += t2 - t1
        if ctx.rank == 0:  # every rank holds the same data; rank 0 keeps the records
            rec = self.records
            rec["step"].append(st.step)
            rec["applied"].append(bool(apply))
            rec["fluid_count"].append(counts.astype(np.int64))
            rec["force_seconds"].append(fsecs)
            rec["imbalance_before"].append(before)
            rec["imbalance_after"].append(after if apply else before)
            if self.cfg.policy == "memory":
                rec.setdefault("capacity", []).append(caps)

    def _within_caps(self, edges, hist, old_cuts, reach, total, speeds, caps, cuts, new):
        """memory: lower the capped ranks' targets until the planned loads keep CAP_SLACK
        under their caps. Cuts have particle granularity (a lattice column is one step), the
        halos shift the sum, and the halos counted at the next check differ from this
        histogram's by a few particles, so a target of exactly the cap ends above it."""
        goal = np.floor(caps * (1 - CAP_SLACK))
        if goal.sum() < total:     # no room for the slack: aim at the caps themselves
            goal = caps
        eff = goal.copy()
        targets = target_loads(self.cfg, total, speeds, caps)
        for _ in range(6):
            over = new - goal
            if not np.any(over > 0):
                break
            eff = np.where(over > 0, eff - over, eff)
            if eff.sum() < total:
                break
            targets = target_loads(self.cfg, total, speeds, eff)
            cuts = solve_cuts(edges, hist, old_cuts, targets, reach, MIN_SLAB_H * self.h)
            new = loads(edges, hist, cuts, reach)
        return targets, cuts, new

    def datasets(self) -> dict:
        r = self.records
        if not r["step"]:
            return {}
        return {"step": np.array(r["step"], np.int64), "applied": np.array(r["applied"], bool),
                "fluid_count": np.array(r["fluid_count"], np.int64),
                "force_seconds": np.array(r["force_seconds"], float),
                "imbalance_before": np.array(r["imbalance_before"]),
                "imbalance_after": np.array(r["imbalance_after"]),
                **({"capacity": np.array(r["capacity"], float)}
                   if len(r.get("capacity", ())) == len(r["step"]) else {})}


def imbalance_vs(loads_, targets) -> float:
    """max_r |N_r - T_r| / mean(T): 0 when every rank is on its target."""
    t = np.asarray(targets, float)
    return float(np.abs(np.asarray(loads_) - t).max() / t.mean())
