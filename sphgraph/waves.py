"""Regular waves: linear wave theory, first-order wavemaker transfer functions,
damping zones (wave absorption) and a free-surface gauge.

Wavemaker theory (Dean & Dalrymple 1991, *Water Wave Mechanics for Engineers and
Scientists*, §6.2): a paddle moving with stroke S (peak-to-peak displacement at the
still-water level) in water of depth d makes, far from the paddle, a progressive
wave of height H with

    piston:  H/S = 2 (cosh 2kd - 1) / (sinh 2kd + 2kd)
    flap:    H/S = 4 sinh(kd)/(kd) * (kd sinh kd - cosh kd + 1) / (sinh 2kd + 2kd)

(flap hinged at the bottom), k from the dispersion relation w^2 = g k tanh(kd).

Damping zone (DualSPHysics ``<damping>``, JDsDamping): fluid velocities in a zone
are relaxed each step by v <- v (1 - dt * redumax * f^2), f in [0, 1] the relative
distance into the zone (0 where it starts, 1 at its end and beyond, up to
``overlimit`` past the end), so waves entering the zone lose their energy instead of
reflecting from the flume's end wall.
"""
from __future__ import annotations

import math

import numpy as np

from .particles import FLUID


# --------------------------------------------------------------------------- linear theory

def wavenumber(period: float, depth: float, g: float = 9.81) -> float:
    """k [1/m] of w^2 = g k tanh(k d) (Newton iterations from the deep-water guess)."""
    w = 2.0 * math.pi / period
    w2 = w * w          # inf, not OverflowError, for a tiny period
    if not 0.0 < w2 < math.inf:   # a period float64 cannot make a wave of: no wave number
        return math.nan
    k = max(w2 / g, math.sqrt(w2 / (g * depth)))
    for _ in range(100):
        th = math.tanh(k * depth)
        f = g * k * th - w2
        df = g * th + g * k * depth * (1.0 - th * th)
        dk = f / df
        k -= dk
        if abs(dk) < 1e-14 * k:
            break
    return k


def wavelength(period: float, depth: float, g: float = 9.81) -> float:
    return 2.0 * math.pi / wavenumber(period, depth, g)


def group_velocity(period: float, depth: float, g: float = 9.81) -> float:
    k = wavenumber(period, depth, g)
    kd2 = 2.0 * k * depth
    c = 2.0 * math.pi / period / k
    return 0.5 * c * (1.0 + kd2 / math.sinh(kd2))


def piston_ratio(kd: float) -> float:
    """H/S of a piston wavemaker (Dean & Dalrymple eq. 6.16)."""
    if kd > 20.0:   # deep water: the same ratio times 2 exp(-2kd) / 2 exp(-2kd) (cosh would overflow)
        e = math.exp(-2.0 * kd)
        return 2.0 * (1.0 - e) ** 2 / (1.0 - e * e + 4.0 * kd * e)
    return 2.0 * (math.cosh(2 * kd) - 1.0) / (math.sinh(2 * kd) + 2 * kd)


def flap_ratio(kd: float) -> float:
    """H/S of a bottom-hinged flap wavemaker (Dean & Dalrymple eq. 6.17)."""
    if kd > 20.0:   # deep water: numerator and denominator over sinh(kd) cosh(kd) (no overflow)
        sh, ch = math.sinh(min(kd, 700.0)), math.cosh(min(kd, 700.0))
        return 4.0 / kd * (kd * math.tanh(kd) - 1.0 + 1.0 / ch) / (2.0 + 2.0 * kd / (sh * ch))
    return (4.0 * math.sinh(kd) / kd * (kd * math.sinh(kd) - math.cosh(kd) + 1.0)
            / (math.sinh(2 * kd) + 2 * kd))


# --------------------------------------------------------------------------- damping zones

_AXES = ("x", "y", "z")
DAMPING_KEYS = ("axis", "start", "end", "overlimit", "redumax")


def validate_damping(c, raw, dim: int) -> list:
    """Validate ``[[damping]]`` entries with the scene checker ``c``; normalised list."""
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list) or not all(isinstance(e, dict) for e in raw):
        raise c.error("damping", "an array of tables ([[damping]] entries)", raw)
    out = []
    for i, e in enumerate(raw):
        key = f"damping[{i}]"
        c.table(key, e, DAMPING_KEYS)
        ax = c.choice(f"{key}.axis", e.get("axis", "x"), _AXES[:dim])
        a = c.number(f"{key}.start", c.require(key, e, "start"))
        b = c.number(f"{key}.end", c.require(key, e, "end"))
        if a == b:
            raise c.error(f"{key}.end", f"a coordinate != start ({a})", b)
        out.append({"axis": ax, "start": a, "end": b,
                    "overlimit": c.number(f"{key}.overlimit", e.get("overlimit", 1e30), ge=0),
                    "redumax": c.number(f"{key}.redumax", e.get("redumax", 10.0), gt=0)})
    return out


