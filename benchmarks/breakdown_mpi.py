"""Per-rank time breakdown of real MPI runs by the seed paper's timers (Figs. 11-12).

    python benchmarks/breakdown_mpi.py [--scene examples/dambreak2d.toml] [--dp 0.01]
                                       [--ranks 2 3] [--steps 1000] [--png docs/breakdown_mpi2.png]

For each rank count: `mpiexec -n N sphgraph run SCENE --comm mpi --max-steps STEPS` (one
numba thread per rank, production schedule, balancing on as the schedule says), then the
run's /timing grouped by the paper's timer names: SendEdge, RecvHalo, SendDisplaced,
RecvDisplaced, SynchroDt, Balancing, and the compute timers FC (forces), NL (cells),
PU (dt terms + integration). Prints a markdown table (ms per step and % of the step per
rank) and one JSON object; `--png` draws `sphgraph plot breakdown` of the first run.
Also reads /balance: checks, applications, and their time as a share of the run.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import h5py

HERE = os.path.dirname(os.path.abspath(__file__))
TIMERS = ("SendEdge", "RecvHalo", "SendDisplaced", "RecvDisplaced", "SynchroDt", "Balancing", "FC", "NL", "PU")


def run(scene, dp, ranks, steps, out, backend="numba-cpu", schedule="production", precision=None):
    # one numba thread a rank on the CPU; on a GPU every rank's kernels run on the device
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1") if backend == "numba-cpu" else dict(os.environ)
    mpiexec = shutil.which("mpiexec") or os.path.join(sys.prefix, "bin", "mpiexec")
    cmd = [mpiexec, "-n", str(ranks), sys.executable, "-m", "sphgraph", "run", scene, "--dp", str(dp),
           "--comm", "mpi", "--max-steps", str(steps), "--out", out, "--overwrite", "--backend", backend,
           "--schedule", schedule] + (["--precision", precision] if precision else [])
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-2000:]}")
    lines = [x for x in (p.stdout + p.stderr).splitlines() if " steps to t = " in x]
    return " ".join(["mpiexec", "-n", str(ranks)] + cmd[5:]), (lines or [""])[-1]


def breakdown(out):
    from sphgraph.trace import load_timing, seconds_by_rank_and_kind, steps_recorded
    t = load_timing(out)
    nsteps = steps_recorded(t)
    per = seconds_by_rank_and_kind(t, timers=True)
    table = {r: {k: per[r].get(k, 0.0) / nsteps * 1e3 for k in TIMERS} for r in sorted(per)}
    with h5py.File(os.path.join(out, "output.h5"), "r") as f:
        bal = None
        if "balance" in f:
            g = f["balance"]
            bal = {"checks": int(len(g["step"])), "applications": int(g["applied"][()].sum()),
                   **{k: (v.item() if hasattr(v, "item") else v) for k, v in g.attrs.items()}}
    return nsteps, table, bal


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=os.path.join(HERE, "..", "examples", "dambreak2d.toml"))
    ap.add_argument("--dp", type=float, default=0.01)
    ap.add_argument("--ranks", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--png", default=None, help="the breakdown of the first run (of each schedule: NAME_SCHEDULE.png)")
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", default=None)
    ap.add_argument("--schedules", nargs="+", default=["production"])
    a = ap.parse_args(argv)
    res = []
    with tempfile.TemporaryDirectory() as tmp:
        for sched in a.schedules:
            for i, n in enumerate(a.ranks):
                out = os.path.join(tmp, f"r{n}_{sched}")
                cmd, summary = run(a.scene, a.dp, n, a.steps, out, a.backend, sched, a.precision)
                nsteps, table, bal = breakdown(out)
                res.append({"ranks": n, "schedule": sched, "backend": a.backend, "command": cmd,
                            "summary": summary, "steps": nsteps, "ms_per_step": table, "balance": bal})
                if a.png and i == 0:
                    from sphgraph.plots import plot_breakdown
                    png = a.png if len(a.schedules) == 1 else a.png.replace(".png", f"_{sched}.png")
                    plot_breakdown(out, path=png)
    for r in res:
        print(f"\n{r['command']}  ({r['summary']})\n")
        print("| rank | " + " | ".join(TIMERS) + " | step |")
        print("|---|" + "---|" * (len(TIMERS) + 1))
        for rank, row in r["ms_per_step"].items():
            tot = sum(row.values())
            cells = " | ".join(f"{row[k]:.3f} ({100 * row[k] / tot:.1f} %)" for k in TIMERS)
            print(f"| {rank} | {cells} | {tot:.2f} ms |")
        if r["balance"]:
            print(f"\n/balance: {r['balance']}")
    print(json.dumps(res))


if __name__ == "__main__":
    main()
