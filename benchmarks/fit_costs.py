"""Refit the mock engine's cost model (sphgraph.perfmodel) from measured single-rank runs.

    python benchmarks/fit_costs.py [EXAMPLES_DIR] [OUT.toml]      (FIT_STEPS=25 steps a case)

Runs each case of FIT_CASES on one rank (numba-cpu), takes every task kind's median time
(`perfmodel.samples_from_timing`) and fits (a, b, c) per kind (`perfmodel.fit_costs`);
prints the TOML (sphgraph/costs_default.toml is one) and each sample against the model.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sphgraph.perfmodel import fit_costs, pairs_per_particle, samples_from_timing  # noqa: E402

FIT_CASES = [("dambreak2d.toml", 0.04), ("dambreak2d.toml", 0.02), ("dambreak2d.toml", 0.01),
             ("dambreak2d.toml", 0.007), ("dambreak3d.toml", 0.04), ("dambreak3d.toml", 0.03),
             ("dambreak3d.toml", 0.02), ("dambreak3d.toml", 0.015)]


def measure_runs(cases, steps: int = 30, backend: str = "numba-cpu") -> list:
    """Run each (scene, dp) case on one rank for `steps` steps; samples for `fit_costs`."""
    from sphgraph import Scene, Simulation
    samples = []
    for scene, dp in cases:
        sc = scene if isinstance(scene, Scene) else Scene.from_toml(scene)
        sim = Simulation(sc, backend=backend, dp=dp)
        for _ in range(steps):
            sim.step()
        n = sim.contexts[0].state.particles.n
        k = pairs_per_particle(sim.consts, sim.dim, sim.scene.dp)
        samples += samples_from_timing(sim.scheduler.times, n, k, first_step=2)
    return samples


def main(argv=None):
    import numba
    argv = sys.argv[1:] if argv is None else argv
    ex = argv[0] if argv else "examples"
    out = argv[1] if len(argv) > 1 else None
    cases = [(os.path.join(ex, f), dp) for f, dp in FIT_CASES]
    samples = measure_runs(cases, steps=int(os.environ.get("FIT_STEPS", "25")))
    m = fit_costs(samples)
    note = (f"Cost model fitted by `python benchmarks/fit_costs.py` on single-rank\n"
            f"numba-cpu runs ({numba.get_num_threads()} threads) of the 2D/3D dam breaks, "
            f"{min(s[1] for s in samples):.0f}..{max(s[1] for s in samples):.0f} particles.\n"
            "forces_halo_* borrow forces_interior's coefficients; unlisted kinds cost 1 us.")
    text = m.to_toml(note)
    if out:
        with open(out, "w") as f:
            f.write(text)
    print(text)
    for lab, p, q, s in sorted(samples):
        print(f"# {lab:16s} n={p:9.0f} pairs={q:11.0f} measured={s:.3e} model={m.seconds(lab, p, q):.3e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
