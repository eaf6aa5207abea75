"""Open boundaries (issue 9 §3): with [domain] exclude_outside, particles leaving the domain
(cause 2) or their density bounds (cause 3) are removed and counted, not fatal; 1 and 3
mock ranks exclude the same ids."""
from __future__ import annotations

import numpy as np
import pytest

from sphgraph import NumericalError, Scene, Simulation


def spill(exclude=True):
    # water on a short floor: the rows beyond the floor's end fall out of the domain's bottom
    return Scene.from_dict({
        "format": 1, "dim": 2, "dp": 0.02, "end_time": 1.0,
        "domain": {"min": [-0.1, -0.06], "max": [1.5, 0.6], "origin": [0.0, 0.0],
                   "exclude_outside": exclude, "exclude_max_share": 1.0},   # an outflow: no bound
        "physics": {"coefsound": 10.0, "hswl": 0.2},
        "fluid": [{"type": "box", "min": [0.02, 0.02], "max": [1.2, 0.2]}],
        "boundary": [{"type": "wall", "min": [0.0, 0.0], "max": [0.8, 0.0], "layers": 2}]})


def test_particles_leaving_the_domain_are_excluded_and_counted_on_1_and_3_ranks():
    out = {}
    for ranks in (1, 3):
        sim = Simulation(spill(), comm="single" if ranks == 1 else "mock", ranks=ranks,
                         decomposition_axis="x")
        n0 = sim.n_total
        for _ in range(260):
            sim.step()
        a = sim.frame_arrays()
        ex = np.sort(np.concatenate([c.state.extra["excluded_ids"] for c in sim.contexts]))
        rec = sim.features.exclusions(sim)
        assert len(ex) > 0 and np.array_equal(np.sort(rec["id"]), ex)
        assert np.all(rec["cause"] == 2)
        # each row is recorded where it left: outside the domain, beyond the floor's end, falling
        x, y = rec["position"].T
        assert rec["position"].shape == (len(ex), 2) and rec["velocity"].shape == (len(ex), 2)
        assert np.all((x < -0.1) | (x > 1.5) | (y < -0.06) | (y > 0.6)) and np.all(x > 0.8)
        assert np.all(rec["velocity"][:, 1] < 0)
        assert np.all((rec["density"] > 900) & (rec["density"] < 1100))
        assert len(a["id"]) + len(ex) == n0 and not np.intersect1d(a["id"], ex).size
        out[ranks] = (ex, a)
    assert np.array_equal(out[1][0], out[3][0])
    # this spill over the floor's edge amplifies round-off of the rank-dependent partial force
    # sums: 1 and 3 ranks differ by 2e-7 m at step 200, before anything is excluded
    np.testing.assert_allclose(out[3][1]["position"], out[1][1]["position"], rtol=0, atol=1e-5)


def test_without_exclusion_leaving_is_fatal():
    sim = Simulation(spill(exclude=False))
    with pytest.raises(NumericalError, match="left the domain"):
        for _ in range(260):
            sim.step()


def test_exclusions_are_written_to_output_the_same_on_1_and_3_ranks(tmp_path):
    """/exclusions in output.h5 (step, time, id, cause, position, velocity, density): the same
    rows on 1 and 3 mock ranks."""
    from sphgraph import run
    from sphgraph.io import read_group
    got = {}
    for ranks in (1, 3):
        run(spill(), comm="single" if ranks == 1 else "mock", ranks=ranks, out=tmp_path / f"r{ranks}",
            max_steps=260, progress=False, checkpoint_every=240 if ranks == 1 else None)
        got[ranks] = read_group(tmp_path / f"r{ranks}", "exclusions")
    a, b = got[1], got[3]
    assert len(a["id"]) >= 2 and a["attrs"]["count"] == len(a["id"])
    assert np.all(np.diff(a["step"]) >= 0) and np.all(a["cause"] == 2)
    for k in ("step", "id", "cause"):
        assert np.array_equal(a[k], b[k]), k
    # dt is a global minimum, but 1 and 3 ranks differ at round-off, which this spill amplifies
    np.testing.assert_allclose(a["time"], b["time"], rtol=1e-5)
    np.testing.assert_allclose(a["position"], b["position"], rtol=0, atol=1e-4)
    assert a["velocity"].shape == a["position"].shape == (len(a["id"]), 2)
    # a restart keeps the exclusions up to its checkpoint (they are not in the checkpoint) and
    # redoes the later ones: the exclusion at step 238 is kept, 243 and 251 are redone, none twice
    run(spill(), restart=tmp_path / "r1" / "checkpoints" / "ckpt_000000240.h5", max_steps=260, progress=False)
    c = read_group(tmp_path / "r1", "exclusions")
    for k in ("step", "id", "cause", "time", "position", "velocity", "density"):
        assert np.array_equal(c[k], a[k]), k


