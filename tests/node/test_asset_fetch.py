"""node/asset_fetch.py against a scripted coordinator link (plain objects, a real cache on disk):
fetching and pinning, resuming after a broken link, hash failures (fetched again, then given
up on), refusals, a cache that cannot be opened, and the rate limit."""
from __future__ import annotations

import asyncio
import logging

import numpy as np
import pytest
from waits import wait_until_async

from node.asset_cache import AssetCache
from node.asset_fetch import AssetFetcher
from node.link import LinkError
from node.records import BlobChunkData, WantedAssets
from protos.asset_manifest import Blob, Manifest, sha256_hex

CHUNK = 64 << 10


def make_asset(name: str, sizes: list[int], seed: int) -> tuple[str, bytes, dict[str, bytes]]:
    rng = np.random.default_rng(seed)
    datas = [rng.integers(0, 256, size=n, dtype=np.uint8).tobytes() for n in sizes]
    blobs = tuple(Blob(sha256_hex(d), len(d), f"{name}-{i}.png") for i, d in enumerate(datas))
    kind = "still" if len(datas) == 1 else "sequence"
    m = Manifest(kind=kind, name=name, blobs=blobs, width=4, height=4, channels=3, bit_depth=8, frames=len(datas),
                 fps=0.0 if kind == "still" else 24.0)
    return m.asset_id, m.canonical(), {b.sha256: d for b, d in zip(blobs, datas)}


class FakeLink:
    """The coordinator's side of the asset calls, scripted."""

    def __init__(self, manifests: dict[str, bytes], blobs: dict[str, bytes], wanted: list[str], *,
                 corrupt: dict[str, int] | None = None, break_at: int | None = None, refuse: set[str] = frozenset()):
        self.manifests, self.blobs = manifests, blobs
        self.lists = [WantedAssets(1, tuple(wanted))]
        self.corrupt = dict(corrupt or {})     # sha -> how many fetches serve a flipped byte
        self.break_at = break_at               # break the link after this many bytes in total
        self.refuse = set(refuse)
        self.sent = 0
        self.handled = 0                       # wanted lists the fetcher has handled
        self.requests: list[tuple[str, int]] = []
        self.end = asyncio.Event()
        self.new_list = asyncio.Event()

    def push(self, ids: list[str]) -> None:
        self.lists.append(WantedAssets(len(self.lists) + 1, tuple(ids)))
        self.new_list.set()

    async def wanted(self):
        i = 0
        while not self.end.is_set():
            while i < len(self.lists):
                yield self.lists[i]
                i += 1
                self.handled = i   # the fetcher asks for the next list once it has taken this one
            self.new_list.clear()
            waiters = [asyncio.ensure_future(self.end.wait()), asyncio.ensure_future(self.new_list.wait())]
            await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
            for w in waiters:
                w.cancel()

    async def get_manifest(self, asset_id: str) -> bytes:
        if asset_id not in self.manifests:
            raise LinkError("NOT_FOUND", f"no asset {asset_id}", refused=True)
        return self.manifests[asset_id]

    async def fetch_blob(self, sha256: str, offset: int):
        self.requests.append((sha256, offset))
        if sha256 in self.refuse or sha256 not in self.blobs:
            raise LinkError("NOT_FOUND", f"no blob {sha256} in the rig's asset store", refused=True)
        data = bytearray(self.blobs[sha256])
        if self.corrupt.get(sha256, 0) > 0:
            self.corrupt[sha256] -= 1
            data[-1] ^= 0xFF
        for at in range(offset, len(data), CHUNK):
            piece = bytes(data[at: at + CHUNK])
            if self.break_at is not None and self.sent + len(piece) > self.break_at:
                raise LinkError("UNAVAILABLE", "connection reset")
            self.sent += len(piece)
            yield BlobChunkData(at, piece)


async def run_until(fetcher: AssetFetcher, link: FakeLink, done) -> None:
    """Run the fetcher on ``link`` until ``done(progress)``; then end the link's wanted stream."""

    async def watch():
        await wait_until_async(fetcher.progress, done, what="the fetcher's progress to reach the test's goal")
        link.end.set()

    watcher = asyncio.create_task(watch())
    try:
        await fetcher.run(link)
    finally:
        watcher.cancel()
        await asyncio.gather(watcher, return_exceptions=True)


