"""Virtual-time gain of load balancing in the mock engine's predict mode (issue 5 req 6):
the Yeh & Petroff scene at 16 M particles on 4 and 14 ranks, homogeneous and mixed-speed.

The balancer cannot run inside predict mode: predict runs no task bodies, so the particles
never move and the `rebalance` body (which needs the particles) never runs. So this script
drives predict mode from outside, frame by frame:

  1. particle positions over time come from a real coarse run of the same scene
     (`sphgraph run examples/yeh_petroff.toml --dp 0.03`, single rank, its output frames);
     each coarse particle stands for (dp_c / dp)^3 fluid or (dp_c / dp)^2 boundary particles
     of the full-resolution scene, smeared over its dp_c-wide cell along the split axis;
  2. at every frame the cuts of each policy are found with the balancer's own functions
     (`sphgraph.balance.loads / target_loads / solve_cuts / imbalance_vs`, the 3-point
     threshold, the 6h minimum width, cuts moving only into neighbours' old slabs), iterated
     to convergence (at 16 M particles ~1,200 steps pass between frames 0.02 s apart, i.e.
     ~24 checks every 50 steps); `time` measures each rank's force seconds from the
     predicted task times (forces_interior + forces_halo_*), as the balancer does from real
     task times;
  3. the step time of each frame is `perfmodel.predict(...)` with those cuts (the real
     production programs, messages and dt allreduce through the engine, modelled costs).

Policies compared: none (the initial equal-fluid cuts kept), particles, time. The virtual
time of the run is the mean predicted step time over the frames times the steps (dt taken
as constant). The time spent checking/applying is not modelled (the paper: 0.03 % / 0.01 %).

    python benchmarks/balance_predict.py [--run /tmp/yp03] [--dp 0.0017] [--every 3] [--json F]
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "..", "examples", "yeh_petroff.toml")
MIXED = [1.0, 2.0, 1.0, 0.5]


def ensure_run(path, dp_c):
    try:
        from sphgraph.io import list_frames
        if list_frames(path):
            return
    except Exception:  # noqa: BLE001 - no usable run there: make one
        pass
    cmd = [sys.executable, "-m", "sphgraph", "run", SCENE, "--dp", str(dp_c), "--out", path, "--overwrite", "--quiet"]
    subprocess.run(cmd, check=True, env=dict(os.environ, NUMBA_NUM_THREADS="1"))


class Profile:
    """Cumulative counts along the split axis of the full-resolution scene (from one coarse frame)."""

    def __init__(self, x, fluid, dp_c, ratio, lo, hi, sub=16):
        self.dx = dp_c / sub
        self.edges = np.arange(lo - dp_c, hi + 2 * dp_c, self.dx)
        box = np.ones(sub) / sub

        def cum(sel, w):
            h = np.histogram(x[sel] - 0.5 * dp_c, bins=self.edges)[0].astype(float) * w
            h = np.convolve(h, box)[: len(h)]     # each particle spread over its dp_c cell
            return h
        self.hf = cum(fluid, ratio ** 3)
        self.hb = cum(~fluid, ratio ** 2)
        self.cf = np.concatenate([[0.0], np.cumsum(self.hf)])
        self.ca = np.concatenate([[0.0], np.cumsum(self.hf + self.hb)])

    def below(self, c, xs):
        return np.interp(xs, self.edges, c)


def shape_for(prof, cuts, reach, k, dim):
    n = len(cuts) - 1
    c = np.array(cuts, float)
    c[0], c[-1] = prof.edges[0], prof.edges[-1]
    a = prof.below(prof.ca, c)
    rows = np.diff(a)
    lo_e = [float(prof.below(prof.ca, c[r] + reach) - a[r]) if r > 0 else 0.0 for r in range(n)]
    hi_e = [float(a[r + 1] - prof.below(prof.ca, c[r + 1] - reach)) if r < n - 1 else 0.0 for r in range(n)]
    return {"rows": [float(v) for v in rows], "lo_edge": lo_e, "hi_edge": hi_e, "k": k, "dim": dim,
            "particles": float(a[-1] - a[0]), "cuts": cuts, "axis": 0}


def equal_fluid_cuts(prof, n, min_width):
    """domain.equal_cuts on the profile: equal fluid shares, every slab >= 6h."""
    tot = prof.cf[-1]
    cuts = np.array([prof.edges[0]] + [float(np.interp(tot * r / n, prof.cf, prof.edges)) for r in range(1, n)]
                    + [prof.edges[-1]])
    for r in range(1, n):
        cuts[r] = max(cuts[r], cuts[r - 1] + min_width)
    for r in range(n - 1, 0, -1):
        cuts[r] = min(cuts[r], cuts[r + 1] - min_width)
    cuts[0], cuts[-1] = -np.inf, np.inf
    return cuts


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="/tmp/yp03", help="coarse run directory (made if missing)")
    ap.add_argument("--coarse-dp", type=float, default=0.03)
    ap.add_argument("--dp", type=float, default=0.0017, help="full resolution (0.0017: ~16.2 M particles)")
    ap.add_argument("--every", type=int, default=3, help="use every n-th frame")
    ap.add_argument("--ranks", default="4,14")
    ap.add_argument("--costs", default=None)
    ap.add_argument("--iters", type=int, default=24, help="balance checks per frame interval (converged)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)

    from sphgraph import Scene
    from sphgraph.perfmodel import CostModel, pairs_per_particle, predict
    from sphgraph.balance import BalanceConfig, imbalance_vs, loads, solve_cuts, target_loads
    from sphgraph.config import derive
    from sphgraph.io import list_frames, read_frame
    from sphgraph.particles import FLUID

    t_start = time.time()
    ensure_run(a.run, a.coarse_dp)
    costs = CostModel.load(a.costs)
    full = Scene.from_toml(SCENE).with_overrides(dp=a.dp)
    coarse = Scene.from_toml(SCENE).with_overrides(dp=a.coarse_dp)
    consts = derive(full.physics, 3, a.dp, coarse.hswl)
    h = consts.h
    k = pairs_per_particle(consts, 3, a.dp)
    reach = 2.2 * h          # as perfmodel.decomposition_shape counts edges
    min_width = 6.0 * h
    ratio = a.coarse_dp / a.dp
    frames = list_frames(a.run)[:: a.every]
    profs = []
    lo, hi = np.inf, -np.inf
    data = []
    for idx, t, step in frames:
        fr = read_frame(a.run, index=idx)
        x = np.asarray(fr["position"])[:, 0]
        data.append((t, step, x, np.asarray(fr["kind"]) == FLUID))
        lo, hi = min(lo, x.min()), max(hi, x.max())
    for t, step, x, fl in data:
        profs.append((t, step, Profile(x, fl, a.coarse_dp, ratio, lo, hi)))

    def step_time(shape, n, speed):
        p = predict(full, n, steps=2, costs=costs, rank_speed=speed, shape=shape)
        force = [sum(v for kk, v in p.per_rank[r].items() if kk.startswith("forces")) / 2 for r in range(n)]
        return p.virtual_s / 2, force

    def balance(prof, cuts, n, speed, policy):
        """Converged balancer cuts from `cuts` (the balancer's functions; threshold 3 points)."""
        cfg = BalanceConfig(policy=policy)
        edges, hist = prof.edges, prof.hf
        applied = 0
        sp = None
        for _ in range(a.iters):
            cur = loads(edges, hist, cuts, reach)
            if policy == "time":
                _, force = step_time(shape_for(prof, cuts, reach, k, 3), n, speed)
                s_new = cur / np.maximum(force, 1e-300)
                s_new = s_new / s_new.sum()
                # as the balancer: shares averaged over the checks with weight cfg.smoothing
                sp = s_new if sp is None else cfg.smoothing * s_new + (1 - cfg.smoothing) * sp / sp.sum()
            targets = target_loads(cfg, cur.sum(), sp if sp is not None else np.ones(n), [np.inf] * n)
            new_cuts = solve_cuts(edges, hist, cuts, targets, reach, min_width)
            before = imbalance_vs(cur, targets)
            after = imbalance_vs(loads(edges, hist, new_cuts, reach), targets)
            if before - after > cfg.threshold:
                cuts = new_cuts
                applied += 1
            elif policy == "particles":
                break
        return cuts, applied

    cases = []
    for n in [int(v) for v in a.ranks.split(",")]:
        for sname, speed in (("homogeneous", [1.0] * n), ("mixed", [MIXED[r % 4] for r in range(n)])):
            t0 = time.time()
            cuts0 = equal_fluid_cuts(profs[0][2], n, min_width)
            state = {"none": cuts0.copy(), "particles": cuts0.copy(), "time": cuts0.copy()}
            per = {p: [] for p in state}
            apps = {p: 0 for p in state}
            for t, step, prof in profs:
                for pol in state:
                    if pol != "none":
                        state[pol], nap = balance(prof, state[pol], n, speed, pol)
                        apps[pol] += nap
                    st, force = step_time(shape_for(prof, state[pol], reach, k, 3), n, speed)
                    per[pol].append({"t": t, "step_s": st, "force_s_max_over_min": max(force) / min(force)})
            mean = {p: float(np.mean([r["step_s"] for r in v])) for p, v in per.items()}
            cases.append({
                "ranks": n, "speeds": sname, "rank_speed": speed,
                "mean_step_s": mean,
                "gain_particles_over_none": mean["none"] / mean["particles"],
                "gain_time_over_none": mean["none"] / mean["time"],
                "gain_time_over_particles": mean["particles"] / mean["time"],
                "applications": apps,
                "final_force_spread": {p: v[-1]["force_s_max_over_min"] for p, v in per.items()},
                "per_frame": per, "seconds": time.time() - t0})
            c = cases[-1]
            print(f"# {n} ranks {sname}: mean step s none {mean['none']:.4g} particles {mean['particles']:.4g} "
                  f"time {mean['time']:.4g}; gain particles {c['gain_particles_over_none']:.3f} "
                  f"time {c['gain_time_over_none']:.3f}", file=sys.stderr)
    import numba
    rep = {"what": "virtual-time gain of load balancing, mock engine predict mode driven frame by frame",
           "scene": "examples/yeh_petroff.toml", "dp": a.dp, "particles": profs[0][2].ca[-1],
           "coarse_run": {"dir": a.run, "dp": a.coarse_dp, "frames_used": len(profs),
                          "t_span": [profs[0][0], profs[-1][0]]},
           "axis": "x", "h": h, "min_width": min_width, "costs": costs.source, "fit_error": costs.fit_error,
           "machine": {"host": platform.node(), "cpu_count": os.cpu_count(), "numba": numba.__version__},
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": "python benchmarks/balance_predict.py " + " ".join(sys.argv[1:]),
           "seconds": time.time() - t_start, "cases": cases,
           "note": "gain = mean predicted step time without balancing / with; step times are virtual "
                   "(cost model), particle positions from the coarse run, counts scaled to dp"}
    text = json.dumps(rep, indent=1)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text + "\n")
    print(json.dumps({k: v for k, v in rep.items() if k != "cases"} |
                     {"cases": [{kk: vv for kk, vv in c.items() if kk != "per_frame"} for c in cases]}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
