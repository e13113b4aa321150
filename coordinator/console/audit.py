"""The operator action log: who did what, when, and what came of it.

Every console action (and every login, failed or not), every show-control command over OSC and
every call of the command line that changes the rig (over gRPC, :mod:`coordinator.wire.calls`) is
one entry: the time (UTC, ISO 8601), who (the user's name, ``token`` for a login with the rig
token, as every command-line call is, ``osc:<address>`` for OSC, ``follow`` for a cue's
auto-follow, ``-`` before a login), the client's address, the action (``cli ...`` from the command
line, ``osc ...`` over OSC), its parameters, whether it worked and the result or the refusal's
reason. Entries are appended as JSON lines to ``console-actions.jsonl`` in the rig directory (one
``write`` on a file opened for appending, flushed and fsynced, in a worker thread so the event
loop keeps serving the nodes) and the last :data:`KEEP` are kept in memory for the page.

Every :class:`ActionLog` of one rig directory in a process shares the entries kept in memory (the
console's, OSC's and the gRPC service's are one log: the page shows them all), and their lines go
to the file in the order they are recorded.
"""
from __future__ import annotations

import asyncio
import json
import logging
import os
import time
import weakref
from collections import deque
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: the log's file name in the rig directory
FILE_NAME = "console-actions.jsonl"
#: entries kept in memory for the page
KEEP = 200


def _append_line(path: Path, line: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
    try:
        data = line.encode()
        os.write(fd, data)      # O_APPEND: one write lands whole at the end, even with other writers
        os.fsync(fd)
    finally:
        os.close(fd)


class _Book:
    """What the ActionLogs of one rig directory share: the newest entries, the revision, the lock."""

    def __init__(self) -> None:
        self.entries: deque[dict[str, Any]] = deque(maxlen=KEEP)
        self.revision = 0
        self._lock: tuple[Any, asyncio.Lock] | None = None     # (a weak reference to its loop, the lock)

    def lock(self) -> asyncio.Lock:
        """The lock of the running event loop (a test may run several loops one after the other)."""
        loop = asyncio.get_running_loop()
        if self._lock is None or self._lock[0]() is not loop:
            self._lock = (weakref.ref(loop), asyncio.Lock())
        return self._lock[1]


#: each rig directory's book, while an ActionLog of it lives
_BOOKS: "weakref.WeakValueDictionary[str, _Book]" = weakref.WeakValueDictionary()


class ActionLog:
    """Appends entries to ``rig_dir/console-actions.jsonl`` and keeps the newest in memory (shared
    with every other ActionLog of the same directory in this process)."""

    def __init__(self, rig_dir: str | os.PathLike[str]):
        self.path = Path(rig_dir) / FILE_NAME
        key = str(Path(rig_dir).resolve())
        book = _BOOKS.get(key)
        if book is None:
            book = _BOOKS[key] = _Book()
        self._book = book

    @property
    def entries(self) -> deque[dict[str, Any]]:
        return self._book.entries

    @property
    def revision(self) -> int:
        """Bumped by every entry (the event stream sends the log when it changes)."""
        return self._book.revision

    async def record(self, *, who: str, address: str, action: str, ok: bool, result: str = "",
                     params: dict[str, Any] | None = None) -> dict[str, Any]:
        """Log one action; returns the entry. A log file that cannot be written is logged (the
        action already happened) and the entry says so."""
        now = time.time()
        entry = {"time": datetime.fromtimestamp(now, timezone.utc).isoformat(timespec="milliseconds"),
                 "unix": round(now, 3), "who": who or "-", "address": address, "action": action,
                 "params": params or {}, "ok": bool(ok), "result": result}
        line = json.dumps(entry, ensure_ascii=False, allow_nan=False, default=str) + "\n"
        async with self._book.lock():       # lines go to the file in the order they are recorded
            try:
                await asyncio.to_thread(_append_line, self.path, line)
            except OSError as exc:
                log.error("cannot append to the console action log %s: %s", self.path, exc)
                entry["log_error"] = f"not written to {self.path.name}: {exc}"
            self._book.entries.append(entry)
            self._book.revision += 1
        return entry

    def recent(self, n: int = 50) -> list[dict[str, Any]]:
        """The newest ``n`` entries, newest first."""
        return list(reversed(list(self.entries)[-n:]))
