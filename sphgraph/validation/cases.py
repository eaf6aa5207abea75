"""Validation cases: a scene, its reference data and its tolerances, run and compared.

Each case is a TOML file in `sphgraph/validation/cases/` (package data)::

    name = "dambreak"              # what `sphgraph validate NAME` takes
    title = "..."
    runner = "surge_front"         # one of RUNNERS below
    dp = 0.02                      # default resolution (--dp overrides)
    [params]                       # runner parameters (sample window, probe position, ...)
    [scene]                        # a complete scene (docs/scenes.md), built per dp by the runner
    [reference]                    # datasets (files in validation/data, each with its source header)
    [tolerances]                   # metric = [low, high]: the run passes when low <= value <= high

`run_case(name, dp=..., backend=..., overrides={...})` returns a `CaseResult` with every
error norm (`metrics`), the tolerance checks and the series to plot. Tolerances live only
in the case files; the numbers they are compared with come from the shipped data, whose
files carry their source (paper, figure, DOI) in their header.
"""
from __future__ import annotations

import contextvars
import copy
import math
import time
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import InputError, NumericalError
from . import load, surge_front

G = 9.81


# --------------------------------------------------------------------------- case files
@dataclass
class Case:
    name: str
    title: str
    runner: str
    dp: float
    scene: dict
    params: dict = field(default_factory=dict)
    reference: dict = field(default_factory=dict)
    tolerances: dict = field(default_factory=dict)
    text: str = ""


def _case_dir():
    return resources.files(__package__).joinpath("cases")


def list_cases() -> list[str]:
    return sorted(p.name[:-5] for p in _case_dir().iterdir() if p.name.endswith(".toml"))


def load_case(name: str) -> Case:
    if name.endswith(".toml") and Path(name).is_file():
        text, src = Path(name).read_text(), name
    else:
        f = _case_dir().joinpath(f"{name}.toml")
        if not f.is_file():
            raise InputError(f"validate: CASE: expected one of {', '.join(list_cases())}, got {name!r}")
        text, src = f.read_text(), f"{name}.toml"
    d = tomllib.loads(text)
    for k in ("name", "runner", "dp", "scene"):
        if k not in d:
            raise InputError(f"{src}: {k}: expected a value, got nothing")
    if d["runner"] not in RUNNERS:
        raise InputError(f"{src}: runner: expected one of {', '.join(RUNNERS)}, got {d['runner']!r}")
    for k, v in d.get("tolerances", {}).items():
        if not (isinstance(v, list) and len(v) == 2):
            raise InputError(f"{src}: tolerances.{k}: expected [low, high], got {v!r}")
    return Case(name=d["name"], title=d.get("title", d["name"]), runner=d["runner"], dp=float(d["dp"]),
                scene=d["scene"], params=d.get("params", {}), reference=d.get("reference", {}),
                tolerances=d.get("tolerances", {}), text=text)


class CaseStopped(NumericalError):
    """A validation run that stopped numerically; `result` is the `CaseResult` over the time
    it reached (metrics, series, the stop in `stopped`), for the runners that sample as they
    go (water heights). The run still fails: the CLI exits 1 with the failure."""

    def __init__(self, e: NumericalError, partial: tuple):
        super().__init__(str(e), step=e.step, particle_id=e.particle_id, cause=e.cause)
        self.partial = partial          # (metrics, series, stats, notes) of the runner
        self.result = None              # the CaseResult, set by run_case


@dataclass
class CaseResult:
    case: str
    dp: float
    metrics: dict
    checks: list                      # (metric, value, low, high, ok)
    series: dict                      # for the plot: name -> (x, y, style)
    wall_s: float
    steps: int
    particles: int
    config: dict
    notes: list = field(default_factory=list)
    plot_path: str | None = None
    stopped: str | None = None        # the numerical failure a partial result stopped at

    @property
    def ok(self) -> bool:
        return self.stopped is None and all(c[4] for c in self.checks)

    def report(self) -> str:
        lines = [f"case {self.case} at dp = {self.dp:g}: {self.particles} particles, {self.steps} steps, "
                 f"{self.wall_s:.1f} s ({', '.join(f'{k}={v}' for k, v in self.config.items())})"]
        tol = {c[0]: c for c in self.checks}
        for k, v in self.metrics.items():
            if k in tol:
                _, _, lo, hi, ok = tol[k]
                lines.append(f"  {k:42s} {v: .4g}   [{lo:g}, {hi:g}] {'ok' if ok else 'OUTSIDE'}")
            else:
                lines.append(f"  {k:42s} {v: .4g}")
        lines += [f"  note: {n}" for n in self.notes]
        if self.stopped is not None:
            lines.append(f"  STOPPED: {self.stopped} (the metrics above are over the time reached)")
        lines.append("PASS" if self.ok else "FAIL")
        return "\n".join(lines)


