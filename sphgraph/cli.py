"""Command line: `sphgraph run | bench | info | schedule | trace | plot`.

A thin layer over the Python API. Exit codes (DESIGN.md §5): 0 success,
1 numerical failure, 2 bad input or usage (one line, no traceback), 3 internal
error (short message; traceback in a log file).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import traceback

from . import COMMAND  # the console script or python -m sphgraph (sphgraph/__init__.py)
from .errors import CommError, DiskFullError, InputError, NumericalError, SphgraphError
from .ranges import check_flag


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse would print usage too)
        raise InputError(f"{self.prog}: {message}")


def _run_flags(p):
    p.add_argument("scene", help="scene TOML file")
    p.add_argument("--end-time", type=float, help="override the scene's end time [s]")
    p.add_argument("--max-steps", type=int, help="stop after N steps")
    p.add_argument("--dp", type=float, help="override the particle spacing [m]")
    p.add_argument("--backend", default="numba-cpu", help="compute backend: numba-cpu | numba-cuda")
    p.add_argument("--precision", choices=["float32", "float64"],
                   help="default float64 on numba-cpu, float32 on numba-cuda")
    p.add_argument("--comm", default="single", help="comm backend: single | mock | mpi")
    p.add_argument("--ranks", type=int, default=1, help="ranks for --comm mock")
    p.add_argument("--schedule", default="production", help="schedule name or TOML file")
    p.add_argument("--rank-speed", help="mock MPI: comma-separated relative rank speeds, e.g. 1,2,1,0.5")
    p.add_argument("--duplicate", metavar="P|N,N..", help="mock MPI: deliver messages twice (probability "
                   "per message, e.g. 0.01, or message numbers, e.g. 5,17); detected and reported")
    p.add_argument("--loss", metavar="P|N,N..", help="mock MPI: drop messages (as --duplicate); detected "
                   "and reported")
    p.add_argument("--seed", type=int, help="mock MPI: random seed of --duplicate/--loss (and delays)")
    p.add_argument("--watchdog", type=float, metavar="SECONDS",
                   help="stop every rank when one waits longer than SECONDS in a receive or collective "
                        "(MPI: default 120, 0 = off; mock: virtual seconds, off by default)")
    p.add_argument("--halo-transport", metavar="auto|staged|ipc",
                   help="how halos travel between GPU ranks (numba-cuda): staged through the host "
                        "(works anywhere) or ipc, device to device (CUDA IPC handles, ranks of one "
                        "host); auto (default): ipc for mock ranks, staged under MPI")
    # load balancing (sphgraph.balance): these flags > the scene's [balance] > the schedule's [rebalance]
    p.add_argument("--rebalance-every", type=_balance_value("every", int), metavar="K",
                   help="check the balance every K steps (schedule default 50)")
    p.add_argument("--rebalance-threshold", type=_balance_value("threshold", float), metavar="X",
                   help="apply new cuts when the imbalance drops by more than X (0.03 = 3 points)")
    p.add_argument("--rebalance-policy", type=_balance_value("policy", str), metavar="particles|time|memory",
                   help="balance fluid particles, measured force time, or particles within each rank's "
                        "capacity")
    p.add_argument("--max-particles-per-rank", type=_balance_value("max_particles_per_rank", int), metavar="N",
                   help="memory policy: a rank's capacity in fluid particles, halos included (CPU, mock; "
                        "on GPU it also caps the free-memory estimate)")
    p.add_argument("--no-rebalance", action="store_true", help="no load balancing (keep the initial cuts)")


def _balance_value(key, conv):
    """argparse type of a balancing flag: parsed by `conv`, checked as the scene key `key`."""
    def parse(text):
        from .balance import expected_form
        try:
            v = conv(text)
        except ValueError:
            v = None          # not a number: reported with the key's expected form
        form = expected_form(key, v)
        if form is not None:
            raise argparse.ArgumentTypeError(f"expected {form}, got {text!r}")
        return v
    return parse


def _balance_flags(args) -> dict:
    """The flag layer of BalanceConfig.resolve (None: not given)."""
    return {"every": args.rebalance_every, "threshold": args.rebalance_threshold,
            "policy": args.rebalance_policy, "max_particles_per_rank": args.max_particles_per_rank,
            "enabled": False if args.no_rebalance else None}


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="sphgraph", description="SPH free-surface flow; every step a task graph")
    sub = ap.add_subparsers(dest="cmd", parser_class=_Parser)
    sub.required = True

    p = sub.add_parser("run", help="run a scene")
    _run_flags(p)
    p.add_argument("--out", help="output directory (default out/<scene name>)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run in --out")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--checkpoint-every", metavar="N|Ts",
                   help="write DIR/checkpoints/ckpt_<step>.h5 every N steps or T simulated seconds (e.g. 0.05s)")
    p.add_argument("--restart", metavar="DIR", help="continue the run in DIR from its newest valid checkpoint")
    p.add_argument("--walltime", type=float, metavar="SECONDS",
                   help="after SECONDS of wall time write a checkpoint and exit 0 (as on SIGTERM)")
    p.add_argument("--no-invariants", action="store_true",
                   help="skip the per-step particle count / id / NaN-velocity checks")

    p = sub.add_parser("bench", help="time a scene; one JSON object on stdout")
    _run_flags(p)
    p.add_argument("--steps", type=int, default=50, help="timed steps")
    p.add_argument("--warmup", type=int, default=5, help="untimed steps first (compilation)")
    p.add_argument("--json", action="store_true", help="print JSON (the default and only format)")

    sub.add_parser("info", help="versions, backends, threads")

    p = sub.add_parser("schedule", help="validate or show a schedule")
    ssub = p.add_subparsers(dest="action", parser_class=_Parser)
    ssub.required = True
    v = ssub.add_parser("validate", help="prove a schedule (exit 2 with one line per problem)")
    v.add_argument("file")
    v.add_argument("--ranks", type=int, default=3)
    v.add_argument("--integrator", choices=["verlet", "symplectic"], default=None,
                   help="default: check both")
    s = ssub.add_parser("show", help="ordered tasks per lane")
    s.add_argument("name")
    s.add_argument("--ranks", type=int, default=3)
    s.add_argument("--rank", type=int, default=1)
    s.add_argument("--integrator", choices=["verlet", "symplectic"], default=None,
                   help="default: the scene's, else verlet")
    s.add_argument("--scene", help="with the feature tasks of this scene (its integrator unless "
                                   "--integrator is given)")
    s.add_argument("--plot", help="draw the multi-rank graph to this PNG/SVG file")

    p = sub.add_parser("trace", help="export task timings")
    p.add_argument("outdir")
    p.add_argument("--chrome", required=True, help="write Chrome trace-event JSON (Perfetto)")

    p = sub.add_parser("validate", help="run a validation case against its reference data "
                                          "(exit 0 within the case's tolerances, 1 outside)")
    p.add_argument("case", nargs="?", help="case name (--list) or case TOML file")
    p.add_argument("--list", action="store_true", help="name the cases")
    p.add_argument("--dp", type=float, help="particle spacing (default: the case's)")
    p.add_argument("--backend", default="numba-cpu")
    p.add_argument("--precision", choices=["float32", "float64"])
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="physics override, e.g. --set integrator=symplectic (repeatable)")
    p.add_argument("--boundary", choices=["dbc", "mdbc", "mdbc-noslip"], default=None,
                   help="wall treatment (default: the case's; mDBC on any backend and rank count)")
    p.add_argument("--out", default="out/validate", help="directory of the comparison plot PNG")
    p.add_argument("--quiet", action="store_true", help="no progress output")

    p = sub.add_parser("study", help="sweep resolution and methods of a case: error against wall time "
                                       "(CSV + log-log PNG with the Pareto front)")
    p.add_argument("case")
    p.add_argument("--dp", help="comma-separated spacings (default: the case's study list)")
    for k in ("integrator", "kernel", "diffusion", "precision", "backend"):
        p.add_argument(f"--{k}", help=f"comma-separated {k} values")
    for k in STUDY_PHYSICS:     # the formulations beyond DualSPHysics', swept beside it
        p.add_argument(f"--{k.replace('_', '-')}", dest=k, help=f"comma-separated [physics] {k} values")
    p.add_argument("--base", help="baseline physics fields the variants depart from, KEY=VALUE[,KEY=VALUE] "
                                  "(e.g. integrator=symplectic)")
    p.add_argument("--out", help="directory (default out/study/<case>)")
    p.add_argument("--target-error", type=float, help="name the cheapest configuration with error <= E")
    p.add_argument("--from-csv", help="skip the runs: read an earlier study CSV")
    p.add_argument("--quiet", action="store_true", help="no progress output (each run's line still printed)")

    p = sub.add_parser("plot", help="figures from a run")
    psub = p.add_subparsers(dest="what", parser_class=_Parser)
    psub.required = True
    q = psub.add_parser("snapshot", help="one frame as a scatter plot")
    q.add_argument("outdir")
    q.add_argument("--time", type=float)
    q.add_argument("--field", default="pressure")
    q.add_argument("--output", "-o")
    q = psub.add_parser("scene3d", help="one frame of a 3D run in 3D (fluid coloured by a field)")
    q.add_argument("outdir")
    q.add_argument("--time", type=float)
    q.add_argument("--field", default="speed")
    q.add_argument("--output", "-o")
    q = psub.add_parser("forces", help="/forces (and /probes heights) time series")
    q.add_argument("outdir")
    q.add_argument("--output", "-o")
    q = psub.add_parser("stability", help="stability map from a small sweep: CFL x coefsound (--map cfl) "
                        "or impact speed x wall model (--map penetration)")
    q.add_argument("--map", choices=("cfl", "penetration"), default="cfl",
                   help="cfl: elliptical drop, CFL x coefsound (default); penetration: slab against a floor, "
                        "impact speed x wall model")
    q.add_argument("--cfl", default="0.1,0.2,0.4,0.8,1.6", help="--map cfl: comma-separated CFL values")
    q.add_argument("--coefsound", default="5,10,20", help="--map cfl: comma-separated coefsound values")
    q.add_argument("--steps", type=int, default=300, help="--map cfl: steps per run")
    q.add_argument("--speeds", default="5,10,20,40", help="--map penetration: comma-separated impact speeds [m/s]")
    q.add_argument("--models", default="dbc-1,dbc-3,mdbc-1,mdbc-3",
                   help="--map penetration: comma-separated wall models, BOUNDARY-LAYERS "
                        "(dbc-1, dbc-3, mdbc-1, mdbc-3)")
    q.add_argument("--dp", type=float, default=0.02, help="--map penetration: particle spacing [m]")
    q.add_argument("--travel", type=float, default=0.3,
                   help="--map penetration: run until the slab would have moved this far [m] (t = travel/speed)")
    q.add_argument("--output", "-o", help="PNG path (default stability.png, or penetration_map.png)")
    for name, helptext in (("timeline", "per-rank Gantt chart of the tasks (paper Fig. 2)"),
                           ("breakdown", "share of each task per rank (paper Figs. 11-12)"),
                           ("balance", "fluid share and force time per rank over time (paper Figs. 5-6)")):
        q = psub.add_parser(name, help=helptext)
        q.add_argument("outdir")
        q.add_argument("--output", "-o")
        if name == "timeline":
            q.add_argument("--steps", default="last3", help="'last3' (default), 'all' or A:B")
    q = psub.add_parser("efficiency", help="parallel efficiency E against ranks (paper Figs. 8-9)")
    q.add_argument("outdir", metavar="FILE.json|OUTDIR")
    q.add_argument("--output", "-o")
    return ap


def _rank_speed(text):
    if not text:
        return None
    try:
        speeds = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"--rank-speed: expected comma-separated numbers, got {text!r}") from None
    for v in speeds:
        check_flag("--rank-speed", v)
    return speeds


def _faults(flag, text):
    """--duplicate/--loss: '0.01' (a probability) or '5,17' (message numbers)."""
    try:
        if any(c in text for c in ".eEnN"):   # a probability (nan and inf are refused by its range)
            return check_flag(f"--{flag}", float(text))
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"--{flag}: expected a probability (e.g. 0.01) or comma-separated message "
                         f"numbers (e.g. 5,17), got {text!r}") from None


def _comm_options(args):
    opts = {}
    rs = _rank_speed(getattr(args, "rank_speed", None))
    if rs is not None:
        opts["rank_speed"] = rs
    for flag in ("duplicate", "loss"):
        if getattr(args, flag, None) is not None:
            opts[flag] = _faults(flag, getattr(args, flag))
    for flag in ("seed", "watchdog", "halo_transport"):
        if getattr(args, flag, None) is not None:
            opts[flag] = getattr(args, flag)
    if opts.get("seed") is not None:
        check_flag("--seed", opts["seed"], integer=True)
    if opts.get("watchdog") is not None:
        check_flag("--watchdog", opts["watchdog"])
    return opts


def _preflight(args, opts) -> None:
    """`run`/`bench`: numbers of the flags in range, every flag applying to --comm, the
    backend able to run here; one line each, before any work (sphgraph.preflight)."""
    from .preflight import check_backend, check_comm
    for flag, value, integer in (("--dp", args.dp, False), ("--end-time", getattr(args, "end_time", None), False),
                                 ("--max-steps", getattr(args, "max_steps", None), True),
                                 ("--steps", getattr(args, "steps", None), True),
                                 ("--warmup", getattr(args, "warmup", None), True)):
        if value is not None:
            check_flag(flag, value, integer=integer)
    check_comm(args.comm, args.ranks, opts)
    check_backend(args.backend)


def cmd_run(args) -> int:
    opts = _comm_options(args)
    _preflight(args, opts)
    from .solver import run
    res = run(args.scene, backend=args.backend, comm=args.comm, ranks=args.ranks, schedule=args.schedule,
              out=args.out, overwrite=args.overwrite, precision=args.precision, end_time=args.end_time,
              max_steps=args.max_steps, dp=args.dp, progress=not args.quiet,
              comm_options=opts, checkpoint_every=args.checkpoint_every,
              restart=args.restart, walltime=args.walltime, invariants=not args.no_invariants,
              balance=_balance_flags(args))
    if res.stopped is not None and _is_root(res):
        print(f"sphgraph: stopped by {res.stopped} at step {res.steps} (t = {res.time:.6g} s); checkpoint "
              f"{res.checkpoint}; continue with: sphgraph run {args.scene} --restart {res.out_dir}",
              file=sys.stderr)
        return 0
    if res.out_dir is not None and not args.quiet and _is_root(res):
        print(f"{res.steps} steps to t = {res.time:.4f} s in {res.wall_s:.1f} s "
              f"({res.steps_per_s:.0f} steps/s after the first step; first step {res.compile_s:.2f} s); "
              f"{res.particles} particles; output {res.out_dir}/output.h5", file=sys.stderr)
    _print_exclusions(res, args.quiet)
    return 0


def _print_exclusions(res, quiet) -> None:
    """The run's exclusions (/exclusions of output.h5), one line: always when there are any."""
    from .errors import InputError
    from .features import exclusion_summary
    from .io import read_group
    if res.out_dir is None or not _is_root(res):
        return
    try:
        rows = read_group(res.out_dir, "exclusions")
    except InputError:      # [domain] exclude_outside = false: no group
        return
    if len(rows["id"]) or not quiet:
        print(f"sphgraph: {exclusion_summary(rows, res.fluid_particles)}", file=sys.stderr)


