"""Validation cases, probes/forces and the speed-vs-accuracy study: small, fast versions with
real tolerances (the default resolutions run with `sphgraph validate CASE`; sweeps in
benchmarks/study_dambreak2d.py and benchmarks/convergence.py)."""
import csv
import math

import numpy as np
import pytest

from sphgraph import Scene
from sphgraph.cli import main
from sphgraph.errors import InputError
from sphgraph.probes import ProbeSampler, parse
from sphgraph.validation import load
from sphgraph.validation.cases import list_cases, load_case, poiseuille_u, run_case


def test_every_case_loads_with_sourced_reference_and_tolerances():
    assert set(list_cases()) >= {"dambreak", "hydrostatic", "buchner", "poiseuille"}
    for name in list_cases():
        c = load_case(name)
        assert c.tolerances, name
        assert all(lo <= hi for lo, hi in c.tolerances.values()), name
        ds = c.reference.get("datasets", {}) or ({"_": c.reference["dataset"]} if "dataset" in c.reference else {})
        for f in ds.values():
            data, header = load(f)
            assert len(data) >= 5 and ("doi" in header.lower() or "thesis" in header.lower()), f
        if not ds:   # analytic cases cite their solution in the case file
            assert "doi:" in c.text or "analytic" in c.text.lower(), name


def test_dambreak_front_against_each_experiment_coarse():
    """dp = a/20: the front leads every experiment (no gate, no friction in the model) by
    5-20 % on average, and the datasets' own spread is reported (~8 %)."""
    r = run_case("dambreak", dp=0.05, plot=False)
    for key in ("ko", "mm1", "mm2"):
        assert 0.0 < r.metrics[f"front_mean_rel_err_{key}"] < 0.2, r.report()
        assert r.metrics[f"front_max_abs_rel_err_{key}"] < 0.25, r.report()
    assert 0.05 < r.metrics["datasets_spread_max_rel"] < 0.12
    assert r.ok, r.report()


def test_hydrostatic_profile_and_tank_force_coarse():
    r = run_case("hydrostatic", dp=0.05, plot=False, params={"end_time": 0.5, "t_avg0": 0.3})
    assert r.metrics["pressure_rms_err_rel_rhogH"] < 0.03, r.report()
    assert abs(r.metrics["tank_force_rel_weight_minus_1"]) < 0.05, r.report()
    assert r.ok, r.report()


def test_buchner_wall_impact_time_coarse():
    """H/15: the wall pressure stays at the data's pre-impact level, rises within the case's
    window around the data's impact (T = t sqrt(g/H) = 2.51) and follows the smoothed data after it."""
    r = run_case("buchner", dp=0.04, plot=False)
    assert r.metrics["pre_impact_rms_err"] < 0.12, r.report()
    assert -0.35 < r.metrics["impact_T_err"] < 0.3, r.report()
    assert r.metrics["post_impact_rms_err"] < 0.4, r.report()
    assert abs(r.metrics["impact_T_data"] - 2.512) < 1e-9


def test_poiseuille_convergence_with_periodic_halo():
    r = run_case("poiseuille", plot=False)
    assert r.metrics["u_l2_err_rel_umax"] < 0.12, r.report()
    assert r.metrics["u_l2_err_at_H/dp=20"] < r.metrics["u_l2_err_at_H/dp=10"]
    assert 0.7 < r.metrics["convergence_order"] < 2.5, r.report()
    assert r.ok


def test_poiseuille_series_solution_limits():
    H, nu, F = 1e-3, 1e-6, 8e-4
    y = np.linspace(0, H, 11)
    assert np.allclose(poiseuille_u(y, 0.0, F, nu, H), 0.0, atol=2e-3 * F * H * H / (8 * nu))
    assert np.allclose(poiseuille_u(y, 50.0, F, nu, H), F / (2 * nu) * y * (H - y), rtol=1e-9, atol=1e-15)