def run_case(name: "str | Case", dp: float | None = None, backend: str = "numba-cpu", precision: str | None = None,
             overrides: dict | None = None, out: str | None = None, plot: bool = True,
             params: dict | None = None, progress: bool = False) -> CaseResult:
    """Run validation case `name` (a case name, a case file path or a `Case` built in code, e.g.
    by :func:`sphgraph.validation.gate.with_gate`); `overrides` are physics fields; `progress`:
    a bar on a terminal (a line every few seconds otherwise) for each simulation the case runs."""
    case = name if isinstance(name, Case) else load_case(name)
    dp = float(dp) if dp is not None else case.dp
    prm = dict(case.params, **(params or {}))
    t0 = time.perf_counter()
    stopped = None
    token = _PROGRESS.set(_RunProgress() if progress else None)
    try:
        metrics, series, stats, notes = RUNNERS[case.runner](case, dp, prm, backend=backend, precision=precision,
                                                             overrides=dict(overrides or {}))
    except CaseStopped as e:
        stopped = e
        metrics, series, stats, notes = e.partial
    finally:
        prog = _PROGRESS.get()
        if prog is not None:
            prog.close()
        _PROGRESS.reset(token)
    wall = time.perf_counter() - t0
    checks = []
    for k, (lo, hi) in case.tolerances.items():
        v = metrics.get(k, math.nan)
        checks.append((k, v, float(lo), float(hi), bool(lo <= v <= hi)))
    cfg = {"backend": backend, "precision": precision or "default"}
    cfg.update(overrides or {})
    res = CaseResult(case=case.name, dp=dp, metrics=metrics, checks=checks, series=series, wall_s=wall,
                     steps=stats["steps"], particles=stats["particles"], config=cfg, notes=notes,
                     stopped=None if stopped is None else str(stopped))
    if plot and out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        from ..plots import plot_validation
        res.plot_path = plot_validation(res, case.title, Path(out) / f"{case.name}.png")
    if stopped is not None:
        stopped.result = res
        raise stopped
    return res


# --------------------------------------------------------------------------- helpers
class _RunProgress:
    """The progress of the simulations one case runs: each new simulation gets its own bar (or
    line), towards the time its runner steps it to; the steps/s count starts after the first
    step (numba's compilation), as `sphgraph run`'s does."""

    def __init__(self):
        self.sim, self.bar = None, None

    def update(self, sim, end_time: float) -> None:
        from ..progress import Progress
        if sim is not self.sim:
            self.close()
            self.sim, self.bar = sim, Progress(end_time)
        if sim.step_count == 1:
            self.bar.reset_clock(1)
        self.bar.update(sim.time, sim.step_count)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.sim, self.bar = None, None


#: run_case's progress (a _RunProgress, or None: quiet), read by _step
_PROGRESS: contextvars.ContextVar = contextvars.ContextVar("sphgraph_validation_progress", default=None)


def _step(sim, end_time: float) -> None:
    """One step of `sim`, a runner's loop towards `end_time`, shown when run_case was asked to."""
    sim.step()
    prog = _PROGRESS.get()
    if prog is not None:
        prog.update(sim, end_time)


def scene_for(case: Case, dp: float, overrides: dict, boundary=None, **top):
    """The case's scene at `dp` with physics overrides (and top-level keys, e.g. end_time);
    `boundary` (the case's wall treatment parameter) is set in the scene's physics before it is
    validated, so that options that need mDBC walls pass the scene's checks."""
    from ..scene import Scene
    d = copy.deepcopy(case.scene)
    d["dp"] = dp
    if boundary is not None and boundary != "dbc":
        d.setdefault("physics", {})["boundary"] = boundary
    layers = top.pop("layers", None)
    if layers is not None:   # wall thickness override (e.g. mDBC wants the kernel's support)
        for b in d.get("boundary", []):
            b["layers"] = int(layers)
        margin = (int(layers) + 1) * dp
        d["domain"] = dict(d["domain"], min=[min(x, -margin) for x in d["domain"]["min"]])
        d["domain"]["max"] = [x + margin for x in d["domain"]["max"]]
    d.update(top)
    d.setdefault("physics", {}).update({k: v for k, v in overrides.items()})
    return Scene.from_dict(d, source=f"case {case.name}")


def _sim(scene, backend, precision, boundary="dbc", **kw):
    """A Simulation; boundary "mdbc" / "mdbc-noslip" sets the scene's `[physics] boundary`,
    which adds the `mdbc` task before each force stage, as `sphgraph run` does."""
    from ..solver import Simulation
    if boundary != "dbc":
        scene = scene.with_overrides(boundary=boundary)
    try:
        return Simulation(scene, backend=backend, precision=precision, invariants=False, **kw)
    except TypeError:   # a solver without the invariants option
        return Simulation(scene, backend=backend, precision=precision, **kw)


def _fluid(sim):
    st = sim.contexts[0].state
    return st.particles


def _arrays(sim):
    if len(sim.contexts) == 1 and sim.compute.name == "numba-cpu":
        st = sim.contexts[0].state
        p = st.particles
        return {"position": p.pos, "velocity": p.vel, "density": p.rho, "kind": p.kind,
                "pressure": st.press}
    return sim.frame_arrays()