def _is_root(res):
    return res.out_dir is None or os.environ.get("PMI_RANK", "0") == "0"


def cmd_bench(args) -> int:
    opts = _comm_options(args)
    _preflight(args, opts)
    from .bench import bench
    out = bench(args.scene, steps=args.steps, warmup=args.warmup, backend=args.backend, comm=args.comm,
                ranks=args.ranks, schedule=args.schedule, precision=args.precision, dp=args.dp,
                comm_options=opts, balance=_balance_flags(args))
    if out is not None:
        print(json.dumps(out))
    return 0


def cmd_info(args) -> int:
    import h5py
    import networkx
    import numba
    import numpy
    from . import __version__
    from .registry import names
    print(f"sphgraph {__version__}")
    print(f"python {sys.version.split()[0]}, numpy {numpy.__version__}, numba {numba.__version__}, "
          f"h5py {h5py.__version__} (HDF5 {h5py.version.hdf5_version}), networkx {networkx.__version__}")
    print(f"numba threads: {numba.get_num_threads()} (threading layer: {numba.config.THREADING_LAYER})")
    print(f"compute backends: {', '.join(names('compute'))}")
    print(f"comm backends: {', '.join(names('comm'))}")
    try:
        import mpi4py
        print(f"mpi4py {mpi4py.__version__}")
    except ImportError:
        print("mpi4py: not installed (pip install sphgraph[mpi])")
    try:
        from numba import cuda
        print(f"cuda available: {cuda.is_available()}")
    except Exception as e:  # noqa: BLE001 - informational only
        print(f"cuda: unavailable ({e})")
    from .schedule import shipped
    print(f"schedules: {', '.join(shipped())}")
    return 0


