"""Assets fetched ahead of use: which assets every node must hold, how far each node is, and
the blob bytes the nodes fetch.

Assets are added to the rig's store (:mod:`coordinator.assets`) by ``shadowless content add``,
usually in another process while the coordinator runs. The coordinator notices through a
:class:`ManifestWatcher` that it polls about once a second: one ``stat`` of
``assets/manifests`` and one listing of it, so an unchanged store costs next to nothing; a
changed listing parses only the manifests it has not seen (an asset id is the hash of its
manifest, so a manifest never changes under its name).

:class:`Distribution` turns the store's manifests into the **wanted list** every node follows
(every asset of the store, sorted by name then id, which is the order nodes fetch them in;
none pinned beyond that until the timeline schedules assets), and a node's reported
:class:`~coordinator.api.AssetProgress` into its readiness (:meth:`Distribution.readiness`),
with the age of each asset's readiness: :func:`note_ready` keeps the instant (the
coordinator's clock) each asset was first reported ready.

:func:`blob_chunks` reads a blob for the FetchBlob call: from an offset to its end, chunk by
chunk, each read in a worker thread (the event loop never waits for the disk, and a blob
never sits in memory whole).
"""
from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
from dataclasses import dataclass
from typing import AsyncIterator, BinaryIO, Iterable, Mapping

from coordinator.api import AssetProgress
from coordinator.assets import AssetStore
from coordinator.errors import Refusal, RefusalKind
from protos.asset_manifest import Manifest, ManifestError, is_sha256

log = logging.getLogger(__name__)

#: FetchBlob's chunk size
BLOB_CHUNK_BYTES = 1 << 20


@dataclass(frozen=True)
class WantedList:
    """What every node must hold: ``asset_ids`` in fetch order, ``pinned_ids`` scheduled to play
    (never evicted). ``revision`` grows with every change (0: nothing announced yet)."""

    revision: int = 0
    asset_ids: tuple[str, ...] = ()
    pinned_ids: tuple[str, ...] = ()


@dataclass(frozen=True)
class Readiness:
    """One node's progress over the wanted list."""

    wanted: int = 0
    ready: int = 0
    bytes_have: int = 0
    bytes_total: int = 0
    assets: tuple[AssetProgress, ...] = ()


def note_ready(since: dict[str, int], reported: Iterable[AssetProgress], now: int) -> bool:
    """Keep in ``since`` (asset id -> instant, e.g. rig-clock nanoseconds) when each asset was first reported ready
    on one node: a newly ready asset takes ``now``, one ready before keeps its instant, one no longer
    reported ready is forgotten (ready again later counts from then). Whether one turned ready."""
    ready = {p.asset_id for p in reported if p.ready}
    new = ready - since.keys()
    for aid in list(since):
        if aid not in ready:
            del since[aid]
    for aid in new:
        since[aid] = now
    return bool(new)


class ManifestWatcher:
    """Notices changes of a store's manifests cheaply (see the module docstring).

    Not thread-safe: one caller polls (the coordinator's watchdog, through a worker thread).
    """

    def __init__(self, store: AssetStore):
        self.store = store
        self._seen: tuple[int, frozenset[str]] | None = None
        self._manifests: dict[str, Manifest] = {}
        self._damaged: set[str] = set()

    def poll(self) -> dict[str, Manifest] | None:
        """The store's manifests (asset id -> manifest) if the directory changed since the last
        poll, else None. Damaged manifests are logged once and left out."""
        d = self.store.manifests_dir
        try:
            key = (d.stat().st_mtime_ns, frozenset(os.listdir(d)))
        except FileNotFoundError:
            key = (0, frozenset())
        if key == self._seen:
            return None
        self._seen = key
        ids = {n[: -len(".json")] for n in key[1] if n.endswith(".json") and is_sha256(n[: -len(".json")])}
        manifests = {}
        for aid in sorted(ids):
            m = self._manifests.get(aid)
            if m is None:
                m = self._load(aid)
            if m is not None:
                manifests[aid] = m
        self._manifests = manifests
        self._damaged &= ids
        return dict(manifests)

    def _load(self, aid: str) -> Manifest | None:
        try:
            return Manifest.from_bytes(self.store.manifest_path(aid).read_bytes(), asset_id=aid)
        except FileNotFoundError:
            return None   # removed between the listing and the read: the next poll sees it gone
        except (ManifestError, OSError) as exc:
            if aid not in self._damaged:
                self._damaged.add(aid)
                log.warning("asset %s: its manifest is damaged, not distributed (%s); `shadowless content verify` "
                            "tells more", aid[:12], exc)
            return None