def all_settled(progress) -> bool:
    return bool(progress) and all(p.ready or p.error for p in progress)


def cached_bytes(cache: AssetCache, sha: str) -> bytes:
    with cache.open_blob(sha) as f:
        return f.read()


@pytest.fixture
def assets():
    a = make_asset("still", [300_000], 1)
    b = make_asset("frames", [100_000, 150_000, 100_000], 2)
    manifests = {a[0]: a[1], b[0]: b[1]}
    blobs = {**a[2], **b[2]}
    return a, b, manifests, blobs


def test_fetches_every_wanted_asset_pins_them_and_reports_progress(tmp_path, assets):
    (aid, _, ablobs), (bid, _, bblobs), manifests, blobs = assets
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    link = FakeLink(manifests, blobs, [aid, bid])
    asyncio.run(run_until(fetcher, link, lambda p: len(p) == 2 and all(x.ready for x in p)))
    progress = {p.asset_id: p for p in fetcher.progress()}
    assert progress[aid].have_bytes == progress[aid].total_bytes == 300_000 and progress[aid].name == "still"
    assert progress[bid].have_bytes == progress[bid].total_bytes == 350_000
    assert fetcher.cache.pinned == {aid, bid}
    for sha, data in blobs.items():
        assert cached_bytes(fetcher.cache, sha) == data
    assert all(off == 0 for _, off in link.requests) and len(link.requests) == 4
    fetcher.close()


def test_no_wanted_assets_never_touches_the_cache_directory(tmp_path, assets):
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    link = FakeLink({}, {}, [])

    async def go():
        task = asyncio.create_task(fetcher.run(link))
        await wait_until_async(lambda: link.handled, lambda n: n >= 1, what="the fetcher to take the empty list")
        link.end.set()
        await task

    asyncio.run(go())
    assert fetcher.progress() == () and fetcher.cache is None and not (tmp_path / "cache").exists()


def test_a_broken_link_leaves_partial_blobs_that_the_next_link_resumes(tmp_path, assets):
    (aid, _, ablobs), _, manifests, blobs = assets
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    first = FakeLink(manifests, blobs, [aid], break_at=200_000)
    with pytest.raises(LinkError):
        asyncio.run(fetcher.run(first))
    sha = next(iter(ablobs))
    on_disk = fetcher.cache.missing(aid)[0][2]
    assert on_disk == 3 * CHUNK and fetcher.progress()[0].have_bytes == on_disk and not fetcher.progress()[0].ready
    second = FakeLink(manifests, blobs, [aid])
    asyncio.run(run_until(fetcher, second, lambda p: p and p[0].ready))
    assert second.requests == [(sha, on_disk)]
    assert cached_bytes(fetcher.cache, sha) == ablobs[sha]
    fetcher.close()


def test_a_restarted_node_resumes_from_the_partial_file(tmp_path, assets):
    (aid, _, ablobs), _, manifests, blobs = assets
    sha = next(iter(ablobs))
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    with pytest.raises(LinkError):
        asyncio.run(fetcher.run(FakeLink(manifests, blobs, [aid], break_at=100_000)))
    fetcher.close()   # the process is gone; its partial file stays
    again = AssetFetcher(tmp_path / "cache", 10 << 20)
    link = FakeLink(manifests, blobs, [aid])
    asyncio.run(run_until(again, link, lambda p: p and p[0].ready))
    assert link.requests == [(sha, CHUNK)]
    assert cached_bytes(again.cache, sha) == ablobs[sha]
    again.close()


def test_a_blob_failing_its_hash_check_is_fetched_again(tmp_path, assets, caplog):
    _, (bid, _, bblobs), manifests, blobs = assets
    bad = list(bblobs)[1]
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    link = FakeLink(manifests, blobs, [bid], corrupt={bad: 2})
    with caplog.at_level(logging.INFO, logger="node"):
        asyncio.run(run_until(fetcher, link, lambda p: p and p[0].ready))
    assert [off for sha, off in link.requests if sha == bad] == [0, 0, 0]
    assert caplog.text.count("failed its hash check, fetching again") == 2
    assert cached_bytes(fetcher.cache, bad) == bblobs[bad]
    assert fetcher.progress()[0].have_bytes == 350_000
    fetcher.close()


