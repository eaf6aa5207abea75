"""Dispersion of SPH gravity waves: one wavelength of a periodic channel (d = 0.3 m), started
with the velocity field of a linear progressive wave; the surface elevation's period is fitted
and compared with w^2 = g k tanh(kd). About 30 s at dp 0.03 on 2 cores.

    python benchmarks/wave_dispersion.py [--dp 0.03] [--coefh 1.0 1.2 1.5] [--kernel wendland]

Measured (docs/features.md): Wendland, coefh 1.0: period 5 % short (dp 0.03 and 0.02);
coefh 1.2: -0.6 %; 1.5: +0.6 %.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from sphgraph import Scene, Simulation, waves


def channel(dp=0.03, depth=0.3, length=1.38, amp=0.01, coefh=1.0, kernel="wendland", periods=5.0):
    """Run the channel; returns {"T_theory", "T_sph", "amp"}."""
    n = round(length / dp)
    lp, nz = n * dp, round(depth / dp)
    k = 2 * math.pi / lp
    w = math.sqrt(9.81 * k * math.tanh(k * depth))
    end = periods * 2 * math.pi / w
    sc = {"format": 1, "dim": 2, "dp": dp, "end_time": end,
          "domain": {"min": [0.0, -3 * dp], "max": [lp, depth + 0.5], "origin": [0.0, 0.0], "periodic": ["x"]},
          "physics": {"coefsound": 10.0, "hswl": depth, "coefh": coefh, "kernel": kernel},
          "initial": {"hydrostatic": True},
          "fluid": [{"type": "box", "min": [0.0, dp], "max": [lp - dp, nz * dp]}],
          "boundary": [{"type": "wall", "min": [0.0, 0.0], "max": [lp - dp, 0.0], "layers": 2}]}
    sim = Simulation(Scene.from_dict(sc))
    ysurf = nz * dp + 0.5 * dp          # the fluid's surface: half a spacing above the top row
    for c in sim.contexts:              # linear progressive wave eta = amp cos(kx - wt) (Dean & Dalrymple ch. 4)
        p = c.state.particles
        fl = p.kind == 0
        x, z = p.pos[fl, 0], p.pos[fl, 1] - ysurf
        p.vel[fl, 0] = amp * w * np.cosh(k * (z + depth)) / math.sinh(k * depth) * np.cos(k * x)
        p.vel[fl, 1] = amp * w * np.sinh(k * (z + depth)) / math.sinh(k * depth) * np.sin(k * x)
        p.vel_m1[:] = p.vel
    h = sim.consts.h
    t, e, nxt = [], [], 0.0
    while sim.time < end:
        if sim.time >= nxt:
            a = sim.frame_arrays()
            t.append(sim.time)
            e.append(waves.surface_elevation(a["position"], a["kind"], 0.25 * lp, dp, h, 0.3 * depth,
                                             depth + 10 * amp) - ysurf)
            nxt += 0.01
        sim.step()
    t, e = np.array(t), np.array(e)
    return {"T_theory": 2 * math.pi / w, **fit_period(t, e - e.mean(), w), "steps": sim.step_count}


def fit_period(t, e, w0):
    """Least-squares sinusoid a sin(wt) + b cos(wt) + c: the best w near w0 (grid, then refined)."""
    def res(w):
        m = np.stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)], 1)
        c = np.linalg.lstsq(m, e, rcond=None)[0]
        return float(((m @ c - e) ** 2).sum()), math.hypot(c[0], c[1])
    ws = np.linspace(0.8 * w0, 1.25 * w0, 451)
    best = min(ws, key=lambda w: res(w)[0])
    best = min(np.linspace(0.999 * best, 1.001 * best, 201), key=lambda w: res(w)[0])
    return {"T_sph": 2 * math.pi / best, "amp": res(best)[1]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.03)
    ap.add_argument("--coefh", type=float, nargs="+", default=[1.0, 1.2, 1.5])
    ap.add_argument("--kernel", default="wendland", choices=("wendland", "cubic"))
    args = ap.parse_args(argv)
    for ch in args.coefh:
        r = channel(dp=args.dp, coefh=ch, kernel=args.kernel)
        r.update(dp=args.dp, coefh=ch, kernel=args.kernel, T_err=r["T_sph"] / r["T_theory"] - 1)
        json.dump(r, sys.stdout)
        print()


if __name__ == "__main__":
    main()
