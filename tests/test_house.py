"""The house rules of the tree, checked on its import statements (every `import` and
`from ... import`, at module level or inside functions), with no allow-list:

* physics (sphgraph/physics) imports nothing of the graph, the scheduler, comm,
  compute backends or output: it is per-pair and per-row maths;
* comm (backends/comm) imports nothing of compute: comm moves bytes, payloads bring
  their own codec (sphgraph.wire);
* compute (backends/compute) imports nothing of the graph, the scheduler, the
  solver, balancing, features or output: the core calls it, not the other way;
* the core (sphgraph/, outside sphgraph/physics) reaches backends only through the
  registry, which names their modules as strings and imports them by name.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imports(path: Path, root: Path = ROOT):
    """(module, line) of every import in `path`, relative imports made absolute
    (backends/ is the package sphgraph.backends)."""
    rel = path.relative_to(root).with_suffix("")
    parts = list(rel.parts)
    if parts[0] == "backends":
        parts = ["sphgraph"] + parts
    pkg = parts[:-1] if parts[-1] != "__init__" else parts[:-1]
    tree = ast.parse(path.read_text(), str(path))
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            for a in n.names:
                yield a.name, n.lineno
        elif isinstance(n, ast.ImportFrom):
            if n.level:
                base = pkg[:len(pkg) - (n.level - 1)] if n.level > 1 else pkg
                mod = ".".join(base + ([n.module] if n.module else []))
            else:
                mod = n.module or ""
            yield mod, n.lineno
            for a in n.names:           # `from . import cuda_kernels`: the module itself
                yield f"{mod}.{a.name}", n.lineno


def files(folder: str, root: Path = ROOT):
    return sorted((root / folder).rglob("*.py"))


def _starts(mod: str, prefixes) -> bool:
    return any(mod == p or mod.startswith(p + ".") for p in prefixes)


OUTPUT = ["sphgraph.io", "sphgraph.xdmf", "sphgraph.checkpoint", "sphgraph.trace", "sphgraph.plots"]
GRAPH = ["sphgraph.graph", "sphgraph.scheduler", "sphgraph.schedule", "sphgraph.solver"]
RULES = {
    "sphgraph/physics": GRAPH + OUTPUT + ["sphgraph.backends", "backends", "sphgraph.features",
                                          "sphgraph.balance"],
    "backends/comm": ["sphgraph.backends.compute", "backends.compute"],
    "backends/compute": GRAPH + OUTPUT + ["sphgraph.balance", "sphgraph.features", "sphgraph.bench",
                                          "sphgraph.backends.comm", "backends.comm"],
}


def broken(folder: str, banned, root: Path = ROOT) -> list:
    out = []
    for f in files(folder, root):
        for mod, line in imports(f, root):
            if _starts(mod, banned):
                out.append(f"{f.relative_to(root)}:{line} imports {mod}")
    return sorted(set(out))


@pytest.mark.parametrize("folder", sorted(RULES))
def test_layer_imports_nothing_above_it(folder):
    assert broken(folder, RULES[folder]) == []


def test_core_reaches_backends_only_through_the_registry():
    out = []
    for f in files("sphgraph"):
        if "physics" in f.relative_to(ROOT).parts or f.name == "registry.py":
            continue
        for mod, line in imports(f):
            if _starts(mod, ["sphgraph.backends", "backends"]):
                out.append(f"{f.relative_to(ROOT)}:{line} imports {mod}")
    assert sorted(set(out)) == []


def test_the_rules_see_a_violation(tmp_path):
    """The checker itself: an absolute and a relative import (inside a function) out of a
    compute module into the graph are found, so an empty result above means the rule
    holds, not that nothing was read."""
    fake = tmp_path / "backends" / "compute" / "_house_probe.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("from sphgraph.graph.task import UserTask\n\n\ndef f():\n    from ...solver import Simulation\n")
    got = broken("backends/compute", RULES["backends/compute"], root=tmp_path)
    assert any("_house_probe.py:1 imports sphgraph.graph.task" in g for g in got), got
    assert any("_house_probe.py:5 imports sphgraph.solver" in g for g in got), got
