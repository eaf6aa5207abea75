"""Run under `mpiexec -n N python tests/mpi_driver.py CHECK [CHECK ...]` by tests/test_multirank.py.

Checks (rank 0 prints one JSON line per check, `{"check": ..., "ok": ..., ...}`):
  equiv2d / equiv3d / equiv2d-migrating (fluid pushed at 2 m/s: rows cross the cuts)
                      a small dam break for STEPS steps with --comm mpi; every step the
                      gathered ids equal the initial ids; rank 0 compares the final
                      positions (by id) with a single-rank run done here (comm single)
  mdbc2d              the 2D dam break with `boundary = "mdbc-noslip"` (bulk-synchronous, push 2 m/s):
                      the mDBC exchange under MPI against the single-rank run, to TOL
  rjump2d             the same with mDBC walls and the renormalised Riemann jump (Symplectic,
                      riemann_jump = "renormalised"): its per-part moments under MPI, to TOL
  mdbc-motion2d       mDBC on a moving body (tests/test_mdbc_motion.py's carried tank, 50 steps)
                      against the single-rank run, to TOL
  mdbc-noslip-motion2d  the same with no-slip walls and a laminar viscosity
  schedules           every shipped schedule, each also with halo_order reversed, gives
                      bit-identical particles (STEPS_SCHED steps, 2D)
  conformance         the comm conformance behaviours (tests/test_comm_conformance.py)
  cuda-ipc            GPU only: the 3D dam break (numba-cuda, float64, Symplectic, push 2 m/s)
                      with --halo-transport staged and ipc; ipc must give the staged bits,
                      both the single-rank numba-cuda run to TOL, and no halo bytes may
                      cross the bus with ipc (per-rank bytes_by_kind)
  cuda-mdbc           numba-cuda (numba's CUDA simulator when NUMBA_ENABLE_CUDASIM=1), float64, the
                      small 2D tank of tests/test_cuda_mdbc_ranks.py (`mpi_scene`) with mDBC no-slip,
                      bulk-synchronous, SPHGRAPH_MDBC_STEPS steps (2), SPHGRAPH_MDBC_TRANSPORT (auto: staged):
                      against numba-cpu on one rank (positions to TOL, velocities 1e-10 m/s,
                      densities 1e-6 kg/m^3, the same ids); per rank the mDBC bytes read from and
                      uploaded to the device, and how many boundary rows' ghost nodes have the
                      halo's fluid within 2h (the sums that cross the cut)
Exit code 0 when every check passed on every rank, 1 otherwise.
"""
from __future__ import annotations

import json
import os
import sys
import traceback

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
EXAMPLES = os.path.join(HERE, "..", "examples")
STEPS = int(os.environ.get("SPHGRAPH_MPI_STEPS", "200"))
STEPS_SCHED = int(os.environ.get("SPHGRAPH_MPI_SCHED_STEPS", "200"))
TOL = 1e-9


def scene(kind):
    from sphgraph import Scene
    if kind == "2d":
        return Scene.from_toml(os.path.join(EXAMPLES, "dambreak2d.toml")).with_overrides(dp=0.04)
    return Scene.from_toml(os.path.join(EXAMPLES, "dambreak3d.toml")).with_overrides(dp=0.03)


def run_sim(sc, comm, steps, schedule="production", check_ids=True, push=0.0):
    from sphgraph import Simulation
    # 3D: split along x (the flow direction); `auto` picks the longest fluid extent (y here)
    sim = Simulation(sc, comm=comm, schedule=schedule, decomposition_axis="x" if sc.dim == 3 else None)
    for c in sim.contexts:   # a uniform push moves rows across the cuts (see test_multirank.kick)
        p = c.state.particles
        p.vel[p.kind == 0, 0] += push
        p.vel_m1[p.kind == 0, 0] += push
    a = sim.frame_arrays()
    ids0 = None if a is None else a["id"].copy()
    bad = None
    for i in range(steps):
        sim.step()
        if check_ids:
            a = sim.frame_arrays()
            if a is not None and bad is None and not np.array_equal(a["id"], ids0):
                bad = f"step {i + 1}: gathered ids differ from the initial set ({len(a['id'])} vs {len(ids0)})"
    a = sim.frame_arrays()
    return sim, a, bad


