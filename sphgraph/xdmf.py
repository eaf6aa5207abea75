"""XDMF text for sphgraph output: a temporal collection of particle clouds.

`DIR/output.xmf` lets ParaView (and VTK's `vtkXdmfReader`) open a run without
knowing anything about sphgraph: one ``Uniform`` grid per frame, ``Polyvertex``
topology (every particle a vertex), and one attribute per dataset of the frame,
all pointing straight into the per-frame files ``frames/frame_NNNNNN.h5``.
Pointing at the frame files rather than at the master's external links keeps the
XDMF valid while the master is being replaced mid-run.

The text follows XDMF 2 (``Version="2.0"``): VTK's wheel ships only the XDMF 2
reader, and ParaView's XDMF 3 readers accept the same file. 2D runs use geometry
type ``XY``, which the reader pads to 3 components itself (z = 0).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import numpy as np

__all__ = ["FieldSpec", "FrameSpec", "collection_xml", "write_xdmf"]

# numpy dtype -> (XDMF NumberType, Precision)
_NUMBER_TYPES = {
    np.dtype(np.int8): ("Char", 1),
    np.dtype(np.uint8): ("UChar", 1),
    np.dtype(np.int16): ("Int", 2),
    np.dtype(np.uint16): ("UInt", 2),
    np.dtype(np.int32): ("Int", 4),
    np.dtype(np.uint32): ("UInt", 4),
    np.dtype(np.int64): ("Int", 8),
    np.dtype(np.uint64): ("UInt", 8),
    np.dtype(np.float32): ("Float", 4),
    np.dtype(np.float64): ("Float", 8),
}


@dataclass(frozen=True)
class FieldSpec:
    """One dataset of a frame group: its name, dtype and shape after the row axis."""

    name: str
    dtype: np.dtype
    tail: tuple = ()


@dataclass(frozen=True)
class FrameSpec:
    """What the XDMF needs to know about one frame file.

    Parameters
    ----------
    index : int
        Frame index (the grid is named ``frame_NNNNNN``).
    time : float
        Physical time of the frame [s].
    file : str
        Path of the frame file relative to the XDMF file.
    group : str
        Group inside the frame file that holds the datasets.
    n : int
        Number of particles (rows).
    fields : tuple of FieldSpec
        The datasets; ``position`` becomes the geometry, the others attributes.
    """

    index: int
    time: float
    file: str
    group: str
    n: int
    fields: tuple = field(default_factory=tuple)


def _number_type(dtype) -> tuple[str, int]:
    try:
        return _NUMBER_TYPES[np.dtype(dtype)]
    except KeyError:
        raise ValueError(f"xdmf: dtype {np.dtype(dtype)} has no XDMF number type") from None


def _data_item(spec: FieldSpec, frame: FrameSpec, indent: str) -> str:
    ntype, prec = _number_type(spec.dtype)
    dims = " ".join(str(d) for d in (frame.n, *spec.tail))
    ref = f"{frame.file}:{frame.group.rstrip('/')}/{spec.name}"
    return (f'{indent}<DataItem Dimensions="{dims}" NumberType="{ntype}" '
            f'Precision="{prec}" Format="HDF">{_escape_text(ref)}</DataItem>\n')


def _escape_text(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _attribute_type(spec: FieldSpec) -> str | None:
    if spec.tail == ():
        return "Scalar"
    if len(spec.tail) == 1 and spec.tail[0] in (2, 3):
        return "Vector"
    return None  # not expressible as a point attribute: left out of the XDMF


def _grid_xml(frame: FrameSpec, dim: int) -> str:
    by_name = {f.name: f for f in frame.fields}
    if "position" not in by_name:
        raise ValueError(f"xdmf: frame {frame.index} has no position dataset")
    i1, i2, i3 = " " * 6, " " * 8, " " * 10
    out = [f'{i1}<Grid Name="frame_{frame.index:06d}" GridType="Uniform">\n',
           f'{i2}<Time Value="{float(frame.time)!r}"/>\n',
           f'{i2}<Topology TopologyType="Polyvertex" NumberOfElements="{frame.n}" '
           f'NodesPerElement="1"/>\n',
           f'{i2}<Geometry GeometryType="{"XY" if dim == 2 else "XYZ"}">\n',
           _data_item(by_name["position"], frame, i3),
           f'{i2}</Geometry>\n']
    for spec in frame.fields:
        if spec.name == "position":
            continue
        atype = _attribute_type(spec)
        if atype is None:
            continue
        out.append(f'{i2}<Attribute Name={quoteattr(spec.name)} AttributeType="{atype}" '
                   f'Center="Node">\n')
        out.append(_data_item(spec, frame, i3))
        out.append(f'{i2}</Attribute>\n')
    return "".join(out) + f"{i1}</Grid>\n"


def collection_xml(frames, dim: int) -> str:
    """XDMF text of a temporal collection, one grid per frame in index order.

    Parameters
    ----------
    frames : iterable of FrameSpec
        The frames to list; an empty collection is valid XDMF.
    dim : int
        2 or 3: geometry type ``XY`` or ``XYZ``.

    Returns
    -------
    str
        The whole XML document.
    """
    if dim not in (2, 3):
        raise ValueError(f"xdmf: dim must be 2 or 3, got {dim}")
    grids = "".join(_grid_xml(fr, dim) for fr in sorted(frames, key=lambda f: f.index))
    return ('<?xml version="1.0" ?>\n'
            '<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n'
            '<Xdmf Version="2.0" xmlns:xi="http://www.w3.org/2001/XInclude">\n'
            '  <Domain>\n'
            '    <Grid Name="particles" GridType="Collection" CollectionType="Temporal">\n'
            + grids
            + '    </Grid>\n'
            '  </Domain>\n'
            '</Xdmf>\n')


def write_xdmf(path, frames, dim: int, fsync: bool = True) -> None:
    """Write `collection_xml(frames, dim)` to `path` atomically (temp file + rename).

    A reader (or a crash) never sees a half-written file: the old version stays
    in place until the new one is complete.
    """
    path = os.fspath(path)
    text = collection_xml(frames, dim)
    d, base = os.path.split(path)
    tmp = os.path.join(d, f".{base}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        if fsync:
            os.fsync(fh.fileno())
    os.replace(tmp, path)