def test_exclusions_are_written_on_numerical_failure(tmp_path, monkeypatch):
    import sphgraph.graph.tasks as T
    from sphgraph import run
    from sphgraph.io import read_group
    orig = T.run_integrate

    def nan_at_255(ctx, task):
        orig(ctx, task)
        if ctx.rank == 1 and ctx.state.step + 1 == 255:
            ctx.state.particles.pos[0, 0] = np.nan
    monkeypatch.setattr(T, "run_integrate", nan_at_255)
    with pytest.raises(NumericalError, match="step 255 .*NaN in position"):
        run(spill(), comm="mock", ranks=3, out=tmp_path / "o", max_steps=260, progress=False)
    rows = read_group(tmp_path / "o", "exclusions")
    assert len(rows["id"]) >= 2 and rows["step"].max() < 255


def still_water(exclude=True):
    # still water; bounds [950, 1050] leave ~40 kg/m3 around the hydrostatic 1000-1009
    return Scene.from_dict({
        "format": 1, "dim": 2, "dp": 0.04, "end_time": 1.0,
        "domain": {"min": [-0.1, -0.1], "max": [1.7, 0.6], "origin": [0.0, 0.0],
                   "exclude_outside": exclude, "exclude_max_share": 0.01},  # 2 of its 228 fluid rows
        "physics": {"coefsound": 10.0, "rho_min": 950.0, "rho_max": 1050.0},
        "initial": {"hydrostatic": True},
        "fluid": [{"type": "box", "min": [0.04, 0.04], "max": [1.56, 0.28]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.6, 0.5]}]})


def set_density(sim, pid, rho):
    """Give particle `pid` density `rho` (now and as its Verlet history) on whichever rank holds it."""
    held = 0
    for c in sim.contexts:
        p = c.state.particles
        r = np.nonzero(p.id == pid)[0]
        p.rho[r] = rho
        p.rho_m1[r] = rho
        held += len(r)
    assert held == 1


def test_density_out_of_bounds_is_excluded_with_cause_3_on_1_and_3_ranks():
    """Two surface particles at the 3-rank slab cuts get a density outside [950, 1050]
    (1060 before step 1, 940 before step 31): each is removed at the end of that step
    with cause 3, and nothing else leaves."""
    sc = still_water()
    p0 = sc.build_particles()
    fl = np.nonzero(p0.kind == 0)[0]
    probe = Simulation(sc, comm="mock", ranks=3, decomposition_axis="x")
    cuts = [probe.contexts[r].state.cut_lo for r in (1, 2)]

    def top_at(x):
        return int(p0.id[fl[np.argmin(np.hypot(p0.pos[fl, 0] - x, p0.pos[fl, 1] - 0.28))]])
    dense, light = top_at(cuts[0]), top_at(cuts[1])
    out = {}
    for ranks in (1, 3):
        sim = Simulation(sc, comm="single" if ranks == 1 else "mock", ranks=ranks, decomposition_axis="x")
        set_density(sim, dense, 1060.0)
        for s in range(60):
            if s == 30:
                set_density(sim, light, 940.0)
            sim.step()
        a = sim.frame_arrays()
        rec = sim.features.exclusions(sim)
        ex = np.sort(np.concatenate([c.state.extra["excluded_ids"] for c in sim.contexts]))
        assert list(rec["step"]) == [1, 31] and list(rec["id"]) == [dense, light]
        assert list(rec["cause"]) == [3, 3]
        assert np.array_equal(ex, np.sort([dense, light]))
        assert np.array_equal(a["id"], np.setdiff1d(p0.id, [dense, light]))   # only they left
        assert sim.invariants.n_excluded == 2
        out[ranks] = (rec, a)
    (r1, a1), (r3, a3) = out[1], out[3]
    for k in ("step", "id", "cause"):
        assert np.array_equal(r1[k], r3[k]), k
    np.testing.assert_allclose(r3["time"], r1["time"], rtol=1e-12)
    np.testing.assert_allclose(a3["position"], a1["position"], rtol=0, atol=1e-9 * 1.8)


