"""Prescribed motion of boundary bodies (kind 2): scene ``[[motion]]`` entries.

A ``[[motion]]`` entry moves the particles of one *named* ``[[boundary]]`` entry
(``body = "paddle"`` refers to ``[[boundary]] name = "paddle"``); those particles
get kind 2 (moving boundary). Each step the ``motion`` task (after ``integrate``,
once per force stage) sets their positions and velocities for the time the stage
ends at: the forces read boundary velocities, and integrate keeps non-fluid
positions fixed, so nothing else is needed (DualSPHysics' RunMotion, which runs
after ComputeVerlet / each Symplectic half step).

Positions are computed from each particle's *initial* position and the time, never
accumulated step by step, so motion does not drift and is the same on any rank count.

Types (every key in docs/features.md):

``rectilinear``  ``times``, ``velocity`` (one vector per time): velocity piecewise
                 linear in time (repeat a time for a jump), held before the first and
                 after the last time; displacement = its exact integral from t = 0.
``rotation``     ``times``, ``omega`` [rad/s] piecewise linear, ``center``; 3D also
                 ``axis``. 2D: counter-clockwise positive.
``piston``       wavemaker from wave ``height`` H and ``period`` T in water ``depth`` d
                 (default: the scene's still-water depth): stroke S = H / (H/S) from
                 first-order wavemaker theory (:func:`sphgraph.waves.piston_ratio`),
                 x(t) = r(t) S/2 sin(wt + phase), r a ``ramp`` over the first periods.
``flap``         as piston, hinged at ``hinge`` (a point, default the body's lowest
                 point): angle r(t) atan(S / (2 l)) sin(wt + phase), with l the hinge's
                 depth below the still-water level (:func:`sphgraph.waves.flap_ratio`).
``gate``         lifted at ``speed`` [m/s] from time ``start`` by ``lift`` metres
                 (the dam-break gate), along the vertical unless ``direction`` says.
"""
from __future__ import annotations

import math

import numpy as np

from .errors import InputError
from .particles import MOVING
from .ranges import CHOICES, describe, expected

TYPES = ("rectilinear", "rotation", "piston", "flap", "gate")
KEYS = {
    "rectilinear": ("body", "type", "times", "velocity"),
    "rotation": ("body", "type", "times", "omega", "center", "axis"),
    "piston": ("body", "type", "height", "period", "depth", "direction", "ramp", "phase", "start", "order"),
    "flap": ("body", "type", "height", "period", "depth", "direction", "ramp", "phase", "start", "hinge"),
    "gate": ("body", "type", "speed", "start", "lift", "direction"),
}
_AXES = ("x", "y", "z")


# --------------------------------------------------------------------------- validation