def _run_sampled(sim, samplers: list, end_time: float) -> None:
    """Step `sim` to `end_time`, sampling at t = 0 and whenever each of `samplers` is due."""
    for s in samplers:
        s.sample(sim)
    while sim.time < end_time - 1e-12:
        _step(sim, end_time)
        for s in samplers:
            if s.due(sim.time):
                s.sample(sim)


def rel_errors(sim_T, sim_Z, ref_T, ref_Z):
    """Relative errors (sim - ref)/ref at the reference times (sim interpolated)."""
    z = np.interp(ref_T, sim_T, sim_Z)
    return (z - ref_Z) / ref_Z


# --------------------------------------------------------------------------- runners
def run_surge_front(case, dp, prm, backend, precision, overrides):
    """Dam break: surge front Z/a and residual column height against each experiment."""
    a = float(prm["a"])
    T0, T1 = prm["window"]
    scale = math.sqrt(2 * G / a)
    scene = scene_for(case, dp, overrides, boundary=prm.get("boundary"), layers=prm.get("layers"))
    sim = _sim(scene, backend, precision, boundary=prm.get("boundary", "dbc"))
    Ts, Zs, Hs = [0.0], [1.0], [2.0]
    T_end = float(prm.get("T_end", T1 + 0.1))
    while sim.time * scale < T_end:
        _step(sim, T_end / scale)
        if sim.step_count % 10 == 0:
            a_ = _arrays(sim)
            fl = a_["kind"] == 0
            pos = a_["position"][fl]
            Ts.append(sim.time * scale)
            Zs.append(surge_front(a_["position"], a_["kind"], a))
            Hs.append(float(pos[pos[:, 0] < 0.1 * a + 1e-9, 1].max(initial=0.0)) / a)
    Ts, Zs, Hs = map(np.array, (Ts, Zs, Hs))
    metrics, series, errs = {}, {"sphgraph (front)": (Ts, Zs, "-")}, {}
    for key, ds in case.reference["datasets"].items():
        data, header = load(ds)
        w = data[(data[:, 0] >= T0) & (data[:, 0] <= T1)]
        e = rel_errors(Ts, Zs, w[:, 0], w[:, 1])
        errs[key] = e
        metrics[f"front_mean_rel_err_{key}"] = float(e.mean())
        metrics[f"front_max_abs_rel_err_{key}"] = float(np.abs(e).max())
        metrics[f"front_rms_rel_err_{key}"] = float(np.sqrt((e ** 2).mean()))
        series[f"{ds.split('_19')[0].replace('_', ' ').title()} ({key})"] = (data[:, 0], data[:, 1], "o")
    # the datasets' own spread: each against their mean, on a common T grid inside every range
    datas = [load(ds)[0] for ds in case.reference["datasets"].values()]
    lo = max(T0, max(d[:, 0].min() for d in datas))
    hi = min(T1, min(d[:, 0].max() for d in datas))
    grid = np.linspace(lo, hi, 9)
    cur = np.array([np.interp(grid, d[:, 0], d[:, 1]) for d in datas])
    metrics["datasets_spread_max_rel"] = float(((cur.max(0) - cur.min(0)) / cur.mean(0)).max())
    allerr = np.concatenate(list(errs.values()))
    metrics["front_mean_rel_err_all"] = float(np.mean(allerr))
    metrics["front_rms_rel_err_all"] = float(np.sqrt(np.mean(allerr ** 2)))
    # residual column height at the back wall, H/a (initial 2): reported, no shipped data yet
    for Tq in (1.0, 2.0):
        metrics[f"column_height_at_T{Tq:g}"] = float(np.interp(Tq, Ts, Hs))
    series["sphgraph (column height H/a)"] = (Ts, Hs, "--")
    notes = [f"T = t*sqrt(2g/a), window {T0}-{T1}; datasets: "
             + ", ".join(f"{k} = {v}" for k, v in case.reference["datasets"].items()),
             "column height H/a = highest fluid particle with x < 0.1a: reported only (the shipped "
             "dam-break files hold the surge front Z/a only)"]
    return metrics, series, {"steps": sim.step_count, "particles": sim.n_total}, notes


