"""One writer per rig directory: an advisory lock on ``DIR/.coordinator.lock``.

A coordinator holds it for as long as it serves the rig, and ``shadowless rig import`` for as
long as it writes into one, so neither overwrites the files under the other. The lock is
``flock(LOCK_EX | LOCK_NB)``: the kernel drops it when its holder exits, however it exits, so a
killed coordinator never leaves a stale lock behind. The holder writes its pid and role into the
file (``"<pid> <role>\\n"``) so the refusal can name it. The file itself stays (removing it would
let two processes lock two different files of the same name).
"""
from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

from coordinator.errors import RigError

__all__ = ["LOCK_NAME", "RigLock", "RigLockError", "holder"]

LOCK_NAME = ".coordinator.lock"
#: the role a coordinator writes; ``shadowless rig import`` writes "rig import"
COORDINATOR = "coordinator"


class RigLockError(RigError):
    """The rig directory is locked by another process; the message names it (and its pid)."""

    def __init__(self, message: str, pid: int | None):
        super().__init__(message)
        self.pid = pid


def _parse(text: str) -> tuple[int | None, str]:
    """``"<pid> <role>"`` -> (pid, role); (None, "") if unreadable."""
    pid, _, role = text.strip().partition(" ")
    return (int(pid), role.strip()) if pid.isdigit() else (None, "")


def _refusal(rig_dir: Path, pid: int | None, role: str) -> RigLockError:
    if role == COORDINATOR or not role:
        who = f"the coordinator with pid {pid}" if pid else "a coordinator (pid unknown)"
        return RigLockError(f"rig {rig_dir} is already served by {who}; stop it first", pid)
    return RigLockError(f"rig {rig_dir} is locked by `shadowless {role}` (pid {pid}); wait for it to finish", pid)


def holder(rig_dir: str | os.PathLike[str]) -> tuple[int | None, str] | None:
    """Who holds the lock of ``rig_dir``, as (pid, role), or None if nobody does. Writes nothing
    (a missing lock file is not created), so a dry run can ask."""
    f = Path(rig_dir) / LOCK_NAME
    try:
        fd = os.open(f, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _parse(os.pread(fd, 256, 0).decode(errors="replace"))
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


class RigLock:
    """The exclusive lock of rig directory ``rig_dir``, held by this process as ``role``.

    ``acquire()`` (or ``with RigLock(dir):``) takes it or raises :class:`RigLockError` naming the
    holder's pid; ``release()`` (or leaving the block) gives it back. Not re-entrant: a second
    RigLock on the same directory is refused even in the same process.
    """

    def __init__(self, rig_dir: str | os.PathLike[str], *, role: str = COORDINATOR):
        self.rig_dir = Path(rig_dir)
        self.path = self.rig_dir / LOCK_NAME
        self.role = role
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> RigLock:
        if self._fd is not None:
            return self
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise RigError(f"cannot lock rig {self.rig_dir}: {exc.strerror or exc} ({self.path})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            who = _parse(os.pread(fd, 256, 0).decode(errors="replace"))
            if who[0] is None:           # the holder has the lock but has not written its pid yet
                time.sleep(0.1)
                who = _parse(os.pread(fd, 256, 0).decode(errors="replace"))
            os.close(fd)
            raise _refusal(self.rig_dir, *who) from None
        except OSError as exc:   # e.g. a filesystem without flock
            os.close(fd)
            raise RigError(f"cannot lock rig {self.rig_dir}: {exc.strerror or exc} ({self.path})") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {self.role}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            os.ftruncate(fd, 0)          # nobody holds it: no pid to name
        finally:
            os.close(fd)                 # closing the last descriptor drops the flock

    def __enter__(self) -> RigLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
