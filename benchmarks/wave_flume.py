"""Regular waves in a 2D flume: piston (or flap) wavemaker, damping zone at the far end.

Measures the wave height and period at one wavelength from the paddle against the
target of first-order wavemaker theory, and the reflection coefficient from two
gauges (Goda & Suzuki 1976). tests/test_waves.py runs `flume()` at dp 0.015 to 6.5 s
(height and period, second-order generation, no artificial viscosity) and a 2.4 L flume at
dp 0.03 to 8 s (reflection); this script runs the long version:

    python benchmarks/wave_flume.py [--dp 0.01] [--end 8] [--type piston|flap] [--no-damping]
                                    [--visc-alpha A] [--laminar-nu NU] [--order 1|2] [--gauges 0.28 0.5 ...]

"H_err" is the zero up-crossing height (mean crest-to-trough) at one wavelength; "along"
gives it, and the first-harmonic height 2 a1 ("H1_err"), at every gauge.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

import sphgraph
from sphgraph import waves
from sphgraph.scene import Scene


def flume_scene(dp=0.02, depth=0.3, height=0.08, period=1.0, length=None, damping=True,
                paddle="piston", end_time=4.5, coefsound=10.0, integrator="verlet", coefh=1.2,
                physics=None, order=1, initial=None):
    """A flume scene dict: paddle at x = 0 (2 layers, moving) with the tank's end wall behind
    its stroke, beach-less far wall, damping over the last 1.2 wavelengths. Returns (dict,
    wavelength).

    coefh 1.2 (h = 1.70 dp): with coefh 1.0 (h = 1.41 dp) the SPH waves are ~9 % longer than
    w^2 = g k tanh(kd) gives (benchmarks/wave_dispersion.py: period of a k-mode 5 % short at
    dp 0.03 and 0.02), so the paddle's volume flux makes a ~9 % lower wave (docs/features.md)."""
    L = waves.wavelength(period, depth)
    length = length or round(3.4 * L / dp) * dp
    # the tank starts two spacings behind the paddle's back stroke: a fixed end wall at the
    # paddle would stand in the water's way once S/2 > dp (sphgraph.motion refuses it)
    kd = 2 * math.pi / L * depth
    ratio = waves.piston_ratio(kd) if paddle == "piston" else waves.flap_ratio(kd)
    top = depth + 3 * height + 0.1
    reach = 0.5 * height / ratio * (1.0 if paddle == "piston" else top / depth)  # a flap's top goes further
    x0 = -dp * math.ceil(reach / dp + 2)
    d = {"format": 1, "name": "wave_flume2d", "dim": 2, "dp": dp, "end_time": end_time,
         "output_interval": end_time,
         "domain": {"min": [-0.3, -3 * dp], "max": [length + 3 * dp, top + 0.3], "origin": [0.0, 0.0]},
         "physics": {"coefsound": coefsound, "integrator": integrator, "hswl": depth, "coefh": coefh},
         "initial": {"hydrostatic": True},
         "fluid": [{"type": "box", "min": [2 * dp, dp], "max": [length - dp, depth]}],
         "boundary": [{"type": "tank", "min": [x0, 0.0], "max": [length, top], "layers": 2},
                      {"type": "wall", "name": "paddle", "min": [0.0, dp], "max": [0.0, top],
                       "layers": 2, "direction": "+"}],
         "motion": [{"body": "paddle", "type": paddle, "height": height, "period": period,
                     "depth": depth, "ramp": 1.0}]}
    if order != 1:
        d["motion"][0]["order"] = order
    d["physics"].update(physics or {})     # e.g. {"visc_alpha": 0.0, "laminar_nu": 1e-6}
    d["initial"].update(initial or {})     # e.g. {"jitter": 1e-12}: benchmarks/flume_spread.py
    if damping:
        d["damping"] = [{"axis": "x", "start": length - 1.2 * L, "end": length, "redumax": 10.0}]
    return d, L


