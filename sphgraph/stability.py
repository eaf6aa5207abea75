"""Where the method fails: small runs that provoke each known failure, and detectors that
name it from the run's *state* (never from the parameters that caused it).

Failures (`Verdict.name`) and how each is detected:

* ``blow-up``            the solver stops with `NumericalError` (NaN, a particle out of the
                         domain, density outside [rho_min, rho_max]), a scene with
                         ``[domain] exclude_outside`` removes a particle for those causes (the
                         scenes here turn it off, so the solver names it), or the kinetic energy
                         grows by more than `energy_growth` between samples of a flow that
                         only loses energy (no inflow, gravity-free or settling).
* ``pressure-noise``     RMS of each fluid particle's pressure minus the Shepard average of
                         its neighbours', relative to the pressure scale, above a bound
                         (checkerboard noise of WCSPH without density diffusion).
* ``compressibility``    max |rho/rho_ref - 1| over the fluid above 1 %, rho_ref the
                         density the particle had at rest (speed of sound too low:
                         Mach > ~0.1).
* ``clumping``           particles pair up: the smallest fluid-fluid distance falls below
                         `clump_fraction` * dp while fluid pressure is negative (tensile
                         instability).
* ``penetration``        a fluid particle lies beyond a wall's outermost boundary layer.

`stability_map(cfls, coefsounds)` runs the gravity-free elliptical drop (Monaghan 1994)
for each pair and returns one verdict per cell (`sphgraph plot stability`, the default
``--map cfl``). `penetration_map(speeds, models)` shoots a slab at a floor for each impact
speed and wall model (DBC or mDBC, 1 or 3 layers): per cell, how many fluid particles got
beyond the floor's outermost layer (counted from the particle positions every step) and the
wall-time per step of that model (``--map penetration``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .errors import InputError, NumericalError
from .scene import Scene

THRESHOLDS = {"energy_growth": 2.0, "pressure_noise": 0.05, "density_variation": 0.01,
              "clump_fraction": 0.5, "penetration_dp": 0.0}


@dataclass
class Verdict:
    name: str                 # "stable" or the failure
    detail: str = ""
    step: int | None = None
    value: float | None = None

    @property
    def stable(self) -> bool:
        return self.name == "stable"


# --------------------------------------------------------------------------- scenes
def drop_scene(dp=0.02, coefsound=20.0, cfl=0.2, kernel="wendland", diffusion="fourtakas", delta=0.1,
               integrator="symplectic", end_time=0.05, radius=0.2, visc_alpha=0.02) -> Scene:
    """A square 2r x 2r water patch without gravity or walls (set its velocity with `set_drop_velocity`)."""
    return Scene.from_dict({
        "format": 1, "name": "drop", "dim": 2, "dp": dp, "end_time": end_time,
        "domain": {"min": [-3.0, -3.0], "max": [3.0, 3.0], "origin": [0.0, 0.0], "exclude_outside": False},
        "physics": {"gravity": [0.0, 0.0], "hswl": 1.0, "coefsound": coefsound, "cfl": cfl, "kernel": kernel,
                    "diffusion": diffusion, "delta": delta, "integrator": integrator, "visc_alpha": visc_alpha,
                    "rho_min": 500.0, "rho_max": 2000.0},
        "fluid": [{"type": "box", "min": [-radius, -radius], "max": [radius, radius]}]})


def set_drop_velocity(sim, A: float) -> None:
    """v = (-A x, A y): Monaghan's elliptical drop (A > 0); A < 0 stretches it (tension)."""
    p = sim.contexts[0].state.particles
    p.vel[:, 0] = -A * p.pos[:, 0]
    p.vel[:, 1] = A * p.pos[:, 1]
    p.vel_m1[:] = p.vel