def check_equiv(kind, push=0.0):
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    sc = scene(kind)
    sim, a, bad = run_sim(sc, "mpi", STEPS, push=push)
    if comm.rank != 0:
        return None
    _, ref, _ = run_sim(sc, "single", STEPS, check_ids=False, push=push)
    span = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    err = float(np.abs(a["position"] - ref["position"]).max()) if a["id"].shape == ref["id"].shape else np.inf
    ok = bad is None and np.array_equal(a["id"], ref["id"]) and err <= TOL * span
    return {"check": f"equiv{kind}" + ("-migrating" if push else ""), "ok": bool(ok), "ranks": comm.size, "steps": STEPS,
            "particles": int(len(a["id"])), "max_abs_err": err, "rel_err": err / span, "ids": bad or "ok"}


RJUMP = {"boundary": "mdbc", "integrator": "symplectic", "riemann": "zhang2017", "riemann_jump": "renormalised"}


def check_mdbc(steps=60, name="mdbc2d", physics=None):
    from mpi4py import MPI

    from sphgraph import Scene
    comm = MPI.COMM_WORLD
    sc = scene("2d")
    d = sc.to_dict()
    d["physics"] = dict(d.get("physics", {}), **(physics or {"boundary": "mdbc-noslip"}))
    sc = Scene.from_dict(d)
    sim, a, bad = run_sim(sc, "mpi", steps, schedule="bulk-synchronous", push=2.0)
    if comm.rank != 0:
        return None
    _, ref, _ = run_sim(sc, "single", steps, schedule="bulk-synchronous", check_ids=False, push=2.0)
    span = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    same = a["id"].shape == ref["id"].shape
    err = float(np.abs(a["position"] - ref["position"]).max()) if same else np.inf
    rho = float(np.abs(a["density"] / ref["density"] - 1).max()) if same else np.inf
    ok = bad is None and np.array_equal(a["id"], ref["id"]) and err <= TOL * span and rho <= TOL
    return {"check": name, "ok": bool(ok), "ranks": comm.size, "steps": steps, "rel_err": err / span,
            "density_rel_err": rho, "ids": bad or "ok"}


def check_mdbc_motion(steps=50, noslip=False):
    """mDBC on a moving body under MPI: tests/test_mdbc_motion.py's carried tank (0.6 m wide,
    3 layers, carried with its water at U = 0.3 m/s; the tank's rows cross the cut) against
    the single-rank run, to TOL; `noslip`: with no-slip walls and a laminar viscosity."""
    from mpi4py import MPI

    from sphgraph import Simulation
    from test_mdbc_motion import U, noslip_scene, scene as carried
    comm = MPI.COMM_WORLD
    sc = noslip_scene(U, width=0.6) if noslip else carried(width=0.6)

    def go(kind):
        sim = Simulation(sc, comm=kind, schedule="bulk-synchronous", decomposition_axis="x")
        for c in sim.contexts:
            c.state.particles.vel[:, 0] += U
            c.state.particles.vel_m1[:, 0] += U
        for _ in range(steps):
            sim.step()
        return sim.frame_arrays()
    a = go("mpi")
    if comm.rank != 0:
        return None
    ref = go("single")
    span = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    same = a["id"].shape == ref["id"].shape and np.array_equal(a["id"], ref["id"])
    err = float(np.abs(a["position"] - ref["position"]).max()) if same else np.inf
    rho = float(np.abs(a["density"] / ref["density"] - 1).max()) if same else np.inf
    return {"check": "mdbc-noslip-motion2d" if noslip else "mdbc-motion2d", "ok": bool(same and err <= TOL * span and rho <= TOL), "ranks": comm.size,
            "steps": steps, "rel_err": err / span, "density_rel_err": rho}


