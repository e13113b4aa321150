"""Durable file writes without NumPy: a crash never leaves a half-written file.

Every write goes to a temp file in the target's folder (``.NAME.XXXXXXXX.tmp``), is fsynced, renamed
over the target, and the folder is fsynced so that the rename itself survives a power cut. Bytes,
text, JSON and batches of files (:func:`atomic_write_files`); :func:`flocked` for writers that must
take turns; :func:`remove_stale_temps` for the temp files a killed writer left.

Only the standard library, so a process that holds no NumPy (a node's network side) can write
through these as well. :mod:`protos.store` adds the NumPy savers (``.npy``, ``.npz``) on top and
re-exports these names for its importers.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import stat
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO, Iterator

__all__ = ["STALE_TEMP_S", "atomic_file", "atomic_write_bytes", "atomic_write_files", "atomic_write_json",
           "atomic_write_text", "flocked", "fsync_dir", "is_temp_name", "remove_stale_temps"]

log = logging.getLogger(__name__)

#: a temp file untouched this long was left by a writer that died (a live one writes continuously)
STALE_TEMP_S = 600.0


@contextmanager
def atomic_file(path: str | os.PathLike[str], *, mode: int = 0o644) -> Iterator[BinaryIO]:
    """Write ``path`` through a temp file in the same folder: fsync, rename, fsync the folder.

    Yields a binary file to write into (large arrays stream straight to disk). If the body
    raises, the temp file is removed and ``path`` keeps its old content.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    fsync_dir(path.parent)


def fsync_dir(path: str | os.PathLike[str]) -> None:
    """Make a rename or an unlink in folder ``path`` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_files(files: "dict[Path, bytes]", *, mode: int = 0o644) -> None:
    """Write several files, each atomically, with one fsync per file and one per folder they fill
    (:func:`atomic_write_bytes` one after the other costs two per file): every file goes to a temp
    file in its folder and is fsynced; then they are renamed in the order given, and a folder is
    fsynced before a file of another folder is renamed, so that a file naming an earlier one (a slot
    file and its LUT) never lands without it. A crash leaves each file whole, old or new (not all of
    them necessarily new); if a write fails, nothing is renamed and the temp files are removed."""
    temps: list[tuple[str, Path]] = []
    try:
        for path, data in files.items():
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
            temps.append((tmp, path))
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, mode)
    except BaseException:
        for tmp, _ in temps:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
        raise
    folder: Path | None = None
    for tmp, path in temps:
        if folder is not None and path.parent != folder:
            fsync_dir(folder)
        os.replace(tmp, path)
        folder = path.parent
    if folder is not None:
        fsync_dir(folder)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, *, mode: int = 0o644) -> None:
    with atomic_file(path, mode=mode) as f:
        f.write(data)


def atomic_write_text(path: str | os.PathLike[str], text: str, *, mode: int = 0o644) -> None:
    atomic_write_bytes(path, text.encode(), mode=mode)


def atomic_write_json(path: str | os.PathLike[str], obj: object) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


@contextmanager
def flocked(path: str | os.PathLike[str], mode: int = fcntl.LOCK_EX) -> Iterator[bool]:
    """Hold ``flock(mode)`` on the file ``path`` (made, with its folder, if missing) while the block
    runs; yields whether it was taken (always True unless ``mode`` has ``LOCK_NB`` and another
    process holds a conflicting lock)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+b") as f:
        try:
            fcntl.flock(f.fileno(), mode)
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def is_temp_name(name: str) -> bool:
    """Whether ``name`` is a temp file of :func:`atomic_file` (``.NAME.XXXXXXXX.tmp``)."""
    return name.startswith(".") and name.endswith(".tmp") and len(name) > 5


def remove_stale_temps(root: str | os.PathLike[str], *, older_than_s: float = STALE_TEMP_S,
                       skip: tuple[str, ...] = ("assets",)) -> list[Path]:
    """Delete the temp files :func:`atomic_file` left under ``root`` when its writer was killed.

    Only files named like its temp files (``.NAME.XXXXXXXX.tmp``) and untouched for
    ``older_than_s`` go; top-level folders in ``skip`` keep their own rules (the asset store sweeps
    its staging folder itself). Symlinked folders are not followed: nothing outside ``root`` goes.
    Logs the count and bytes removed once, at INFO. Returns what was removed.
    """
    root = Path(root)
    now = time.time()
    removed = []
    freed = 0
    for dirpath, dirnames, filenames in os.walk(root):
        if Path(dirpath) == root:
            dirnames[:] = [d for d in dirnames if d not in skip]
        for name in filenames:
            if not is_temp_name(name):
                continue
            f = Path(dirpath) / name
            try:
                st = f.lstat()
                if stat.S_ISREG(st.st_mode) and now - st.st_mtime >= older_than_s:
                    f.unlink()
                    removed.append(f)
                    freed += st.st_size
            except FileNotFoundError:
                pass
    if removed:
        log.info("removed %d temp file(s) (%d bytes) left by interrupted writes under %s", len(removed), freed, root)
    return removed
