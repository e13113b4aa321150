"""The repository's shape: files that hold one concern, and documents that never point
outside the repository."""
from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("coordinator", "node", "sim", "protos", "bench", "shadowless")

#: modules allowed past the general limit, with theirs (none now)
LIMITS: dict[str, int] = {}
#: DESIGN.md section 8: a module past ~900 lines usually holds two concerns; below that, a module is
#: split where its concerns part, never to meet a line count (a 600-line cap had begun to shape files)
GENERAL_LIMIT = 900


def _tracked(*patterns: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", *patterns], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [ROOT / line for line in out.splitlines() if (ROOT / line).exists()]


def test_no_module_holds_two_concerns_by_size():
    too_long = []
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            rel = f.relative_to(ROOT).as_posix()
            if rel.endswith(("_pb2.py", "_pb2_grpc.py")):
                continue
            n = len(f.read_text().splitlines())
            if n > LIMITS.get(rel, GENERAL_LIMIT):
                too_long.append(f"{rel}: {n} lines")
    assert too_long == []


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
