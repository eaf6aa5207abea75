"""The row fill of box-only scenes (sphgraph.geometry.RowFill, sphgraph/lattice_kernels.py)
against the key path it replaces (Scene._lattice: union of keys, np.unique, contains,
in_box): the same particles, bit for bit, in the same order.

Two guards: digests of the example scenes' particles computed with the key path before
the row fill existed (so neither path can drift unnoticed), and random box scenes built
both ways."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from sphgraph.scene import Scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
FIELDS = ("id", "kind", "pos", "vel", "rho", "vel_m1", "rho_m1")

# (name, dp or None for the file's, dtype) -> (particles, fluid, sha256[:16] of every array, hswl),
# from the key path at commit 3b32f18 (before the row fill); the hydrostatic scenes' float64
# digests again after the start's densities moved from numpy's `**` to libm's pow
# (lattice_kernels.hydrostatic_density: numpy's float64 power is SVML code on AVX-512 CPUs and
# libm elsewhere, so those three digests held on one kind of CPU only)
REFERENCE = {
    ("spheric2", 0.02, "float32"): (199780, 80703, "fe19a453e5fd0427", 0.54),
    ("spheric2", 0.02, "float64"): (199780, 80703, "49428a6b71032c64", 0.54),
    ("spheric2", 0.01, "float32"): (1128243, 664290, "5bed104c324efd73", 0.55),
    ("dambreak2d", None, "float32"): (5501, 5000, "81ac423b467b764d", 2.0),
    ("dambreak2d", None, "float64"): (5501, 5000, "d34411f2277ea235", 2.0),
    ("dambreak3d", None, "float32"): (17847, 9900, "316a24ae4751ea19", 0.3),
    ("dambreak3d", None, "float64"): (17847, 9900, "73f861fe60da47dd", 0.3),
    ("still_water", None, "float32"): (1630, 1225, "f37545b34b7725aa", 0.5),        # hydrostatic, 2D
    ("still_water", None, "float64"): (1630, 1225, "b4d5ebe56022ac00", 0.5),
    ("wave_flume2d", None, "float32"): (7076, 6180, "0fb17e48558854ee", 0.3),       # walls, motion
    ("wave_flume2d", None, "float64"): (7076, 6180, "665872eb06fab0f8", 0.3),
    ("yeh_petroff", None, "float32"): (20940, 9000, "7a7f91545eda9bdc", 0.3),       # open bottom
    ("yeh_petroff", None, "float64"): (20940, 9000, "34b1719d7b91ea30", 0.3),
    ("platform_wave", None, "float32"): (9672, 3942, "4e5f22f68bb1291c", 0.24),     # cylinders: key path
    ("platform_wave", None, "float64"): (9672, 3942, "12e5024f9c41a42b", 0.24),
}


def digest(p) -> str:
    h = hashlib.sha256()
    for k in FIELDS:
        a = getattr(p, k)
        h.update(k.encode())
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def key_path(scene: Scene) -> Scene:
    """The same scene, built through keys (the row fill switched off in its cache)."""
    s = Scene.from_dict(scene.to_dict(), source=scene.source)
    s._cache["rows"] = None
    return s


@pytest.mark.parametrize("name,dp,dtype", sorted(REFERENCE, key=str))
def test_examples_match_the_key_path_digests(name, dp, dtype):
    sc = Scene.from_toml(EXAMPLES / f"{name}.toml")
    if dp is not None:
        sc = sc.with_overrides(dp=dp)
    assert sc.uses_row_fill() == (name != "platform_wave")
    p = sc.build_particles(np.dtype(dtype))
    n, nf, dig, hswl = REFERENCE[(name, dp, dtype)]
    assert (p.n, p.n_fluid, sc.count_particles(), sc.hswl) == (n, nf, (nf, n - nf), hswl)
    assert digest(p) == dig


def random_scene(rng, dim):
    """Overlapping fluid boxes, a tank (open or closed, 1-3 layers), box obstacles (solid or
    surface, some open at the bottom, some crossing the tank's walls) and walls, off the
    lattice, at a coarse dp."""
    lo = np.zeros(dim)
    hi = rng.uniform(0.6, 1.2, dim)

    def box(a, b):
        p = rng.uniform(a, b, (2, dim))
        return np.sort(p, axis=0)

    dp = float(rng.uniform(0.03, 0.06))
    fluid = []
    for _ in range(int(rng.integers(1, 4))):
        f = box(lo - 0.1, hi + 0.1)
        f[1] = np.maximum(f[1], f[0] + 2 * dp)
        fluid.append({"type": "box", "min": f[0].tolist(), "max": f[1].tolist()})
    bnd = [{"type": "tank", "min": lo.tolist(), "max": hi.tolist(), "layers": int(rng.integers(1, 4)),
            "open_top": bool(rng.integers(0, 2))}]
    for _ in range(int(rng.integers(0, 4))):
        b = box(lo - 0.1, hi + 0.1)
        b[1] = np.maximum(b[1], b[0] + 0.01)
        e = {"type": "box", "min": b[0].tolist(), "max": b[1].tolist()}
        if rng.integers(0, 2):
            e.update(fill="surface", layers=int(rng.integers(1, 3)), open_bottom=bool(rng.integers(0, 2)))
        bnd.append(e)
    for _ in range(int(rng.integers(0, 3))):
        w = box(lo, hi)
        ax = int(rng.integers(0, dim))
        w[1, ax] = w[0, ax]
        w[1] = np.where(np.arange(dim) == ax, w[1], np.maximum(w[1], w[0] + 0.01))
        bnd.append({"type": "wall", "min": w[0].tolist(), "max": w[1].tolist(),
                    "layers": int(rng.integers(1, 3)), "direction": "+" if rng.integers(0, 2) else "-"})
    d = {"format": 1, "dim": dim, "dp": dp, "end_time": 1.0,
         "domain": {"min": (lo - 0.5).tolist(), "max": (hi + 0.5).tolist(),
                    "origin": rng.uniform(-0.05, 0.05, dim).tolist()},
         "fluid": fluid, "boundary": bnd}
    if rng.integers(0, 2):
        d["initial"] = {"hydrostatic": True}
    return Scene.from_dict(d, source="<random>")


@pytest.mark.parametrize("dim", [2, 3])
def test_random_box_scenes_match_the_key_path(dim):
    rng = np.random.default_rng(20261203 + dim)
    compared = 0
    for _ in range(40):
        sc = random_scene(rng, dim)
        ref = key_path(sc)
        try:
            want = ref.build_particles(np.float32)
        except Exception as e:   # noqa: BLE001  e.g. no fluid outside the boundaries
            with pytest.raises(type(e), match="fluid"):
                sc.build_particles(np.float32)
            continue
        assert sc.uses_row_fill()
        got = sc.build_particles(np.float32)
        for k in FIELDS:
            a, b = getattr(got, k), getattr(want, k)
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), k
        assert sc.count_particles() == ref.count_particles()
        assert sc.hswl == ref.hswl and sc.surface_level() == ref.surface_level()
        compared += 1
    assert compared >= 20


def test_row_fill_keeps_no_index_vectors():
    """The particle set is written without the key path's index vectors (nothing of the
    scene's size stays in its cache) and with every array in its final type."""
    sc = Scene.from_toml(EXAMPLES / "spheric2.toml")
    p = sc.build_particles(np.float32)
    assert "lattice" not in sc._cache
    held = sum(getattr(v, "nbytes", 0) for v in vars(sc._cache["rows"]).values())
    assert held < p.n * 2
    assert (p.pos.dtype, p.vel.dtype, p.rho.dtype, p.id.dtype, p.kind.dtype) == \
        (np.float64, np.float32, np.float32, np.int64, np.int8)