def check_schedules():
    from mpi4py import MPI

    from sphgraph import Schedule
    from sphgraph.schedule import shipped
    comm = MPI.COMM_WORLD
    sc = scene("2d")
    results = {}
    for name in shipped():
        base = Schedule.load(name)
        for rev in (False, True):
            if rev:
                d = {"format": 1, "order": list(base.order), "halo_order": [2, 1],
                     "lanes": dict(base.lanes), "rebalance": dict(base.rebalance)}
                s = Schedule.from_dict(d, name=f"{name}-reversed")
            else:
                s = base
            _, a, bad = run_sim(sc, "mpi", STEPS_SCHED, schedule=s, check_ids=False, push=2.0)
            if comm.rank == 0:
                results[s.name] = a
    if comm.rank != 0:
        return None
    names = list(results)
    ref = results[names[0]]
    diff = [n for n in names[1:] if not all(np.array_equal(results[n][k], ref[k])
                                            for k in ("id", "position", "velocity", "density"))]
    return {"check": "schedules", "ok": not diff, "ranks": comm.size, "schedules": names,
            "differ": diff, "steps": STEPS_SCHED}


def check_conformance():
    from mpi4py import MPI

    import test_comm_conformance as tc
    from sphgraph.registry import get
    comm = MPI.COMM_WORLD
    backend = get("comm", "mpi")()
    failures = []
    for name, fn in tc.behaviours():
        try:
            fn(backend)
        except Exception:   # noqa: BLE001
            failures.append(f"rank {comm.rank}: {name}: {traceback.format_exc(limit=3)}")
    allf = comm.gather(failures, root=0)
    if comm.rank != 0:
        return None
    flat = [f for fs in allf for f in fs]
    return {"check": "conformance", "ok": not flat, "ranks": comm.size, "failures": flat,
            "behaviours": [n for n, _ in tc.behaviours()]}


def push(sim, st, speed=2.0):
    """Fluid pushed along x (rows cross the cuts), uploaded again to the device."""
    p = st.particles
    p.vel[p.kind == 0, 0] += speed
    p.vel_m1[p.kind == 0, 0] += speed
    st.extra.pop("dev", None)        # a fresh upload (prepare keeps device rows of the same host set)
    sim.compute.prepare(st)


def check_cuda_ipc(steps=20):
    from mpi4py import MPI

    from sphgraph import Simulation
    comm = MPI.COMM_WORLD
    sc = scene("3d").with_overrides(dp=0.02, integrator="symplectic")
    got, kinds = {}, {}
    for tr in ("staged", "ipc"):
        sim = Simulation(sc, backend="numba-cuda", precision="float64", comm="mpi", decomposition_axis="x",
                         comm_options={"halo_transport": tr})
        for c in sim.contexts:
            push(sim, c.state)
        for _ in range(steps):
            sim.step()
        got[tr] = sim.frame_arrays()
        kinds[tr] = comm.gather(dict(sim.contexts[0].state.extra.get("bytes_by_kind", {})), root=0)
    if comm.rank != 0:
        return None
    ref_sim = Simulation(sc, backend="numba-cuda", precision="float64", comm="single")
    push(ref_sim, ref_sim.contexts[0].state)
    for _ in range(steps):
        ref_sim.step()
    ref = ref_sim.frame_arrays()
    span = float(np.max(np.asarray(sc.domain_max) - np.asarray(sc.domain_min)))
    a, b = got["staged"], got["ipc"]
    def err_of(x):
        return float(np.abs(x["position"] - ref["position"]).max()) if np.array_equal(x["id"], ref["id"]) else np.inf
    err = max(err_of(a), err_of(b))
    # ipc: no halo row up or down, one 32-byte read of the edges' row ranges a sort
    edge_reads = [k.get("d2h:edge", 0) for k in kinds["ipc"]]
    ok = err <= TOL * span and all(k.get("h2d:halo", 0) == 0 for k in kinds["ipc"]) and \
        all(0 < e <= 32 * 3 * steps for e in edge_reads)
    return {"check": "cuda-ipc", "ok": bool(ok), "ranks": comm.size, "steps": steps, "particles": int(len(b["id"])),
            "rel_err": err / span, "edge_reads": edge_reads,
            "staged_h2d_halo": [k.get("h2d:halo", 0) for k in kinds["staged"]],
            "ipc_bytes_by_kind": kinds["ipc"]}


