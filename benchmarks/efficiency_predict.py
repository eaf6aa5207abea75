"""Predicted parallel efficiency (issue 4 §7): the mock engine's predict mode on a
16 M-particle Yeh & Petroff scene, and the 2-rank fit of the communication tasks.

    E = (steps/s with N ranks / N) / (steps/s with 1 rank)        (the seed paper's formula)

Two subcommands:

  fit-mpi   runs the 2D/3D dam breaks under `mpiexec -n 2 ... --comm mpi` (1 numba thread per
            rank), gathers every rank's task times, and fits (a, b, c) of the kinds a single-rank
            run cannot see: send_edges, recv_halo_1/2, forces_halo_1/2, send_displaced,
            recv_displaced (the same features `perfmodel.predict` uses). The other kinds keep the
            shipped single-rank fit. Then, in the same command, it measures 1-rank x 1-thread and
            2-rank x 1-thread steps/s with `sphgraph bench` on validation cases and predicts them
            with the old and the new costs. Writes the merged costs (TOML) and a JSON report.

  curve     predicts steps/s for N = 1, 2, 4, 8, 14, 16, 32, 64 ranks, production and
            bulk-synchronous schedules, for examples/yeh_petroff.toml at --dp (default 0.0017:
            about 16.2 M particles), and writes E per N. Variants:
              cpu       the costs as fitted (1 numba thread per rank on this machine), network of
                        shared-memory MPI (latency 2 us, 5 GB/s);
              gpu-host  a MODEL of a GPU per rank: every task cost divided by --gpu-speed (default
                        205 M particle-steps/s, DualSPHysics on one H100, over the CPU
                        rank's predicted particle-steps/s on this scene), messages
                        through host-staged MPI at 4.9 GB/s, latency 10 us;
              gpu-ipc   the same, messages by same-host CUDA IPC at 385 GB/s, latency 10 us.
            The GPU variants are models (costs scaled from the CPU fit, not measured on a GPU).

    python benchmarks/efficiency_predict.py fit-mpi [--out-costs F.toml] [--json F.json]
    python benchmarks/efficiency_predict.py curve [--dp 0.0017] [--costs F.toml] [--json F.json]
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
EXAMPLES = os.path.join(HERE, "..", "examples")
RANKS = [1, 2, 4, 8, 14, 16, 32, 64]
SCHEDULES = ["production", "bulk-synchronous"]
COMM_KINDS = ["send_edges", "recv_halo_1", "recv_halo_2", "forces_halo_1", "forces_halo_2",
              "send_displaced", "recv_displaced"]
FIT_CASES = [("dambreak2d.toml", 0.02), ("dambreak2d.toml", 0.01), ("dambreak2d.toml", 0.007),
             ("dambreak3d.toml", 0.03), ("dambreak3d.toml", 0.02)]
CHECK_CASES = [("dambreak2d.toml", 0.01), ("dambreak3d.toml", 0.025)]   # 3D 0.025: not a fit size
DISPLACED_FRACTION = 1e-3
PAPER = {"2": 0.98, "4": 0.92, "14": 0.81}


# --------------------------------------------------------------------------- worker (under mpiexec)
def worker(scene, dp, steps, warmup):
    """One rank of a 2-rank run: per-rank medians of task seconds and the features of each kind."""
    from sphgraph import Scene, Simulation
    from sphgraph.perfmodel import pairs_per_particle
    sim = Simulation(Scene.from_toml(scene), comm="mpi", dp=dp)
    for _ in range(warmup):
        sim.step()
    sim.scheduler.times.clear()
    feats = []
    for _ in range(steps):
        sim.step()
        st = sim.contexts[0].state
        feats.append((st.particles.n, *(0 if st.halos.get(i) is None else st.halos[i].n for i in (1, 2))))
    ctx = sim.contexts[0]
    t = sim.scheduler.times
    dur: dict = {}
    for name, a, b in zip(t.task, t.start, t.end):
        dur.setdefault(name.split("@")[0], []).append(b - a)
    k = pairs_per_particle(sim.consts, sim.dim, sim.scene.dp)
    mine = {"rank": ctx.rank, "feat": np.mean(feats, axis=0).tolist(), "k": k,
            "median": {lab: float(np.median(v)) for lab, v in dur.items()},
            "mean": {lab: float(np.mean(v)) for lab, v in dur.items()}}
    allr = sim.comm.gather(mine)
    if sim.comm.is_root:
        print("RESULT " + json.dumps(allr))


def samples_from_ranks(allr):
    """(label, particles, pairs, seconds) per rank and comm kind, features as perfmodel.predict."""
    from sphgraph.perfmodel import task_features
    n = len(allr)
    by = {r["rank"]: r for r in allr}
    out = []
    for r in range(n):
        own, h1, h2 = by[r]["feat"]
        k = by[r]["k"]
        sent = (by[r + 1]["feat"][1] if r + 1 < n else 0.0) + (by[r - 1]["feat"][2] if r > 0 else 0.0)
        for lab in COMM_KINDS:
            if lab not in by[r]["median"]:
                continue
            moved = {"send_edges": sent, "recv_halo_1": h1, "forces_halo_1": h1, "recv_halo_2": h2,
                     "forces_halo_2": h2, "recv_displaced": DISPLACED_FRACTION * sent}.get(lab, 0.0)
            p, q = task_features(lab, own, moved, moved, k)
            out.append((lab, float(p), float(q), by[r]["median"][lab]))
    return out


def mpiexec(args, threads=1, ranks=2, timeout=600):
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    cmd = [os.path.join(sys.prefix, "bin", "mpiexec"), "-n", str(ranks), sys.executable] + args
    if ranks == 1:
        cmd = [sys.executable] + args
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-2000:]}")
    return p.stdout


def bench(scene, dp, steps, ranks, repeat):
    args = ["-m", "sphgraph", "bench", scene, "--dp", str(dp), "--steps", str(steps), "--warmup", "5", "--json"]
    if ranks > 1:
        args += ["--comm", "mpi"]
    runs = []
    for _ in range(repeat):
        out = mpiexec(args, threads=1, ranks=ranks)
        runs.append(json.loads(next(x for x in out.splitlines() if x.startswith("{"))))
    return max(runs, key=lambda r: r["steps_per_s"])


def cmd_fit_mpi(a):
    from sphgraph import Scene
    from sphgraph.perfmodel import CostModel, fit_costs, predict
    t0 = time.time()
    load_before = os.getloadavg()
    if a.refit_single:   # the single-rank kinds refitted now, under the same load as the 2-rank runs
        single = os.path.abspath(a.out_costs or "costs_fit.toml") + ".single.toml"
        mpiexec([os.path.join(os.path.dirname(os.path.abspath(__file__)), "fit_costs.py"), EXAMPLES, single], ranks=1,
                timeout=900)
        a.base_costs = single
    samples, raw = [], []
    for f, dp in FIT_CASES:
        scene = os.path.join(EXAMPLES, f)
        out = mpiexec([os.path.abspath(__file__), "_worker", scene, str(dp), str(a.steps), "5"])
        allr = json.loads(next(x for x in out.splitlines() if x.startswith("RESULT "))[7:])
        raw.append({"scene": f, "dp": dp, "ranks": allr})
        samples += samples_from_ranks(allr)
    fitted = fit_costs(samples, labels=COMM_KINDS)
    base = CostModel.load(a.base_costs)
    merged = CostModel(dict(base.coeffs), dict(base.fit_error), "<merged>")
    merged.coeffs.update(fitted.coeffs)
    merged.fit_error.update(fitted.fit_error)
    note = (base_note(a.base_costs) + "\n" +
            "send_edges, recv_halo_*, forces_halo_*, send_displaced, recv_displaced: fitted by\n"
            "`python benchmarks/efficiency_predict.py fit-mpi` on `mpiexec -n 2` runs (1 numba thread per\n"
            f"rank) of {', '.join(f'{f} dp {dp}' for f, dp in FIT_CASES)};\n"
            "per rank the median seconds of each kind over the steps (receives include any wait).\n"
            "unlisted kinds cost 1 us.")
    text = merged.to_toml(note)
    if a.out_costs:
        with open(a.out_costs, "w") as fh:
            fh.write(text)
    fit_s = time.time() - t0
    if a.refit_single and not a.keep_single:
        os.remove(a.base_costs)
    # the check: measured 1- and 2-rank steps/s against predictions, same command
    checks = []
    for f, dp in CHECK_CASES:
        scene = os.path.join(EXAMPLES, f)
        m1 = bench(scene, dp, a.check_steps, 1, a.repeat)
        m2 = bench(scene, dp, a.check_steps, 2, a.repeat)
        sc = Scene.from_toml(scene).with_overrides(dp=dp)
        row = {"scene": f, "dp": dp, "particles": m1["particles"],
               "measured": {"1r_x_1t": m1["steps_per_s"], "2r_x_1t": m2["steps_per_s"],
                            "E": m2["steps_per_s"] / 2 / m1["steps_per_s"]},
               "measured_task_seconds_per_step_rank0_2r": {k: v / a.check_steps for k, v in m2["task_seconds"].items()}}
        for tag, costs in (("old_costs", base), ("new_costs", merged)):
            p1, p2 = predict(sc, 1, steps=20, costs=costs), predict(sc, 2, steps=20, costs=costs)
            row[tag] = {"1r": p1.steps_per_s, "2r": p2.steps_per_s, "E": p2.steps_per_s / 2 / p1.steps_per_s,
                        "error_1r": p1.steps_per_s / m1["steps_per_s"] - 1.0,
                        "error_2r": p2.steps_per_s / m2["steps_per_s"] - 1.0}
            if tag == "new_costs":
                row["predicted_task_seconds_per_step_rank0_2r"] = {k: v / 20 for k, v in p2.per_rank[0].items()}
        checks.append(row)
    rep = {"what": "2-rank fit of the communication task costs and its check", "machine": machine(),
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": "python benchmarks/efficiency_predict.py " + " ".join(sys.argv[1:]),
           "load_avg_before": load_before, "single_rank_kinds_refitted": bool(a.refit_single),
           "fit_cases": FIT_CASES, "steps_per_fit_run": a.steps, "fit_seconds": fit_s,
           "coeffs": {k: list(v) for k, v in fitted.coeffs.items()}, "fit_error": fitted.fit_error,
           "samples": samples, "checks": checks,
           "note": "error = predicted / measured - 1; measured = best of --repeat runs; "
                   "fit_error = relative RMS error of the fit per kind"}
    dump(rep, a.json)
    return 0


def base_note(spec):
    from importlib import resources
    if spec is None:
        text = resources.files("sphgraph").joinpath("costs_default.toml").read_text()
    else:
        text = open(spec).read()
    lines = [ln[2:] for ln in text.splitlines() if ln.startswith("# ")]
    keep = [ln for ln in lines if not ln.startswith(("send_edges", "forces_halo_* borrow", "per rank the median", "`python benchmarks",
                                                         "rank) of", "unlisted kinds"))]
    return "\n".join(keep)


# --------------------------------------------------------------------------- the curve
def machine():
    import numba
    return {"host": platform.node(), "cpu": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "numba": numba.__version__,
            "load_avg": os.getloadavg()}


def cmd_curve(a):
    from sphgraph import Scene
    from sphgraph.perfmodel import CostModel, decomposition_shape, predict
    costs = CostModel.load(a.costs)
    sc = Scene.from_toml(os.path.join(EXAMPLES, "yeh_petroff.toml")).with_overrides(dp=a.dp)
    from sphgraph.domain import choose_axis
    from sphgraph.errors import InputError
    t0 = time.time()
    shapes, skipped = {}, {}
    for ax in a.axes.split(","):
        for n in RANKS:
            try:
                shapes[ax, n] = decomposition_shape(sc, n, axis=None if ax == "auto" else ax)
            except InputError as e:
                skipped.setdefault(ax, {})[str(n)] = str(e)
    axis_name = {ax: "xyz"[next(v["axis"] for (q, _), v in shapes.items() if q == ax)] for ax in a.axes.split(",")}
    shape_s = time.time() - t0
    first = next(iter(shapes.values()))
    n_part = first["particles"]
    # CPU rank throughput for one whole step on one rank, predicted (particle-steps/s)
    p1 = predict(sc, 1, steps=2, costs=costs, shape=shapes[a.axes.split(",")[0], 1])
    cpu_psps = n_part * p1.steps_per_s
    gpu_speed = a.gpu_speed or (205e6 / cpu_psps)
    variants = {
        "cpu": {"speed": 1.0, "latency": 2.0e-6, "bandwidth": 5.0e9,
                "label": "CPU ranks (1 thread, fitted costs), MPI 5 GB/s"},
        "gpu-host": {"speed": gpu_speed, "latency": 10e-6, "bandwidth": 4.9e9,
                     "label": f"MODEL GPU ranks (costs / {gpu_speed:.0f}), host MPI 4.9 GB/s"},
        "gpu-ipc": {"speed": gpu_speed, "latency": 10e-6, "bandwidth": 385e9,
                    "label": f"MODEL GPU ranks (costs / {gpu_speed:.0f}), CUDA IPC 385 GB/s"},
    }
    if a.variants:
        variants = {k: v for k, v in variants.items() if k in a.variants.split(",")}
    results = {}
    for ax in a.axes.split(","):
        for vname, v in variants.items():
            key = f"{vname}:{axis_name[ax]}"
            results[key] = {"label": f"{v['label']}, split {axis_name[ax]}", "axis": axis_name[ax],
                            "speed": v["speed"], "latency": v["latency"], "bandwidth": v["bandwidth"],
                            "not_decomposable": skipped.get(ax, {}), "schedules": {}}
            for sched in SCHEDULES:
                rows = {}
                for n in RANKS:
                    if (ax, n) not in shapes:
                        continue
                    p = predict(sc, n, schedule=sched, steps=a.steps, costs=costs, rank_speed=[v["speed"]] * n,
                                latency=v["latency"], bandwidth=v["bandwidth"], shape=shapes[ax, n])
                    rp = p.rank_particles
                    rows[n] = {"steps_per_s": p.steps_per_s, "max_rank_particles": max(rp),
                               "min_rank_particles": min(rp), "imbalance": max(rp) / (sum(rp) / n) - 1.0,
                               "task_seconds_per_step_rank0": {k: s / a.steps for k, s in p.per_rank[0].items()}}
                base = rows[1]["steps_per_s"]
                for n in rows:
                    rows[n]["E"] = rows[n]["steps_per_s"] / n / base
                results[key]["schedules"][sched] = {str(n): r for n, r in rows.items()}
    rep = {"what": "predicted parallel efficiency, mock engine predict mode (no kernels)",
           "formula": "E = (steps/s with N / N) / (steps/s with 1)",
           "scene": "examples/yeh_petroff.toml", "dp": a.dp, "particles": int(n_part),
           "ranks": RANKS, "steps_predicted": a.steps, "costs": costs.source,
           "fit_error": costs.fit_error, "gpu_speed": gpu_speed,
           "gpu_speed_basis": "205e6 particle-steps/s (DualSPHysics, one H100, ANCHORS.md) / the CPU "
                              f"rank's predicted {cpu_psps:.3e} particle-steps/s on this scene",
           "paper": PAPER, "machine": machine(),
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": "python benchmarks/efficiency_predict.py " + " ".join(sys.argv[1:]),
           "decomposition_seconds": shape_s, "seconds": time.time() - t0,
           "variants": results}
    dump(rep, a.json)
    return 0


def dump(rep, path):
    text = json.dumps(rep, indent=1)
    if path:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path, "w") as fh:
            fh.write(text + "\n")
    print(text)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_worker":
        worker(argv[1], float(argv[2]), int(argv[3]), int(argv[4]))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("fit-mpi")
    f.add_argument("--steps", type=int, default=40)
    f.add_argument("--check-steps", type=int, default=60)
    f.add_argument("--repeat", type=int, default=2)
    f.add_argument("--base-costs", default=None, help="single-rank costs to extend (default: shipped)")
    f.add_argument("--out-costs", default=None)
    f.add_argument("--refit-single", action="store_true",
                   help="refit the single-rank kinds first (benchmarks/fit_costs.py, 1 thread) in the same command")
    f.add_argument("--keep-single", action="store_true")
    f.add_argument("--json", default=None)
    c = sub.add_parser("curve")
    c.add_argument("--dp", type=float, default=0.0017)
    c.add_argument("--steps", type=int, default=3)
    c.add_argument("--costs", default=None)
    c.add_argument("--gpu-speed", type=float, default=None)
    c.add_argument("--axes", default="x,auto", help="split axes to predict (auto: the scene's choice)")
    c.add_argument("--variants", default=None, help="comma list of cpu,gpu-host,gpu-ipc")
    c.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    return cmd_fit_mpi(a) if a.cmd == "fit-mpi" else cmd_curve(a)


if __name__ == "__main__":
    raise SystemExit(main())
