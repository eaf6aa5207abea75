"""Schedule lanes as CUDA streams (issue 6 §3): production against bulk-synchronous on
mock ranks sharing one GPU, with the device's own timeline.

For each schedule (and each `--streams` setting: 1 = one stream per lane with events,
0 = everything on the default stream, as before lanes): set-up, warm-up steps (the
first compiles), timed steps (device synchronised before and after), then a few traced
steps: the backend records timing events per task on its lane's stream and around the
edge copies (`edge_d2h`: pack + device -> pinned host in send_edges; `halo_h2d`: pinned
host -> device + pressures in recv_halo). Per rank and force stage it reports how long
forces_interior ran on the device while the edges of that stage were copied: the rank's
own (`own_edge_d2h`, `own_halo_h2d`) and its neighbours' (`nb_edge_d2h`: the edges they
copy down to send; `nb_halo_h2d`: the halos they upload), and how many interior force
tasks overlapped any of them (`interior_overlapping_edges` of `interior_tasks`).

In production the interior forces are launched right after the edge sends are posted,
before any halo is received, so on the device they run while edges travel (copied down
by the neighbour, sent, uploaded); bulk-synchronous receives every halo before it
launches any force. The mock ranks run in one process and share the GPU (their streams
are their own); the host runs the ranks' tasks one after the other, so at ~1 M particles
the host work between a rank's interior launch and its own halo upload outlasts the
interior forces (about 2 ms on an H200): the overlap seen there is with the neighbour's
edge copy. Under mpiexec each rank has its own host process.
SPHERIC test 2 (examples/spheric2.toml) by default, `--scene` another.

    python3 benchmarks/gpu_lanes.py --dp 0.01 --ranks 2 --steps 10 --warmup 3 --json out.json
Prints one JSON line per run and writes everything to --json.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_scene(path, dp):
    from sphgraph.scene import Scene
    return Scene.from_toml(path).with_overrides(dp=dp)


def overlaps(trace) -> list:
    """Per (rank, step, stage): forces_interior's device interval and how long it overlapped
    the edge copies of that stage: the rank's own (`own_*`: its edges copied down in
    send_edges, its halo uploaded in recv_halo_k) and its neighbours' (`nb_*`: the edges
    they copy down to send, the halos they upload), in seconds."""
    by = {}
    for e in trace:
        by.setdefault(e["step"], []).append(e)
    out = []
    for step, rows in sorted(by.items()):
        for inter in (e for e in rows if e["task"].startswith("forces_interior@")):
            s = inter["task"].split("@")[1]
            ov = {"own_edge_d2h": 0.0, "own_halo_h2d": 0.0, "nb_edge_d2h": 0.0, "nb_halo_h2d": 0.0,
                  "own_send_edges": 0.0, "nb_send_edges": 0.0}
            for c in rows:
                # staged: the copies; ipc: the edge pack itself (send_edges@s on its stream)
                if c["task"] in ("edge_d2h", "halo_h2d") and (c["inside"] or "").endswith("@" + s):
                    name = c["task"]
                elif c["task"] == f"send_edges@{s}" and not c["inside"]:
                    name = "send_edges"
                else:
                    continue
                key = ("own_" if c["rank"] == inter["rank"] else "nb_") + name
                ov[key] += max(0.0, min(c["end"], inter["end"]) - max(c["start"], inter["start"]))
            out.append({"rank": inter["rank"], "step": step, "stage": int(s),
                        "interior_s": inter["end"] - inter["start"], **ov})
    return out


def run(dp, ranks, schedule, streams, steps, warmup, trace_steps, precision, scene, profile=None, chrome=None):
    os.environ["SPHGRAPH_CUDA_STREAMS"] = str(streams)   # read by the backend's constructor
    from numba import cuda

    from sphgraph.solver import Simulation
    t0 = time.perf_counter()
    sim = Simulation(load_scene(scene, dp), backend="numba-cuda", precision=precision, comm="mock", ranks=ranks,
                     schedule=schedule)
    setup = time.perf_counter() - t0
    sim.scheduler.record_times = False
    t0 = time.perf_counter()
    for _ in range(warmup):
        sim.step()
    cuda.synchronize()
    warm = time.perf_counter() - t0
    prof = None
    if profile:
        import cProfile
        prof = cProfile.Profile()
        prof.enable()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    cuda.synchronize()
    wall = time.perf_counter() - t0
    if prof is not None:
        import io
        import pstats
        prof.disable()
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(25)
        with open(profile, "a") as f:
            f.write(f"== {schedule} streams={streams} dp={dp}: {steps} steps, {wall:.3f} s\n{buf.getvalue()}\n")
    sim.compute.start_device_trace()
    first = sim.step_count
    for _ in range(trace_steps):
        sim.step()
    trace = [e for e in sim.compute.device_trace() if e["step"] >= first]
    ov = overlaps(trace)
    r = {"scene": str(scene), "dp": dp, "ranks": ranks, "schedule": schedule, "streams": streams, "precision": precision,
         "particles": int(sim.n_total), "device": sim.compute.device_name(), "uses_lanes": sim.compute.uses_lanes,
         "setup_s": setup, "warmup_s": warm, "steps": steps, "steps_per_s": steps / wall,
         "particle_steps_per_s": steps * sim.n_total / wall, "trace_steps": trace_steps,
         "overlap": ov, "interior_s": sum(x["interior_s"] for x in ov),
         **{k + "_s": sum(x[k] for x in ov) for k in ("own_edge_d2h", "own_halo_h2d", "nb_edge_d2h", "nb_halo_h2d",
                                                        "own_send_edges", "nb_send_edges")},
         "interior_tasks": len(ov),
         "interior_overlapping_edges": sum(1 for x in ov if x["own_edge_d2h"] + x["own_halo_h2d"] + x["nb_edge_d2h"]
                                           + x["nb_halo_h2d"] + x["own_send_edges"] + x["nb_send_edges"] > 0),
         "trace": trace}
    if chrome:
        from sphgraph.trace import write_device_chrome_trace
        write_device_chrome_trace(trace, Path(chrome) / f"device_{schedule}_dp{dp}_r{ranks}_s{streams}.json",
                                  {"schedule": schedule, "ranks": ranks, "dp": dp, "particles": int(sim.n_total)})
    sim.compute.trace = None
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "spheric2.toml"))
    ap.add_argument("--dp", type=float, nargs="+", default=[0.01])
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--trace-steps", type=int, default=2)
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--schedules", nargs="+", default=["production", "bulk-synchronous"])
    ap.add_argument("--streams", type=int, nargs="+", default=[1], help="1: a stream per lane; 0: default stream")
    ap.add_argument("--profile", default=None, help="append a cProfile of the timed steps (top 25) to this file")
    ap.add_argument("--chrome", default=None, help="write each run's device timeline (Perfetto JSON) into this folder")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    out = {"date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "command": " ".join(sys.argv), "runs": []}
    for dp in a.dp:
        for streams in a.streams:
            for sch in a.schedules:
                r = run(dp, a.ranks, sch, streams, a.steps, a.warmup, a.trace_steps, a.precision, a.scene, a.profile, a.chrome)
                out["runs"].append(r)
                print(json.dumps({k: v for k, v in r.items() if k not in ("trace", "overlap")}), flush=True)
                if a.json:
                    Path(a.json).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
