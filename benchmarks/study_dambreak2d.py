"""Speed against accuracy for the 2D dam break (issue 7 §3): `sphgraph study dambreak` with a
fixed sweep, chart for the README.

    python benchmarks/study_dambreak2d.py [--fine] [--out out/study/dambreak2d]

Error: RMS of the relative surge-front error against the three experiments together
(Koshizuka & Oka 1996; Martin & Moyce 1952, a = 1.125 in and 2.25 in) for T = t sqrt(2g/a) in
0.5-2.5. Sweep: one factor at a time around DualSPHysics' formulation (Verlet, Wendland,
Fourtakas diffusion, alpha 0.02, float64, numba-cpu) at dp = 0.05, 0.04, 0.03 m (--fine adds
0.02 for the baseline and Symplectic): integrator, kernel, diffusion (molteni, none), precision
(float32), artificial viscosity alpha 0.1. About 5 minutes on 2 loaded cores (10 with --fine).
Writes study.csv and study.png there and copies the PNG to docs/study_dambreak2d.png.
"""
import argparse
import shutil
import sys
from pathlib import Path

from sphgraph.study import configurations, run_study
from sphgraph.validation.cases import load_case

ap = argparse.ArgumentParser()
ap.add_argument("--fine", action="store_true")
ap.add_argument("--out", default="out/study/dambreak2d")
ap.add_argument("--target-error", type=float, default=0.08)
ap.add_argument("--device", action="store_true",
                help="GPU host sweep: numba-cuda (float32/float64, Verlet/Symplectic) down to dp = 0.01 "
                     "against numba-cpu on the host's cores; stops starting runs after --budget s")
ap.add_argument("--budget", type=float, default=480.0)
args = ap.parse_args()

case = load_case("dambreak")
if args.device:
    import csv
    import time
    from sphgraph.study import AXES, FIELDS, baseline, describe, run_one
    base = baseline(case)
    plan = ([dict(base, backend="numba-cuda", precision="float32", dp=d) for d in (0.04, 0.03, 0.02, 0.015, 0.01)]
            + [dict(base, backend="numba-cuda", precision="float64", dp=d) for d in (0.02, 0.01)]
            + [dict(base, backend="numba-cuda", precision="float32", integrator="symplectic", dp=d) for d in (0.02, 0.01)]
            + [dict(base, backend="numba-cpu", precision="float64", dp=d) for d in (0.04, 0.03, 0.02)])
    t0 = time.perf_counter()
    rows = []
    Path(args.out).mkdir(parents=True, exist_ok=True)
    part = Path(args.out) / "rows.csv"
    for cfg in plan:
        if time.perf_counter() - t0 > args.budget:
            print(f"budget spent: skipped {describe(dict(cfg, error=float('nan'), wall_s=0))}", flush=True)
            continue
        r = run_one("dambreak", cfg, "front_rms_rel_err_all")
        r["pareto"] = 0
        rows.append(r)
        print(describe(r), flush=True)
        with open(part, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
    res = run_study("dambreak", out=args.out, from_csv=part, target_error=args.target_error)
    print(res["summary"])
    sys.exit(0)
axes = {"integrator": ["symplectic"], "kernel": ["cubic"], "diffusion": ["molteni", "none"],
        "precision": ["float32"], "visc_alpha": [0.1]}
configs = configurations(case, [0.05, 0.04, 0.03], axes)
if args.fine:
    configs += [c for c in configurations(case, [0.02], {"integrator": ["symplectic"]})]
res = run_study("dambreak", out=args.out, configs=configs, target_error=args.target_error,
                log=lambda s: print(s, flush=True))
print(res["summary"])
docs = Path(__file__).resolve().parents[1] / "docs" / "study_dambreak2d.png"
shutil.copy(res["png"], docs)
shutil.copy(res["csv"], docs.with_suffix(".csv"))
print(f"copied to {docs} (+ .csv)")
sys.exit(0)
