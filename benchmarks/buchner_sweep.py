"""Buchner wall pressure: formulations x resolutions against the sensor (issue 22 §3).

    python benchmarks/buchner_sweep.py --backend numba-cuda --precision float64 \\
        --dp-fractions 80 --variants all --timeout-per-run 120 --json $OUT/buchner_sweep_80.json
    python benchmarks/buchner_sweep.py --backend numba-cuda --precision float64 \\
        --dp-fractions 120 --variants all --timeout-per-run 150 --json $OUT/buchner_sweep_120.json
    python benchmarks/buchner_sweep.py --list                       # the variants table
    python benchmarks/buchner_sweep.py --estimate --dp-fractions 80 120  # particles, steps (no run)

Each run is `sphgraph validate buchner --dp H/N [--set KEY=VALUE ...] [--boundary B]`, called
in-process through the same API (`sphgraph.validation.cases.run_case`, the overrides parsed by
the CLI's own `_overrides`), so one process compiles the kernels once per configuration and
the metrics are the case's own, unchanged: plateau = mean of the raw P1 samples over T 3-5.5
(data 0.547), first peak = largest running mean over T 0.05 within T 0.5 after the series' own
impact (data 0.691), etc. (docs/validation.md, "Buchner wall pressure: formulations against
the sensor"). Targets: |plateau error| <= 15 %, |first-peak error| <= 25 %.

Runs go resolution by resolution (every variant at the first N, then the next N), so a call cut
off by a time limit leaves the coarser set complete. One JSON line per run on stdout as it
finishes (`flush`), and `--json OUT` rewritten after every run (with the raw P1 series of each
run, also of the runs that stopped: up to where they stopped). A run that fails numerically
(NumericalError: NaN, a particle out of the domain, density bounds), exceeds
`--timeout-per-run` (checked between steps) or is killed (SIGTERM, e.g. `timeout`) is recorded
with its failure, the T it reached and its steps, and the sweep goes on (killed: stops after
writing).

Not in the table: delta-SPH density diffusion (or artificial viscosity) with the Riemann term --
`config.derive` switches the diffusion term off whenever `riemann` is set (the Riemann pair has
its own density dissipation, and `forces_riemann` / cuda_riemann add no viscosity), so
`--set diffusion=... --set delta=...` beside zhang2017 would repeat the zhang run.

Steps to T 7.4 scale with N (dt ~ h/c0, c0 fixed by H): ~42,300 at H/80 (15,542 particles) and
~63,500 at H/120 (32,907) for every variant (docs/validation.md: 20,944-21,065 at H/40, 42,317 /
42,870 at H/80); `--estimate` prints them. DualSPHysics' Verlet run (`dsph`) stopped at H/80 on
numba-cpu (step 30,317), which the sweep records as its failure.

`--T-end` shortens the case (its `params.T_end`, the run length only): for smoke checks; the
plateau (needs T >= 5.5) and the first peak (needs an impact) are then absent.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path


CASE = "buchner"
H = 0.6                      # the case's params.H (checked against the case file at start)
TARGET = {"plateau": 0.15, "first_peak": 0.25}

ZHANG = ("integrator=symplectic", "riemann=zhang2017")
# name: (--set KEY=VALUE items, --boundary or None, what it is)
VARIANTS = {   # in run order: the Riemann family first, DualSPHysics' references last
    "zhang": (ZHANG, None, "riemann = zhang2017 (limiter eta 3, the default), Symplectic"),
    "zhang-eta1": (ZHANG + ("riemann_eta=1.0",), None, "zhang2017, Symplectic, weaker limiter eta 1 (1/3 of the "
                                                         "default's P* dissipation)"),
    "zhang-eta0.3": (ZHANG + ("riemann_eta=0.3",), None, "zhang2017, Symplectic, limiter eta 0.3 (1/10)"),
    "zhang-mdbc": (ZHANG, "mdbc", "zhang2017, Symplectic, mDBC walls (free slip)"),
    "zhang-eta1-mdbc": (ZHANG + ("riemann_eta=1.0",), "mdbc", "zhang2017, Symplectic, eta 1, mDBC walls"),
    "zhang-eta0.3-mdbc": (ZHANG + ("riemann_eta=0.3",), "mdbc",
                          "zhang2017, Symplectic, eta 0.3, mDBC walls (the weakest limiter raised the plateau, "
                          "mDBC walls the first peak: both together)"),
    "zhang-eta0.3-mdbc-cancel": (ZHANG + ("riemann_eta=0.3", "riemann_wall=cancel"), "mdbc",
                                 "the same, the walls cancelling the Riemann term's density dissipation of the "
                                 "rows next to them (holds fast impacts on mDBC walls)"),
    "zhang-eta0.3-mdbc-renorm": (ZHANG + ("riemann_eta=0.3", "riemann_jump=renormalised"), "mdbc",
                                 "the same with the walls adding no jump and every fluid row's jump without its "
                                 "linear part (riemann_jump = renormalised: holds fast impacts, keeps dissipation)"),
    "zhang-eta0.3-mdbc-renorm-cancel": (ZHANG + ("riemann_eta=0.3", "riemann_jump=renormalised", "riemann_wall=cancel"),
                                        "mdbc", "the renormalised jump, the walls cancelling the jump of the rows it "
                                        "cannot renormalise"),
    "zhang-shift": (ZHANG + ("shifting=nobound", "shifting_tfs=1.5"), None,
                    "zhang2017, Symplectic, particle shifting (Lind et al.; nobound, free-surface threshold 1.5)"),
    "dsph-df": (("diffusion_time=dufort-frankel",), None,
                "DualSPHysics' terms, DuFort-Frankel diffusion step (the doc's H/80 row; the Verlet leapfrog "
                "stops at H/80)"),
    "dsph": ((), None,
             "the case as is: DualSPHysics' formulation (Verlet, Wendland, alpha 0.02, Fourtakas delta 0.1, DBC); "
             "stopped at H/80 on numba-cpu (step 30,317)"),
}

# docs/validation.md, H/40 and H/80 (2-core VM): steps to T 7.4. dt ~ h/c0 with c0 fixed by H, so
# steps ~ N; DualSPHysics' Verlet run stops at H/80 (step 30,317, t = 1.313 s).
STEPS_KNOWN = {"dsph": (40, 21065), "dsph-df": (80, 42870), "zhang": (80, 42317)}   # (N, steps)


class RunTimeout(Exception):
    pass


class Killed(BaseException):
    pass


TERM = []   # the signals received (SIGTERM): the run stops at its next step boundary


def on_term(signum, frame):
    """First SIGTERM: flag it (Watch raises Killed after the current step, outside any
    compiled call); a second one raises at once."""
    TERM.append(signum)
    if len(TERM) > 1:
        raise Killed(f"signal {signum} (twice)")


class Watch:
    """Observes the runner without changing it: `ProbeSampler.sample` is called after every
    step of `run_wall_pressure`; the wrapper keeps the sampler and the simulation (for a run
    that stops: the T reached, steps, the series so far), times the first step (set-up and
    compilation) and enforces the per-run time limit between steps."""

    def __init__(self):
        from sphgraph import probes
        self.sim = self.sampler = None
        self.t0 = self.first = None
        self.limit = None
        orig = probes.ProbeSampler.sample
        watch = self

        def sample(sampler, sim):
            if watch.first is None and watch.t0 is not None:
                watch.first = time.perf_counter() - watch.t0
            watch.sim, watch.sampler = sim, sampler
            out = orig(sampler, sim)
            if TERM:
                raise Killed(f"signal {TERM[0]} at step {sim.step_count}")
            if watch.limit is not None and time.perf_counter() - watch.t0 > watch.limit:
                raise RunTimeout(f"past --timeout-per-run {watch.limit:g} s at step {sim.step_count}")
            return out

        probes.ProbeSampler.sample = sample

    def start(self, limit):
        self.sim = self.sampler = None
        self.first = None
        self.limit = limit
        self.t0 = time.perf_counter()


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def validate_cmd(n, items, boundary, backend, precision, t_end):
    parts = ["sphgraph validate", CASE, f"--dp {H / n:.10g}", f"--backend {backend}"]
    if precision:
        parts.append(f"--precision {precision}")
    parts += [f"--set {s}" for s in items]
    if boundary:
        parts.append(f"--boundary {boundary}")
    if t_end is not None:
        parts.append(f"(T_end {t_end:g})")
    return " ".join(parts)


def run_one(name, n, a, watch):
    from sphgraph.cli import _overrides
    from sphgraph.validation.cases import run_case
    items, boundary, _ = VARIANTS[name]
    dp = H / n
    params = {}
    if boundary:
        params["boundary"] = boundary
    if a.T_end is not None:
        params["T_end"] = a.T_end
    rec = {"variant": name, "overrides": list(items), "boundary": boundary or "dbc", "N": n, "dp": dp,
           "backend": a.backend, "precision": a.precision or "default",
           "cmd": validate_cmd(n, items, boundary, a.backend, a.precision, a.T_end)}
    out = None
    if a.plots:
        out = str(Path(a.plots) / f"{name}_H{n:g}")
    watch.start(a.timeout_per_run)
    res, err = None, None
    try:
        res = run_case(CASE, dp=dp, backend=a.backend, precision=a.precision, overrides=_overrides(list(items)),
                       out=out, plot=bool(a.plots), params=params or None)
    except Killed as e:
        err = e
    except Exception as e:  # noqa: BLE001  a run that fails is recorded, the sweep goes on
        err = e
    wall = time.perf_counter() - watch.t0
    if TERM and err is not None and not isinstance(err, Killed):   # whatever the signal interrupted
        err = Killed(f"signal {TERM[0]} ({type(err).__name__}: {err})")
    sim = watch.sim
    scale = math.sqrt(9.81 / H)
    rec["wall_s"] = wall
    rec["first_step_s"] = watch.first          # set-up, compilation and the first step
    if res is not None:
        m = res.metrics
        rec.update(particles=res.particles, steps=res.steps, reached_end=True, failure=None)
        rec["T_reached"] = _num(sim.time * scale) if sim is not None else None
        rec.update(
            impact_T=_num(m.get("impact_T")), impact_T_err=_num(m.get("impact_T_err")),
            plateau=_num(m.get("plateau_p_rel_rhogH")), plateau_data=_num(m.get("plateau_p_data")),
            plateau_rel_err=_num(m.get("plateau_rel_err")),
            first_peak=_num(m.get("first_peak_smoothed_rel_rhogH")), first_peak_data=_num(m.get("first_peak_data")),
            first_peak_rel_err=_num(m.get("first_peak_rel_err")),
            largest_raw=_num(m.get("peak_p_rel_rhogH")), post_impact_rms=_num(m.get("post_impact_rms_err")),
            pre_impact_rms=_num(m.get("pre_impact_rms_err")), case_tolerances_ok=bool(res.ok))
        pe, fe = rec["plateau_rel_err"], rec["first_peak_rel_err"]
        rec["within_target"] = {"plateau": pe is not None and abs(pe) <= TARGET["plateau"],
                                "first_peak": fe is not None and abs(fe) <= TARGET["first_peak"]}
        rec["within_target"]["both"] = rec["within_target"]["plateau"] and rec["within_target"]["first_peak"]
        rec["metrics"] = {k: _num(v) for k, v in m.items()}
        T, P, _ = res.series["sphgraph P1"]
    else:
        rec.update(particles=getattr(sim, "n_total", None), steps=getattr(sim, "step_count", None),
                   reached_end=False, failure=f"{type(err).__name__}: {err}".strip(),
                   T_reached=_num(sim.time * scale) if sim is not None else None)
        if not isinstance(err, (RunTimeout, Killed)) and not type(err).__name__ == "NumericalError":
            rec["traceback"] = traceback.format_exception(type(err), err, err.__traceback__)[-6:]
        T = P = None
        if watch.sampler is not None:
            try:
                t, p = watch.sampler.series("P1", "pressure")
                T, P = t * scale, p / (1000.0 * 9.81 * H)
            except (KeyError, IndexError):
                pass
    if rec.get("steps") and watch.first is not None and wall > watch.first and rec["steps"] > 1:
        rec["steps_per_s"] = (rec["steps"] - 1) / (wall - watch.first)
    series = None if T is None else {"T": [float(x) for x in T], "p": [float(x) for x in P]}
    return rec, series, err


def estimate(ns, variants):
    from sphgraph.validation.cases import load_case, scene_for
    case = load_case(CASE)
    rows = []
    for n in ns:
        scene = scene_for(case, H / n, {}, end_time=float(case.params["T_end"]) / math.sqrt(9.81 / H))
        nf, nb = scene.count_particles()
        for v in variants:
            n0, steps0 = STEPS_KNOWN.get(v, STEPS_KNOWN["zhang"])
            rows.append({"variant": v, "N": n, "dp": H / n, "particles": nf + nb, "fluid": nf,
                         "steps_estimate": int(round(steps0 * n / n0))})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", choices=["float32", "float64"])
    ap.add_argument("--dp-fractions", type=float, nargs="+", default=[80.0, 120.0], metavar="N",
                    help="dp = H/N for each N (H = 0.6 m; the case's default is 40)")
    ap.add_argument("--variants", nargs="+", default=["all"], metavar="NAME", help="names from --list, or all")
    ap.add_argument("--json", help="write every run (with its raw P1 series) here, rewritten after each run")
    ap.add_argument("--timeout-per-run", type=float, help="seconds; checked between steps")
    ap.add_argument("--T-end", dest="T_end", type=float, help="shorter case (smoke checks; no plateau then)")
    ap.add_argument("--plots", help="directory: the case's comparison PNG per run (needs matplotlib)")
    ap.add_argument("--list", action="store_true", help="print the variants and exit")
    ap.add_argument("--estimate", action="store_true", help="print particles and estimated steps, run nothing")
    a = ap.parse_args(argv)
    if a.list:
        for k, (items, b, what) in VARIANTS.items():
            print(f"{k:16s} {' '.join('--set ' + s for s in items)}{' --boundary ' + b if b else ''}\n"
                  f"{'':16s} {what}")
        return 0
    names = list(VARIANTS) if a.variants == ["all"] else a.variants
    bad = [v for v in names if v not in VARIANTS]
    if bad:
        ap.error(f"--variants: unknown {bad}: expected names from {list(VARIANTS)} or all")
    from sphgraph.validation.cases import load_case
    case = load_case(CASE)
    assert float(case.params["H"]) == H, case.params["H"]
    if a.estimate:
        for r in estimate(a.dp_fractions, names):
            print(json.dumps(r), flush=True)
        return 0

    signal.signal(signal.SIGTERM, on_term)
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10,
                                cwd=Path(__file__).resolve().parents[1]).stdout.strip() or None
    except Exception:  # noqa: BLE001
        commit = None
    device = None
    if a.backend == "numba-cuda":
        try:
            from numba import cuda
            device = cuda.get_current_device().name
            device = device.decode() if isinstance(device, bytes) else str(device)
        except Exception as e:  # noqa: BLE001
            device = f"unknown ({e})"
    meta = {"case": CASE, "backend": a.backend, "precision": a.precision or "default", "N": a.dp_fractions,
            "variants": {k: {"set": list(VARIANTS[k][0]), "boundary": VARIANTS[k][1] or "dbc",
                             "what": VARIANTS[k][2]} for k in names},
            "T_end": a.T_end, "timeout_per_run": a.timeout_per_run, "targets": TARGET, "commit": commit,
            "device": device, "host": os.uname().nodename, "cudasim": os.environ.get("NUMBA_ENABLE_CUDASIM") == "1",
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    print(json.dumps({"meta": meta}), flush=True)
    watch = Watch()
    runs = []
    killed = None

    def write():
        if not a.json:
            return
        p = Path(a.json)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + ".tmp")
        tmp.write_text(json.dumps({"meta": meta, "runs": runs}, indent=1))
        os.replace(tmp, p)

    for n in a.dp_fractions:
        for name in names:
            rec, series, err = run_one(name, n, a, watch)
            print(json.dumps(rec), flush=True)
            runs.append(dict(rec, series=series))
            write()
            if isinstance(err, Killed) or TERM:
                killed = err if isinstance(err, Killed) else Killed(f"signal {TERM[0]} after the run")
            if killed is not None:
                break
        if killed is not None:
            break
    if killed is not None:
        print(json.dumps({"killed": str(killed), "runs_done": len(runs)}), flush=True)
        return 124
    ok = [r for r in runs if r["reached_end"]]
    summary = {"summary": [{"variant": r["variant"], "N": r["N"], "reached_end": r["reached_end"],
                            "plateau_rel_err": r.get("plateau_rel_err"), "first_peak_rel_err": r.get("first_peak_rel_err"),
                            "within_target": r.get("within_target", {}).get("both", False)} for r in runs],
               "runs": len(runs), "reached_end": len(ok)}
    print(json.dumps(summary), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
