"""Dependency graphs: per rank, derived from declared data access; and across ranks.

Per-rank rule (sequential task flow over the canonical order; a group name such as
"particles" stands for each of its members, `task.GROUPS`):
  read        after the last write of that datum (read-after-write) and after
              every accumulation since (the reader sees the complete sum);
  write       after the last write (WAW), every read since (WAR) and every
              accumulation since;
  accumulate  after the last write and every read since, but *not* after other
              accumulations: partial buffers summed in a fixed order make any
              order of force tasks legal and bit-identical.

Multi-rank graph (DESIGN.md §3): each rank's program order (the schedule) +
send -> receive edges + one node per collective joined by every rank. Posting a
send never waits; a receive waits for its send; a cycle means deadlock.
"""
from __future__ import annotations

import networkx as nx

from .task import GROUPS, Task, fine


def rank_graph(tasks: list[Task]) -> nx.DiGraph:
    """DAG of one rank's step; edges carry `reason` ("halo_1: read after write")."""
    g = nx.DiGraph()
    last_write: dict[str, Task] = {}
    readers: dict[str, list[Task]] = {}
    accums: dict[str, list[Task]] = {}

    def dep(u, v, datum, why):
        if u is None or u == v:
            return
        if not g.has_edge(u.name, v.name):
            g.add_edge(u.name, v.name, why=[])
        g.edges[u.name, v.name]["why"].append((datum, why))

    for t in tasks:
        g.add_node(t.name, task=t)
        reads, writes, accumulates = fine(t.reads), fine(t.writes), fine(t.accumulates)
        for d in reads:
            dep(last_write.get(d), t, d, "read after write")
            for a in accums.get(d, ()):
                dep(a, t, d, "read after accumulate")
        for d in accumulates:
            dep(last_write.get(d), t, d, "accumulate after write")
            for r in readers.get(d, ()):
                dep(r, t, d, "accumulate after read")
        for d in writes:
            dep(last_write.get(d), t, d, "write after write")
            for r in readers.get(d, ()):
                dep(r, t, d, "write after read")
            for a in accums.get(d, ()):
                dep(a, t, d, "write after accumulate")
        for d in reads:
            readers.setdefault(d, []).append(t)
        for d in accumulates:
            accums.setdefault(d, []).append(t)
        for d in writes:
            last_write[d] = t
            readers[d] = []
            accums[d] = []
    for _, _, data in g.edges(data=True):
        data["reason"] = _reason(data.pop("why"))
    return g


def _reason(why: list) -> str:
    """"datum: why" joined by "; ", a group's members for the same reason named by the group."""
    out = list(why)
    for group, members in GROUPS.items():
        for w in dict.fromkeys(w for _, w in why):
            if all((m, w) in out for m in members):
                i = out.index((members[0], w))
                out = [x for x in out if not (x[1] == w and x[0] in members)]
                out.insert(min(i, len(out)), (group, w))
    return "; ".join(f"{d}: {w}" for d, w in out)


def lane_edges(program: list[Task], graph: nx.DiGraph) -> list[tuple[str, str]]:
    """Cross-lane dependencies of one rank's `program` (its tasks in issue order), as
    (producer, consumer) task names, consumers in issue order: the edges of `graph`
    (`rank_graph` of the canonical tasks) whose ends run on different lanes, plus one
    edge between two tasks on different lanes that accumulate into the same datum, in
    issue order. Accumulations commute (either order gives the same rows) but they
    write the same storage, so they must not run at the same time: on a device with one
    stream per lane (numba-cuda) this order is an event like the others. Tasks on one
    lane need no edge: a lane runs its tasks in issue order."""
    pos = {t.name: i for i, t in enumerate(program)}
    lane = {t.name: t.lane for t in program}
    out = {(u, v) for u, v in graph.edges() if u in pos and v in pos and lane[u] != lane[v]}
    for i, a in enumerate(program):
        for b in program[i + 1:]:
            if a.lane != b.lane and set(fine(a.accumulates)) & set(fine(b.accumulates)):
                out.add((a.name, b.name))
    bad = [e for e in out if pos[e[0]] > pos[e[1]]]
    if bad:    # a validated schedule never issues a consumer before its producer
        raise ValueError(f"lane_edges: consumer issued before its producer: {sorted(bad)}")
    return sorted(out, key=lambda e: (pos[e[1]], pos[e[0]]))


def order_violations(g: nx.DiGraph, order: list[str]) -> list[str]:
    """Dependencies that the issue order `order` breaks, as messages."""
    pos = {name: i for i, name in enumerate(order)}
    out = []
    for u, v, data in g.edges(data=True):
        if u in pos and v in pos and pos[u] > pos[v]:
            out.append(f"{v} is placed before {u}, which it depends on ({data['reason']})")
    return out


def multi_rank_graph(programs: dict[int, list[Task]]) -> nx.DiGraph:
    """Nodes (rank, task name) or ("all", name) for collectives; see module doc."""
    g = nx.DiGraph()

    def node(r, t):
        return ("all", t.name) if t.collective else (r, t.name)

    for r, prog in programs.items():
        prev = None
        for t in prog:
            n = node(r, t)
            g.add_node(n, task=t)
            if prev is not None:
                g.add_edge(prev, n, kind="program")
            prev = n
    for r, prog in programs.items():
        for t in prog:
            for m in t.sends:
                peer = r + m.peer
                for u in programs.get(peer, ()):
                    if any(rm.peer == -m.peer and rm.tag == m.tag for rm in u.recvs):
                        g.add_edge(node(r, t), node(peer, u), kind="message", tag=m.tag)
    return g


def describe_cycle(g: nx.DiGraph, cycle) -> str:
    parts = []
    for u, v in cycle:
        if g.edges[u, v].get("kind") == "message":
            parts.append(f"{_fmt(v)} waits for {_fmt(u)}")
        else:
            parts.append(f"{_fmt(v)} comes after {_fmt(u)}")
    return "; ".join(parts)


def _fmt(n):
    r, name = n
    return f"{name} (all ranks)" if r == "all" else f"rank {r} {name}"


def find_deadlock(g: nx.DiGraph) -> str | None:
    try:
        cyc = nx.find_cycle(g)
    except nx.NetworkXNoCycle:
        return None
    return describe_cycle(g, cyc)
