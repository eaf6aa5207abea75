"""The mock MPI engine: deadlock reports, network and cost model, virtual-time determinism,
rank speeds, message ordering, wall timing, predict mode and the cost fit."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from conftest import example
from sphgraph import Scene, Schedule, Simulation
from sphgraph import perfmodel as cm
from sphgraph.backends.comm.mock import Engine, MockComm, run_programs
from sphgraph.backends.compute.numba_cpu import NumbaCPU
from sphgraph.errors import DeadlockError, InputError
from sphgraph.graph.task import Message, Task
from sphgraph.graph.tasks import tag_edges
from sphgraph.scheduler import RankContext


def small():
    return Scene.from_toml(example("dambreak2d.toml")).with_overrides(dp=0.04)


def bare(comm):
    return {r: RankContext(rank=r, state=SimpleNamespace(got=[]), compute=None, comm=comm.endpoint(r))
            for r in range(comm.size)}


# --------------------------------------------------------------------------- deadlock
def test_receive_before_send_schedule_deadlocks_with_report():
    """Both halo receives placed before the edge sends: the validator rejects it, and the
    engine, run on it directly, stops with who waits on what instead of hanging."""
    bad = Schedule.from_dict({"format": 1, "order": [
        "send_displaced", "recv_displaced", "build_cells", "recv_halo_1", "recv_halo_2", "send_edges",
        "forces_interior", "forces_halo_1", "forces_halo_2", "dt_local", "dt_allreduce", "integrate"]})
    with pytest.raises(InputError, match="deadlock"):
        bad.validate(3)
    sim = Simulation(small(), comm="mock", ranks=3)
    sim.scheduler.programs = {r: bad.program(r, 3, 1) for r in range(3)}
    with pytest.raises(DeadlockError) as e:
        sim.step()
    msg = str(e.value)
    lines = msg.splitlines()
    assert f"rank 1 waits in recv_halo_1@1 for a message from rank 0 (tag {tag_edges(1, 1)})" in lines
    assert f"rank 0 waits in recv_halo_2@1 for a message from rank 1 (tag {tag_edges(1, -1)})" in lines
    assert f"rank 2 waits in recv_halo_1@1 for a message from rank 1 (tag {tag_edges(1, 1)})" in lines


def test_collective_not_reached_by_every_rank_deadlocks():
    comm = MockComm(ranks=3)
    noop = lambda ctx, task: None  # noqa: E731
    progs = {0: [Task("sync", fn=noop, collective=True)],
             1: [Task("sync", fn=noop, collective=True)],
             2: [Task("wait", fn=noop, recvs=(Message(-1, 5),))]}
    with pytest.raises(DeadlockError) as e:
        run_programs(progs, bare(comm), comm)
    msg = str(e.value)
    assert "rank 0 waits in sync for every rank (rank(s) 2 not there)" in msg
    assert "rank 2 waits in wait for a message from rank 1 (tag 5)" in msg


# --------------------------------------------------------------------------- network model
def test_network_and_cost_model_times():
    costs = {"send": [1.0, 0.0, 0.0], "recv": [0.5, 0.0, 0.0], "late": [3.0, 0.0, 0.0]}
    comm = MockComm(ranks=2, latency=0.1, bandwidth=1000.0, costs=costs)

    def send(ctx, task):
        ctx.comm.isend(1, 7, np.zeros(100))           # 800 bytes

    def recv(ctx, task):
        ctx.state.got.append(ctx.comm.recv(0, 7))
    progs = {0: [Task("send", fn=send, sends=(Message(1, 7),))],
             1: [Task("recv", fn=recv, recvs=(Message(-1, 7),))]}
    ctxs = bare(comm)
    recs = {(r, n): (a, b) for r, n, a, b in run_programs(progs, ctxs, comm)}
    assert recs[0, "send"] == (0.0, 1.0)
    # arrival = 1.0 (posted at the end of send) + 0.1 latency + 800 B / 1000 B/s = 1.9; + 0.5 recv cost
    assert recs[1, "recv"][0] == 0.0 and recs[1, "recv"][1] == pytest.approx(2.4)
    assert comm.engine.bytes == 800 and comm.engine.messages == 1
    np.testing.assert_array_equal(ctxs[1].state.got[0], np.zeros(100))
    # a receiver arriving late does not wait: completes at its clock + its cost
    comm2 = MockComm(ranks=2, latency=0.1, bandwidth=1000.0, costs=costs)
    progs[1] = [Task("late", fn=lambda c, t: None)] + progs[1]
    recs = {(r, n): (a, b) for r, n, a, b in run_programs(progs, bare(comm2), comm2)}
    assert recs[1, "recv"] == (3.0, 3.5)


def test_collective_completes_at_last_arrival_plus_allreduce_cost():
    costs = {"work": [1.0, 0.0, 0.0], "dt_allreduce": [0.0, 0.0, 0.0]}
    comm = MockComm(ranks=4, latency=0.01, costs=costs, rank_speed=[1, 2, 1, 0.5])

    def reduce(ctx, task):
        ctx.state.got.append(ctx.comm.allreduce_min(10.0 - ctx.rank))
    progs = {r: [Task("work", fn=lambda c, t: None), Task("dt_allreduce", fn=reduce, collective=True)]
             for r in range(4)}
    ctxs = bare(comm)
    recs = {(r, n): (a, b) for r, n, a, b in run_programs(progs, ctxs, comm)}
    # work takes 1/speed: 1, 0.5, 1, 2; the allreduce ends at max(arrivals) + 2*ceil(log2 4)*latency
    assert [recs[r, "work"][1] for r in range(4)] == [1.0, 0.5, 1.0, 2.0]
    for r in range(4):
        assert recs[r, "dt_allreduce"] == (recs[r, "work"][1], pytest.approx(2.0 + 4 * 0.01))
        assert ctxs[r].state.got == [7.0]


def test_non_overtaking_within_a_pair_and_reorder_across_pairs():
    eng = Engine(3, latency=1e-6, bandwidth=1e9, delay=1e-2, reorder=True, seed=5)
    for i in range(50):
        eng.post(0, 2, 1, i, 8, t_post=i * 1e-4)       # pair (0 -> 2, tag 1)
        eng.post(1, 2, 1, i, 8, t_post=i * 1e-4 + 5e-5)  # pair (1 -> 2, tag 1)
    a = [m.arrival for m in eng.mail[(0, 2, 1)]]
    b = [m.arrival for m in eng.mail[(1, 2, 1)]]
    assert a == sorted(a) and b == sorted(b)           # never overtakes within a pair
    assert [m.payload for m in eng.mail[(0, 2, 1)]] == list(range(50))
    merged = sorted([(t, "a", i) for i, t in enumerate(a)] + [(t, "b", i) for i, t in enumerate(b)])
    send_order = [x for i in range(50) for x in (("a", i), ("b", i))]
    assert [(s, i) for _, s, i in merged] != send_order  # pairs are delivered out of send order


def test_payload_is_frozen_at_send():
    comm = MockComm(ranks=2)
    data = np.arange(5.0)

    def send(ctx, task):
        ctx.comm.isend(1, 3, data)
        data[:] = -1

    def recv(ctx, task):
        ctx.state.got.append(ctx.comm.recv(0, 3))
    progs = {0: [Task("send", fn=send, sends=(Message(1, 3),))],
             1: [Task("recv", fn=recv, recvs=(Message(-1, 3),))]}
    ctxs = bare(comm)
    run_programs(progs, ctxs, comm)
    np.testing.assert_array_equal(ctxs[1].state.got[0], np.arange(5.0))


# --------------------------------------------------------------------------- virtual time
def timing_of(steps=10, **opts):
    sim = Simulation(small(), comm="mock", ranks=3, comm_options=opts)
    for _ in range(steps):
        sim.step()
    return sim, sim.scheduler.times.columns()


def test_virtual_time_is_deterministic():
    _, a = timing_of(delay=1e-4, reorder=True, seed=2)
    _, b = timing_of(delay=1e-4, reorder=True, seed=2)
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    sim, c = timing_of()
    assert sim.comm.virtual_time is True
    assert not np.array_equal(a["end"], c["end"])       # the delays changed the times


def test_rank_speed_scales_modelled_durations():
    _, base = timing_of(steps=3)
    _, fast = timing_of(steps=3, rank_speed=[1.0, 2.0, 0.5])

    def dur(cols, rank, task):
        sel = (cols["rank"] == rank) & (cols["task"] == task)
        return (cols["end"][sel] - cols["start"][sel])
    np.testing.assert_allclose(dur(fast, 1, "forces_interior@1"), dur(base, 1, "forces_interior@1") / 2.0)
    np.testing.assert_allclose(dur(fast, 2, "forces_interior@1"), dur(base, 2, "forces_interior@1") * 2.0)
    np.testing.assert_allclose(dur(fast, 0, "build_cells"), dur(base, 0, "build_cells"))
    # a slow rank stretches every rank's step (the dt allreduce waits for it)
    assert fast["end"].max() > base["end"].max()
    # and the fast ones wait longer in the allreduce
    assert dur(fast, 1, "dt_allreduce").sum() > dur(base, 1, "dt_allreduce").sum()


def test_wall_timing_mode():
    sim, cols = timing_of(steps=3, timing="wall")
    d = cols["end"] - cols["start"]
    assert (d >= 0).all() and d.sum() > 0


class _ClockedCPU(NumbaCPU):
    """numba-cpu with a stand-in device clock (the real one, numba-cuda's timing events, runs
    in the GPU tests): every task takes (rank + 1) ms of 'device' time while the clock runs."""

    has_device_clock = True

    def __init__(self):
        super().__init__()
        self.started, self.stopped, self.on = 0, 0, False

    def start_task_clock(self):
        self.started += 1
        self.on = True

    def stop_task_clock(self):
        self.stopped += 1
        self.on = False

    def task_device_seconds(self, state, task):
        return (state.rank + 1) * 1e-3 if self.on else None


def _device_durations_hold(cols, steps):
    late = np.isin(cols["step"], steps) & np.array([not t.startswith(("dt_allreduce", "recv_")) for t in cols["task"]])
    d = (cols["end"] - cols["start"])[late]
    return np.allclose(d, (cols["rank"][late] + 1) * 1e-3, rtol=1e-9)


def test_device_timing_takes_the_backends_task_times():
    sim = Simulation(small(), backend=_ClockedCPU, comm="mock", ranks=3, comm_options={"timing": "device"})
    for _ in range(3):
        sim.step()
    cols = sim.scheduler.times.columns()
    assert sim.compute.started == 1 and sim.compute.stopped == 0 and sim.comm.clock == "device task times"
    assert _device_durations_hold(cols, np.unique(cols["step"]))
    m = Simulation(small(), comm="mock", ranks=3)        # the model's durations differ
    m.step()
    assert m.comm.clock == "cost model"
    first = cols["step"] == cols["step"].min()
    assert not np.allclose((cols["end"] - cols["start"])[first][:5], 1e-3)


def test_auto_timing_reads_the_device_only_inside_a_window():
    sim = Simulation(small(), backend=_ClockedCPU, comm="mock", ranks=3)
    assert not sim.comm.device_clock_window(True)      # no step yet: no compute backend known
    sim.comm.device_clock_window(False)
    sim.step()
    assert sim.comm.clock == "cost model" and sim.compute.started == 0
    assert sim.comm.device_clock_window(True)
    sim.step()
    sim.step()
    assert sim.comm.clock == "device task times" and sim.compute.on
    assert sim.comm.device_clock_window(False)
    sim.step()
    assert sim.comm.clock == "cost model" and not sim.compute.on
    assert (sim.compute.started, sim.compute.stopped) == (1, 1)
    cols = sim.scheduler.times.columns()
    steps = np.unique(cols["step"])
    assert _device_durations_hold(cols, steps[1:3]) and not _device_durations_hold(cols, steps[3:])
    # a model-timed mock (or any comm without a device clock) opens no window
    assert not Simulation(small(), comm="mock", ranks=2, comm_options={"timing": "model"}).comm.device_clock_window(True)


def test_bench_predicts_from_a_device_window_after_its_timed_steps():
    from sphgraph.bench import PREDICT_STEPS, bench
    for steps in (4, PREDICT_STEPS + 2):
        r = bench(small(), steps=steps, warmup=1, backend=_ClockedCPU, comm="mock", ranks=2)
        assert r["predict_steps"] == min(steps, PREDICT_STEPS) and r["predicted_from"] == "device task times"
        # the window's device times, scaled to the timed steps: 1 ms on rank 0 and 2 ms on rank 1
        # a task; the slower rank paces the step
        assert r["task_seconds"]["forces_interior"] == pytest.approx(steps * 3e-3, rel=1e-9)
        assert r["predicted_wall_s"] >= steps * 2e-3 * 6


def test_the_device_window_starts_with_the_ranks_clocks_together():
    """The cost model prices the ranks' rows (here 1 s a row a step, so ranks with different
    row counts drift apart by seconds); the window's prediction is of the device's times
    alone, as if the whole run had been timed on the device, with no wait inherited from
    the model's drift."""
    from sphgraph.bench import bench
    costs = {"integrate": [0.0, 1.0, 0.0]}
    r = bench(small(), steps=6, warmup=2, backend=_ClockedCPU, comm="mock", ranks=2,
              comm_options={"costs": costs})
    dev = Simulation(small(), backend=_ClockedCPU, comm="mock", ranks=2,
                     comm_options={"costs": costs, "timing": "device"})
    for _ in range(8):
        dev.step()
    cols = dev.scheduler.times.columns()
    late = cols["step"] > cols["step"].min() + 1
    per_step = (cols["end"][late].max() - cols["start"][late].min()) / 6
    assert r["predicted_wall_s"] == pytest.approx(6 * per_step, rel=0.05)


