"""Command line contracts: exit codes, one-line errors, nothing written on bad input,
blow-up reported with step and particle id, output readable (also by VTK's XDMF reader)."""
import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

from sphgraph.io import list_frames, read_attrs, read_frame, read_timing

from conftest import example

GOOD = """format = 1
name = "tiny"
dim = 2
dp = 0.05
end_time = 0.02
output_interval = 0.01
[domain]
min = [0.0, 0.0]
max = [1.0, 1.0]
[[fluid]]
type = "box"
min = [0.0, 0.0]
max = [0.3, 0.4]
[[boundary]]
type = "tank"
min = [0.0, 0.0]
max = [1.0, 0.8]
"""


def sph(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "sphgraph", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=300)


def test_run_writes_the_output_contract(tmp_path):
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD)
    r = sph("run", scene, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    frames = list_frames(tmp_path / "o")
    assert frames[0][1] == 0.0 and frames[0][2] == 0 and len(frames) >= 3
    a = read_frame(tmp_path / "o", index=0)
    assert a["id"].dtype == np.int64 and a["kind"].dtype == np.int8
    assert np.all(np.diff(a["id"]) > 0)
    assert a["position"].shape == (len(a["id"]), 2)
    attrs = read_attrs(tmp_path / "o")
    for k in ("scene", "version", "backend", "comm", "ranks", "schedule", "precision", "dim", "dp", "h"):
        assert k in attrs, k
    assert attrs["scene"] == GOOD
    t = read_timing(tmp_path / "o")
    assert {"build_cells", "forces_interior@1", "integrate@1"} <= set(map(str, t["task"]))
    with h5py.File(tmp_path / "o" / "output.h5") as f:
        assert "000000" in f["frames"] and f["frames/000001"].attrs["time"] > 0
    # refuse to overwrite without --overwrite
    r2 = sph("run", scene, "--out", tmp_path / "o")
    assert r2.returncode == 2 and "--overwrite" in r2.stderr
    assert sph("run", scene, "--out", tmp_path / "o", "--overwrite", "--max-steps", "2").returncode == 0


def test_xdmf_opens_in_vtk(tmp_path):
    vtk = pytest.importorskip("vtk")
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD)
    assert sph("run", scene, "--out", tmp_path / "o", "--quiet").returncode == 0
    reader = vtk.vtkXdmfReader()
    reader.SetFileName(str(tmp_path / "o" / "output.xmf"))
    reader.UpdateInformation()
    reader.Update()
    out = reader.GetOutputDataObject(0)
    block = out.GetBlock(0) if out.IsA("vtkMultiBlockDataSet") else out
    a = read_frame(tmp_path / "o", index=0)
    assert block.GetNumberOfPoints() == len(a["id"])
    pd = block.GetPointData()
    for name in ("density", "pressure", "velocity"):
        assert pd.GetArray(name) is not None, name


BAD = [
    ("malformed TOML", GOOD.replace('dim = 2', 'dim = = 2'), "tiny.toml"),
    ("unknown key", GOOD.replace('dim = 2', 'dim = 2\ncolour = "blue"'), "colour"),
    ("wrong type", GOOD.replace('dp = 0.05', 'dp = "fine"'), "dp"),
    ("dp <= 0", GOOD.replace('dp = 0.05', 'dp = -0.01'), "dp"),
    ("fluid outside the domain", GOOD.replace('max = [0.3, 0.4]', 'max = [0.3, 1.4]'), "fluid[0]"),
    ("bad kernel", GOOD + '[physics]\nkernel = "gauss"\n', "physics.kernel"),
]


@pytest.mark.parametrize("what,text,key", BAD, ids=[b[0] for b in BAD])
def test_bad_scene_is_one_line_exit_2_nothing_written(tmp_path, what, text, key):
    scene = tmp_path / "tiny.toml"
    scene.write_text(text)
    r = sph("run", scene, "--out", tmp_path / "o")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert key in lines[0] and "tiny.toml" in lines[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args,key", [
    (["--backend", "fortran"], "--backend"), (["--dp", "0"], "--dp"), (["--comm", "carrier-pigeon"], "--comm"),
    (["--schedule", "nope"], "--schedule"), (["--precision", "float16"], "--precision"),
])
def test_bad_flags_exit_2(tmp_path, args, key):
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD)
    r = sph("run", scene, "--out", tmp_path / "o", *args)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and key in r.stderr, r.stderr
    assert not (tmp_path / "o").exists()


