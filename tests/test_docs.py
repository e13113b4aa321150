"""The operator's documentation holds together: every relative link in README.md and docs/*.md
names a file that exists, the README stays short, every benchmark JSON the pages name (and
every one kept under docs/benchmarks/) parses and says what measured it, where and when, and every
JSON kept under docs/benchmarks/ is linked from some page, so that no kept run is an orphan a reader
cannot reach from the figure it measured."""
from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
JSON_NAME = re.compile(r"benchmarks/[\w.-]+\.json")
README_MAX_LINES = 250                 # issue 38: "at most about 250 lines"


def _targets(page: Path) -> list[str]:
    """The relative link targets of a Markdown page, without their #fragment (code blocks skipped)."""
    text = re.sub(r"(?ms)^```.*?^```", "", page.read_text(encoding="utf-8"))
    out = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue                      # http:, https:, mailto:, and anchors within the page
        out.append(target.split("#", 1)[0])
    return out


def test_the_pages_exist():
    names = {p.name for p in PAGES}
    for page in ("quickstart.md", "operator-guide.md", "venue-checklist.md", "console.md",
                 "show-control.md", "research.md", "studies.md", "benchmarks.md", "deployment.md",
                 "architecture.md", "solver.md"):
        assert page in names, f"docs/{page} is missing"


def test_every_relative_link_points_to_a_file():
    broken = []
    for page in PAGES:
        for target in _targets(page):
            if not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, "links to files that do not exist:\n" + "\n".join(broken)


def test_the_link_check_sees_a_broken_link(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("[ok](page.md) [web](https://example.org) [here](#top) [gone](missing.md#x)\n"
                    "```\n[in code](nowhere.md)\n```\n")
    assert _targets(page) == ["page.md", "missing.md"]


def test_the_venue_checklist_covers_the_network_the_projectors_and_the_camera():
    text = (ROOT / "docs" / "venue-checklist.md").read_text(encoding="utf-8").lower()
    topics = ("igmp", "switch", "keystone", "eco", "auto-iris", "warm-up", "exposure", "focus",
              "white balance")
    missing = [t for t in topics if t not in text]
    assert not missing, f"docs/venue-checklist.md says nothing of {missing}"


def test_readme_stays_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines < README_MAX_LINES, f"README.md has {lines} lines; move detail into docs/"


def _linked_json(page: Path) -> set[str]:
    """The docs/benchmarks/*.json files a page links to, as "benchmarks/NAME.json"."""
    out = set()
    for target in _targets(page):
        match = JSON_NAME.search(target)
        if match and match.end() == len(target):
            out.add(match.group(0))
    return out


def test_every_kept_benchmark_json_is_linked():
    linked = set()
    for page in PAGES:
        linked |= _linked_json(page)
    kept = {f"benchmarks/{p.name}" for p in (ROOT / "docs" / "benchmarks").glob("*.json")}
    orphans = sorted(kept - linked)
    assert not orphans, ("kept under docs/benchmarks/ but linked from no page (link each file, not a "
                         "range such as 'x_1 to _8'):\n" + "\n".join(orphans))


def test_the_orphan_check_sees_a_range_and_a_bare_name(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("[a](benchmarks/a.json) to [_3](benchmarks/a_3.json); benchmarks/b.json in prose; "
                    "[c](../docs/benchmarks/c.json#x)\n```\n[d](benchmarks/d.json)\n```\n")
    assert _linked_json(page) == {"benchmarks/a.json", "benchmarks/a_3.json", "benchmarks/c.json"}


def test_every_benchmark_json_named_parses():
    named = set()
    for page in PAGES:
        named.update(JSON_NAME.findall(page.read_text(encoding="utf-8")))
    assert named, "no page names a benchmark JSON"
    kept = {f"benchmarks/{p.name}" for p in (ROOT / "docs" / "benchmarks").glob("*.json")}
    assert named <= kept, f"named but not kept in docs/benchmarks/: {sorted(named - kept)}"
    for name in sorted(kept):
        doc = json.loads((ROOT / "docs" / name).read_text(encoding="utf-8"))
        missing = {"name", "command", "date", "machine", "result"} - set(doc)
        assert not missing, f"docs/{name} lacks {sorted(missing)}"
        assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", doc["date"]), f"docs/{name}: date {doc['date']!r}"
        assert doc["machine"].get("cpus"), f"docs/{name}: the machine says no cpu count"
