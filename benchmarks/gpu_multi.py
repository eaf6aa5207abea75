"""Multi-GPU efficiency of the numba-cuda backend (issue 6 req 8, issue 10).

    E = (steps/s with N ranks / N) / (steps/s with 1 rank, --comm single)

Same code, precision, case and machine, in one call: for each dp, `sphgraph bench`
once with `--comm single` (one GPU) and once per schedule under
`mpiexec -n N ... --comm mpi` (one rank per GPU: the backend selects GPU
local_rank % ngpu). SPHERIC test 2 (examples/spheric2.toml) by default.

    python3 benchmarks/gpu_multi.py --dp 0.01 0.006 0.00375 --ranks 2 --steps 20 --json out.json
Prints one JSON line per run and writes everything to --json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def bench(scene, dp, steps, warmup, precision, ranks=1, schedule="production", extra=(), timeout=900):
    cmd = [sys.executable, "-m", "sphgraph", "bench", str(scene), "--dp", str(dp), "--steps", str(steps),
           "--warmup", str(warmup), "--backend", "numba-cuda", "--precision", precision,
           "--schedule", schedule, "--json", *extra]
    if ranks > 1:
        mpiexec = shutil.which("mpiexec") or os.path.join(sys.prefix, "bin", "mpiexec")
        cmd = [mpiexec, "-n", str(ranks)] + cmd + ["--comm", "mpi"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        return {"error": f"rc {p.returncode}", "cmd": " ".join(cmd), "stderr": p.stderr[-3000:]}
    line = next((x for x in p.stdout.splitlines() if x.startswith("{")), None)
    if line is None:
        return {"error": "no JSON", "cmd": " ".join(cmd), "stdout": p.stdout[-2000:]}
    r = json.loads(line)
    r["cmd"] = " ".join(cmd[cmd.index("-m") - 1:]) if ranks == 1 else " ".join(cmd)
    r["process_s"] = time.perf_counter() - t0
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "spheric2.toml"))
    ap.add_argument("--dp", type=float, nargs="+", default=[0.01, 0.006])
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--schedules", nargs="+", default=["production", "bulk-synchronous"])
    ap.add_argument("--transports", nargs="+", default=["staged"], choices=["staged", "ipc"],
                    help="--halo-transport of the multi-rank runs (a key SCHEDULE or SCHEDULE+ipc each)")
    ap.add_argument("--extra", nargs="*", default=[], help="more `sphgraph bench` arguments (multi-rank runs)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    out = {"date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "command": " ".join(sys.argv), "runs": []}
    for dp in a.dp:
        one = bench(a.scene, dp, a.steps, a.warmup, a.precision)
        row = {"dp": dp, "single": one}
        for sch in a.schedules:
            for tr in a.transports:
                key = sch if tr == "staged" else f"{sch}+{tr}"
                m = bench(a.scene, dp, a.steps, a.warmup, a.precision, ranks=a.ranks, schedule=sch,
                          extra=list(a.extra) + ["--halo-transport", tr])
                row[key] = m
                if "steps_per_s" in m and "steps_per_s" in one:
                    row[f"E_{key}"] = (m["steps_per_s"] / a.ranks) / one["steps_per_s"]
        out["runs"].append(row)
        brief = {k: (v if not isinstance(v, dict) else
                     {kk: v.get(kk) for kk in ("particles", "steps_per_s", "particle_steps_per_s", "device",
                                               "ranks", "schedule", "error", "stderr")})
                 for k, v in row.items()}
        print(json.dumps(brief), flush=True)
        if a.json:
            Path(a.json).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
