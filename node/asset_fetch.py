"""Fetching the rig's assets ahead of use, into the node's on-disk cache.

For the node's current link to the coordinator, an :class:`AssetFetcher` follows the ``Wanted``
stream (every asset this node must hold), pins that set in the cache (:mod:`node.asset_cache`:
never evicted), and for each wanted asset that is not ready fetches its manifest, then each
missing blob from where its partial file ends, one blob at a time, in chunks. A complete blob
is hashed (``finish_blob``); one whose bytes do not hash to its name is deleted and fetched
again, up to ``attempts`` times, then the fetcher gives up on that asset with a message the
heartbeat carries to ``shadowless status`` (and tries again after the next rejoin or change of
the wanted list). An asset turning ready or given up on calls ``on_change`` (the node's app
sends a heartbeat at once, so the operator sees it without waiting for the next regular one);
progress bytes never do.

It survives link loss: :meth:`AssetFetcher.run` ends with the link (the node's app rejoins and
calls it again), and every fetch resumes from the partial blobs on disk, also after the node
itself was killed. The cache is opened when the first non-empty wanted list arrives, so a rig
without assets never touches the cache directory; one that cannot be opened (another node on
the same directory, no permission) is reported per asset, and the node keeps projecting.

The event loop never waits for the disk: every cache call runs in a worker thread.
"""
from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import AsyncIterator, Callable, Protocol

from node.asset_cache import AssetCache, AssetCacheError
from node.link import LinkError
from node.records import AssetProgressRecord, BlobChunkData, WantedAssets
from protos.asset_manifest import Manifest

log = logging.getLogger("node")

#: gRPC status names by which the coordinator refuses one asset or blob (the link itself is fine)
ASSET_REFUSALS = frozenset({"NOT_FOUND", "INVALID_ARGUMENT", "FAILED_PRECONDITION", "OUT_OF_RANGE"})
#: how often a long fetch logs its progress
PROGRESS_LOG_S = 5.0


class AssetLink(Protocol):
    """What the fetcher needs of :class:`node.link.CoordinatorLink`."""

    def wanted(self) -> AsyncIterator[WantedAssets]: ...

    async def get_manifest(self, asset_id: str) -> bytes: ...

    def fetch_blob(self, sha256: str, offset: int) -> AsyncIterator[BlobChunkData]: ...


def short(h: str) -> str:
    return h[:12] + "…"


def human_bytes(n: float) -> str:
    """``120_000_000`` -> ``'120 MB'`` (decimal units, as the operator's commands print them)."""
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" or n >= 100 else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


class _GiveUp(Exception):
    """This asset cannot be fetched now; the message says why."""


