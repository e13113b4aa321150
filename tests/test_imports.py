"""The import rules of docs/architecture.md, checked on every module of the project.

Every import counts, including those inside functions and those under ``if TYPE_CHECKING:``
(never executed, but a type named there ties the two modules as much as a run-time import). The rules:

* no import cycles between modules;
* every package stands on a floor (``FLOORS``) and imports only packages on lower floors, and of
  those only the ones ``ALLOWED`` lists (node, sim -> protos; coordinator -> imaging, protos; ...);
  nothing imports ``bench`` (the ``shadowless bench`` command loads it by name, lazily);
* the coordinator's core reaches no edge, and no edge imports the core's module;
* generated ``*_pb2`` modules only in the wire and link modules listed here;
* ``import grpc`` (or any ``grpc_*`` package) only in wire and link modules: a module one of whose
  dotted name's parts is ``wire`` or ``link``, or ends with ``_wire`` or ``_link``
  (``coordinator.wire.node_service``, ``node.link``, ``rigctl.link``, ``node.outputs.room_link``,
  ``bench.preauth_wire``). For this rule every import counts, under ``if TYPE_CHECKING`` too.
  Generated ``*_pb2_grpc`` modules are the wire themselves, and ``grpc_tools`` (the protobuf
  compiler that ``protos.generate`` runs) is no gRPC at run time.
"""
from __future__ import annotations

import ast
import functools
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
    "shadowless": {"coordinator", "node", "sim", "protos", "imaging", "studies", "rigctl", "planner"},
    "bench": set(PACKAGES) - {"bench"},
}

#: the only modules outside protos/ that may touch generated protobuf code: the coordinator's
#: messages, services and room camera; the operator's, the node's and the room's links; the room's wire;
#: the preauth benchmark's attacker
WIRE_MODULES = {
    "coordinator.wire.node_messages", "coordinator.wire.control_messages", "coordinator.wire.image_parts",
    "coordinator.wire.frame_packets", "coordinator.wire.handshake_service", "coordinator.wire.node_service",
    "coordinator.wire.control_service", "coordinator.wire.content_service", "coordinator.wire.serve",
    "coordinator.wire.room_camera",
    "rigctl.link",
    "node.wire", "node.link", "node.outputs.room_link",
    "sim.wire.messages", "sim.wire.service", "sim.link",
    "bench.preauth_wire",
}
#: packages named grpc_* that are no gRPC at run time (the protobuf compiler)
NOT_GRPC = {"grpc_tools"}


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


def _imports(module: str, path: Path) -> set[str]:
    """Every project module ``module`` imports, anywhere in it (in functions and under ``if
    TYPE_CHECKING`` too)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    is_pkg = path.name == "__init__.py"

    def visit(node: ast.AST) -> None:
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


@functools.cache
def graph() -> dict[str, set[str]]:
    """Each module's imports, parsed on first use: at module level every xdist worker parsed the whole
    project while collecting (1.6 CPU-s each), though one worker runs these tests."""
    return {m: _imports(m, p) for m, p in MODULES.items()}


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


def test_the_checker_sees_cycles_and_every_import(tmp_path):
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
    f = tmp_path / "m.py"
    f.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import coordinator.server\n"
                 "def f():\n    import coordinator.rig\n")
    assert _imports("x.m", f) == {"coordinator.server", "coordinator.rig"}


def test_there_are_modules_to_check():
    assert len(MODULES) > 80 and "coordinator.server" in MODULES and "node.app" in MODULES


def test_no_import_cycles():
    assert _cycles(graph()) == []


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_go_in_the_intended_direction(package):
    bad = sorted(f"{m} -> {o}" for m, outs in graph().items() if m.split(".")[0] == package
                 for o in outs if o.split(".")[0] not in ALLOWED[package] | {package})
    assert bad == []


def test_protobuf_only_at_the_wire_edges():
    users = {m for m, outs in graph().items() if any(o.startswith("protos.") and o.endswith(("_pb2", "_pb2_grpc"))
                                                       for o in outs)}
    outside = {m for m in users if not m.startswith("protos")}
    assert outside <= WIRE_MODULES, sorted(outside - WIRE_MODULES)
    assert WIRE_MODULES <= outside, f"no longer using generated code: {sorted(WIRE_MODULES - outside)}"
    assert all(is_wire_or_link(m) for m in WIRE_MODULES), sorted(m for m in WIRE_MODULES if not is_wire_or_link(m))


def is_wire_or_link(module: str) -> bool:
    """Whether ``module`` may import grpc: one of its name's parts is ``wire`` or ``link`` or ends
    with ``_wire`` or ``_link``."""
    return any(p in ("wire", "link") or p.endswith(("_wire", "_link")) for p in module.split("."))


def grpc_imports(path: Path) -> set[str]:
    """The gRPC packages (``grpc``, ``grpc_*`` but :data:`NOT_GRPC`) a file imports anywhere in it."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
        for name in names:
            top = name.split(".")[0]
            if (top == "grpc" or top.startswith("grpc_")) and top not in NOT_GRPC:
                found.add(top)
    return found


