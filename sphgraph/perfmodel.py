"""The performance model of multi-rank runs and its one predictor (DESIGN.md §4).

A task's modelled duration is

    seconds = (a + b * particles + c * pairs) / rank_speed[rank]

with (a, b, c) per task kind. `particles` is the row count the task works on
(owned rows; halo rows for halo forces; rows moved for sends/receives) and
`pairs` an estimate of the interactions it computes (`particles` times the
number of lattice neighbours within 2h, halved for halo forces, whose rows see
owned rows on one side only). The estimate is the same in fitting and in
prediction, so the fitted coefficients absorb its bias.

Messages: latency + bytes / bandwidth; the dt allreduce costs
2 * ceil(log2 N) * latency after the last rank arrives.

Displaced rows (rows crossing a cut) are priced as `displaced_fraction` of the sender's
edge rows towards that neighbour, in the message's bytes and in recv_displaced's rows:
no kernel runs in a prediction, so the rows that would cross are unknown, and the
paper's measure is a fraction of the halo (about 1000x less data), which grows with the
scene as the edge does; a fixed count would not.

recv_displaced issued after build_cells (production) also merges the arrivals into the
sorted rows and cells: that work is part of recv_displaced's fitted cost (its fit on
2-rank runs measures the task as the schedule runs it), not a term of its own, so the
same coefficients serve both orders and fitted files load unchanged. What the order
changes in prediction is the wait: the message travels during build_cells.

`fit_costs` fits (a, b, c) by least squares on samples of measured single-rank runs
(`samples_from_timing`; benchmarks/fit_costs.py runs them). `step_pricing` is the one
pricing of a step's tasks and messages: `predict` (a scene's decomposition estimated,
no particles on ranks) and the mock comm's predict mode (the real rank states) both
use it, and run the real multi-rank programs of a schedule through the mock engine.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

DEFAULT_LATENCY = 2.0e-6        # s, shared-memory MPI on one host
DEFAULT_BANDWIDTH = 5.0e9       # bytes/s
DISPLACED_FRACTION = 1e-3       # displaced rows per edge row and step (module doc)
HALO_ROW_BYTES = {2: 2 * 8 + 2 * 8 + 8 + 1, 3: 3 * 8 + 3 * 8 + 8 + 1}  # pos, vel, rho, kind (float64)
ROW_BYTES = {2: 8 + 1 + 2 * 8 * 3 + 2 * 8, 3: 8 + 1 + 3 * 8 * 3 + 2 * 8}  # a whole Particles row

# kinds whose cost the single-rank fit cannot see, and the fitted kind they borrow from
BORROW = {"forces_halo_1": "forces_interior", "forces_halo_2": "forces_interior"}


def neighbours_within(dim: int, radius_over_dp: float) -> int:
    """Lattice points (other than the centre) within `radius_over_dp` lattice spacings."""
    r = int(math.floor(radius_over_dp))
    ax = np.arange(-r, r + 1)
    grids = np.meshgrid(*([ax] * dim), indexing="ij")
    d2 = sum(g.astype(float) ** 2 for g in grids)
    return int(np.count_nonzero(d2 <= radius_over_dp ** 2 + 1e-9)) - 1


@dataclass
class CostModel:
    """Per task kind (label) coefficients (a [s], b [s/particle], c [s/pair])."""

    coeffs: dict = field(default_factory=dict)
    fit_error: dict = field(default_factory=dict)   # kind -> relative RMS error of the fit
    source: str = "<dict>"
    default: tuple = (1.0e-6, 0.0, 0.0)

    @classmethod
    def load(cls, spec=None) -> "CostModel":
        """None (shipped default fit), a CostModel, a dict {kind: [a, b, c]} or a TOML path."""
        if isinstance(spec, CostModel):
            return spec
        if spec is None:
            text = resources.files("sphgraph").joinpath("costs_default.toml").read_text()
            return cls._from_toml(tomllib.loads(text), "costs_default.toml")
        if isinstance(spec, dict):
            if "costs" in spec:
                return cls._from_toml(spec, "<dict>")
            return cls({k: tuple(float(x) for x in v) for k, v in spec.items()})
        with open(spec, "rb") as f:
            return cls._from_toml(tomllib.load(f), str(spec))

    @classmethod
    def _from_toml(cls, d, source):
        coeffs = {k: tuple(float(x) for x in v) for k, v in d["costs"].items()}
        err = {k: float(v) for k, v in d.get("fit_error", {}).items()}
        return cls(coeffs, err, source)

    def to_toml(self, comment: str = "") -> str:
        lines = [f"# {c}" for c in comment.splitlines()] if comment else []
        lines += ["format = 1", "", "[costs]  # kind = [a (s), b (s/particle), c (s/pair)]"]
        for k, (a, b, c) in sorted(self.coeffs.items()):
            lines.append(f"{k} = [{a:.6e}, {b:.6e}, {c:.6e}]")
        if self.fit_error:
            lines += ["", "[fit_error]  # relative RMS error of the fit per kind"]
            for k, v in sorted(self.fit_error.items()):
                lines.append(f"{k} = {v:.4f}")
        return "\n".join(lines) + "\n"

    def coeff(self, label: str) -> tuple:
        if label in self.coeffs:
            return self.coeffs[label]
        if label in BORROW and BORROW[label] in self.coeffs:
            return self.coeffs[BORROW[label]]
        return self.default

    def seconds(self, label: str, particles: float, pairs: float, speed: float = 1.0) -> float:
        a, b, c = self.coeff(label)
        return max(0.0, a + b * particles + c * pairs) / speed


def pairs_per_particle(consts, dim: int, dp: float) -> float:
    """Lattice neighbours within 2h: the pair estimate's factor."""
    return float(neighbours_within(dim, 2.0 * consts.h / dp))


