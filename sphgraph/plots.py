"""Figures from sphgraph output (matplotlib, imported lazily: `pip install sphgraph[plot]`).

Shared helpers come first (matplotlib loading, output paths, saving); each figure
is one public function below them (`plot_snapshot` now; timelines and breakdowns
are meant to be added the same way). Figures are drawn on a bare
`matplotlib.figure.Figure` with the Agg canvas, never through pyplot, so plotting
neither needs a display nor switches the backend of a user's session.
"""
from __future__ import annotations

import os

import numpy as np

from .errors import InputError
from .io import read_attrs, read_frame

__all__ = ["SNAPSHOT_FIELDS", "plot_snapshot"]


# ---------------------------------------------------------------------- shared helpers
def _new_figure(figsize=(8.0, 5.0)):
    """A Figure attached to an Agg canvas; InputError when matplotlib is missing."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("plotting needs matplotlib: expected it installed "
                         "(pip install sphgraph[plot])") from None
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _check_path(path, what: str) -> str:
    """The output path as str; its extension picks the format (png, svg, pdf...)."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lstrip(".").lower()
    formats = _new_figure().canvas.get_supported_filetypes()
    if ext not in formats:
        raise InputError(f"{path}: {what}: expected a file name ending in one of "
                         f"{', '.join('.' + f for f in sorted(formats))}")
    return path


def _save(fig, path: str) -> str:
    d = os.path.dirname(path)
    if d:
        os.makedirs(d, exist_ok=True)
    fig.savefig(path, dpi=150)
    return path


def _marker_area(extent_x: float, extent_y: float, spacing: float, fig_width_in: float) -> float:
    """Scatter marker area [pt^2] so that particles of size `spacing` roughly touch."""
    span = max(extent_x, extent_y * 1.0, 1e-300)
    points_per_metre = 0.75 * fig_width_in * 72.0 / span
    return float(np.clip((spacing * points_per_metre) ** 2, 0.05, 60.0))


# ---------------------------------------------------------------------- snapshot
def _speed(fr):
    return np.linalg.norm(fr["velocity"], axis=1)


def _component(axis: int):
    def get(fr):
        vel = fr["velocity"]
        if axis >= vel.shape[1]:
            raise InputError(f"field velocity_{'xyz'[axis]}: this run is {vel.shape[1]}D: "
                             f"expected one of {', '.join(_fields_for(vel.shape[1]))}")
        return vel[:, axis]
    return get


# field -> (colorbar label, value getter)
SNAPSHOT_FIELDS = {
    "pressure": ("pressure [Pa]", lambda fr: fr["pressure"]),
    "density": ("density [kg/m³]", lambda fr: fr["density"]),
    "speed": ("speed |v| [m/s]", _speed),
    "velocity_x": ("velocity x [m/s]", _component(0)),
    "velocity_y": ("velocity y [m/s]", _component(1)),
    "velocity_z": ("velocity z [m/s]", _component(2)),
    "kind": ("kind (0 fluid, 1 fixed, 2 moving)", lambda fr: fr["kind"]),
    "id": ("particle id", lambda fr: fr["id"]),
}


def _fields_for(dim: int) -> list[str]:
    return [f for f in SNAPSHOT_FIELDS if not (dim == 2 and f == "velocity_z")]