def test_eager_order_gives_the_clock_orders_times_and_rows():
    """Which runnable rank the engine runs next changes the order in which one process
    issues the ranks' tasks, never a virtual time or a row: "eager" (a rank runs up to its
    next wait) against "clock" (smallest virtual clock first), 3 ranks, 12 steps with a
    rebalance, on the cost model's clock."""
    runs = {}
    for order in ("clock", "eager"):
        sim = Simulation(small(), comm="mock", ranks=3, comm_options={"order": order})
        for _ in range(12):
            sim.step()
        runs[order] = (sim.scheduler.times.columns(), sim.frame_arrays())
        assert sim.comm.order == order
    (tc, ac), (te, ae) = runs["clock"], runs["eager"]
    # /timing's rows come in the order the tasks ran: the two orders did differ
    assert list(zip(tc["rank"], tc["task"])) != list(zip(te["rank"], te["task"]))
    key = lambda c: np.lexsort((c["start"], c["rank"], c["step"]))   # noqa: E731
    for k in ("start", "end"):
        assert np.array_equal(tc[k][key(tc)], te[k][key(te)]), k
    for k in ac:
        assert np.array_equal(ac[k], ae[k]), k
    assert Simulation(small(), comm="mock", ranks=2).comm.order == "eager"
    assert Simulation(small(), comm="mock", ranks=2, comm_options={"delay": 1e-6}).comm.order == "clock"
    with pytest.raises(InputError, match="order"):
        MockComm(ranks=2, order="fifo")


