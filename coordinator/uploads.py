"""Content uploaded from an operator's machine, held until it is complete, then added as an asset.

An upload is a list of files (name, size, SHA-256) announced up front; its id is the SHA-256 of
that list, so announcing the same files again (a ``content add`` run again after a cut) finds
the bytes already received and the operator's client sends only the rest. Files arrive in
chunks, each appended at the offset the coordinator holds, into::

    assets/uploads/<upload_id>/spec.json     the announced files (written first, atomically)
    assets/uploads/<upload_id>/files/<name>  each file as received so far

:meth:`Uploads.finish` checks every file's size and SHA-256 against the announcement, adds
the files to the store (:meth:`coordinator.assets.AssetStore.add`: one file is a still or a
video, several an image sequence sorted by name) and removes the upload; content the store
refuses (a corrupt video) is refused naming the operator's file, and its upload is removed at
once. Uploads left unfinished are removed after :data:`STALE_UPLOAD_S` without a byte; what a
crash leaves of one is settled at start (:mod:`coordinator.recovery`).

Everything here blocks on the disk: the gRPC edge (:mod:`coordinator.wire.content_service`) calls it
from worker threads. One lock per upload orders its writes.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from coordinator.assets import AssetStore, copy_hashing
from coordinator.errors import AssetError
from protos.store import atomic_write_bytes
from protos.asset_manifest import Manifest, is_sha256

#: uploads without a new byte for this long are removed (by :meth:`Uploads.sweep`)
STALE_UPLOAD_S = 7 * 24 * 3600.0
#: the most files one upload may hold (an image sequence of 100k frames is an hour at 30 fps)
MAX_FILES = 100_000
#: a file name: no folders, no control characters, not hidden, at most 200 characters
_NAME = re.compile(r"^[^/\\\x00-\x1f]{1,200}$")


@dataclass(frozen=True)
class UploadFile:
    """One announced file."""

    name: str
    size: int
    sha256: str


@dataclass(frozen=True)
class AddedAsset:
    """What :meth:`Uploads.finish` made: the manifest, whether the store had it, notes for the operator."""

    manifest: Manifest
    existed: bool
    notes: tuple[str, ...] = ()


def check_spec(files: list[UploadFile]) -> None:
    """Refuse an announcement a store could not take, naming what is wrong (ValueError)."""
    if not files:
        raise ValueError("an upload needs at least one file")
    if len(files) > MAX_FILES:
        raise ValueError(f"an upload holds at most {MAX_FILES} files, not {len(files)}")
    seen = set()
    for f in files:
        if not _NAME.match(f.name) or f.name in (".", "..") or f.name.startswith("."):
            raise ValueError(f"{f.name!r} is not a plain file name (no folders, not hidden, at most 200 characters)")
        if f.name in seen:
            raise ValueError(f"the file name {f.name!r} appears twice")
        seen.add(f.name)
        if not is_sha256(f.sha256):
            raise ValueError(f"{f.name}: {f.sha256!r} is not a SHA-256 (64 lowercase hex digits)")
        if f.size < 0:
            raise ValueError(f"{f.name}: negative size")


def operator_names(text: str, folder: Path, files: list[UploadFile], sequence: str) -> str:
    """``text`` with the upload's internal paths (``…/uploads/<id>/files/NAME``, the folder) replaced
    by the names the operator announced, so a refusal names the operator's own file."""
    for base in dict.fromkeys((folder, folder.resolve())):
        for f in files:
            text = text.replace(str(base / f.name), f.name)
        text = text.replace(str(base), sequence)
    return text


def upload_id(files: list[UploadFile]) -> str:
    """The SHA-256 of the announcement's canonical JSON."""
    doc = [{"name": f.name, "sha256": f.sha256, "size": f.size} for f in files]
    return hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


