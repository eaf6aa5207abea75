"""Mock MPI: N ranks in one process, run by a deterministic discrete-event engine.

Every rank has a virtual clock. The engine runs one runnable rank's next task at a
time. A task is runnable unless it is a receive whose message has not been *sent* yet,
or a collective that not every rank has reached. Which runnable rank goes next is the
`order`: "clock", the one with the smallest clock (ties: lowest rank); "eager", the
rank that ran last while it can, then the smallest clock, and a task that waits for its
rank's device to read a result (`Task.reads_device`: dt, the check) only when no rank
has another task to run. The virtual times and every rank's results do not depend on the
order (a task starts at its own rank's clock and its messages' arrivals); the wall clock
does: on one GPU, "eager" issues a rank's tasks up to its next wait in one go, so its
kernels (the interior forces above all) reach the device while the host issues the next
rank's, and every rank's halo forces and integration are queued before the host first
waits for the device, where "clock" interleaves the ranks task by task and the device
idles while the host issues each rank's small tasks between its waits. The
random draws of `delay`, `reorder`, `duplicate` and `loss` follow the order in which
messages are posted, so "auto" (the default) is "clock" with any of those set and
"eager" otherwise. Then:

  send        the payload is frozen (deep-copied) and posted with
              arrival = post time + latency + bytes / bandwidth (+ random delay);
  receive     completes at max(rank clock, arrival) + its own cost;
  collective  (dt_allreduce) completes on every rank at max(arrival clocks) +
              2 ceil(log2 N) latency + its cost; the value is the min over ranks.

Durations (`timing`): "model", the cost model (`perfmodel.CostModel`, per task kind
a + b·particles + c·pairs) divided by `rank_speed[rank]`; "wall", the body's measured
wall time divided by `rank_speed[rank]`; "device", the task's device time as the
compute backend measured it (`ComputeBackend.task_device_seconds`: numba-cuda's timing
events around each task run alone on the device -- the mock's ranks share one device, whose
other ranks' kernels would otherwise stretch a rank's times; the model without a device
clock); "auto" (the default), the model, and "device" inside `device_clock_window(True)` on
a backend with a device clock (`sphgraph bench` opens one after its timed steps).

Options (constructor keywords, `comm_options` of `sphgraph.run` / `Simulation`):
  rank_speed  list of relative throughputs (2 = twice as fast), default all 1
  latency, bandwidth   network model (s, bytes/s)
  delay       extra uniform random delay in [0, delay) s on every message (seeded)
  reorder     True: extra random delays large enough to deliver messages of different
              (source, tag) pairs out of order; within one pair MPI's non-overtaking
              rule is kept (a message never arrives before an earlier one of its pair)
  duplicate   messages delivered twice: a probability per message (a number in [0, 1]) or
              the messages' numbers (a list of ints; 1 = the run's first message posted)
  loss        messages dropped, chosen the same way; `duplicate` and `loss` are seeded by
              `seed` (their own stream: delays do not change with them)
  seed        random seed of delay / reorder / duplicate / loss
  watchdog    virtual seconds a rank may wait in one receive or collective before the run
              stops with CommError naming the rank, task, step and peer (0 = off, the default)
  order       "auto" (default), "clock" or "eager": which runnable rank runs next (above)
  timing      "auto" (default), "model", "wall" or "device" (see Durations)
  mode        "execute" (real kernels) or "predict" (modelled costs, no task bodies)
  costs       cost model: None (shipped fit), a dict {kind: [a, b, c]}, a TOML path

When no rank can run and not all have finished, `DeadlockError` names what every
rank waits on; the engine never hangs.

Every message carries a sequence number per (source, dest, tag) (`base.SeqCheck`);
the receiver checks it. A message seen twice (in a receive, or still queued when the
step ends) raises `CommError` "message duplicated"; a jump in the numbers, or a rank
waiting for a message its sender numbered but that never came (the engine runs out
of events), raises `CommError` "message lost". Both name the ranks, tag, task and step.
"""
from __future__ import annotations

import copy
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from sphgraph.errors import CommError, DeadlockError, InputError
from sphgraph.errors import SphgraphError as InternalError
from sphgraph.registry import register
from sphgraph.wire import WirePayload, payload_nbytes

from sphgraph.perfmodel import (DEFAULT_BANDWIDTH, DEFAULT_LATENCY, CostModel, allreduce_seconds,
                                pairs_per_particle, step_pricing, task_features)

