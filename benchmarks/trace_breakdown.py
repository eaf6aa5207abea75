"""The seed paper's per-rank breakdown (Figs. 11-12) from a device timeline instead of /timing.

    python benchmarks/trace_breakdown.py TRACE.json [TRACE.json ...] [--png-dir docs]

TRACE.json: a device trace in Perfetto / Chrome JSON as `benchmarks/gpu_lanes.py --chrome` writes
it (each task's interval on its rank's lane stream, from CUDA timing events). For mock ranks
sharing one GPU this is where /timing cannot help: the mock's /timing is its virtual clock. Each
task's device seconds are grouped by the paper's timer names (SendEdge, RecvHalo, SynchroDt, FC,
NL, PU, ...) per rank; prints ms a step and the share of the rank's task time, and draws
`sphgraph plot breakdown`'s bars (`plots.plot_breakdown` with this table). Tasks of one rank on
different lanes overlap on the device, so the shares are of summed task time, not of the step.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def timing_of(trace: dict) -> dict:
    """The trace's task intervals as /timing's columns (copies inside tasks left out)."""
    t = {"rank": [], "task": [], "start": [], "end": [], "step": []}
    for e in trace["traceEvents"]:
        if e.get("ph") != "X" or e.get("args", {}).get("inside"):
            continue
        t["rank"].append(int(e["pid"]))
        t["task"].append(e["name"])
        t["start"].append(e["ts"] * 1e-6)
        t["end"].append((e["ts"] + e["dur"]) * 1e-6)
        t["step"].append(int(e["args"]["step"]))
    return t


def main(argv=None):
    sys.path.insert(0, ROOT)
    from sphgraph.plots import plot_breakdown
    from sphgraph.trace import seconds_by_rank_and_kind
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("traces", nargs="+")
    ap.add_argument("--png-dir", default=None, help="write breakdown_<trace name>.png here")
    a = ap.parse_args(argv)
    out = []
    for path in a.traces:
        trace = json.load(open(path))
        meta = trace.get("otherData", {})
        t = timing_of(trace)
        steps = len(set(t["step"]))
        per = seconds_by_rank_and_kind(t, timers=True)
        timers = sorted({k for d in per.values() for k in d})
        print(f"\n{os.path.basename(path)}: {meta.get('schedule')} schedule, {meta.get('ranks')} ranks, "
              f"{meta.get('particles')} particles, {steps} traced steps; device ms a step (share of the rank's task time)")
        print("| rank | " + " | ".join(timers) + " |")
        print("|---" * (len(timers) + 1) + "|")
        for r in sorted(per):
            tot = sum(per[r].values())
            print(f"| {r} | " + " | ".join(f"{1e3 * per[r].get(k, 0.0) / steps:.2f} ({100 * per[r].get(k, 0.0) / tot:.1f} %)"
                                          for k in timers) + " |")
        row = {"trace": path, "meta": meta, "steps": steps,
               "ms_per_step": {r: {k: 1e3 * v / steps for k, v in d.items()} for r, d in per.items()}}
        if a.png_dir:
            name = os.path.splitext(os.path.basename(path))[0]
            row["png"] = plot_breakdown(a.png_dir, os.path.join(a.png_dir, f"breakdown_{name}.png"), timing=t,
                                        title=f"device time by task: {meta.get('ranks')} mock ranks, "
                                              f"{meta.get('schedule')} ({meta.get('particles')} particles)")
        out.append(row)
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