def cmd_schedule(args) -> int:
    from .schedule import Schedule
    sched = Schedule.load(args.file if args.action == "validate" else args.name)
    if args.action == "validate":
        stages = [1, 2] if args.integrator is None else [1 if args.integrator == "verlet" else 2]
        for st in stages:
            for r in sorted({1, args.ranks}):
                sched.validate(r, st, rebalance=bool(sched.rebalance))
        print(f"{sched.source}: valid for 1 and {args.ranks} ranks, "
              f"{' and '.join('Verlet' if s == 1 else 'Symplectic' for s in stages)}")
        return 0
    integrator = args.integrator or "verlet"
    kinds, ring = frozenset(), False
    if args.scene is not None:   # the scene's feature tasks, for its split axis on --ranks ranks
        from .features import scene_layout
        from .scene import Scene
        scene = Scene.from_toml(args.scene)
        kinds, ring = scene_layout(scene, args.ranks)
        integrator = args.integrator or scene.physics.integrator
    stages = 1 if integrator == "verlet" else 2
    sched.validate(args.ranks, stages, features=kinds, ring=ring)
    print(sched.describe(ranks=args.ranks, stages=stages, rank=min(args.rank, args.ranks - 1),
                         features=kinds, ring=ring))
    if args.plot:
        from .plots import plot_schedule_graph
        path = plot_schedule_graph(sched, args.ranks, stages, args.plot, kinds, ring)
        print(f"wrote {path}")
    return 0


