"""How much memory this process may still take, and the check that refuses work that would not fit.

A command that may allocate more than the machine holds estimates its peak first and calls
:func:`ensure_fits` (or asks :func:`fits` when it can drop a part instead). The memory available
is the smaller of the kernel's ``MemAvailable`` (``/proc/meminfo``) and the headroom under this
process's cgroup limit (v2 ``memory.max``, v1 ``memory.limit_in_bytes``), when one is set.

``SHADOWLESS_MEMORY_LIMIT`` overrides it: a size (``2G``, ``512M``, ``1.5GiB``, bytes) is the
budget whatever the machine holds (tests use it to make a refusal fast and deterministic), and
``off`` turns the check off (the operator forces a run the estimate would refuse).

Only the standard library is imported here, so the command-line wiring, the benchmarks and the
jobs may all use it.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from coordinator.errors import CoordinatorError

__all__ = ["ENV_LIMIT", "Budget", "MemoryBudgetError", "available", "ensure_fits", "fits", "gb", "parse_bytes"]

#: the environment variable that sets the budget (a size) or turns the check off (``off``)
ENV_LIMIT = "SHADOWLESS_MEMORY_LIMIT"
_OFF = ("off", "none", "unlimited", "force")
_UNITS = {"": 1, "b": 1, "k": 1 << 10, "kb": 1 << 10, "kib": 1 << 10, "m": 1 << 20, "mb": 1 << 20,
          "mib": 1 << 20, "g": 1 << 30, "gb": 1 << 30, "gib": 1 << 30, "t": 1 << 40, "tb": 1 << 40, "tib": 1 << 40}
_NO_LIMIT = 1 << 60  # cgroup v1 reports "no limit" as a number near 2**63


class MemoryBudgetError(CoordinatorError):
    """The work would need more memory than this process may take; the message says what to do."""


@dataclass(frozen=True)
class Budget:
    """The memory this process may still take (None: unlimited, the check is off) and where that came from."""

    bytes: int | None
    source: str


def gb(n: float) -> str:
    """``n`` bytes with one decimal in GB (GiB, as ``free -g``), e.g. ``'31.2 GB'``; below 1 GB in MB."""
    return f"{n / 2**30:.1f} GB" if n >= 2**30 else f"{n / 2**20:.0f} MB"


def parse_bytes(text: str) -> int:
    """A size such as ``2G``, ``512M``, ``1.5GiB`` or ``1048576`` in bytes (binary units).

    Raises ``ValueError`` naming the text when it is not a positive size."""
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([a-zA-Z]*)\s*", text)
    unit = m.group(2).lower() if m else ""
    if not m or unit not in _UNITS or float(m.group(1)) <= 0:
        raise ValueError(f"{text!r} is not a memory size: give e.g. 2G, 512M or a number of bytes")
    return int(float(m.group(1)) * _UNITS[unit])


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _stat(path: Path, key: str) -> int:
    try:
        for line in path.read_text().splitlines():
            k, _, v = line.partition(" ")
            if k == key and v.strip().isdigit():
                return int(v)
    except OSError:
        pass
    return 0


def mem_available(meminfo: Path = Path("/proc/meminfo")) -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes (None if the kernel does not say)."""
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def cgroup_headroom(root: Path = Path("/sys/fs/cgroup")) -> int | None:
    """What this process's memory cgroup still allows (limit - usage + reclaimable file cache), in bytes;
    None without a limit. cgroup v2 (``memory.max``) first, then v1 (``memory/memory.limit_in_bytes``)."""
    v2 = root / "memory.max"
    if v2.exists():
        limit = _read_int(v2)  # "max": no limit
        if limit is None or limit >= _NO_LIMIT:
            return None
        used = _read_int(root / "memory.current") or 0
        return max(0, limit - used + _stat(root / "memory.stat", "inactive_file"))
    v1 = root / "memory"
    limit = _read_int(v1 / "memory.limit_in_bytes")
    if limit is None or limit >= _NO_LIMIT:
        return None
    used = _read_int(v1 / "memory.usage_in_bytes") or 0
    return max(0, limit - used + _stat(v1 / "memory.stat", "total_inactive_file"))


def available(env: dict[str, str] | None = None) -> Budget:
    """The memory this process may still take: ``SHADOWLESS_MEMORY_LIMIT`` when set, else the smaller of
    ``MemAvailable`` and the cgroup's headroom. Raises :class:`MemoryBudgetError` on a malformed variable."""
    env = os.environ if env is None else env
    text = env.get(ENV_LIMIT, "").strip()
    if text:
        if text.lower() in _OFF:
            return Budget(None, f"{ENV_LIMIT}={text}")
        try:
            return Budget(parse_bytes(text), f"{ENV_LIMIT}={text}")
        except ValueError as exc:
            raise MemoryBudgetError(f"{ENV_LIMIT}: {exc}, or 'off' to run without the memory check") from None
    found = [(v, s) for v, s in ((mem_available(), "MemAvailable"), (cgroup_headroom(), "cgroup limit")) if v is not None]
    if not found:
        return Budget(None, "unknown")
    v, s = min(found)
    return Budget(v, s)


def fits(estimate_bytes: float, budget: Budget | None = None) -> bool:
    """Whether ``estimate_bytes`` more fit in ``budget`` (default :func:`available`)."""
    budget = available() if budget is None else budget
    return budget.bytes is None or estimate_bytes <= budget.bytes


def ensure_fits(estimate_bytes: float, *, what: str, hint: str, budget: Budget | None = None) -> None:
    """Raise :class:`MemoryBudgetError` (one line) when ``estimate_bytes`` more do not fit.

    ``what`` names the work (``"25 per-projector baselines at 2592x1944"``); ``hint`` says what to do
    (``"use --no-baseline or a smaller --size"``). The message reads: ``needs about 31.2 GB for <what>,
    22.9 GB available; <hint> (or SHADOWLESS_MEMORY_LIMIT=off to try anyway)``.
    """
    budget = available() if budget is None else budget
    if fits(estimate_bytes, budget):
        return
    note = "" if budget.source in ("MemAvailable", "cgroup limit") else f" ({budget.source})"
    if budget.source == "cgroup limit":
        note = " under this process's cgroup limit"
    raise MemoryBudgetError(f"needs about {gb(estimate_bytes)} for {what}, {gb(budget.bytes)} available{note}; "
                            f"{hint} (or {ENV_LIMIT}=off to try anyway)")