def task_features(label: str, n_owned: int, halo_rows: int, moved_rows: int, k: float):
    """(particles, pairs) of a task, by label (see module doc)."""
    if label == "forces_interior":
        return n_owned, n_owned * k
    if label in ("forces_halo_1", "forces_halo_2"):
        return halo_rows, 0.5 * halo_rows * k
    if label in ("send_edges", "recv_halo_1", "recv_halo_2", "recv_displaced"):
        return moved_rows, 0.0
    if label == "send_displaced":
        return n_owned, 0.0   # scans every owned row for leavers
    return n_owned, 0.0


def network_seconds(nbytes: int, latency: float, bandwidth: float) -> float:
    return latency + nbytes / bandwidth


def allreduce_seconds(nranks: int, latency: float) -> float:
    return 2.0 * math.ceil(math.log2(max(nranks, 1))) * latency if nranks > 1 else 0.0


# --------------------------------------------------------------------------- fitting
def samples_from_timing(timing, n_particles: int, k: float, first_step: int = 1) -> list:
    """(label, particles, pairs, mean seconds) per task kind of one measured single-rank run.

    `timing` is `RunResult.timing` (a TaskTimes); `n_particles` the rank's row count
    (`RankState.particles.n`; constant on one rank); `k` = pairs_per_particle.
    """
    tot: dict[str, list] = {}
    for s, name, a, b in zip(timing.step, timing.task, timing.start, timing.end):
        if s >= first_step:
            tot.setdefault(name.split("@")[0], []).append(b - a)
    out = []
    for label, xs in tot.items():
        # one sample per task instance mean (a Symplectic step has two force stages)
        p, q = task_features(label, n_particles, 0, 0, k)
        out.append((label, float(p), float(q), float(np.median(xs))))
    return out


def fit_costs(samples, labels=None) -> CostModel:
    """Least-squares fit of (a, b, c) per kind from samples (label, particles, pairs, seconds).

    Samples come from several runs of different sizes (and, to separate b from c, of
    different pairs per particle: 2D and 3D scenes). Coefficients are clipped at >= 0
    (refitting without the clipped terms). `fit_error[kind]` is the relative RMS error
    sqrt(mean(((model - measured) / measured)^2)) over that kind's samples.
    """
    by: dict[str, list] = {}
    for lab, p, q, s in samples:
        if labels is None or lab in labels:
            by.setdefault(lab, []).append((p, q, s))
    coeffs, err = {}, {}
    for lab, rows in by.items():
        X = np.array([[1.0, p, q] for p, q, _ in rows])
        y = np.array([s for _, _, s in rows])
        active = [0, 1, 2] if lab.startswith("forces") else [0, 1]
        while True:
            # relative least squares: weight rows by 1/measured (every size counts alike)
            w = 1.0 / np.maximum(y, 1e-12)
            sol, *_ = np.linalg.lstsq(X[:, active] * w[:, None], y * w, rcond=None)
            neg = [active[i] for i, v in enumerate(sol) if v < 0]
            if not neg or len(active) == 1:
                break
            active = [i for i in active if i not in neg[:1]]
        coef = np.zeros(3)
        coef[active] = np.maximum(sol, 0.0)
        coeffs[lab] = tuple(float(v) for v in coef)
        model = X @ coef
        err[lab] = float(np.sqrt(np.mean(((model - y) / np.maximum(y, 1e-12)) ** 2)))
    return CostModel(coeffs, err, "<fit>")


