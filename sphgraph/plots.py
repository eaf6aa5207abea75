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

__all__ = ["SNAPSHOT_FIELDS", "plot_snapshot", "plot_scene3d", "plot_forces", "plot_timeline", "plot_breakdown", "plot_schedule_graph",
           "plot_efficiency"]


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


def colour_range(values, field: str, tail: float = 0.5) -> dict:
    """Colour limits for a field's fluid values, as keyword arguments of ``scatter``.

    WCSPH leaves a few rows at an impact or a wall with pressures tens of times the bulk's;
    spread over the whole range they would leave every other particle one colour. The
    limits are the `tail` and 100 - `tail` percentiles (signed fields: symmetric about 0 at
    the 100 - `tail` percentile of |v|) when the whole range is more than 1.5 times theirs,
    else the whole range; ``extend`` tells the colour bar which side has values beyond the
    limits (drawn in the end colours). ``kind`` and ``id`` keep fixed limits.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if field == "kind":
        return {"cmap": "tab10", "vmin": -0.5, "vmax": 9.5, "extend": "neither"}
    if field == "id" or v.size == 0:
        return {"cmap": "viridis", "vmin": None, "vmax": None, "extend": "neither"}
    if field.startswith("velocity_"):
        a = np.abs(v)
        hi = float(np.percentile(a, 100.0 - tail))
        if float(a.max()) <= 1.5 * hi or hi == 0.0:
            hi = float(a.max())
        hi = hi or 1.0                   # a field at rest: a scale of +-1, not a zero-width one
        over, under = bool((v > hi).any()), bool((v < -hi).any())
        lo = -hi
        cmap = "coolwarm"
    else:
        lo, hi = (float(x) for x in np.percentile(v, [tail, 100.0 - tail]))
        if hi <= lo or float(v.max() - v.min()) <= 1.5 * (hi - lo):
            lo, hi = float(v.min()), float(v.max())
        under, over = bool((v < lo).any()), bool((v > hi).any())
        cmap = "viridis"
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max", (True, True): "both"}
    return {"cmap": cmap, "vmin": lo, "vmax": hi, "extend": extend[(under, over)]}


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
    rng = colour_range(values[fluid], field)
    extend = rng.pop("extend")
    sc = ax.scatter(x[fluid], y[fluid], s=s, c=values[fluid], linewidths=0, **rng)
    fig.colorbar(sc, ax=ax, label=label, shrink=0.9, extend=extend)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel(ylabel)
    title = f"t = {fr['time']:.3f} s (step {fr['step']}): {field}"
    ax.set_title(title + (f" — {view}" if view else ""))

    if path is None:
        path = os.path.join(os.fspath(out_dir), f"snapshot_t{fr['time']:.3f}_{field}.png")
    return _save(fig, path)


def plot_scene3d(out_dir, time: float | None = None, field: str = "speed", path=None,
                 max_boundary: int = 40000) -> str:
    """A 3D view of one frame: fluid particles coloured by `field`, boundary particles grey.

    For 3D runs (``sphgraph plot scene3d``); the view looks along the flume from above
    the paddle's side. Boundary particles are thinned to at most `max_boundary` (every
    k-th one) so the walls stay light; moving ones (kind 2) are drawn dark.
    """
    if field not in SNAPSHOT_FIELDS:
        raise InputError(f"snapshot field {field!r}: expected one of {', '.join(SNAPSHOT_FIELDS)}")
    fr = read_frame(out_dir, time=time)
    pos = np.asarray(fr["position"], dtype=np.float64)
    if pos.shape[1] != 3:
        raise InputError(f"{out_dir}: scene3d: expected a 3D run, got a {pos.shape[1]}D one "
                         "(use 'sphgraph plot snapshot')")
    path = _check_path(path or os.path.join(os.fspath(out_dir), f"scene3d_t{fr['time']:.3f}_{field}.png"),
                       "scene3d image")
    label, getter = SNAPSHOT_FIELDS[field]
    values = np.asarray(getter(fr), dtype=np.float64)
    kind = np.asarray(fr["kind"])
    ext = np.maximum(np.ptp(pos, axis=0), 1e-12)
    fig = _new_figure(figsize=(10.0, 4.6))
    ax = fig.add_subplot(projection="3d")
    # a long flume: keep x to scale, but let y and z take at least a fifth of its length
    ax.set_box_aspect(np.maximum(ext / ext.max(), 0.2), zoom=1.35)
    b = np.flatnonzero(kind != 0)
    s = float(np.clip(2.0e5 / max(len(pos), 1), 0.3, 12.0))
    if b.size:
        # bodies (away from the outer walls, or moving) dark; the tank's walls faint and thinned
        dp = float(read_attrs(out_dir).get("dp", 0.0))
        lo, hi = pos[b].min(0) + 2.5 * dp, pos[b].max(0) - 2.5 * dp
        body = np.all(pos[b] > lo, axis=1) & np.all(pos[b][:, :2] < hi[:2], axis=1) | (kind[b] == 2)
        walls = b[~body][::max(1, int(np.ceil((~body).sum() / max_boundary)))]
        ax.scatter(*pos[walls].T, s=s, c="0.75", alpha=0.12, linewidths=0, depthshade=False)
        ax.scatter(*pos[b[body]].T, s=s, c="0.3", alpha=0.8, linewidths=0, depthshade=False)
    f = np.flatnonzero(kind == 0)
    rng = colour_range(values[f], field)
    extend = rng.pop("extend")
    sc = ax.scatter(*pos[f].T, s=s, c=values[f], linewidths=0, depthshade=False, **rng)
    fig.colorbar(sc, ax=ax, label=label, shrink=0.6, pad=0.02, extend=extend)
    ax.view_init(elev=24, azim=-58)
    ax.locator_params(nbins=4)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(f"t = {fr['time']:.2f} s (step {fr['step']}): {len(f):,} fluid, "
                 f"{len(pos) - len(f):,} boundary particles")
    d = os.path.dirname(path)
    if d:
        os.makedirs(d, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight", pad_inches=0.05)   # 3D axes leave wide margins
    return path


def plot_forces(out_dir, path=None) -> str:
    """Time series of ``/forces`` (each body's force components) and, when the run has
    them, the ``/probes`` surface heights, from a run's output (``sphgraph plot forces``)."""
    from .io import read_group
    path = _check_path(path or os.path.join(os.fspath(out_dir), "forces.png"), "forces plot")
    forces = read_group(out_dir, "forces")
    try:
        probes = read_group(out_dir, "probes")
    except InputError:
        probes = {}
    heights = {k: v for k, v in probes.items() if isinstance(v, dict) and "height" in v}
    fig = _new_figure(figsize=(9.0, 6.0 if heights else 3.6))
    axes = fig.subplots(2 if heights else 1, 1, sharex=True, squeeze=False)[:, 0]
    t = np.asarray(forces["time"])
    for name, v in forces.items():
        if not isinstance(v, dict) or "force" not in v:
            continue
        F = np.asarray(v["force"])
        for a in range(F.shape[1]):
            axes[0].plot(t, F[:, a], lw=1.0, label=f"{name} F{'xyz'[a]}")
    axes[0].set_ylabel("force [N]")
    axes[0].legend(fontsize=8, ncol=2)
    axes[0].grid(alpha=0.3)
    if heights:
        for name, v in heights.items():
            axes[1].plot(np.asarray(probes["time"]), np.asarray(v["height"]), lw=1.0, label=name)
        axes[1].set_ylabel("surface height [m]")
        axes[1].legend(fontsize=8)
        axes[1].grid(alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    return _save(fig, path)


# ---------------------------------------------------------------------- task timings
def _kind_colors(labels):
    from matplotlib import colormaps
    cmap = colormaps["tab20"]
    from .graph.kinds import TaskKind
    known = TaskKind.labels()
    return {lab: cmap((known.index(lab) if lab in known else len(known) + i) % 20)
            for i, lab in enumerate(labels)}


def plot_timeline(out_dir, path=None, steps="last3") -> str:
    """Per-rank Gantt chart of the tasks (the seed paper's Fig. 2): one row per rank and lane."""
    from .graph.kinds import LANES
    from .trace import load_timing
    t = load_timing(out_dir)
    path = _check_path(path or os.path.join(os.fspath(out_dir), "timeline.png"), "timeline")
    step = np.asarray(t["step"])
    if steps == "all":
        sel = np.ones(len(step), bool)
    elif steps.startswith("last"):
        k = int(steps[4:] or 3)
        sel = step > step.max() - k
    else:
        try:
            a, b = (int(x) for x in steps.split(":"))
        except ValueError:
            raise InputError(f"--steps: expected 'all', 'lastN' or A:B, got {steps!r}") from None
        sel = (step >= a) & (step < b)
    ranks = np.asarray(t["rank"])[sel]
    names = [str(x).split("@")[0] for x in np.asarray(t["task"])[sel]]
    lanes = [str(x) for x in np.asarray(t["lane"])[sel]]
    start, end = np.asarray(t["start"])[sel], np.asarray(t["end"])[sel]
    rows = sorted({(int(r), ln) for r, ln in zip(ranks, lanes)}, key=lambda x: (x[0], LANES.index(x[1]) if x[1] in LANES else 9))
    row_of = {rl: i for i, rl in enumerate(rows)}
    colors = _kind_colors(sorted(set(names)))
    fig = _new_figure((10.0, 1.0 + 0.45 * len(rows)))
    ax = fig.add_subplot()
    t0 = start.min() if len(start) else 0.0
    for r, ln, nm, a, b in zip(ranks, lanes, names, start, end):
        ax.barh(row_of[(int(r), ln)], (b - a) * 1e3, left=(a - t0) * 1e3, color=colors[nm], edgecolor="none")
    ax.set_yticks(range(len(rows)), [f"rank {r} {ln}" for r, ln in rows])
    ax.invert_yaxis()
    attrs = read_attrs(out_dir)
    clock = "virtual ms (mock MPI)" if attrs.get("comm") == "mock" else "ms"
    ax.set_xlabel(f"time [{clock}]")
    ax.set_title(f"task timeline, schedule {attrs.get('schedule', '?')}")
    from matplotlib.patches import Patch
    ax.legend(handles=[Patch(color=c, label=n) for n, c in colors.items()], fontsize=7,
              loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return _save(fig, path)


def plot_breakdown(out_dir, path=None, timers: bool = True, timing: dict | None = None,
                   title: str = "time breakdown by task") -> str:
    """Share of each task per rank (the seed paper's Figs. 11-12), stacked bars; by the
    paper's timer names (SendEdge, RecvHalo, SendDisplaced, RecvDisplaced, SynchroDt,
    Balancing, FC, NL, PU) unless `timers` is False (then by task kind). `timing`: a table
    of the same columns as a run's /timing (rank, task, start, end, step) instead of the
    one in out_dir (benchmarks/trace_breakdown.py: a device trace's)."""
    from .trace import load_timing, seconds_by_rank_and_kind
    t = load_timing(out_dir) if timing is None else timing
    path = _check_path(path or os.path.join(os.fspath(out_dir), "breakdown.png"), "breakdown")
    per = seconds_by_rank_and_kind(t, timers=timers)
    kinds = sorted({k for d in per.values() for k in d})
    colors = _kind_colors(kinds)
    fig = _new_figure((8.0, 4.5))
    ax = fig.add_subplot()
    ranks = sorted(per)
    bottom = np.zeros(len(ranks))
    for k in kinds:
        tot = np.array([sum(per[r].values()) for r in ranks])
        share = np.array([per[r].get(k, 0.0) for r in ranks]) / np.maximum(tot, 1e-300) * 100
        ax.bar([str(r) for r in ranks], share, bottom=bottom, color=colors[k], label=k)
        bottom += share
    ax.set_xlabel("rank")
    ax.set_ylabel("share of task time [%]")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return _save(fig, path)


def plot_schedule_graph(schedule, ranks: int, stages: int, path, features=(), ring=False) -> str:
    """The multi-rank step graph: one column of tasks per rank, message edges across
    (`features`: a scene's feature task kinds, `ring`: its periodic split axis)."""
    from .graph.build import multi_rank_graph
    path = _check_path(path, "--plot")
    programs = {r: schedule.program(r, ranks, stages, ring=ring, features=features) for r in range(ranks)}
    g = multi_rank_graph(programs)
    # one row per task name (rows of the fullest program), so ranks line up and the
    # collective, drawn once in the middle, has its row to itself
    rows = [t.name for t in max(programs.values(), key=len)]
    pos = {}
    for r, prog in programs.items():
        for t in prog:
            n = ("all", t.name) if t.collective else (r, t.name)
            pos[n] = ((ranks - 1) / 2.0 if t.collective else r, -rows.index(t.name))
    fig = _new_figure((3.0 + 2.6 * ranks, 1.0 + 0.42 * max(len(p) for p in programs.values())))
    ax = fig.add_subplot()
    for u, v, d in g.edges(data=True):
        (x0, y0), (x1, y1) = pos[u], pos[v]
        msg = d.get("kind") == "message"
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0),
                    arrowprops={"arrowstyle": "->", "color": "tab:red" if msg else "0.6",
                                "lw": 1.0, "connectionstyle": "arc3,rad=0.15" if msg else "arc3"})
    for n, (x, y) in pos.items():
        ax.text(x, y, n[1], ha="center", va="center", fontsize=7,
                bbox={"boxstyle": "round", "fc": "lightyellow" if n[0] == "all" else "white", "ec": "0.5"})
    ax.set_xlim(-0.7, ranks - 0.3)
    ax.set_ylim(-max(len(p) for p in programs.values()), 1)  # text and arrows do not autoscale
    ax.set_xticks(range(ranks), [f"rank {r}" for r in range(ranks)])
    ax.set_yticks([])
    ax.set_title(f"schedule {schedule.name}: program order (grey), messages (red)")
    return _save(fig, path)


def plot_balance(out_dir, path=None) -> str:
    """Load balancing (seed paper Figs. 5-6): each rank's share of the fluid particles
    at every check, and its force-computation time per step."""
    from .io import read_group
    try:
        d = read_group(out_dir, "balance")
    except Exception:  # noqa: BLE001 - any read failure means: no balancing records
        d = None
    if not d or "step" not in d:
        raise InputError(f"{out_dir}: /balance: expected balancing records (a multi-rank run "
                         f"with a schedule that places `rebalance`), found none")
    path = _check_path(path or os.path.join(os.fspath(out_dir), "balance.png"), "balance")
    step = np.asarray(d["step"])
    counts = np.asarray(d["fluid_count"], float)
    fsec = np.asarray(d["force_seconds"], float)
    applied = np.asarray(d["applied"], bool)
    fig = _new_figure((9.0, 6.5))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    share = counts / counts.sum(axis=1, keepdims=True) * 100
    for r in range(share.shape[1]):
        ax1.plot(step, share[:, r], marker=".", label=f"rank {r}")
        ax2.plot(step, fsec[:, r] * 1e3, marker=".", label=f"rank {r}")
    for s in step[applied]:
        ax1.axvline(s, color="0.8", lw=0.8, zorder=0)
        ax2.axvline(s, color="0.8", lw=0.8, zorder=0)
    ax1.set_ylabel("share of fluid particles [%]\n(halos included)")
    ax2.set_ylabel("force time per step [ms]")
    ax2.set_xlabel("step (grey lines: new cuts applied)")
    ax1.legend(fontsize=7, ncol=min(4, share.shape[1]))
    attrs = d.get("attrs", {})
    ax1.set_title(f"load balancing: policy {attrs.get('policy', '?')}, "
                  f"{int(applied.sum())} of {len(step)} checks applied")
    return _save(fig, path)


PAPER_EFFICIENCY = [(2, 0.98, "2 GPUs, >= 4 M"), (4, 0.92, "4 GPUs"), (14, 0.81, "14 GPUs, 16 M")]


def efficiency_series(data: dict) -> list[dict]:
    """[{label, N, E, measured}] from an efficiency JSON: `benchmarks/efficiency_predict.py
    curve` (variants x schedules), `benchmarks/efficiency_cpu.py` (one measured N), or
    {"series": [{"label", "N", "E", "measured"}]}."""
    if "series" in data:
        return [dict(s, measured=bool(s.get("measured", False))) for s in data["series"]]
    out = []
    for vname, v in data.get("variants", {}).items():
        for sched, rows in v.get("schedules", {}).items():
            ns = sorted(int(n) for n in rows)
            out.append({"label": f"{v.get('label', vname)} [{sched}]", "N": ns,
                        "E": [float(rows[str(n)]["E"]) for n in ns], "measured": False,
                        "variant": vname, "schedule": sched})
    if not out and "E" in data and "ranks" in data:
        out.append({"label": f"measured, {data.get('scene', '?')}, {data['ranks']} ranks x 1 thread",
                    "N": [1, int(data["ranks"])], "E": [1.0, float(data["E"])], "measured": True})
        p = data.get("predicted")
        if p and "E" in p:
            out.append({"label": "predicted (mock engine)", "N": [1, int(data["ranks"])],
                        "E": [1.0, float(p["E"])], "measured": False})
    return out


def plot_efficiency(source, path=None) -> str:
    """Parallel efficiency E = (steps/s on N / N) / (steps/s on 1) against N (seed paper
    Figs. 8-9), with the paper's points (0.98 on 2 GPUs, 0.92 on 4, 0.81 on 14 at 16 M).
    `source`: an efficiency JSON file, or a directory holding `efficiency.json`."""
    import json
    src = os.fspath(source)
    if os.path.isdir(src):
        src = os.path.join(src, "efficiency.json")
    try:
        with open(src) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise InputError(f"{source}: expected an efficiency JSON file (benchmarks/efficiency_predict.py "
                         f"curve --json F) or a directory holding efficiency.json") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{src}: expected JSON: {e}") from None
    series = efficiency_series(data) if isinstance(data, dict) else []
    if not series:
        raise InputError(f"{src}: expected efficiency results (variants/schedules with E per N, "
                         f"'series', or an efficiency_cpu.py result), found none")
    path = _check_path(path or os.path.splitext(src)[0] + ".png", "efficiency")
    fig = _new_figure((8.0, 5.5))
    ax = fig.subplots()
    styles = {"production": "-", "bulk-synchronous": "--"}
    colors: dict = {}
    cycle = ["C0", "C1", "C2", "C3", "C4", "C5", "C6"]
    for s in series:
        key = s.get("variant", s["label"])
        c = colors.setdefault(key, cycle[len(colors) % len(cycle)])
        ax.plot(s["N"], s["E"], ls="-" if s["measured"] else styles.get(s.get("schedule"), "-"),
                marker="s" if s["measured"] else "o", ms=4, color=c, label=s["label"])
    for n, e, what in PAPER_EFFICIENCY:
        ax.plot([n], [e], marker="*", ms=13, color="k", ls="none",
                label="seed paper (2012)" if n == PAPER_EFFICIENCY[0][0] else None)
        ax.annotate(f"{e:.2f} ({what})", (n, e), textcoords="offset points", xytext=(6, -12), fontsize=7)
    ax.axhline(1.0, color="0.7", lw=0.8, zorder=0)
    ns = sorted({n for s in series for n in s["N"]} | {n for n, _, _ in PAPER_EFFICIENCY})
    ax.set_xscale("log", base=2)
    ax.set_xticks(ns)
    ax.set_xticklabels([str(n) for n in ns])
    lo = min(min(s["E"]) for s in series)
    ax.set_ylim(max(0.0, min(lo, 0.75) - 0.05), 1.05)
    ax.set_xlabel("ranks N")
    ax.set_ylabel("E = (steps/s on N / N) / (steps/s on 1)")
    parts = [str(data.get("scene", "")).replace("examples/", "")]
    if data.get("particles"):
        parts.append(f"{data['particles'] / 1e6:.1f} M particles")
    if "variants" in data:
        parts.append("predicted by the mock engine (model)")
    ax.set_title("parallel efficiency: " + ", ".join(p for p in parts if p), fontsize=10)
    ax.legend(fontsize=7, loc="lower left")
    return _save(fig, path)


# ---------------------------------------------------------------------- validation, study, stability
def plot_validation(result, title: str, path) -> str:
    """Simulation against reference of one validation case (`sphgraph validate`)."""
    path = _check_path(path, "validation")
    # a series (x, y, style, panel) goes to the axes of its panel (one a gauge, say), the
    # others to one axes; within a panel the run and its data share a colour
    panels = list(dict.fromkeys(v[3] if len(v) > 3 else None for v in result.series.values()))
    ncol = 1 if len(panels) == 1 else 2
    nrow = (len(panels) + ncol - 1) // ncol
    fig = _new_figure((7.5 * (1 if ncol == 1 else 1.6), 5.0 * (1 if nrow == 1 else 0.75 * nrow)))
    axes = np.atleast_1d(fig.subplots(nrow, ncol, squeeze=False)).ravel()
    for i, (label, v) in enumerate(result.series.items()):
        x, y, style = v[:3]
        k = panels.index(v[3] if len(v) > 3 else None)
        ax = axes[k]
        color = f"C{i}" if len(panels) == 1 else f"C{k}"
        if style == "o":
            ax.plot(x, y, "o", ms=5, mfc="none", label=label, color=color)
        elif style == ".":
            ax.plot(x, y, ".", ms=2, label=label, color=color, alpha=0.5 if len(panels) > 1 else 1.0)
        else:
            ax.plot(x, y, style, lw=1.4, label=label, color=color)
    worst = [c for c in result.checks if not c[4]]
    verdict = 'PASS' if result.ok else 'FAIL ' + ', '.join(c[0] for c in worst)
    if result.stopped is not None:   # a run that stopped: its series end there
        verdict = f"STOPPED ({result.stopped[:90]})"
    fig.suptitle(f"{title}\ndp = {result.dp:g}: {verdict}", fontsize=9)
    for ax in axes[:len(panels)]:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    return _save(fig, path)


def pareto_front(cost, err) -> np.ndarray:
    """Indices of the points no other point beats in both cost and error (sorted by cost)."""
    cost, err = np.asarray(cost, float), np.asarray(err, float)
    order = np.argsort(cost, kind="stable")
    front, best = [], np.inf
    for i in order:
        if np.isfinite(err[i]) and err[i] < best:
            front.append(i)
            best = err[i]
    return np.array(front, int)


def plot_study(rows: list, path, title: str = "", error_key: str = "error",
               xlabel: str = "wall time [s] of the run (this machine)") -> str:
    """Error against wall time (log-log) of a `sphgraph study`, Pareto front marked."""
    path = _check_path(path, "study")
    fig = _new_figure((8.0, 5.5))
    ax = fig.subplots()
    ok = [r for r in rows if np.isfinite(r[error_key]) and r["wall_s"] > 0]
    groups: dict = {}
    # a run is labelled by the settings that differ between the plotted runs: the ones they all share
    # would make every label the same long line
    result = {"case", "dp", "error", "wall_s", "steps", "particles", "status", "pareto", error_key}
    keys = [k for k in rows[0] if k not in result] if rows else []
    varied = [k for k in keys if len({str(r.get(k)) for r in ok}) > 1]
    for r in ok:
        label = ", ".join(f"{k}={r[k]}" for k in varied) or ", ".join(f"{k}={r[k]}" for k in keys[:5])
        groups.setdefault(label, []).append(r)
    markers = "osD^v<>ph*"
    for i, (label, rs) in enumerate(sorted(groups.items())):
        rs = sorted(rs, key=lambda r: r["dp"])
        ax.plot([r["wall_s"] for r in rs], [r[error_key] for r in rs], marker=markers[i % len(markers)],
                ls=":", ms=6, mfc="none", color=f"C{i % 10}", label=label)
        for r in rs:
            ax.annotate(f"{r['dp']:g}", (r["wall_s"], r[error_key]), textcoords="offset points",
                        xytext=(4, 3), fontsize=6, color=f"C{i % 10}")
    if ok:
        idx = pareto_front([r["wall_s"] for r in ok], [r[error_key] for r in ok])
        ax.plot([ok[i]["wall_s"] for i in idx], [ok[i][error_key] for i in idx], "-", color="k", lw=2,
                alpha=0.35, zorder=0, label="Pareto front")
        ax.plot([ok[i]["wall_s"] for i in idx], [ok[i][error_key] for i in idx], "s", color="k", ms=9,
                mfc="none", zorder=0)
    failed = [r for r in rows if not np.isfinite(r[error_key])]
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(error_key.replace("_", " "))
    failed_note = f"  ({len(failed)} run{'s' * (len(failed) != 1)} failed)" if failed else ""
    ax.set_title((title or "error against cost") + failed_note, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(0.0, -0.12), ncol=1, frameon=False)
    return _save(fig, path)


def plot_stability(cells: list, path, x="cfl", y="coefsound", title="") -> str:
    """Stability map: one marker per run of a sweep, coloured by the failure detected."""
    path = _check_path(path, "stability")
    fig = _new_figure((7.0, 5.0))
    ax = fig.subplots()
    kinds = sorted({c["verdict"] for c in cells}, key=lambda v: (v != "stable", v))
    for i, k in enumerate(kinds):
        cs = [c for c in cells if c["verdict"] == k]
        ax.scatter([c[x] for c in cs], [c[y] for c in cs], s=140, marker="s" if k == "stable" else "X",
                   color="C2" if k == "stable" else f"C{(i + 2) % 10}", label=k, edgecolors="k", linewidths=0.5)
    for c in cells:
        if c.get("value") is not None:
            ax.annotate(f"{c['value']:.2g}", (c[x], c[y]), textcoords="offset points", xytext=(0, 9),
                        fontsize=6, ha="center")
    ax.set_xscale("log")
    ax.set_yscale("log")
    for setter, key in ((ax.set_xticks, x), (ax.set_yticks, y)):
        vals = sorted({c[key] for c in cells})
        setter(vals, [f"{v:g}" for v in vals])
    ax.minorticks_off()
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.set_title(title or f"where the method fails: {x} x {y} (label: worst density variation, "
                 "or energy growth factor)", fontsize=8)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_penetration(cells: list, path, title="") -> str:
    """Wall-penetration map (`stability.penetration_map`): impact speed x wall model, each cell
    coloured by the share of the fluid that got beyond the wall (green: held) and labelled with
    the count; beside it each model's median wall-time per step (its cost)."""
    from matplotlib.colors import Normalize
    from matplotlib import colormaps
    path = _check_path(path, "penetration map")
    speeds = sorted({c["speed"] for c in cells})
    models = list(dict.fromkeys(c["model"] for c in cells))
    fig = _new_figure((9.0, 1.6 + 0.7 * len(models)))
    ax, axc = fig.subplots(1, 2, width_ratios=[3, 1], sharey=True)
    reds, norm = colormaps["Reds"], Normalize(0.0, 0.6)
    for c in cells:
        x, y = speeds.index(c["speed"]), models.index(c["model"])
        share = c["through"] / c["n_fluid"]
        if c["verdict"] == "stable":
            color, text = "#9bd19b", "held"
        elif c["through"]:
            color, text = reds(norm(0.08 + share)), f"{c['through']}/{c['n_fluid']}\nfrom step {c['step']}"
        else:
            color, text = "0.7", c["verdict"]
        if "then" in c.get("detail", ""):
            text += "\n(then left domain)" if "domain" in c["detail"] else "\n(then blow-up)"
        ax.add_patch(_rect((x - 0.5, y - 0.5), color))
        ax.text(x, y, text, ha="center", va="center", fontsize=7, color="w" if share > 0.35 else "k")
    ax.set_xlim(-0.5, len(speeds) - 0.5)
    ax.set_ylim(len(models) - 0.5, -0.5)
    ax.set_xticks(range(len(speeds)), [f"{v:g}" for v in speeds])
    ax.set_yticks(range(len(models)), models)
    ax.set_xlabel("impact speed [m/s]")
    ax.set_ylabel("wall model (boundary-layers)")
    ax.set_title(title or "fluid particles beyond the outermost wall row (counted from positions "
                 "every step)", fontsize=8)
    from .stability import model_costs
    cost = model_costs(cells)
    ms = [cost[m] or 0.0 for m in models]
    axc.barh(range(len(models)), ms, color=["C0" if m.startswith("dbc") else "C1" for m in models])
    for y, v in enumerate(ms):
        axc.text(v, y, f" {v:.2f}", va="center", fontsize=7)
    axc.set_xlim(0, 1.35 * max(ms + [1e-3]))
    axc.set_xlabel("ms per step (median)")
    axc.set_title("cost", fontsize=8)
    axc.grid(alpha=0.3, axis="x")
    return _save(fig, path)


def _rect(xy, color):
    from matplotlib.patches import Rectangle
    return Rectangle(xy, 1.0, 1.0, facecolor=color, edgecolor="k", linewidth=0.5)