def flume(dp=0.02, end_time=4.5, sample=0.02, gauges=None, comm="single", ranks=1, **kw):
    """Run the flume; returns {"t": [...], "eta": {x: [...]}, "L": ..., "scene": Scene, ...}."""
    d, L = flume_scene(dp=dp, end_time=end_time, **kw)
    scene = Scene.from_dict(d)
    depth = kw.get("depth", 0.3)
    x_paddle = 1.5 * dp            # mean position of the paddle's wet face (2 layers from x = 0)
    gauges = gauges or [x_paddle + L]
    sim = sphgraph.Simulation(scene, comm=comm, ranks=ranks)
    h = sim.consts.h
    t_out, eta = [], {g: [] for g in gauges}
    next_t = 0.0
    t0 = time.perf_counter()
    while sim.time < end_time - 1e-12:
        if sim.time >= next_t - 1e-12:
            a = sim.frame_arrays()
            t_out.append(sim.time)
            for g in gauges:
                eta[g].append(waves.surface_elevation(a["position"], a["kind"], g, dp, h,
                                                      0.5 * depth, depth + 3 * kw.get("height", 0.08))
                              - depth)
            next_t += sample
        sim.step()
    return {"t": np.array(t_out), "eta": {g: np.array(v) for g, v in eta.items()}, "L": L,
            "steps": sim.step_count, "wall_s": time.perf_counter() - t0, "particles": sim.n_total,
            "sim": sim}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dp", type=float, default=0.01)
    ap.add_argument("--end", type=float, default=8.0)
    ap.add_argument("--type", default="piston", choices=("piston", "flap"))
    ap.add_argument("--height", type=float, default=0.08)
    ap.add_argument("--no-damping", action="store_true")
    ap.add_argument("--visc-alpha", type=float, help="artificial viscosity alpha (default 0.01)")
    ap.add_argument("--laminar-nu", type=float, help="laminar viscosity [m^2/s] (default off)")
    ap.add_argument("--order", type=int, default=1, choices=(1, 2), help="piston wavemaker order (2: Madsen 1971)")
    ap.add_argument("--boundary", choices=("dbc", "mdbc", "mdbc-noslip"),
                    help="wall and paddle treatment (default: the scene's, dbc)")
    ap.add_argument("--gauges", type=float, nargs="+", default=[0.28, 0.5, 0.75, 1.0, 1.25],
                    help="gauge positions in wavelengths from the paddle (1 and 1.25 are always added)")
    args = ap.parse_args(argv)
    H, T = args.height, 1.0
    L = waves.wavelength(T, 0.3)
    x_paddle = 1.5 * args.dp
    fracs = sorted(set(args.gauges) | {1.0, 1.25})
    gs = [x_paddle + f * L for f in fracs]
    phys = {k: v for k, v in (("visc_alpha", args.visc_alpha), ("laminar_nu", args.laminar_nu),
                              ("boundary", args.boundary)) if v is not None}
    r = flume(dp=args.dp, end_time=args.end, paddle=args.type, height=H, damping=not args.no_damping,
              gauges=gs, physics=phys, order=args.order)
    cg = waves.group_velocity(T, 0.3)
    g1, g2 = gs[fracs.index(1.0)], gs[fracs.index(1.25)]
    t_from = L / cg + 2 * T
    st = waves.wave_stats(r["t"], r["eta"][g1], t_from, args.end)
    refl = reflection(r["t"], r["eta"][g1], r["eta"][g2], 0.25 * L, T, t_from, args.end)
    along = []
    for f, g in zip(fracs, gs):   # each gauge from the time the full-height waves reach it
        t0 = g / cg + 2 * T
        sg = waves.wave_stats(r["t"], r["eta"][g], t0, args.end)
        along.append({"at_L": f, "H_err": sg["height"] / H - 1, "heights": sg["heights"],
                      "H1_err": first_harmonic(r["t"], r["eta"][g], T, t0, args.end) / H - 1})
    out = {"dp": args.dp, "type": args.type, "H_target": H, "T_target": T, "physics": phys, "order": args.order,
           "H": st["height"], "T": st["period"], "H_err": st["height"] / H - 1, "T_err": st["period"] / T - 1,
           "reflection": refl, "along": along, "particles": r["particles"], "steps": r["steps"],
           "wall_s": r["wall_s"], "window": [t_from, args.end]}
    json.dump(out, sys.stdout, indent=1)
    print()


def first_harmonic(t, eta, period, t_from, t_to):
    """2 a1: twice the least-squares amplitude of eta at the wave frequency over [t_from, t_to]."""
    s = (t >= t_from) & (t <= t_to) & np.isfinite(eta)
    w = 2 * math.pi / period
    A = np.stack([np.cos(w * t[s]), np.sin(w * t[s]), np.ones(s.sum())], axis=1)
    c = np.linalg.lstsq(A, eta[s], rcond=None)[0]
    return 2.0 * math.hypot(c[0], c[1])


def reflection(t, eta1, eta2, dx, period, t_from, t_to):
    """Goda & Suzuki (1976) two-gauge separation at the wave frequency: Kr = a_R / a_I."""
    s = (t >= t_from) & (t <= t_to)
    t, e1, e2 = t[s], eta1[s] - eta1[s].mean(), eta2[s] - eta2[s].mean()
    w = 2 * math.pi / period
    # least-squares amplitude of the first harmonic at each gauge
    A = np.stack([np.cos(w * t), np.sin(w * t)], axis=1)
    c1 = np.linalg.lstsq(A, e1, rcond=None)[0]
    c2 = np.linalg.lstsq(A, e2, rcond=None)[0]
    z1, z2 = complex(c1[0], -c1[1]), complex(c2[0], -c2[1])
    k = 2 * math.pi / waves.wavelength(period, 0.3)
    # eta = Re[(aI e^{-ikx} + aR e^{ikx}) e^{iwt}]
    a_i = (z1 * np.exp(1j * k * dx) - z2) / (2j * np.sin(k * dx)) * (-1)
    a_r = (z2 - z1 * np.exp(-1j * k * dx)) / (2j * np.sin(k * dx))
    return float(abs(a_r) / abs(a_i))


if __name__ == "__main__":
    main()