def test_without_exclusion_a_density_out_of_bounds_is_fatal():
    sim = Simulation(still_water(exclude=False))
    set_density(sim, int(np.nonzero(sim.scene.build_particles().kind == 0)[0][-1]), 1060.0)
    with pytest.raises(NumericalError, match="step 1 .*density outside"):
        sim.step()


KILLED_RUN = r'''
import os, signal, sys
import sphgraph.graph.tasks as T
from sphgraph.cli import main
scene, out = sys.argv[1:3]
orig = T.run_integrate

def killed_in_step_250(ctx, task):   # after the checkpoint at 240 and the exclusion at 243
    orig(ctx, task)
    if ctx.state.step + 1 == 250:
        os.kill(os.getpid(), signal.SIGKILL)
T.run_integrate = killed_in_step_250
sys.exit(main(["run", scene, "--out", out, "--quiet", "--max-steps", "260", "--checkpoint-every", "240"]))
'''


def test_exclusions_survive_a_sigkill_through_the_checkpoint(tmp_path):
    """A SIGKILL leaves no /exclusions in output.h5; the checkpoint holds the rows recorded
    before it (step 238), so the restarted run's table equals the uninterrupted run's, bit for bit."""
    import os
    import signal
    import subprocess
    import sys

    from sphgraph import InputError, run
    from sphgraph import checkpoint as ck
    from sphgraph.io import read_group
    run(spill(), out=tmp_path / "ref", max_steps=260, progress=False)
    ref = read_group(tmp_path / "ref", "exclusions")
    assert ref["step"].min() < 240 < ref["step"].max(), ref["step"]   # rows before and after the checkpoint
    scene, drv = tmp_path / "spill.toml", tmp_path / "drv.py"
    scene.write_text(spill().text)
    drv.write_text(KILLED_RUN)
    r = subprocess.run([sys.executable, str(drv), str(scene), str(tmp_path / "o")], capture_output=True,
                       text=True, timeout=120, env=dict(os.environ, NUMBA_NUM_THREADS="1"))
    assert r.returncode == -signal.SIGKILL, (r.returncode, r.stderr)
    with pytest.raises(InputError):
        read_group(tmp_path / "o", "exclusions")            # not written: the process was killed
    c = ck.find_latest(tmp_path / "o")
    assert c.step == 240
    run(str(scene), restart=tmp_path / "o", max_steps=260, progress=False)
    got = read_group(tmp_path / "o", "exclusions")
    for k in ("step", "time", "id", "cause", "position", "velocity", "density"):
        assert got[k].dtype == ref[k].dtype and np.array_equal(got[k], ref[k]), (k, got[k], ref[k])
    assert got["attrs"]["count"] == len(ref["id"])
    assert np.array_equal(c.exclusions["id"], ref["id"][ref["step"] <= 240])   # from the checkpoint


def spill_default(share=None):
    """The spill with [domain] as a user writes it: exclusion left at its default (on)."""
    d = spill().to_dict()
    d["domain"] = {k: d["domain"][k] for k in ("min", "max", "origin")}
    if share is not None:
        d["domain"]["exclude_max_share"] = share
    return Scene.from_dict(d)


def test_exclusion_is_on_by_default_and_stops_the_run_past_its_share(tmp_path):
    """Default: particles leaving are excluded; the run stops (NumericalError, exit 1) when the
    exclusions pass exclude_max_share of the fluid (0.1 % by default: the spill's first
    exclusion is 1 of 600), and /exclusions holds every one up to then."""
    from sphgraph import run
    from sphgraph.io import read_group
    assert spill_default().exclude_outside and spill_default().exclude_max_share == 1e-3
    sim = Simulation(spill_default())
    with pytest.raises(NumericalError, match=r"1 particles excluded, 0.167 % of the run's 600 fluid particles, "
                       r"above domain.exclude_max_share = 0.1 %"):
        for _ in range(260):
            sim.step()
    first = sim.step_count
    assert len(sim.features.excluded) == 1
    # 1 % of 600: the run goes on to the 7th exclusion
    with pytest.raises(NumericalError, match="7 particles excluded") as err:
        run(spill_default(0.01), out=tmp_path / "r", max_steps=400, progress=False)
    assert err.value.step > first
    rows = read_group(tmp_path / "r", "exclusions")
    assert len(rows["id"]) == 7 and rows["step"][0] == first and rows["step"][-1] == err.value.step
    assert np.all(rows["cause"] == 2)


