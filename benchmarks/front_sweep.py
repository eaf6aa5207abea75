"""2D dam-break surge front: formulations at one resolution against the three experiments
(issue 22 §4: mean error <= 6 % over T = 0.5-2.5 against each, at dp = a/100).

    python benchmarks/front_sweep.py --backend numba-cuda --precision float64 --dp 0.01 \\
        --variants all --json $OUT/front_sweep.json

Each run is `sphgraph validate dambreak[_walls3] --dp DP [--set ...] [--boundary ...]` through
`run_case`, the front measured as the case measures it (the foremost fluid particle on the
floor, T = t sqrt(2g/a)); no parameter is fitted: the variants are the options that exist,
and laminar viscosity is water's (1.0e-6 m^2/s at 20 C). One JSON line per run as it ends,
`--json` rewritten after every run; a run that fails numerically is recorded and the sweep
goes on.

`--at-size` runs each variant three times, at each experiment's own column width
(sphgraph.validation.scale.at_size; `--dp` then is dp/a), and compares each run with its own
experiment only: the cases are written at a = 1 m, where water's viscosity acts on a Reynolds
number some 200 times larger than in Martin & Moyce's 1.125 in column.
"""
from __future__ import annotations

import argparse
import json
import sys
import traceback

NU_WATER = 1.0e-6   # m^2/s, water at 20 C (kinematic viscosity)
# column width a of each experiment, m: Koshizuka & Oka 1996 (L = 0.146 m, 2L high), Martin &
# Moyce 1952 (a = 1.125 in and 2.25 in, n^2 = 2)
SIZES = {"ko": 0.146, "mm1": 1.125 * 0.0254, "mm2": 2.25 * 0.0254}
ZHANG = {"integrator": "symplectic", "riemann": "zhang2017", "riemann_eta": 0.3}
# name: (case, physics overrides, boundary, what it is)
VARIANTS = {
    "dsph": ("dambreak", {}, "dbc", "DualSPHysics' formulation, one wall layer (the case's own)"),
    "noslip-laminar": ("dambreak_walls3", {"laminar_nu": NU_WATER}, "mdbc-noslip",
                       "bed friction: no-slip mDBC walls (3 layers) and water's laminar viscosity"),
    "noslip-laminar-df": ("dambreak_walls3", {"laminar_nu": NU_WATER, "diffusion_time": "dufort-frankel"},
                          "mdbc-noslip", "the same with the DuFort-Frankel diffusion step (the leapfrog's "
                          "odd-even mode stops fine Verlet runs: docs/validation.md)"),
    "zhang-eta0.3-mdbc": ("dambreak_walls3", ZHANG, "mdbc",
                          "zhang2017, eta 0.3, mDBC walls: the formulation that met Buchner's targets"),
    "zhang-eta0.3-noslip": ("dambreak_walls3", dict(ZHANG, laminar_nu=NU_WATER), "mdbc-noslip",
                            "the same with no-slip walls and water's laminar viscosity"),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", default=None)
    ap.add_argument("--dp", type=float, default=0.01)
    ap.add_argument("--variants", default="all", help="comma list of " + ", ".join(VARIANTS) + ", or all")
    ap.add_argument("--json", default=None)
    ap.add_argument("--at-size", action="store_true", help="each experiment's own column width (--dp is dp/a)")
    a = ap.parse_args(argv)
    from sphgraph.errors import NumericalError
    from sphgraph.validation.cases import load_case, run_case
    from sphgraph.validation.scale import at_size
    names = list(VARIANTS) if a.variants == "all" else a.variants.split(",")
    rows = []
    for name in names:
        case, over, boundary, what = VARIANTS[name]
        row = {"variant": name, "what": what, "case": case, "overrides": over, "boundary": boundary, "dp": a.dp,
               "backend": a.backend, "precision": a.precision or "default"}
        try:
            runs = ([(k, at_size(load_case(case), size), a.dp * size) for k, size in SIZES.items()]
                    if a.at_size else [(None, case, a.dp)])
            front, walls, steps, parts, metrics = {}, 0.0, 0, 0, {}
            for key, c, dp in runs:
                r = run_case(c, dp=dp, backend=a.backend, precision=a.precision, overrides=over,
                             params={"boundary": boundary}, plot=False)
                m = r.metrics
                keys = [key] if key else list(SIZES)
                front.update({k: m[f"front_mean_rel_err_{k}"] for k in keys})
                metrics.update(m if key is None else {f"{n}@{key}": v for n, v in m.items()})
                walls, steps, parts = walls + r.wall_s, steps + r.steps, max(parts, r.particles)
            row.update(ok=True, wall_s=walls, steps=steps, particles=parts, at_size=a.at_size,
                       sizes_m=SIZES if a.at_size else None, front_mean=front,
                       front_rms_all=None if a.at_size else metrics["front_rms_rel_err_all"],
                       within_6pct=all(abs(v) <= 0.06 for v in front.values()), metrics=metrics)
        except NumericalError as e:
            row.update(ok=False, failure=str(e))
        except Exception:   # noqa: BLE001 - recorded, the next run goes on
            row.update(ok=False, failure=traceback.format_exc(limit=3))
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "metrics"}), flush=True)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(rows, f)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