# --------------------------------------------------------------------------- probes
def _tank(extra=None):
    d = {"format": 1, "name": "tank", "dim": 2, "dp": 0.02, "end_time": 0.1,
         "domain": {"min": [-0.2, -0.2], "max": [1.2, 1.0], "origin": [0.0, 0.0]},
         "initial": {"hydrostatic": True},
         "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [1.0, 0.5]}],
         "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8], "layers": 3}]}
    d.update(extra or {})
    return Scene.from_dict(d)


def test_probes_on_still_water_state():
    """At the hydrostatic start: point pressure = rho0 g depth, surface height = the surface,
    force on the tank = the water's weight (each within a few %)."""
    sc = _tank({"probes": {"points": [{"name": "P", "position": [0.5, 0.2]}],
                           "heights": [{"name": "H", "position": [0.5]}]},
                "forces": {"bodies": [{"name": "tank", "min": [-1, -1], "max": [2, 2]}]}})
    from sphgraph.solver import Simulation
    sim = Simulation(sc)
    smp = ProbeSampler(sc)
    smp.sample(sim)
    zs = sc.surface_level()
    p = smp.rows["probes"][0]["P"]["pressure"]
    assert abs(p / (1000 * 9.81 * (zs - 0.2)) - 1) < 0.02, p
    assert abs(smp.rows["probes"][0]["H"] - zs) < sc.dp, (smp.rows["probes"][0]["H"], zs)
    F = smp.rows["forces"][0]["tank"]
    weight = sim.n_fluid * sc.constants.mass_fluid * 9.81
    assert abs(-F[1] / weight - 1) < 0.05 and abs(F[0]) < 1e-6 * weight, (F, weight)
    tree = smp.datasets()
    assert set(tree) == {"probes", "forces"} and tree["probes"][0]["P"]["velocity"].shape == (1, 2)


def test_probe_tables_are_validated():
    with pytest.raises(InputError, match=r"probes.points\[0\].position"):
        parse(_tank({"probes": {"points": [{"name": "P", "position": [0.5]}]}}))
    with pytest.raises(InputError, match="probes: expected keys"):
        parse(_tank({"probes": {"pionts": []}}))
    with pytest.raises(InputError, match=r"forces.bodies\[0\].max"):
        parse(_tank({"forces": {"bodies": [{"name": "b", "min": [0, 0], "max": [-1, 1]}]}}))
    assert parse(_tank())["points"] == []


# --------------------------------------------------------------------------- CLI and study
def test_cli_validate_shows_each_simulations_progress_unless_quiet(tmp_path, capsys, monkeypatch):
    """Lines (no terminal) towards the end each runner steps its simulation to: the poiseuille
    case runs two simulations (H/10, H/20), and each gets its own progress from t = 0."""
    import sphgraph.progress as P

    class Every(P.Progress):            # a line at every update, not every 5 s
        def __init__(self, end_time, **kw):
            super().__init__(end_time, **dict(kw, every_s=0.0))
    monkeypatch.setattr(P, "Progress", Every)
    assert main(["validate", "poiseuille", "--out", str(tmp_path)]) == 0
    lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("t = ")]
    steps = [int(x.split("step ")[1].split()[0]) for x in lines]
    restarts = [i for i in range(1, len(steps)) if steps[i] < steps[i - 1]]
    assert len(lines) > 10 and len(restarts) == 1, lines[:3]     # two simulations, each from its start
    for last in (lines[restarts[0] - 1], lines[-1]):    # each ends at the end it was shown towards
        t, end = (float(v) for v in last.split()[2].split("/"))
        assert 0 < end <= t < 1.01 * end, last     # the last step may pass the end by one dt
    assert main(["validate", "poiseuille", "--out", str(tmp_path), "--quiet"]) == 0
    assert "t = " not in capsys.readouterr().err


