"""Every scene feature's work is its own task of the step graph (issue 23 §1, §7).

A scene with every feature on -- a periodic axis, particle shifting, a moving body, a
damping zone, exclusion, probes and body forces (sampled by a run that writes output: its
`probes` task) -- and one with mDBC (numba-cpu, one rank, no moving body): each feature's tasks are in the step graph with their dependencies, in
`/timing` of output.h5 once a rank and step (stage), in the Chrome trace and in `sphgraph
schedule show --scene`. The compute backend records which task is running whenever the
core calls it: after set-up every call that computes or changes the rows comes from inside
a task -- the one of its feature -- so no feature rides inside another task and nothing
advances the solver outside the scheduler.
"""
from __future__ import annotations

import json

import pytest

import sphgraph
from sphgraph import Scene, Simulation
from sphgraph.backends.compute.numba_cpu import NumbaCPU
from sphgraph.cli import main
from sphgraph.graph.build import rank_graph
from sphgraph.io import read_timing
from sphgraph.toml_writer import dumps_toml
from sphgraph.trace import write_chrome_trace

# calls that compute or change a rank's rows (host_arrays / sync_host only read them)
WORK = ("prepare", "build_cells", "forces", "prepare_halo", "reduce_forces", "dt_local", "integrate",
        "check", "take_displaced", "add_displaced", "edge", "shift_part", "shift_displacement",
        "shift_apply", "mdbc")


class Recording(NumbaCPU):
    """numba-cpu that notes (method, argument, running task) of every call of WORK; it asks
    for lanes only to be told by the scheduler which task runs (lane_begin / lane_end)."""

    uses_lanes = True

    def __init__(self):
        super().__init__()
        self.calls = []
        self.task = None

    def lane_begin(self, state, task, step):
        self.task = task.name

    def lane_end(self, state, task, step):
        self.task = None


def _recorded(name):
    def call(self, state, *args, **kw):
        arg = args[0] if name in ("forces", "shift_part") else None
        self.calls.append((name, arg, self.task))
        return getattr(NumbaCPU, name)(self, state, *args, **kw)
    return call


for _name in WORK:
    setattr(Recording, _name, _recorded(_name))


def everything(integrator="symplectic"):
    """A periodic channel (x) over a floor, a bar moving down into the water, a damping zone,
    shifting, exclusion (on by default), probes and the force on the floor."""
    return Scene.from_dict({
        "format": 1, "name": "everything", "dim": 2, "dp": 0.02, "end_time": 1.0,
        "domain": {"min": [0.0, -0.1], "max": [1.0, 0.8], "origin": [0.01, 0.0], "periodic": ["x"],
                   "exclude_max_share": 1.0},
        "physics": {"coefsound": 10.0, "integrator": integrator, "shifting": "full"},
        "initial": {"hydrostatic": True},
        "decomposition": {"axis": "x"},
        "fluid": [{"type": "box", "min": [0.0, 0.02], "max": [1.0, 0.3]}],
        "boundary": [{"type": "wall", "min": [0.01, 0.0], "max": [0.99, 0.0], "direction": "-"},
                     {"type": "wall", "name": "bar", "min": [0.4, 0.36], "max": [0.6, 0.36], "layers": 2}],
        "motion": [{"body": "bar", "type": "rectilinear", "times": [0.0, 1.0],
                    "velocity": [[0.0, -0.5], [0.0, -0.5]]}],
        "damping": [{"axis": "x", "start": 0.7, "end": 0.95}],
        "probes": {"points": [{"name": "P1", "position": [0.5, 0.1]}],
                   "heights": [{"name": "H1", "position": [0.3]}]},
        "forces": {"bodies": [{"name": "floor", "min": [0.0, -0.05], "max": [1.0, 0.01]}]}})


def mdbc_scene():
    return Scene.from_dict({
        "format": 1, "name": "mdbc", "dim": 2, "dp": 0.05, "end_time": 1.0,
        "domain": {"min": [-0.25, -0.25], "max": [1.25, 1.0]},
        "physics": {"boundary": "mdbc-noslip", "shifting": "nobound"},
        "fluid": [{"type": "box", "min": [0.0, 0.0], "max": [0.4, 0.5]}],
        "boundary": [{"type": "tank", "min": [0.0, 0.0], "max": [1.0, 0.8], "layers": 3}]})


# feature -> {task label: the compute calls (method, argument) made inside it}
PERIODIC = {"forces_images": {("forces", "halo_3"), ("prepare_halo", None)}, "wrap": set()}
SHIFTING = {"shift_interior": {("shift_part", "interior")}, "shift_images": {("shift_part", "halo_3")},
            "shift_displacement": {("shift_displacement", None)}, "shift_apply": {("shift_apply", None)}}
