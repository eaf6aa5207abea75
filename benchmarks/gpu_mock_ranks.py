"""Many ranks at the speed of one: N mock ranks in one process against `--comm single`
on one GPU, wall clock (issue 21 §2).

For each particle spacing, the runs (`single`, then `mock` at each `--ranks`, each
`--transport`) alternate `--rounds` times; a run is a fresh `Simulation`, `--warmup`
untimed steps, then `--steps` timed ones between two device synchronisations. Per run it
reports steps/s (wall), the host seconds of each task kind per rank-step (the body's
`perf_counter` time, launches and host waits included), the device allocations and host
waits per step (the backend's own counters, `NumbaCUDA.counters`), the halo bytes of
/timing's message tasks, and whether every rank's ids are unique and complete.
The ratio is the median mock steps/s over the median single steps/s of the same call.

    python3 benchmarks/gpu_mock_ranks.py --dp 0.006 0.004 --ranks 2 4 --steps 30 --rounds 3 \
        --json out.json
With `--match` it also runs float64 single and mock for `--match-steps` steps and prints the
largest position difference over the domain's extent (the 1e-9 check).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _say(*a):
    print(*a, file=sys.stderr, flush=True)


def _wrap_programs(sim, host):
    """Every task body timed on the host: host[label] += seconds."""
    def wrap(fn, label):
        def run(ctx, task):
            t0 = time.perf_counter()
            try:
                if fn is not None:
                    fn(ctx, task)
            finally:
                host[label] = host.get(label, 0.0) + time.perf_counter() - t0
        return run
    def wrap_value(value, label):
        # a declared reduction's value (dt_allreduce: the wait for the dt terms) runs in the
        # mock engine before the bodies: its host time goes to the task too
        def run(ctx):
            t0 = time.perf_counter()
            try:
                return value(ctx)
            finally:
                host[label] = host.get(label, 0.0) + time.perf_counter() - t0
        return run

    def wrapped(t):
        red = None if t.reduce is None else (t.reduce[0], wrap_value(t.reduce[1], t.label))
        return replace(t, fn=wrap(t.fn, t.label), reduce=red)
    sch = sim.scheduler
    for progs in {id(sch.programs): sch.programs, id(sch.programs_rebalance): sch.programs_rebalance}.values():
        for r, prog in progs.items():
            progs[r] = [wrapped(t) for t in prog]


def one_run(scene, dp, comm, ranks, transport, steps, warmup, precision, schedule, order="auto"):
    from numba import cuda

    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    sc = Scene.from_toml(scene).with_overrides(dp=dp)
    opts = {"halo_transport": transport, "order": order} if comm == "mock" else None
    sim = Simulation(sc, backend="numba-cuda", comm=comm, ranks=ranks, precision=precision, schedule=schedule,
                     comm_options=opts)
    for _ in range(warmup):
        sim.step()
    host: dict = {}
    _wrap_programs(sim, host)
    be = sim.compute
    cuda.synchronize()
    c0 = be.counters()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    cuda.synchronize()
    wall = time.perf_counter() - t0
    c1 = be.counters()
    per = {k: (c1.get(k, 0) - c0.get(k, 0)) / steps for k in c1}
    ids = np.concatenate([be.host_arrays(c.state)["id"] for c in sim.contexts])
    cols = sim.scheduler.times.columns()
    halo_bytes = sum(int(c.state.bytes_sent) for c in sim.contexts)
    rank_steps = steps * sim.nranks
    return {"dp": dp, "comm": comm, "ranks": sim.nranks, "transport": transport if comm == "mock" else None,
            "order": sim.comm.order if comm == "mock" else None,
            "particles": sim.n_total, "steps": steps, "wall_s": wall, "steps_per_s": steps / wall,
            "host_s_per_rank_step": {k: v / rank_steps for k, v in sorted(host.items())},
            "host_s_per_step": sum(host.values()) / steps,
            "per_step": per, "halo_bytes_sent": halo_bytes,
            "timing_rows": int(len(cols["task"])),
            "ids_unique": bool(len(np.unique(ids)) == len(ids) == sim.n_total)}


def match(scene, dp, ranks, transport, steps, schedule):
    """float64: mock `ranks` against single, largest |dx| over the domain's extent."""
    from sphgraph.scene import Scene
    from sphgraph.solver import Simulation
    sc = Scene.from_toml(scene).with_overrides(dp=dp)
    out = {}
    for comm, n in (("single", 1), ("mock", ranks)):
        opts = {"halo_transport": transport} if comm == "mock" else None
        sim = Simulation(sc, backend="numba-cuda", comm=comm, ranks=n, precision="float64", schedule=schedule,
                         comm_options=opts)
        for _ in range(steps):
            sim.step()
        a = sim.frame_arrays()
        out[comm] = a
    ext = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    same_ids = bool(np.array_equal(out["single"]["id"], out["mock"]["id"]))
    dx = float(np.max(np.abs(out["single"]["position"] - out["mock"]["position"]))) / ext if same_ids else None
    return {"dp": dp, "ranks": ranks, "transport": transport, "steps": steps, "same_ids": same_ids,
            "max_dx_over_extent": dx}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "spheric2.toml"))
    ap.add_argument("--dp", type=float, nargs="+", default=[0.006])
    ap.add_argument("--ranks", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--transport", nargs="+", default=["staged"])
    ap.add_argument("--schedule", default="production")
    ap.add_argument("--orders", nargs="+", default=["auto"], help="the mock engine's order(s): auto, clock, eager")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--match", action="store_true")
    ap.add_argument("--match-dp", type=float, default=0.02)
    ap.add_argument("--match-steps", type=int, default=60)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    results = []
    for dp in a.dp:
        configs = [("single", 1, "staged", None)] + [("mock", r, t, o) for r in a.ranks for t in a.transport
                                                     for o in a.orders]
        for rnd in range(a.rounds):
            for comm, r, t, o in configs:     # alternated: every config once per round
                try:
                    res = one_run(a.scene, dp, comm, r, t, a.steps, a.warmup, a.precision, a.schedule, o)
                except Exception as e:   # noqa: BLE001 - reported, the other runs go on
                    res = {"dp": dp, "comm": comm, "ranks": r, "transport": t, "order": o,
                           "error": f"{type(e).__name__}: {e}"}
                res["round"] = rnd
                res["asked_order"] = o
                results.append(res)
                print(json.dumps(res), flush=True)
        single = [x["steps_per_s"] for x in results if x.get("dp") == dp and x["comm"] == "single" and "error" not in x]
        for comm, r, t, o in configs[1:]:
            got = [x["steps_per_s"] for x in results if x.get("dp") == dp and x["comm"] == comm and x["ranks"] == r
                   and x.get("transport") == t and x.get("round") is not None and x.get("asked_order") == o
                   and "error" not in x]
            if single and got:
                ratio = statistics.median(got) / statistics.median(single)
                summary = {"dp": dp, "ranks": r, "transport": t, "order": o, "rounds": len(got),
                           "median_single": statistics.median(single),
                           "median_mock": statistics.median(got), "ratio": ratio}
                results.append({"summary": summary})
                print(json.dumps({"summary": summary}), flush=True)
    if a.match:
        for r in a.ranks:
            for t in a.transport:
                m = match(a.scene, a.match_dp, r, t, a.match_steps, a.schedule)
                results.append({"match": m})
                print(json.dumps({"match": m}), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
