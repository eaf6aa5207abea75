"""RecvDisplaced per rank on real 2-rank MPI runs: receive after build_cells (production)
against receive before it (bulk-synchronous), issue 4 §2.

    python benchmarks/displaced_wait.py [--scene examples/dambreak2d.toml] [--dp 0.01]
                                        [--steps 3000] [--repeat 2] [--first 20]

Runs `mpiexec -n 2 sphgraph run SCENE --comm mpi --max-steps STEPS --schedule S` (one numba
thread per rank), alternating bulk-synchronous and production REPEAT times, and reads each
run's /timing from step FIRST on. Per rank: the recv_displaced task's mean duration (wait +
receive + append or merge), and its wait: how long after the task started the neighbour's
send_displaced of that step ended (the message was not posted yet; both ranks on one host,
MPI.Wtime from a start barrier, rank 1's clock aligned on the dt allreduce's ends), capped
at the task's duration, with the share of steps that waited. Prints one JSON object per run.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def run(scene, dp, steps, schedule, out):
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    mpiexec = os.path.join(sys.prefix, "bin", "mpiexec")
    cmd = [mpiexec, "-n", "2", sys.executable, "-m", "sphgraph", "run", scene, "--dp", str(dp), "--comm", "mpi",
           "--max-steps", str(steps), "--schedule", schedule, "--out", out, "--overwrite", "--quiet"]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr[-2000:]}")


def analyse(out, first):
    from sphgraph.trace import load_timing
    t = load_timing(out)
    rank, step = np.asarray(t["rank"]), np.asarray(t["step"])
    name = np.array([str(x).split("@")[0] for x in t["task"]])
    a, b = np.asarray(t["start"], float), np.asarray(t["end"], float)

    def col(r, lab, c):
        m = (rank == r) & (name == lab) & (step >= first)
        return dict(zip(step[m].tolist(), c[m].tolist()))
    # the ranks' clocks start at a barrier's exit, which a loaded machine skews by up to
    # milliseconds: rank 1's clock is shifted by the median difference of the dt allreduce's
    # end (every rank leaves it when the last one arrives)
    e0, e1 = col(0, "dt_allreduce", b), col(1, "dt_allreduce", b)
    offset = float(np.median([e1[s] - e0[s] for s in e0 if s in e1]))
    a = np.where(rank == 1, a - offset, a)
    b = np.where(rank == 1, b - offset, b)
    res = {"clock_offset_ms": 1e3 * offset}
    for r in (0, 1):
        rs, re_ = col(r, "recv_displaced", a), col(r, "recv_displaced", b)
        posted = col(1 - r, "send_displaced", b)
        steps = [s for s in rs if s in posted]
        wait = np.array([min(max(0.0, posted[s] - rs[s]), re_[s] - rs[s]) for s in steps])
        dur = np.array([re_[s] - rs[s] for s in steps])
        bc = np.array(list(col(r, "build_cells", b).values())) - np.array(list(col(r, "build_cells", a).values()))
        res[r] = {"steps": len(steps), "recv_displaced_ms": 1e3 * float(dur.mean()),
                  "wait_ms": 1e3 * float(wait.mean()), "steps_waiting_pct": 100.0 * float(np.mean(wait > 0)),
                  "build_cells_ms": 1e3 * float(bc.mean())}
    return res


def main(argv=None):
    """Run and print; `--analyse DIR..` only reads existing runs' /timing."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=os.path.join(HERE, "..", "examples", "dambreak2d.toml"))
    ap.add_argument("--dp", type=float, default=0.01)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--first", type=int, default=20)
    ap.add_argument("--analyse", nargs="+", default=None, metavar="DIR")
    a = ap.parse_args(argv)
    if a.analyse:
        from sphgraph.io import read_attrs
        for out in a.analyse:
            print(json.dumps({"run": out, "schedule": str(read_attrs(out).get("schedule", "")),
                              "per_rank": analyse(out, a.first)}))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeat):
            for sched in ("bulk-synchronous", "production"):
                out = os.path.join(tmp, f"{sched}-{i}")
                run(a.scene, a.dp, a.steps, sched, out)
                print(json.dumps({"schedule": sched, "run": i, "dp": a.dp, "steps": a.steps,
                                  "load": os.getloadavg()[0], "per_rank": analyse(out, a.first)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
