"""Task graph: derived dependencies, graph shapes, validator, schedules, user tasks."""
import networkx as nx
import numpy as np
import pytest

import sphgraph
from sphgraph import Schedule, Scene, UserTask
from sphgraph.graph.build import multi_rank_graph, rank_graph
from sphgraph.graph.kinds import TaskKind
from sphgraph.schedule import ScheduleError, shipped
from sphgraph.solver import Simulation

from conftest import example

PROD = Schedule.load("production")


def reduced_edges(rank, nranks, stages=1):
    g = rank_graph(PROD.canonical(rank, nranks, stages))
    return set(nx.transitive_reduction(g).edges())


def test_one_rank_graph_is_the_serial_step():
    assert reduced_edges(0, 1) == {
        ("build_cells", "forces_interior@1"), ("forces_interior@1", "dt_local"),
        ("dt_local", "dt_allreduce"), ("dt_allreduce", "integrate@1")}


def test_middle_rank_graph_has_both_halos_and_commuting_force_tasks():
    forces = ["forces_interior@1", "forces_halo_1@1", "forces_halo_2@1"]
    pre = ("build_cells", "recv_displaced")       # both accumulate into particles and cells
    want = {("send_displaced", t) for t in pre} | {(t, "send_edges@1") for t in pre}
    want |= {("recv_halo_1@1", "forces_halo_1@1"),
             ("recv_halo_2@1", "forces_halo_2@1"), ("dt_local", "dt_allreduce"),
             ("dt_allreduce", "integrate@1"), ("send_edges@1", "integrate@1")}
    want |= {(t, f) for t in pre for f in forces} | {(f, "dt_local") for f in forces}
    assert reduced_edges(1, 3) == want
    g = rank_graph(PROD.canonical(1, 3, 1))
    for a in forces:  # accumulations commute: no order among the force tasks
        for b in forces:
            assert a == b or not nx.has_path(g, a, b)
    # nor between build_cells and recv_displaced (merged or appended: the same rows)
    assert not nx.has_path(g, *pre) and not nx.has_path(g, *pre[::-1])


def _with_pre(pre):
    o = [x for x in base_order() if x not in ("send_displaced", "recv_displaced", "build_cells")]
    return list(pre) + o


@pytest.mark.parametrize("ranks", [1, 2, 3, 4])
@pytest.mark.parametrize("stages", [1, 2])
def test_validator_accepts_build_cells_and_recv_displaced_in_either_order(ranks, stages):
    for pre in (("send_displaced", "recv_displaced", "build_cells"),
                ("send_displaced", "build_cells", "recv_displaced")):
        Schedule.from_dict({"format": 1, "order": _with_pre(pre)}).validate(ranks, stages)
        Schedule.from_dict({"format": 1, "order": _with_pre(pre), "halo_order": [2, 1]}).validate(ranks, stages)
    assert PROD.order.index("build_cells") < PROD.order.index("recv_displaced")   # the paper's overlap
    bulk = Schedule.load("bulk-synchronous").order
    assert bulk.index("recv_displaced") < bulk.index("build_cells")              # no overlap


def test_validator_still_rejects_what_breaks_the_migration_dependencies():
    # receiving or building before the rows that left are taken out
    rejects({"order": _with_pre(("recv_displaced", "send_displaced", "build_cells"))},
            match="recv_displaced is placed before send_displaced")
    msg = rejects({"order": _with_pre(("build_cells", "send_displaced", "recv_displaced"))},
                  match="build_cells is placed before send_displaced")
    assert "particles: accumulate after write" in msg
    # a reader of the rows or cells between build_cells and recv_displaced
    o = _with_pre(("send_displaced", "build_cells", "recv_displaced"))
    o.remove("send_edges")
    o.insert(o.index("recv_displaced"), "send_edges")
    msg = rejects({"order": o}, match="send_edges@1 is placed before recv_displaced")
    assert "read after accumulate" in msg
    o = _with_pre(("send_displaced", "build_cells", "recv_displaced"))
    o.remove("forces_interior")
    o.insert(o.index("build_cells"), "forces_interior")
    rejects({"order": o}, match="forces_interior@1 is placed before build_cells")
    # integrate (a writer of the rows) before either
    o = _with_pre(("send_displaced", "build_cells"))
    o.insert(o.index("integrate") + 1, "recv_displaced")
    rejects({"order": o}, match="integrate@1 is placed before recv_displaced")