def test_eager_order_reads_the_device_after_every_rank_issued_its_work():
    """Under "eager" a task that waits for its rank's device (exclude: Task.reads_device) runs
    only once no rank has another task to issue: in every step, each rank's check (which starts
    what exclude reads) ran before the first exclude, and so did each rank's halo forces of stage 1
    before the first dt_allreduce (a collective: dt_local only starts the dt terms, the wait for
    them is the reduction's) -- the order /timing's rows were recorded in. Under "clock" the
    exclude part is not so."""
    def first_read_after_all(cols, read, before):
        ok = []
        for step in np.unique(cols["step"]):
            seq = [(r, t) for r, t, s in zip(cols["rank"], cols["task"], cols["step"]) if s == step]
            first = next(i for i, (_, t) in enumerate(seq) if t == read)
            last = max(i for i, (_, t) in enumerate(seq) if t in before)
            ok.append(last < first)
        return all(ok)
    res = {}
    for order in ("eager", "clock"):
        sim = Simulation(small(), comm="mock", ranks=3, comm_options={"order": order})
        for _ in range(4):
            sim.step()
        cols = sim.scheduler.times.columns()
        assert "exclude" in set(cols["task"])
        res[order] = (first_read_after_all(cols, "dt_allreduce", {"forces_halo_1@1", "forces_halo_2@1"}),
                      first_read_after_all(cols, "exclude", {"check"}))
    assert res["eager"] == (True, True)
    assert res["clock"] == (True, False)