def validate(c, raw, dim: int, names, source_depth=None) -> list:
    """Validate the scene's ``motion`` value (an array of tables) with checker ``c``.

    ``names``: the named boundary entries. Returns normalised entries (plain
    TOML values, every key present). Raises InputError via ``c``.
    """
    if not isinstance(raw, list) or not all(isinstance(e, dict) for e in raw):
        raise c.error("motion", "an array of tables ([[motion]] entries)", raw)
    out, bodies = [], set()
    for i, e in enumerate(raw):
        key = f"motion[{i}]"
        t = c.choice(f"{key}.type", c.require(key, e, "type"), TYPES)
        c.table(key, e, KEYS[t])
        body = c.require(key, e, "body")
        if not isinstance(body, str) or body not in names:
            raise c.error(f"{key}.body", "the name of a [[boundary]] entry (one of: "
                          + (", ".join(sorted(names)) or "none named") + ")", body)
        if body in bodies:
            raise c.error(f"{key}.body", "a body moved by one [[motion]] entry only", body)
        bodies.add(body)
        n = {"body": body, "type": t}
        if t in ("rectilinear", "rotation"):
            times = e.get("times")
            # each time a number in range (sphgraph.ranges) before the comparisons of the order
            if (not isinstance(times, list) or not times
                    or not all(expected(f"{key}.times", x) is None for x in times)
                    or any(b < a for a, b in zip(times, times[1:]))):
                raise c.error(f"{key}.times", "a non-empty list of non-decreasing times, each "
                              + describe(f"{key}.times")[2:], times)
            n["times"] = [float(x) for x in times]
            if t == "rectilinear":
                vel = e.get("velocity")
                if not isinstance(vel, list) or len(vel) != len(times):
                    raise c.error(f"{key}.velocity", f"a list of {len(times)} velocity vectors "
                                  "(one per time)", vel)
                n["velocity"] = [list(c.vector(f"{key}.velocity[{j}]", v, dim)) for j, v in enumerate(vel)]
            else:
                om = e.get("omega")
                if not isinstance(om, list) or len(om) != len(times):
                    raise c.error(f"{key}.omega", f"a list of {len(times)} angular velocities [rad/s]", om)
                n["omega"] = [c.number(f"{key}.omega[{j}]", w) for j, w in enumerate(om)]
                n["center"] = list(c.vector(f"{key}.center", c.require(key, e, "center"), dim))
                if dim == 3:
                    ax = c.vector(f"{key}.axis", c.require(key, e, "axis"), 3)
                    if not np.linalg.norm(ax) > 0:
                        raise c.error(f"{key}.axis", "a non-zero vector", e["axis"])
                    n["axis"] = list(ax / np.linalg.norm(ax))
                elif "axis" in e:
                    raise c.error(f"{key}.axis", "no axis in 2D (rotation is about the out-of-plane axis)",
                                  e["axis"])
        elif t in ("piston", "flap"):
            n["height"] = c.number(f"{key}.height", c.require(key, e, "height"), gt=0)
            n["period"] = c.number(f"{key}.period", c.require(key, e, "period"), gt=0)
            if "depth" in e:
                n["depth"] = c.number(f"{key}.depth", e["depth"], gt=0)
            n["direction"] = c.choice(f"{key}.direction", e.get("direction", "x"), _AXES[:dim - 1])
            n["ramp"] = c.number(f"{key}.ramp", e.get("ramp", 1.0), ge=0)
            n["phase"] = c.number(f"{key}.phase", e.get("phase", 0.0))
            n["start"] = c.number(f"{key}.start", e.get("start", 0.0), ge=0)
            if t == "piston":
                o = e.get("order", 1)
                if isinstance(o, bool) or not isinstance(o, int) or o not in CHOICES["motion[].order"]:
                    raise c.error(f"{key}.order", "1 (first-order wavemaker theory) or 2 (Madsen 1971)", o)
                n["order"] = int(o)
            if t == "flap" and "hinge" in e:
                n["hinge"] = list(c.vector(f"{key}.hinge", e["hinge"], dim))
        else:  # gate
            n["speed"] = c.number(f"{key}.speed", c.require(key, e, "speed"), gt=0)
            n["lift"] = c.number(f"{key}.lift", c.require(key, e, "lift"), gt=0)
            n["start"] = c.number(f"{key}.start", e.get("start", 0.0), ge=0)
            n["direction"] = c.choice(f"{key}.direction", e.get("direction", _AXES[dim - 1]), _AXES[:dim])
        out.append(n)
    return out


# --------------------------------------------------------------------------- kinematics

class Table:
    """Piecewise-linear function of time (values [n, m]) and its exact integral from t = 0.

    Held constant before the first and after the last time; a repeated time is a jump.
    """

    def __init__(self, times, values):
        self.t = np.asarray(times, float)
        v = np.asarray(values, float)
        self.v = v.reshape(len(self.t), -1)
        seg = np.diff(self.t)[:, None] * 0.5 * (self.v[1:] + self.v[:-1])
        self.cum = np.concatenate([np.zeros((1, self.v.shape[1])), np.cumsum(seg, axis=0)])
        self.x0 = self._integral(0.0)

    def _eval(self, t):
        T, V = self.t, self.v
        if t <= T[0]:
            return V[0].copy(), V[0] * (t - T[0])
        k = int(np.searchsorted(T, t, side="right")) - 1
        if k >= len(T) - 1:
            return V[-1].copy(), self.cum[-1] + V[-1] * (t - T[-1])
        f = (t - T[k]) / (T[k + 1] - T[k])
        v = V[k] + f * (V[k + 1] - V[k])
        return v, self.cum[k] + (t - T[k]) * 0.5 * (V[k] + v)

    def _integral(self, t):
        return self._eval(t)[1]

    def __call__(self, t):
        """(value at t, integral from 0 to t)."""
        v, x = self._eval(t)
        return v, x - self.x0