SHIFTING_HALOS = {"shift_halo_1": {("shift_part", "halo_1")}, "shift_halo_2": {("shift_part", "halo_2")}}
MOTION = {"motion": set(), "damping": set()}
EXCLUSION = {"check": {("check", None)}, "exclude": set()}
PROBES = {"probes": set()}
MDBC = {"mdbc": {("mdbc", None)}}


def _run(tmp_path, scene, ranks, steps=6):
    res = sphgraph.run(scene, backend=Recording, comm="single" if ranks == 1 else "mock", ranks=ranks,
                       out=tmp_path / f"o{ranks}", progress=False, max_steps=steps)
    return res, read_timing(res.out_dir)


def _check(timing, calls, expected, ranks, stages, steps):
    """Each expected task: in /timing for every rank and step (the last-stage ones once a
    step), its compute calls made inside it and nowhere else; every WORK call after set-up
    inside a task."""
    labels = [str(x).split("@")[0] for x in timing["task"]]
    for label, inside in expected.items():
        rows = [i for i, x in enumerate(labels) if x == label]
        per_step = stages if label in ("motion", "forces_images", "mdbc") else 1
        assert len(rows) == ranks * steps * per_step, (label, len(rows))
        for method, arg in inside:
            where = {t for m, a, t in calls if m == method and a == arg}
            assert where and all(t is not None and t.split("@")[0] == label for t in where), (label, where)
    outside = [(m, a) for m, a, t in calls if t is None]
    assert not outside, f"work outside the scheduler's tasks: {sorted(set(outside))}"


def test_every_feature_is_its_own_task_on_one_and_three_ranks(tmp_path):
    sc = everything()
    for ranks in (1, 3):
        sim = Simulation(sc, backend=Recording, comm="single" if ranks == 1 else "mock", ranks=ranks,
                         sample=True)
        expected = {**PERIODIC, **SHIFTING, **MOTION, **EXCLUSION, **PROBES}
        if ranks == 3:   # the split axis is the periodic one: a ring, no images, halos both sides
            expected = {**SHIFTING, **MOTION, **EXCLUSION, **PROBES, **SHIFTING_HALOS}
            for k in ("shift_images", "forces_images", "wrap"):
                expected.pop(k, None)
        # the step graph: each task there, ordered by its declared data
        for c in sim.contexts:
            prog = sim.scheduler.programs[c.rank]
            names = [t.name for t in prog]
            for label in expected:
                assert any(n.split("@")[0] == label for n in names), (ranks, c.rank, label, names)
            g = rank_graph(sim.schedule.canonical(c.rank, ranks, 2, rebalance=False,
                                                  features=sim.features.kinds, ring=ranks > 1))
            assert g.has_edge("shift_displacement@2", "integrate@2")      # velocities before the update
            assert "velocities: write after read" in g.edges["shift_displacement@2", "integrate@2"]["reason"]
            assert g.has_edge("integrate@2", "shift_apply@2")
            assert g.has_edge("shift_interior@2", "shift_displacement@2")
            assert g.has_edge("dt_allreduce", "motion@1")
            if ranks == 1:
                assert "shift_images@1" not in g                                 # shifting: last stage only
                assert g.has_edge("forces_images@2", "shift_images@2")            # images: read after write
                assert "images" in g.edges["forces_images@2", "shift_images@2"]["reason"]
                assert g.has_edge("forces_images@1", "integrate@1")               # forces: read after accumulate
        sim.compute.calls.clear()
        steps = 6
        for _ in range(steps):
            sim.step()
        t = sim.scheduler.times.columns()
        _check(t, sim.compute.calls, expected, ranks, 2, steps)
        # the probes task sampled every step (interval 0): probes and forces at each step's end
        rows = sim.probe_sampler.rows
        assert [r["step"] for r in rows["probes"]] == [r["step"] for r in rows["forces"]] == list(range(1, 7))


def test_timing_trace_and_schedule_show_list_the_feature_tasks(tmp_path, capsys):
    res, t = _run(tmp_path, everything(integrator="verlet"), 1)
    labels = {str(x).split("@")[0] for x in t["task"]}
    want = set(PERIODIC) | set(SHIFTING) | set(MOTION) | set(EXCLUSION) | set(PROBES)
    assert want <= labels, want - labels
    trace = write_chrome_trace(res.out_dir, tmp_path / "trace.json")
    names = {e["name"].split("@")[0] for e in json.load(open(trace))["traceEvents"] if e["ph"] == "X"}
    assert want <= names, want - names
    path = tmp_path / "everything.toml"
    path.write_text(dumps_toml(everything(integrator="verlet").to_dict()))
    assert main(["schedule", "show", "production", "--scene", str(path), "--ranks", "1", "--rank", "0"]) == 0
    out = capsys.readouterr().out
    for label in want:
        assert f" {label}" in out, (label, out)
    assert main(["schedule", "show", "production", "--ranks", "1", "--rank", "0"]) == 0
    plain = capsys.readouterr().out
    assert not any(f" {label}" in plain for label in want - {"motion"}), plain