from .base import CommBackend, SeqCheck, where

REORDER_WINDOW = 1.0e-3   # s of random extra delay when reorder=True and no larger delay is set
COLLECTIVE_TIMEOUT = 300.0


@dataclass
class _Msg:
    payload: object
    nbytes: int
    arrival: float
    seq: int                  # per (source, dest, tag), from the sender's SeqCheck
    task: str | None = None   # the sending task and step, for reports
    step: int | None = None


class _Faults:
    """Which messages a fault hits: a probability per message or explicit message numbers."""

    def __init__(self, name, value, rng):
        self.rng = rng
        self.p, self.numbers = 0.0, frozenset()
        if isinstance(value, (list, tuple, set, frozenset)):
            if not all(isinstance(k, (int, np.integer)) and not isinstance(k, bool) and k >= 1 for k in value):
                raise InputError(f"--comm mock: {name}: expected message numbers >= 1, got {value!r}")
            self.numbers = frozenset(int(k) for k in value)
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and 0.0 <= value <= 1.0:
            self.p = float(value)
        else:
            raise InputError(f"--comm mock: {name}: expected a probability in [0, 1] or a list of "
                             f"message numbers >= 1, got {value!r}")

    def __bool__(self):
        return bool(self.p or self.numbers)

    def hits(self, number: int) -> bool:
        if self.numbers:
            return number in self.numbers
        return self.p > 0 and self.rng.random() < self.p



_SHARED = (int, float, bool, str, bytes, type(None), np.generic)   # immutable: no copy needed


def freeze(payload):
    """A private copy: later changes by the sender never reach the receiver. Arrays and
    the arrays among a payload's attributes are copied, immutable values shared, anything
    else deep-copied; a WirePayload copies itself as its type says (`__deepcopy__`)."""
    if isinstance(payload, np.ndarray):
        return payload.copy()
    d = getattr(payload, "__dict__", None)
    if d is None or isinstance(payload, WirePayload):
        return copy.deepcopy(payload)
    out = copy.copy(payload)
    od = out.__dict__
    for k, v in d.items():
        if isinstance(v, np.ndarray):
            od[k] = v.copy()
        elif not isinstance(v, _SHARED):
            od[k] = copy.deepcopy(v)
    return out


def _rows(payload) -> int:
    if payload is None:
        return 0
    n = getattr(payload, "n", None)
    return int(n) if n is not None else 0


class _Collective:
    """Value exchange among the N threads running one collective task."""

    def __init__(self, n):
        self.n = n
        self.values = [None] * n
        self.barrier = threading.Barrier(n, timeout=COLLECTIVE_TIMEOUT)

    def exchange(self, rank, value) -> list:
        if self.n == 1:
            return [value]
        self.values[rank] = value
        self.barrier.wait()
        out = list(self.values)
        self.barrier.wait()
        return out


class MockEndpoint:
    """What one simulated rank's tasks call (`ctx.comm`)."""

    def __init__(self, engine, rank):
        self.engine = engine
        self.rank = rank
        self.size = engine.n
        self.task = None
        self.inbox = {}       # (source, tag) -> deque of payloads the engine matched for this task
        self.outbox = []      # (dest, tag, payload) posted during this task
        self.collective = None
        self.reduced = None   # a declared reduction's result, computed by the engine (Task.reduce)
        self.received_rows = 0

    def isend(self, dest, tag, payload):
        if not 0 <= dest < self.size or dest == self.rank:
            raise InternalError(f"rank {self.rank}: isend to invalid rank {dest}")
        self.outbox.append((dest, tag, freeze(payload)))

    def recv(self, source, tag):
        q = self.inbox.get((source, tag))
        if q:
            p = q.popleft()
        else:  # an undeclared receive: only legal if the message is already posted
            box = self.engine.mail.get((source, self.rank, tag))
            if not box:
                name = self.task.name if self.task is not None else "?"
                raise DeadlockError(f"rank {self.rank} waits in {name} for a message from rank {source} "
                                    f"(tag {tag}) that the task did not declare and nobody has sent")
            m = box.popleft()
            self.engine.accept(self.rank, source, tag, m, self.task)
            self.engine._late_arrival[self.rank] = max(self.engine._late_arrival[self.rank], m.arrival)
            p = m.payload
        self.received_rows += _rows(p)
        return p

    def _coll(self):
        if self.collective is None:
            name = self.task.name if self.task is not None else "?"
            raise InternalError(f"rank {self.rank}: task {name} calls a collective but is not declared "
                                f"collective")
        return self.collective

    def allreduce_min(self, x):
        if self.reduced is not None:
            return self.reduced
        return min(self._coll().exchange(self.rank, x))

    def allreduce(self, x, op="sum"):
        vals = self._coll().exchange(self.rank, x)
        return _reduce(vals, op)

    def allgather(self, x) -> list:
        return self._coll().exchange(self.rank, x)

    def gather(self, x) -> list | None:
        out = self._coll().exchange(self.rank, x)
        return out if self.rank == 0 else None