class Distribution:
    """The wanted list and the readiness bookkeeping (see the module docstring).

    Parameters
    ----------
    store : AssetStore
        The rig's asset store.
    """

    def __init__(self, store: AssetStore):
        self.store = store
        self.watcher = ManifestWatcher(store)
        self.manifests: dict[str, Manifest] = {}
        self.wanted = WantedList()

    # ------------------------------------------------------------ the wanted list
    def load(self) -> bool:
        """Read the store now (blocking; at start). Whether the wanted list changed."""
        snapshot = self.watcher.poll()
        return self.apply(snapshot) if snapshot is not None else False

    async def refresh(self) -> bool:
        """Poll the store in a worker thread; whether the wanted list changed."""
        snapshot = await asyncio.to_thread(self.watcher.poll)
        return self.apply(snapshot) if snapshot is not None else False

    def apply(self, manifests: Mapping[str, Manifest]) -> bool:
        """Take the store's manifests; a new revision of the wanted list if its ids changed."""
        self.manifests = dict(manifests)
        ids = tuple(sorted(self.manifests, key=lambda a: (self.manifests[a].name, a)))
        if ids == self.wanted.asset_ids and self.wanted.revision:
            return False
        old = set(self.wanted.asset_ids)
        self.wanted = WantedList(revision=self.wanted.revision + 1, asset_ids=ids, pinned_ids=())
        added, removed = [a for a in ids if a not in old], old - set(ids)
        if added or removed:
            total = sum(m.total_bytes for m in self.manifests.values())
            log.info("assets changed (%s): every node now wants %d asset(s), %.1f MB",
                     ", ".join(filter(None, [f"{len(added)} added" if added else "",
                                             f"{len(removed)} removed" if removed else ""])),
                     len(ids), total / 1e6)
        return True

    # ------------------------------------------------------------ readiness
    def readiness(self, reported: Iterable[AssetProgress], *, ready_since: Mapping[str, int] | None = None,
                  now_ns: int = 0) -> Readiness:
        """A node's readiness from what it reported (its last heartbeat's assets): one entry per
        wanted asset, totals from the store's manifests (a node's own figures are only trusted for
        the bytes it has, clipped to the total). ``ready_since`` (see :func:`note_ready`, in
        nanoseconds) and ``now_ns`` (the same clock) give each ready asset's ``ready_age_ms``."""
        since = ready_since or {}
        by_id = {p.asset_id: p for p in reported}
        items = []
        for aid in self.wanted.asset_ids:
            m = self.manifests.get(aid)
            total = m.total_bytes if m is not None else 0
            r = by_id.get(aid)
            ready = bool(r is not None and r.ready)
            have = total if ready else min(total, r.have_bytes) if r is not None else 0
            at = since.get(aid) if ready else None
            items.append(AssetProgress(asset_id=aid, have_bytes=have, total_bytes=total, ready=ready,
                                       error="" if r is None or ready else r.error,
                                       name=m.name if m is not None else "",
                                       ready_age_ms=(now_ns - at) / 1e6 if at is not None else math.nan))
        return Readiness(wanted=len(items), ready=sum(p.ready for p in items),
                         bytes_have=sum(p.have_bytes for p in items), bytes_total=sum(p.total_bytes for p in items),
                         assets=tuple(items))

    # ------------------------------------------------------------ serving
    def _manifest_bytes(self, asset_id: str) -> bytes:
        if not is_sha256(asset_id):
            raise Refusal(RefusalKind.INVALID,
                             f"{asset_id!r} is not an asset id (64 lowercase hex digits)")
        m = self.manifests.get(asset_id)
        if m is not None:
            return m.canonical()
        try:   # added since the last poll
            return self.store.manifest_path(asset_id).read_bytes()
        except FileNotFoundError:
            raise Refusal(RefusalKind.NOT_FOUND,
                             f"no asset {asset_id} in the rig's store (removed?)") from None

    async def manifest_bytes(self, asset_id: str) -> bytes:
        """An asset's canonical manifest bytes; a Refusal (INVALID, NOT_FOUND) otherwise."""
        return await asyncio.to_thread(self._manifest_bytes, asset_id)

    async def blob_chunks(self, sha256: str, offset: int) -> AsyncIterator[tuple[int, bytes]]:
        """See :func:`blob_chunks`."""
        async for item in blob_chunks(self.store, sha256, offset):
            yield item


def open_blob_at(store: AssetStore, sha256: str, offset: int) -> tuple[BinaryIO, int]:
    """A store blob opened for reading, and its size; a Refusal for a malformed name (INVALID), a
    blob the store does not hold (NOT_FOUND) or an offset past its end (INVALID)."""
    if not is_sha256(sha256):
        raise Refusal(RefusalKind.INVALID,
                         f"{sha256!r} is not a blob name (64 lowercase hex digits)")
    try:
        f = open(store.blob_path(sha256), "rb")
    except FileNotFoundError:
        raise Refusal(RefusalKind.NOT_FOUND,
                         f"no blob {sha256} in the rig's asset store (its asset was removed?)") from None
    size = os.fstat(f.fileno()).st_size
    if offset < 0 or offset > size:
        f.close()
        raise Refusal(RefusalKind.INVALID,
                         f"offset {offset} is past the end of blob {sha256[:12]}… ({size} bytes): "
                         f"resume at most at {size}")
    return f, size


async def blob_chunks(store: AssetStore, sha256: str, offset: int, *,
                      chunk_bytes: int = BLOB_CHUNK_BYTES) -> AsyncIterator[tuple[int, bytes]]:
    """``(offset, bytes)`` chunks of a store blob from ``offset`` to its end, each at most
    ``chunk_bytes``, read in a worker thread; the next chunk is read while the caller sends
    this one. Refusals as :func:`open_blob_at`, raised before the first chunk."""
    f, size = await asyncio.to_thread(open_blob_at, store, sha256, offset)
    fd, guard, closed = f.fileno(), threading.Lock(), False

    def read(at: int) -> bytes:
        with guard:   # a read still running when the caller went away finishes before the close
            return b"" if closed else os.pread(fd, min(chunk_bytes, size - at), at)

    pending: asyncio.Future | None = None
    try:
        if offset < size:
            pending = asyncio.ensure_future(asyncio.to_thread(read, offset))
        while pending is not None:
            data = await pending
            pending = None
            if not data:
                break   # the file shrank under us (it never should): the node's hash check tells
            at = offset
            offset += len(data)
            if offset < size:
                pending = asyncio.ensure_future(asyncio.to_thread(read, offset))
            yield at, data
    finally:
        if pending is not None:
            pending.cancel()
        with guard:
            closed = True
            f.close()