def run_hydrostatic(case, dp, prm, backend, precision, overrides):
    """Still water: pressure profile against rho g (z_s - z), and the force on the tank against
    the fluid's weight, averaged over [t_avg0, end]."""
    from ..probes import ProbeSampler
    scene = scene_for(case, dp, overrides, boundary=prm.get("boundary"), end_time=float(prm["end_time"]))
    sim = _sim(scene, backend, precision, boundary=prm.get("boundary", "dbc"))
    rho0 = scene.physics.rho0
    H = scene.hswl
    zs = scene.surface_level()
    spec = {"interval": 0.0, "points": [], "heights": [], "force_interval": 0.0,
            "bodies": [("tank", np.array(scene.domain_min), np.array(scene.domain_max))]}
    sampler = ProbeSampler(scene, spec)
    t_avg0 = float(prm["t_avg0"])
    errs, vmax, fy = [], 0.0, []
    weight = sim.n_fluid * scene.constants.mass_fluid * G
    k = 0
    while sim.time < scene.end_time - 1e-12:
        _step(sim, scene.end_time)
        k += 1
        if sim.time >= t_avg0 and k % int(prm.get("every", 20)) == 0:
            a = sim.frame_arrays()
            fl = a["kind"] == 0
            z = a["position"][fl, -1]
            exact = rho0 * G * (zs - z)
            deep = z < zs - 2 * dp      # the surface rows have half a kernel: left out
            errs.append((a["pressure"][fl][deep] - exact[deep]) / (rho0 * G * H))
            vmax = max(vmax, float(np.sqrt((a["velocity"][fl] ** 2).sum(1)).max()) / math.sqrt(G * H))
            sampler.sample(sim)
            down = scene.constants.gravity / np.linalg.norm(scene.constants.gravity)
            fy.append(float(sampler.rows["forces"][-1]["tank"] @ down))
    e = np.mean(errs, axis=0)
    a = sim.frame_arrays()
    fl = a["kind"] == 0
    z = a["position"][fl, -1]
    metrics = {"pressure_rms_err_rel_rhogH": float(np.sqrt((e ** 2).mean())),
               "pressure_max_abs_err_rel_rhogH": float(np.abs(e).max()),
               "max_speed_rel_sqrt_gH": vmax,
               "tank_force_rel_weight_minus_1": float(np.mean(fy) / weight - 1.0)}
    order = np.argsort(z)
    series = {"sphgraph p/(rho g H)": (z[order] / H, a["pressure"][fl][order] / (rho0 * G * H), "."),
              "analytic rho g (z_s - z)": (np.array([0, zs / H]), np.array([zs / H, 0]), "-")}
    notes = [f"averaged over t in [{t_avg0}, {scene.end_time}] s; top 2 dp excluded from the norms",
             "force on the tank = pressure force of the fluid on every boundary particle (sphgraph.probes)"]
    return metrics, series, {"steps": sim.step_count, "particles": sim.n_total}, notes


def run_wall_pressure(case, dp, prm, backend, precision, overrides):
    """Buchner (2002) 2D dam break: pressure on the far wall at 0.2H against the experiment."""
    from ..probes import ProbeSampler
    H = float(prm["H"])
    scale = math.sqrt(G / H)                       # T = t sqrt(g/H) (checked: see docs/validation.md)
    scene = scene_for(case, dp, overrides, boundary=prm.get("boundary"), end_time=float(prm["T_end"]) / scale)
    # the far wall snaps to the nearest lattice plane: put the probe on that plane
    L = float(prm["L"])
    ox = float(scene.lattice_origin[0])
    xw = ox + round((L - ox) / dp) * dp
    pprobe = np.array([xw - float(prm.get("probe_offset_dp", 0.0)) * dp, float(prm["probe_y"])])
    spec = {"interval": float(prm["dT"]) / scale, "points": [("P1", pprobe)], "heights": [],
            "force_interval": 0.0, "bodies": []}
    sampler = ProbeSampler(scene, spec)
    sim = _sim(scene, backend, precision, boundary=prm.get("boundary", "dbc"))
    rho0 = scene.physics.rho0
    while sim.time < scene.end_time - 1e-12:
        _step(sim, scene.end_time)
        sampler.sample(sim)
    t, p = sampler.series("P1", "pressure")
    T, P = t * scale, p / (rho0 * G * H)
    data, header = load(case.reference["dataset"])
    data = data[np.argsort(data[:, 0])]
    thr = float(prm["impact_threshold"])
    dT = float(prm["dT"])

    def running_mean(x, window_T):
        k = max(1, int(round(window_T / dT)))
        return np.convolve(x, np.ones(k) / k, mode="same")

    Ps = running_mean(P, float(prm.get("smooth_T", 0.05)))      # WCSPH pressure noise
    Pl = running_mean(P, float(prm.get("smooth_post_T", 0.25)))  # for the post-impact levels
    hit = np.nonzero(Ps > thr)[0]
    T_imp = float(T[hit[0]]) if len(hit) else math.inf
    T_imp_data = float(data[np.nonzero(data[:, 1] > thr)[0][0], 0])
    metrics = {}
    pre = data[data[:, 0] < T_imp_data - 0.1]
    e = np.interp(pre[:, 0], T, P) - pre[:, 1]
    metrics["pre_impact_rms_err"] = float(np.sqrt((e ** 2).mean()))
    metrics["pre_impact_data_rms"] = float(np.sqrt((pre[:, 1] ** 2).mean()))
    metrics["impact_T"] = T_imp
    metrics["impact_T_data"] = T_imp_data
    metrics["impact_T_err"] = T_imp - T_imp_data
    post = data[(data[:, 0] >= T_imp_data + 0.2) & (data[:, 0] <= T[-1])]
    if len(post):
        e = np.interp(post[:, 0], T, Pl) - post[:, 1]
        metrics["post_impact_rms_err"] = float(np.sqrt((e ** 2).mean()))
        metrics["post_impact_mean_err"] = float(e.mean())
    plateau = data[(data[:, 0] >= 3.0) & (data[:, 0] <= 5.5)]
    if len(plateau) and T[-1] >= 5.5:
        m = (T >= 3.0) & (T <= 5.5)
        metrics["plateau_p_rel_rhogH"] = float(P[m].mean())
        metrics["plateau_p_data"] = float(plateau[:, 1].mean())
    metrics["peak_p_rel_rhogH"] = float(P.max())
    metrics["peak_p_smoothed_rel_rhogH"] = float(Ps.max())
    # the first peak: the largest running mean (T smooth_T) within first_peak_T after each
    # series' own impact (same threshold), the data's max over the same window after theirs
    w = float(prm.get("first_peak_T", 0.5))
    if math.isfinite(T_imp):
        m = (T >= T_imp) & (T <= T_imp + w)
        d = data[(data[:, 0] >= T_imp_data) & (data[:, 0] <= T_imp_data + w)]
        metrics["first_peak_smoothed_rel_rhogH"] = float(Ps[m].max())
        metrics["first_peak_data"] = float(d[:, 1].max())
        metrics["first_peak_rel_err"] = metrics["first_peak_smoothed_rel_rhogH"] / metrics["first_peak_data"] - 1.0
    if "plateau_p_rel_rhogH" in metrics:
        metrics["plateau_rel_err"] = metrics["plateau_p_rel_rhogH"] / metrics["plateau_p_data"] - 1.0
    series = {"sphgraph P1": (T, P, "-"),
              f"sphgraph P1, running mean over T {prm.get('smooth_post_T', 0.25)}": (T, Pl, "-"),
              "Buchner 2002 (exp.)": (data[:, 0], data[:, 1], "o")}
    notes = [f"probe at x = {pprobe[0]:.4f} ({prm.get('probe_offset_dp', 0)} dp off the wall plane), "
             f"y = {pprobe[1]:.4f} m; T = t*sqrt(g/H)",
             f"impact = first T with the running mean (T {prm.get('smooth_T', 0.05)}) of p/(rho g H) > {thr}, "
             f"same threshold on the data; post-impact norms use the running mean over T {prm.get('smooth_post_T', 0.25)}; "
             "plateau = mean over T 3-5.5"]
    return metrics, series, {"steps": sim.step_count, "particles": sim.n_total}, notes


