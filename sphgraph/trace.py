"""Task timings out of `output.h5` /timing: Chrome trace events, per-kind sums.

Chrome trace-event JSON (https://docs.google.com/document/d/1CvAClvFfyA5R-PhYUmn5OOQtYMH4h6I0nSsKchNAySU)
opens in Perfetto / chrome://tracing: one process per rank, one thread per lane; a device
timeline (numba-cuda's timing events) likewise.
"""
from __future__ import annotations

import json
import os

import numpy as np

from .errors import InputError
from .graph.kinds import LANES
from .io import read_attrs, read_timing


def load_timing(out_dir) -> dict:
    t = read_timing(out_dir)
    if t is None or len(t.get("rank", ())) == 0:
        raise InputError(f"{out_dir}: /timing: expected task timings in output.h5, found none")
    return t


def chrome_events(t: dict, virtual: bool = False) -> list[dict]:
    events = []
    for r in sorted(set(int(x) for x in t["rank"])):
        events.append({"ph": "M", "name": "process_name", "pid": r, "args": {"name": f"rank {r}"}})
        for i, lane in enumerate(LANES):
            events.append({"ph": "M", "name": "thread_name", "pid": r, "tid": i, "args": {"name": lane}})
    lane_id = {name: i for i, name in enumerate(LANES)}
    for r, s, name, lane, a, b in zip(t["rank"], t["step"], t["task"], t["lane"], t["start"], t["end"]):
        events.append({"ph": "X", "name": str(name), "cat": str(name).split("@")[0], "pid": int(r),
                       "tid": lane_id.get(str(lane), 0), "ts": float(a) * 1e6,
                       "dur": max(float(b) - float(a), 0.0) * 1e6, "args": {"step": int(s)}})
    return events


def write_chrome_trace(out_dir, path) -> str:
    t = load_timing(out_dir)
    attrs = read_attrs(out_dir)
    doc = {"traceEvents": chrome_events(t), "displayTimeUnit": "ms",
           "otherData": {"comm": str(attrs.get("comm", "")), "ranks": int(attrs.get("ranks", 1)),
                         "schedule": str(attrs.get("schedule", "")),
                         "clock": "virtual seconds (mock MPI)" if attrs.get("comm") == "mock" else "wall seconds"}}
    path = os.fspath(path)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f)
    os.replace(tmp, path)
    return path


def device_chrome_events(trace: list) -> list[dict]:
    """Chrome trace events of a device timeline (`NumbaCUDA.device_trace()`: rank, step,
    task, lane, inside, start, end in device seconds): one process per rank, one thread
    per lane (the lane's CUDA stream), copies made inside a task on a thread of their own."""
    lanes = list(LANES) + ["copies"]
    events = []
    for r in sorted({int(e["rank"]) for e in trace}):
        events.append({"ph": "M", "name": "process_name", "pid": r, "args": {"name": f"rank {r} (device)"}})
        for i, lane in enumerate(lanes):
            events.append({"ph": "M", "name": "thread_name", "pid": r, "tid": i, "args": {"name": lane}})
    lane_id = {name: i for i, name in enumerate(lanes)}
    for e in trace:
        tid = lane_id["copies"] if e.get("inside") else lane_id.get(str(e.get("lane")), 0)
        args = {"step": int(e["step"])}
        if e.get("inside"):
            args["inside"] = str(e["inside"])
        events.append({"ph": "X", "name": str(e["task"]), "cat": str(e["task"]).split("@")[0], "pid": int(e["rank"]),
                       "tid": tid, "ts": float(e["start"]) * 1e6,
                       "dur": max(float(e["end"]) - float(e["start"]), 0.0) * 1e6, "args": args})
    return events


def write_device_chrome_trace(trace: list, path, meta: dict | None = None) -> str:
    """A device timeline as Chrome trace-event JSON (opens in Perfetto), written whole."""
    doc = {"traceEvents": device_chrome_events(trace), "displayTimeUnit": "ms",
           "otherData": {"clock": "device seconds (CUDA timing events)", **(meta or {})}}
    path = os.fspath(path)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f)
    os.replace(tmp, path)
    return path


def seconds_by_rank_and_kind(t: dict, timers: bool = False) -> dict:
    """{rank: {kind label: seconds}} over all recorded steps; with `timers`, grouped by the
    seed paper's timer names instead (SendEdge, RecvHalo, SynchroDt, FC, ...; user tasks
    keep their own name)."""
    from .graph.kinds import TaskKind
    names = {k.label: k.timer for k in TaskKind} if timers else {}
    out: dict = {}
    dur = np.asarray(t["end"], float) - np.asarray(t["start"], float)
    for r, name, d in zip(t["rank"], t["task"], dur):
        k = str(name).split("@")[0]
        k = names.get(k, k)
        per = out.setdefault(int(r), {})
        per[k] = per.get(k, 0.0) + float(d)
    return out


def steps_recorded(t: dict) -> int:
    """Number of distinct steps in a timing table."""
    return len(set(int(s) for s in t["step"]))
