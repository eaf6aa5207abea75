"""Dynamic load balancing: new slab cuts from the ranks' particles or measured times.

The seed paper (§III-C) checks every 50 steps and applies new cuts only when
they reduce the imbalance by more than 3 % (here: percentage points of
max_r |N_r - mean| / mean of the balanced quantity). Policies:

  particles  equal fluid particles per rank, halo particles included
  time       shares proportional to each rank's measured speed (fluid particles
             per second of force computation, exponentially weighted), so ranks
             of different speed finish together
  memory     the shares of `base` (particles or time) capped by each rank's
             particle capacity (`max_particles_per_rank`, or a GPU's free memory);
             a scene that cannot fit at all is an InputError

Cuts are coordinates along the split axis, found on a global histogram of the
fluid positions with bins much finer than dp (particle granularity up to ties
of lattice columns). Every slab stays >= 6h wide, and a cut moves at most into
its neighbours' old slabs, so applying it only moves rows between neighbours
(the next step's send_displaced / recv_displaced carry them).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .particles import FLUID

POLICIES = ("particles", "time", "memory")


@dataclass
class BalanceConfig:
    enabled: bool = True
    every: int = 50
    threshold: float = 0.03
    policy: str = "particles"
    base: str = "particles"                 # what `memory` caps
    max_particles_per_rank: int | None = None
    smoothing: float = 1.0                  # weight of the newest sample of speeds (time policy); <1 damps noise

    @classmethod
    def resolve(cls, schedule: dict, scene: dict, flags: dict, source="scene") -> "BalanceConfig":
        """Precedence: command-line flag > scene [balance] > schedule [rebalance]."""
        merged = {}
        for layer in (schedule or {}, scene or {}, {k: v for k, v in (flags or {}).items() if v is not None}):
            merged.update(layer)
        known = {"enabled", "every", "threshold", "policy", "base", "max_particles_per_rank", "smoothing"}
        for k in merged:
            if k not in known:
                raise InputError(f"{source}: balance.{k}: unknown key: expected one of {', '.join(sorted(known))}")
        c = cls(**merged)
        if c.policy not in POLICIES or c.base not in ("particles", "time"):
            raise InputError(f"{source}: balance.policy: expected one of {', '.join(POLICIES)}, got {c.policy!r}")
        if isinstance(c.every, bool) or not isinstance(c.every, int) or c.every < 1:
            raise InputError(f"{source}: balance.every: expected an integer >= 1, got {c.every!r}")
        if not isinstance(c.threshold, (int, float)) or c.threshold < 0:
            raise InputError(f"{source}: balance.threshold: expected a number >= 0, got {c.threshold!r}")
        if c.max_particles_per_rank is not None and (not isinstance(c.max_particles_per_rank, int)
                                                     or c.max_particles_per_rank < 1):
            raise InputError(f"{source}: balance.max_particles_per_rank: expected an integer >= 1, "
                             f"got {c.max_particles_per_rank!r}")
        return c


def imbalance(values) -> float:
    v = np.asarray(values, float)
    m = v.mean()
    return float(np.abs(v - m).max() / m) if m > 0 else 0.0


def loads(hist_edges, hist, cuts, reach) -> np.ndarray:
    """Fluid particles each rank processes for `cuts`: its own plus its halos (within reach)."""
    cum = np.concatenate([[0.0], np.cumsum(hist)])

    def below(x):  # particles with coordinate < x
        return np.interp(x, hist_edges, cum)
    n = len(cuts) - 1
    out = np.empty(n)
    for r in range(n):
        lo, hi = cuts[r], cuts[r + 1]
        own = below(hi) - below(lo)
        halo = (below(lo) - below(lo - reach) if r > 0 else 0.0) + \
               (below(hi + reach) - below(hi) if r < n - 1 else 0.0)
        out[r] = own + halo
    return out


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
        load = loads(hist_edges, hist, cuts, reach)
        # move each cut by half the excess of the heavier side, in particle-count space
        for r in range(1, n):
            excess = (load[r - 1] - targets[r - 1]) - (load[r] - targets[r])
            c = np.interp(cuts[r], hist_edges, cum) - 0.5 * excess
            cuts[r] = np.interp(np.clip(c, 0, cum[-1]), cum, hist_edges)
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
        raise InputError(f"balance: memory: the scene needs {int(total)} particles on {n} ranks but their "
                         f"capacities sum to {int(caps.sum())}: use more ranks or raise max_particles_per_rank")
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
    caps: list | None = None
    records: dict = field(default_factory=lambda: {"step": [], "applied": [], "fluid_count": [],
                                                   "force_seconds": [], "imbalance_before": [],
                                                   "imbalance_after": []})
    check_s: float = 0.0
    apply_s: float = 0.0
    speed: np.ndarray | None = None
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
        sync = getattr(ctx.compute, "sync_host", None)   # device-resident rows: current host positions
        if sync is not None:
            sync(st)
        x = st.particles.pos[st.particles.kind == FLUID, self.axis]
        n_own = len(x)
        n_halo = sum(int(np.count_nonzero(h.kind == FLUID)) for h in st.halos.values() if h is not None)
        steps = max(self.steps_since.get(ctx.rank, self.cfg.every), 1)
        fsec = self.force_s.pop(ctx.rank, 0.0) / steps
        self.steps_since[ctx.rank] = self.cfg.every
        xa = st.particles.pos[:, self.axis]  # the slabs span all particles, fluid or not
        lo, hi = (float(xa.min()), float(xa.max())) if len(xa) else (np.inf, -np.inf)
        info = ctx.comm.allgather((n_own, n_halo, fsec, lo, hi))
        counts = np.array([i[0] + i[1] for i in info], float)
        fsecs = np.array([i[2] for i in info])
        gl, gh = min(i[3] for i in info), max(i[4] for i in info)
        bins = max(int((gh - gl) / (self.dp / 16)) + 1, 1)
        edges = np.linspace(gl, gh + 1e-9, bins + 1)
        hist = np.histogram(x, bins=edges)[0].astype(np.int64)
        hist = np.sum(ctx.comm.allgather(hist), axis=0).astype(float)
        reach = dom.reach
        speed = counts / np.maximum(fsecs, 1e-300) if fsecs.min() > 0 else np.ones(len(counts))
        a = self.cfg.smoothing
        self.speed = speed if self.speed is None else a * speed + (1 - a) * self.speed
        cur = loads(edges, hist, dom.cuts, reach)
        total = cur.sum()
        caps = self.caps if self.caps is not None else [self.cfg.max_particles_per_rank or np.inf] * len(counts)
        targets = target_loads(self.cfg, total, self.speed, caps)
        cuts = solve_cuts(edges, hist, dom.cuts, targets, reach, 6.0 * self.h)
        new = loads(edges, hist, cuts, reach)
        # the balanced quantity: load relative to target (1 = on target)
        before = imbalance_vs(cur, targets)
        after = imbalance_vs(new, targets)
        over_cap = self.cfg.policy == "memory" and np.any(cur > np.asarray(caps) + 0.5)
        apply = (before - after) > self.cfg.threshold or over_cap
        t1 = time.perf_counter()
        if apply:
            dom.cuts = cuts
            st.cut_lo, st.cut_hi = cuts[ctx.rank], cuts[ctx.rank + 1]
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

    def datasets(self) -> dict:
        r = self.records
        if not r["step"]:
            return {}
        return {"step": np.array(r["step"], np.int64), "applied": np.array(r["applied"], bool),
                "fluid_count": np.array(r["fluid_count"], np.int64),
                "force_seconds": np.array(r["force_seconds"], float),
                "imbalance_before": np.array(r["imbalance_before"]),
                "imbalance_after": np.array(r["imbalance_after"])}


def imbalance_vs(loads_, targets) -> float:
    """max_r |N_r - T_r| / mean(T): 0 when every rank is on its target."""
    t = np.asarray(targets, float)
    return float(np.abs(np.asarray(loads_) - t).max() / t.mean())