def run_body_force(case, dp, prm, backend, precision, overrides):
    """Force of the flow on a named body (`[forces]` sampler) against a measured force history."""
    from ..probes import ProbeSampler
    scene = scene_for(case, dp, overrides, boundary=prm.get("boundary"), end_time=float(prm["t_end"]),
                      layers=prm.get("layers"))
    lo, hi = np.array(prm["body_min"], float), np.array(prm["body_max"], float)
    spec = {"interval": 0.0, "points": [], "heights": [], "force_interval": float(prm["dt_sample"]),
            "bodies": [("body", lo, hi)]}
    sampler = ProbeSampler(scene, spec)
    sim = _sim(scene, backend, precision, boundary=prm.get("boundary", "dbc"))
    _run_sampled(sim, [sampler], scene.end_time)
    t, F = sampler.series("body", "force")
    comp = int(prm.get("component", 0))
    f = F[:, comp]
    k = max(1, int(round(float(prm.get("smooth_t", 0.02)) / float(prm["dt_sample"]))))
    fs = np.convolve(f, np.ones(k) / k, mode="same")
    data, header = load(case.reference["dataset"])
    data = data[np.argsort(data[:, 0])]
    w = data[(data[:, 0] >= 0.0) & (data[:, 0] <= t[-1])]
    scale = float(np.abs(w[:, 1]).max())
    e = np.interp(w[:, 0], t, fs) - w[:, 1]
    i_d = int(np.argmax(w[:, 1]))
    i_s = int(np.argmax(fs))
    metrics = {"force_rms_err_rel_peak": float(np.sqrt((e ** 2).mean()) / scale),
               "force_mean_err_rel_peak": float(e.mean() / scale),
               "peak_force_N": float(fs[i_s]), "peak_force_data_N": float(w[i_d, 1]),
               "peak_force_rel_err": float(fs[i_s] / w[i_d, 1] - 1.0),
               "peak_time_s": float(t[i_s]), "peak_time_data_s": float(w[i_d, 0]),
               "peak_time_err_s": float(t[i_s] - w[i_d, 0])}
    # arrival: first time the (smoothed) force passes a fraction of the measured peak
    thr = float(prm.get("arrival_fraction", 0.3)) * scale
    ta = t[np.nonzero(fs > thr)[0]]
    td = w[np.nonzero(w[:, 1] > thr)[0], 0]
    metrics["arrival_time_s"] = float(ta[0]) if len(ta) else math.inf
    metrics["arrival_time_data_s"] = float(td[0])
    metrics["arrival_time_err_s"] = metrics["arrival_time_s"] - metrics["arrival_time_data_s"]
    after = w[(w[:, 0] >= td[0] + 0.1)]
    e2 = np.interp(after[:, 0], t, fs) - after[:, 1]
    metrics["after_impact_rms_err_rel_peak"] = float(np.sqrt((e2 ** 2).mean()) / scale)
    # the error in newtons over a fixed window of the measured history, with no time shift
    # (params.rms_window; default: the whole compared history)
    w0, w1 = (float(x) for x in prm.get("rms_window", (w[0, 0], w[-1, 0])))
    win = w[(w[:, 0] >= w0) & (w[:, 0] <= w1)]
    e3 = np.interp(win[:, 0], t, fs) - win[:, 1]
    metrics["force_rms_err_N"] = float(np.sqrt((e3 ** 2).mean())) if len(win) else math.inf
    series = {"sphgraph F_x (raw)": (t, f, "-"), f"sphgraph F_x, running mean {k * float(prm['dt_sample']):g} s":
              (t, fs, "-"), "experiment": (data[:, 0], data[:, 1], "o")}
    notes = [f"body: boundary particles in {list(lo)} - {list(hi)}; pressure force of the fluid "
             "(sphgraph.probes); component " + "xyz"[comp]]
    return metrics, series, {"steps": sim.step_count, "particles": sim.n_total}, notes


