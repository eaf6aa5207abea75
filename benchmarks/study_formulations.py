"""The formulations beyond DualSPHysics' beside it (issue 22 §6): `sphgraph study dambreak` with an
explicit plan, error against wall time with the Pareto front, for the README chart.

    python benchmarks/study_formulations.py [--dps 0.05,0.04,0.03,0.02] [--out out/study/formulations]

Error: as benchmarks/study_dambreak2d.py (RMS of the relative surge-front error against the three
experiments, T = 0.5-2.5). Plan, at every dp, each a complete formulation:
  DualSPHysics'        Verlet, Wendland, Fourtakas diffusion, alpha 0.02, DBC (the case's own)
  + DuFort-Frankel     Verlet with `diffusion_time = "dufort-frankel"`
  + mDBC no-slip       Verlet with `boundary = "mdbc-noslip"`
  Symplectic           the same physics, Symplectic
  + Riemann            Symplectic with `riemann = "zhang2017"` (it needs Symplectic)
  + mDBC no-slip       Symplectic with `boundary = "mdbc-noslip"`
  alpha 0.1            Verlet, artificial viscosity 0.1
  Riemann eta 0.3, mDBC  Symplectic, `riemann = "zhang2017"`, `riemann_eta = 0.3`, `boundary = "mdbc"`:
                       the formulation that met Buchner's wall-pressure targets (docs/validation.md)
  renormalised jump    the same with `riemann_jump = "renormalised"` (the jump's linear part removed)
With `--case buchner` the plan is the wall-pressure one (error: the smoothed pressure at Buchner's
sensor against the data after the impact, `post_impact_rms_err`, in rho g H): DualSPHysics', mDBC,
Symplectic with the Riemann term on DBC, and on mDBC walls with `riemann_eta = 0.3` under each
`riemann_wall` and `riemann_jump` that holds mDBC walls.
numba-cpu, float64. Writes study.csv / study.png there and copies them to docs/study_formulations*.
"""
import argparse
import shutil
from pathlib import Path

from sphgraph.study import baseline, run_study
from sphgraph.validation.cases import load_case

ap = argparse.ArgumentParser()
ap.add_argument("--dps", help="default: 0.05,0.04,0.03,0.02 (dam breaks), 0.015,0.01 (buchner)")
ap.add_argument("--case", default="dambreak",
                help="dambreak, dambreak_walls3 (3 wall layers, as mDBC asks), or buchner (wall pressure)")
ap.add_argument("--out", default="out/study/formulations")
ap.add_argument("--target-error", type=float, default=0.08)
args = ap.parse_args()

case = load_case(args.case)
extra = ("riemann", "riemann_eta", "riemann_wall", "riemann_jump", "diffusion_time", "boundary", "visc_alpha")
base = baseline(case, extra)
ZHANG_MDBC = {"integrator": "symplectic", "riemann": "zhang2017", "riemann_eta": 0.3, "boundary": "mdbc"}
RENORM = dict(ZHANG_MDBC, riemann_jump="renormalised")
if args.case == "buchner":
    variants = [{}, {"boundary": "mdbc"}, {"integrator": "symplectic", "riemann": "zhang2017"},
                ZHANG_MDBC, dict(ZHANG_MDBC, riemann_wall="cancel"), RENORM, dict(RENORM, riemann_wall="cancel")]
    dps = args.dps or "0.015,0.01"
else:
    variants = [{}, {"diffusion_time": "dufort-frankel"}, {"boundary": "mdbc-noslip"},
                {"integrator": "symplectic"}, {"integrator": "symplectic", "riemann": "zhang2017"},
                {"integrator": "symplectic", "boundary": "mdbc-noslip"}, {"visc_alpha": 0.1}, ZHANG_MDBC, RENORM]
    dps = args.dps or "0.05,0.04,0.03,0.02"
configs = [dict(base, dp=float(dp), **v) for dp in dps.split(",") for v in variants]
res = run_study(args.case, out=args.out, configs=configs, target_error=args.target_error,
                log=lambda s: print(s, flush=True))
print(res["summary"])
docs = Path(__file__).resolve().parents[1] / "docs" / ("study_formulations.png" if args.case == "dambreak"
                                                       else f"study_formulations_{args.case}.png")
shutil.copy(res["png"], docs)
shutil.copy(res["csv"], docs.with_suffix(".csv"))
print(f"copied to {docs} (+ .csv)")
