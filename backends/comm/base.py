"""Communication backends: how ranks talk, and how the scheduler runs their programs.

`execute(jobs, record)` is the one place a step's tasks run: `jobs` is a list
of (RankContext, [Task, ...]) for the ranks this process drives, each list in
schedule order; `record(rank, task, start, end)` is called for every task.
Single-process and MPI backends drive one rank each in issue order (an MPI
receive blocks, a send is posted without waiting); the mock backend drives N
ranks through a discrete-event engine. Every comm backend passes the shared
conformance suite in `tests/test_comm_conformance.py`.
"""
from __future__ import annotations

import time

from sphgraph.errors import CommError, InputError

HALO_TRANSPORTS = ("auto", "staged", "ipc")


class CommBackend:
    """Base class. Subclasses register with `@register("comm", NAME)`."""

    name = "base"
    virtual_time = False   # True when task times are simulated seconds
    clock = "wall"         # what the task times are: "wall", or a virtual clock's source
    one_process = False    # every rank in this process: a message may carry device buffers as they are

    def __init__(self, ranks: int = 1, halo_transport: str = "auto", **options):
        self.size = ranks
        if halo_transport not in HALO_TRANSPORTS:
            raise InputError(f"--halo-transport: expected one of {', '.join(HALO_TRANSPORTS)}, "
                             f"got {halo_transport!r}")
        # how halos travel between device-resident ranks: through the host (MPI or the
        # mock's copy) or device to device (CUDA IPC between processes; backends/compute/cuda_halo);
        # "auto": device to device when every rank is in this process, else through the host
        self.halo_transport = halo_transport

    @property
    def local_ranks(self) -> list[int]:
        """Ranks whose programs this process runs."""
        return [0]

    @property
    def is_root(self) -> bool:
        return 0 in self.local_ranks

    def endpoint(self, rank: int):
        """The object a rank's tasks call: isend, recv, allreduce_min."""
        raise NotImplementedError

    def execute(self, jobs, record) -> None:
        raise NotImplementedError

    def gather_rows(self, per_rank: dict) -> list | None:
        """Collect `per_rank[rank]` objects of all ranks on the root (list in rank order)."""
        raise NotImplementedError

    def allreduce(self, value, op):
        raise NotImplementedError

    def gather(self, obj) -> list | None:
        """Every rank's `obj` on the root in rank order (None elsewhere). One rank a
        process (the default: one rank in all) is the only case that needs it."""
        return [obj]

    def bcast(self, obj):
        return obj

    def barrier(self) -> None:
        """Wait until every rank's process gets here (nothing to wait for in one process)."""

    def device_clock_window(self, on: bool) -> bool:
        """A virtual clock timed by the device: from the next step on (on), take task
        durations from the compute backend's own device task times, each task alone on the
        device; off: back to the clock's usual source. True when the clock's source changed
        (False by default: no virtual clock, or one that never reads the device)."""
        return False

    def first_problem(self, found):
        """The lowest rank's end-of-step problem (or None), the same on every rank;
        `found` is this process's first. One process holds every rank by default."""
        return found

    def abort(self, code: int) -> None:
        pass

    def finish(self) -> None:
        """End of a run (every rank): report a message sent but never received (CommError)."""

    def clock(self) -> float:
        return time.perf_counter()


def where(task: str | None, step: int | None) -> str:
    """' in TASK at step N' (the parts that are known)."""
    return (f" in {task}" if task else "") + (f" at step {step}" if step is not None else "")


class SeqCheck:
    """One rank's message sequence numbers: sender side per (dest, tag), receiver side per
    (source, tag). MPI keeps the messages of one (source, tag) in order (non-overtaking), so
    the receiver must see 1, 2, 3, ...: a number seen before is a duplicate, a jump a loss."""

    def __init__(self, rank: int):
        self.rank = rank
        self.sent: dict = {}      # (dest, tag) -> number of the last message sent
        self.expect: dict = {}    # (source, tag) -> number of the next message to receive

    def next_send(self, dest: int, tag: int) -> int:
        n = self.sent.get((dest, tag), 0) + 1
        self.sent[(dest, tag)] = n
        return n

    def accept(self, source: int, tag: int, seq: int, task=None, step=None) -> None:
        """Check message `seq` from `source`; raise CommError on a duplicate or a gap."""
        want = self.expect.get((source, tag), 1)
        if seq == want:
            self.expect[(source, tag)] = want + 1
            return
        if seq < want:
            raise CommError(f"message duplicated: rank {self.rank} received message #{seq} from rank "
                            f"{source} (tag {tag}) a second time{where(task, step)}")
        missing = f"#{want}" if seq == want + 1 else f"#{want}-#{seq - 1}"
        raise CommError(f"message lost: rank {self.rank} received message #{seq} from rank {source} "
                        f"(tag {tag}){where(task, step)} but never {missing}")

    def duplicate(self, source: int, tag: int, seq: int) -> bool:
        """Whether a message still queued for this rank repeats one already received."""
        return seq < self.expect.get((source, tag), 1)

    def outstanding(self, source: int, tag: int, sender: "SeqCheck", queued: int) -> int:
        """Messages `sender` numbered for this rank beyond those received and `queued`: lost."""
        return sender.sent.get((self.rank, tag), 0) - (self.expect.get((source, tag), 1) - 1) - queued