def test_auto_timing_without_a_device_clock_is_the_model():
    _, auto = timing_of(steps=3)
    _, model = timing_of(steps=3, timing="model")
    for k in auto:
        assert np.array_equal(auto[k], model[k]), k


def test_bad_options_are_input_errors():
    with pytest.raises(InputError, match="rank_speed"):
        MockComm(ranks=3, rank_speed=[1, 2])
    with pytest.raises(InputError, match="timing"):
        MockComm(ranks=2, timing="fast")
    with pytest.raises(InputError, match="unknown option"):
        MockComm(ranks=2, colour="red")


# --------------------------------------------------------------------------- predict and fit
def test_predict_mode_in_simulation_runs_no_kernels():
    sim = Simulation(small(), comm="mock", ranks=3, comm_options={"mode": "predict"}, fixed_dt=1e-4)
    before = sim.frame_arrays()["position"].copy()
    for _ in range(3):
        sim.step()
    assert np.array_equal(sim.frame_arrays()["position"], before)
    cols = sim.scheduler.times.columns()
    assert set(cols["rank"].tolist()) == {0, 1, 2} and cols["end"].max() > 0


def test_predict_api_and_efficiency():
    sc = small()
    p1 = cm.predict(sc, 1, steps=5)
    p3 = cm.predict(sc, 3, steps=5)
    assert p1.steps_per_s > 0 and p3.steps_per_s > p1.steps_per_s
    assert sum(p3.rank_particles) == p3.particles == p1.particles
    assert {"forces_interior", "forces_halo_1", "send_edges", "dt_allreduce"} <= set(p3.task_seconds)
    slow = cm.predict(sc, 3, steps=5, rank_speed=[1.0, 1.0, 0.25])
    assert slow.steps_per_s < p3.steps_per_s
    a = cm.predict(sc, 3, steps=5)
    assert a.steps_per_s == p3.steps_per_s and a.task_seconds == p3.task_seconds
    e = cm.efficiency_curve(sc, [2, 3], steps=3)
    assert all(0 < v <= 1.05 for v in e.values())