def _reduce(vals, op):
    if op in ("min", min):
        return min(vals)
    if op in ("max", max):
        return max(vals)
    if op in ("sum", sum):
        out = vals[0]
        for v in vals[1:]:
            out = out + v
        return out
    raise ValueError(f"unknown reduction {op!r}")


class Engine:
    """The discrete-event core, shared by execute mode and predict mode.

    Clocks persist across steps (`run_*` calls): the virtual time of a run is
    `max(engine.clock)` after its last step.
    """

    def __init__(self, n, latency=DEFAULT_LATENCY, bandwidth=DEFAULT_BANDWIDTH, delay=0.0,
                 reorder=False, seed=0, duplicate=0.0, loss=0.0, watchdog=0.0, order="clock"):
        self.n = n
        self.eager = order == "eager"
        self.latency = float(latency)
        self.bandwidth = float(bandwidth)
        self.delay = float(delay)
        self.reorder = bool(reorder)
        self.rng = np.random.default_rng(seed)
        self.clock = [0.0] * n
        self.mail: dict = {}            # (source, dest, tag) -> deque[_Msg] in send order
        self._last_arrival: dict = {}   # (source, dest, tag) -> arrival of the latest message
        self._last_sent: dict = {}      # (source, dest, tag) -> the latest _Msg posted
        self.seqs = [SeqCheck(r) for r in range(n)]   # each rank's numbering and checks
        frng = np.random.default_rng([int(seed), 1])   # faults: their own stream
        self.duplicate = _Faults("duplicate", duplicate, frng)
        self.loss = _Faults("loss", loss, frng)
        self.watchdog = float(watchdog)
        self.step = None                # the step being run (1-based), for reports
        self._late_arrival = [0.0] * n
        self.messages = 0
        self.bytes = 0
        self.duplicated = 0             # injected faults, for tests and reports
        self.lost = 0

    # -- messages ----------------------------------------------------------------------
    def post(self, src, dest, tag, payload, nbytes, t_post, task=None):
        arrival = t_post + self.latency + nbytes / self.bandwidth
        extra = 0.0
        if self.delay > 0:
            extra += self.rng.uniform(0.0, self.delay)
        if self.reorder:
            extra += self.rng.uniform(0.0, max(self.delay, REORDER_WINDOW))
        arrival += extra
        key = (src, dest, tag)
        arrival = max(arrival, self._last_arrival.get(key, -np.inf))   # non-overtaking in a pair
        self._last_arrival[key] = arrival
        self.messages += 1
        self.bytes += nbytes
        msg = _Msg(payload, nbytes, arrival, self.seqs[src].next_send(dest, tag), task, self.step)
        self._last_sent[key] = msg             # the sender's record of what it sent last
        if self.loss and self.loss.hits(self.messages):
            self.lost += 1                     # numbered by the sender, never delivered
            return
        box = self.mail.setdefault(key, deque())
        box.append(msg)
        if self.duplicate and self.duplicate.hits(self.messages):
            self.duplicated += 1               # the network delivers the same message twice
            box.append(msg)

    def align(self) -> None:
        """Every rank's clock to the latest clock or queued arrival: a virtual barrier where the
        clock changes its source. Durations of one source (the cost model's CPU-fitted seconds)
        leave the ranks' clocks apart by what that source priced differently between them; the
        first waits under the next source (device task times) would carry that gap as if it
        were communication."""
        t = max(self.clock)
        for box in self.mail.values():
            for m in box:
                t = max(t, m.arrival)
        self.clock = [t] * self.n

    def accept(self, rank, source, tag, msg, task=None):
        """The receiver's check of a message's sequence number (CommError on a fault)."""
        self.seqs[rank].accept(source, tag, msg.seq, task.name if task is not None else None, self.step)

    def _check_queues(self):
        """End of a step: a message still queued that repeats one received is a duplicate."""
        for (src, dest, tag), box in self.mail.items():
            for m in box:
                if self.seqs[dest].duplicate(src, tag, m.seq):
                    raise CommError(f"message duplicated: rank {dest} got message #{m.seq} from rank {src} "
                                    f"(tag {tag}, sent{where(m.task, m.step)}) a second time: a copy is "
                                    f"still queued at the end of "
                                    f"{'the step' if self.step is None else f'step {self.step}'}")

    def _lost(self, rank, task, m) -> str | None:
        """A report when `rank` waits in `task` for message `m` that its sender numbered but
        that never arrived (the engine has run out of events), else None."""
        src = rank + m.peer
        box = self.mail.get((src, rank, m.tag), ())
        if self.seqs[rank].outstanding(src, m.tag, self.seqs[src], len(box)) <= 0:
            return None
        queued = {q.seq for q in box}
        first = self.seqs[rank].expect.get((src, m.tag), 1)
        want = next(k for k in range(first, self.seqs[src].sent[(rank, m.tag)] + 1) if k not in queued)
        last = self._last_sent.get((src, rank, m.tag))
        sent = where(last.task, last.step) if last is not None and last.seq == want else ""
        return (f"message lost: rank {rank} waits{where(task.name, self.step)} for message #{want} from rank "
                f"{src} (tag {m.tag}), which rank {src} sent{sent} but which never arrived")

    def _watch(self, rank, task, waited, peer) -> None:
        """Mock watchdog: a wait longer than `watchdog` virtual seconds stops the run."""
        if self.watchdog > 0 and waited > self.watchdog:
            raise CommError(f"watchdog: rank {rank} waited {waited:.6g} s (virtual, limit {self.watchdog:g} s)"
                            f"{where(task.name, self.step)} for {peer}")

    def _missing(self, rank, task):
        """The first declared receive of `task` whose message is not posted, or None."""
        need: dict = {}
        for m in task.recvs:
            key = (rank + m.peer, rank, m.tag)
            need[key] = need.get(key, 0) + 1
            if len(self.mail.get(key, ())) < need[key]:
                return m
        return None

    def _take(self, rank, task):
        """Pop the task's declared messages: ({(source, tag): deque[payload]}, latest arrival,
        the peer of the latest)."""
        inbox: dict = {}
        latest, peer = -np.inf, None
        for m in task.recvs:
            src = rank + m.peer
            msg = self.mail[(src, rank, m.tag)].popleft()
            self.accept(rank, src, m.tag, msg, task)
            if msg.arrival > latest:
                latest, peer = msg.arrival, f"rank {src} (tag {m.tag})"
            inbox.setdefault((src, m.tag), deque()).append(msg.payload)
        return inbox, latest, peer

    # -- the loop ----------------------------------------------------------------------
    def _loop(self, programs: dict, run_task, run_collective, record):
        ranks = sorted(programs)
        if ranks != list(range(self.n)):
            raise InternalError(f"mock engine: expected programs of ranks 0..{self.n - 1}, got {ranks}")
        pc = {r: 0 for r in ranks}
        last = None
        while True:
            if self.eager and last is not None and pc[last] < len(programs[last]):
                t = programs[last][pc[last]]    # the rank that ran last goes on while it can
                if not t.collective and not t.reads_device and self._missing(last, t) is None:
                    run_task(last, t, record)
                    pc[last] += 1
                    continue
            pending = [r for r in ranks if pc[r] < len(programs[r])]
            if not pending:
                self._check_queues()
                return
            # collectives: run when every rank stands at the same one
            heads = {r: programs[r][pc[r]] for r in pending}
            if len(pending) == self.n and all(t.collective for t in heads.values()) \
                    and len({t.name for t in heads.values()}) == 1:
                run_collective(ranks, heads, record)
                for r in ranks:
                    pc[r] += 1
                continue
            runnable = [r for r in pending if not heads[r].collective and self._missing(r, heads[r]) is None]
            if not runnable:
                lost = next((x for r in pending if not heads[r].collective
                             for x in [self._lost(r, heads[r], self._missing(r, heads[r]))] if x), None)
                if lost:
                    raise CommError(lost)
                raise DeadlockError(self._deadlock_report(ranks, pending, heads))
            if self.eager:
                free = [q for q in runnable if not heads[q].reads_device]
                pool = free or runnable       # device reads once nothing else can be issued
                r = last = last if last in pool else min(pool, key=lambda q: (self.clock[q], q))
            else:
                r = min(runnable, key=lambda q: (self.clock[q], q))
            run_task(r, heads[r], record)
            pc[r] += 1

    def _deadlock_report(self, ranks, pending, heads) -> str:
        lines = ["every rank waits (deadlock):"]
        for r in ranks:
            if r not in heads:
                lines.append(f"rank {r} has finished its step")
                continue
            t = heads[r]
            if t.collective:
                absent = [q for q in ranks if q not in heads or heads[q].name != t.name]
                lines.append(f"rank {r} waits in {t.name} for every rank (rank(s) "
                             f"{', '.join(map(str, absent))} not there)")
            else:
                m = self._missing(r, t)
                lines.append(f"rank {r} waits in {t.name} for a message from rank {r + m.peer} (tag {m.tag})")
        return "\n".join(lines)

    def _watch_collective(self, ranks, heads, t_all) -> None:
        if self.watchdog > 0:
            last = max(ranks, key=lambda q: (self.clock[q], -q))
            for r in ranks:
                self._watch(r, heads[r], t_all - self.clock[r],
                            f"every rank (collective; rank {last} joined last)")

    # -- predict: modelled costs, no bodies --------------------------------------------
    def run_modelled(self, programs, cost, message_bytes, record):
        """`cost(rank, task)` -> seconds; `message_bytes(rank, task, msg)` -> bytes of a send."""
        def run_task(r, task, rec):
            start = self.clock[r]
            latest = -np.inf
            if task.recvs:
                _, latest, peer = self._take(r, task)
                self._watch(r, task, latest - start, peer)
            end = max(start, latest) + cost(r, task)
            for m in task.sends:
                self.post(r, r + m.peer, m.tag, None, message_bytes(r, task, m), end, task.name)
            self.clock[r] = end
            rec(r, task, start, end)

        def run_collective(ranks, heads, rec):
            t_all = max(self.clock[r] for r in ranks) + allreduce_seconds(self.n, self.latency)
            self._watch_collective(ranks, heads, t_all)
            for r in ranks:
                end = t_all + cost(r, heads[r])
                rec(r, heads[r], self.clock[r], end)
                self.clock[r] = end

        self._loop(programs, run_task, run_collective, record)