def height_metrics(prm, data, heights, t_end):
    """The water-height case's metrics from sampled heights ({gauge: (t, h)}, h above the floor)
    against the data's columns at the data's times up to t_end, no time shift: RMS and mean error
    a gauge, the arrival of each gauge dry at the start, and the RMS over all relative to h0.
    Also scores stored series over a shorter window (benchmarks/spheric2_heights.py --rescore)."""
    w = data[data[:, 0] <= t_end + 1e-12]
    h0 = float(prm["h0"])
    thr = float(prm.get("arrival_h", 0.02))
    metrics, sq = {}, []
    for g in prm["gauges"]:
        name, col = str(g[0]), int(g[3])
        t, h = (np.asarray(a, float) for a in heights[name])
        hd = w[:, col]
        e = np.interp(w[:, 0], t, h) - hd
        metrics[f"height_rms_err_m_{name}"] = float(np.sqrt((e ** 2).mean()))
        metrics[f"height_mean_err_m_{name}"] = float(e.mean())
        sq.append(float((e ** 2).mean()))
        if hd[0] < thr:        # a gauge dry at the start: the front's arrival there
            ts = t[np.nonzero(h > thr)[0]]
            td = w[np.nonzero(hd > thr)[0], 0]
            if len(td):
                metrics[f"arrival_s_{name}"] = float(ts[0]) if len(ts) else math.inf
                metrics[f"arrival_data_s_{name}"] = float(td[0])
                metrics[f"arrival_err_s_{name}"] = metrics[f"arrival_s_{name}"] - float(td[0])
    metrics["height_rms_err_rel_h0_all"] = float(np.sqrt(np.mean(sq)) / h0)
    return metrics


def run_water_heights(case, dp, prm, backend, precision, overrides):
    """Water height gauges (`[probes] heights`) against measured height histories, one dataset
    column a gauge, compared at the data's times with no time shift; with `[params] sensors`,
    also pressure sensors on a body's faces against `[reference] pressures`
    (sphgraph.validation.sensors), sampled every `dt_sample_p` s by a second sampler."""
    from ..probes import ProbeSampler
    from .sensors import sensor_points
    scene = scene_for(case, dp, overrides, boundary=prm.get("boundary"), end_time=float(prm["t_end"]),
                      layers=prm.get("layers"))
    gauges = prm["gauges"]                         # [[name, x, y, data column], ...]
    spec = {"interval": float(prm["dt_sample"]), "points": [], "bodies": [], "force_interval": 0.0,
            "heights": [(str(g[0]), np.array(g[1:3], float)) for g in gauges]}
    samplers = [ProbeSampler(scene, spec)]
    sim = _sim(scene, backend, precision, boundary=prm.get("boundary", "dbc"))
    points = []
    if prm.get("sensors"):
        a = _arrays(sim)
        points = sensor_points(prm, np.asarray(a["position"]), np.asarray(a["kind"]), dp)
        samplers.append(ProbeSampler(scene, {"interval": float(prm["dt_sample_p"]), "points": points,
                                             "heights": [], "bodies": [], "force_interval": 0.0}))
    try:
        _run_sampled(sim, samplers, scene.end_time)
    except NumericalError as e:     # the heights up to the stop, scored up to the last sample
        last = float(samplers[0].series(str(gauges[0][0]), "height")[0][-1])
        raise CaseStopped(e, _heights_result(case, prm, samplers, points, sim, last)) from e
    return _heights_result(case, prm, samplers, points, sim, sim.time)


