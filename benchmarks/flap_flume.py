"""The regular-wave flume of benchmarks/flume_spread.py with a flap instead of the piston (order 1),
one start, `[physics] boundary` from the command line: H and T at one wavelength.

    python benchmarks/flap_flume.py dbc|mdbc [--json out.json]
"""
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import wave_flume  # noqa: E402
from sphgraph import waves  # noqa: E402

b = sys.argv[1]
t0 = time.perf_counter()
r = wave_flume.flume(dp=0.015, end_time=8.0, height=0.08, period=1.0, depth=0.3, paddle="flap",
                     physics={"visc_alpha": 0.0, "laminar_nu": 1e-6, "boundary": b})
g = next(iter(r["eta"]))
cg = waves.group_velocity(1.0, 0.3)
st = waves.wave_stats(r["t"], r["eta"][g], r["L"] / cg + 2.0, 8.0)
out = {"paddle": "flap", "boundary": b, "dp": 0.015, "H_err": st["height"] / 0.08 - 1, "T_err": st["period"] - 1,
       "heights": [float(h) for h in st["heights"]], "steps": r["steps"], "particles": r["particles"],
       "wall_s": time.perf_counter() - t0}
print(json.dumps(out))
if "--json" in sys.argv:
    with open(sys.argv[sys.argv.index("--json") + 1], "w") as f:
        json.dump(out, f, indent=1)
