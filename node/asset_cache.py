"""The node's on-disk asset cache: manifests and blobs kept by hash, fetched ahead of use.

A node fetches every asset a show needs ahead of time, in chunks (the transport is not this
module's concern); this module keeps it across restarts, within a size cap. Layout::

    LOCK                              flock'ed while an AssetCache has the directory open
    index.json                        LRU use stamps and the pinned set (atomic rewrite)
    manifests/<asset_id>.json         the manifest's canonical bytes (hash == asset id)
    blobs/<sha[:2]>/<sha256>          a complete blob; only ever created by renaming a
                                      partial file whose bytes hashed to its name
    blobs/<sha[:2]>/<sha256>.part     a partial blob; its length is the resume offset

Rules, as built:

* **What counts.** Every cached manifest reserves the declared size of each of its blobs,
  counted once however many assets share it, from :meth:`AssetCache.begin` on, whether the
  blob is fetched, partial or missing. So the cap bounds the cache when every fetch is done;
  partial files are always within it (a blob never grows past its declared size).
* **Eviction.** When :meth:`AssetCache.begin` would push the reserved bytes past ``max_bytes``,
  cached assets are evicted, least recently used first (:meth:`AssetCache.touch`, and
  ``begin``, stamp a use), skipping pinned ones (:meth:`AssetCache.pin`). Evicting removes
  the manifest, then the blobs (complete or partial) no remaining asset, and not the one
  being begun, names. If the pinned assets and the new one do not fit together, nothing is
  evicted and :class:`AssetCacheError` says how many bytes they need and the cap.
  A cache opened with a smaller cap than it holds evicts at start, as far as pins allow.
* **Crash consistency.** Manifests and the index are written to a temp file, fsync'ed and
  renamed. A blob is complete only under its final name, which ``finish_blob`` gives it after
  hashing the partial file in full (and fsyncing it). At start the cache re-reads the
  directory: temp files go, a manifest whose bytes do not hash to its name goes, blobs no
  manifest names go (a crash mid-eviction), a complete blob of the wrong size goes, a partial
  longer than declared goes, a partial beside its complete blob goes; a partial blob resumes
  at its on-disk length. Use stamps are a counter (an edge computer's wall clock may jump),
  rewritten whenever the LRU order changes; a lost index only loses the order (manifests'
  modification times stand in).
* **Bit rot.** Complete blobs are not re-hashed at start (gigabytes on an SD card);
  :meth:`AssetCache.verify` re-hashes an asset's blobs and removes the bad ones, which
  :meth:`AssetCache.missing` then lists again.

One process per directory (the ``LOCK`` file enforces it): nodes sharing a machine need
distinct directories. Methods are thread-safe (one lock serialises them).
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import shutil
import threading
from pathlib import Path
from typing import BinaryIO, Iterable, Mapping

from node.errors import NodeError
from protos.asset_manifest import Manifest, ManifestError, is_sha256

__all__ = ["AssetCache", "AssetCacheError", "default_cache_dir"]
log = logging.getLogger(__name__)

_INDEX = "index.json"
_LOCK = "LOCK"
_TMP = ".tmp"
_PART = ".part"
_HASH_CHUNK = 1 << 20


class AssetCacheError(NodeError):
    """The asset cache refused an operation or found bad data; the message says which
    asset or blob and what to do."""


def default_cache_dir(environ: Mapping[str, str] | None = None) -> Path:
    """The default cache directory: ``$XDG_CACHE_HOME/shadowless/assets``, or
    ``~/.cache/shadowless/assets`` when ``XDG_CACHE_HOME`` is unset or not absolute.

    ``environ`` defaults to ``os.environ``; the directory is not created.
    """
    env = os.environ if environ is None else environ
    base = env.get("XDG_CACHE_HOME", "")
    root = Path(base) if base and os.path.isabs(base) else Path(env.get("HOME") or Path.home()) / ".cache"
    return root / "shadowless" / "assets"


def _short(h: str) -> str:
    return h[:12]


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temp file, fsync and rename."""
    tmp = path.with_name(path.name + _TMP)
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _hash_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


