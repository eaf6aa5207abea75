"""Output contract (DESIGN.md §5): HDF5 round trip, XDMF through VTK, crash safety, plots."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings

import h5py
import numpy as np
import pytest

from sphgraph.errors import InputError
from sphgraph.io import (OutputWarning, OutputWriter, list_frames, prepare_out_dir, read_attrs,
                         read_frame, read_group, read_timing)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = 'format = 1\nname = "tiny"\n[domain]\nmin = [0, 0]\nmax = [1, 1]\n'


def synthetic(n: int, dim: int, seed: int, precision="float64") -> dict:
    """A small particle set; boundary first, like Scene.build_particles."""
    rng = np.random.default_rng(seed)
    dt = np.dtype(precision)
    kind = np.zeros(n, np.int8)
    kind[: n // 4] = 1
    return {
        "id": np.arange(n, dtype=np.int64),
        "kind": kind,
        "position": rng.random((n, dim)),
        "velocity": rng.standard_normal((n, dim)).astype(dt),
        "density": (1000 + rng.standard_normal(n)).astype(dt),
        "pressure": rng.standard_normal(n).astype(dt) * 1e3,
    }


def root_attrs(dim, precision="float64", dp=0.05):
    return {"scene": SCENE, "version": "0.1.0", "backend": "numba-cpu", "comm": "single",
            "ranks": 1, "schedule": "production", "precision": precision, "dim": dim,
            "dp": dp, "h": 1.4 * dp}


def write_run(out, dim, nframes=3, n=64, precision="float64"):
    prepare_out_dir(out, overwrite=False)
    frames = [synthetic(n, dim, seed, precision) for seed in range(nframes)]
    with OutputWriter(out, root_attrs(dim, precision), dim, precision) as w:
        for i, fr in enumerate(frames):
            w.write_frame(i, 0.25 * i, 100 * i, fr)
    return frames


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_round_trip_bit_exact(tmp_path, dim, precision):
    out = tmp_path / "run"
    frames = write_run(out, dim, precision=precision)
    assert list_frames(out) == [(0, 0.0, 0), (1, 0.25, 100), (2, 0.5, 200)]
    for i, fr in enumerate(frames):
        got = read_frame(out, index=i)
        assert (got["index"], got["time"], got["step"]) == (i, 0.25 * i, 100 * i)
        for k, v in fr.items():
            assert got[k].dtype == v.dtype, k
            np.testing.assert_array_equal(got[k], v, err_msg=k)
    assert read_frame(out, time=0.3)["index"] == 1      # nearest frame
    assert read_frame(out)["index"] == 2                # default: last
    attrs = read_attrs(out)
    for k, v in root_attrs(dim, precision).items():
        assert attrs[k] == v, k


def test_master_layout_through_h5py(tmp_path):
    """The contract paths work in plain h5py, from any working directory."""
    out = tmp_path / "run"
    frames = write_run(out, 3)
    cwd = os.getcwd()
    os.chdir("/")
    try:
        with h5py.File(out / "output.h5", "r") as f:
            assert sorted(f["frames"]) == ["000000", "000001", "000002"]
            g = f["/frames/000002"]
            assert g.attrs["time"] == 0.5 and g.attrs["step"] == 200
            np.testing.assert_array_equal(g["position"][()], frames[2]["position"])
            assert g["id"].dtype == np.int64 and g["kind"].dtype == np.int8
            assert f.attrs["scene"] == SCENE and f.attrs["dim"] == 3
            assert sorted(f["timing"]) == ["bytes", "end", "lane", "rank", "start", "step", "task"]
    finally:
        os.chdir(cwd)
    assert (out / "frames" / "frame_000002.h5").is_file()


def test_rows_sorted_by_id_and_validated(tmp_path):
    out = tmp_path / "run"
    prepare_out_dir(out, overwrite=False)
    fr = synthetic(20, 2, 0)
    perm = np.random.default_rng(1).permutation(20)
    shuffled = {k: v[perm] for k, v in fr.items()}
    with OutputWriter(out, root_attrs(2), 2, "float64") as w:
        w.write_frame(0, 0.0, 0, shuffled)
        with pytest.raises(ValueError, match="position"):
            w.write_frame(1, 0.1, 1, {**fr, "position": fr["position"][:, :1]})
        with pytest.raises(ValueError, match="missing"):
            w.write_frame(1, 0.1, 1, {k: v for k, v in fr.items() if k != "pressure"})
        dup = {k: np.concatenate([v, v[:1]]) for k, v in shuffled.items()}
        with pytest.raises(ValueError, match="more than once"):
            w.write_frame(1, 0.1, 1, dup)
    got = read_frame(out, index=0)
    for k, v in fr.items():
        np.testing.assert_array_equal(got[k], v, err_msg=k)
    assert [i for i, _, _ in list_frames(out)] == [0]


def test_timing_and_groups_round_trip(tmp_path):
    out = tmp_path / "run"
    prepare_out_dir(out, overwrite=False)
    tasks = np.array(["build_cells", "forces_interior@1", "dt_allreduce", "recv_halo_1"])
    lanes = np.array(["compute", "compute", "comm", "comm"])
    with OutputWriter(out, root_attrs(2), 2, "float64") as w:
        w.write_frame(0, 0.0, 0, synthetic(10, 2, 0))
        for step in range(3):
            w.write_timing(np.arange(4) % 2, step, tasks, lanes,
                           step + np.arange(4) * 0.1, step + np.arange(4) * 0.1 + 0.05)
        w.write_frame(1, 0.1, 3, synthetic(10, 2, 1))    # timing persisted with the frame
        assert len(read_timing(out)["rank"]) == 12
        w.write_timing(1, 3, "integrate", "compute", 3.0, 3.5)  # scalars broadcast
        w.write_group("probes", {"time": np.linspace(0, 1, 5), "pressure": np.ones((5, 2)),
                                 "name": np.array(["p1", "p2"])}, {"interval": 0.25})
        w.write_group("forces/column", {"fx": np.arange(3.0)})
        w.write_group("probes", {"time": np.linspace(0, 1, 6)})  # overwrite-on-write
    t = read_timing(out)
    assert t["rank"].dtype == np.int32 and t["step"].dtype == np.int64
    assert t["start"].dtype == np.float64 and t["task"].dtype.kind == "U"
    np.testing.assert_array_equal(t["task"][:4], tasks)
    np.testing.assert_array_equal(t["lane"][:4], lanes)
    np.testing.assert_array_equal(t["step"], np.r_[np.repeat([0, 1, 2], 4), 3])
    assert t["task"][-1] == "integrate" and t["end"][-1] == 3.5
    probes = read_group(out, "probes")
    assert set(probes) == {"time"} and len(probes["time"]) == 6
    np.testing.assert_array_equal(read_group(out, "forces")["column"]["fx"], np.arange(3.0))
    with pytest.raises(InputError, match="no group"):
        read_group(out, "balance")


def test_open_existing_appends_and_truncates(tmp_path):
    out = tmp_path / "run"
    frames = write_run(out, 2)
    w = OutputWriter.open_existing(out)
    w.write_timing(0, 150, "integrate", "compute", 0.0, 1.0)
    w.write_timing(0, 250, "integrate", "compute", 1.0, 2.0)
    w.truncate(after_step=150)          # restart from a checkpoint at step 150
    assert [i for i, _, _ in w.frames] == [0, 1]
    assert not (out / "frames" / "frame_000002.h5").exists()
    w.write_frame(2, 0.6, 240, frames[0])
    w.close()
    assert list_frames(out)[-1] == (2, 0.6, 240)
    np.testing.assert_array_equal(read_timing(out)["step"], [150])
    assert read_attrs(out)["scene"] == SCENE


# ---------------------------------------------------------------------- XDMF via VTK
def _vtk_frames(xmf):
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    reader = vtk.vtkXdmfReader()      # the XDMF 2 reader; the wheel has no vtkXdmf3Reader
    reader.SetFileName(str(xmf))
    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    times = info.Get(vtk.vtkStreamingDemandDrivenPipeline.TIME_STEPS())
    out = []
    for t in times:
        reader.UpdateTimeStep(t)
        grid = reader.GetOutputDataObject(0)
        pd = grid.GetPointData()
        arrays = {pd.GetArrayName(j): vtk_to_numpy(pd.GetArray(j))
                  for j in range(pd.GetNumberOfArrays())}
        out.append((t, grid.GetNumberOfPoints(), vtk_to_numpy(grid.GetPoints().GetData()), arrays))
    return out


@pytest.mark.parametrize("dim", [2, 3])
def test_xdmf_reads_in_vtk(tmp_path, dim):
    out = tmp_path / "run"
    frames = write_run(out, dim, n=50)
    got = _vtk_frames(out / "output.xmf")
    assert [t for t, *_ in got] == [0.0, 0.25, 0.5]
    for k in (0, -1):
        _, npts, pts, arrays = got[k]
        fr = frames[k]
        assert npts == 50
        assert {"id", "kind", "velocity", "density", "pressure"} <= set(arrays)
        np.testing.assert_array_equal(pts[:, :dim], fr["position"])
        np.testing.assert_array_equal(arrays["velocity"][:, :dim], fr["velocity"])
        if dim == 2:  # the reader pads XY geometry and 2-component vectors with z = 0
            assert not pts[:, 2].any() and not arrays["velocity"][:, 2].any()
        np.testing.assert_array_equal(arrays["density"], fr["density"])
        np.testing.assert_array_equal(arrays["pressure"], fr["pressure"])
        np.testing.assert_array_equal(arrays["id"], fr["id"])


# ---------------------------------------------------------------------- crash safety
CRASH_SCRIPT = textwrap.dedent("""
    import sys, time
    import numpy as np
    from sphgraph.io import OutputWriter, prepare_out_dir
    out, dim = sys.argv[1], int(sys.argv[2])
    prepare_out_dir(out, overwrite=False)
    rng = np.random.default_rng(0)
    n = 20000
    w = OutputWriter(out, {"scene": "x = 1", "dp": 0.01}, dim, "float32")
    i = 0
    while True:
        w.write_frame(i, 0.01 * i, 10 * i, {
            "id": np.arange(n), "kind": np.zeros(n, np.int8),
            "position": rng.random((n, dim)), "velocity": rng.random((n, dim)),
            "density": np.full(n, 1000.0), "pressure": np.full(n, float(i))})
        w.write_timing(0, i, ["forces_interior"] * 50, "compute", np.arange(50.0), np.arange(50.0) + 1)
        if i < 3:
            print(i, flush=True)
        i += 1
        time.sleep(0.002)
