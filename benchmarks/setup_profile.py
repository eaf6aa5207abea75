"""Where the host's set-up of SPHERIC 2 goes (issue 6 §6, the largest scene): seconds and
peak host bytes per particle of each phase, one fresh process per dp.

Phases: `scene` (read and validate the TOML at dp), `count` (the particle count: the
lattice, or the fast path's row counts), `constants` (hswl and what follows from it),
`particles` (the rows: positions, ids, kinds, densities), `state` (`Simulation` from those
rows: rank state and the backend's `prepare`, which on numba-cuda is the upload).
Peak memory per phase is the process's resident high-water mark (Linux: VmHWM, reset before
each phase through /proc/self/clear_refs) less what was resident when the phase began.

With `--backend numba-cuda` and no GPU, run it under NUMBA_ENABLE_CUDASIM=1: the device
arrays are then host arrays, so the `state` phase's peak counts them too (reported apart as
`device_bytes_per_particle`, the backend's own count), and its time includes the
simulator's copies (`simulated_copy_s`, from a profile of the phase, left out of
`state_host_s`).

    python3 benchmarks/setup_profile.py --dp 0.006 0.004 --json out.json
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def measure(dp, backend, precision):
    import cProfile
    import pstats

    import numpy as np
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from gpu_bench import spheric2
    from sphgraph.solver import Simulation
    out = {"dp": dp, "backend": backend, "precision": precision, "phases": {}}
    keep = {}

    def phase(name, fn, profile=False):
        import gc
        gc.collect()
        rss0 = _status("VmRSS")
        _reset_peak()
        pr = cProfile.Profile() if profile else None
        t0 = time.perf_counter()
        if pr:
            pr.enable()
        r = fn()
        if pr:
            pr.disable()
        s = time.perf_counter() - t0
        out["phases"][name] = {"s": s, "peak_extra_bytes": _status("VmHWM") - rss0,
                               "held_bytes": _status("VmRSS") - rss0}
        keep[name] = pr
        return r

    sc = phase("scene", lambda: spheric2(dp))
    nf, nb = phase("count", sc.count_particles)
    phase("constants", lambda: sc.constants)
    dtype = np.dtype(precision)
    p = phase("particles", lambda: sc.build_particles(dtype))
    sim = phase("state", lambda: Simulation(sc, backend=backend, precision=precision, particles=p),
                profile=True)
    n = nf + nb
    out.update(particles=n, fluid=nf, boundary=nb, rss_end_bytes=_status("VmRSS"))
    st = pstats.Stats(keep["state"])
    copy_s = sum(v[2] for k, v in st.stats.items() if k[2] == "copy_to_device" and "simulator" in k[0])
    ph = out["phases"]
    if backend == "numba-cuda":
        dev = sim.compute.state_bytes(sim.contexts[0].state)
        out["device_bytes_per_particle"] = dev / n
        out["simulated_copy_s"] = copy_s
        ph["state"]["state_host_s"] = ph["state"]["s"] - copy_s
    for v in ph.values():
        v["s_per_M"] = v["s"] / (n / 1e6)
        v["peak_B_per_particle"] = v["peak_extra_bytes"] / n
        v["held_B_per_particle"] = v["held_bytes"] / n
    out["total_s"] = sum(v["s"] for v in ph.values())
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, nargs="+", default=[0.006, 0.004])
    ap.add_argument("--backend", default="numba-cuda")
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--json", default=None)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # the child process
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(measure(a.dp[0], a.backend, a.precision)))
        return None
    runs = []
    for dp in a.dp:   # a fresh process per dp: peak memory and caches of its own
        cmd = [sys.executable, __file__, "--one", "--dp", str(dp), "--backend", a.backend,
               "--precision", a.precision]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode:
            print(r.stderr, file=sys.stderr)
            runs.append({"dp": dp, "error": r.stderr[-2000:]})
            continue
        res = json.loads(r.stdout.strip().splitlines()[-1])
        runs.append(res)
        line = " ".join(f"{k} {v['s']:.2f} s ({v['s_per_M']:.3f} s/M, peak +{v['peak_B_per_particle']:.0f} B)"
                        for k, v in res["phases"].items())
        print(f"dp {dp}: {res['particles']:,} particles: {line}; total {res['total_s']:.2f} s", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps({"runs": runs, "command": " ".join(sys.argv)}, indent=1))
    return runs


if __name__ == "__main__":
    main()
