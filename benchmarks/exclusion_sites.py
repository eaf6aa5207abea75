"""Where a run's excluded particles left: each `/exclusions` row (position, velocity, density
as they were in the step that removed it) put against the nearest face of the scene's tanks
and boxes, counted by face and cause, and drawn over the geometry.

    python benchmarks/exclusion_sites.py --backend numba-cuda --dp 0.02 \\
        --run zhang-mdbc4-renorm-cancel --json $OUT/sites.json --plot $OUT/sites.png

The run is `benchmarks/spheric2_heights.py`'s (`--run`: one of its RUNS) to `--t-end` or to
its exclusion stop, stepped as the validation case steps it (no output files); `--json` is
rewritten at every 0.5 s of simulated time, so a run cut short keeps its rows. The report is
what was measured: per face, the rows that left through it or next to it, their mean speed
and the signed distance from the face into the fluid's side (negative: through the wall).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def faces(scene_dict: dict) -> list:
    """(name, axis, coordinate, side, lo, hi) of every face of the scene's `tank` and `box`
    boundaries; side +1 where the fluid lies at larger coordinates (a tank's low faces, a
    box's high faces), lo/hi the face's extent on the other axes."""
    out = []
    for k, b in enumerate(scene_dict.get("boundary", [])):
        if b.get("type") not in ("tank", "box"):
            continue
        lo, hi = np.asarray(b["min"], float), np.asarray(b["max"], float)
        inside = 1 if b["type"] == "tank" else -1          # the fluid is inside a tank, outside a box
        for a in range(len(lo)):
            for end, x in (("min", lo[a]), ("max", hi[a])):
                side = inside if end == "min" else -inside
                out.append((f"{b['type']}{k} {'xyz'[a]}={x:g}", a, float(x), side, lo, hi))
    return out


def nearest_face(pos: np.ndarray, fcs: list) -> tuple[np.ndarray, np.ndarray]:
    """For each row: the index of the nearest face (distance to the face's rectangle) and the
    signed distance along its normal, positive on the fluid's side."""
    dist = np.full((len(pos), len(fcs)), np.inf)
    signed = np.zeros_like(dist)
    for j, (_, a, x, side, lo, hi) in enumerate(fcs):
        q = np.clip(pos, lo, hi)
        q[:, a] = x
        dist[:, j] = np.linalg.norm(pos - q, axis=1)
        signed[:, j] = side * (pos[:, a] - x)
    j = np.argmin(dist, axis=1)
    return j, signed[np.arange(len(pos)), j]


def report(cols: dict, fcs: list, dp: float) -> list:
    pos, vel = np.asarray(cols["position"]), np.asarray(cols["velocity"])
    j, s = nearest_face(pos, fcs)
    speed = np.linalg.norm(vel, axis=1)
    rows = []
    for k in np.unique(j):
        m = j == k
        causes, counts = np.unique(cols["cause"][m], return_counts=True)
        rows.append({"face": fcs[k][0], "rows": int(m.sum()),
                     "by_cause": {int(c): int(n) for c, n in zip(causes, counts)},
                     "mean_speed": float(speed[m].mean()), "max_speed": float(speed[m].max()),
                     "normal_dist_dp": [float(np.min(s[m]) / dp), float(np.median(s[m]) / dp),
                                        float(np.max(s[m]) / dp)],
                     "t": [float(np.min(cols["time"][m])), float(np.max(cols["time"][m]))],
                     "density": [float(np.min(cols["density"][m])), float(np.max(cols["density"][m]))]})
    return sorted(rows, key=lambda r: -r["rows"])


def plot(cols: dict, scene_dict: dict, path: str, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle
    pos = np.asarray(cols["position"])
    dim = pos.shape[1]
    views = [(0, 1, "x", "y"), (0, 2, "x", "z")] if dim == 3 else [(0, 1, "x", "y")]
    fig, axs = plt.subplots(1, len(views), figsize=(6.5 * len(views), 4.5), squeeze=False)
    for ax, (a, b, la, lb) in zip(axs[0], views):
        for bd in scene_dict.get("boundary", []):
            if bd.get("type") in ("tank", "box"):
                lo, hi = bd["min"], bd["max"]
                ax.add_patch(Rectangle((lo[a], lo[b]), hi[a] - lo[a], hi[b] - lo[b], fill=False, color="k", lw=1))
        sc = ax.scatter(pos[:, a], pos[:, b], c=cols["time"], s=8, cmap="viridis")
        ax.set_xlabel(f"{la} [m]")
        ax.set_ylabel(f"{lb} [m]")
        ax.set_aspect("equal")
        ax.autoscale_view()
    fig.colorbar(sc, ax=axs[0].tolist(), label="t excluded [s]")
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", default=None)
    ap.add_argument("--dp", type=float, default=0.02)
    ap.add_argument("--t-end", type=float, default=None, help="s (default: the case's)")
    ap.add_argument("--run", default="zhang-mdbc4-renorm-cancel")
    ap.add_argument("--json", default=None)
    ap.add_argument("--plot", default=None)
    a = ap.parse_args(argv)
    from spheric2_heights import RUNS

    from sphgraph.errors import NumericalError
    from sphgraph.validation.cases import _sim, load_case, scene_for
    case = load_case("spheric2")
    params, overrides = RUNS[a.run]
    end = a.t_end if a.t_end is not None else float(case.params["t_end"])
    scene = scene_for(case, a.dp, overrides, boundary=params.get("boundary"), end_time=end,
                      layers=params.get("layers"))
    sim = _sim(scene, a.backend, a.precision, boundary=params.get("boundary", "dbc"))
    sd = case.scene             # the geometry's faces: a layers override leaves them where they are
    fcs = faces(sd)
    t0 = time.perf_counter()

    def save(failure, quiet):
        """The rows so far, their sites and the run's state: at the end, and at each 0.5 s
        mark (a run cut short by a time limit keeps what it recorded)."""
        cols = sim.features.exclusions(sim)
        out = {"run": a.run, "dp": a.dp, "backend": a.backend, "precision": a.precision or "default",
               "t": sim.time, "steps": sim.step_count, "particles": sim.n_total, "fluid": sim.n_fluid,
               "wall_s": time.perf_counter() - t0, "failure": failure, "excluded": len(cols["id"]),
               "sites": report(cols, fcs, a.dp) if len(cols["id"]) else [],
               "rows": {k: np.asarray(v).tolist() for k, v in cols.items()}}
        if not quiet:
            print(json.dumps({k: v for k, v in out.items() if k != "rows"}, indent=1), flush=True)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(out, f)
        return cols

    failure, mark = None, 0.5
    try:
        while sim.time < end:
            sim.step()
            if sim.time >= mark:
                print(f"t = {sim.time:.3f} s, step {sim.step_count}, excluded {len(sim.features.excluded)}",
                      flush=True)
                save(None, quiet=True)
                mark += 0.5
    except NumericalError as e:
        failure = str(e)
    cols = save(failure, quiet=False)
    if a.plot and len(cols["id"]):
        plot(cols, sd, a.plot, f"{a.run}, dp {a.dp}, {a.backend}: {len(cols['id'])} rows excluded by "
                               f"t = {sim.time:.3f} s" + (" (stopped)" if failure else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
