"""The `[probes]` / `[forces]` sample as the host sampler took it before the per-rank sums: every
rank's rows gathered in id order, then numpy over all of them (points and heights verbatim from
that sampler; the force as the dense body x fluid pair sum, which equals its cell-grid sum to
round-off: tests/test_probe_forces.py). The reference the per-rank sums are checked against."""
from __future__ import annotations

import numpy as np

from sphgraph.probes import kernel_w


def point(s, x, pos, vel, rho, p):
    d = pos - x
    r = np.sqrt((d * d).sum(1))
    m = r < 2.0 * s.h
    r = r[m]
    w = kernel_w(r, s.h, s.aw, s.kernel) * s.mass_f / rho[m]
    sw = w.sum()
    if sw < 0.1:
        return {"pressure": 0.0, "velocity": np.zeros(s.dim), "kernel_sum": sw}
    return {"pressure": float((p[m] * w).sum() / sw), "velocity": (vel[m] * w[:, None]).sum(0) / sw,
            "kernel_sum": sw}


def height(s, xh, pos, rho):
    hor = pos[:, :-1]
    m = np.all(np.abs(hor - xh) < 2.0 * s.h, axis=1)
    if not m.any():
        return float(s.zlo)
    sub, vol = pos[m], s.mass_f / rho[m]
    zs = np.arange(max(s.zlo, sub[:, -1].min() - 2 * s.h), min(s.zhi, sub[:, -1].max() + 2 * s.h), 0.25 * s.dp)
    pts = np.concatenate([np.broadcast_to(xh, (len(zs), s.dim - 1)), zs[:, None]], axis=1)
    d = pts[:, None, :] - sub[None, :, :]
    r = np.sqrt((d * d).sum(-1))
    sw = (kernel_w(r, s.h, s.aw, s.kernel) * vol[None, :]).sum(1)
    full = np.nonzero(sw >= 0.5)[0]
    return float(zs[full[-1]]) if len(full) else float(s.zlo)


def sample(s, a) -> dict:
    """{"probes": {name: value}, "forces": {name: force}} of sampler `s`'s spec from the
    gathered arrays `a` (`Simulation.frame_arrays`)."""
    from test_probe_forces import dense_force
    fl = a["kind"] == 0
    pos, vel, rho, p = a["position"][fl], a["velocity"][fl], a["density"][fl], a["pressure"][fl]
    out = {"probes": {}, "forces": {}}
    for name, x in s.spec["points"]:
        out["probes"][name] = point(s, x, pos, vel, rho, p)
    for name, x in s.spec["heights"]:
        out["probes"][name] = height(s, x, pos, rho)
    for name, lo, hi in s.spec["bodies"]:
        out["forces"][name] = dense_force(s, np.asarray(lo), np.asarray(hi), a)
    return out