def cmd_trace(args) -> int:
    from .trace import write_chrome_trace
    path = write_chrome_trace(args.outdir, args.chrome)
    print(f"wrote {path}")
    return 0


def cmd_plot(args) -> int:
    from . import plots
    if args.what == "stability" and args.map == "penetration":
        from .stability import model_costs, penetration_map
        models = [m.strip() for m in args.models.split(",") if m.strip()]
        cells = penetration_map(_floats(args.speeds, "--speeds"), models, travel=args.travel, dp=args.dp)
        for c in cells:
            print(f"{c['model']} {c['speed']:g} m/s: {c['verdict']}" + (f" ({c['detail']})" if c["detail"] else "")
                  + f", {c['ms_per_step']:.3g} ms/step")
        for m, ms in model_costs(cells).items():
            print(f"{m}: {ms:.3g} ms/step (median over speeds)")
        path = plots.plot_penetration(cells, args.output or "penetration_map.png")
    elif args.what == "stability":
        from .stability import stability_map
        cells = stability_map(_floats(args.cfl, "--cfl"), _floats(args.coefsound, "--coefsound"), steps=args.steps)
        for c in cells:
            print(f"cfl {c['cfl']:g} coefsound {c['coefsound']:g}: {c['verdict']}"
                  + (f" ({c['detail']})" if c.get("detail") else ""))
        path = plots.plot_stability(cells, args.output or "stability.png")
    elif args.what == "snapshot":
        path = plots.plot_snapshot(args.outdir, time=args.time, field=args.field, path=args.output)
    elif args.what == "scene3d":
        path = plots.plot_scene3d(args.outdir, time=args.time, field=args.field, path=args.output)
    elif args.what == "forces":
        path = plots.plot_forces(args.outdir, path=args.output)
    elif args.what == "balance":
        path = plots.plot_balance(args.outdir, path=args.output)
    elif args.what == "efficiency":
        path = plots.plot_efficiency(args.outdir, path=args.output)
    elif args.what == "timeline":
        path = plots.plot_timeline(args.outdir, path=args.output, steps=args.steps)
    else:
        path = plots.plot_breakdown(args.outdir, path=args.output)
    print(f"wrote {path}")
    return 0