class Uploads:
    """The uploads of one rig's store (see the module docstring)."""

    def __init__(self, store: AssetStore):
        self.store = store
        self.root = store.root / "uploads"
        self._locks: dict[str, threading.Lock] = {}
        self._specs: dict[str, list[UploadFile]] = {}
        self._guard = threading.Lock()

    def _lock(self, uid: str) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(uid, threading.Lock())

    def _dir(self, uid: str) -> Path:
        if not is_sha256(uid):
            raise ValueError(f"{uid!r} is not an upload id")
        return self.root / uid

    def _spec(self, uid: str) -> list[UploadFile]:
        spec = self._dir(uid) / "spec.json"      # ValueError for what is not an upload id
        cached = self._specs.get(uid)
        if cached is not None and spec.exists():
            return cached
        try:
            doc = json.loads(spec.read_text())
            files = [UploadFile(str(d["name"]), int(d["size"]), str(d["sha256"])) for d in doc["files"]]
        except FileNotFoundError:
            raise AssetError(f"no upload {uid[:12]} (finished, removed as stale, or never begun): begin it again") from None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise AssetError(" ".join(f"upload {uid[:12]} is damaged ({type(exc).__name__}: {exc}): "
                                      f"begin it again".split())) from exc
        self._specs[uid] = files
        return files

    def _have(self, uid: str, files: list[UploadFile]) -> list[int]:
        d = self._dir(uid) / "files"
        out = []
        for f in files:
            try:
                out.append(min(f.size, (d / f.name).stat().st_size))
            except FileNotFoundError:
                out.append(0)
        return out

    # ------------------------------------------------------------------ the steps
    def begin(self, files: list[UploadFile]) -> tuple[str, list[int]]:
        """Announce ``files``: the upload's id and the bytes already held of each."""
        check_spec(files)
        uid = upload_id(files)
        total = sum(f.size for f in files)
        with self._lock(uid):
            d = self._dir(uid)
            (d / "files").mkdir(parents=True, exist_ok=True)
            have = self._have(uid, files)
            free = shutil.disk_usage(d).free
            # room for the rest of the upload, and for its copy into the store
            need = total - sum(have) + total
            if need > free:
                raise AssetError(f"not enough disk space on the coordinator for this upload: it needs "
                                 f"{need / 1e9:.2f} GB, {free / 1e9:.2f} GB are free")
            spec = d / "spec.json"
            if not spec.exists():
                doc = {"files": [{"name": f.name, "size": f.size, "sha256": f.sha256} for f in files]}
                atomic_write_bytes(spec, json.dumps(doc, indent=1).encode())
            os.utime(d)
        return uid, have

    def append(self, uid: str, index: int, offset: int, data: bytes) -> int:
        """Append ``data`` to file ``index`` of upload ``uid`` at ``offset``, which must be the
        bytes held of it; the bytes held after. (No fsync: :meth:`finish` checks every hash.)"""
        files = self._spec(uid)
        if not 0 <= index < len(files):
            raise ValueError(f"upload {uid[:12]} has {len(files)} file(s), no file {index}")
        f = files[index]
        path = self._dir(uid) / "files" / f.name
        with self._lock(uid):
            have = self._have(uid, files)[index]
            if offset != have:
                raise AssetError(f"{f.name}: the coordinator holds {have} bytes, not {offset}: resume from there")
            if have + len(data) > f.size:
                raise ValueError(f"{f.name}: more than its announced {f.size} bytes")
            with open(path, "ab") as out:
                out.write(data)
            return have + len(data)

    def have(self, uid: str) -> list[int]:
        """Bytes held of each file of upload ``uid``."""
        return self._have(uid, self._spec(uid))

    def finish(self, uid: str, *, name: str | None = None, fps: float | None = None) -> AddedAsset:
        """Check the files against the announcement and add them as one asset; the upload is removed."""
        files = self._spec(uid)
        with self._lock(uid):
            have = self._have(uid, files)
            short = [f"{f.name} ({h} of {f.size} bytes)" for f, h in zip(files, have) if h != f.size]
            if short:
                raise AssetError("the upload is not complete: " + ", ".join(short[:5]) +
                                 (f" and {len(short) - 5} more" if len(short) > 5 else ""))
            folder = self._dir(uid) / "files"
            for f in files:
                with open(folder / f.name, "rb") as src:
                    digest, _ = copy_hashing(src, None)
                if digest != f.sha256:
                    (folder / f.name).unlink()       # received damaged: it must come again
                    raise AssetError(f"{f.name}: the bytes received hash to {digest[:12]}…, not the announced "
                                     f"{f.sha256[:12]}…; the file was dropped, upload it again")
            before = {aid for aid, _ in self.store.list()}
            notes: list[str] = []
            src = folder / files[0].name if len(files) == 1 else folder
            if src == folder and not name:
                name = "sequence"
            try:
                m = self.store.add(src, name=name or None, fps=fps, note=notes.append)
            except AssetError as exc:      # the content is refused: nothing of it is kept
                self._drop(uid)
                raise AssetError(operator_names(str(exc), folder, files, name or "the sequence")) from None
            finally:
                notes[:] = [operator_names(n, folder, files, name or "the sequence") for n in notes]
            self._drop(uid)
        return AddedAsset(m, m.asset_id in before, tuple(notes))

    def _drop(self, uid: str) -> None:
        """Remove upload ``uid``'s folder and forget it."""
        shutil.rmtree(self._dir(uid), ignore_errors=True)
        with self._guard:
            self._locks.pop(uid, None)
            self._specs.pop(uid, None)

    def sweep(self, *, now: float | None = None, max_age_s: float = STALE_UPLOAD_S) -> list[str]:
        """Remove uploads without a new byte for ``max_age_s``; their ids."""
        now = time.time() if now is None else now
        gone = []
        if not self.root.is_dir():
            return gone
        for d in self.root.iterdir():
            try:
                idle = now - max([d.stat().st_mtime, *(p.stat().st_mtime for p in (d / "files").glob("*"))])
            except (OSError, ValueError):
                continue
            if idle > max_age_s:
                shutil.rmtree(d, ignore_errors=True)
                gone.append(d.name)
        return gone


__all__ = ["AddedAsset", "STALE_UPLOAD_S", "UploadFile", "Uploads", "check_spec", "operator_names", "upload_id"]