def _ramp(t, duration):
    """Smooth start: (r, dr/dt), r = (1 - cos(pi t / duration)) / 2 up to `duration`, then 1."""
    if duration <= 0 or t >= duration:
        return 1.0, 0.0
    if t <= 0:
        return 0.0, 0.0
    a = math.pi / duration
    return 0.5 * (1.0 - math.cos(a * t)), 0.5 * a * math.sin(a * t)


def _rotation_matrix(axis, angle, dim):
    c, s = math.cos(angle), math.sin(angle)
    if dim == 2:
        return np.array([[c, -s], [s, c]])
    x, y, z = axis
    C = 1.0 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


class Body:
    """One moving body: ``state(t)`` -> ("translate", disp, vel) or ("rotate", center, axis, angle, rate)."""

    def __init__(self, entry: dict, dim: int, ref_pos: np.ndarray, default_depth: float, g: float,
                 swl: float | None = None, where: str = "motion"):
        """``where``: the entry's place in error messages ("scene.toml: motion[0]")."""
        from . import waves
        self.entry = entry
        self.dim = dim
        self.type = t = entry["type"]
        self.name = entry["body"]
        if t == "rectilinear":
            self.table = Table(entry["times"], entry["velocity"])
        elif t == "rotation":
            self.table = Table(entry["times"], entry["omega"])
            self.center = np.asarray(entry["center"], float)
            self.axis = np.asarray(entry.get("axis", [0.0, 0.0, 1.0]), float)
        elif t in ("piston", "flap"):
            d = float(entry.get("depth", default_depth))
            self.depth = d
            H, T = entry["height"], entry["period"]
            if not g > 0:
                raise InputError(f"{where}.type: expected a wavemaker in a scene with vertical gravity "
                                 f"(w^2 = g k tanh(kd)), got {t!r} with g = {g}")
            self.omega = 2.0 * math.pi / T
            self.k = waves.wavenumber(T, d, g)
            kd = self.k * d
            ratio = 0.0 if not 0.0 < kd < math.inf else (
                waves.piston_ratio(kd) if t == "piston" else waves.flap_ratio(kd))
            if not (math.isfinite(self.omega) and ratio > 0 and math.isfinite(H / ratio)):
                raise InputError(f"{where}.period: expected a period and depth giving a finite wave "
                                 f"(w^2 = g k tanh(kd), kd = {kd:.3g}), got period {T!r} in depth {d!r} m")
            self.stroke = H / ratio
            # second order (Madsen 1971): X2(t) = a2 sin(2(wt + phase)) cancels the free second
            # harmonic a sinusoidal paddle sheds next to the wave's bound one
            self.a2 = 0.0
            if entry.get("order", 1) == 2:
                self.a2 = H * H / (32.0 * d) * (3.0 * math.cosh(kd) / math.sinh(kd) ** 3 - 2.0 / ratio)
            self.dir = _AXES.index(entry["direction"])
            if t == "flap":
                if "hinge" in entry:
                    self.center = np.asarray(entry["hinge"], float)
                else:  # lowest point of the body, at its mean horizontal position
                    self.center = ref_pos.mean(axis=0)
                    self.center[dim - 1] = ref_pos[:, dim - 1].min()
                # the hinge's depth below the still-water level (d for a hinge on the bottom)
                self.arm = d if swl is None else float(swl - self.center[dim - 1])
                if not self.arm > 0:
                    raise InputError(f"{where}.hinge: expected a hinge below the still-water level "
                                     f"{swl:.6g} m, got {list(self.center)}")
                self.theta = math.atan(0.5 * self.stroke / self.arm)
                # rotation that moves the top towards +direction
                if dim == 2:
                    self.axis = np.array([0.0, 0.0, -1.0])
                else:
                    up = np.zeros(3)
                    up[2] = 1.0
                    e = np.zeros(3)
                    e[self.dir] = 1.0
                    self.axis = np.cross(up, e)
        else:  # gate
            v = np.zeros(dim)
            v[_AXES.index(entry["direction"])] = entry["speed"]
            t0, t1 = entry["start"], entry["start"] + entry["lift"] / entry["speed"]
            self.table = Table([t0, t0, t1, t1], [np.zeros(dim), v, v, np.zeros(dim)])

    def state(self, t: float):
        typ = self.type
        if typ in ("rectilinear", "gate"):
            v, x = self.table(t)
            return "translate", x, v
        if typ == "rotation":
            w, a = self.table(t)
            return "rotate", self.center, self.axis, float(a[0]), float(w[0])
        e = self.entry
        tt = t - e["start"]
        if tt <= 0:
            s, ds = 0.0, 0.0
        else:
            r, dr = _ramp(tt, e["ramp"] * e["period"])
            ph = self.omega * tt + e["phase"]
            s = r * math.sin(ph)
            ds = dr * math.sin(ph) + r * self.omega * math.cos(ph)
        if typ == "piston":
            x = np.zeros(self.dim)
            v = np.zeros(self.dim)
            x[self.dir] = 0.5 * self.stroke * s
            v[self.dir] = 0.5 * self.stroke * ds
            if self.a2 and tt > 0:
                x[self.dir] += self.a2 * r * math.sin(2.0 * ph)
                v[self.dir] += self.a2 * (dr * math.sin(2.0 * ph) + 2.0 * r * self.omega * math.cos(2.0 * ph))
            return "translate", x, v
        return "rotate", self.center, self.axis, self.theta * s, self.theta * ds

    def displacement(self, t: float) -> float:
        """Horizontal displacement of the body at the still-water level (wavemakers)."""
        kind = self.state(t)
        if kind[0] == "translate":
            return float(kind[1][self.dir]) if self.type == "piston" else float(np.linalg.norm(kind[1]))
        return self.arm * math.tan(kind[3])

    def apply(self, ref, t):
        """(positions, velocities) [n, dim] of particles whose initial positions are ``ref``."""
        st = self.state(t)
        if st[0] == "translate":
            _, x, v = st
            return ref + x, np.broadcast_to(v, ref.shape)
        _, c, axis, angle, rate = st
        dim = self.dim
        if dim == 2:
            sgn = axis[2]  # rotation about +z (counter-clockwise) or -z
            R = _rotation_matrix(None, sgn * angle, 2)
            p = c + (ref - c) @ R.T
            r = p - c
            w = sgn * rate
            vel = np.stack([-w * r[:, 1], w * r[:, 0]], axis=1)
            return p, vel
        R = _rotation_matrix(axis, angle, 3)
        p = c + (ref - c) @ R.T
        vel = rate * np.cross(axis, p - c)
        return p, vel