def _floats(text, flag):
    try:
        return [float(x) for x in str(text).split(",") if x.strip()]
    except ValueError:
        raise InputError(f"{flag}: expected comma-separated numbers, got {text!r}") from None


def _overrides(items):
    out = {}
    for it in items:
        k, sep, v = it.partition("=")
        if not sep or not k:
            raise InputError(f"--set: expected KEY=VALUE, got {it!r}")
        for conv in (int, float, str):
            try:
                out[k] = conv(v)
                break
            except ValueError:
                continue
    return out


def cmd_validate(args) -> int:
    from .validation.cases import CaseStopped, list_cases, load_case, run_case
    if args.list or not args.case:
        for name in list_cases():
            print(f"{name:12s} {load_case(name).title}")
        return 0
    try:
        res = run_case(args.case, dp=args.dp, backend=args.backend, precision=args.precision,
                       overrides=_overrides(args.set), out=args.out,
                       params={"boundary": args.boundary} if args.boundary else None,
                       progress=not args.quiet)
    except CaseStopped as e:    # what the run measured before it stopped, then the failure (exit 1)
        print(e.result.report())
        if e.result.plot_path:
            print(f"wrote {e.result.plot_path}")
        raise
    print(res.report())
    if res.plot_path:
        print(f"wrote {res.plot_path}")
    return 0 if res.ok else 1