def test_an_asset_whose_blob_keeps_failing_is_given_up_with_a_clear_message(tmp_path, assets, caplog):
    (aid, _, _), (bid, _, bblobs), manifests, blobs = assets
    bad = list(bblobs)[0]
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20, attempts=3)
    link = FakeLink(manifests, blobs, [bid, aid], corrupt={bad: 99})
    with caplog.at_level(logging.INFO, logger="node"):
        asyncio.run(run_until(fetcher, link, all_settled))
    p = {x.asset_id: x for x in fetcher.progress()}
    assert p[aid].ready and not p[bid].ready
    assert "failed its hash check 3 times" in p[bid].error and "shadowless content verify" in p[bid].error
    assert p[bid].have_bytes == 0   # the bad first blob was deleted; the fetch stopped there
    assert [sha for sha, _ in link.requests].count(bad) == 3
    assert "giving up on it for now" in caplog.text
    # a new wanted list tries it again (the operator may have repaired the store)
    link2 = FakeLink(manifests, blobs, [bid, aid])
    asyncio.run(run_until(fetcher, link2, lambda q: all(x.ready for x in q)))
    assert cached_bytes(fetcher.cache, bad) == bblobs[bad]
    fetcher.close()


def test_refused_blobs_and_manifests_give_up_on_that_asset_only(tmp_path, assets):
    (aid, _, ablobs), (bid, _, _), manifests, blobs = assets
    ghost = "ab" * 32
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    link = FakeLink(manifests, blobs, [ghost, aid, bid], refuse={next(iter(ablobs))})
    asyncio.run(run_until(fetcher, link, all_settled))
    p = {x.asset_id: x for x in fetcher.progress()}
    assert "refused its manifest (NOT_FOUND" in p[ghost].error
    assert "refused blob" in p[aid].error and "NOT_FOUND" in p[aid].error
    assert p[bid].ready
    fetcher.close()


def test_an_asset_over_the_cache_cap_is_reported(tmp_path, assets):
    (aid, _, _), (bid, _, _), manifests, blobs = assets
    fetcher = AssetFetcher(tmp_path / "cache", 400_000)
    link = FakeLink(manifests, blobs, [aid, bid])
    asyncio.run(run_until(fetcher, link, all_settled))
    p = {x.asset_id: x for x in fetcher.progress()}
    assert p[aid].ready and "over the cache cap" in p[bid].error and "--cache-max" in p[bid].error
    fetcher.close()


def test_a_cache_in_use_by_another_node_is_reported_per_asset(tmp_path, assets):
    (aid, _, _), _, manifests, blobs = assets
    with AssetCache(tmp_path / "cache", max_bytes=1 << 20):
        fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
        link = FakeLink(manifests, blobs, [aid])
        asyncio.run(run_until(fetcher, link, all_settled))
    (p,) = fetcher.progress()
    assert "in use by another process" in p.error and "--cache-dir" in p.error and link.requests == []


def test_the_rate_limit_holds_a_fetch_back(tmp_path):
    """Two fetchers side by side on one loop: the one without a limit fetches eight times the bytes
    and is done while the one held to 128 KiB/s (1.5 s for its 256 KiB) is still fetching. Without
    the limit the small fetch would end first."""
    big_id, big_manifest, big_blobs = make_asset("big", [2 << 20], 3)
    small_id, small_manifest, small_blobs = make_asset("small", [256 << 10], 4)
    free = AssetFetcher(tmp_path / "free", 10 << 20)
    held = AssetFetcher(tmp_path / "held", 10 << 20, rate=128 << 10)
    free_link = FakeLink({big_id: big_manifest}, big_blobs, [big_id])
    held_link = FakeLink({small_id: small_manifest}, small_blobs, [small_id])
    ready = lambda p: bool(p) and p[0].ready  # noqa: E731

    async def go():
        held_run = asyncio.create_task(run_until(held, held_link, ready))
        await run_until(free, free_link, ready)
        held_then = held.progress()
        await held_run
        return held_then

    held_then = asyncio.run(go())
    assert not ready(held_then), f"the rate-limited fetch ended before one eight times its size: {held_then}"
    assert cached_bytes(held.cache, next(iter(small_blobs))) == next(iter(small_blobs.values()))
    free.close()
    held.close()