def check_cuda_mdbc():
    from mpi4py import MPI

    import cudasim_helpers as H
    from sphgraph import Simulation
    from sphgraph.physics.mdbc import ghost_positions, interface_boxes
    from test_cuda_mdbc_ranks import SCHEDULE, mpi_scene
    comm = MPI.COMM_WORLD
    steps = int(os.environ.get("SPHGRAPH_MDBC_STEPS", "2"))
    sc = mpi_scene(comm.size)
    transport = os.environ.get("SPHGRAPH_MDBC_TRANSPORT", "auto")
    sim = Simulation(sc, backend="numba-cuda", precision="float64", comm="mpi", schedule=SCHEDULE,
                     comm_options={"halo_transport": transport})
    for _ in range(steps):
        sim.step()
    f = sim.frame_arrays()
    st = sim.contexts[0].state
    sim.compute.sync_host(st)
    p = st.particles
    b = p.kind != 0
    ghosts = ghost_positions(np.asarray(p.pos[b], np.float64), interface_boxes(sc))
    near = 0
    for h in st.halos.values():
        if h is not None and h.n:
            fl = np.asarray(h.pos[h.kind == 0], np.float64)
            if len(fl):
                d2 = ((ghosts[:, None, :] - fl[None, :, :]) ** 2).sum(-1)
                near += int((d2.min(axis=1) < (2 * sc.constants.h) ** 2).sum())
    by = st.extra.get("bytes_by_kind", {})
    mine = {"rank": comm.rank, "rows": int(p.n), "ghosts_near_halo_fluid": near,
            "d2h_mdbc": int(by.get("d2h:mdbc", 0)), "h2d_mdbc": int(by.get("h2d:mdbc", 0))}
    ranks = comm.gather(mine, root=0)
    if comm.rank != 0:
        return None
    i = np.argsort(f["id"])
    got = ({k: f[k][i] for k in ("id", "position", "velocity", "density")}, sim.time)
    r = H.diff(sc, H.run(sc, "numba-cpu", steps), got)
    staged = sim.halo_transport == "staged"    # ipc: the values stay on the device (no mDBC bytes)
    ok = (r["ids"] and r["time"][0] == r["time"][1] and r["pos"] <= TOL and r["vel"] < 1e-10 and r["rho"] < 1e-6
          and all(x["ghosts_near_halo_fluid"] > 0 and (not staged or (x["d2h_mdbc"] > 0 and x["h2d_mdbc"] > 0))
                  for x in ranks))
    return {"check": "cuda-mdbc", **r, "ok": bool(ok), "ranks": comm.size, "steps": steps,
            "transport": sim.halo_transport, "simulator": os.environ.get("NUMBA_ENABLE_CUDASIM") == "1",
            "per_rank": ranks}


CHECKS = {"equiv2d": lambda: check_equiv("2d"), "equiv3d": lambda: check_equiv("3d"),
          "cuda-ipc": check_cuda_ipc, "cuda-mdbc": check_cuda_mdbc,
          "equiv2d-migrating": lambda: check_equiv("2d", 2.0), "mdbc2d": check_mdbc, "mdbc-motion2d": check_mdbc_motion,
          "rjump2d": lambda: check_mdbc(name="rjump2d", physics=RJUMP),
          "mdbc-noslip-motion2d": lambda: check_mdbc_motion(noslip=True),
          "schedules": check_schedules, "conformance": check_conformance}


def main(argv):
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    ok = True
    for name in argv:
        try:
            res = CHECKS[name]()
        except Exception:   # noqa: BLE001
            res = {"check": name, "ok": False, "rank": comm.rank, "error": traceback.format_exc()}
            print(json.dumps(res), flush=True)
            comm.Abort(1)
        if res is not None:
            print(json.dumps(res), flush=True)
            ok = ok and res["ok"]
    ok = comm.bcast(ok, root=0)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
