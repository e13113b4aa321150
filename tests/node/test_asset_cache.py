"""The node's asset cache, on real files: verified resumable downloads, LRU eviction under a
cap with pins, and consistency after a crash (a subprocess killed with SIGKILL)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from node.asset_cache import AssetCache, AssetCacheError, default_cache_dir
from node.errors import NodeError
from protos.asset_manifest import Blob, Manifest, sha256_hex

REPO = Path(__file__).resolve().parents[2]


def _blob(rng: np.random.Generator, size: int) -> bytes:
    return rng.integers(0, 256, size, dtype=np.uint8).tobytes()


def _sequence(blobs: list[bytes], name: str = "seq") -> Manifest:
    return Manifest(kind="sequence", name=name, blobs=tuple(Blob(sha256_hex(b), len(b), f"f{i:03d}.png")
                                                            for i, b in enumerate(blobs)),
                    width=4, height=4, channels=3, bit_depth=8, frames=len(blobs), fps=24.0)


def _still(data: bytes, name: str = "still") -> Manifest:
    return Manifest(kind="still", name=name, blobs=(Blob(sha256_hex(data), len(data), "img.png"),),
                    width=4, height=4, channels=3, bit_depth=8, frames=1)


def _fetch(cache: AssetCache, m: Manifest, source: dict[str, bytes], rng: np.random.Generator | None = None) -> None:
    """Download every missing blob of ``m`` from ``source`` in random chunk sizes."""
    rng = rng or np.random.default_rng(0)
    for sha, size, offset in cache.missing(m.asset_id):
        while offset < size:
            n = int(rng.integers(1, 5000))
            offset = cache.write_chunk(sha, offset, source[sha][offset:offset + n])
        cache.finish_blob(sha)


def _add(cache: AssetCache, m: Manifest, source: dict[str, bytes]) -> str:
    cache.begin(m.canonical(), m.asset_id)
    _fetch(cache, m, source)
    assert cache.ready(m.asset_id)
    return m.asset_id


def test_a_multi_blob_asset_downloaded_in_random_chunks_equals_its_source(tmp_path):
    rng = np.random.default_rng(1)
    frames = [_blob(rng, int(rng.integers(1, 60_000))) for _ in range(4)] + [b""]
    frames.append(frames[1])                        # a repeated frame: one blob, listed twice
    m = _sequence(frames)
    source = {sha256_hex(b): b for b in frames}
    with AssetCache(tmp_path / "c", max_bytes=1 << 20) as cache:
        got = cache.begin(m.canonical(), m.asset_id)
        assert got == m and not cache.ready(m.asset_id)
        todo = cache.missing(m.asset_id)
        assert [t[0] for t in todo] == list(dict.fromkeys(b.sha256 for b in m.blobs))
        assert all(off == 0 for _, _, off in todo) and cache.progress(m.asset_id) == (0, m.total_bytes)
        _fetch(cache, m, source, rng)
        assert cache.ready(m.asset_id) and cache.missing(m.asset_id) == []
        assert cache.progress(m.asset_id) == (m.total_bytes, m.total_bytes)
        for b, data in zip(m.blobs, frames):
            with cache.open_blob(b.sha256) as f:
                assert f.read() == data
            assert cache.blob_path(b.sha256).read_bytes() == data
            assert cache.blob_path(b.sha256).relative_to(tmp_path / "c") == Path("blobs", b.sha256[:2], b.sha256)
        assert (tmp_path / "c" / "manifests" / f"{m.asset_id}.json").read_bytes() == m.canonical()
        assert cache.reserved_bytes() == cache.bytes_on_disk() == sum(len(b) for b in source.values())
    with AssetCache(tmp_path / "c", max_bytes=1 << 20) as again:    # kept across a restart
        assert again.ready(m.asset_id) and again.manifest(m.asset_id) == m


def test_a_chunk_at_the_wrong_offset_or_past_the_declared_size_is_refused(tmp_path):
    data = _blob(np.random.default_rng(2), 1000)
    m = _still(data)
    sha = m.blobs[0].sha256
    with AssetCache(tmp_path, max_bytes=10_000) as cache:
        with pytest.raises(AssetCacheError, match="not part of any cached asset"):
            cache.write_chunk(sha, 0, data[:10])
        cache.begin(m.canonical(), m.asset_id)
        assert cache.write_chunk(sha, 0, data[:100]) == 100
        for off in (0, 50, 101, 200):
            with pytest.raises(AssetCacheError, match="resume at 100"):
                cache.write_chunk(sha, off, data[off:off + 10])
        with pytest.raises(AssetCacheError, match="past its declared size of 1000"):
            cache.write_chunk(sha, 100, data[100:] + b"x")
        with pytest.raises(AssetCacheError, match="incomplete: 100 of 1000"):
            cache.finish_blob(sha)
        assert cache.missing(m.asset_id) == [(sha, 1000, 100)]
        assert cache.progress(m.asset_id) == (100, 1000)
        cache.write_chunk(sha, 100, data[100:])
        cache.finish_blob(sha)
        with pytest.raises(AssetCacheError, match="already complete"):
            cache.write_chunk(sha, 1000, b"")
        assert cache.finish_blob(sha).read_bytes() == data      # idempotent


def test_a_blob_whose_bytes_do_not_hash_to_its_name_is_rejected_and_fetched_again(tmp_path):
    data = _blob(np.random.default_rng(3), 5000)
    m = _still(data)
    sha = m.blobs[0].sha256
    with AssetCache(tmp_path, max_bytes=10_000) as cache:
        cache.begin(m.canonical(), m.asset_id)
        bad = bytearray(data)
        bad[1234] ^= 0xFF
        cache.write_chunk(sha, 0, bytes(bad))
        with pytest.raises(AssetCacheError, match=f"blob {sha} failed its hash check"):
            cache.finish_blob(sha)
        assert not cache.ready(m.asset_id) and cache.missing(m.asset_id) == [(sha, 5000, 0)]
        assert list((tmp_path / "blobs").rglob("*")) == [tmp_path / "blobs" / sha[:2]]
        with pytest.raises(AssetCacheError, match="not in the cache"):
            cache.blob_path(sha)
        _fetch(cache, m, {sha: data})
        assert cache.ready(m.asset_id)


def test_verify_finds_a_blob_corrupted_on_disk_and_missing_lists_it_again(tmp_path):
    rng = np.random.default_rng(4)
    frames = [_blob(rng, 3000), _blob(rng, 2000)]
    m = _sequence(frames)
    source = {sha256_hex(b): b for b in frames}
    with AssetCache(tmp_path, max_bytes=10_000) as cache:
        _add(cache, m, source)
        assert cache.verify(m.asset_id) == []
        path = cache.blob_path(m.blobs[1].sha256)
        raw = bytearray(path.read_bytes())
        raw[7] ^= 0x01
        path.write_bytes(bytes(raw))
        assert cache.ready(m.asset_id)                  # not re-hashed until asked
        assert cache.verify(m.asset_id) == [m.blobs[1].sha256]
        assert not cache.ready(m.asset_id)
        assert cache.missing(m.asset_id) == [(m.blobs[1].sha256, 2000, 0)]
        _fetch(cache, m, source)
        assert cache.ready(m.asset_id) and cache.verify(m.asset_id) == []


def test_a_manifest_that_does_not_hash_to_its_id_is_refused(tmp_path):
    m = _still(b"hello")
    other = _still(b"world")
    with AssetCache(tmp_path, max_bytes=10_000) as cache:
        with pytest.raises(AssetCacheError, match="do not hash to asset") as info:
            cache.begin(m.canonical(), other.asset_id)
        assert isinstance(info.value, NodeError)
        loose = json.dumps(m.to_json(), indent=1).encode()      # valid JSON, hashed, but not canonical
        with pytest.raises(AssetCacheError, match="canonical"):
            cache.begin(loose, sha256_hex(loose))
        assert cache.assets() == [] and list((tmp_path / "manifests").iterdir()) == []
        with pytest.raises(AssetCacheError, match="not in the cache"):
            cache.missing(m.asset_id)


_CHILD = r"""
import sys
from node.asset_cache import AssetCache
directory, sha_done, sha_part = sys.argv[1:4]
src = {sha_done: open(sys.argv[4], "rb").read(), sha_part: open(sys.argv[5], "rb").read()}
cache = AssetCache(directory, max_bytes=1 << 24)
for sha in (sha_done, sha_part):
    offset = 0
    while offset < len(src[sha]):
        offset = cache.write_chunk(sha, offset, src[sha][offset:offset + 4096])
        if sha == sha_part:
            print(offset, flush=True)
            if offset == 20 * 4096:
                sys.stdin.read()   # the test kills this process here, 20 chunks into the blob
    cache.finish_blob(sha)