@register("comm", "mock")
class MockComm(CommBackend):
    """`--comm mock --ranks N`: N ranks in this process (see module doc)."""

    virtual_time = True
    one_process = True
    clock = "cost model"

    def __init__(self, ranks: int = 2, rank_speed=None, latency=DEFAULT_LATENCY, bandwidth=DEFAULT_BANDWIDTH,
                 delay=0.0, reorder=False, seed=0, timing="auto", mode="execute", costs=None,
                 duplicate=0.0, loss=0.0, watchdog=0.0, halo_transport="auto", order="auto", **options):
        if options:
            raise InputError(f"--comm mock: unknown option(s) {', '.join(sorted(options))}: expected "
                             "rank_speed, latency, bandwidth, delay, reorder, seed, timing, mode, costs, "
                             "duplicate, loss, watchdog, halo_transport, order")
        if order not in ("auto", "clock", "eager"):
            raise InputError(f"--comm mock: order: expected 'auto', 'clock' or 'eager', got {order!r}")
        super().__init__(ranks, halo_transport)
        if timing not in ("auto", "model", "wall", "device"):
            raise InputError(f"--comm mock: timing: expected 'auto', 'model', 'wall' or 'device', got {timing!r}")
        if mode not in ("execute", "predict"):
            raise InputError(f"--comm mock: mode: expected 'execute' or 'predict', got {mode!r}")
        speed = [1.0] * ranks if rank_speed is None else [float(s) for s in rank_speed]
        if len(speed) != ranks or any(not s > 0 for s in speed):
            raise InputError(f"--comm mock: rank_speed: expected {ranks} numbers > 0, got {rank_speed!r}")
        watchdog = 0.0 if watchdog is None else watchdog
        for key, v in (("latency", latency), ("bandwidth", bandwidth), ("delay", delay), ("watchdog", watchdog)):
            if not isinstance(v, (int, float)) or v < 0 or (key == "bandwidth" and v == 0):
                raise InputError(f"--comm mock: {key}: expected a number >= 0, got {v!r}")
        self.rank_speed = speed
        self.timing = timing
        self.mode = mode
        self.costs = CostModel.load(costs)
        if order == "auto":
            order = "clock" if (delay or reorder or duplicate or loss) else "eager"
        self.order = order
        self.engine = Engine(ranks, latency, bandwidth, delay, reorder, seed, duplicate, loss, watchdog, order)
        self.endpoints = [MockEndpoint(self.engine, r) for r in range(ranks)]
        self._k = {}
        self._clock_on = False     # the compute backend's device task clock is running
        self._window = False       # device_clock_window(True): timing "auto" reads the device
        self._compute = None       # the compute backend of the last step
        self._pool = None          # threads of the collectives that exchange inside their bodies

    @property
    def local_ranks(self) -> list[int]:
        return list(range(self.size))

    def endpoint(self, rank: int):
        return self.endpoints[rank]

    def gather_rows(self, per_rank: dict):
        return [per_rank[r] for r in range(self.size)]

    def allreduce(self, value, op):
        return value      # every rank is local: the caller's value is already global

    def device_clock_window(self, on: bool) -> bool:
        """timing "auto" on a backend with a device clock: the cost model's durations, but the
        device's own (isolated) task times inside a window -- isolating the tasks costs the
        wall clock a device synchronisation a task, which ordinary steps must not pay."""
        was = self._window
        self._window = bool(on)
        c = self._compute
        return (self.timing == "auto" and self.mode == "execute" and c is not None
                and c.has_device_clock and was != self._window)

    # -- durations ---------------------------------------------------------------------
    def _pairs_k(self, ctx):
        key = id(ctx.state.consts)
        if key not in self._k:
            st = ctx.state
            self._k[key] = pairs_per_particle(st.consts, st.consts.dim, st.consts.dp)
        return self._k[key]

    def _model_seconds(self, ctx, task, moved_rows: int) -> float:
        label = task.label
        st = ctx.state
        if getattr(st, "particles", None) is None:   # a bare context (tests, user experiments)
            return self.costs.seconds(label, moved_rows, 0.0, self.rank_speed[ctx.rank])
        halo_rows = 0
        if label in ("forces_halo_1", "forces_halo_2"):
            h = st.halos.get(int(label[-1]))
            halo_rows = 0 if h is None else h.n
        p, q = task_features(label, st.particles.n, halo_rows, moved_rows, self._pairs_k(ctx))
        return self.costs.seconds(label, p, q, self.rank_speed[ctx.rank])

    # -- execute -----------------------------------------------------------------------
    def execute(self, jobs, record) -> None:
        if self.mode == "predict":
            return self._predict_step(jobs, record)
        eng = self.engine
        ctxs = {ctx.rank: ctx for ctx, _ in jobs}
        programs = {ctx.rank: prog for ctx, prog in jobs}
        wall = self.timing == "wall"
        compute = jobs[0][0].compute if jobs else None
        self._compute = compute
        device = compute is not None and compute.has_device_clock and (
            self.timing == "device" or (self.timing == "auto" and self._window))
        if device != self._clock_on:
            compute.start_task_clock() if device else compute.stop_task_clock()
            self._clock_on = device
            eng.align()
        self.clock = "device task times" if device else "task bodies' wall time" if wall else "cost model"
        eng.step = _step_of(jobs)

        def body(r, task):
            ep = self.endpoints[r]
            ep.task, ep.outbox, ep.received_rows = task, [], 0
            eng._late_arrival[r] = -np.inf
            t0 = time.perf_counter()
            if task.fn is not None:
                task.fn(ctxs[r], task)
            w = time.perf_counter() - t0
            if wall:
                return w / self.rank_speed[r]
            if device:
                d = ctxs[r].compute.task_device_seconds(ctxs[r].state, task)
                if d is not None:
                    return d / self.rank_speed[r]
            moved = ep.received_rows + sum(_rows(p) for _, _, p in ep.outbox)
            return self._model_seconds(ctxs[r], task, moved)

        def run_task(r, task, rec):
            ep = self.endpoints[r]
            start = eng.clock[r]
            latest, peer = -np.inf, None
            if task.recvs:
                ep.inbox, latest, peer = eng._take(r, task)
            dur = body(r, task)
            ep.inbox = {}
            eng._watch(r, task, max(latest, eng._late_arrival[r]) - start, peer or "a message")
            end = max(start, latest, eng._late_arrival[r]) + dur
            for dest, tag, payload in ep.outbox:
                eng.post(r, dest, tag, payload, payload_nbytes(payload), end, task.name)
            ep.outbox, ep.task = [], None
            eng.clock[r] = end
            rec(r, task, start, end)

        def run_collective(ranks, heads, rec):
            coll = _Collective(len(ranks))
            durs, errors = {}, {}
            reduced = all(heads[r].reduce is not None for r in ranks)
            if reduced:
                # one declared reduction: every rank's value reduced here, then each body runs
                # alone (its comm call returns the result): no thread a rank, no barrier
                op, value = heads[ranks[0]].reduce[0], heads[ranks[0]].reduce[1]
                v = _reduce([value(ctxs[r]) for r in ranks], op)
                for r in ranks:
                    ep = self.endpoints[r]
                    ep.reduced = v
                    try:
                        durs[r] = body(r, heads[r])
                    finally:
                        ep.reduced = None

            def go(r):
                ep = self.endpoints[r]
                ep.collective = coll
                try:
                    durs[r] = body(r, heads[r])
                except BaseException as e:   # noqa: BLE001 - re-raised in the engine's thread
                    errors[r] = e
                    coll.barrier.abort()
                finally:
                    ep.collective = None
            if reduced:
                pass
            elif len(ranks) == 1:
                go(ranks[0])
            else:
                # the same N threads for every collective of the run: a rank's body finds its
                # thread's device context (numba-cuda) already made current
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(max_workers=self.size, thread_name_prefix="mock-rank")
                for f in [self._pool.submit(go, r) for r in ranks]:
                    f.result()
            if errors:
                first = min(errors)
                e = errors[first]
                if isinstance(e, threading.BrokenBarrierError):
                    e = next((x for x in errors.values() if not isinstance(x, threading.BrokenBarrierError)), e)
                raise e
            t_all = max(eng.clock[r] for r in ranks) + allreduce_seconds(self.n_ranks, eng.latency)
            eng._watch_collective(ranks, heads, t_all)
            for r in ranks:
                end = t_all + durs[r]
                rec(r, heads[r], eng.clock[r], end)
                for dest, tag, payload in self.endpoints[r].outbox:
                    eng.post(r, dest, tag, payload, payload_nbytes(payload), end, heads[r].name)
                self.endpoints[r].outbox, self.endpoints[r].task = [], None
                eng.clock[r] = end

        eng._loop(programs, run_task, run_collective, record)

    @property
    def n_ranks(self):
        return self.size

    # -- predict mode inside a Simulation: real states and programs, no bodies ----------
    def _predict_step(self, jobs, record):
        """The programs through the engine with perfmodel.step_pricing's costs, from each
        rank's rows and its edge rows towards each neighbour as the states hold them now."""
        ctxs = {ctx.rank: ctx for ctx, _ in jobs}
        programs = {ctx.rank: prog for ctx, prog in jobs}
        self.engine.step = _step_of(jobs)
        rows, lo, hi = [0] * self.size, [0] * self.size, [0] * self.size
        for r, ctx in ctxs.items():
            dom, p = ctx.domain, ctx.state.particles
            rows[r] = p.n
            if dom is None:      # one rank: no edges
                continue
            x = p.pos[:, dom.axis]
            lo[r] = int(np.count_nonzero(x < dom.lo + dom.reach)) if r > 0 else 0
            hi[r] = int(np.count_nonzero(x >= dom.hi - dom.reach)) if r < self.size - 1 else 0
        first = next(iter(ctxs.values()))
        cost, message_bytes = step_pricing(self.costs, rows, lo, hi, self._pairs_k(first),
                                           first.state.particles.dim, self.rank_speed)
        self.engine.run_modelled(programs, cost, message_bytes, record)

def _step_of(jobs) -> int | None:
    """The step being run, 1-based as in the solver's messages (None for bare contexts)."""
    step = getattr(jobs[0][0].state, "step", None) if jobs else None
    return None if step is None else int(step) + 1


def run_programs(programs: dict, contexts: dict, comm: MockComm | None = None, record=None):
    """Run per-rank task lists through the engine directly (no schedule validation).

    For tests and experiments: `programs` {rank: [Task]}, `contexts` {rank: RankContext}.
    """
    comm = comm or MockComm(ranks=len(programs))
    recs = []
    comm.execute([(contexts[r], programs[r]) for r in sorted(programs)],
                 record or (lambda r, t, a, b: recs.append((r, t.name, a, b))))
    return recs