def test_mdbc_is_its_own_task(tmp_path):
    sim = Simulation(mdbc_scene(), backend=Recording)
    sim.compute.calls.clear()
    steps = 4
    for _ in range(steps):
        sim.step()
    _check(sim.scheduler.times.columns(), sim.compute.calls, {**MDBC, **EXCLUSION,
           "shift_interior": {("shift_part", "interior")}}, 1, 1, steps)
    names = [t.name for t in sim.scheduler.programs[0]]
    assert names.index("mdbc@1") < names.index("forces_interior@1")


@pytest.mark.parametrize("kind", ["periodic", "shifting", "motion", "exclusion", "probes"])
def test_a_feature_off_has_no_task(kind):
    d = everything().to_dict()
    if kind == "periodic":
        d["domain"].pop("periodic")
        d["domain"]["min"][0], d["domain"]["max"][0] = -0.1, 1.1
    elif kind == "shifting":
        d["physics"]["shifting"] = "none"
    elif kind == "motion":
        d.pop("motion")
        d.pop("damping")
    elif kind == "exclusion":
        d["domain"]["exclude_outside"] = False
    else:
        d.pop("probes")
        d.pop("forces")
    sim = Simulation(Scene.from_dict(d), sample=True)
    labels = {t.label for t in sim.scheduler.programs[0]}
    gone = {"periodic": set(PERIODIC) | {"shift_images"}, "shifting": set(SHIFTING),
            "motion": set(MOTION), "exclusion": set(EXCLUSION), "probes": set(PROBES)}[kind]
    assert not (gone & labels), gone & labels
    assert "probes" not in {t.label for t in Simulation(everything()).scheduler.programs[0]}   # no output


def test_a_schedule_may_place_feature_tasks_and_the_validator_proves_the_place():
    from sphgraph.features import MDBC_KINDS
    from sphgraph.graph.kinds import FEATURES
    from sphgraph.schedule import Schedule, ScheduleError
    base = ["send_displaced", "build_cells", "recv_displaced", "send_edges", "forces_interior",
            "recv_halo_1", "forces_halo_1", "recv_halo_2", "forces_halo_2", "dt_local", "dt_allreduce",
            "integrate"]
    # named feature tasks go where the order says: the images' forces commute with the
    # interior's, their shifting sums with the halos'
    ok = list(base)
    ok.insert(ok.index("forces_interior"), "forces_images")
    ok.insert(ok.index("dt_local"), "shift_images")
    ok += ["wrap", "exclude"]
    s = Schedule.load({"format": 1, "order": ok})
    s.validate(1, 2, features=FEATURES)
    # mDBC on several ranks sums the halos: an order with the interior forces before them is
    # refused (a periodic ring with mDBC is refused at start, sphgraph.features)
    with pytest.raises(ScheduleError, match=r"mdbc@1 is placed before recv_halo_1@1.*halo_1: read after write"):
        s.validate(3, 2, features=FEATURES, ring=True)
    ring = frozenset(FEATURES) - set(MDBC_KINDS)
    s.validate(3, 2, features=ring, ring=True)
    names = [t.name for t in s.program(1, 3, 2, features=ring, ring=True)]
    assert names.index("forces_images@2") < names.index("forces_interior@2")
    assert names.index("forces_halo_2@2") < names.index("shift_images@2") < names.index("integrate@2")
    # the unnamed ones are placed: shifting around integrate, then motion and damping, then the named wrap
    assert names.index("integrate@2") < names.index("shift_apply@2") < names.index("motion@2") \
        < names.index("damping@2") < names.index("wrap@2") < names.index("exclude")
    # the check that exclude reads goes right before it when the order names exclude alone
    assert names.index("check") == names.index("exclude") - 1
    # a reorder the data forbid: wrap (writes positions) before damping (reads them)
    bad = base + ["wrap", "damping"]
    with pytest.raises(ScheduleError, match="wrap@2 is placed before damping@2"):
        Schedule.load({"format": 1, "order": bad}).validate(1, 2, features=FEATURES)
    # the displacement must see the velocities before the update, the apply must follow it
    for order, task, why in ((base[:-1] + ["integrate", "shift_displacement"], "shift_displacement",
                              "velocities: write after read"),
                             (base[:-1] + ["shift_apply", "integrate"], "shift_apply", "positions")):
        with pytest.raises(ScheduleError, match=task) as e:
            Schedule.load({"format": 1, "order": order}).validate(1, 1, features=FEATURES)
        assert why in str(e.value), str(e.value)
    Schedule.load({"format": 1, "order": base[:-1] + ["integrate", "shift_displacement"]}).validate(1, 1)