def tank_scene(dp=0.04, diffusion="fourtakas", delta=0.1, coefsound=20.0, cfl=0.2, layers=3,
               end_time=0.4, kernel="wendland") -> Scene:
    """Dam break 1 x 2 m column in a 4 m tank (examples/dambreak2d geometry, coarse)."""
    return Scene.from_dict({
        "format": 1, "name": "tank", "dim": 2, "dp": dp, "end_time": end_time,
        "domain": {"min": [-0.3, -0.3], "max": [4.3, 4.5], "origin": [0.0, 0.0], "exclude_outside": False},
        "physics": {"diffusion": diffusion, "delta": delta, "coefsound": coefsound, "cfl": cfl,
                    "visc_alpha": 0.02, "kernel": kernel},
        "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [1.0, 2.0]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [4.0, 3.0], "layers": layers}]})


def jet_scene(dp=0.02, speed=10.0, layers=1, coefsound=20.0, end_time=0.06, visc_alpha=0.02,
              boundary="dbc") -> Scene:
    """A 0.4 x 0.2 m slab of water shot at `speed` (set it with `set_jet_velocity`) against a floor
    of `layers` boundary layers treated by `boundary` ("dbc", "mdbc", "mdbc-noslip"); no gravity
    needed: the impact dominates; c0 is set from the still-water scale, not from the impact speed."""
    return Scene.from_dict({
        "format": 1, "name": "jet", "dim": 2, "dp": dp, "end_time": end_time,
        "domain": {"min": [-1.0, -0.5], "max": [2.0, 1.0], "origin": [0.0, 0.0], "exclude_outside": False},
        "physics": {"hswl": 0.2, "coefsound": coefsound, "visc_alpha": visc_alpha, "rho_min": 100.0,
                    "rho_max": 5000.0, "boundary": boundary},
        "fluid": [{"type": "box", "min": [0.3, 2 * dp], "max": [0.7, 0.2 + 2 * dp]}],
        "boundary": [{"type": "wall", "min": [-0.5, 0.0], "max": [1.5, 0.0], "layers": layers, "direction": "-"}]})


def set_jet_velocity(sim, speed: float) -> None:
    p = sim.contexts[0].state.particles
    fl = p.kind == 0
    p.vel[fl, 1] = -speed
    p.vel_m1[:] = p.vel


# --------------------------------------------------------------------------- detectors (state only)
def _fluid(sim):
    st = sim.contexts[0].state
    p = st.particles
    fl = p.kind == 0
    return st, p, fl


def kinetic_energy(sim) -> float:
    st, p, fl = _fluid(sim)
    return 0.5 * st.consts.mass_fluid * float((p.vel[fl] ** 2).sum())


def pressure_noise(sim, p_scale: float) -> float:
    """RMS over fluid of (p_i - Shepard mean of the neighbours' p) / p_scale."""
    from .probes import kernel_w
    st, p, fl = _fluid(sim)
    pos, pr, rho = p.pos[fl], st.press[fl], p.rho[fl]
    h = st.consts.h
    aw = float(st.consts.prm[3])
    out = np.full(len(pos), np.nan)
    cell = _cells(pos, 2 * h)
    m = st.consts.mass_fluid
    w0 = kernel_w(0.0, h, aw)
    for i in range(len(pos)):
        j = _neighbours(cell, pos, i, 2 * h)
        r = np.sqrt(((pos[j] - pos[i]) ** 2).sum(1))
        w = kernel_w(r, h, aw) * m / rho[j]
        if w.sum() + w0 * m / rho[i] < 0.95:     # surface or wall row: half a kernel, skip
            continue
        out[i] = pr[i] - (w * pr[j]).sum() / w.sum()
    out = out[np.isfinite(out)]
    return float(np.sqrt((out ** 2).mean()) / p_scale) if len(out) else 0.0


def _cells(pos, size):
    keys = np.floor(pos / size).astype(np.int64)
    d = {}
    for i, k in enumerate(map(tuple, keys)):
        d.setdefault(k, []).append(i)
    return {"size": size, "keys": keys, "map": {k: np.array(v) for k, v in d.items()}}


def _neighbours(cell, pos, i, reach):
    k = cell["keys"][i]
    dim = len(k)
    cand = []
    for off in np.ndindex(*(3,) * dim):
        key = tuple(k + np.array(off) - 1)
        if key in cell["map"]:
            cand.append(cell["map"][key])
    cand = np.concatenate(cand)
    r2 = ((pos[cand] - pos[i]) ** 2).sum(1)
    return cand[(r2 < reach * reach) & (cand != i)]


def min_fluid_distance(sim) -> float:
    st, p, fl = _fluid(sim)
    pos = p.pos[fl]
    cell = _cells(pos, st.consts.dp)
    best = math.inf
    for key, rows in cell["map"].items():
        cand = np.concatenate([cell["map"][tuple(np.array(key) + np.array(o) - 1)]
                               for o in np.ndindex(*(3,) * pos.shape[1])
                               if tuple(np.array(key) + np.array(o) - 1) in cell["map"]])
        d2 = ((pos[rows][:, None, :] - pos[cand][None, :, :]) ** 2).sum(-1)
        d2[d2 == 0] = np.inf
        best = min(best, float(d2.min()))
    return math.sqrt(best)


def outer_wall(sim, axis: int = 1, side: int = -1) -> float:
    """Coordinate of the outermost boundary layer along `axis`, read from the boundary particles
    (side -1: the fluid is above it, so the lowest row)."""
    _, p, fl = _fluid(sim)
    x = p.pos[~fl, axis]
    return float(x.min() if side < 0 else x.max())


def beyond_wall(sim, wall) -> int:
    """Fluid particles beyond `wall` = (axis, coordinate, side); side -1: fluid must stay above."""
    _, p, fl = _fluid(sim)
    axis, coord, side = wall
    x = p.pos[fl, axis]
    return int(((x < coord) if side < 0 else (x > coord)).sum())


def density_variation(sim, rho_ref) -> float:
    st, p, fl = _fluid(sim)
    ids = p.id[fl]
    return float(np.abs(p.rho[fl] / rho_ref[ids] - 1.0).max())


# --------------------------------------------------------------------------- watched runs
def watch(sim, steps: int, every: int = 10, *, p_scale=None, noise_bound=None, density_bound=None,
          clump_fraction=None, wall=None, energy_growth=None, rho_ref=None) -> Verdict:
    """Step `sim` up to `steps` steps; after every `every` steps check the state with the
    detectors asked for; the first failure found is returned, else `stable`.

    wall: (axis, coordinate of the outermost boundary layer, side) — side -1: fluid must
    stay above it."""
    if rho_ref is None and density_bound is not None:
        st, p, _ = _fluid(sim)
        rho_ref = np.empty(p.n)
        rho_ref[p.id] = p.rho
    e0 = kinetic_energy(sim) if energy_growth else None
    worst = {}
    for k in range(1, steps + 1):
        try:
            sim.step()
        except NumericalError as e:
            return Verdict("blow-up", f"{e.cause} at step {e.step}", step=e.step)
        ex = sim.features.excluded
        if ex:    # a scene with [domain] exclude_outside: a removed particle is the same failure
            step, _, pid, cause = ex[0][:4]
            from .errors import CAUSES
            return Verdict("blow-up", f"{CAUSES[cause]} at step {step} (particle id {pid} excluded)", step=step)
        if k % every and k != steps:
            continue
        st, p, fl = _fluid(sim)
        if energy_growth:
            e = kinetic_energy(sim)
            if e0 > 0 and e > energy_growth * e0:
                return Verdict("blow-up", f"kinetic energy grew x{e / e0:.3g} by step {sim.step_count}",
                               step=sim.step_count, value=e / e0)
        if wall is not None:
            n = beyond_wall(sim, wall)
            if n:
                return Verdict("penetration", f"{n} fluid particles beyond the wall at step "
                               f"{sim.step_count}", step=sim.step_count, value=float(n))
        if density_bound is not None:
            v = density_variation(sim, rho_ref)
            worst["density"] = max(worst.get("density", 0.0), v)
            if v > density_bound:
                return Verdict("compressibility", f"density variation {100 * v:.2g} % > {100 * density_bound:g} % "
                               f"at step {sim.step_count}", step=sim.step_count, value=v)
        if clump_fraction is not None:
            dmin = min_fluid_distance(sim) / st.consts.dp
            worst["dmin"] = min(worst.get("dmin", math.inf), dmin)
            if dmin < clump_fraction and (st.press[fl] < 0).any():
                return Verdict("clumping", f"particles {dmin:.2g} dp apart under negative pressure at step "
                               f"{sim.step_count}", step=sim.step_count, value=dmin)
        if noise_bound is not None and (k % (every * 5) == 0 or k == steps):
            v = pressure_noise(sim, p_scale)
            worst["noise"] = max(worst.get("noise", 0.0), v)
            if v > noise_bound:
                return Verdict("pressure-noise", f"pressure noise {v:.3g} x scale > {noise_bound:g} at step "
                               f"{sim.step_count}", step=sim.step_count, value=v)
    return Verdict("stable", ", ".join(f"worst {k} {v:.3g}" for k, v in worst.items()),
                   value=next(iter(worst.values()), None))


def stability_map(cfls, coefsounds, steps=300, dp=0.04, A=5.0) -> list[dict]:
    """Elliptical drop (v = (-A x, A y), no gravity) for each (CFL, coefsound): blow-up,
    compressibility (density variation > 1 %) or stable."""
    from .solver import Simulation
    cells = []
    for cs in coefsounds:
        for cfl in cfls:
            sim = Simulation(drop_scene(dp=dp, coefsound=cs, cfl=cfl, end_time=10.0), invariants=False)
            set_drop_velocity(sim, A)
            v = watch(sim, steps, every=10, density_bound=THRESHOLDS["density_variation"], energy_growth=1.5)
            cells.append({"cfl": cfl, "coefsound": cs, "verdict": v.name, "detail": v.detail, "value": v.value,
                          "step": v.step})
    return cells


# wall models of the penetration map: label -> ([physics] boundary, layers)
# (mdbc-4: the kernel's support at h = 2 dp, benchmarks/riemann_wall_jet.py)
WALL_MODELS = {"dbc-1": ("dbc", 1), "dbc-3": ("dbc", 3), "mdbc-1": ("mdbc", 1), "mdbc-3": ("mdbc", 3),
               "mdbc-4": ("mdbc", 4)}


def penetration_map(speeds, models=("dbc-1", "dbc-3", "mdbc-1", "mdbc-3"), travel=0.3, dp=0.02, max_steps=20000,
                    warmup=10, physics=None) -> list[dict]:
    """A slab hitting the floor (`jet_scene`) at each impact speed [m/s], for each wall model of
    `WALL_MODELS`: one cell per (speed, model); `physics`, scene physics keys over the jet's
    (e.g. the integrator and the Riemann term).

    Each run lasts until the slab, left alone, would have moved `travel` metres (t = travel /
    speed; 0.3 m is 1.5 slab heights: the impact is over and the water spread on the floor), at
    most `max_steps` steps. After every step the fluid particles below the floor's outermost
    boundary row (its coordinate read from the boundary particles, `outer_wall`) are counted
    from their positions (`beyond_wall`). The models of one speed run one after the other, so
    a change in the machine's load hits them alike.

    Cell keys: ``through`` the most fluid particles beyond the wall at once (0: held) of
    ``n_fluid``; ``step`` the first step with any; ``verdict`` "penetration", "stable", or
    "blow-up" (the solver stopped with `NumericalError` before any crossing; after one the
    verdict stays "penetration" and ``detail`` names the error); ``steps`` / ``time`` how far
    it ran; ``ms_per_step`` the median wall-time of one `sim.step()` past the first `warmup`
    steps (JIT compilation): the model's cost."""
    from .solver import Simulation
    unknown = [m for m in models if m not in WALL_MODELS]
    if unknown:
        raise InputError(f"--models: unknown wall model {unknown[0]!r}; expected some of "
                         f"{', '.join(WALL_MODELS)}")
    cells = []
    for speed in speeds:
        if not speed > 0:
            raise InputError(f"--speeds: expected impact speeds > 0 m/s, got {speed:g}")
        for model in models:
            boundary, layers = WALL_MODELS[model]
            scene = jet_scene(dp=dp, layers=layers, boundary=boundary)
            sim = Simulation(scene.with_overrides(**physics) if physics else scene, invariants=False)
            set_jet_velocity(sim, speed)
            wall = (1, outer_wall(sim), -1)
            through, first, error, times = 0, None, "", []
            while sim.time < travel / speed and len(times) < max_steps:
                t0 = time.perf_counter()
                try:
                    sim.step()
                except NumericalError as e:
                    error = f"{e.cause} at step {e.step}"
                    break
                times.append(time.perf_counter() - t0)
                n = beyond_wall(sim, wall)
                if n and first is None:
                    first = sim.step_count
                through = max(through, n)
            verdict = "penetration" if through else ("blow-up" if error else "stable")
            detail = f"{through} of {sim.n_fluid} fluid particles through from step {first}" if through else ""
            if error:
                detail = f"{detail}; then {error}" if detail else error
            timed = times[warmup:] or times
            cells.append({"model": model, "boundary": boundary, "layers": layers, "speed": speed,
                          "verdict": verdict, "through": through, "n_fluid": sim.n_fluid, "step": first,
                          "detail": detail, "steps": len(times), "time": sim.time,
                          "ms_per_step": 1e3 * float(np.median(timed)) if timed else None})
    return cells


def model_costs(cells: list) -> dict:
    """Median ``ms_per_step`` of each wall model over its cells of a `penetration_map`."""
    out = {}
    for m in dict.fromkeys(c["model"] for c in cells):
        ms = [c["ms_per_step"] for c in cells if c["model"] == m and c["ms_per_step"] is not None]
        out[m] = float(np.median(ms)) if ms else None
    return out
