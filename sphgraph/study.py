"""`sphgraph study CASE`: what accuracy costs.

Sweeps resolution (dp), time integrator, kernel, density diffusion, precision and backend
for a validation case (`sphgraph.validation.cases`), records the case's error metric and
the wall time of each run, and writes

* `study.csv`  one row per run (configuration, error, wall time, steps, particles, status,
  whether it is on the Pareto front),
* `study.png`  error against wall time, log-log, the Pareto front marked.

The sweep is one factor at a time around the case's own configuration, at every dp (a
full factorial grows too fast for a 2-core machine): each axis value is tried with the
others at their baseline. `--target-error E` names the cheapest run with error <= E
("model no more than a scene needs": 2D cases stay 2D, coarse dp where it suffices).
The error metric and default dp list come from the case file's `[study]` table.
"""
from __future__ import annotations

import csv
import math
import time
import tomllib
from pathlib import Path

import numpy as np

from .errors import InputError, NumericalError

AXES = ("integrator", "kernel", "diffusion", "precision", "backend")
DEFAULT_AXES = {"integrator": ["verlet", "symplectic"], "kernel": ["wendland", "cubic"],
                "diffusion": ["fourtakas", "molteni", "none"], "precision": ["float64", "float32"],
                "backend": ["numba-cpu"]}
FIELDS = ["case", "dp", *AXES, "error", "wall_s", "steps", "particles", "status", "pareto"]


def baseline(case, extra_axes=(), base=None) -> dict:
    """The configuration every variant departs from: the case's own, with `base` (e.g.
    {"integrator": "symplectic"}) on top."""
    from .config import PhysicsConfig
    ph = dict(case.scene.get("physics", {}), **(base or {}))
    extra_axes = list(extra_axes) + [k for k in (base or {}) if k not in AXES and k not in extra_axes]
    base = {"integrator": ph.get("integrator", "verlet"), "kernel": ph.get("kernel", "wendland"),
            "diffusion": ph.get("diffusion", "fourtakas"), "precision": "float64", "backend": "numba-cpu"}
    for k in extra_axes:     # any other physics field swept (e.g. visc_alpha)
        base[k] = ph.get(k, getattr(PhysicsConfig(), k))
    return base


def configurations(case, dps, axes, base=None) -> list[dict]:
    """One factor at a time around the baseline, at every dp (duplicates removed)."""
    base = baseline(case, [k for k in axes if k not in AXES], base)
    extra = [k for k in base if k not in AXES]
    out, seen = [], set()
    for dp in dps:
        variants = [dict(base)]
        for ax, values in axes.items():
            for v in values:
                variants.append(dict(base, **{ax: v}))
        for v in variants:
            key = (dp, *(v[a] for a in list(AXES) + extra))
            if key not in seen:
                seen.add(key)
                out.append(dict(v, dp=dp))
    return out


def run_one(case_name: str, cfg: dict, error_key: str, progress: bool = False) -> dict:
    from .validation.cases import run_case
    overrides = {k: v for k, v in cfg.items() if k not in ("dp", "precision", "backend")}
    if cfg["diffusion"] == "none":
        overrides["delta"] = 0.0
    row = dict(cfg, case=case_name, status="ok")
    t0 = time.perf_counter()
    try:
        res = run_case(case_name, dp=cfg["dp"], backend=cfg["backend"], precision=cfg["precision"],
                       overrides=overrides, plot=False, progress=progress)
        row.update(error=float(res.metrics[error_key]), wall_s=res.wall_s, steps=res.steps,
                   particles=res.particles)
    except NumericalError as e:
        row.update(error=math.inf, wall_s=time.perf_counter() - t0, steps=e.step or 0, particles=0,
                   status=f"failed: {e.cause}")
    except InputError as e:   # a combination the scene refuses (e.g. a Riemann term under Verlet)
        row.update(error=math.inf, wall_s=0.0, steps=0, particles=0, status=f"refused: {e}")
    return row


def cheapest(rows, target: float):
    ok = [r for r in rows if np.isfinite(r["error"]) and r["error"] <= target]
    return min(ok, key=lambda r: r["wall_s"]) if ok else None


def describe(r) -> str:
    extra = "".join(f" {k}={r[k]}" for k in r if k not in FIELDS)
    return (f"dp={r['dp']:g} {r['integrator']} {r['kernel']} diffusion={r['diffusion']} "
            f"{r['precision']} {r['backend']}{extra}: error {r['error']:.4g}, {r['wall_s']:.1f} s")


def read_csv(path) -> list[dict]:
    rows = []
    with open(path) as f:
        for r in csv.DictReader(f):
            for k in ("dp", "error", "wall_s"):
                r[k] = float(r[k])
            for k in ("steps", "particles"):
                r[k] = int(float(r[k]))
            rows.append(r)
    return rows


def run_study(case_name: str, dps=None, axes=None, out=None, target_error=None, from_csv=None,
              log=print, configs=None, base=None, progress: bool = False) -> dict:
    """Run (or read, `from_csv`) the sweep; `configs` replaces the one-at-a-time list; `base`:
    physics fields of the baseline the variants depart from; `progress`: each run's progress
    (run_case's), and each run's line numbered k/N."""
    from .plots import pareto_front, plot_study
    from .validation.cases import load_case
    case = load_case(case_name)
    st = tomllib.loads(case.text).get("study", {})
    error_key = st.get("error", next(iter(case.tolerances), "error"))
    out = Path(out or Path("out") / "study" / case.name)
    out.mkdir(parents=True, exist_ok=True)
    if from_csv:
        rows = read_csv(from_csv)
    else:
        dps = dps or st.get("dps") or [case.dp]
        if axes is None or not axes:
            axes = {k: v for k, v in DEFAULT_AXES.items() if k in st.get("axes", AXES)}
        rows = []
        todo = list(configs or configurations(case, dps, axes, base))
        for k, cfg in enumerate(todo, 1):
            r = run_one(case.name, cfg, error_key, progress=progress)
            log(f"[{k}/{len(todo)}] " + describe(r) + ("" if r["status"] == "ok" else f" [{r['status']}]"))
            rows.append(r)
        if rows and all(r["status"].startswith("refused") for r in rows):
            raise InputError(f"study {case.name}: every configuration was refused; the first: "
                             f"{rows[0]['status'][len('refused: '):]}")
    front = set(pareto_front([r["wall_s"] for r in rows], [r["error"] for r in rows]).tolist())
    for i, r in enumerate(rows):
        r["pareto"] = int(i in front)
    fields = FIELDS[:1 + 1 + len(AXES)] + sorted({k for r in rows for k in r} - set(FIELDS)) + FIELDS[2 + len(AXES):]
    with open(out / "study.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    png = plot_study(rows, out / "study.png", title=f"{case.title}: {error_key} against wall time",
                     error_key="error")
    lines = [f"{len(rows)} runs; error = {error_key}; wrote {out / 'study.csv'} and {png}",
             "Pareto front (cheapest first):"]
    lines += ["  " + describe(rows[i]) for i in sorted(front, key=lambda i: rows[i]["wall_s"])]
    best = None
    if target_error is not None:
        best = cheapest(rows, target_error)
        lines.append(f"target error {target_error:g}: " + (f"cheapest: {describe(best)}" if best else
                     "no configuration meets it; the most accurate: " +
                     describe(min(rows, key=lambda r: r["error"]))))
    return {"rows": rows, "csv": out / "study.csv", "png": png, "best": best, "summary": "\n".join(lines)}