def test_cli_summary_of_exclusions_and_exit_1_past_the_share(tmp_path, capsys):
    from sphgraph.cli import main
    from sphgraph.scene import dumps_toml
    f = tmp_path / "spill.toml"
    f.write_text(dumps_toml(spill_default(1.0).to_dict()))
    assert main(["run", str(f), "--out", str(tmp_path / "a"), "--max-steps", "260", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "sphgraph: excluded" in err and "particle left the domain" in err and "% of 600 fluid" in err
    assert "; at x " in err and ", y " in err       # the box the excluded rows' positions span
    f.write_text(dumps_toml(spill_default().to_dict()))
    assert main(["run", str(f), "--out", str(tmp_path / "b"), "--max-steps", "260", "--quiet"]) == 1
    assert "numerical failure" in capsys.readouterr().err


SIM_SCRIPT = r'''
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_exclusion import still_water
from sphgraph import Simulation
sc = still_water()
out = {}
for backend in ("numba-cpu", "numba-cuda"):
    p0 = sc.build_particles()
    fl = np.nonzero(p0.kind == 0)[0]
    p0.rho[fl[np.argmax(p0.pos[fl, 1])]] = 1060.0     # a surface particle above rho_max
    sim = Simulation(sc, backend=backend, precision="float64", particles=[p0])
    for _ in range(3):
        sim.step()
    a = sim.frame_arrays()
    rec = sim.features.exclusions(sim)
    out[backend] = {"rec": [[int(x) for x in rec[k]] for k in ("step", "id", "cause")], "ids": a["id"].tolist(),
                    "pos": a["position"].tolist(), "rho": a["density"].tolist()}
print(json.dumps(out))
'''


@pytest.mark.slow
def test_exclusion_on_numba_cuda_in_the_simulator():
    """The device path: the backend's own check finds the row, sync_host brings the rows down,
    the row goes and prepare uploads the rest; the same exclusion and particles as numba-cpu
    (NUMBA_ENABLE_CUDASIM=1, 339 particles, 3 steps, ~35 s)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1")
    here = str(Path(__file__).resolve().parent)
    r = subprocess.run([sys.executable, "-c", SIM_SCRIPT, here], capture_output=True, text=True, env=env,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    cpu, gpu = out["numba-cpu"], out["numba-cuda"]
    assert cpu["rec"] == gpu["rec"] and len(cpu["rec"][1]) == 1 and cpu["rec"][2] == [3]
    assert cpu["ids"] == gpu["ids"]
    np.testing.assert_allclose(gpu["pos"], cpu["pos"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(gpu["rho"], cpu["rho"], rtol=0, atol=1e-9)


def test_exclusion_columns_round_trip_and_read_the_older_four():
    """/exclusions columns -> rows -> columns is the identity; columns written before position,
    velocity and density were recorded (step, time, id, cause) read back with NaN there."""
    from sphgraph.features import exclusion_columns, exclusion_rows
    rows = [(3, 0.01, 7, 2, (0.5, -0.1), (0.2, -1.0), 1001.0), (5, 0.02, 9, 3, (0.1, 0.3), (0.0, 0.1), 1200.0)]
    cols = exclusion_columns(rows, 2)
    assert cols["position"].shape == (2, 2) and cols["density"].dtype == float
    assert exclusion_rows(cols, 2) == rows
    assert exclusion_rows(cols, 2, [False, True]) == rows[1:]
    old = {k: cols[k] for k in ("step", "time", "id", "cause")}
    back = exclusion_rows(old, 2)
    assert [r[:4] for r in back] == [r[:4] for r in rows]
    assert all(np.isnan(r[4]).all() and np.isnan(r[5]).all() and np.isnan(r[6]) for r in back)
    mixed = exclusion_columns(back + rows, 2)      # a restart adds new rows to the older ones
    assert mixed["position"].shape == (4, 2) and np.isnan(mixed["position"][:2]).all()
    from sphgraph.features import exclusion_summary
    line = exclusion_summary(cols, 100)
    assert line.endswith("steps 3-5; at x 0.1..0.5, y -0.1..0.3 m)"), line
    assert "; at" not in exclusion_summary(old, 100)     # no positions recorded: no box
    empty = exclusion_columns([], 3)                 # a checkpoint before any exclusion
    assert empty["position"].shape == (0, 3) and exclusion_rows(empty, 3) == []
