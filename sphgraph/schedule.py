"""Schedules: the overlap policy as data (TOML files in `sphgraph/schedules/`).

Format (documented for users in docs/schedules.md):

    format = 1
    description = "..."
    order = ["send_displaced", "build_cells", "recv_displaced", "send_edges",
             "forces_interior", "recv_halo_1", "forces_halo_1", "recv_halo_2",
             "forces_halo_2", "dt_local", "dt_allreduce", "integrate", "rebalance"]
    halo_order = [1, 2]          # [2, 1] swaps every halo_1 and halo_2 task
    [lanes]                      # optional: lane of a task kind (compute | comm | copy)
    send_edges = "comm"
    [rebalance]                  # optional
    every = 50
    threshold = 0.03
    policy = "particles"

`order` is the issue order of one step. The span from the first to the last
per-stage kind is the stage block: a Symplectic step issues it twice (stage 1
and 2; dt tasks only in stage 1, shifting, damping and wrapping only in the last).
Kinds a rank's role lacks (halos at the ends, everything multi-rank on one rank) are
skipped. A scene feature's task that `order` does not name goes where
`graph.kinds.PLACEMENT` says (after the task it follows, e.g. `shift_apply` right after
`integrate`), so a schedule written without it runs that feature; naming it places it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from .balance import expected_form
from .errors import InputError
from .files import SCHEDULE_LIMIT, parse_toml, read_text
from .graph.build import find_deadlock, multi_rank_graph, order_violations, rank_graph
from .graph.kinds import CONDITIONAL, LANES, PLACEMENT, TaskKind
from .graph.task import Task, UserTask
from .graph.tasks import applicable, canonical_tasks, in_stage

TOP_KEYS = ("format", "name", "description", "order", "halo_order", "lanes", "rebalance")
REBALANCE_KEYS = {"every": int, "threshold": float, "policy": str}
POLICIES = ("particles", "time", "memory")


class ScheduleError(InputError):
    """One or more problems, one line each."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("\n".join(problems))


def shipped() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("sphgraph.schedules").iterdir()
                  if p.name.endswith(".toml"))


