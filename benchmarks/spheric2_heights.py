"""SPHERIC test 2 (the MARIN dam break onto a box): water heights at the four gauges against
Kleefsman et al. 2005's measurements, DualSPHysics' formulation beside the options of issue 22
(mDBC walls; the low-dissipation Riemann pressure term), same resolution, same gauges.

    python benchmarks/spheric2_heights.py --backend numba-cuda --precision float32 --dp 0.02 \\
        --runs dsph,mdbc,zhang-mdbc --json $OUT/spheric2_heights.json --plot $OUT/spheric2_heights.png

Each run is the validation case as `sphgraph validate spheric2` runs it (`run_case`: the
`[probes] heights` sampler every 0.01 s, compared at the data's times over 0-6 s with no
time shift, and the eight pressure sensors on the box every 2 ms, sphgraph.validation.sensors).
One JSON line per run as it finishes (metrics, particles, steps, wall seconds, compile
included); `--json` also holds each run's series, `--plot` draws every run against the data,
one panel a gauge or a sensor (pressures as running means over the case's smooth_peak_t).
A run that fails numerically is recorded with its failure and the sweep goes on.
`--rescore FILE... --window T` runs nothing: it scores the stored series of earlier `--json`
files over 0-T s (the case's metrics, `cases.height_metrics`), so that a run cut short at
`--t-end` compares with full runs over the same window; `--replot FILE... --plot PNG` draws them.
"""
from __future__ import annotations

import argparse
import json
import sys

# run: (params over the case's, physics overrides)
RUNS = {"dsph": ({}, {}),                                     # the case as shipped: DualSPHysics' set-up
        "mdbc": ({"boundary": "mdbc"}, {}),                   # mDBC walls (the case's 3 layers)
        # the low-dissipation pressure and walls that met Buchner's targets (docs/validation.md)
        "zhang-mdbc": ({"boundary": "mdbc"}, {"riemann": "zhang2017", "riemann_eta": 0.3}),
        "zhang": ({}, {"riemann": "zhang2017", "riemann_eta": 0.3}),
        # mDBC walls as deep as the kernel's support (h = 2 dp here: 4 layers; docs/validation.md,
        # "Wall penetration map": three layers of mDBC let a fast jet through)
        "mdbc4": ({"boundary": "mdbc", "layers": 4}, {}),
        "zhang-mdbc4": ({"boundary": "mdbc", "layers": 4}, {"riemann": "zhang2017", "riemann_eta": 0.3}),
        # the same with the walls cancelling the Riemann term's density dissipation next to them
        "zhang-mdbc-cancel": ({"boundary": "mdbc"}, {"riemann": "zhang2017", "riemann_eta": 0.3,
                                                     "riemann_wall": "cancel"}),
        "zhang-mdbc4-cancel": ({"boundary": "mdbc", "layers": 4}, {"riemann": "zhang2017", "riemann_eta": 0.3,
                                                                  "riemann_wall": "cancel"}),
        # the walls adding no jump, every fluid row's jump without its linear part
        "zhang-mdbc4-renorm": ({"boundary": "mdbc", "layers": 4}, {"riemann": "zhang2017", "riemann_eta": 0.3,
                                                                  "riemann_jump": "renormalised"}),
        # the same, the walls cancelling the jump of the rows it cannot renormalise
        "zhang-mdbc4-renorm-cancel": ({"boundary": "mdbc", "layers": 4},
                                      {"riemann": "zhang2017", "riemann_eta": 0.3, "riemann_jump": "renormalised",
                                       "riemann_wall": "cancel"}),
        "zhang-noslip4-renorm": ({"boundary": "mdbc-noslip", "layers": 4},
                                 {"riemann": "zhang2017", "riemann_eta": 0.3, "riemann_jump": "renormalised",
                                  "laminar_nu": 1e-6}),
        # bed friction: no-slip mDBC walls and water's laminar viscosity (1.0e-6 m^2/s, not fitted)
        "noslip4": ({"boundary": "mdbc-noslip", "layers": 4}, {"laminar_nu": 1e-6}),
        "zhang-noslip4-cancel": ({"boundary": "mdbc-noslip", "layers": 4},
                                 {"riemann": "zhang2017", "riemann_eta": 0.3, "riemann_wall": "cancel",
                                  "laminar_nu": 1e-6})}


