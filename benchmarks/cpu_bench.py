"""CPU speed of the dam breaks against DualSPHysics' figures (shared ANCHORS.md).

    python benchmarks/cpu_bench.py [--out results.json]

Runs `sphgraph bench` (the real scheduled path, numba compile kept out of the
timed steps and reported as compile_s) for the 2D dam break at dp 0.01 (21,001
particles, DualSPHysics' count) and the 3D dam break at dp 0.0085 (171,496),
in float64 and float32, and prints a markdown table with the load average
(the machine is shared: a loaded machine gives low bounds).
"""
import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
EX = os.path.join(HERE, "..", "examples")
CASES = [("dambreak2d.toml", 0.01, 300, 2.2e6), ("dambreak3d.toml", 0.0085, 20, 0.24e6)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="cpu_bench.json")
    ap.add_argument("--precisions", default="float64,float32")
    a = ap.parse_args()
    rows = []
    for scene, dp, steps, dsph in CASES:
        for prec in a.precisions.split(","):
            load0 = os.getloadavg()[0]
            cmd = [sys.executable, "-m", "sphgraph", "bench", os.path.join(EX, scene), "--dp", str(dp),
                   "--steps", str(steps), "--warmup", "3", "--precision", prec, "--json"]
            t0 = time.time()
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            d = json.loads(out)
            d["load_before"] = load0
            d["load_after"] = os.getloadavg()[0]
            d["dualsphysics_particle_steps_per_s"] = dsph
            d["ratio_vs_dualsphysics"] = d["particle_steps_per_s"] / dsph
            d["command"] = " ".join(["sphgraph"] + cmd[3:])
            d["elapsed_s"] = time.time() - t0
            rows.append(d)
            print(f"| {scene} | {d['particles']:,} | {prec} | {d['particle_steps_per_s'] / 1e6:.2f} M | "
                  f"{d['interactions_per_s'] / 1e6:.0f} M | {d['ratio_vs_dualsphysics']:.2f}x | "
                  f"{d['compile_s']:.2f} s | {d['bytes_per_particle']:.0f} | "
                  f"{d['load_before']:.1f}/{d['load_after']:.1f} |", flush=True)
    with open(a.out, "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