def _check_sweep(body, ref, fixed_pos, dp, where) -> None:
    """Refuse a wavemaker whose stroke runs through fixed boundary particles.

    A fixed wall inside the stroke (e.g. a tank's end wall at the paddle, which the
    paddle passes on its back stroke once S/2 exceeds a spacing) stands in the
    water's way: the water cannot follow the paddle back, the delivered stroke is
    short and the wave low -- silently, and the more so the finer dp. A piston moves
    S/2 at every height; a flap (tan(angle) = S / 2l) moves in proportion to the
    height above its hinge."""
    a, tol = body.dir, 0.25 * dp
    v = ref.shape[1] - 1
    if body.type == "piston":
        half = np.full(len(fixed_pos), 0.5 * body.stroke)
    else:
        half = np.abs(fixed_pos[:, v] - body.center[v]) * math.tan(body.theta)
    lo, hi = ref.min(axis=0), ref.max(axis=0)
    inside = (fixed_pos[:, a] > lo[a] - half - tol) & (fixed_pos[:, a] < hi[a] + half + tol)
    for b in range(ref.shape[1]):
        if b != a:
            # strictly within the paddle's face: a floor or side wall it slides along is fine
            inside &= (fixed_pos[:, b] > lo[b] + tol) & (fixed_pos[:, b] < hi[b] - tol)
    n = int(inside.sum())
    if n:
        ax = _AXES[a]
        reach = float(half[inside].max())
        first = fixed_pos[np.nonzero(inside)[0][0]]
        raise InputError(
            f"{where}.body: expected fixed walls out of the stroke of {body.type} {body.name!r} "
            f"({ax} from {lo[a] - reach:.6g} to {hi[a] + reach:.6g} m), got {n} fixed boundary "
            f"particles in it (e.g. at {[round(float(x), 6) for x in first]}); start the tank "
            f"behind {ax} = {lo[a] - reach:.6g} m so the water can follow the paddle back")


