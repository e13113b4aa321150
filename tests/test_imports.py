"""The import rules of docs/architecture.md, checked on every module of the project.

Every import counts, including those inside functions; only imports under
``if TYPE_CHECKING:`` (never executed) are left out. The rules:

* no import cycles between modules;
* node -> protos only; coordinator -> protos only; sim -> protos only (plus themselves);
* nothing imports ``bench`` but the CLI wiring (``shadowless``) and ``bench`` itself;
* nothing in coordinator/node/sim/protos imports the CLI wiring (``shadowless``);
* generated ``*_pb2`` modules only in the wire, service and client modules listed here.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("protos", "imaging", "coordinator", "node", "sim", "studies", "rigctl", "planner", "shadowless", "bench")

#: each package's floor: a module may import only packages on a lower floor (and its own package)
FLOORS = {
    "protos": 0,
    "imaging": 1,
    "coordinator": 2, "node": 2, "sim": 2,
    "rigctl": 3,
    "studies": 4,
    "planner": 5,
    "shadowless": 6,
    "bench": 7,
}
#: which packages on lower floors each package may import; a narrower rule than the floors
ALLOWED = {
    "protos": set(),
    "imaging": {"protos"},
    "node": {"protos"},
    "coordinator": {"protos", "imaging"},
    "sim": {"protos"},
    "studies": {"rigctl", "coordinator", "sim", "protos", "imaging"},
    "rigctl": {"coordinator", "protos", "imaging"},
    "planner": {"studies", "sim", "protos"},
    "shadowless": {"coordinator", "node", "sim", "protos", "imaging", "studies", "rigctl", "planner", "bench"},
    "bench": set(PACKAGES) - {"bench"},
}

#: the only modules outside protos/ that may touch generated protobuf code
WIRE_MODULES = {
    "coordinator.wire", "coordinator.services", "coordinator.content_service", "rigctl.client",
    "coordinator.camera",
    "node.wire", "node.link", "node.outputs.room",
    "sim.wire", "sim.service", "sim.client",
}


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = f
    return mods


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imports(module: str, path: Path) -> set[str]:
    """Every project module ``module`` imports (anywhere but under ``if TYPE_CHECKING``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    is_pkg = path.name == "__init__.py"

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                if (r := _resolve(alias.name)) is not None:
                    found.add(r)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                full = f"{target}.{alias.name}"
                r = full if full in MODULES else _resolve(target)
                if r is not None:
                    found.add(r)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    found.discard(module)
    return found


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_the_checker_sees_cycles_and_type_checking_blocks(tmp_path):
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
    f = tmp_path / "m.py"
    f.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import coordinator.server\n"
                 "def f():\n    import coordinator.rig\n")
    assert _imports("x.m", f) == {"coordinator.rig"}


def test_there_are_modules_to_check():
    assert len(MODULES) > 80 and "coordinator.server" in MODULES and "node.app" in MODULES


def test_no_import_cycles():
    assert _cycles(GRAPH) == []


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_go_in_the_intended_direction(package):
    bad = sorted(f"{m} -> {o}" for m, outs in GRAPH.items() if m.split(".")[0] == package
                 for o in outs if o.split(".")[0] not in ALLOWED[package] | {package})
    assert bad == []


def test_protobuf_only_at_the_wire_edges():
    users = {m for m, outs in GRAPH.items() if any(o.startswith("protos.") and o.endswith(("_pb2", "_pb2_grpc"))
                                                     for o in outs)}
    outside = {m for m in users if not m.startswith("protos")}
    assert outside <= WIRE_MODULES, sorted(outside - WIRE_MODULES)
    assert len(WIRE_MODULES) <= 11