@pytest.mark.parametrize("rank,nranks,halos", [(0, 1, []), (0, 2, [2]), (1, 2, [1]), (0, 3, [2]), (1, 3, [1, 2]), (2, 3, [1])])
def test_graph_shape_follows_the_rank_role(rank, nranks, halos):
    names = {t.name for t in PROD.program(rank, nranks, 1)}
    for side in (1, 2):
        assert (f"recv_halo_{side}@1" in names) == (side in halos)
        assert (f"forces_halo_{side}@1" in names) == (side in halos)
    assert ("send_edges@1" in names) == (nranks > 1)


def test_symplectic_has_two_stages_and_one_dt():
    names = [t.name for t in PROD.program(1, 3, 2)]
    for s in (1, 2):
        for k in ("send_edges", "forces_interior", "recv_halo_1", "forces_halo_2", "integrate"):
            assert names.count(f"{k}@{s}") == 1
    assert names.count("dt_local") == 1 and names.index("dt_local") < names.index("integrate@1")
    g = rank_graph(PROD.canonical(1, 3, 2))
    assert nx.has_path(g, "integrate@1", "forces_interior@2")
    assert nx.has_path(g, "forces_halo_1@1", "recv_halo_1@2")  # halo buffer reused: write after read


def test_multi_rank_graph_has_messages_and_one_collective():
    progs = {r: PROD.program(r, 3, 1) for r in range(3)}
    g = multi_rank_graph(progs)
    assert g.has_edge((0, "send_edges@1"), (1, "recv_halo_1@1"))
    assert g.has_edge((1, "send_edges@1"), (0, "recv_halo_2@1"))
    assert g.has_edge((2, "send_displaced"), (1, "recv_displaced"))
    assert ("all", "dt_allreduce") in g and sum(1 for n in g if n[1] == "dt_allreduce") == 1
    assert nx.is_directed_acyclic_graph(g)


@pytest.mark.parametrize("name", shipped())
@pytest.mark.parametrize("ranks", [1, 2, 3, 4])
@pytest.mark.parametrize("stages", [1, 2])
def test_shipped_schedules_validate(name, ranks, stages):
    s = Schedule.load(name)
    s.validate(ranks, stages)
    Schedule.from_dict({"format": 1, "order": s.order, "halo_order": [2, 1]}).validate(ranks, stages)


def base_order():
    return list(PROD.order)


def rejects(d, ranks=3, match=""):
    with pytest.raises(ScheduleError) as e:
        Schedule.from_dict({"format": 1, **d}).validate(ranks, 1)
    msg = str(e.value)
    assert match in msg, msg
    return msg


def test_validator_rejects_a_dependency_cycle_order():
    o = base_order()
    o.remove("forces_halo_1")
    o.insert(o.index("recv_halo_1"), "forces_halo_1")  # halo forces before their receive
    msg = rejects({"order": o}, match="forces_halo_1@1 is placed before recv_halo_1@1")
    assert "halo_1: read after write" in msg


def test_validator_rejects_missing_duplicated_unknown_lane():
    o = base_order()
    o.remove("dt_allreduce")
    rejects({"order": o}, match="missing task 'dt_allreduce'")
    rejects({"order": base_order() + ["integrate"]}, match="duplicated task 'integrate'")
    rejects({"order": base_order(), "lanes": {"send_edges": "gpu"}}, match="unknown lane 'gpu'")
    rejects({"order": base_order() + ["probe"]}, match="unknown task 'probe'")
    # several problems of one file come out together, one line each
    msg = rejects({"order": base_order() + ["integrate", "probe"], "lanes": {"send_edges": "gpu"}},
                  match="unknown lane 'gpu'")
    lines = msg.splitlines()
    assert len(lines) == 3 and "duplicated task 'integrate'" in msg and "unknown task 'probe'" in msg


