"""How far round-off moves the regular-wave check of tests/test_waves.py.

The test runs `wave_flume.flume` at dp 0.015 to 8 s (order-2 stroke, no artificial viscosity,
water's laminar viscosity) and asserts the mean zero up-crossing height of waves 3-6 one
wavelength from the paddle within 5 % of the paddle's H. Particle flows are chaotic: a change at
the last bit of the start grows into a different particle history, and the measured height
moves with it. Each run here is that test's flume with the fluid's start positions moved by
`initial.jitter` x dp (uniform, the scene's fixed seed; 1e-12 x dp is 1.5e-14 m, round-off of
positions near 1 m), so the spread of the heights is the spread a different CPU or compiler
(other SIMD widths, other libm) can give the test.

    python benchmarks/flume_spread.py [--jitter 0 1e-12 2e-12 ...] [--workers 4] [--json out.json]
                                      [--boundary mdbc]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def one(jitter: float, boundary: str = "dbc", end: float = 8.0, dp: float = 0.015) -> dict:
    sys.path.insert(0, HERE)
    import wave_flume
    from sphgraph import waves
    t0 = time.perf_counter()
    r = wave_flume.flume(dp=dp, end_time=end, height=0.08, period=1.0, depth=0.3, order=2,
                         physics={"visc_alpha": 0.0, "laminar_nu": 1e-6, "boundary": boundary},
                         initial={"jitter": jitter} if jitter > 0 else None)
    g = next(iter(r["eta"]))
    cg = waves.group_velocity(1.0, 0.3)
    st = waves.wave_stats(r["t"], r["eta"][g], r["L"] / cg + 2.0, end)   # the test's window
    return {"jitter": jitter, "boundary": boundary, "dp": dp, "particles": r["particles"],
            "H_err": st["height"] / 0.08 - 1.0, "T_err": st["period"] / 1.0 - 1.0,
            "heights": [float(h) for h in st["heights"]], "steps": r["steps"],
            "wall_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jitter", type=float, nargs="+", default=[0.0, 1e-12, 2e-12, 3e-12])
    ap.add_argument("--workers", type=int, default=1, help="runs side by side (processes)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--dp", type=float, default=0.015, help="particle spacing (the test's: 0.015)")
    ap.add_argument("--boundary", default="dbc", choices=("dbc", "mdbc"),
                    help="[physics] boundary of the tank and the paddle (mdbc: the paddle's ghosts move with it)")
    a = ap.parse_args(argv)
    out = []

    def done(r):   # each run as it ends (the JSON too): a cut-off batch keeps what finished
        out.append(r)
        print(f"jitter {r['jitter']:.0e}: H {100 * r['H_err']:+.2f} %, T {100 * r['T_err']:+.2f} %, "
              f"waves {', '.join(f'{h / 0.08:.3f}' for h in r['heights'])} H, {r['wall_s']:.0f} s", flush=True)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(sorted(out, key=lambda x: x["jitter"]), f, indent=1)
    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(a.workers) as ex:
            for fut in as_completed([ex.submit(one, j, a.boundary, 8.0, a.dp) for j in a.jitter]):
                done(fut.result())
    else:
        for j in a.jitter:
            done(one(j, a.boundary, 8.0, a.dp))
    hs = [100 * r["H_err"] for r in out]
    print(f"H error over {len(hs)} runs: {min(hs):+.2f} ... {max(hs):+.2f} %, mean {sum(hs) / len(hs):+.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