class Damping:
    """Velocity relaxation zones (the ``damping`` task, last stage of a step)."""

    def __init__(self, entries: list):
        from .physics.damping import zone_table
        self.zones = [(_AXES.index(e["axis"]), e["start"], e["end"], e["overlimit"], e["redumax"])
                      for e in entries]
        self.table = zone_table(self.zones)

    @classmethod
    def from_scene(cls, scene) -> "Damping | None":
        e = scene.extra.get("damping")
        return cls(e) if e else None

    def factor(self, pos: np.ndarray, dt: float) -> np.ndarray:
        """Multiplier of each row's velocity (1 outside every zone; sphgraph.physics.damping)."""
        from .physics.damping import damping_factors
        f = np.empty(len(pos))
        damping_factors(np.ascontiguousarray(pos, np.float64), self.table, float(dt), f)
        return f

    def apply(self, ctx) -> None:
        """The ``damping`` task on the backend's rows."""
        ctx.compute.damp(ctx.state, self, ctx.state.dt)


# --------------------------------------------------------------------------- gauges

def surface_elevation(pos, kind, x0: float, dp: float, h: float, z_lo: float, z_hi: float,
                      threshold: float = 0.5, axis: int = 0, vertical: int | None = None) -> float:
    """Free-surface height at horizontal coordinate ``x0`` (2D, or 3D at one line).

    The Shepard-like sum s(z) = sum_j V_j W(|r - r_j|) (V_j = dp^dim, Wendland C2)
    along the vertical line at ``x0`` is ~1 inside the fluid and falls to 0 across the
    surface; the surface is the highest z with s(z) >= ``threshold`` (DualSPHysics'
    GaugeSwl with its mass threshold), linearly interpolated between samples dp/8 apart.
    Returns nan if no fluid is near the line.
    """
    pos = np.asarray(pos, float)
    dim = pos.shape[1]
    v = dim - 1 if vertical is None else vertical
    sel = (kind == FLUID) & (np.abs(pos[:, axis] - x0) < 2.0 * h)
    q = pos[sel]
    if len(q) == 0:
        return float("nan")
    z = np.arange(z_lo, z_hi, dp / 8.0)
    line = np.zeros((len(z), dim))
    line[:, axis] = x0
    line[:, v] = z
    if dim == 3:
        other = [a for a in range(3) if a not in (axis, v)][0]
        line[:, other] = q[:, other].mean()
    r = np.linalg.norm(line[:, None, :] - q[None, :, :], axis=2) / h
    qq = np.clip(1.0 - 0.5 * r, 0.0, None)
    w = qq ** 4 * (2.0 * r + 1.0)
    ad = 7.0 / (4.0 * math.pi * h * h) if dim == 2 else 21.0 / (16.0 * math.pi * h ** 3)
    s = ad * w.sum(axis=1) * dp ** dim
    above = np.nonzero(s >= threshold)[0]
    if len(above) == 0:
        return float("nan")
    i = above[-1]
    if i + 1 >= len(z):
        return float(z[-1])
    # interpolate the crossing between samples i and i+1
    return float(z[i] + (s[i] - threshold) / (s[i] - s[i + 1]) * (z[i + 1] - z[i]))


def wave_stats(t, eta, t_from: float, t_to: float) -> dict:
    """Mean height and period of the waves in ``eta(t)`` over ``[t_from, t_to]``
    by zero up-crossings of eta - mean; height = max - min within each wave."""
    t = np.asarray(t, float)
    eta = np.asarray(eta, float)
    s = (t >= t_from) & (t <= t_to)
    t, e = t[s], eta[s] - np.nanmean(eta[s])
    up = np.nonzero((e[:-1] < 0) & (e[1:] >= 0))[0]
    tc = t[up] - e[up] * (t[up + 1] - t[up]) / (e[up + 1] - e[up])  # interpolated crossings
    heights = [float(e[a:b + 1].max() - e[a:b + 1].min()) for a, b in zip(up[:-1], up[1:])]
    periods = list(np.diff(tc))
    return {"height": float(np.mean(heights)) if heights else float("nan"),
            "period": float(np.mean(periods)) if periods else float("nan"),
            "heights": heights, "periods": [float(p) for p in periods]}