print("finished", flush=True)
"""


def test_a_download_killed_mid_write_resumes_at_its_on_disk_length_and_completes(tmp_path):
    rng = np.random.default_rng(5)
    done, part = _blob(rng, 50_000), _blob(rng, 4 << 20)
    m = _sequence([done, part])
    (tmp_path / "done.bin").write_bytes(done)
    (tmp_path / "part.bin").write_bytes(part)
    cache_dir = tmp_path / "cache"
    with AssetCache(cache_dir, max_bytes=1 << 24) as cache:
        cache.begin(m.canonical(), m.asset_id)
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(cache_dir), m.blobs[0].sha256, m.blobs[1].sha256,
                             str(tmp_path / "done.bin"), str(tmp_path / "part.bin")],
                            cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(20)]
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdin.close()
        proc.stdout.close()
        proc.stderr.close()
    last = int(lines[-1])
    assert "finished" not in lines and last == 20 * 4096
    with AssetCache(cache_dir, max_bytes=1 << 24) as cache:        # the killed child's lock is gone
        sha_part = m.blobs[1].sha256
        on_disk = (cache_dir / "blobs" / sha_part[:2] / f"{sha_part}.part").stat().st_size
        assert cache.missing(m.asset_id) == [(sha_part, len(part), on_disk)]
        assert on_disk == last < len(part)
        assert cache.blob_path(m.blobs[0].sha256).read_bytes() == done
        assert cache.progress(m.asset_id) == (len(done) + on_disk, m.total_bytes)
        with pytest.raises(AssetCacheError, match=f"resume at {on_disk}"):
            cache.write_chunk(sha_part, 0, part[:10])
        _fetch(cache, m, {m.blobs[1].sha256: part})
        assert cache.ready(m.asset_id) and cache.blob_path(sha_part).read_bytes() == part


def test_restart_cleans_up_what_a_crash_can_leave_but_never_marks_an_unchecked_blob_complete(tmp_path):
    rng = np.random.default_rng(6)
    a, b = _blob(rng, 3000), _blob(rng, 3000)
    m = _sequence([a, b])
    with AssetCache(tmp_path, max_bytes=10_000) as cache:
        cache.begin(m.canonical(), m.asset_id)
        cache.write_chunk(m.blobs[0].sha256, 0, a)      # complete length, never finished
    stray = "ab" * 32
    (tmp_path / "blobs" / "ab").mkdir()
    (tmp_path / "blobs" / "ab" / stray).write_bytes(b"orphan")          # named by no manifest
    (tmp_path / "index.json.tmp").write_bytes(b"{half")                  # a torn index write
    (tmp_path / "index.json").write_bytes(b"not json")                   # a lost index: order only
    with AssetCache(tmp_path, max_bytes=10_000) as cache:
        assert cache.assets() == [m.asset_id] and not cache.ready(m.asset_id)
        assert cache.missing(m.asset_id) == [(m.blobs[0].sha256, 3000, 3000), (m.blobs[1].sha256, 3000, 0)]
        assert not (tmp_path / "blobs" / "ab" / stray).exists() and not (tmp_path / "index.json.tmp").exists()
        cache.finish_blob(m.blobs[0].sha256)
        assert cache.missing(m.asset_id) == [(m.blobs[1].sha256, 3000, 0)]


def test_lru_evicts_the_least_recently_used_unpinned_asset_keeps_shared_blobs_and_survives_restart(tmp_path):
    rng = np.random.default_rng(7)
    a1, s, b1, c1, d1, e1 = (_blob(rng, n) for n in (800, 400, 1000, 400, 800, 900))
    source = {sha256_hex(x): x for x in (a1, s, b1, c1, d1, e1)}
    A, B, C = _sequence([a1, s], "A"), _still(b1, "B"), _sequence([c1, s], "C")
    D, E = _still(d1, "D"), _still(e1, "E")
    with AssetCache(tmp_path, max_bytes=3000) as cache:
        for x in (B, A, C):
            _add(cache, x, source)
        cache.pin([B.asset_id])                         # B is the oldest, but scheduled
        assert cache.assets() == [B.asset_id, A.asset_id, C.asset_id]
        assert cache.reserved_bytes() == 2600           # s counted once
        _add(cache, D, source)                          # 3400 > 3000: A goes, not B
        assert cache.assets() == [B.asset_id, C.asset_id, D.asset_id]
        assert cache.ready(B.asset_id) and cache.ready(C.asset_id)
        assert cache.blob_path(sha256_hex(s)).read_bytes() == s          # shared with C: kept
        with pytest.raises(AssetCacheError):
            cache.blob_path(sha256_hex(a1))
        assert not (tmp_path / "manifests" / f"{A.asset_id}.json").exists()
        assert cache.reserved_bytes() == cache.bytes_on_disk() == 2600
        cache.touch(C.asset_id)
        assert cache.assets() == [B.asset_id, D.asset_id, C.asset_id]
    with AssetCache(tmp_path, max_bytes=3000) as cache:                  # order and pins survive
        assert cache.assets() == [B.asset_id, D.asset_id, C.asset_id] and cache.pinned == {B.asset_id}
        _add(cache, E, source)                          # 3500 > 3000: D (least recent unpinned) goes
        assert cache.assets() == [B.asset_id, C.asset_id, E.asset_id]
        assert all(cache.ready(x.asset_id) for x in (B, C, E))
        cache.pin([])
        cache.touch(B.asset_id)
    with AssetCache(tmp_path, max_bytes=1500) as cache:                  # a smaller cap evicts at start
        assert cache.assets() == [B.asset_id] and cache.reserved_bytes() == 1000
        assert sorted(p.name for p in (tmp_path / "blobs").rglob("*") if p.is_file()) == [sha256_hex(b1)]


def test_pinned_assets_that_do_not_fit_are_refused_and_nothing_is_evicted(tmp_path):
    rng = np.random.default_rng(8)
    x, y, z = _blob(rng, 1200), _blob(rng, 1200), _blob(rng, 300)
    source = {sha256_hex(v): v for v in (x, y, z)}
    X, Y, Z = _still(x, "X"), _still(y, "Y"), _still(z, "Z")
    with AssetCache(tmp_path, max_bytes=2000) as cache:
        cache.pin([X.asset_id, Y.asset_id])
        _add(cache, Z, source)
        _add(cache, X, source)
        with pytest.raises(AssetCacheError, match="need 2400 bytes, over the cache cap of 2000 bytes"):
            cache.begin(Y.canonical(), Y.asset_id)
        assert cache.assets() == [Z.asset_id, X.asset_id] and cache.ready(Z.asset_id) and cache.ready(X.asset_id)
        cache.pin([Y.asset_id])                         # reschedule: now X may go, Z stays (LRU first)
        cache.touch(Z.asset_id)
        _add(cache, Y, source)
        assert cache.assets() == [Z.asset_id, Y.asset_id]
        cache.pin([])
        big = _still(_blob(rng, 2001), "big")           # too big alone
        with pytest.raises(AssetCacheError, match="asset [0-9a-f]{12} need 2001 bytes"):
            cache.begin(big.canonical(), big.asset_id)
        assert cache.assets() == [Z.asset_id, Y.asset_id] and cache.ready(Y.asset_id)


def test_one_process_per_directory_conflicting_sizes_and_the_default_location(tmp_path):
    with AssetCache(tmp_path, max_bytes=100) as cache:
        with pytest.raises(AssetCacheError, match="in use by another process"):
            AssetCache(tmp_path, max_bytes=100)
        m = _still(b"abc")
        cache.begin(m.canonical(), m.asset_id)
        liar = Manifest(kind="still", name="liar", blobs=(Blob(m.blobs[0].sha256, 4, "x.png"),),
                        width=4, height=4, channels=3, bit_depth=8, frames=1)
        with pytest.raises(AssetCacheError, match="declares blob .* as 4 bytes, another manifest says 3"):
            cache.begin(liar.canonical(), liar.asset_id)
        with pytest.raises(AssetCacheError, match="not an asset id"):
            cache.pin(["nope"])
    with pytest.raises(AssetCacheError, match="closed"):
        cache.touch(m.asset_id)
    with pytest.raises(ValueError):
        AssetCache(tmp_path, max_bytes=0)
    assert default_cache_dir({"XDG_CACHE_HOME": "/var/cache/x", "HOME": "/h"}) == Path("/var/cache/x/shadowless/assets")
    assert default_cache_dir({"HOME": "/h"}) == Path("/h/.cache/shadowless/assets")
    assert default_cache_dir({"XDG_CACHE_HOME": "rel", "HOME": "/h"}) == Path("/h/.cache/shadowless/assets")
    assert os.path.isabs(default_cache_dir())