def test_validator_rejects_receive_before_send_deadlock():
    o = base_order()
    o.remove("send_edges")
    o.insert(o.index("forces_halo_2") + 1, "send_edges")  # every rank waits for a halo first
    msg = rejects({"order": o}, ranks=2, match="deadlock on 2 ranks")
    assert "rank 0 recv_halo_2@1 waits for rank 1 send_edges@1" in msg or \
        "rank 1 recv_halo_1@1 waits for rank 0 send_edges@1" in msg
    Schedule.from_dict({"format": 1, "order": o}).validate(1, 1)  # fine on one rank


def test_schedule_cli_validate_exit_codes(tmp_path, capsys):
    from sphgraph.cli import main
    assert main(["schedule", "validate", "production", "--ranks", "3"]) == 0
    bad = tmp_path / "bad.toml"
    o = base_order()
    o.remove("send_edges")
    o.insert(o.index("forces_halo_2") + 1, "send_edges")
    bad.write_text("format = 1\norder = [" + ", ".join(f'"{x}"' for x in o) + "]\n")
    assert main(["schedule", "validate", str(bad), "--ranks", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith("sphgraph: error: ") for line in err)
    assert any("deadlock" in line for line in err)


def small_dambreak():
    return Scene.from_toml(example("dambreak2d.toml")).with_overrides(dp=0.05)


@pytest.mark.parametrize("integrator", ["verlet", "symplectic"])
def test_every_shipped_schedule_gives_identical_particles(integrator):
    res = {}
    for name in shipped():
        for halo in ([1, 2], [2, 1]):
            sched = Schedule.from_dict({"format": 1, "order": Schedule.load(name).order, "halo_order": halo})
            sim = Simulation(small_dambreak().with_overrides(integrator=integrator), schedule=sched)
            for _ in range(30):
                sim.step()
            res[(name, tuple(halo))] = sim.frame_arrays()
    ref = next(iter(res.values()))
    for key, a in res.items():
        for f in ("position", "velocity", "density"):
            np.testing.assert_array_equal(a[f], ref[f], err_msg=str(key))


def test_custom_schedule_and_user_tasks_run(tmp_path):
    """A probe (reads particles, writes its own datum) and an extra force term
    (accumulates into forces@s) declared by the user, placed by a custom schedule."""
    seen = []

    def probe(ctx, task):
        p = ctx.state.particles
        seen.append(float(p.pos[p.kind == 0, 1].mean()))

    def antigravity(ctx, task):
        buf = ctx.force_buffer("user_antigravity")
        fluid = ctx.state.particles.kind == 0
        buf.ace[fluid] = -ctx.state.consts.gravity

    tasks = [UserTask("probe", probe, reads=("particles",), writes=("probe",)),
             UserTask("antigravity", antigravity, reads=("particles",), accumulates=("forces@1",))]
    order = base_order()
    order.insert(order.index("dt_local"), "antigravity")
    order.append("probe")
    sched = {"format": 1, "order": order}
    blob = Scene.from_dict({
        "format": 1, "name": "blob", "dim": 2, "dp": 0.02, "end_time": 0.05,
        "domain": {"min": [-1.0, -1.0], "max": [2.0, 2.0], "origin": [0.0, 0.0]},
        "physics": {"hswl": 0.3}, "fluid": [{"type": "box", "min": [0, 0], "max": [0.3, 0.3]}]})
    res = sphgraph.run(blob, schedule=sched, user_tasks=tasks, out=tmp_path / "o", progress=False,
                       max_steps=200)
    assert len(seen) == res.steps
    assert abs(seen[-1] - seen[0]) < 1e-3  # no net fall: the user force cancels gravity
    free = sphgraph.run(blob, out=tmp_path / "f", progress=False, max_steps=200)
    a = sphgraph.io.read_frame(free.out_dir)
    assert a["position"][a["kind"] == 0, 1].mean() < seen[0] - 0.5 * 9.81 * free.time ** 2 * 0.9
    t = sphgraph.io.read_timing(res.out_dir)
    assert {"probe", "antigravity"} <= {str(x) for x in t["task"]}


def test_task_kind_table_is_the_one_source_of_names():
    labels = TaskKind.labels()
    assert len(labels) == len(set(labels))
    for s in shipped():
        assert set(Schedule.load(s).order) <= set(labels)
    assert TaskKind.from_label("dt_allreduce").timer == "SynchroDt"


def test_lane_edges_are_the_cross_lane_dependencies():
    """lane_edges: the rank graph's edges between tasks on different lanes, plus the
    accumulate-order edge build_cells -- recv_displaced (issue order), every producer
    issued before its consumer; a backend without lanes gets the programs unwrapped."""
    from sphgraph.graph.build import lane_edges
    for name in shipped():
        S = Schedule.load(name)
        for rank, nranks, stages in ((0, 1, 1), (0, 2, 1), (1, 3, 2)):
            prog = S.program(rank, nranks, stages)
            lane = {t.name: t.lane for t in prog}
            pos = {t.name: i for i, t in enumerate(prog)}
            g = rank_graph(S.canonical(rank, nranks, stages))
            edges = lane_edges(prog, g)
            cross = {(u, v) for u, v in g.edges() if lane[u] != lane[v]}
            assert cross <= set(edges)
            extra = set(edges) - cross
            if nranks > 1:
                pre = sorted(("build_cells", "recv_displaced"), key=pos.get)
                assert extra == {tuple(pre)}, (name, extra)
            else:
                assert extra == set()
            assert all(pos[u] < pos[v] and lane[u] != lane[v] for u, v in edges)
    sim = Simulation(small_dambreak(), comm="mock", ranks=2)    # numba-cpu: no lanes
    assert not any(hasattr(t.fn, "lane_step") for p in sim.scheduler.programs.values() for t in p)


def test_lane_program_calls_the_backend_hooks_around_each_body():
    """lane_program wraps each body in lane_begin / lane_end with its LaneStep: the lane,
    the producers on other lanes it waits for, whether it records its event, the first
    task of each lane (waits for the previous step) and the last (records step-end events)."""
    from dataclasses import replace
    from types import SimpleNamespace

    from sphgraph.graph.build import lane_edges
    from sphgraph.scheduler import lane_program
    S = Schedule.load("production")
    prog = [replace(t, fn=None) for t in S.program(1, 3, 2)]
    g = rank_graph(S.canonical(1, 3, 2))
    wrapped = lane_program(prog, g)
    assert [t.name for t in wrapped] == [t.name for t in prog]
    calls = []
    compute = SimpleNamespace(lane_begin=lambda st, t, s: calls.append(("begin", t.name, s)),
                              lane_end=lambda st, t, s: calls.append(("end", t.name, s)))
    ctx = SimpleNamespace(compute=compute, state=None)
    for t in wrapped:
        t.fn(ctx, t)
    assert [(c[0], c[1]) for c in calls] == [(x, t.name) for t in prog for x in ("begin", "end")]
    steps = {c[1]: c[2] for c in calls}
    edges = lane_edges(prog, g)
    assert {(u, v) for v, s in steps.items() for u in s.waits} == set(edges)
    assert {v for v, s in steps.items() if s.record} == {u for u, _ in edges}
    assert all(steps[t.name].lane == t.lane for t in prog)
    assert [v for v, s in steps.items() if s.first] == ["send_displaced", "build_cells"]
    assert [v for v, s in steps.items() if s.last] == [prog[-1].name]
    # the overlap: the interior forces wait for no edge send and no halo receive
    for st in (1, 2):
        w = steps[f"forces_interior@{st}"].waits
        assert not any(x.startswith(("send_edges", "recv_halo")) for x in w), w
        assert f"recv_halo_1@{st}" in steps[f"forces_halo_1@{st}"].waits
