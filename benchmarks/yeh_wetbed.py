"""Yeh & Petroff column force: the dry floor of examples/yeh_petroff.toml against the
experiment's wet bed (examples/yeh_petroff_wetbed.toml), same resolution, same sampler,
same window, the same DuFort-Frankel diffusion step (issue 22 §4).

    python benchmarks/yeh_wetbed.py --backend numba-cuda --dp 0.005 --json $OUT/yeh_wetbed.json

Each run is the validation case as `sphgraph validate` runs it (`run_case`), with the dry
case's run and RMS window set to the wet case's (t_end 1.6 s, force_rms_err_N over
0.3-1.6 s, no time shift; the force is the 0.02 s running mean of the [forces] sampler at
0.002 s, as both case files say). One JSON line per run as it finishes: the case's metrics,
particles, steps, wall seconds; `--json` also holds each run's force series. A run that fails
numerically is recorded with its failure and the sweep goes on. `--out DIR` keeps each case's
comparison plot.
"""
from __future__ import annotations

import argparse
import sys

# case, params over the case's, physics overrides: the dry run takes the wet example's
# DuFort-Frankel diffusion step (with DualSPHysics' leapfrog the dry run stops at dp 0.0085:
# docs/validation.md, "Runs that stop for one particle"), so the floor is the one difference
CASES = {"dry": ("yeh_petroff", {"t_end": 1.6, "rms_window": [0.3, 1.6]}, {"diffusion_time": "dufort-frankel"}),
         "wet": ("yeh_petroff_wetbed", {}, {}),
         # bed friction as the issue names it: no-slip mDBC walls (3 layers: the kernel's support)
         "wet-noslip": ("yeh_petroff_wetbed", {"boundary": "mdbc-noslip", "layers": 3}, {}),
         # the same with water's laminar viscosity (1.0e-6 m^2/s at 20 C) beside the artificial one,
         # as benchmarks/front_sweep.py's noslip-laminar runs take it in 2D
         "wet-noslip-laminar": ("yeh_petroff_wetbed", {"boundary": "mdbc-noslip", "layers": 3},
                                {"laminar_nu": 1.0e-6}),
         # the low-dissipation pressure that met Buchner's targets (docs/validation.md)
         "wet-zhang": ("yeh_petroff_wetbed", {}, {"integrator": "symplectic", "diffusion_time": "leapfrog",
                                                   "riemann": "zhang2017", "riemann_eta": 0.3}),
         # the release as a lifted gate (sphgraph.validation.gate) at c = V / sqrt(g h0) = 1 and 2
         # (1.72 and 3.43 m/s for h0 = 0.3 m): not the experiment's speed, which the sources do not
         # state, but how far a release inside Lauber & Hager's instantaneous range moves the force
         "wet-gate-c1": ("yeh_petroff_wetbed", {}, {}, 1.0),
         "wet-gate-c2": ("yeh_petroff_wetbed", {}, {}, 2.0)}
GATE_FACE_X, GATE_H0 = 0.4, 0.3   # m: the column's face (gate position) and height in both example files


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", default=None)
    ap.add_argument("--dp", type=float, default=0.005)
    ap.add_argument("--runs", default="dry,wet", help="comma list of " + ", ".join(CASES) + " (run in the order given)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    from sphgraph.validation.cases import load_case, run_case
    from sphgraph.validation.gate import with_gate
    from sweep_rows import attempt, record
    rows = []
    for key in a.runs.split(","):
        name, params, overrides, *gate = CASES[key]
        case = with_gate(load_case(name), a.dp, GATE_FACE_X, GATE_H0, gate[0]) if gate else name
        row = {"run": key, "case": name, "dp": a.dp, "backend": a.backend, "precision": a.precision or "default"}

        def one():
            r = run_case(case, dp=a.dp, backend=a.backend, precision=a.precision, params=params,
                         overrides=overrides, out=a.out, plot=a.out is not None)
            return dict(metrics=r.metrics, steps=r.steps, particles=r.particles, wall_s=r.wall_s,
                        checks=[list(c) for c in r.checks],
                        series={k: [list(map(float, v[0])), list(map(float, v[1]))] for k, v in r.series.items()
                                if "running mean" in k})
        record(rows, attempt(row, one), a.json)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