def test_cli_validate_exit_codes_and_plot(tmp_path, capsys):
    assert main(["validate", "--list"]) == 0
    assert "poiseuille" in capsys.readouterr().out
    assert main(["validate", "poiseuille", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "convergence_order" in out and "PASS" in out
    assert (tmp_path / "poiseuille.png").stat().st_size > 1000
    strict = tmp_path / "strict.toml"
    strict.write_text(load_case("poiseuille").text.replace("u_l2_err_rel_umax = [0.0, 0.12]",
                                                           "u_l2_err_rel_umax = [0.0, 1e-6]"))
    assert main(["validate", str(strict), "--out", str(tmp_path)]) == 1
    assert "OUTSIDE" in capsys.readouterr().out
    assert main(["validate", "nosuchcase"]) == 2


def test_study_csv_png_pareto_and_target(tmp_path, capsys):
    """Verlet fails the laminar flow (its leapfrog velocity is unstable for diffusion): the
    study records it as the expensive-and-wrong point; the target picks Symplectic."""
    rc = main(["study", "poiseuille", "--dp", "5e-5", "--integrator", "verlet,symplectic",
               "--out", str(tmp_path), "--target-error", "0.12"])
    out = capsys.readouterr().out
    assert rc == 0, out
    rows = list(csv.DictReader(open(tmp_path / "study.csv")))
    assert {r["integrator"] for r in rows} == {"verlet", "symplectic"}
    err = {r["integrator"]: float(r["error"]) for r in rows}
    assert err["symplectic"] < 0.12 < err["verlet"] or not math.isfinite(err["verlet"])
    assert any(r["pareto"] == "1" for r in rows)
    assert "cheapest: dp=5e-05 symplectic" in out
    assert "[1/2] dp=5e-05" in out and "[2/2] dp=5e-05" in out      # each run's line, numbered
    assert (tmp_path / "study.png").stat().st_size > 1000
    assert main(["study", "poiseuille", "--from-csv", str(tmp_path / "study.csv"), "--out", str(tmp_path),
                 "--target-error", "1e-9"]) == 1


def test_study_sweeps_the_new_formulations_beside_dualsphysics(tmp_path, capsys):
    """`--riemann` / `--boundary` are axes like the others: each value a run at the baseline
    of the rest, a column of the CSV, and `--target-error` picks among them."""
    args = ["study", "poiseuille", "--dp", "5e-5", "--riemann", "none,zhang2017", "--boundary", "mdbc-noslip"]
    rc = main(args + ["--base", "integrator=symplectic", "--out", str(tmp_path), "--target-error", "1.0"])
    out = capsys.readouterr().out
    assert rc == 0, out
    rows = list(csv.DictReader(open(tmp_path / "study.csv")))
    got = {(r["integrator"], r["riemann"], r["boundary"]): r for r in rows}
    assert set(got) == {("symplectic", "none", "dbc"), ("symplectic", "zhang2017", "dbc"),
                        ("symplectic", "none", "mdbc-noslip")}
    assert all(r["status"] == "ok" for r in rows)
    assert len({float(r["error"]) for r in rows}) == 3          # each formulation gave its own error
    assert "cheapest: dp=5e-05" in out
    # around the case's Verlet baseline the Riemann term is refused by the scene: a row, not a crash
    rc = main(args + ["--out", str(tmp_path / "v")])
    rows = list(csv.DictReader(open(tmp_path / "v" / "study.csv")))
    bad = [r for r in rows if r["riemann"] == "zhang2017"]
    assert rc == 0 and len(bad) == 1 and bad[0]["status"].startswith("refused: ") and "symplectic" in bad[0]["status"]
    capsys.readouterr()
    assert main(args + ["--base", "integrater=symplectic", "--out", str(tmp_path / "x")]) == 2
    assert "--base: 'integrater' is not a [physics] field" in capsys.readouterr().err


def test_study_sweeps_the_riemann_jump_with_a_numeric_base(tmp_path, capsys):
    """`--riemann-jump` is an axis; `--base` numbers (riemann_eta=0.3) reach the scene as numbers."""
    rc = main(["study", "poiseuille", "--dp", "5e-5", "--riemann-jump", "plain,renormalised", "--base",
               "integrator=symplectic,riemann=zhang2017,boundary=mdbc,riemann_eta=0.3", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0, out
    rows = list(csv.DictReader(open(tmp_path / "study.csv")))
    assert sorted(r["riemann_jump"] for r in rows) == ["plain", "renormalised"]
    assert all(r["status"] == "ok" and float(r["riemann_eta"]) == 0.3 for r in rows), rows


def test_run_writes_probes_and_forces_groups(tmp_path):
    """A scene with [probes] and [forces]: `sphgraph.run` samples them at their interval and
    writes /probes and /forces; a bad table is refused when the scene is read, before anything
    is written."""
    import sphgraph
    from sphgraph.io import read_group
    sc = _tank({"end_time": 0.02, "dp": 0.05,
                "probes": {"interval": 0.005, "points": [{"name": "P", "position": [0.5, 0.2]}],
                           "heights": [{"name": "H", "position": [0.5]}]},
                "forces": {"interval": 0.0, "bodies": [{"name": "tank", "min": [-1, -1], "max": [2, 2]}]}})
    res = sphgraph.run(sc, out=tmp_path / "o", progress=False)
    g = read_group(res.out_dir, "probes")
    assert len(g["time"]) == 5 and np.allclose(np.diff(g["time"]), 0.005, atol=5e-4)  # first step past each mark
    assert g["P"]["velocity"].shape == (5, 2) and np.all(g["P"]["pressure"] > 0.9 * 1000 * 9.81 * 0.3)
    f = read_group(res.out_dir, "forces")
    assert len(f["time"]) == res.steps + 1 and f["tank"]["force"].shape == (res.steps + 1, 2)
    with pytest.raises(InputError, match=r"probes\.points\[0\]\.position"):   # refused when the scene is read
        sphgraph.run(_tank({"probes": {"points": [{"name": "P"}]}}), out=tmp_path / "bad", progress=False)
    assert not (tmp_path / "bad").exists()


# --------------------------------------------------------------------------- mDBC
def test_mdbc_ghost_nodes_mirror_across_the_interface():
    from sphgraph.physics.mdbc import ghost_positions, interface_boxes
    sc = _tank()
    dp = sc.dp
    boxes = interface_boxes(sc)
    pts = np.array([[0.5, 0.0], [0.5, -2 * dp], [0.0, 0.3], [1.0 + dp, 0.3], [0.0, 0.0]])
    g = ghost_positions(pts, boxes)
    assert np.allclose(g, [[0.5, dp], [0.5, 3 * dp], [dp, 0.3], [1.0 - 2 * dp, 0.3], [dp, dp]])


def test_mdbc_noslip_mirrors_the_tangential_velocity_only():
    """A floor row under a ghost whose fluid moves along the wall and away from it: no-slip
    gives the row minus the tangential velocity and none of the normal one (a mirrored normal
    velocity doubles the separation in the continuity sum and pulls fluid into the wall)."""
    from sphgraph.config import P_RHO0
    from sphgraph.physics.mdbc import ghost_value
    prm = np.zeros(64)
    prm[P_RHO0] = 1000.0
    for dim, bx, v in ((3, (0.0, 0.0, -0.01), (1.0, 2.0, 0.5)), (2, (0.0, -0.01, 0.0), (1.5, 0.7, 0.0)),
                       (3, (-0.006, 0.0, -0.008), (0.3, 0.4, 0.6))):
        A = np.eye(4)
        b = np.array([1000.0, 0.0, 0.0, 0.0])
        sw = 2.0
        vs = np.array(v) * sw
        r, *u = ghost_value(A, b, np.zeros((4, 4)), np.zeros(4), vs, sw, *bx, dim, prm, 1e-3, True)
        n = np.array(bx) / np.linalg.norm(bx)
        vt = np.array(v) - np.dot(v, n) * n
        assert r == 1000.0
        assert np.allclose(u[:dim], -vt[:dim], atol=1e-15), (u, vt)
        assert abs(np.dot(u, n)) < 1e-15
        r, *u = ghost_value(A, b, np.zeros((4, 4)), np.zeros(4), vs, sw, *bx, dim, prm, 1e-3, False)
        assert u == [0.0, 0.0, 0.0]


def test_noslip_wall_velocity_reaches_the_viscous_terms_only():
    """A fluid row above an mDBC no-slip wall row that carries the no-slip velocity: with
    P_WALL_NOSLIP the continuity term is the one of a still wall (v_b = 0), the laminar and
    artificial viscosity and the dt term see v_b (they differ from the still wall's); without
    it, as for DBC's moving walls, every term sees v_b. Same for riemann_pair; a fluid b
    is never touched."""
    from sphgraph.config import O_KERNEL, P_WALL_NOSLIP, PhysicsConfig, derive
    from sphgraph.physics.interact import fluid_pair, riemann_pair
    c = derive(PhysicsConfig(boundary="mdbc-noslip", laminar_nu=1e-3, visc_alpha=0.1), dim=3, dp=0.01, hswl=0.3)
    prm, kid = c.prm, int(c.opt[O_KERNEL])
    assert prm[P_WALL_NOSLIP] == 1.0
    assert derive(PhysicsConfig(boundary="mdbc"), dim=3, dp=0.01, hswl=0.3).prm[P_WALL_NOSLIP] == 0.0
    r = np.array([0.004, -0.003, 0.009])
    va, vb = np.array([0.8, 0.1, -0.3]), np.array([-0.7, 0.2, 0.0])
    z = np.zeros(3)

    def fp(v_b, bound=True, p=prm):
        dv = va - v_b
        return np.array(fluid_pair(*r, float(r @ r), *dv, *v_b, 1001.0, 1 / 1001.0, 1000.5, 300.0, 250.0,
                                   c.mass_bound, bound, bound, p, kid, 0, True), float)

    def rp(v_b, bound=True, p=prm):
        dv = va - v_b
        return np.array(riemann_pair(*r, float(r @ r), *dv, *v_b, 1001.0, 1 / 1001.0, 1000.5, 300.0, 250.0,
                                     c.mass_bound, bound, bound, p, kid, True), float)
    moving, still = fp(vb), fp(z)
    assert moving[3] == pytest.approx(still[3], rel=1e-14)          # continuity: the still wall's
    assert abs(moving[0] - still[0]) > 1e-3 * abs(still[0])         # viscosity: the no-slip velocity's
    assert moving[6] != still[6]                                    # the dt term too
    off = prm.copy()
    off[P_WALL_NOSLIP] = 0.0
    assert fp(vb, p=off)[3] != pytest.approx(still[3], rel=1e-6)   # DBC: the wall's velocity counts
    assert np.array_equal(fp(vb, bound=False), fp(vb, bound=False, p=off))
    rm, rs = rp(vb), rp(z)
    assert rm[3] == pytest.approx(rs[3], rel=1e-14)
    assert abs(rm[0] - rs[0]) > 1e-6 * abs(rs[0])


def test_mdbc_noslip_removes_the_dbc_wall_offset_in_poiseuille_flow():
    """Same flow, same resolutions: DBC's no-slip sits dp/2 outside the wall (error 0.099 at
    H/20); mDBC with mirrored ghost velocities puts it on the wall (error ~0.011)."""
    dbc = run_case("poiseuille", plot=False)
    m = run_case("poiseuille", plot=False, params={"boundary": "mdbc-noslip"})
    assert m.metrics["u_l2_err_rel_umax"] < 0.03, m.report()
    assert m.metrics["u_l2_err_rel_umax"] < dbc.metrics["u_l2_err_rel_umax"] / 4
    assert m.metrics["u_l2_err_at_H/dp=10"] < 0.03


def test_yeh_petroff_column_force_arrives_coarse():
    """3D, dp = 0.06 (a few seconds): the force on the column (the [forces] sampler) stays ~0
    until the surge arrives, then rises within 0.15 s of the measured arrival."""
    r = run_case("yeh_petroff", dp=0.06, plot=False, params={"t_end": 0.6})
    assert -0.15 < r.metrics["arrival_time_err_s"] < 0.05, r.report()
    assert r.metrics["peak_force_N"] > 10.0


MDBC_SCENE = """format = 1
name = "mdbc_dam"
dim = 2
dp = 0.05
end_time = 1.0
output_interval = 1.0
[domain]
min = [-0.25, -0.25]
max = [1.25, 1.0]
[physics]
boundary = "{boundary}"
[[fluid]]
type = "box"
min = [0.0, 0.0]
max = [0.4, 0.5]
[[boundary]]
type = "tank"
min = [0.0, 0.0]
max = [1.0, 0.8]
layers = 3
"""


def test_scene_boundary_mdbc_noslip_runs_like_the_validation_path(tmp_path, capsys):
    """`[physics] boundary = "mdbc-noslip"` through `sphgraph run` (the builder's `mdbc` task):
    the same particles, bit for bit, as a user task with the same body placed by a schedule
    on the DBC scene, and as the runner's `boundary` param; unsupported runs are refused at
    start (exit 2, one line, nothing written)."""
    from sphgraph.config import P_WALL_NOSLIP
    from sphgraph.features import Mdbc
    from sphgraph.graph.task import UserTask
    from sphgraph.io import read_frame
    from sphgraph.solver import Simulation
    from sphgraph.validation.cases import _sim
    steps = 12
    path = tmp_path / "mdbc.toml"
    path.write_text(MDBC_SCENE.format(boundary="mdbc-noslip"))
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--max-steps", str(steps), "--quiet"]) == 0
    got = read_frame(tmp_path / "o")
    assert got["step"] == steps
    dbc = Scene.from_dict(Scene.from_toml(path).to_dict() | {"physics": {"boundary": "dbc"}})
    m = Mdbc(dbc, noslip=True)
    user = UserTask("user_mdbc", lambda ctx, task: m.apply(ctx), reads=("particles", "cells"),
                    writes=("particles", "cells"), per_stage=True)
    order = ["build_cells", "user_mdbc", "forces_interior", "dt_local", "dt_allreduce", "integrate"]
    old = Simulation(dbc, schedule={"format": 1, "order": order}, user_tasks=[user], invariants=False)
    for ctx in old.contexts:   # the wall rows' no-slip velocity is for the viscous terms only (the scene's flag)
        ctx.state.prm[P_WALL_NOSLIP] = 1.0
    runner = _sim(dbc, "numba-cpu", None, boundary="mdbc-noslip")
    plain = Simulation(dbc, invariants=False)
    for s in (old, runner, plain):
        for _ in range(steps):
            s.step()
    for s in (old, runner):
        a = s.frame_arrays()
        for k in ("position", "velocity", "density"):
            assert np.array_equal(a[k], got[k]), k
    wall = got["kind"] != 0
    assert np.abs(got["velocity"][wall]).max() > 0          # mirrored fluid velocity on the walls
    assert not np.array_equal(plain.frame_arrays()["density"], got["density"])   # DBC differs
    capsys.readouterr()
    # several ranks need the halos before the forces (tests/test_mdbc_ranks.py): production is refused
    for flags in (["--comm", "mock", "--ranks", "2"],):
        assert main(["run", str(path), "--out", str(tmp_path / "bad"), "--quiet", *flags]) == 2, flags
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "physics.boundary" in err[0] and "bulk-synchronous" in err[0], err
        assert not (tmp_path / "bad").exists()
    with pytest.raises(InputError, match=r"physics.boundary: expected one of \"dbc\", \"mdbc\", \"mdbc-noslip\""):
        Scene.from_dict(dbc.to_dict() | {"physics": {"boundary": "mDBC"}})


def test_gate_holds_the_column_and_releases_it_underneath():
    """sphgraph.validation.gate.with_gate on the 2D dam break (dp = a/20): the gate's rows sit
    on the lattice clear of the walls and the fluid; closed (its lift starting at 0.2 s) it holds
    the column while a free column's toe runs 3 dp past its place; then it rises at c sqrt(g h0)
    and the water that leaves the column passes under its lower edge, none over or through it."""
    from sphgraph.particles import FLUID, MOVING
    from sphgraph.solver import Simulation
    from sphgraph.validation.cases import scene_for
    from sphgraph.validation.gate import G, opening_time, with_gate
    dp, c, t_lift, t_end = 0.05, 0.35, 0.2, 0.4
    base = load_case("dambreak")
    a = float(base.params["a"])
    h0 = 2 * a
    assert abs(opening_time(h0, c) - h0 / (c * math.sqrt(G * h0))) < 1e-12
    gated = with_gate(base, dp, face_x=a, h0=h0, c=c)
    assert gated.scene["motion"][-1]["start"] == 0.0
    gated.scene["motion"][-1]["start"] = t_lift
    scene = scene_for(gated, dp, {}, end_time=t_end)
    sim = Simulation(scene, invariants=False)
    p = sim.contexts[0].state.particles
    pos0 = np.asarray(p.pos).copy()
    d = np.linalg.norm(pos0[:, None, :] - pos0[None, :, :], axis=-1) + np.eye(len(pos0)) * 1e9
    assert d.min() > 0.99 * dp
    y0 = {int(i): float(y) for i, y in zip(np.asarray(p.id), pos0[:, 1])}

    def fluid_front(s):
        q = s.contexts[0].state.particles
        return q.pos[q.kind == FLUID, 0].max()

    free = Simulation(scene_for(base, dp, {}, end_time=t_lift), invariants=False)
    while free.time < t_lift - 1e-12:
        free.step()
    while sim.time < t_lift - 1e-12:
        sim.step()
    assert fluid_front(free) > a + 3 * dp           # a free column's toe has left
    assert fluid_front(sim) < a + dp                # the closed gate (at a + dp) holds the column
    while sim.time < t_end - 1e-12:
        sim.step()
    p = sim.contexts[0].state.particles
    pos, kind, ids = np.asarray(p.pos), np.asarray(p.kind), np.asarray(p.id)
    moving = kind == MOVING
    lift = np.array([pos[k, 1] - y0[int(i)] for k, i in zip(np.nonzero(moving)[0], ids[moving])])
    assert moving.sum() == 2 * len(set(np.round(pos[moving, 1], 6)))
    assert np.allclose(lift, c * math.sqrt(G * h0) * (sim.time - t_lift), atol=1e-9)
    bottom = pos[moving, 1].min()
    out = (kind == FLUID) & (pos[:, 0] > a + 3 * dp)
    assert out.sum() > 0                            # the gate rose: water left the column
    assert pos[out, 1].max() < bottom               # under it, not over or through it


def test_case_at_the_experiments_size_scales_every_length():
    """sphgraph.validation.scale.at_size: with no viscosity a Froude-scaled run gives the same
    Z(T) at any size: the 1 m case at a/20 and Martin & Moyce's 1.125 in column at a/20 agree to
    round-off accumulated over the run (1.4e-6 measured; a length left unscaled moves it by percents)."""
    from sphgraph.validation.scale import at_size
    base = load_case("dambreak")
    small = at_size(base, 1.125 * 0.0254)
    assert small.params["a"] == 1.125 * 0.0254 and small.scene["fluid"][0]["max"][1] == 2 * 1.125 * 0.0254
    big = run_case(base, dp=0.05, plot=False).metrics
    m = run_case(small, dp=0.05 * small.params["a"], plot=False).metrics
    for k in ("ko", "mm1", "mm2"):
        assert abs(m[f"front_mean_rel_err_{k}"] - big[f"front_mean_rel_err_{k}"]) < 1e-5
    with pytest.raises(ValueError, match="buchner"):
        at_size(load_case("buchner"), 0.1)


def test_marin_gauges_fill_in_the_order_of_their_distance_from_the_water():
    """The SPHERIC 2 data's columns are placed by the case at x = 1.488, 0.992 and 0.496 m (and
    2.638 in the reservoir): the dry gauges must then wet in that order, the reservoir gauge
    must start at the initial depth, and every gauge's data column must be a distinct one."""
    c = load_case("spheric2")
    data, _ = load(c.reference["dataset"])
    gauges = c.params["gauges"]
    assert sorted(int(g[3]) for g in gauges) == [1, 2, 3, 4]
    face = 1.992                                     # the water column's face at t = 0
    dry = [g for g in gauges if float(g[1]) < face]
    wet = [g for g in gauges if float(g[1]) > face]
    arrival = {g[0]: data[np.nonzero(data[:, int(g[3])] > c.params["arrival_h"])[0][0], 0] for g in dry}
    by_distance = sorted(dry, key=lambda g: face - float(g[1]))
    assert [arrival[g[0]] for g in by_distance] == sorted(arrival.values()), arrival
    assert len(wet) == 1 and abs(data[0, int(wet[0][3])] - c.params["h0"]) < 0.01


def test_spheric2_heights_coarse():
    """3D, dp = 0.1 to t = 0.4 s (seconds): the gauge behind the box stays dry as the data
    do, the reservoir gauge reads the initial depth within one dp, and the gauge
    nearest the column sees the front (late at this dp: the kernel sum of a thin front stays
    below the height's threshold; 0.16 s at dp 0.1)."""
    r = run_case("spheric2", dp=0.1, plot=False, params={"t_end": 0.4})
    assert r.metrics["height_rms_err_m_H1"] < 0.002, r.report()
    t, h, *_ = r.series["sphgraph H4"]
    assert abs(h[0] - 0.55) < 0.1 and t[0] == 0.0
    assert 0.0 < r.metrics["arrival_err_s_H3"] < 0.25, r.report()
    # the box's eight pressure sensors, sampled every 2 ms by their own sampler: the top's stay
    # dry as the data's do before 1 s, the front face's read the impact the data see at 0.39 s
    t, p, *_ = r.series["sphgraph P1"]
    assert np.allclose(np.diff(t), 0.002, atol=1e-3) and t[-1] > 0.39
    assert all(r.metrics[f"p_rms_err_kPa_P{k}"] < 0.05 for k in (5, 6, 7, 8)), r.report()
    assert "impact_t_data_s_P1" in r.metrics and np.isfinite(r.metrics["p_rms_err_rel_rhogh0_all"])


def test_a_heights_run_that_stops_reports_what_it_measured(tmp_path, capsys, monkeypatch):
    """A water-heights run that stops numerically (a failure injected once t > 0.05 s) keeps
    its gauges' series and metrics up to the stop (CaseStopped.result: not ok, the failure
    named); `sphgraph validate` prints that report, draws it and exits 1 with the failure."""
    from sphgraph.errors import NumericalError
    from sphgraph.solver import Simulation
    from sphgraph.validation.cases import CaseStopped
    orig = Simulation.step

    def failing(self, *a, **k):
        if self.time > 0.05:
            raise NumericalError(f"step {self.step_count}: injected failure", step=self.step_count)
        return orig(self, *a, **k)
    monkeypatch.setattr(Simulation, "step", failing)
    case = tmp_path / "s2.toml"
    case.write_text(load_case("spheric2").text.replace("t_end = 6.0 ", "t_end = 0.3 "))
    with pytest.raises(CaseStopped, match="injected failure") as ei:
        run_case(str(case), dp=0.1, plot=False)
    r = ei.value.result
    t, h, *_ = r.series["sphgraph H4"]
    assert 0.04 <= t[-1] <= 0.06 and len(t) >= 5, t
    assert not r.ok and "injected failure" in r.stopped and "STOPPED: step" in r.report()
    assert r.metrics["height_rms_err_m_H1"] < 0.002 and abs(h[0] - 0.55) < 0.1
    assert main(["validate", str(case), "--dp", "0.1", "--out", str(tmp_path / "o")]) == 1
    out = capsys.readouterr()
    assert "STOPPED: step" in out.out and "numerical failure: step" in out.err
    assert (tmp_path / "o" / "spheric2.png").stat().st_size > 1000


def test_walls_drawn_on_the_domain_face_stay_in_the_run():
    """examples/spheric2.toml at dp 0.04 draws its outer tank layer on domain.max (3.22 + 3 dp =
    3.32): the end-of-step check must not exclude it for the rounding of its position."""
    from sphgraph.solver import Simulation
    sc = Scene.from_toml("examples/spheric2.toml").with_overrides(dp=0.04, end_time=0.001)
    sim = Simulation(sc, backend="numba-cpu")
    hi = np.asarray(sc.domain_max)
    assert (sim.contexts[0].state.particles.pos > hi).any()     # rounded beyond the face
    sim.step()
    assert sim.features.excluded == [] and sim.n_total == 41224
