"""Pressure sensors on a body's faces against a measured pressure history (SPHERIC test 2's box).

A case lists its sensors in `[params] sensors` as ``[name, x, y, z, face, data column]``,
``face`` one of ``"x+"``, ``"x-"``, ``"y+"``, ``"y-"``, ``"z+"``, ``"z-"`` (the outward normal of the face
the sensor sits on), and the body as ``sensor_body = [[min], [max]]``. The sensor is read by a
`[probes]` point (Shepard interpolation of the fluid, sphgraph.probes) put `probe_offset_dp`
particle spacings off the body's outermost boundary rows along that normal, as the Buchner case
puts its probe off the wall plane: dynamic boundaries keep the fluid ~1.5 dp off the wall, so a
point on the rows themselves has almost no fluid in reach. The offset and the filters below are
the case's, fixed before any comparison and the same for every formulation.

Metrics, the simulated series and the data both on the sampler's times (the data interpolated),
no time shift:

* ``p_rms_err_kPa_<name>``: RMS of the difference of the two running means over
  ``smooth_t`` (the level: hydrostatic and slowly varying pressure) over the compared window;
* ``impact_t_err_s_<name>``: the first time the running mean over ``smooth_peak_t`` passes
  ``impact_p``, against the data's (sensors the data see pass it only);
* ``first_peak_rel_err_<name>``: the largest running mean over ``smooth_peak_t`` within
  ``first_peak_t`` after each series' own impact, relative to the data's;
* ``p_rms_err_rel_rhogh0_all``: the level RMS over every sensor, over rho0 g h0.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

FACES = {"x+": (0, 1.0), "x-": (0, -1.0), "y+": (1, 1.0), "y-": (1, -1.0), "z+": (2, 1.0), "z-": (2, -1.0)}
# the case parameters' defaults (module docstring), in one place for the metrics and the report's note
DEFAULTS = {"probe_offset_dp": 2.0, "smooth_t": 0.1, "smooth_peak_t": 0.02, "impact_p": 1000.0, "first_peak_t": 0.1}


def _param(prm: dict, key: str) -> float:
    return float(prm.get(key, DEFAULTS[key]))


def sensor_points(prm: dict, pos: np.ndarray, kind: np.ndarray, dp: float) -> list:
    """[(name, position)] of the case's sensors: each put `probe_offset_dp` dp off the outermost
    boundary rows of `sensor_body` along its face's normal (rows at the body's floor, z < dp/2,
    are the tank's and left out)."""
    lo, hi = (np.asarray(v, float) for v in prm["sensor_body"])
    off = _param(prm, "probe_offset_dp") * dp
    b = pos[kind != 0]
    inside = np.all((b >= lo - 0.5 * dp) & (b <= hi + 0.5 * dp), axis=1) & (b[:, -1] > 0.5 * dp)
    rows = b[inside]
    if not len(rows):
        raise InputError(f"params.sensor_body: expected a box around boundary rows at dp {dp}, got "
                         f"{lo.tolist()} - {hi.tolist()} (no rows)")
    out = []
    for i, s in enumerate(prm["sensors"]):
        name, x, face = str(s[0]), np.array(s[1:4], float), str(s[4])
        if face not in FACES:
            raise InputError(f"params.sensors[{i}]: face: expected one of {', '.join(FACES)}, got {face!r}")
        axis, sign = FACES[face]
        plane = rows[:, axis].max() if sign > 0 else rows[:, axis].min()
        x[axis] = plane + sign * off
        out.append((name, x))
    return out


def running_mean(x: np.ndarray, window_s: float, dt: float) -> np.ndarray:
    k = max(1, int(round(window_s / dt)))
    return np.convolve(x, np.ones(k) / k, mode="same")


def pressure_metrics(prm: dict, data: np.ndarray, pressures: dict, t_end: float, rho0: float,
                     g: float = 9.81) -> dict:
    """The sensors' metrics (module docstring) from sampled pressures {name: (t, p [Pa])},
    sampled every `dt_sample_p` s, against the data's columns over 0-t_end."""
    dt = float(prm["dt_sample_p"])
    thr = _param(prm, "impact_p")
    w_lvl, w_peak, w_first = (_param(prm, k) for k in ("smooth_t", "smooth_peak_t", "first_peak_t"))
    metrics, sq = {}, []
    for s in prm["sensors"]:
        name, col = str(s[0]), int(s[5])
        t, p = (np.asarray(a, float) for a in pressures[name])
        keep = t <= min(t_end, data[-1, 0]) + 1e-12
        t, p = t[keep], p[keep]
        pd = np.interp(t, data[:, 0], data[:, col])
        e = running_mean(p, w_lvl, dt) - running_mean(pd, w_lvl, dt)
        metrics[f"p_rms_err_kPa_{name}"] = float(np.sqrt((e ** 2).mean())) / 1000.0
        sq.append(float((e ** 2).mean()))
        ps, pds = running_mean(p, w_peak, dt), running_mean(pd, w_peak, dt)
        hit_d = np.nonzero(pds > thr)[0]
        if not len(hit_d):
            continue
        hit = np.nonzero(ps > thr)[0]
        metrics[f"impact_t_data_s_{name}"] = float(t[hit_d[0]])
        if not len(hit):
            metrics[f"impact_t_err_s_{name}"] = math.inf
            continue
        metrics[f"impact_t_err_s_{name}"] = float(t[hit[0]] - t[hit_d[0]])
        peak = float(ps[(t >= t[hit[0]]) & (t <= t[hit[0]] + w_first)].max())
        peak_d = float(pds[(t >= t[hit_d[0]]) & (t <= t[hit_d[0]] + w_first)].max())
        metrics[f"first_peak_kPa_{name}"] = peak / 1000.0
        metrics[f"first_peak_data_kPa_{name}"] = peak_d / 1000.0
        metrics[f"first_peak_rel_err_{name}"] = peak / peak_d - 1.0
    metrics["p_rms_err_rel_rhogh0_all"] = float(np.sqrt(np.mean(sq))) / (rho0 * g * float(prm["h0"]))
    return metrics


def pressure_note(prm: dict) -> str:
    """The report's line on how the sensors were read and compared."""
    return (f"pressure sensors: a point probe {_param(prm, 'probe_offset_dp')} dp off the body's outer rows, sampled "
            f"every {prm['dt_sample_p']} s; level = running mean over {_param(prm, 'smooth_t')} s of both series; "
            f"impact = first running mean over {_param(prm, 'smooth_peak_t')} s above {_param(prm, 'impact_p')} Pa; "
            f"first peak = its largest within {_param(prm, 'first_peak_t')} s of each series' own impact "
            "(sphgraph.validation.sensors)")


def pressure_series(prm: dict, data: np.ndarray, points: list, sampled: dict) -> dict:
    """The plot's series, one panel a sensor: the sampled pressure and the data, in kPa."""
    series = {}
    for s, (name, x) in zip(prm["sensors"], points):
        t, p = sampled[name]
        series[f"sphgraph {name}"] = (t, np.asarray(p) / 1000.0, "-", name)
        series[f"experiment {name} [kPa] (probe at {', '.join(f'{v:.4f}' for v in x)})"] = (
            data[:, 0], data[:, int(s[5])] / 1000.0, ".", name)
    return series