# [physics] fields `sphgraph study` sweeps besides its own axes (sphgraph.study: extra axes)
STUDY_PHYSICS = ("riemann", "riemann_wall", "riemann_jump", "diffusion_time", "boundary", "shifting", "visc_alpha")

def _base_value(default, v: str):
    """A --base value in its field's type (the scene's checks then judge its range): a number
    for a numeric field (one that defaults to None, e.g. hswl, where it reads as one), else the
    string."""
    if isinstance(default, bool) or not isinstance(default, (int, float, type(None))):
        return v
    try:
        return int(v) if isinstance(default, int) else float(v)
    except ValueError:
        return v


def cmd_study(args) -> int:
    from .study import run_study
    axes = {k: getattr(args, k).split(",")
            for k in ("integrator", "kernel", "diffusion", "precision", "backend", *STUDY_PHYSICS) if getattr(args, k)}
    if "visc_alpha" in axes:
        axes["visc_alpha"] = _floats(args.visc_alpha, "--visc-alpha")
    from .config import PhysicsConfig
    base = {}
    for item in (args.base.split(",") if args.base else []):
        k, eq, v = item.partition("=")
        if not eq or not k or not v:
            raise InputError(f"--base: expected KEY=VALUE[,KEY=VALUE...], got {args.base!r}")
        k = k.strip()
        if k not in PhysicsConfig.__dataclass_fields__:
            raise InputError(f"--base: {k!r} is not a [physics] field: expected one of "
                             f"{', '.join(sorted(PhysicsConfig.__dataclass_fields__))}")
        base[k] = _base_value(PhysicsConfig.__dataclass_fields__[k].default, v.strip())
    out = run_study(args.case, dps=_floats(args.dp, "--dp") if args.dp else None, axes=axes, out=args.out,
                    target_error=args.target_error, from_csv=args.from_csv, base=base, progress=not args.quiet)
    print(out["summary"])
    return 0 if args.target_error is None or out.get("best") is not None else 1