def _heights_result(case, prm, samplers, points, sim, t_end):
    """run_water_heights' (metrics, series, stats, notes) from what was sampled up to t_end."""
    from .sensors import pressure_metrics, pressure_note, pressure_series
    gauges = prm["gauges"]
    floor = float(prm.get("floor", 0.0))
    data, _ = load(case.reference["dataset"])
    h0 = float(prm["h0"])
    thr = float(prm.get("arrival_h", 0.02))
    series = {}
    for g in gauges:
        name, col = str(g[0]), int(g[3])
        t, z = samplers[0].series(name, "height")
        # a column with no fluid over it reads the domain's floor (sphgraph.probes): the tank
        # floor's height is the gauge's zero
        series[f"sphgraph {name}"] = (t, np.maximum(z - floor, 0.0), "-", name)
        series[f"experiment {name} (x = {g[1]})"] = (data[:, 0], data[:, col], ".", name)
    metrics = height_metrics(prm, data, {str(g[0]): series[f"sphgraph {g[0]}"][:2] for g in gauges}, t_end)
    w = data[data[:, 0] <= t_end + 1e-12]
    notes = [f"gauges (name, x, y): {', '.join(f'{g[0]} ({g[1]}, {g[2]})' for g in gauges)}; height = highest "
             "point of the vertical line where the fluid's kernel sum reaches 0.5 (sphgraph.probes), less the "
             f"floor at z = {floor}; sampled every {prm['dt_sample']} s, compared at the data's times over "
             f"0-{w[-1, 0]:.2f} s; arrival = first time above {thr} m; rel_h0: over the initial depth {h0} m"]
    if points:
        pdata, _ = load(case.reference["pressures"])
        sampled = {name: samplers[1].series(name, "pressure") for name, _ in points}
        metrics.update(pressure_metrics(prm, pdata, sampled, t_end, sim.scene.physics.rho0))
        series.update(pressure_series(prm, pdata, points, sampled))
        notes.append(pressure_note(prm))
    return metrics, series, {"steps": sim.step_count, "particles": sim.n_total}, notes


# --------------------------------------------------------------------------- Poiseuille
def poiseuille_u(y, t, F, nu, H, nterms=60):
    """Start-up of plane Poiseuille flow between walls at y = 0 and y = H driven by a body
    force F from rest (Morris, Fox & Zhu 1997, J. Comput. Phys. 136:214-226, eq. 21,
    doi:10.1006/jcph.1997.5776)."""
    y = np.asarray(y, float)
    u = F / (2 * nu) * y * (H - y)
    for n in range(nterms):
        k = 2 * n + 1
        u -= 4 * F * H * H / (nu * math.pi ** 3 * k ** 3) * np.sin(math.pi * y * k / H) * math.exp(
            -k * k * math.pi ** 2 * nu * t / (H * H))
    return u


def periodic_tasks(L: float, x0: float = 0.0):
    """User tasks that make the x axis periodic with period L on one rank.

    `periodic_image` (per force stage, after the interior forces): the rows within reach of
    either end, shifted by -/+L, become a halo (`state.halos[1]`) whose forces are summed
    like any other part (`compute.forces(state, "halo_1")`, reduced in the fixed order).
    `periodic_wrap` (after the last integrate): positions back into [x0, x0 + L).
    Shared kernels are untouched.
    """
    from ..graph.task import UserTask
    from ..state import Halo

    def image(ctx, task):
        st = ctx.state
        p = st.particles
        reach = 2.0 * st.consts.h * 1.05
        x = p.pos[:, 0]
        lo = x < x0 + reach
        hi = x > x0 + L - reach
        idx = np.concatenate([np.nonzero(lo)[0], np.nonzero(hi)[0]])
        shift = np.concatenate([np.full(lo.sum(), L), np.full(hi.sum(), -L)])
        pos = p.pos[idx].copy()
        pos[:, 0] += shift
        halo = Halo(pos=pos, vel=p.vel[idx].copy(), rho=p.rho[idx].copy(), kind=p.kind[idx].copy())
        ctx.compute.prepare_halo(st, halo)
        st.halos[1] = halo
        ctx.compute.forces(st, "halo_1")

    def wrap(ctx, task):
        p = ctx.state.particles
        p.pos[:, 0] = x0 + np.mod(p.pos[:, 0] - x0, L)

    return [UserTask("periodic_image", image, reads=("particles", "cells"), accumulates=("forces@1",),
                     per_stage=True),
            UserTask("periodic_wrap", wrap, reads=("particles",), writes=("particles",))]


def periodic_schedule():
    order = ["build_cells", "forces_interior", "periodic_image", "dt_local", "dt_allreduce", "integrate",
             "periodic_wrap"]
    return {"format": 1, "description": "one rank, x periodic (validation)", "order": order}