""")


@pytest.mark.parametrize("extra_s", [0.0, 0.37, 1.0])
def test_sigkill_leaves_readable_output(tmp_path, extra_s):
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", CRASH_SCRIPT, str(out), "3"],
                            stdout=subprocess.PIPE, env=env, text=True)
    try:
        # wait for 3 frames whatever the start-up cost, then kill mid-loop
        for _ in range(3):
            assert proc.stdout.readline(), "writer died before its third frame"
        time.sleep(extra_s)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    with h5py.File(out / "output.h5", "r") as f:
        assert "frames" in f and "timing" in f
    frames = list_frames(out)
    assert len(frames) >= 3
    assert [i for i, _, _ in frames] == list(range(len(frames)))
    for i, t, step in frames:
        fr = read_frame(out, index=i)
        assert fr["position"].shape == (20000, 3) and fr["pressure"][0] == i
    assert len(read_timing(out)["step"]) >= 50 * (len(frames) - 1)
    import xml.etree.ElementTree as ET
    ET.parse(out / "output.xmf")   # well-formed: the xmf was replaced atomically too


def test_damaged_frame_files_are_skipped(tmp_path):
    out = tmp_path / "run"
    write_run(out, 2, nframes=4)
    os.remove(out / "frames" / "frame_000003.h5")
    with open(out / "frames" / "frame_000002.h5", "r+b") as fh:
        fh.truncate(100)
    with pytest.warns(OutputWarning, match="frame 00000[23]"):
        frames = list_frames(out)
    assert [i for i, _, _ in frames] == [0, 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutputWarning)
        assert read_frame(out)["index"] == 1
        with pytest.raises(InputError, match="frame 2"):
            read_frame(out, index=2)


# ---------------------------------------------------------------------- out dir
def test_prepare_out_dir_refuses_and_overwrites(tmp_path):
    out = tmp_path / "run"
    write_run(out, 2)
    keep = out / "notes.txt"
    keep.write_text("mine")
    with pytest.raises(InputError, match="output exists.*--overwrite or --restart"):
        prepare_out_dir(out, overwrite=False)
    with pytest.raises(InputError, match="output exists"):
        OutputWriter(out, root_attrs(2), 2, "float64")
    prepare_out_dir(out, overwrite=False, restart=True)
    assert (out / "output.h5").exists()
    prepare_out_dir(out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["frames", "notes.txt"]
    assert not any((out / "frames").iterdir()) and keep.read_text() == "mine"
    assert not (tmp_path / "new").exists()
    prepare_out_dir(tmp_path / "new" / "deep", overwrite=False)
    assert (tmp_path / "new" / "deep" / "frames").is_dir()


def test_readers_on_missing_output(tmp_path):
    with pytest.raises(InputError, match="no output.h5"):
        list_frames(tmp_path)


# ---------------------------------------------------------------------- plots
def test_colour_range_leaves_impact_outliers_out_of_the_scale():
    from sphgraph.plots import colour_range

    rng = np.random.default_rng(3)
    bulk = rng.uniform(0.0, 3000.0, 2000)                       # hydrostatic-like pressures
    p = np.concatenate([bulk, [6.0e4, -5.5e4]])                 # two rows at an impact
    r = colour_range(p, "pressure")
    assert 0.0 <= r["vmin"] < 50.0 and 2950.0 < r["vmax"] <= 3000.0
    assert r["extend"] == "both" and r["cmap"] == "viridis"
    r = colour_range(bulk, "pressure")                          # no outliers: the whole range
    assert (r["vmin"], r["vmax"], r["extend"]) == (bulk.min(), bulk.max(), "neither")
    v = np.concatenate([rng.uniform(-0.5, 1.0, 2000), [40.0]])   # nothing below -0.5
    r = colour_range(v, "velocity_x")
    assert r["vmin"] == -r["vmax"] and 0.97 < r["vmax"] <= 1.0 and r["extend"] == "max"
    assert colour_range(np.zeros(5), "velocity_y")["vmax"] == 1.0       # a field at rest
    assert colour_range(np.full(5, 2.0), "density")["vmin"] == 2.0     # a uniform field
    assert colour_range(np.arange(4.0), "kind")["vmax"] == 9.5


def test_plot_scene3d_png(tmp_path):
    pytest.importorskip("matplotlib")
    from sphgraph.plots import plot_scene3d

    out = tmp_path / "run"
    write_run(out, 3, n=400)
    path = plot_scene3d(out, field="pressure")
    with open(path, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    assert os.path.getsize(path) > 1000
    out2 = tmp_path / "run2"
    write_run(out2, 2, n=100)
    with pytest.raises(InputError, match="expected a 3D run"):
        plot_scene3d(out2)


@pytest.mark.parametrize("dim", [2, 3])
def test_plot_snapshot_png(tmp_path, dim):
    pytest.importorskip("matplotlib")
    from sphgraph.plots import plot_snapshot

    out = tmp_path / "run"
    write_run(out, dim, n=400)
    path = plot_snapshot(out, time=0.3, field="speed")
    assert os.path.basename(path) == "snapshot_t0.250_speed.png"
    with open(path, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    assert os.path.getsize(path) > 1000
    svg = plot_snapshot(out, field="pressure", path=tmp_path / "p.svg")
    assert open(svg).read(200).lstrip().startswith("<?xml")
    with pytest.raises(InputError, match="expected one of pressure"):
        plot_snapshot(out, field="vorticity")
    with pytest.raises(InputError, match=r"\.png"):
        plot_snapshot(out, path=tmp_path / "p.xyz")
