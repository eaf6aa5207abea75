"""Fine runs that used to stop for one particle (issue 22 §1): do they reach their end?

  python benchmarks/fine_runs.py wall2d                       # examples/dambreak_wall2d.toml, dp H/120, 1.25 s
  python benchmarks/fine_runs.py wall2d --diffusion-time leapfrog --no-exclude
  python benchmarks/fine_runs.py yeh_petroff --dp 0.0085 --backend numba-cuda --precision float32

Prints one JSON object: whether the run reached its end time, where it stopped otherwise (the
solver's message: step, particle id, cause), steps, wall seconds, the exclusions (count, share
of the fluid, by cause) and the fluid density's extremes over the run (sampled every
`--every` steps), for the settings given.
Results: BENCHMARKS.md §"Runs that stop for one particle".
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = {"wall2d": (ROOT / "examples" / "dambreak_wall2d.toml", None, 1.25),
         "yeh_petroff": (ROOT / "examples" / "yeh_petroff.toml", 0.0085, 1.6)}


def scene_for(case, dp=None, diffusion_time=None, exclude=True, end_time=None):
    from sphgraph.scene import Scene
    path, dp0, t_end = CASES[case]
    d = Scene.from_toml(path).to_dict()
    d["dp"] = dp or dp0 or d["dp"]
    d["end_time"] = end_time or t_end
    d["output_interval"] = max(d["end_time"] / 25, d.get("output_interval", 0.0))
    if diffusion_time is not None:
        d["physics"]["diffusion_time"] = diffusion_time
    d["domain"]["exclude_outside"] = bool(exclude)
    return Scene.from_dict(d, source=str(path))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", choices=sorted(CASES))
    ap.add_argument("--dp", type=float)
    ap.add_argument("--end-time", type=float)
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision")
    ap.add_argument("--diffusion-time", choices=("leapfrog", "dufort-frankel"))
    ap.add_argument("--no-exclude", action="store_true", help="[domain] exclude_outside = false")
    ap.add_argument("--every", type=int, default=200, help="steps between density samples")
    a = ap.parse_args(argv)
    from sphgraph import NumericalError
    from sphgraph.features import exclusion_summary
    from sphgraph.solver import Simulation
    scene = scene_for(a.case, a.dp, a.diffusion_time, not a.no_exclude, a.end_time)
    sim = Simulation(scene, backend=a.backend, precision=a.precision)
    lo, hi = np.inf, -np.inf
    t0 = time.perf_counter()
    failure = None
    try:
        while sim.time < scene.end_time - 1e-12:
            sim.step()
            if sim.step_count % a.every == 0:
                arr = sim.frame_arrays()
                rho = arr["density"][arr["kind"] == 0]
                lo, hi = min(lo, float(rho.min())), max(hi, float(rho.max()))
    except NumericalError as e:
        failure = str(e)
    wall = time.perf_counter() - t0
    rows = sim.features.exclusions(sim) if scene.exclude_outside else None
    print(json.dumps({
        "case": a.case, "dp": scene.dp, "particles": sim.n_total, "fluid": sim.n_fluid,
        "backend": a.backend, "precision": sim.precision,
        "diffusion_time": scene.physics.diffusion_time, "exclude_outside": scene.exclude_outside,
        "end_time": scene.end_time, "reached_end": failure is None, "failure": failure,
        "time": sim.time, "steps": sim.step_count, "wall_s": round(wall, 1),
        "exclusions": None if rows is None else exclusion_summary(rows, sim.n_fluid),
        "n_excluded": None if rows is None else int(len(rows["id"])),
        "fluid_density_min": lo, "fluid_density_max": hi}))
    return 0 if failure is None else 1


if __name__ == "__main__":
    raise SystemExit(main())