def step_pricing(model: CostModel, rows, lo_edge, hi_edge, k: float, dim: int, speed,
                 displaced_fraction: float = DISPLACED_FRACTION):
    """(cost, message_bytes) of one step for the mock engine's `run_modelled`: `cost(rank,
    task)` seconds and `message_bytes(rank, task, msg)` of a send, from each rank's rows,
    its edge rows towards the lower and the upper neighbour (0 at an end), the pairs per
    particle `k` and the ranks' speeds. Displaced rows: see the module doc."""
    def edge_rows(r, d):
        return lo_edge[r] if d < 0 else hi_edge[r]

    def cost(rank, task):
        lab = task.label
        if lab == "send_edges":
            moved = sum(edge_rows(rank, m.peer) for m in task.sends)
        elif lab in ("recv_halo_1", "forces_halo_1"):
            moved = hi_edge[rank - 1]
        elif lab in ("recv_halo_2", "forces_halo_2"):
            moved = lo_edge[rank + 1]
        elif lab == "recv_displaced":
            moved = sum(displaced_fraction * edge_rows(rank + m.peer, -m.peer) for m in task.recvs)
        else:
            moved = 0
        p, q = task_features(lab, rows[rank], moved, moved, k)
        return model.seconds(lab, p, q, speed[rank])

    def message_bytes(rank, task, m):
        if task.label == "send_edges":
            return int(edge_rows(rank, m.peer) * HALO_ROW_BYTES[dim])
        return int(displaced_fraction * edge_rows(rank, m.peer) * ROW_BYTES[dim])

    return cost, message_bytes


# --------------------------------------------------------------------------- prediction
@dataclass
class Prediction:
    ranks: int
    steps: int
    particles: int
    virtual_s: float                 # virtual time of `steps` steps
    steps_per_s: float
    task_seconds: dict               # label -> summed virtual seconds over ranks and steps
    per_rank: dict                   # rank -> {label: seconds}
    rank_particles: list
    fit_error: dict
    timing: object = None            # TaskTimes of the predicted run


def decomposition_shape(scene, ranks: int, max_build: int = 1_000_000, axis=None, weights=None):
    """Estimated per-rank rows, halo rows and k for `scene` split on `ranks` ranks.

    The scene's particles are built (at a coarser dp if the scene has more than
    `max_build` particles; counts then scale by (dp_c / dp)^dim), split with the
    solver's `equal_cuts`, and each rank's edge rows counted within 2.2h of its cuts.
    """
    from .domain import choose_axis, equal_cuts
    from .particles import FLUID
    dim = scene.dim
    # fluid fills volumes (~dp^-dim), boundaries are single layers on surfaces (~dp^-(dim-1));
    # count on a 4x coarser lattice first: counting 16 M lattice points is itself slow
    nf4, nb4 = scene.with_overrides(dp=scene.dp * 4.0).count_particles()
    n_est = nf4 * 4.0 ** dim + nb4 * 4.0 ** (dim - 1)
    sc, ratio = scene, 1.0
    if n_est > max_build:
        ratio = (n_est / max_build) ** (1.0 / dim)
        sc = scene.with_overrides(dp=scene.dp * ratio)
    p = sc.build_particles(np.float64)
    wts = np.where(p.kind == FLUID, ratio ** dim, ratio ** (dim - 1))
    n_full = float(wts.sum())
    # the full-resolution h (cuts and reach in metres); hswl from the coarse build (only c0
    # depends on it), since the scene's own hswl would enumerate the full lattice
    from .config import derive
    consts = derive(scene.physics, dim, scene.dp, sc.hswl)
    ax = choose_axis(axis or scene.decomposition_axis, p, consts.gravity)
    cuts = equal_cuts(p, ax, ranks, consts.h, weights)
    x = p.pos[:, ax]
    from .domain import REACH_H
    reach = REACH_H * consts.h
    owner = np.searchsorted(cuts[1:-1], x, side="right")
    rows, lo_edge, hi_edge = [], [], []
    for r in range(ranks):
        sel = owner == r
        mine, w = x[sel], wts[sel]
        rows.append(float(w.sum()))
        lo_edge.append(float(w[mine < cuts[r] + reach].sum()) if r > 0 else 0.0)
        hi_edge.append(float(w[mine >= cuts[r + 1] - reach].sum()) if r < ranks - 1 else 0.0)
    k = pairs_per_particle(consts, scene.dim, scene.dp)
    return {"rows": rows, "lo_edge": lo_edge, "hi_edge": hi_edge, "k": k, "dim": scene.dim,
            "particles": n_full, "cuts": cuts, "axis": ax}