class AssetFetcher:
    """Keeps the node's cache holding what the coordinator says it must (see the module docstring).

    Parameters
    ----------
    cache_dir : Path
        The node's ``--cache-dir``.
    max_bytes : int
        The node's ``--cache-max``.
    rate : float, optional
        Bytes per second to fetch at most (``--fetch-rate``); None: as fast as the link goes.
    attempts : int
        Fetches of one blob that fail their hash check before the fetcher gives up on its asset.
    open_cache : callable
        ``(directory, max_bytes) -> AssetCache`` (tests may inject one).
    on_change : callable, optional
        Called (no arguments, on the event loop) when an asset turns ready or is given up on, or the
        cache cannot be opened: what the operator must learn at once. Never for progress bytes.
    """

    def __init__(self, cache_dir: Path, max_bytes: int, *, rate: float | None = None, attempts: int = 3,
                 open_cache: Callable[[Path, int], AssetCache] | None = None,
                 on_change: Callable[[], None] | None = None):
        self.cache_dir = Path(cache_dir)
        self.max_bytes = max_bytes
        self.rate = rate
        self.attempts = attempts
        self._open_cache = open_cache or (lambda d, m: AssetCache(d, max_bytes=m))
        self.cache: AssetCache | None = None
        self._cache_error = ""
        self._wanted: WantedAssets | None = None
        self._progress: dict[str, AssetProgressRecord] = {}
        self._failed: dict[str, str] = {}
        self._current = ""   # the asset being fetched
        self._kick = asyncio.Event()
        self.on_change = on_change

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    # ---------------------------------------------------------------- what the heartbeat carries
    def progress(self) -> tuple[AssetProgressRecord, ...]:
        """One record per wanted asset, in the wanted order (cheap: no disk access)."""
        if self._wanted is None:
            return ()
        out = []
        for aid in self._wanted.asset_ids:
            p = self._progress.get(aid) or AssetProgressRecord(asset_id=aid)
            error = self._failed.get(aid) or (self._cache_error if self.cache is None else "")
            out.append(replace(p, error=error) if error != p.error else p)
        return tuple(out)

    def close(self) -> None:
        """Release the cache directory."""
        if self.cache is not None:
            self.cache.close()
            self.cache = None

    # ---------------------------------------------------------------- one link
    async def run(self, link: AssetLink) -> None:
        """Follow ``link``'s wanted list and fetch, until the link ends (returns) or breaks
        (:class:`LinkError`). Assets given up on are tried again."""
        self._failed.clear()
        self._kick = asyncio.Event()
        follow = asyncio.create_task(self._follow(link), name="assets-wanted")
        fetch = asyncio.create_task(self._fetch_loop(link), name="assets-fetch")
        try:
            done, _ = await asyncio.wait({follow, fetch}, return_when=asyncio.FIRST_COMPLETED)
            for t in done:
                t.result()
        finally:
            for t in (follow, fetch):
                t.cancel()
            await asyncio.gather(follow, fetch, return_exceptions=True)

    async def _follow(self, link: AssetLink) -> None:
        try:
            async for wanted in link.wanted():
                await self.on_wanted(wanted)
        except LinkError as exc:
            if exc.code != "UNIMPLEMENTED":
                raise
            log.warning("the coordinator does not distribute assets (an older release?): nothing fetched ahead")
            await asyncio.Event().wait()   # the rest of the session goes on

    async def on_wanted(self, wanted: WantedAssets) -> None:
        """Take a new wanted list: open the cache if needed, pin the set, note what is ready."""
        self._wanted = wanted
        self._failed.clear()
        try:
            if wanted.asset_ids or self.cache is not None:
                await self._take(wanted)
        finally:
            self._kick.set()   # the fetch loop starts over with this list

    async def _take(self, wanted: WantedAssets) -> None:
        cache = await self._ensure_cache()
        if cache is None:
            return
        try:
            await asyncio.to_thread(cache.pin, set(wanted.asset_ids) | set(wanted.pinned_ids))
        except AssetCacheError as exc:
            log.error("cannot pin the wanted assets: %s", exc)
        snapshot = await asyncio.to_thread(self._snapshot, cache, wanted.asset_ids)
        if self._wanted is wanted:   # the asset being fetched keeps its running count
            current = self._progress.get(self._current) if self._current in snapshot else None
            before = {aid for aid, p in self._progress.items() if p.ready}
            self._progress = {**snapshot, **({self._current: current} if current else {})}
            if any(p.ready and aid not in before for aid, p in self._progress.items()):
                self._changed()   # e.g. held in the cache from an earlier session
        ready = sum(p.ready for p in snapshot.values())
        total = sum(p.total_bytes for p in snapshot.values())
        log.info("the rig wants %d asset(s) on this node: %d ready in the cache%s", len(wanted.asset_ids), ready,
                 f" ({human_bytes(total)} known so far)" if total else "")

    async def _ensure_cache(self) -> AssetCache | None:
        if self.cache is None:
            try:
                self.cache = await asyncio.to_thread(self._open_cache, self.cache_dir, self.max_bytes)
                self._cache_error = ""
                log.info("asset cache %s (cap %s)", self.cache_dir, human_bytes(self.max_bytes))
            except (AssetCacheError, OSError, ValueError) as exc:
                msg = f"asset cache {self.cache_dir} unavailable: {exc}"
                if msg != self._cache_error:
                    log.error("%s; nothing is fetched until it opens (tried again on the next change)", msg)
                    self._cache_error = msg
                    self._changed()
        return self.cache

    @staticmethod
    def _snapshot(cache: AssetCache, ids: tuple[str, ...]) -> dict[str, AssetProgressRecord]:
        out = {}
        cached = set(cache.assets())
        for aid in ids:
            if aid not in cached:
                out[aid] = AssetProgressRecord(asset_id=aid)
                continue
            have, total = cache.progress(aid)
            out[aid] = AssetProgressRecord(asset_id=aid, have_bytes=have, total_bytes=total, ready=cache.ready(aid),
                                           name=cache.manifest(aid).name)
        return out

    # ---------------------------------------------------------------- fetching
    async def _fetch_loop(self, link: AssetLink) -> None:
        while True:
            self._kick.clear()
            wanted, cache = self._wanted, self.cache
            if wanted is not None and cache is not None:
                for aid in wanted.asset_ids:
                    if self._wanted is not wanted:
                        break   # a new list: start over (ready assets are skipped quickly)
                    if aid in self._failed:
                        continue
                    self._current = aid
                    try:
                        await self._fetch_asset(link, cache, aid)
                    except _GiveUp as exc:
                        self._failed[aid] = str(exc)
                        await self._reread(cache, aid)
                        log.error("asset %s: %s; giving up on it for now (tried again after the next rejoin or "
                                  "change of the rig's assets)", short(aid), exc)
                        self._changed()
                    finally:
                        self._current = ""
            if not self._kick.is_set():
                await self._kick.wait()

    async def _fetch_asset(self, link: AssetLink, cache: AssetCache, aid: str) -> None:
        m = await self._begin(link, cache, aid)
        if await asyncio.to_thread(cache.ready, aid):
            self._set(aid, m, *await asyncio.to_thread(cache.progress, aid), ready=True)
            return
        have, total = await asyncio.to_thread(cache.progress, aid)
        self._set(aid, m, have, total)
        log.info("fetching asset %s (%s) %.0f %% of %s", short(aid), m.name, 100.0 * have / max(1, total),
                 human_bytes(total))
        counts = Counter(b.sha256 for b in m.blobs)
        t0, start_have = time.monotonic(), have
        for sha, size, offset in await asyncio.to_thread(cache.missing, aid):
            await self._fetch_blob(link, cache, aid, m, sha, size, offset, counts[sha])
            if self._wanted is not None and aid not in self._wanted.asset_ids:
                log.info("asset %s (%s) is no longer wanted: stopped fetching it", short(aid), m.name)
                return
        have, total = await asyncio.to_thread(cache.progress, aid)
        ready = await asyncio.to_thread(cache.ready, aid)
        self._set(aid, m, have, total, ready=ready)
        dt = time.monotonic() - t0
        got = have - start_have
        log.info("asset %s (%s) ready: %s fetched in %.2f s (%.1f MB/s)", short(aid), m.name, human_bytes(got), dt,
                 got / 1e6 / max(dt, 1e-6))

    async def _begin(self, link: AssetLink, cache: AssetCache, aid: str) -> Manifest:
        """The asset's manifest, from the cache or fetched (and verified: it must hash to ``aid``)."""
        if aid in await asyncio.to_thread(cache.assets):
            return await asyncio.to_thread(cache.manifest, aid)
        try:
            data = await link.get_manifest(aid)
        except LinkError as exc:
            if exc.code in ASSET_REFUSALS:
                raise _GiveUp(f"the coordinator refused its manifest ({exc.code}: {exc.details})") from exc
            raise
        try:
            return await asyncio.to_thread(cache.begin, data, aid)
        except AssetCacheError as exc:
            raise _GiveUp(str(exc)) from exc

    async def _fetch_blob(self, link: AssetLink, cache: AssetCache, aid: str, m: Manifest, sha: str, size: int,
                          offset: int, copies: int) -> None:
        """Fetch one blob from ``offset`` until it is complete and verified (see the module docstring)."""
        failures = 0
        while True:
            if 0 < offset < size:
                log.info("asset %s (%s): resuming blob %s at byte %d of %d", short(aid), m.name, short(sha), offset, size)
            try:
                offset = await self._stream(link, cache, aid, m, sha, size, offset, copies)
            except LinkError as exc:
                if exc.code in ASSET_REFUSALS:
                    raise _GiveUp(f"the coordinator refused blob {short(sha)} ({exc.code}: {exc.details})") from exc
                raise
            except (AssetCacheError, OSError) as exc:   # e.g. a write racing a cancelled one, a full disk
                failures += 1
                if failures >= self.attempts:
                    raise _GiveUp(f"cannot write blob {short(sha)} to the cache: {exc}") from exc
                log.warning("asset %s: writing blob %s failed (%s); resuming from what is on disk", short(aid),
                            short(sha), exc)
                offset = await self._on_disk(cache, aid, sha)
                continue
            try:
                await asyncio.to_thread(cache.finish_blob, sha)
                return
            except AssetCacheError as exc:
                failures += 1
                short_of = offset < size
                if failures >= self.attempts:
                    if short_of:
                        raise _GiveUp(f"blob {short(sha)} ended at byte {offset} of {size} ({exc})") from exc
                    raise _GiveUp(f"blob {short(sha)} failed its hash check {failures} times: the coordinator's copy "
                                  f"may be damaged (`shadowless content verify {aid[:12]}` tells)") from exc
                if short_of:
                    log.warning("asset %s: blob %s ended at byte %d of %d; fetching the rest", short(aid), short(sha),
                                offset, size)
                else:
                    log.warning("asset %s: blob %s failed its hash check, fetching again (attempt %d of %d)",
                                short(aid), short(sha), failures + 1, self.attempts)
                offset = await self._on_disk(cache, aid, sha)

    async def _stream(self, link: AssetLink, cache: AssetCache, aid: str, m: Manifest, sha: str, size: int,
                      offset: int, copies: int) -> int:
        """Write the blob's chunks from ``offset``; the offset reached."""
        if offset >= size:
            return offset
        t0, sent0, next_log = time.monotonic(), offset, time.monotonic() + PROGRESS_LOG_S
        async for chunk in link.fetch_blob(sha, offset):
            if chunk.offset != offset:
                raise AssetCacheError(f"the coordinator sent bytes at {chunk.offset} where {offset} was expected")
            offset = await asyncio.to_thread(cache.write_chunk, sha, offset, chunk.data)
            self._add(aid, len(chunk.data) * copies)
            now = time.monotonic()
            if self.rate:
                ahead = (offset - sent0) / self.rate - (now - t0)
                if ahead > 0:
                    await asyncio.sleep(ahead)
            if now >= next_log:
                next_log = now + PROGRESS_LOG_S
                p = self._progress[aid]
                log.info("fetching asset %s (%s) %.0f %% of %s", short(aid), m.name,
                         100.0 * p.have_bytes / max(1, p.total_bytes), human_bytes(p.total_bytes))
        return offset

    async def _on_disk(self, cache: AssetCache, aid: str, sha: str) -> int:
        """Where blob ``sha`` resumes now (its partial length), and the asset's progress re-read."""
        missing = await asyncio.to_thread(cache.missing, aid)
        await self._reread(cache, aid)
        return next((off for s, _, off in missing if s == sha), 0)

    async def _reread(self, cache: AssetCache, aid: str) -> None:
        """The asset's progress from the disk (after a blob was deleted, or given up on)."""
        try:
            have, total = await asyncio.to_thread(cache.progress, aid)
        except AssetCacheError:
            return   # not begun: nothing on disk
        p = self._progress.get(aid)
        self._progress[aid] = replace(p, have_bytes=have, total_bytes=total) if p else \
            AssetProgressRecord(asset_id=aid, have_bytes=have, total_bytes=total)

    def _set(self, aid: str, m: Manifest, have: int, total: int, *, ready: bool = False) -> None:
        was = self._progress.get(aid)
        self._progress[aid] = AssetProgressRecord(asset_id=aid, have_bytes=have, total_bytes=total, ready=ready,
                                                  name=m.name)
        if ready and (was is None or not was.ready):
            self._changed()

    def _add(self, aid: str, n: int) -> None:
        p = self._progress.get(aid)
        if p is not None:
            self._progress[aid] = replace(p, have_bytes=max(0, p.have_bytes + n))