def test_the_grpc_checker_sees_every_import_and_knows_the_edge_names(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import grpc.aio\n"
                 "def f():\n    from grpc_health.v1 import health\n    import grpc_tools\n    import grpcio_other\n")
    assert grpc_imports(f) == {"grpc", "grpc_health"}
    assert all(map(is_wire_or_link, ["coordinator.wire.node_service", "node.link", "rigctl.link", "sim.wire.service",
                                     "node.outputs.room_link", "bench.preauth_wire"]))
    assert not any(map(is_wire_or_link, ["coordinator.server", "node.linker", "rigctl.wired", "sim.rewire"]))


def test_grpc_only_in_wire_and_link_modules():
    users = {m for m, path in MODULES.items() if grpc_imports(path)}
    generated = {m for m in users if m.startswith("protos.") and m.endswith("_pb2_grpc")}
    assert len(users) > 15 and generated, "the checker sees the modules that do import grpc"
    assert sorted(m for m in users - generated if not is_wire_or_link(m)) == []


def _reach(module: str) -> set[str]:
    """Every module ``module`` imports, directly or through others."""
    seen: set[str] = set()
    todo = [module]
    while todo:
        for o in graph().get(todo.pop(), ()):
            if o not in seen:
                seen.add(o)
                todo.append(o)
    return seen


#: the coordinator's edges: what the composition root (coordinator.app) builds beside the core
EDGES = ("coordinator.wire", "coordinator.console", "coordinator.osc", "coordinator.mdns", "coordinator.app")
#: in the wire package but no edge of the core: the client a job's room camera captures through
NOT_EDGES = {"coordinator.wire.room_camera"}


def _is_edge(module: str) -> bool:
    return module not in NOT_EDGES and any(module == e or module.startswith(e + ".") for e in EDGES)


def test_the_core_reaches_no_edge_and_the_edges_see_it_only_through_its_protocols():
    core = _reach("coordinator.server") | {"coordinator.server"}
    assert sorted(m for m in core if _is_edge(m)) == []
    # the console and the gRPC edge import the Protocols (coordinator.ports), never the core's module
    edges = [m for m in MODULES if _is_edge(m) and m != "coordinator.app"]
    assert len(edges) > 10
    assert sorted(f"{m} -> coordinator.server" for m in edges if "coordinator.server" in _reach(m)) == []
    assert "coordinator.server" in graph()["coordinator.app"], "the root builds the core"


def test_every_allowed_import_goes_down_a_floor():
    up = sorted(f"{p} -> {q}" for p, allowed in ALLOWED.items() for q in allowed if FLOORS[q] >= FLOORS[p])
    assert up == [], f"ALLOWED lets a package import one on its own floor or above: {up}"
    assert set(FLOORS) == set(PACKAGES) == set(ALLOWED)
