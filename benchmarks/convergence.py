"""Convergence order of the Poiseuille start-up case (validation case `poiseuille`).

    python benchmarks/convergence.py [--n 10,20,40,80] [--integrator symplectic] [--boundary mdbc-noslip]

Runs H/dp = n for each n, prints the L2 error of u(y) / u_max at t = 0.2 s against the
series solution (Morris et al. 1997), the order between successive resolutions and the
least-squares order, and the error if the no-slip walls were on the first boundary rows
(the dynamic-boundary offset). About 1-2 minutes on 2 cores up to n = 80.
"""
import argparse
import time

import numpy as np

from sphgraph.validation.cases import load_case, poiseuille_error

ap = argparse.ArgumentParser()
ap.add_argument("--n", default="10,20,40,80")
ap.add_argument("--integrator", default="symplectic")
ap.add_argument("--boundary", default="dbc", help="dbc | mdbc | mdbc-noslip (wall treatment)")
args = ap.parse_args()
case = load_case("poiseuille")
H = float(case.params["H"])
ns = [int(x) for x in args.n.split(",")]
dps, errs = [], []
print(f"{'H/dp':>5} {'particles':>9} {'steps':>6} {'wall_s':>7} {'L2 err/umax':>12} {'order':>6} {'err, walls on rows':>19}")
for n in ns:
    dp = H / n
    t0 = time.perf_counter()
    e, _, sim = poiseuille_error(case, dp, dict(case.params, boundary=args.boundary), "numba-cpu", None,
                                 {"integrator": args.integrator})
    wall = time.perf_counter() - t0
    order = "" if not errs else f"{np.log(errs[-1] / e) / np.log(dps[-1] / dp):6.2f}"
    dps.append(dp)
    errs.append(e)
    print(f"{n:5d} {sim.n_total:9d} {sim.step_count:6d} {wall:7.1f} {e:12.4g} {order:>6} {sim.err_walls_on_rows:19.4g}",
          flush=True)
print(f"least-squares order: {np.polyfit(np.log(dps), np.log(errs), 1)[0]:.2f}")