class Motion:
    """Every moving body of a scene, and the ``motion`` task's work on one rank."""

    def __init__(self, bodies: list, ids: np.ndarray, body_of: np.ndarray, ref: np.ndarray):
        self.bodies = bodies
        self.ids = ids          # sorted ids of moving particles
        self.body_of = body_of  # body index per id
        self.ref = ref          # initial positions per id

    @classmethod
    def from_scene(cls, scene, particles) -> "Motion | None":
        entries = scene.extra.get("motion") or []
        if not entries:
            return None
        masks = scene.boundary_masks()
        # initial positions from the scene's lattice, not from `particles` (which may be a
        # restart's): boundary ids are 0..nb-1 in lattice order
        bidx = scene._lattice()[0]
        lat = scene._lattice_def()
        bodies, ids, body_of, refs = [], [], [], []
        g = abs(float(scene.physics.gravity[scene.dim - 1]))
        for i, e in enumerate(entries):
            rows = np.nonzero(masks[e["body"]])[0]
            ref = lat.positions(bidx[rows])
            bodies.append(Body(e, scene.dim, ref, scene.hswl, g, scene.surface_level(),
                               where=f"{scene.source}: motion[{i}]"))
            ids.append(rows.astype(np.int64))
            body_of.append(np.full(len(rows), len(bodies) - 1, np.int32))
            refs.append(ref)
        ids = np.concatenate(ids)
        if any(b.type in ("piston", "flap") for b in bodies):   # fixed positions only when needed
            fixed = np.ones(len(bidx), bool)
            fixed[ids] = False
            fixed_pos = lat.positions(bidx[fixed])
            for i, (body, ref) in enumerate(zip(bodies, refs)):
                if body.type in ("piston", "flap"):
                    _check_sweep(body, ref, fixed_pos, scene.dp, f"{scene.source}: motion[{i}]")
        order = np.argsort(ids, kind="stable")
        return cls(bodies, ids[order], np.concatenate(body_of)[order], np.concatenate(refs)[order])

    def table(self, t: float, points: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) [n, dim] of every moving particle at time ``t``, in the
        order of ``self.ids``: what a device backend uploads and puts on its rows by id.
        ``points``: other points carried with the particles' bodies instead (one a particle,
        given at t = 0, e.g. mDBC's ghost nodes), which each body moves as it moves its own."""
        ref = self.ref if points is None else points
        pos = np.empty_like(ref)
        vel = np.empty_like(ref)
        for i, body in enumerate(self.bodies):
            s = self.body_of == i
            pos[s], vel[s] = body.apply(ref[s], t)
        return pos, vel

    def move(self, state, t: float) -> None:
        """Set kind-2 rows of ``state.particles`` to their positions/velocities at time ``t``."""
        p = state.particles
        rows = np.nonzero(p.kind == MOVING)[0]
        if len(rows) == 0:
            return
        k = np.searchsorted(self.ids, p.id[rows])
        b = self.body_of[k]
        for i, body in enumerate(self.bodies):
            s = b == i
            if not s.any():
                continue
            pos, vel = body.apply(self.ref[k[s]], t)
            p.pos[rows[s]] = pos
            p.vel[rows[s]] = vel
