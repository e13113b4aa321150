"""coordinator/memory_budget.py: the memory this process may still take (MemAvailable, the cgroup's
headroom, SHADOWLESS_MEMORY_LIMIT) and the one-line refusal of work that would not fit."""
from __future__ import annotations

import pytest

from coordinator import memory_budget as mb


def test_sizes_parse_in_binary_units_and_bad_ones_name_the_text():
    assert mb.parse_bytes("2G") == 2 * 2**30 == mb.parse_bytes("2 GiB") == mb.parse_bytes("2gb")
    assert mb.parse_bytes("512M") == 512 * 2**20 and mb.parse_bytes("1.5G") == 3 * 2**29
    assert mb.parse_bytes("1048576") == 2**20 and mb.parse_bytes("4k") == 4096
    for bad in ("", "lots", "-1G", "0", "2X", "1.2.3G", "G"):
        with pytest.raises(ValueError, match="is not a memory size: give e.g. 2G"):
            mb.parse_bytes(bad)


def test_the_environment_sets_or_turns_off_the_budget():
    b = mb.available({"SHADOWLESS_MEMORY_LIMIT": "2G"})
    assert b == mb.Budget(2 * 2**30, "SHADOWLESS_MEMORY_LIMIT=2G")
    assert mb.fits(2 * 2**30, b) and not mb.fits(2 * 2**30 + 1, b)
    off = mb.available({"SHADOWLESS_MEMORY_LIMIT": "off"})
    assert off.bytes is None and mb.fits(1e30, off)
    mb.ensure_fits(1e30, what="anything", hint="-", budget=off)
    with pytest.raises(mb.MemoryBudgetError) as exc:
        mb.available({"SHADOWLESS_MEMORY_LIMIT": "plenty"})
    assert str(exc.value) == ("SHADOWLESS_MEMORY_LIMIT: 'plenty' is not a memory size: give e.g. 2G, 512M or a number "
                              "of bytes, or 'off' to run without the memory check")


def test_without_the_variable_the_machine_decides():
    b = mb.available({})
    assert b.source in ("MemAvailable", "cgroup limit") and 0 < b.bytes


def test_meminfo_and_both_cgroup_versions_are_read(tmp_path):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:   2000000 kB\n")
    assert mb.mem_available(meminfo) == 2000000 * 1024
    assert mb.mem_available(tmp_path / "missing") is None
    v2 = tmp_path / "v2"
    v2.mkdir()
    (v2 / "memory.max").write_text("max\n")
    assert mb.cgroup_headroom(v2) is None
    (v2 / "memory.max").write_text(f"{4 * 2**30}\n")
    (v2 / "memory.current").write_text(f"{3 * 2**30}\n")
    (v2 / "memory.stat").write_text(f"anon 1\ninactive_file {2**29}\n")
    assert mb.cgroup_headroom(v2) == 2**30 + 2**29
    v1 = tmp_path / "v1"
    (v1 / "memory").mkdir(parents=True)
    (v1 / "memory" / "memory.limit_in_bytes").write_text("9223372036854771712\n")   # v1's "no limit"
    assert mb.cgroup_headroom(v1) is None
    (v1 / "memory" / "memory.limit_in_bytes").write_text(f"{2**30}\n")
    (v1 / "memory" / "memory.usage_in_bytes").write_text(f"{2**29}\n")
    assert mb.cgroup_headroom(v1) == 2**29
    assert mb.cgroup_headroom(tmp_path / "none") is None


def test_a_refusal_is_one_line_naming_the_need_the_budget_and_what_to_do():
    budget = mb.Budget(int(22.9 * 2**30), "MemAvailable")
    with pytest.raises(mb.MemoryBudgetError) as exc:
        mb.ensure_fits(31.2 * 2**30, what="25 per-projector baselines at 2592x1944",
                       hint="use --no-baseline or a smaller --size", budget=budget)
    assert str(exc.value) == ("needs about 31.2 GB for 25 per-projector baselines at 2592x1944, 22.9 GB available; "
                              "use --no-baseline or a smaller --size (or SHADOWLESS_MEMORY_LIMIT=off to try anyway)")
    small = mb.Budget(40 * 2**20, "SHADOWLESS_MEMORY_LIMIT=40M")
    with pytest.raises(mb.MemoryBudgetError, match=r"^needs about 300 MB for x, 40 MB available "
                                                   r"\(SHADOWLESS_MEMORY_LIMIT=40M\); y \(or"):
        mb.ensure_fits(300 * 2**20, what="x", hint="y", budget=small)
    mb.ensure_fits(40 * 2**20, what="x", hint="y", budget=small)