def test_missing_scene_file_exit_2(tmp_path):
    r = sph("run", tmp_path / "nope.toml", "--out", tmp_path / "o")
    assert r.returncode == 2 and "nope.toml" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_blow_up_exit_1_with_step_and_particle_earlier_frames_intact(tmp_path):
    """CFL far beyond stability: the run must stop with the step, cause and a particle id."""
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD.replace("end_time = 0.02", "end_time = 2.0").replace(
        "output_interval = 0.01", "output_interval = 0.002") + "[physics]\ncfl = 3.0\n")
    r = sph("run", scene, "--out", tmp_path / "o", "--quiet")
    assert r.returncode == 1, r.stderr
    assert "step" in r.stderr and "particle id" in r.stderr, r.stderr
    frames = list_frames(tmp_path / "o")
    assert frames and frames[0][2] == 0
    for idx, _, _ in frames:
        a = read_frame(tmp_path / "o", index=idx)
        assert len(a["id"]) > 0


def test_info_and_python_m():
    r = sph("info")
    assert r.returncode == 0 and "numba-cpu" in r.stdout and "mock" in r.stdout


def test_snapshot_plot(tmp_path):
    pytest.importorskip("matplotlib")
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD)
    assert sph("run", scene, "--out", tmp_path / "o", "--quiet").returncode == 0
    r = sph("plot", "snapshot", tmp_path / "o", "--field", "pressure", "-o", tmp_path / "s.png")
    assert r.returncode == 0 and (tmp_path / "s.png").stat().st_size > 1000
    for what in ("timeline", "breakdown"):
        r = sph("plot", what, tmp_path / "o", "-o", tmp_path / f"{what}.svg")
        assert r.returncode == 0 and (tmp_path / f"{what}.svg").stat().st_size > 1000, r.stderr
    r = sph("trace", tmp_path / "o", "--chrome", tmp_path / "t.json")
    assert r.returncode == 0
    import json
    ev = json.loads((tmp_path / "t.json").read_text())["traceEvents"]
    assert any(e.get("name") == "forces_interior@1" and e["ph"] == "X" for e in ev)


def test_bench_json_fields():
    r = sph("bench", example("still_water.toml"), "--steps", "5", "--warmup", "1", "--json")
    assert r.returncode == 0, r.stderr
    import json
    d = json.loads(r.stdout)
    for k in ("particles", "fluid_particles", "dim", "steps", "wall_s", "compile_s", "steps_per_s",
              "particle_steps_per_s", "interactions_per_s", "bytes_per_particle", "task_seconds",
              "backend", "comm", "ranks", "precision", "integrator", "device", "version"):
        assert k in d, k
    assert d["interactions_per_s"] > d["particle_steps_per_s"] > 0


# --------------------------------------------------------------------------- load balancing flags
def _balance_scene(tmp_path, table="", name="dam.toml"):
    """The 2D dam break at dp 0.05, with an optional [balance] table."""
    text = open(example("dambreak2d.toml")).read().replace("dp = 0.02 ", "dp = 0.05 ")
    path = tmp_path / name
    path.write_text(text + ("\n[balance]\n" + table if table else ""))
    return path


def _balance_run(tmp_path, name, scene, *flags):
    from sphgraph.cli import main
    from sphgraph.io import read_group
    sched = tmp_path / "every7.toml"   # production with a schedule cadence of 7
    if not sched.exists():
        from importlib import resources
        prod = resources.files("sphgraph.schedules").joinpath("production.toml").read_text()
        sched.write_text(prod.replace("every = 50", "every = 7"))
    out = tmp_path / name
    rc = main(["run", str(scene), "--comm", "mock", "--ranks", "4", "--max-steps", "15", "--quiet",
               "--schedule", str(sched), "--out", str(out), *flags])
    assert rc == 0
    try:
        return read_group(out, "balance")
    except Exception:  # noqa: BLE001 - no /balance group
        return None


def test_rebalance_flag_over_scene_over_schedule(tmp_path):
    """The cadence used is the steps of /balance: schedule 7, scene 5, flag 3."""
    plain, table = _balance_scene(tmp_path), _balance_scene(tmp_path, "every = 5\npolicy = \"time\"\n", "table.toml")
    d = _balance_run(tmp_path, "schedule", plain)
    assert list(d["step"]) == [6, 13] and d["attrs"]["policy"] == "particles"
    d = _balance_run(tmp_path, "scene", table)
    assert list(d["step"]) == [4, 9, 14] and d["attrs"]["policy"] == "time"
    d = _balance_run(tmp_path, "flag", table, "--rebalance-every", "3", "--rebalance-threshold", "0.5",
                     "--rebalance-policy", "memory", "--max-particles-per-rank", "900")
    assert list(d["step"]) == [2, 5, 8, 11, 14]
    a = d["attrs"]
    assert a["every"] == 3 and a["threshold"] == 0.5 and a["policy"] == "memory"
    assert np.all(d["capacity"] == 900)
    assert _balance_run(tmp_path, "off", table, "--no-rebalance") is None


