"""Facts about the host a process runs on, shared by the coordinator and the nodes."""
from __future__ import annotations

import functools
from pathlib import Path


@functools.lru_cache(maxsize=1)
def boot_id() -> str:
    """This boot's id (``/proc/sys/kernel/random/boot_id``); "" where the kernel has none.

    Two processes with the same boot id share CLOCK_MONOTONIC: the rig clock (a coordinator's
    monotonic clock) survives a coordinator restart on the same boot, not a reboot.
    """
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:  # pragma: no cover - non-Linux
        return ""