@pytest.mark.parametrize("costs", [None, "mpi2"])
def test_predict_overlaps_displaced_rows_with_build_cells(costs):
    """production receives the displaced rows after build_cells (their merge is part of
    recv_displaced's fitted cost), bulk-synchronous before it: in predict mode the receive
    waits less when the message travels during the build, never more; the fitted 2-rank
    costs still load and drive both orders."""
    import os
    sc = small()
    if costs == "mpi2":
        costs = os.path.join(os.path.dirname(example("dambreak2d.toml")), "..", "benchmarks", "costs_mpi2.toml")
        assert "recv_displaced" in cm.CostModel.load(costs).coeffs
    prod = cm.predict(sc, 3, "production", steps=4, costs=costs, latency=2e-5)
    bulk = cm.predict(sc, 3, "bulk-synchronous", steps=4, costs=costs, latency=2e-5)
    for r in range(3):
        assert prod.per_rank[r]["recv_displaced"] <= bulk.per_rank[r]["recv_displaced"] + 1e-12
    assert prod.task_seconds["recv_displaced"] < bulk.task_seconds["recv_displaced"]
    t = prod.timing.columns()
    for r in range(3):   # recv_displaced issued after build_cells on every rank
        names = list(t["task"][(t["rank"] == r) & (t["step"] == 0)])
        assert names.index("build_cells") < names.index("recv_displaced")


