"""The repository's shape: files sized by their concern, the coordinator's share of the product,
and documents that never point outside the repository."""
from __future__ import annotations

import ast
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _packages() -> tuple[str, ...]:
    """The product's packages: those whose import rules tests/test_imports.py checks (read from its
    ``PACKAGES``, so that a new package is counted here the day it is added there)."""
    tree = ast.parse((ROOT / "tests" / "test_imports.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "PACKAGES" for t in node.targets):
            return tuple(ast.literal_eval(node.value))
    raise AssertionError("tests/test_imports.py defines no PACKAGES")


PACKAGES = _packages()

#: modules allowed past the general limit, with theirs (none now)
LIMITS: dict[str, int] = {}
#: a module past ~900 lines usually holds two concerns; below that, a module is split where its
#: concerns part, never to meet a line count (a 600-line cap had begun to shape files)
GENERAL_LIMIT = 900
#: the coordinator is the server and its jobs: at most this share of the product's lines
COORDINATOR_SHARE = 0.35


def _tracked(*patterns: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", *patterns], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [ROOT / line for line in out.splitlines() if (ROOT / line).exists()]


def _product_lines() -> dict[str, int]:
    """Lines of every hand-written module of the product (generated ``*_pb2*`` files and tests aside),
    by path relative to the repository."""
    lines = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            if f.name.endswith(("_pb2.py", "_pb2_grpc.py", "_pb2.pyi")):
                continue
            lines[f.relative_to(ROOT).as_posix()] = len(f.read_text().splitlines())
    return lines


def test_the_product_packages_are_counted():
    lines = _product_lines()
    assert {"coordinator", "node", "sim", "shadowless"} <= set(PACKAGES)
    assert all(any(path.startswith(pkg + "/") for path in lines) for pkg in PACKAGES), PACKAGES
    assert not any(path.endswith("_pb2.py") or path.startswith("tests/") for path in lines)


def test_no_module_holds_two_concerns_by_size():
    lines = _product_lines()
    too_long = [f"{rel}: {n} lines (limit {LIMITS.get(rel, GENERAL_LIMIT)})"
                for rel, n in sorted(lines.items(), key=lambda kv: -kv[1]) if n > LIMITS.get(rel, GENERAL_LIMIT)]
    largest = max(lines, key=lines.get)
    assert too_long == [], (f"the largest file is {largest} with {lines[largest]} lines; a file past {GENERAL_LIMIT} lines "
                            f"usually holds two concerns: split it where they part. Past the limit: {too_long}")


def test_the_coordinator_is_the_server_and_its_jobs():
    lines = _product_lines()
    total = sum(lines.values())
    by_package = {pkg: sum(n for rel, n in lines.items() if rel.startswith(pkg + "/")) for pkg in PACKAGES}
    share = by_package["coordinator"] / total
    assert share <= COORDINATOR_SHARE, (
        f"coordinator/ holds {by_package['coordinator']} of the product's {total} lines, {share:.1%} "
        f"(at most {COORDINATOR_SHARE:.0%}): move what is not the server or its jobs to the package of its role. "
        f"By package: " + ", ".join(f"{pkg} {n}" for pkg, n in sorted(by_package.items(), key=lambda kv: -kv[1])))


def test_the_architecture_document_is_in_the_repository_and_nothing_points_outside():
    assert (ROOT / "docs" / "architecture.md").exists()
    offenders = []
    for f in _tracked("*.py", "*.md", "*.toml", "*.glsl", "*.proto", "Makefile", "*.sh", "*.service", "*.env"):
        if f.resolve() == Path(__file__).resolve():
            continue
        text = f.read_text(errors="replace")
        for needle in ("DESIGN.md", "../shared", "shared/reference"):
            if needle in text:
                offenders.append(f"{f.relative_to(ROOT)}: {needle}")
    assert offenders == []


def _asyncio_wait_fors(source: str) -> list[int]:
    """Lines of ``source`` that call ``asyncio.wait_for`` or import it by name."""
    hits = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr == "wait_for" and isinstance(node.value, ast.Name) \
                and node.value.id == "asyncio":
            hits.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.module == "asyncio" and any(a.name == "wait_for" for a in node.names):
            hits.append(node.lineno)
    return hits


def test_no_wait_loses_a_cancel():
    """On Python 3.11 ``asyncio.wait_for`` drops a cancel that meets the awaited thing's completion, so a
    loop around it runs on and the stop() awaiting it hangs: the product waits with ``asyncio.timeout``
    (docs/architecture.md, "Waits that keep a cancel")."""
    assert _asyncio_wait_fors("import asyncio\nasync def f(e):\n    await asyncio.wait_for(e.wait(), 1)\n") == [3]
    assert _asyncio_wait_fors("from asyncio import wait_for\n") == [1]
    assert _asyncio_wait_fors("async def f(c):\n    await c.wait_for(lambda: True)\n") == []   # a Condition's
    found = [f"{f.relative_to(ROOT)}:{line}" for pkg in PACKAGES for f in sorted((ROOT / pkg).rglob("*.py"))
             if not f.name.endswith(("_pb2.py", "_pb2_grpc.py")) for line in _asyncio_wait_fors(f.read_text())]
    assert not found, f"asyncio.wait_for in the product (use `async with asyncio.timeout(t):`): {found}"