@pytest.mark.parametrize("cmd,args,flag", [
    ("run", ["--rebalance-every", "0"], "--rebalance-every: expected an integer >= 1"),
    ("run", ["--rebalance-every", "often"], "--rebalance-every: expected an integer >= 1"),
    ("run", ["--rebalance-threshold", "-0.1"], "--rebalance-threshold: expected a number >= 0"),
    ("run", ["--rebalance-policy", "greedy"], "--rebalance-policy: expected one of particles, time, memory"),
    ("run", ["--max-particles-per-rank", "1e6"], "--max-particles-per-rank: expected an integer >= 1"),
    ("bench", ["--rebalance-every", "-3"], "--rebalance-every: expected an integer >= 1"),
])
def test_bad_rebalance_flags_exit_2(tmp_path, capsys, cmd, args, flag):
    from sphgraph.cli import main
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD)
    rc = main([cmd, str(scene), *args] + (["--out", str(tmp_path / "o")] if cmd == "run" else []))
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and flag in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("table,key", [("evry = 5", "balance.evry: unknown key"),
                                       ('every = "5"', "balance.every: expected an integer >= 1"),
                                       ("policy = 3", "balance.policy: expected one of")])
def test_bad_balance_table_exit_2_nothing_written(tmp_path, capsys, table, key):
    from sphgraph.cli import main
    scene = tmp_path / "tiny.toml"
    scene.write_text(GOOD + "[balance]\n" + table + "\n")
    rc = main(["run", str(scene), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and key in err[0] and "tiny.toml" in err[0], err
    assert not (tmp_path / "o").exists()


def test_plot_balance_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    from sphgraph.cli import main
    scene = _balance_scene(tmp_path)
    assert main(["run", str(scene), "--comm", "mock", "--ranks", "4", "--max-steps", "20", "--quiet",
                 "--rebalance-every", "5", "--out", str(tmp_path / "o")]) == 0
    png = tmp_path / "balance.png"
    assert main(["plot", "balance", str(tmp_path / "o"), "-o", str(png)]) == 0
    assert png.stat().st_size > 1000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["plot", "balance", str(tmp_path / "o")]) == 0    # default: OUTDIR/balance.png
    assert (tmp_path / "o" / "balance.png").stat().st_size > 1000


def test_bench_takes_the_rebalance_flags(tmp_path, capsys):
    """Schedule cadence 50: no check in 5 steps; --rebalance-every 2 places `rebalance`."""
    import json
    from sphgraph.cli import main
    scene = _balance_scene(tmp_path)
    for flags, placed in (([], False), (["--rebalance-every", "2"], True)):
        assert main(["bench", str(scene), "--comm", "mock", "--ranks", "4", "--steps", "4", "--warmup", "1",
                     *flags]) == 0
        assert ("rebalance" in json.loads(capsys.readouterr().out)["task_seconds"]) is placed


def test_breakdown_of_a_device_trace(tmp_path):
    """benchmarks/trace_breakdown.py: a device trace's task intervals become /timing's columns
    (copies inside tasks left out), grouped by the paper's timers per rank, drawn by
    `plots.plot_breakdown` from that table."""
    import importlib.util
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
    spec = importlib.util.spec_from_file_location("trace_breakdown", os.path.join(root, "benchmarks", "trace_breakdown.py"))
    tb = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tb)
    ev = [{"ph": "M", "name": "process_name", "pid": 0, "args": {"name": "rank 0 (device)"}}]
    for r in (0, 1):
        for step in (5, 6):
            ev += [{"ph": "X", "name": "forces_interior@1", "pid": r, "tid": 0, "ts": 1000.0 * step, "dur": 300.0,
                    "args": {"step": step}},
                   {"ph": "X", "name": "send_edges@1", "pid": r, "tid": 1, "ts": 1000.0 * step, "dur": 100.0,
                    "args": {"step": step}},
                   {"ph": "X", "name": "edge_d2h", "pid": r, "tid": 2, "ts": 1000.0 * step, "dur": 50.0,
                    "args": {"step": step, "inside": "send_edges@1"}}]
    trace = {"traceEvents": ev, "otherData": {"schedule": "production", "ranks": 2, "particles": 10}}
    p = tmp_path / "device_x.json"
    p.write_text(json.dumps(trace))
    out = tb.main([str(p), "--png-dir", str(tmp_path)])
    ms = out[0]["ms_per_step"]
    assert out[0]["steps"] == 2
    assert ms[0] == pytest.approx({"FC": 0.3, "SendEdge": 0.1}) and ms[1] == pytest.approx(ms[0])
    assert (tmp_path / "breakdown_device_x.png").stat().st_size > 1000


def test_a_closed_pipe_is_not_an_internal_error():
    """`sphgraph validate --list | head -1`: the reader goes away; no internal error, no traceback log."""
    import subprocess
    import sys
    r = subprocess.run(f"{sys.executable} -m sphgraph validate --list | head -1", shell=True,
                       capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() and "internal error" not in r.stderr and "Traceback" not in r.stderr, r.stderr