def poiseuille_scene(case, dp, prm, overrides):
    H, nu, F = float(prm["H"]), float(prm["nu"]), float(prm["F"])
    nx = int(prm.get("nx", 8))
    L = nx * dp
    ncol = int(round(H / dp))
    layers = 3
    c0 = float(prm["c0"])
    phys = {"gravity": [F, 0.0], "laminar_nu": nu, "visc_alpha": 0.0, "diffusion": "molteni",
            "integrator": "symplectic", "hswl": H, "coefsound": c0 / math.sqrt(F * H), "rho_min": 900.0, "rho_max": 1100.0}
    phys.update(case.scene.get("physics", {}))
    phys.update(overrides)
    d = {"format": 1, "name": "poiseuille", "dim": 2, "dp": dp, "end_time": float(prm["t_end"]),
         "domain": {"min": [-L, -(layers + 1) * dp], "max": [2 * L, H + (layers + 1) * dp],
                    "origin": [0.0, 0.5 * dp]},
         "physics": phys,
         # fluid rows at y = dp/2 .. H - dp/2, walls' first rows at -dp/2 and H + dp/2: walls at 0 and H
         "fluid": [{"type": "box", "min": [0.0, 0.5 * dp], "max": [L - dp, H - 0.5 * dp]}],
         "boundary": [{"type": "wall", "min": [0.0, -0.5 * dp], "max": [L - dp, -0.5 * dp], "layers": layers,
                       "direction": "-"},
                      {"type": "wall", "min": [0.0, H + 0.5 * dp], "max": [L - dp, H + 0.5 * dp],
                       "layers": layers, "direction": "+"}]}
    from ..scene import Scene
    return Scene.from_dict(d, source=f"case {case.name}"), L


def poiseuille_error(case, dp, prm, backend, precision, overrides):
    scene, L = poiseuille_scene(case, dp, prm, overrides)
    sim = _sim(scene, backend, precision, boundary=prm.get("boundary", "dbc"), schedule=periodic_schedule(),
               user_tasks=periodic_tasks(L))
    while sim.time < scene.end_time - 1e-12:
        _step(sim, scene.end_time)
    p = _fluid(sim)
    fl = p.kind == 0
    y, u = p.pos[fl, 1], p.vel[fl, 0]
    H, nu, F = float(prm["H"]), float(prm["nu"]), float(prm["F"])
    ue = poiseuille_u(y, sim.time, F, nu, H)
    umax = float(poiseuille_u(np.array([H / 2]), sim.time, F, nu, H)[0])
    err = float(np.sqrt(((u - ue) ** 2).mean()) / umax)
    # the same flow with the no-slip walls on the first boundary rows (channel H + dp wide):
    # how much of the error is the dynamic-boundary wall offset
    ub = poiseuille_u(y + 0.5 * dp, sim.time, F, nu, H + dp)
    sim.err_walls_on_rows = float(np.sqrt(((u - ub) ** 2).mean()) / umax)
    return err, (y, u, ue), sim


def run_poiseuille(case, dp, prm, backend, precision, overrides):
    """Body-force-driven start-up flow between plates, x periodic: L2 error of u(y) at t_end
    against the series solution, at dp and at the coarser resolutions of `refine` -> order."""
    H = float(prm["H"])
    ratios = prm.get("refine", [2.0, 1.0])        # dp * r for each r: coarser first
    dps = [dp * r for r in ratios]
    errs, steps, npart = [], 0, 0
    last = None
    for d in dps:
        e, prof, sim = poiseuille_error(case, d, prm, backend, precision, overrides)
        errs.append(e)
        shifted = sim.err_walls_on_rows
        steps += sim.step_count
        npart = sim.n_total
        last = (prof, sim.time)
    metrics = {"u_l2_err_rel_umax": errs[-1], "u_l2_err_if_walls_on_boundary_rows": shifted}
    for d, e in zip(dps, errs):
        metrics[f"u_l2_err_at_H/dp={H / d:.0f}"] = e
    if len(dps) > 1:
        k = np.polyfit(np.log(dps), np.log(errs), 1)[0]
        metrics["convergence_order"] = float(k)
    (y, u, ue), t = last
    order = np.argsort(y)
    series = {"sphgraph u(y)": (y[order] / H, u[order], "."), f"analytic (t = {t:.3g} s)": (y[order] / H, ue[order], "-")}
    notes = [f"F = {prm['F']} m/s^2, nu = {prm['nu']} m^2/s, H = {H} m, t = {prm['t_end']} s "
             f"(nu t/H^2 = {float(prm['nu']) * float(prm['t_end']) / H ** 2:.2f}); walls midway between "
             "the first fluid and boundary rows; dp = " + ", ".join(f"{d:.3g}" for d in dps)]
    return metrics, series, {"steps": steps, "particles": npart}, notes


RUNNERS = {"surge_front": run_surge_front, "hydrostatic": run_hydrostatic, "body_force": run_body_force,
           "wall_pressure": run_wall_pressure, "poiseuille": run_poiseuille, "water_heights": run_water_heights}
