"""DecodeAhead holds fewer large frames than its depth (node/asset_frames.py's AHEAD_BYTES), and
small ones up to its depth."""
from __future__ import annotations

import numpy as np
import pytest

from node.asset_cache import AssetCache
from node.asset_frames import AHEAD_BYTES, MIN_AHEAD, DecodeAhead, open_frames
from node.image_files import encode_png
from protos.asset_manifest import Blob, Manifest, sha256_hex


@pytest.fixture
def cache(tmp_path):
    with AssetCache(tmp_path / "cache", max_bytes=1 << 31) as c:
        yield c


def _sequence(cache: AssetCache, frames: list[np.ndarray]) -> str:
    """A PNG sequence asset in the cache, as the node fetches one."""
    files = [(f"f{i}.png", encode_png(f)) for i, f in enumerate(frames)]
    h, w, c = frames[0].shape
    m = Manifest(kind="sequence", name="budget", blobs=tuple(Blob(sha256_hex(d), len(d), n) for n, d in files),
                 width=w, height=h, channels=c, bit_depth=8, frames=len(files), fps=30.0)
    cache.begin(m.canonical(), m.asset_id)
    by_sha = {sha256_hex(d): d for _, d in files}
    for sha, _, _ in cache.missing(m.asset_id):
        cache.write_chunk(sha, 0, by_sha[sha])
        cache.finish_blob(sha)
    return m.asset_id


def _frames(n: int, h: int, w: int) -> list[np.ndarray]:
    out = []
    for i in range(n):
        f = np.zeros((h, w, 3), np.uint8)
        f[i % h, :, :] = 200 + i          # one bright row per frame: each frame its own
        out.append(f)
    return out


def test_large_frames_are_decoded_ahead_within_the_byte_budget_and_all_still_come(cache):
    h, w = 1200, 1200                     # 4.3 MB each: the budget allows 2, the floor keeps MIN_AHEAD
    assert h * w * 3 * MIN_AHEAD > AHEAD_BYTES
    frames = _frames(10, h, w)
    with DecodeAhead(open_frames(cache, _sequence(cache, frames)), depth=8) as ahead:
        ahead.want(0)
        assert ahead.wait_ahead(30)
        s = ahead.stats()
        assert s.buffered == MIN_AHEAD and s.decoded == MIN_AHEAD
        for k in range(10):
            assert ahead.wait_ahead(30)
            assert ahead.stats().buffered <= MIN_AHEAD
            assert np.array_equal(ahead.get(k, timeout=30), frames[k])
        assert ahead.stats().misses == 0


def test_small_frames_are_decoded_ahead_to_the_whole_depth(cache):
    frames = _frames(12, 36, 64)
    with DecodeAhead(open_frames(cache, _sequence(cache, frames)), depth=8) as ahead:
        ahead.want(0)
        assert ahead.wait_ahead(30)
        assert ahead.stats().buffered == 8
        assert np.array_equal(ahead.get(3, timeout=30), frames[3])