def plot(rows, path, case) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from sphgraph.validation import load
    from sphgraph.validation.sensors import running_mean
    data, _ = load(case.reference["dataset"])
    pdata, _ = load(case.reference["pressures"])
    prm = case.params
    gauges, sensors = prm["gauges"], prm["sensors"]
    w, dt = float(prm["smooth_peak_t"]), float(prm["dt_sample_p"])
    fig, axes = plt.subplots(4, 3, figsize=(16, 13))
    for ax, g in zip(axes.ravel(), gauges):
        ax.plot(data[:, 0], data[:, int(g[3])], ".", ms=1.5, color="0.4", label=f"experiment (x = {g[1]} m)")
        for i, r in enumerate(rows):
            if "series" in r:     # a run that stopped: its heights up to the stop, dashed
                t, h = r["series"][g[0]]
                err = r["metrics"][f"height_rms_err_m_{g[0]}"]
                what = (f"RMS {1000 * err:.0f} mm" if r.get("ok") else
                        f"stopped at {r['t_stop']:.2f} s; RMS {1000 * err:.0f} mm to then")
                ax.plot(t, h, "-" if r.get("ok") else "--", lw=1.1, color=f"C{i}", label=f"{r['run']} ({what})")
        ax.set_title(g[0], fontsize=9)
        ax.set_ylabel("h [m]")
    # the box's sensors: both series as running means over smooth_peak_t (the metrics' filters)
    tg = np.arange(0.0, pdata[-1, 0], dt)
    for ax, s in zip(axes.ravel()[len(gauges):], sensors):
        pd = running_mean(np.interp(tg, pdata[:, 0], pdata[:, int(s[5])]), w, dt)
        ax.plot(tg, pd / 1000.0, "-", lw=0.8, color="0.4", label="experiment")
        for i, r in enumerate(rows):
            if s[0] in r.get("series", {}):
                t, p = (np.asarray(v, float) for v in r["series"][s[0]])
                err = r["metrics"].get(f"p_rms_err_kPa_{s[0]}", float("nan"))
                ax.plot(t, running_mean(p, w, dt) / 1000.0, "-" if r.get("ok") else "--", lw=0.9, color=f"C{i}",
                        label=f"{r['run']} (level RMS {err:.2f} kPa)")
        ax.set_title(f"{s[0]} ({'front face' if s[4] == 'x+' else 'top'}, z = {s[3]} m, x = {s[1]} m), "
                     f"running mean {1000 * w:.0f} ms", fontsize=9)
        ax.set_ylabel("p [kPa]")
    for ax in axes.ravel():
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    r0 = rows[0]
    fig.suptitle(f"SPHERIC test 2, water heights and box pressures, dp = {r0['dp']} ({r0['backend']}, "
                 f"{r0['precision']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def sensor_names(case) -> set:
    """The names of the case's pressure sensors (`[params] sensors`)."""
    return {str(s[0]) for s in case.params.get("sensors", [])}


def fields(r, sensors: set) -> dict:
    """A run's row fields from its CaseResult: metrics, counts and the simulated series (heights in m,
    the pressures of `sensors` in Pa as sampled: the case's series hold them in kPa)."""
    series = {}
    for k, v in r.series.items():
        if k.startswith("sphgraph "):
            name = k.split()[1]
            scale = 1000.0 if name in sensors else 1.0
            series[name] = [list(map(float, v[0])), list(map(float, scale * v[1]))]
    return dict(metrics=r.metrics, steps=r.steps, particles=r.particles, wall_s=r.wall_s, series=series)


def rescore(case, paths, window) -> int:
    """One JSON line a stored run that has its series: the case's metrics over 0-window s (a run
    that stopped or was cut short at t_end is compared with the others over its own length)."""
    from sphgraph.validation import load
    from sphgraph.validation.cases import height_metrics
    from sphgraph.validation.sensors import pressure_metrics
    data, _ = load(case.reference["dataset"])
    pdata, _ = load(case.reference["pressures"])
    for path in paths:
        with open(path) as f:
            for r in json.load(f):
                if not r.get("series"):
                    continue
                last = min(t[-1] for t, _ in r["series"].values())
                if window is not None and window > last + 1e-9:
                    print(json.dumps({"file": path, "run": r["run"], "skipped": f"its series end at {last:.2f} s"}))
                    continue
                m = height_metrics(case.params, data, r["series"], last if window is None else window)
                if sensor_names(case) <= set(r["series"]):     # runs stored before the box's sensors have none
                    rho0 = float(case.scene.get("physics", {}).get("rho0", 1000.0))
                    m.update(pressure_metrics(case.params, pdata, r["series"], last if window is None else window,
                                              rho0))
                print(json.dumps({"file": path, "run": r["run"], "dp": r["dp"], "window_s": window or last,
                                  "metrics": m}), flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="numba-cpu")
    ap.add_argument("--precision", default=None)
    ap.add_argument("--dp", type=float, default=0.02)
    ap.add_argument("--t-end", type=float, default=None, help="s (default: the case's 6 s)")
    ap.add_argument("--runs", default="dsph,zhang-mdbc", help="comma list of " + ", ".join(RUNS))
    ap.add_argument("--json", default=None)
    ap.add_argument("--plot", default=None)
    ap.add_argument("--rescore", nargs="+", default=None, metavar="JSON",
                    help="no run: score the stored series of these --json files over 0-WINDOW s")
    ap.add_argument("--window", type=float, default=None, help="s, with --rescore")
    ap.add_argument("--replot", nargs="+", default=None, metavar="JSON",
                    help="no run: draw the stored runs of these --json files into --plot")
    a = ap.parse_args(argv)
    if a.replot and not a.plot:
        ap.error("--replot: expected --plot PNG, the figure to draw, got none")
    from sphgraph.validation.cases import CaseStopped, load_case, run_case
    from sweep_rows import attempt, record
    case = load_case("spheric2")
    gauges, sensors = case.params["gauges"], sensor_names(case)
    if a.rescore:
        return rescore(case, a.rescore, a.window)
    if a.replot:
        rows = [r for path in a.replot for r in json.load(open(path))]
        plot(rows, a.plot, case)
        return 0
    rows = []
    for key in a.runs.split(","):
        params, overrides = RUNS[key]
        params = dict(params, **({"t_end": a.t_end} if a.t_end else {}))
        row = {"run": key, "case": case.name, "dp": a.dp, "backend": a.backend, "precision": a.precision or "default",
               "params": params, "overrides": overrides}

        def one(row=row):
            try:
                r = run_case(case, dp=a.dp, backend=a.backend, precision=a.precision, params=params,
                             overrides=overrides, plot=False)
            except CaseStopped as e:    # the heights up to the stop, metrics over that window
                row.update(fields(e.result, sensors), t_stop=float(e.result.series[f"sphgraph {gauges[0][0]}"][0][-1]))
                raise
            return fields(r, sensors)
        record(rows, attempt(row, one), a.json)
        if a.plot:
            plot(rows, a.plot, case)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