COMMANDS = {"validate": cmd_validate, "study": cmd_study, "run": cmd_run, "bench": cmd_bench, "info": cmd_info, "schedule": cmd_schedule,
            "trace": cmd_trace, "plot": cmd_plot}


def main(argv=None) -> int:
    """The command line; returns the exit code. SIGINT at any moment (start-up, a step, a
    write, the report of another error) ends with one line and 130."""
    if threading.current_thread() is threading.main_thread():
        # the command leaves at once (_sigint_exit); a library caller gets KeyboardInterrupt
        signal.signal(signal.SIGINT, _sigint_exit if COMMAND else signal.default_int_handler)
    try:
        code = _main(argv)
    except KeyboardInterrupt:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)   # a second ^C must not interrupt the report
        print(_INTERRUPTED, file=sys.stderr)
        return 130
    if COMMAND and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)   # the work is done: ^C in the exit must not print
    return code


_INTERRUPTED = "sphgraph: interrupted (SIGINT); output written so far stays readable"


def _sigint_exit(signum, frame):
    """SIGINT in the command: one line, the temporary file of a write in progress removed,
    exit 130 -- now, wherever the main thread is. A KeyboardInterrupt would be raised at the
    next bytecode, which may be a finaliser or a ctypes callback (llvmlite's), where Python
    prints it and swallows it, and the run goes on. Every finished file is complete
    (writes are atomic), so leaving at once is as safe as a kill."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        # no import here: the main thread may hold the import lock; and the module may be
        # half imported (the signal came during its import), without the function yet and
        # with nothing written through it
        remove = getattr(sys.modules.get("sphgraph.files"), "remove_in_flight", None)
        if remove is not None:
            remove()
        if _root():
            os.write(2, (_INTERRUPTED + "\n").encode())
    finally:
        os._exit(130)


def _root() -> bool:
    return os.environ.get("PMI_RANK", "0") == "0"   # under MPI every rank raises it: print once


def _main(argv) -> int:
    try:
        args = build_parser().parse_args(argv)
        return COMMANDS[args.cmd](args)
    except InputError as e:
        lines = str(e).splitlines() or [type(e).__name__]
        first = (sys.argv[1:] if argv is None else list(argv))[:1]
        if len(lines) > 1 and first and first[0] in ("run", "bench"):   # run: one line (DESIGN.md §5)
            lines = [f"{lines[0]} (and {len(lines) - 1} more problem(s): see `sphgraph schedule validate`)"]
        if _root():
            for line in lines:
                print(f"sphgraph: error: {line}", file=sys.stderr)
        return 2
    except NumericalError as e:
        if _root():
            print(f"sphgraph: numerical failure: {e}", file=sys.stderr)
        return 1
    except DiskFullError as e:   # the writing rank (the root) reports it
        print(f"sphgraph: {e}", file=sys.stderr)
        return e.exit_code
    except CommError as e:   # one line: which ranks, task or tag, step
        print(f"sphgraph: communication error: {e}", file=sys.stderr)
        return e.exit_code
    except SphgraphError as e:
        return _internal(e)
    except BrokenPipeError:   # the reader closed stdout (`sphgraph validate --list | head`): not our failure
        # point stdout at devnull so that the interpreter's flush at exit does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141            # 128 + SIGPIPE, as a shell reports a pipe's writer
    except Exception as e:  # noqa: BLE001 - exit 3 with the traceback in a log, never a bare crash
        return _internal(e)


def _internal(e) -> int:
    fd, path = tempfile.mkstemp(prefix="sphgraph-error-", suffix=".log")
    with os.fdopen(fd, "w") as f:
        traceback.print_exc(file=f)
    print(f"sphgraph: internal error: {type(e).__name__}: {e} (traceback in {path})", file=sys.stderr)
    return 3