def predict(scene, ranks: int, schedule="production", steps: int = 10, costs=None, rank_speed=None,
            latency: float = DEFAULT_LATENCY, bandwidth: float = DEFAULT_BANDWIDTH,
            displaced_fraction: float = DISPLACED_FRACTION, shape=None) -> Prediction:
    """Steps/s and per-task virtual times of `scene` on `ranks` ranks, no kernels run.

    The real programs of `schedule` (the same expansion the scheduler runs), the
    real messages between them and the dt allreduce go through the mock engine;
    durations come from `costs` (a CostModel or spec for `CostModel.load`; default the
    shipped fit) priced by `step_pricing`. `displaced_fraction` of the edge rows migrate
    per step.
    """
    from .registry import get
    from .scene import Scene
    from .schedule import Schedule
    from .scheduler import TaskTimes

    if not isinstance(scene, Scene):
        scene = Scene.from_toml(scene)
    model = CostModel.load(costs)
    sched = Schedule.load(schedule)
    stages = 1 if scene.physics.integrator == "verlet" else 2
    sched.validate(ranks, stages)
    shape = shape or decomposition_shape(scene, ranks)
    speed = list(rank_speed) if rank_speed is not None else [1.0] * ranks
    if len(speed) != ranks:
        raise ValueError(f"rank_speed: expected {ranks} values, got {len(speed)}")
    programs = {r: sched.program(r, ranks, stages) for r in range(ranks)}
    rows = shape["rows"]
    cost, message_bytes = step_pricing(model, rows, shape["lo_edge"], shape["hi_edge"], shape["k"],
                                       shape["dim"], speed, displaced_fraction)
    times = TaskTimes()
    eng = get("comm", "mock")(ranks=ranks, latency=latency, bandwidth=bandwidth).engine
    for s in range(steps):
        def rec(rank, task, a, b, _s=s):
            times.rank.append(rank)
            times.step.append(_s)
            times.task.append(task.name)
            times.lane.append(task.lane)
            times.start.append(a)
            times.end.append(b)
        eng.run_modelled(programs, cost, message_bytes, rec)
    total = max(eng.clock)
    per_rank: dict = {}
    task_seconds: dict = {}
    for r, name, a, b in zip(times.rank, times.task, times.start, times.end):
        lab = name.split("@")[0]
        per_rank.setdefault(r, {}).setdefault(lab, 0.0)
        per_rank[r][lab] += b - a
        task_seconds[lab] = task_seconds.get(lab, 0.0) + (b - a)
    return Prediction(ranks=ranks, steps=steps, particles=int(shape["particles"]), virtual_s=total,
                      steps_per_s=steps / total if total > 0 else float("inf"),
                      task_seconds=task_seconds, per_rank=per_rank,
                      rank_particles=[int(x) for x in rows], fit_error=dict(model.fit_error),
                      timing=times)


def efficiency_curve(scene, ranks_list, **kw) -> dict:
    """E(N) = (steps/s on N / N) / (steps/s on 1), predicted, for each N in `ranks_list`."""
    base = predict(scene, 1, **kw).steps_per_s
    return {n: predict(scene, n, **kw).steps_per_s / n / base for n in ranks_list}