def plot_snapshot(out_dir, time: float | None = None, field: str = "pressure",
                  path=None) -> str:
    """Draw one frame's particles coloured by a field.

    2D runs: the (x, y) plane. 3D runs: a slice ``|y - y_mid| < 2 dp`` seen
    along y (x horizontal, z vertical) when the ``dp`` attribute is known and the
    slice holds particles, otherwise all particles projected onto x–z. Fluid
    particles are coloured by `field`; boundary particles are grey (except for
    ``kind`` and ``id``, which colour every particle).

    Parameters
    ----------
    out_dir : str or os.PathLike
        Output directory of a run.
    time : float, optional
        Physical time; the nearest frame is drawn. Default: the last frame.
    field : str, optional
        One of `SNAPSHOT_FIELDS`: ``pressure`` (default), ``density``,
        ``speed``, ``velocity_x``, ``velocity_y``, ``velocity_z`` (3D), ``kind``,
        ``id``.
    path : str or os.PathLike, optional
        Image file; its extension picks the format (``.png``, ``.svg``...).
        Default ``DIR/snapshot_t{time:.3f}_{field}.png``.

    Returns
    -------
    str
        The path written.

    Raises
    ------
    InputError
        Unknown field, unsupported extension, missing output or matplotlib.
    """
    if field not in SNAPSHOT_FIELDS:
        raise InputError(f"snapshot field {field!r}: expected one of {', '.join(SNAPSHOT_FIELDS)}")
    if path is not None:
        path = _check_path(path, "snapshot image")
    fr = read_frame(out_dir, time=time)
    attrs = read_attrs(out_dir)
    pos = np.asarray(fr["position"], dtype=np.float64)
    dim = pos.shape[1]
    label, getter = SNAPSHOT_FIELDS[field]
    values = np.asarray(getter(fr), dtype=np.float64)
    kind = np.asarray(fr["kind"])
    dp = attrs.get("dp")

    if dim == 2:
        x, y, depth = pos[:, 0], pos[:, 1], None
        keep = np.ones(len(pos), bool)
        view, ylabel = "", "y [m]"
    else:
        x, y, depth = pos[:, 0], pos[:, 2], pos[:, 1]
        ylabel = "z [m]"
        keep = np.ones(len(pos), bool)
        view = "projection on x–z"
        if dp is not None and len(pos):
            y_mid = 0.5 * (depth.min() + depth.max())
            in_slice = np.abs(depth - y_mid) < 2.0 * float(dp)
            if in_slice.any():
                keep, view = in_slice, f"slice |y − {y_mid:.3g}| < 2dp"

    sel = np.flatnonzero(keep)
    if depth is not None:
        sel = sel[np.argsort(-depth[sel], kind="stable")]  # nearer (smaller y) drawn last
    ext_x = float(np.ptp(x[sel])) if sel.size else 1.0
    ext_y = float(np.ptp(y[sel])) if sel.size else 1.0
    spacing = float(dp) if dp is not None else np.sqrt(max(ext_x * ext_y, 1e-300) / max(sel.size, 1))
    aspect = np.clip(ext_y / ext_x, 0.25, 2.5) if ext_x > 0 else 1.0
    fig = _new_figure(figsize=(8.0, 1.0 + 6.5 * aspect))
    ax = fig.add_subplot()
    s = _marker_area(ext_x, ext_y, spacing, 8.0)

    colour_all = field in ("kind", "id")
    fluid = sel if colour_all else sel[kind[sel] == 0]
    bound = sel[:0] if colour_all else sel[kind[sel] != 0]
    if bound.size:
        ax.scatter(x[bound], y[bound], s=s, c="0.6", marker="s", linewidths=0, label="boundary")
    cmap, norm_kw = "viridis", {}
    if field.startswith("velocity_"):
        vmax = float(np.max(np.abs(values[fluid]))) if fluid.size else 1.0
        cmap, norm_kw = "coolwarm", {"vmin": -vmax or -1.0, "vmax": vmax or 1.0}
    elif field == "kind":
        cmap, norm_kw = "tab10", {"vmin": -0.5, "vmax": 9.5}
    sc = ax.scatter(x[fluid], y[fluid], s=s, c=values[fluid], cmap=cmap, linewidths=0,
                    **norm_kw)
    fig.colorbar(sc, ax=ax, label=label, shrink=0.9)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel(ylabel)
    title = f"t = {fr['time']:.3f} s (step {fr['step']}): {field}"
    ax.set_title(title + (f" — {view}" if view else ""))

    if path is None:
        path = os.path.join(os.fspath(out_dir), f"snapshot_t{fr['time']:.3f}_{field}.png")
    return _save(fig, path)