@dataclass
class Schedule:
    name: str
    order: list[str]
    source: str = "<dict>"
    description: str = ""
    halo_order: tuple = (1, 2)
    lanes: dict = field(default_factory=dict)
    rebalance: dict = field(default_factory=dict)
    text: str = ""

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, spec) -> "Schedule":
        """A shipped name, a path to a TOML file, a dict, or a Schedule."""
        if isinstance(spec, Schedule):
            return spec
        if isinstance(spec, dict):
            return cls.from_dict(spec, source="<dict>")
        spec = str(spec)
        path = Path(spec)
        if not path.suffix and not path.exists():
            if spec not in shipped():
                raise InputError(f"--schedule: unknown schedule {spec!r}: expected a file or one of "
                                 f"{', '.join(shipped())}")
            text = resources.files("sphgraph.schedules").joinpath(spec + ".toml").read_text()
            return cls.from_text(text, source=f"{spec}.toml", name=spec)
        text = read_text(path, SCHEDULE_LIMIT, "schedule file")
        return cls.from_text(text, source=spec, name=path.stem)

    @classmethod
    def from_text(cls, text: str, source: str, name: str | None = None) -> "Schedule":
        d = parse_toml(text, source)
        s = cls.from_dict(d, source=source, name=name)
        s.text = text
        return s

    @classmethod
    def from_dict(cls, d: dict, source: str = "<dict>", name: str | None = None) -> "Schedule":
        problems = []
        if not isinstance(d, dict):
            raise ScheduleError([f"{source}: expected a table of schedule keys"])
        for k in d:
            if k not in TOP_KEYS:
                problems.append(f"{source}: {k}: unknown key: expected one of {', '.join(TOP_KEYS)}")
        if d.get("format") != 1:
            problems.append(f"{source}: format: expected 1, got {d.get('format')!r}")
        order = d.get("order")
        if not isinstance(order, list) or not order or not all(isinstance(x, str) for x in order):
            problems.append(f"{source}: order: expected a non-empty list of task names, got {order!r}")
            order = []
        halo = d.get("halo_order", [1, 2])
        if not isinstance(halo, list) or not all(type(x) is int for x in halo) or sorted(halo) != [1, 2]:
            problems.append(f"{source}: halo_order: expected [1, 2] or [2, 1], got {halo!r}")
            halo = [1, 2]
        lanes = d.get("lanes", {})
        if not isinstance(lanes, dict):
            problems.append(f"{source}: lanes: expected a table of task = lane, got {lanes!r}")
            lanes = {}
        for k, v in lanes.items():
            if v not in LANES:
                problems.append(f"{source}: lanes.{k}: unknown lane {v!r}: expected one of {', '.join(LANES)}")
        reb = d.get("rebalance", {})
        if not isinstance(reb, dict):
            problems.append(f"{source}: rebalance: expected a table, got {reb!r}")
            reb = {}
        for k, v in reb.items():
            typ = REBALANCE_KEYS.get(k)
            if typ is None:
                problems.append(f"{source}: rebalance.{k}: unknown key: expected one of "
                                f"{', '.join(REBALANCE_KEYS)}")
            elif typ is not str and expected_form(k, v) is not None:   # the range of balance.KEY
                problems.append(f"{source}: rebalance.{k}: expected {expected_form(k, v)}, got {v!r}")
            elif k == "policy" and v not in POLICIES:
                problems.append(f"{source}: rebalance.policy: expected one of {', '.join(POLICIES)}, got {v!r}")
        if problems:
            # report the task-name problems of the same file too, so one run lists them all
            # (user tasks are declared from Python only, so any name not a kind is listed)
            problems += _name_problems(source, order, lanes, set())
            raise ScheduleError(list(dict.fromkeys(problems)))
        return cls(name=name or d.get("name") or "custom", order=list(order), source=source,
                   description=d.get("description", ""), halo_order=tuple(halo), lanes=dict(lanes),
                   rebalance=dict(reb))

    # ------------------------------------------------------------------ expansion
    def _swapped(self, label: str) -> str:
        if tuple(self.halo_order) == (2, 1):
            if label.endswith("_1"):
                return label[:-2] + "_2"
            if label.endswith("_2"):
                return label[:-2] + "_1"
        return label

    def program(self, rank: int, nranks: int, stages: int, user_tasks=(), rebalance=False,
                motion=False, ring=False, features=()) -> list[Task]:
        """The ordered task instances of one rank (skipping kinds its role lacks;
        `rebalance` places that conditional kind, `features` the scene features' kinds
        (`sphgraph.features.Features.kinds`; `motion` adds the ``motion`` kind); `ring`:
        the slab chain is closed, the periodic split axis of sphgraph.periodic)."""
        return self._expand(rank, nranks, stages, {u.name: u for u in user_tasks}, rebalance,
                            _features(features, motion), ring)[0]

    def labels(self, features=()) -> list[str]:
        """The order's labels with the halo order applied and the tasks of `features` that
        it does not name placed (`graph.kinds.PLACEMENT`)."""
        labels = [self._swapped(x) for x in self.order]
        for kind, (where, anchors) in PLACEMENT.items():
            if kind not in features or kind.label in labels:
                continue
            at = [labels.index(a) for a in anchors if a in labels]
            if where == "end" or not at:   # no anchor: the validator names what is missing
                labels.append(kind.label)
            else:
                labels.insert(max(at) + 1 if where == "after" else min(at), kind.label)
        return labels

    def _expand(self, rank, nranks, stages, users: dict, rebalance, features=frozenset(), ring=False):
        from .graph.tasks import make_task
        labels = self.labels(features)

        def per_stage(label):
            if label in users:
                return users[label].per_stage
            return TaskKind.from_label(label).per_stage

        idx = [i for i, x in enumerate(labels) if per_stage(x)]
        first, last = (idx[0], idx[-1]) if idx else (len(labels), len(labels) - 1)
        blocks = [(labels[:first], None)]
        for s in range(1, stages + 1):
            blocks.append((labels[first:last + 1], s))
        blocks.append((labels[last + 1:], None))
        prog = []
        for labs, s in blocks:
            for lab in labs:
                if lab in users:
                    u = users[lab]
                    st = s if u.per_stage else None
                    if not u.per_stage and s not in (None, 1):
                        continue
                    prog.append(Task(lab, st, reads=tuple(u.reads), writes=tuple(u.writes),
                                     accumulates=tuple(u.accumulates),
                                     lane=self.lanes.get(lab, u.lane), fn=u.fn))
                    continue
                kind = TaskKind.from_label(lab)
                if kind is TaskKind.REBALANCE and not rebalance:
                    continue
                if kind in CONDITIONAL and kind is not TaskKind.REBALANCE and kind not in features:
                    continue
                if not applicable(kind, rank, nranks, ring):
                    continue
                if s is not None and not in_stage(kind, s, stages):
                    continue  # dt tasks: once per step; shifting, damping, wrap: last stage
                prog.append(make_task(kind, s if kind.per_stage else None, rank, nranks,
                                      lane=self.lanes.get(lab), ring=ring))
        return prog, labels

    def canonical(self, rank, nranks, stages, user_tasks=(), rebalance=False, motion=False,
                  ring=False, features=()) -> list[Task]:
        """The reference order with user tasks inserted where the schedule puts them."""
        features = _features(features, motion)
        prog = self.program(rank, nranks, stages, user_tasks, rebalance, ring=ring, features=features)
        builtin = canonical_tasks(rank, nranks, stages, rebalance, features, ring)
        users = [t for t in prog if not isinstance(t.kind, TaskKind)]
        out = list(builtin)
        for u in users:
            i = prog.index(u)
            before = [t for t in prog[:i] if isinstance(t.kind, TaskKind) or t in out]
            anchor = before[-1] if before else None
            out.insert(out.index(anchor) + 1 if anchor in out else 0, u)
        return out

    # ------------------------------------------------------------------ validation
    def validate(self, ranks: int = 1, stages: int = 1, user_tasks=(), rebalance=False, motion=False,
                 ring=False, features=()) -> None:
        """Prove the schedule for `ranks` ranks; raise ScheduleError listing every problem."""
        features = _features(features, motion)
        src = self.source
        problems = _name_problems(src, self.order, self.lanes, {u.name for u in user_tasks})
        if problems:
            raise ScheduleError(problems)
        programs = {}
        for r in range(ranks):
            prog = self.program(r, ranks, stages, user_tasks, rebalance, ring=ring, features=features)
            programs[r] = prog
            names = [t.name for t in prog]
            for t in canonical_tasks(r, ranks, stages, rebalance, features, ring):
                if t.name not in names:
                    problems.append(f"{src}: order: missing task {t.label!r} (needed as {t.name} on rank {r} "
                                    f"of {ranks})")
            g = rank_graph(self.canonical(r, ranks, stages, user_tasks, rebalance, ring=ring,
                                          features=features))
            for v in order_violations(g, names):
                problems.append(f"{src}: order: rank {r}: {v}")
        problems = list(dict.fromkeys(problems))
        if problems:
            raise ScheduleError(problems)
        cyc = find_deadlock(multi_rank_graph(programs))
        if cyc:
            raise ScheduleError([f"{src}: deadlock on {ranks} ranks: {cyc}"])

    def describe(self, ranks=1, stages=1, rank=0, features=(), ring=False) -> str:
        """Ordered tasks per lane for one rank (`sphgraph schedule show`); `features`: the
        feature kinds of a scene (`sphgraph.features.task_kinds`)."""
        prog = self.program(rank, ranks, stages, rebalance=bool(self.rebalance), ring=ring,
                            features=features)
        lines = [f"schedule {self.name} ({self.source}): rank {rank} of {ranks}, {stages} force stage(s)"]
        if self.description:
            lines.append(f"  {self.description}")
        for lane in LANES:
            ts = [f"{i:2d} {t.name}" for i, t in enumerate(prog) if t.lane == lane]
            lines.append(f"  [{lane}]")
            lines.extend(f"    {x}" for x in ts or ["(none)"])
        return "\n".join(lines)


def _features(features, motion: bool = False) -> frozenset:
    """The feature kinds to place: `features` (kinds or labels), ``motion`` added when asked."""
    out = {TaskKind.from_label(k) if isinstance(k, str) else k for k in features}
    if motion:
        out.add(TaskKind.MOTION)
    return frozenset(out)


def _name_problems(src: str, order, lanes, users: set) -> list[str]:
    """Duplicated or unknown task names in `order` and unknown tasks in `lanes`."""
    problems, seen = [], set()
    for lab in order:
        if lab in seen:
            problems.append(f"{src}: order: duplicated task {lab!r}: each task is placed exactly once")
        seen.add(lab)
        if lab not in users and lab not in TaskKind.labels():
            problems.append(f"{src}: order: unknown task {lab!r}: expected one of "
                            f"{', '.join(TaskKind.labels())} or a user task")
    for lab in lanes:
        if lab not in users and lab not in TaskKind.labels():
            problems.append(f"{src}: lanes.{lab}: unknown task: expected one of {', '.join(TaskKind.labels())}")
    return problems