def test_predict_large_scene_without_building_it():
    """A 16 M-particle scene on 64 ranks: shape from a coarse build, scaled."""
    sc = Scene.from_toml(example("yeh_petroff.toml"))
    nf, nb = sc.count_particles()
    # fluid ~ dp^-3, one-layer boundaries ~ dp^-2: the refinement r giving 16 M particles
    r = next(r for r in np.arange(1.0, 100.0, 0.01) if nf * r ** 3 + nb * r ** 2 >= 16e6)
    big = sc.with_overrides(dp=sc.dp / r)
    shape = cm.decomposition_shape(big, 64, max_build=200_000, axis="x")
    assert 14e6 < shape["particles"] < 18e6
    assert sum(shape["rows"]) == pytest.approx(shape["particles"], rel=1e-9)
    p = cm.predict(big, 64, steps=2, shape=shape)
    assert p.steps_per_s > 0 and len(p.per_rank) == 64


def test_fit_recovers_known_coefficients():
    true = {"forces_interior": (1e-4, 2e-8, 3e-9), "integrate": (5e-6, 1e-8, 0.0)}
    samples = []
    for n, k in ((1000, 20), (5000, 20), (20000, 20), (4000, 150), (30000, 150)):
        for lab, (a, b, c) in true.items():
            p, q = cm.task_features(lab, n, 0, 0, k)
            samples.append((lab, p, q, a + b * p + c * q))
    m = cm.fit_costs(samples)
    for lab, coef in true.items():
        np.testing.assert_allclose(m.coeffs[lab], coef, rtol=1e-6, atol=1e-15)
        assert m.fit_error[lab] < 1e-9


def test_shipped_cost_fit_loads_and_states_its_error():
    m = cm.CostModel.load()
    assert "forces_interior" in m.coeffs and m.fit_error
    assert m.seconds("forces_halo_1", 100, 1000) == m.seconds("forces_interior", 100, 1000)
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks.fit_costs import measure_runs    # the fit's runs (kernels) live in benchmarks/
    samples = measure_runs([(example("dambreak2d.toml"), 0.04)], steps=4)
    labels = {s[0] for s in samples}
    assert {"forces_interior", "build_cells", "integrate"} <= labels


def test_device_timeline_as_chrome_trace(tmp_path):
    """A device timeline (NumbaCUDA.device_trace's rows) as Perfetto JSON: a process per rank,
    a thread per lane, copies on their own thread, microseconds."""
    import json

    from sphgraph.trace import write_device_chrome_trace
    trace = [{"rank": 0, "step": 4, "task": "forces_interior@1", "lane": "compute", "inside": None,
              "start": 0.010, "end": 0.012},
             {"rank": 1, "step": 4, "task": "send_edges@1", "lane": "comm", "inside": None,
              "start": 0.0105, "end": 0.0106},
             {"rank": 1, "step": 4, "task": "edge_d2h", "lane": "comm", "inside": "send_edges@1",
              "start": 0.0105, "end": 0.01055}]
    path = write_device_chrome_trace(trace, tmp_path / "dev.json", {"ranks": 2})
    doc = json.loads(open(path).read())
    x = [e for e in doc["traceEvents"] if e["ph"] == "X"]
    assert [e["name"] for e in x] == ["forces_interior@1", "send_edges@1", "edge_d2h"]
    assert x[0]["ts"] == pytest.approx(10000.0) and x[0]["dur"] == pytest.approx(2000.0)
    names = {(e["pid"], e["tid"]): e["args"]["name"] for e in doc["traceEvents"] if e["name"] == "thread_name"}
    assert names[(1, x[2]["tid"])] == "copies" and names[(1, x[1]["tid"])] == "comm"
    assert {e["args"]["name"] for e in doc["traceEvents"] if e["name"] == "process_name"} == \
        {"rank 0 (device)", "rank 1 (device)"}
    assert doc["otherData"]["ranks"] == 2
