"""One CPU run of a checkout's sphgraph, for A/B comparisons of two trees in one call:
steps/s (wall) of `--steps` steps after 3 untimed ones, numba-cpu, float64, one rank.

    # an older tree in a worktree, with backends/ and schedules/ linked under sphgraph/
    git worktree add /tmp/base REV && ln -s ../backends /tmp/base/sphgraph/backends \\
        && ln -s ../schedules /tmp/base/sphgraph/schedules
    for r in 1 2 3; do for t in /tmp/base $PWD; do
        NUMBA_CACHE_DIR=/tmp/nc_$(basename $t) python3 benchmarks/cpu_ab.py $t spheric2 0.035 15
    done; done

Each tree gets its own NUMBA_CACHE_DIR (numba's caches are keyed on file paths). Prints one
JSON line.
"""
import json
import sys
import time


def main(argv):
    root, name, dp, steps = argv[0], argv[1], float(argv[2]), int(argv[3])
    sys.path.insert(0, root)
    import sphgraph
    if not sphgraph.__file__.startswith(root):
        raise SystemExit(f"imported {sphgraph.__file__}, not the tree {root}")
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    sc = Scene.from_toml(f"{root}/examples/{name}.toml").with_overrides(dp=dp)
    sim = Simulation(sc, backend="numba-cpu", precision="float64")
    for _ in range(3):
        sim.step()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    w = time.perf_counter() - t0
    print(json.dumps({"tree": root, "scene": name, "dp": dp, "particles": sim.n_total, "steps": steps,
                      "steps_per_s": steps / w}))


if __name__ == "__main__":
    main(sys.argv[1:])
