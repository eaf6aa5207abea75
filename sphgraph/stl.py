"""STL triangle meshes: read (binary and ASCII), write, and check that a mesh is closed.

Only numpy: a mesh is a float64 array ``[T, 3, 3]`` (triangle, vertex, coordinate).
Normals stored in the file are ignored (they are often wrong); what the scene needs --
inside tests and the nearest surface point -- comes from the vertices
(:mod:`sphgraph.shapes`).

Format (the de-facto standard, e.g. https://www.fabbers.com/tech/STL_Format):
binary = 80-byte header, uint32 triangle count, then per triangle 12 float32
(normal, 3 vertices) and a uint16 attribute, 50 bytes; ASCII = ``solid name``,
``facet normal ... outer loop vertex x y z (x3) endloop endfacet``, ``endsolid``.
A binary file may also begin with ``solid``, so the binary form is recognised by its
size (84 + 50 T bytes) before the text form is tried.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .files import STL_LIMIT, read_bytes

_BIN_DTYPE = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_VERTEX = re.compile(rb"vertex\s+(" + _FLOAT.encode() + rb")\s+(" + _FLOAT.encode()
                     + rb")\s+(" + _FLOAT.encode() + rb")")


class MeshError(ValueError):
    """An STL file that cannot be used; the message is the 'got ...' part of an input error."""


def read_stl(path) -> np.ndarray:
    """Triangles ``[T, 3, 3]`` (float64) of a binary or ASCII STL file.

    Raises
    ------
    OSError
        The file cannot be read.
    MeshError
        Neither a binary nor an ASCII STL, no triangles, or non-finite coordinates.
    """
    data = read_bytes(path, STL_LIMIT, "STL file")
    if len(data) >= 84:
        n = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * n:
            tris = _checked(np.frombuffer(data, _BIN_DTYPE, n, 84)["v"].astype(np.float64))
            return _decimal(tris)
    head = data[:512].lstrip().lower()
    if not head.startswith(b"solid"):
        raise MeshError(f"{len(data)} bytes that are neither a binary STL (84 + 50*T bytes) "
                        "nor an ASCII STL (starting with 'solid')")
    vals = _VERTEX.findall(data)
    if len(vals) % 3:
        raise MeshError(f"an ASCII STL with {len(vals)} vertices (not a multiple of 3)")
    with np.errstate(over="ignore"):   # 1e999 reads as inf, and is refused as such
        tris = np.array(vals, dtype=np.float64).reshape(-1, 3, 3) if vals else np.empty((0, 3, 3))
    return _checked(tris)


def _decimal(x: np.ndarray) -> np.ndarray:
    """float32 values rounded to 7 significant digits: the decimals they were written from.

    A binary STL keeps float32, so 0.1 reads as 0.10000000149: a face meant to lie on a
    lattice plane would land a hair beside it and gain or lose a layer of particles. The
    change is below float32's own resolution (relative 6e-8).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(x != 0, 6 - np.floor(np.log10(np.abs(x))), 0.0)
    scale = 10.0 ** e
    return np.where(np.isfinite(x), np.round(x * scale) / scale, x)


def _checked(tris: np.ndarray) -> np.ndarray:
    """Refuse an empty mesh and non-finite vertices before any arithmetic on them."""
    if len(tris) == 0:
        raise MeshError("an STL file without triangles")
    bad = ~np.isfinite(tris).all(axis=(1, 2))
    if bad.any():
        raise MeshError(f"an STL file with non-finite coordinates ({int(bad.sum())} triangles, "
                        f"the first is triangle {int(np.argmax(bad))})")
    return tris


def closure_problem(tris: np.ndarray) -> str | None:
    """Why finite triangles ``[T, 3, 3]`` are no closed surface around a volume, or None.

    Closed: every edge shared by exactly two triangles (:func:`open_edges`). Around a
    volume: a non-zero surface area and enclosed volume (relative to the bounding box), so
    triangles that collapse to lines or points -- combinatorially closed -- are refused.
    """
    n_open = open_edges(tris)
    if n_open:
        return f"{n_open} edges not shared by exactly two triangles"
    with np.errstate(all="ignore"):   # vertices near float64's limit: inf products are refused too
        size = float(np.ptp(tris.reshape(-1, 3), axis=0).max())
        a, v = area(tris), volume(tris)
        if not (np.isfinite(a) and a > 1e-12 * size * size):
            return f"{len(tris)} triangles of zero area"
        if not (np.isfinite(v) and v > 1e-12 * size ** 3):
            return "a surface enclosing no volume (flat or degenerate triangles)"
    return None


def write_stl(path, tris, binary: bool = True, name: str = "sphgraph") -> None:
    """Write triangles ``[T, 3, 3]`` as a binary (default) or ASCII STL, normals from the vertices."""
    tris = np.asarray(tris, np.float64)
    nrm = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    if binary:
        rec = np.zeros(len(tris), _BIN_DTYPE)
        rec["normal"], rec["v"] = nrm, tris
        header = name.encode()[:80].ljust(80, b" ")
        Path(path).write_bytes(header + np.uint32(len(tris)).tobytes() + rec.tobytes())
        return
    lines = [f"solid {name}"]
    for t, n in zip(tris, nrm):
        lines.append(f"  facet normal {n[0]:.9g} {n[1]:.9g} {n[2]:.9g}\n    outer loop")
        lines += [f"      vertex {v[0]:.17g} {v[1]:.17g} {v[2]:.17g}" for v in t]
        lines.append("    endloop\n  endfacet")
    lines.append(f"endsolid {name}\n")
    Path(path).write_text("\n".join(lines))


def open_edges(tris: np.ndarray) -> int:
    """Number of edges not shared by exactly two triangles (0 for a closed, watertight mesh).

    Vertices are welded by exact coordinates, as STL writers repeat each shared vertex
    bit for bit.
    """
    verts, inv = np.unique(tris.reshape(-1, 3), axis=0, return_inverse=True)
    f = inv.reshape(-1, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.sort(e, axis=1)
    e = e[e[:, 0] != e[:, 1]]   # a degenerate triangle's collapsed edge joins nothing
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int((counts != 2).sum())


def volume(tris: np.ndarray) -> float:
    """Enclosed volume (divergence theorem: sum of signed tetrahedra from the origin), >= 0."""
    return abs(float(np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])).sum()) / 6.0)


def area(tris: np.ndarray) -> float:
    """Surface area."""
    return 0.5 * float(np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum())