class AssetCache:
    """Assets fetched ahead of use, stored by hash under ``directory``, capped at ``max_bytes``.

    Parameters
    ----------
    directory : str or os.PathLike
        Where the cache lives (created if absent); the node's ``--cache-dir``. See
        :func:`default_cache_dir` for the default location.
    max_bytes : int
        The cap on the bytes the cached assets' blobs take (> 0); the node's ``--cache-max``.

    Raises :class:`AssetCacheError` when another process has the directory open, ``ValueError``
    on a bad ``max_bytes``. Use as a context manager, or :meth:`close`, to release the directory.
    """

    def __init__(self, directory: str | os.PathLike, *, max_bytes: int) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes <= 0:
            raise ValueError(f"max_bytes must be a positive integer, got {max_bytes!r}")
        self.directory = Path(directory)
        self.max_bytes = max_bytes
        self._lock = threading.RLock()
        self._manifests: dict[str, Manifest] = {}
        self._sizes: dict[str, int] = {}       # sha256 -> declared size, over cached manifests
        self._used: dict[str, int] = {}        # asset id -> use stamp (larger = more recent)
        self._clock = 0
        self._pinned: set[str] = set()
        self._lock_fd: int | None = None
        self._manifest_dir = self.directory / "manifests"
        self._blob_dir = self.directory / "blobs"
        for d in (self.directory, self._manifest_dir, self._blob_dir):
            d.mkdir(parents=True, exist_ok=True)
        self._acquire_directory()
        try:
            self._recover()
            if self._evict_to_fit({}, best_effort=True):
                self._write_index()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ life cycle

    def _acquire_directory(self) -> None:
        fd = os.open(self.directory / _LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise AssetCacheError(f"asset cache {self.directory} is in use by another process: "
                                      "give each node its own --cache-dir") from exc
            raise
        self._lock_fd = fd

    def close(self) -> None:
        """Release the directory (the index is already on disk). Idempotent."""
        with self._lock:
            if self._lock_fd is not None:
                os.close(self._lock_fd)
                self._lock_fd = None

    def __enter__(self) -> "AssetCache":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._lock_fd is None:
            raise AssetCacheError(f"asset cache {self.directory} is closed")

    def _recover(self) -> None:
        """Re-read the directory after a restart or a crash (see the module docstring)."""
        count = freed = 0
        for tmp in self.directory.rglob("*" + _TMP):
            try:
                size = tmp.lstat().st_size
                tmp.unlink()
            except OSError:
                continue
            count, freed = count + 1, freed + size
        if count:
            log.info("asset cache %s: removed %d temp file(s) (%d bytes) left by interrupted writes",
                     self.directory, count, freed)
        mtimes: dict[str, float] = {}
        for path in sorted(self._manifest_dir.iterdir()):
            asset_id = path.name.removesuffix(".json")
            try:
                if not (path.name.endswith(".json") and is_sha256(asset_id)):
                    raise ManifestError("not a manifest file name")
                m = Manifest.from_bytes(path.read_bytes(), asset_id=asset_id)
                self._check_sizes(m, asset_id)
            except (ManifestError, AssetCacheError, OSError):
                self._remove_path(path)
                continue
            self._add_manifest(asset_id, m)
            mtimes[asset_id] = path.stat().st_mtime
        self._sweep_blobs()
        index = self._read_index()
        used = {a: int(s) for a, s in index.get("used", {}).items() if a in self._manifests and isinstance(s, int)}
        # assets the index does not know (index lost, or a crash inside begin) count as oldest
        unknown = sorted((a for a in self._manifests if a not in used), key=lambda a: (mtimes[a], a))
        floor = min(used.values(), default=0) - len(unknown)
        for i, a in enumerate(unknown):
            used[a] = floor + i
        self._used = used
        clock = index.get("clock", 0)
        self._clock = max([clock if isinstance(clock, int) else 0, *used.values()])
        self._pinned = {a for a in index.get("pinned", []) if isinstance(a, str) and is_sha256(a)}

    def _sweep_blobs(self) -> None:
        for sub in list(self._blob_dir.iterdir()):
            if not sub.is_dir():
                sub.unlink(missing_ok=True)
                continue
            for path in list(sub.iterdir()):
                sha = path.name.removesuffix(_PART)
                partial = path.name.endswith(_PART)
                declared = self._sizes.get(sha)
                if declared is None or sha[:2] != sub.name or not path.is_file():
                    self._remove_path(path)
                    continue
                size = path.stat().st_size
                if partial and (size > declared or self._final(sha).exists()):
                    path.unlink(missing_ok=True)
                elif not partial and size != declared:
                    path.unlink(missing_ok=True)

    @staticmethod
    def _remove_path(path: Path) -> None:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)

    def _read_index(self) -> dict:
        try:
            doc = json.loads((self.directory / _INDEX).read_bytes())
        except (OSError, ValueError):
            return {}
        return doc if isinstance(doc, dict) and doc.get("version") == 1 else {}

    def _write_index(self) -> None:
        doc = {"version": 1, "clock": self._clock, "used": dict(sorted(self._used.items())),
               "pinned": sorted(self._pinned)}
        _write_atomic(self.directory / _INDEX, json.dumps(doc, indent=1).encode())

    # ------------------------------------------------------------------ bookkeeping

    def _final(self, sha: str) -> Path:
        return self._blob_dir / sha[:2] / sha

    def _part(self, sha: str) -> Path:
        return self._blob_dir / sha[:2] / (sha + _PART)

    def _check_sizes(self, m: Manifest, asset_id: str) -> None:
        """Refuse a manifest that declares a known blob with another size."""
        seen: dict[str, int] = {}
        for b in m.blobs:
            known = self._sizes.get(b.sha256, seen.get(b.sha256, b.size))
            if known != b.size:
                raise AssetCacheError(f"asset {_short(asset_id)} declares blob {_short(b.sha256)} as {b.size} bytes, "
                                      f"another manifest says {known}: one of them is wrong")
            seen[b.sha256] = b.size

    def _add_manifest(self, asset_id: str, m: Manifest) -> None:
        self._manifests[asset_id] = m
        for b in m.blobs:
            self._sizes[b.sha256] = b.size

    def _manifest(self, asset_id: str) -> Manifest:
        m = self._manifests.get(asset_id)
        if m is None:
            raise AssetCacheError(f"asset {_short(asset_id)} is not in the cache: begin it first")
        return m

    def _declared(self, sha: str) -> int:
        size = self._sizes.get(sha)
        if size is None:
            raise AssetCacheError(f"blob {_short(sha)} is not part of any cached asset "
                                  "(begin its asset first; it may have been evicted)")
        return size

    def _partial_size(self, sha: str) -> int:
        try:
            return self._part(sha).stat().st_size
        except FileNotFoundError:
            return 0

    def _have(self, sha: str) -> int:
        """Bytes of ``sha`` on disk: its declared size when complete, else the partial length."""
        return self._sizes[sha] if self._final(sha).exists() else self._partial_size(sha)

    def _blobs_of(self, asset_ids: Iterable[str]) -> dict[str, int]:
        out: dict[str, int] = {}
        for a in asset_ids:
            for b in self._manifests[a].blobs:
                out[b.sha256] = b.size
        return out

    def _stamp(self, asset_id: str) -> bool:
        """Mark a use; whether the LRU order changed."""
        newest = max(self._used, key=self._used.__getitem__, default=None)
        if newest == asset_id:
            return False
        self._clock += 1
        self._used[asset_id] = self._clock
        return True

    # ------------------------------------------------------------------ eviction

    def _evict_to_fit(self, new_blobs: dict[str, int], *, best_effort: bool, new_id: str = "") -> list[str]:
        """Evict least recently used unpinned assets until the cached blobs plus ``new_blobs``
        (sha256 -> size) fit in the cap; return the evicted ids (the caller writes the index).
        Raises, evicting nothing, when the pinned assets and the new one alone exceed the cap
        (unless ``best_effort``: then it evicts what it may)."""
        protected = {a for a in self._manifests if a in self._pinned}
        needed = sum({**self._blobs_of(protected), **new_blobs}.values())
        if needed > self.max_bytes and not best_effort:
            what = f"asset {_short(new_id)} and the {len(protected)} pinned asset(s) in the cache" if protected \
                else f"asset {_short(new_id)}"
            raise AssetCacheError(f"{what} need {needed} bytes, over the cache cap of {self.max_bytes} bytes: "
                                  "raise --cache-max or schedule fewer assets; nothing was evicted")
        evicted = []
        candidates = sorted((a for a in self._manifests if a not in protected), key=self._used.__getitem__)
        for victim in candidates:
            if sum({**self._sizes, **new_blobs}.values()) <= self.max_bytes:
                break
            self._evict(victim, keep=new_blobs)
            evicted.append(victim)
        return evicted

    def _evict(self, asset_id: str, *, keep: Mapping[str, int]) -> None:
        m = self._manifests.pop(asset_id)
        self._used.pop(asset_id, None)
        (self._manifest_dir / f"{asset_id}.json").unlink(missing_ok=True)
        still_named = set(self._blobs_of(self._manifests)) | set(keep)
        for b in m.blobs:
            if b.sha256 not in still_named:
                self._sizes.pop(b.sha256, None)
                self._final(b.sha256).unlink(missing_ok=True)
                self._part(b.sha256).unlink(missing_ok=True)

    # ------------------------------------------------------------------ assets

    def begin(self, manifest_bytes: bytes, asset_id: str) -> Manifest:
        """Start (or resume) caching an asset: verify and store its manifest, making room.

        Parameters
        ----------
        manifest_bytes : bytes
            The manifest's canonical JSON, as the coordinator sent it.
        asset_id : str
            The asset id it must hash to (64 lowercase hex digits).

        Returns
        -------
        Manifest
            The parsed manifest; :meth:`missing` says what to fetch.

        Raises
        ------
        AssetCacheError
            The bytes do not hash to ``asset_id`` or are not a valid canonical manifest; the
            manifest declares a cached blob with another size; or the pinned assets and this
            one do not fit in the cap (nothing is evicted then).
        """
        with self._lock:
            self._check_open()
            try:
                m = Manifest.from_bytes(bytes(manifest_bytes), asset_id=asset_id)
            except ManifestError as exc:
                raise AssetCacheError(f"refused the manifest of asset {str(asset_id)[:12]}: {exc}") from exc
            if asset_id in self._manifests:
                if self._stamp(asset_id):
                    self._write_index()
                return self._manifests[asset_id]
            self._check_sizes(m, asset_id)
            self._evict_to_fit({b.sha256: b.size for b in m.blobs}, best_effort=False, new_id=asset_id)
            self._add_manifest(asset_id, m)
            self._stamp(asset_id)
            # index first: a crash before the manifest lands leaves a stamp the next start drops
            self._write_index()
            _write_atomic(self._manifest_dir / f"{asset_id}.json", m.canonical())
            return m

    def manifest(self, asset_id: str) -> Manifest:
        """The cached manifest of ``asset_id``; :class:`AssetCacheError` if it is not cached."""
        with self._lock:
            return self._manifest(asset_id)

    def assets(self) -> list[str]:
        """Cached asset ids, least recently used first."""
        with self._lock:
            return sorted(self._manifests, key=lambda a: (self._used[a], a))

    def missing(self, asset_id: str) -> list[tuple[str, int, int]]:
        """Blobs of ``asset_id`` still to fetch, in manifest order, each once.

        Returns
        -------
        list of (str, int, int)
            ``(sha256, size, offset)``: the blob, its declared size and the offset to resume
            at (the partial file's length; 0 when nothing is on disk). A partial blob whose
            length equals its size is listed too: it awaits :meth:`finish_blob`.
        """
        with self._lock:
            out, seen = [], set()
            for b in self._manifest(asset_id).blobs:
                if b.sha256 in seen or self._final(b.sha256).exists():
                    continue
                seen.add(b.sha256)
                out.append((b.sha256, b.size, self._partial_size(b.sha256)))
            return out

    def ready(self, asset_id: str) -> bool:
        """Whether the manifest and every blob of ``asset_id`` are in the cache, complete."""
        with self._lock:
            m = self._manifests.get(asset_id)
            return m is not None and all(self._final(b.sha256).exists() for b in m.blobs)

    def progress(self, asset_id: str) -> tuple[int, int]:
        """``(bytes_have, bytes_total)`` for ``asset_id``, over its blob list as declared
        (a blob listed twice counts twice, like :attr:`Manifest.total_bytes`)."""
        with self._lock:
            m = self._manifest(asset_id)
            return sum(self._have(b.sha256) for b in m.blobs), m.total_bytes

    def touch(self, asset_id: str) -> None:
        """Mark ``asset_id`` as used now (it becomes the last to be evicted); the order is
        written to the index when it changes."""
        with self._lock:
            self._check_open()
            self._manifest(asset_id)
            if self._stamp(asset_id):
                self._write_index()

    def pin(self, asset_ids: Iterable[str]) -> None:
        """Replace the pinned set: the assets scheduled to play, never evicted. Ids need not
        be cached yet. Persisted in the index."""
        with self._lock:
            self._check_open()
            ids = set(asset_ids)
            bad = sorted(a for a in ids if not is_sha256(a))
            if bad:
                raise AssetCacheError(f"cannot pin {bad[0]!r}: not an asset id (64 lowercase hex digits)")
            if ids != self._pinned:
                self._pinned = ids
                self._write_index()

    @property
    def pinned(self) -> frozenset[str]:
        """The pinned asset ids."""
        return frozenset(self._pinned)

    def reserved_bytes(self) -> int:
        """Bytes the cached assets' blobs take once fetched (each blob once): what the cap bounds."""
        with self._lock:
            return sum(self._sizes.values())

    def bytes_on_disk(self) -> int:
        """Bytes of complete and partial blob files now on disk."""
        with self._lock:
            return sum(self._have(sha) for sha in self._sizes)

    # ------------------------------------------------------------------ blobs

    def write_chunk(self, sha256: str, offset: int, data: bytes) -> int:
        """Append ``data`` to the partial file of blob ``sha256``.

        Parameters
        ----------
        sha256 : str
            A blob of a cached (begun) asset.
        offset : int
            Where ``data`` starts in the blob: must equal the partial file's length.
        data : bytes
            The chunk.

        Returns
        -------
        int
            The partial file's new length.

        Raises
        ------
        AssetCacheError
            The blob is not named by a cached asset, is already complete, ``offset`` is not
            the partial length (the message says where to resume), or the chunk would grow
            the blob past its declared size.
        """
        with self._lock:
            self._check_open()
            declared = self._declared(sha256)
            if self._final(sha256).exists():
                raise AssetCacheError(f"blob {_short(sha256)} is already complete")
            have = self._partial_size(sha256)
            if offset != have:
                raise AssetCacheError(f"chunk of blob {_short(sha256)} starts at offset {offset}, but {have} bytes "
                                      f"are on disk: resume at {have}")
            if offset + len(data) > declared:
                raise AssetCacheError(f"chunk would grow blob {_short(sha256)} to {offset + len(data)} bytes, "
                                      f"past its declared size of {declared}")
            part = self._part(sha256)
            part.parent.mkdir(exist_ok=True)
            fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
            finally:
                os.close(fd)
            return offset + len(data)

    def finish_blob(self, sha256: str) -> Path:
        """Check a fully written partial blob against its hash and move it into place.

        Returns
        -------
        pathlib.Path
            The complete blob's path (also when it was already complete).

        Raises
        ------
        AssetCacheError
            The blob is not named by a cached asset; the partial file is shorter than
            declared (kept, to resume); or its bytes do not hash to ``sha256`` (the partial
            file is deleted: fetch the blob again from offset 0).
        """
        with self._lock:
            self._check_open()
            declared = self._declared(sha256)
            final, part = self._final(sha256), self._part(sha256)
            if final.exists():
                return final
            if declared == 0 and not part.exists():
                part.parent.mkdir(exist_ok=True)
                part.touch()
            have = self._partial_size(sha256)
            if have != declared:
                raise AssetCacheError(f"blob {_short(sha256)} is incomplete: {have} of {declared} bytes on disk")
            got = _hash_file(part)
            if got != sha256:
                part.unlink(missing_ok=True)
                raise AssetCacheError(f"blob {sha256} failed its hash check (its bytes hash to {_short(got)}): "
                                      "deleted, fetch it again")
            with open(part, "rb+") as f:
                os.fsync(f.fileno())
            os.replace(part, final)
            _fsync_dir(final.parent)
            return final

    def blob_path(self, sha256: str) -> Path:
        """The path of a complete blob; :class:`AssetCacheError` if it is not complete."""
        with self._lock:
            final = self._final(sha256) if is_sha256(sha256) else None
            if final is None or sha256 not in self._sizes or not final.exists():
                raise AssetCacheError(f"blob {str(sha256)[:12]} is not in the cache")
            return final

    def open_blob(self, sha256: str) -> BinaryIO:
        """Open a complete blob for reading (binary); the caller closes it. An open blob
        stays readable even if it is evicted meanwhile."""
        with self._lock:
            return open(self.blob_path(sha256), "rb")

    def verify(self, asset_id: str) -> list[str]:
        """Re-hash every complete blob of ``asset_id``; remove those whose bytes are wrong.

        Returns
        -------
        list of str
            The removed blobs (each once); :meth:`missing` lists them again.
        """
        with self._lock:
            self._check_open()
            bad = []
            for b in self._manifest(asset_id).blobs:
                final = self._final(b.sha256)
                if b.sha256 in bad or not final.exists():
                    continue
                if final.stat().st_size != b.size or _hash_file(final) != b.sha256:
                    final.unlink(missing_ok=True)
                    bad.append(b.sha256)
            return bad
