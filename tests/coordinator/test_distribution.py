"""Assets fetched ahead of use (coordinator/distribution.py and the node's fetcher, end to end).

First the bookkeeping with plain objects: the manifest watcher, the wanted list, readiness from
reported progress, chunked blob reads and their refusals. Then real processes and sockets: a rig
of two nodes that fetch a still added before the start and a video added while running, readiness
reaching the status at once (not with the next heartbeat), a node killed in the middle of a 30 MB
blob that resumes after its restart, and the raw calls' statuses.
"""
from __future__ import annotations

import asyncio
import hashlib
import json
import math
import os
import re
import signal
from pathlib import Path

import grpc
import numpy as np
import pytest

av = pytest.importorskip("av")

from coordinator.api import AssetProgress, NodeState  # noqa: E402
from coordinator.assets import AssetStore  # noqa: E402
from coordinator.distribution import Distribution, ManifestWatcher, blob_chunks  # noqa: E402
from coordinator.rig import Rig, grid_slots, init_rig  # noqa: E402
from coordinator.app import CoordinatorApp  # noqa: E402
from coordinator.errors import Refusal, RefusalKind  # noqa: E402
from coordinator.sessions import Heartbeat, NodeInfo, NodeSession  # noqa: E402
from protos import auth, common_pb2, node_pb2, node_pb2_grpc  # noqa: E402
from protos.asset_manifest import sha256_hex  # noqa: E402
from protos.version import PROTOCOL_VERSION, SESSION_KEY  # noqa: E402
from shadowless.local import LocalRig  # noqa: E402
from waits import wait_until, wait_until_async  # noqa: E402


# ---------------------------------------------------------------- helpers
def npy_still(path: Path, shape: tuple[int, ...], seed: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, np.random.default_rng(seed).random(shape, dtype=np.float32))
    return path


def video(path: Path, frames: int = 12, w: int = 64, h: int = 48) -> Path:
    codec = next((c for c in ("libx264", "mpeg4") if c in av.codecs_available), None)
    if codec is None:
        pytest.skip("PyAV has neither libx264 nor mpeg4")
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=24)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        for i in range(frames):
            arr = np.full((h, w, 3), (i * 20) % 256, np.uint8)
            for pkt in s.encode(av.VideoFrame.from_ndarray(arr, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    return path


@pytest.fixture
def store(tmp_path) -> AssetStore:
    init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 2), width=32, height=32, content_width=32,
             content_height=32)
    return AssetStore(tmp_path / "rig")


# ---------------------------------------------------------------- bookkeeping, plain objects
def test_the_watcher_notices_adds_and_removes_and_is_quiet_otherwise(store, tmp_path):
    w = ManifestWatcher(store)
    assert w.poll() == {} and w.poll() is None            # no assets/ yet: empty, then unchanged
    a = store.add(npy_still(tmp_path / "a.npy", (4, 4, 3), 0))
    got = w.poll()
    assert list(got) == [a.asset_id] and got[a.asset_id] == a
    assert w.poll() is None
    b = store.add(npy_still(tmp_path / "b.npy", (4, 4, 3), 1))
    assert set(w.poll()) == {a.asset_id, b.asset_id}
    store.remove(a.asset_id)
    assert set(w.poll()) == {b.asset_id}


def test_a_damaged_manifest_is_left_out_with_one_warning(store, tmp_path, caplog):
    a = store.add(npy_still(tmp_path / "a.npy", (4, 4, 3), 0))
    (store.manifests_dir / f"{'f' * 64}.json").write_bytes(b"{not json")
    w = ManifestWatcher(store)
    assert list(w.poll()) == [a.asset_id]
    (store.manifests_dir / "other.txt").write_text("x")   # the listing changes, the damage is not news
    assert list(w.poll()) == [a.asset_id]
    assert caplog.text.count("its manifest is damaged") == 1


def test_the_wanted_list_is_every_asset_by_name_and_changes_revision_only_when_it_changes(store, tmp_path):
    d = Distribution(store)
    assert d.load() and d.wanted.revision == 1 and d.wanted.asset_ids == ()
    z = store.add(npy_still(tmp_path / "z.npy", (4, 4, 3), 0), name="zebra")
    a = store.add(npy_still(tmp_path / "a.npy", (4, 4, 3), 1), name="aardvark")
    assert d.load() and d.wanted.revision == 2
    assert d.wanted.asset_ids == (a.asset_id, z.asset_id) and d.wanted.pinned_ids == ()
    assert not d.load() and d.wanted.revision == 2        # nothing changed on disk
    assert not d.apply(dict(d.manifests))                  # the same set again
    store.remove(z.asset_id)
    assert asyncio.run(d.refresh()) and d.wanted.asset_ids == (a.asset_id,) and d.wanted.revision == 3


def test_readiness_counts_bytes_and_ready_assets_from_the_nodes_reports(store, tmp_path):
    d = Distribution(store)
    a = store.add(npy_still(tmp_path / "a.npy", (10, 10, 3), 0), name="a")
    b = store.add(npy_still(tmp_path / "b.npy", (20, 10, 3), 1), name="b")
    c = store.add(npy_still(tmp_path / "c.npy", (5, 10, 3), 2), name="c")
    d.load()
    ta, tb, tc = (m.total_bytes for m in (a, b, c))
    none = d.readiness(())
    assert (none.wanted, none.ready, none.bytes_have, none.bytes_total) == (3, 0, 0, ta + tb + tc)
    assert [(p.asset_id, p.name, p.have_bytes, p.ready) for p in none.assets] == [
        (a.asset_id, "a", 0, False), (b.asset_id, "b", 0, False), (c.asset_id, "c", 0, False)]
    reported = [AssetProgress(a.asset_id, have_bytes=ta, total_bytes=ta, ready=True),
                AssetProgress(b.asset_id, have_bytes=tb * 10, total_bytes=tb),          # clipped to the store's size
                AssetProgress(c.asset_id, have_bytes=7, total_bytes=0, error="failed its hash check 3 times"),
                AssetProgress("e" * 64, have_bytes=999, ready=True)]                     # not wanted: ignored
    r = d.readiness(reported)
    assert (r.wanted, r.ready, r.bytes_have, r.bytes_total) == (3, 1, ta + tb + 7, ta + tb + tc)
    assert r.assets[2].error == "failed its hash check 3 times" and r.assets[0].error == ""


def test_blob_chunks_stream_from_an_offset_and_refuse_clearly(store, tmp_path):
    m = store.add(npy_still(tmp_path / "big.npy", (300, 400, 3), 3))   # 1.44 MB: two chunks from 0
    sha, size = m.blobs[0].sha256, m.blobs[0].size
    data = store.blob_path(sha).read_bytes()

    async def collect(offset, *, blob=sha, **kw):
        return [(at, chunk) async for at, chunk in blob_chunks(store, blob, offset, **kw)]

    chunks = asyncio.run(collect(0))
    assert [at for at, _ in chunks] == [0, 1 << 20] and b"".join(c for _, c in chunks) == data
    tail = asyncio.run(collect(size - 1000, chunk_bytes=300))
    assert [len(c) for _, c in tail] == [300, 300, 300, 100] and b"".join(c for _, c in tail) == data[-1000:]
    assert asyncio.run(collect(size)) == []
    for blob, offset, kind, text in [("0" * 64, 0, RefusalKind.NOT_FOUND, "no blob 0000"),
                                     ("xyz", 0, RefusalKind.INVALID, "not a blob name"),
                                     (sha, size + 1, RefusalKind.INVALID,
                                      f"past the end of blob {sha[:12]}… ({size} bytes)")]:
        with pytest.raises(Refusal) as err:
            asyncio.run(collect(offset, blob=blob))
        assert err.value.kind == kind and text in err.value.message


def test_the_coordinator_pushes_a_changed_store_and_reports_readiness(tmp_path):
    rig = Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=32, content_height=32))
    store = AssetStore(rig.path)

    async def go():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False).coordinator
        coord.distribution.load()
        s = NodeSession(session="s", slot="r0c0", peer="test", info=NodeInfo(), instance_joins=1, joined=0.0,
                        last_seen=0.0)
        coord.by_slot["r0c0"] = coord.sessions["s"] = s
        assert not await coord.refresh_assets() and not s.wanted_event.is_set()
        m = store.add(npy_still(tmp_path / "a.npy", (8, 8, 3), 0))
        assert await coord.refresh_assets() and s.wanted_event.is_set()
        s.heartbeat = Heartbeat(assets=(AssetProgress(m.asset_id, have_bytes=100, total_bytes=m.total_bytes),))
        n0, n1 = coord.status().nodes
        assert (n0.assets_wanted, n0.assets_ready, n0.asset_bytes_have, n0.asset_bytes_total) == (1, 0, 100, m.total_bytes)
        assert n0.assets[0].name == "a"
        assert (n1.state, n1.assets_wanted, n1.asset_bytes_have) == (NodeState.EXPECTED, 1, 0)

    asyncio.run(go())


# ---------------------------------------------------------------- real processes and sockets
def cache_dirs(tmp_path: Path, slots: list[str]) -> dict[str, Path]:
    return {s: tmp_path / "caches" / s for s in slots}


def make_rig(tmp_path: Path, slots: list[str]) -> LocalRig:
    """A rig whose every node keeps its cache under tmp_path (never the home directory)."""
    dirs = cache_dirs(tmp_path, slots)
    return LocalRig(slots, tmp_path, output_size=(32, 32), content_size=(32, 32), mdns=False,
                    extra_node_args={s: ["--cache-dir", str(dirs[s]), "--cache-max", "200M"] for s in slots}).create()


async def wait_ready(rig: LocalRig, client, count: int, *, timeout: float = 120.0):
    """Until every node holds ``count`` wanted assets, all ready; the status then."""
    async def seen():
        for s, p in rig.nodes.items():
            if p.poll() is not None:
                raise RuntimeError(f"node {s} exited with {p.returncode}:\n{rig.log('node-' + s)[-3000:]}")
        st = await client.status()
        return [(n.slot, n.assets_ready, n.assets_wanted, n.asset_bytes_have) for n in st.nodes], st

    _, st = await wait_until_async(seen, lambda s: all(ready == wanted == count for _, ready, wanted, _ in s[0]),
                                   what=f"every node holding {count} assets, ready (slot, ready, wanted, bytes)",
                                   timeout=timeout)
    return st


def assert_caches_hold(store: AssetStore, dirs: dict[str, Path], manifests) -> None:
    for slot, d in dirs.items():
        for m in manifests:
            for b in m.blobs:
                cached = d / "blobs" / b.sha256[:2] / b.sha256
                assert cached.read_bytes() == store.blob_path(b.sha256).read_bytes(), f"{slot}: {b.name}"
            assert (d / "manifests" / f"{m.asset_id}.json").read_bytes() == m.canonical()


def test_two_nodes_fetch_a_still_added_before_and_a_video_added_while_running(tmp_path):
    slots = ["r0c0", "r0c1"]
    rig = make_rig(tmp_path, slots)
    store = AssetStore(rig.rig_dir)
    still = store.add(npy_still(tmp_path / "src" / "card.npy", (90, 160, 3), 0))
    try:
        rig.start_coordinator()
        for s in slots:
            rig.start_node(s)

        async def go():
            async with await rig.client() as c:
                await rig.wait_live(c)
                st = await wait_ready(rig, c, 1)
                assert [a.name for a in st.nodes[0].assets] == ["card"]
                clip = store.add(video(tmp_path / "src" / "clip.mp4"))
                st = await wait_ready(rig, c, 2)
                for n in st.nodes:
                    assert n.asset_bytes_have == n.asset_bytes_total == still.total_bytes + clip.total_bytes
                    assert {a.name for a in n.assets} == {"card", "clip"} and all(a.ready for a in n.assets)
                return clip

        clip = asyncio.run(go())
        assert_caches_hold(store, cache_dirs(tmp_path, slots), [still, clip])
        table = rig.run_cli(["status"])
        assert table.count("2/2 100%") == 2, table
        for s in slots:
            assert re.search(rf"asset {clip.asset_id[:12]}… \(clip\) ready", rig.log(f"node-{s}")), rig.log(f"node-{s}")
        assert "every node now wants 2 asset(s)" in rig.log("coordinator")
    finally:
        rig.close()


def test_readiness_reaches_the_status_at_once_not_with_the_next_heartbeat(tmp_path):
    """Heartbeats 8 s apart: an asset added once the nodes are live is reported ready by the status
    well before a second regular heartbeat could have carried it, as the ages on the coordinator's
    clock show (the node sends a heartbeat as soon as the asset is ready)."""
    hb_ms = 8000
    slots = ["r0c0", "r0c1"]
    rig = make_rig(tmp_path, slots)
    toml = rig.rig_dir / "rig.toml"
    text = toml.read_text()
    assert "heartbeat_ms = 1000" in text and "lost_after_ms = 5000" in text
    toml.write_text(text.replace("heartbeat_ms = 1000", f"heartbeat_ms = {hb_ms}")
                    .replace("lost_after_ms = 5000", f"lost_after_ms = {6 * hb_ms}"))
    store = AssetStore(rig.rig_dir)
    try:
        rig.start_coordinator()
        for s in slots:
            rig.start_node(s)

        async def go():
            async with await rig.client() as c:
                live = await rig.wait_live(c)
                assert all(n.assets_wanted == 0 and not math.isnan(n.live_age_ms) for n in live.nodes)
                m = store.add(npy_still(tmp_path / "src" / "late.npy", (60, 80, 3), 11))
                return m, await wait_ready(rig, c, 1)

        m, st = asyncio.run(go())
        for n in st.nodes:
            (a,) = n.assets
            assert a.asset_id == m.asset_id and a.ready, n
            assert 0.0 <= a.ready_age_ms <= n.live_age_ms, n
            # Live = the node's first heartbeat, before the asset existed; the next regular one was due
            # a full period later. The ready report came well within that period, so not with it.
            assert n.live_age_ms - a.ready_age_ms < hb_ms / 2, n
        d = json.loads(rig.run_cli(["status", "--json"]))
        for n in d["nodes"]:
            (item,) = n["assets"]["items"]
            assert item["ready"] and item["ready_age_ms"] is not None and n["live_age_ms"] is not None
            assert n["live_age_ms"] - item["ready_age_ms"] < hb_ms / 2, n
    finally:
        rig.close()


def test_a_node_killed_mid_blob_resumes_after_its_restart(tmp_path, capsys):
    slots = ["r0c0", "r0c1"]
    rig = make_rig(tmp_path, slots)
    dirs = cache_dirs(tmp_path, slots)
    store = AssetStore(rig.rig_dir)
    big = store.add(npy_still(tmp_path / "src" / "noise.npy", (1000, 2500, 3), 7))   # 30 MB of float32 noise
    sha, size = big.blobs[0].sha256, big.blobs[0].size
    part = dirs["r0c0"] / "blobs" / sha[:2] / f"{sha}.part"
    try:
        rig.start_coordinator()
        rig.start_node("r0c0", ["--fetch-rate", "6M"])   # slow enough to be caught in the middle
        rig.start_node("r0c1")
        def partial() -> int:
            assert rig.nodes["r0c0"].poll() is None, rig.log("node-r0c0")[-3000:]
            return part.stat().st_size if part.exists() else -1

        wait_until(partial, lambda n: n >= 6_000_000, what="6 MB of the blob's partial file on r0c0", timeout=90)
        rig.stop_node("r0c0", signal.SIGKILL)
        killed_at = part.stat().st_size
        assert 0 < killed_at < size
        before = len(rig.log("node-r0c0"))
        rig.start_node("r0c0")   # at full speed

        async def go():
            async with await rig.client() as c:
                return await wait_ready(rig, c, 1)

        asyncio.run(go())
        after = rig.log("node-r0c0")[before:]
        resumed = re.search(rf"resuming blob {sha[:12]}… at byte (\d+) of {size}", after)
        assert resumed and int(resumed.group(1)) >= killed_at, after
        assert_caches_hold(store, dirs, [big])
        assert not part.exists()
        rate = re.search(r"ready: ([\d.]+) MB fetched in ([\d.]+) s \(([\d.]+) MB/s\)", rig.log("node-r0c1"))
        assert rate, rig.log("node-r0c1")
        with capsys.disabled():
            print(f"\n30 MB asset over loopback, one node: {rate.group(1)} MB in {rate.group(2)} s "
                  f"({rate.group(3)} MB/s); r0c0 killed at byte {killed_at}, resumed at {resumed.group(1)}")
        assert float(rate.group(3)) > 1.0
    finally:
        rig.close()


async def _raw_join(stub, token: bytes, slot: str) -> str:
    cn = auth.new_nonce()
    hello = await stub.Hello(common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, client_nonce=cn, role="node",
                                                     slot=slot))
    proof = auth.client_proof(token, "node", hello.rig_id, slot, cn, hello.server_nonce)
    login = common_pb2.LoginRequest(protocol_version=PROTOCOL_VERSION, role="node", slot=slot, client_nonce=cn,
                                    server_nonce=hello.server_nonce, client_proof=proof)
    return (await stub.Join(node_pb2.JoinRequest(login=login, info=node_pb2.NodeInfo(hostname="test")))).session


def test_the_asset_calls_answer_with_clear_statuses(tmp_path):
    rig = make_rig(tmp_path, ["r0c0"])
    store = AssetStore(rig.rig_dir)
    m = store.add(npy_still(tmp_path / "src" / "a.npy", (300, 400, 3), 1))   # 1.44 MB: two chunks
    sha, size = m.blobs[0].sha256, m.blobs[0].size
    data = store.blob_path(sha).read_bytes()
    try:
        rig.start_coordinator()
        rig.wait_ready()

        async def go():
            async with grpc.aio.insecure_channel(f"127.0.0.1:{rig.port}") as ch:
                stub = node_pb2_grpc.NodeLinkStub(ch)
                with pytest.raises(grpc.aio.AioRpcError) as err:   # no session
                    [c async for c in stub.FetchBlob(node_pb2.BlobRequest(sha256=sha))]
                assert err.value.code() == grpc.StatusCode.UNAUTHENTICATED
                md = ((SESSION_KEY, await _raw_join(stub, rig.token, "r0c0")),)

                async def fetch(sha_, offset):
                    return [c async for c in stub.FetchBlob(node_pb2.BlobRequest(sha256=sha_, offset=offset), metadata=md)]

                chunks = await fetch(sha, 0)
                assert [c.offset for c in chunks] == [0, 1 << 20] and b"".join(c.data for c in chunks) == data
                assert b"".join(c.data for c in await fetch(sha, 12345)) == data[12345:]
                assert await fetch(sha, size) == []
                for sha_, offset, code, text in [("0" * 64, 0, grpc.StatusCode.NOT_FOUND, "no blob"),
                                                 (sha, size + 1, grpc.StatusCode.INVALID_ARGUMENT, "past the end"),
                                                 ("../../token", 0, grpc.StatusCode.INVALID_ARGUMENT, "not a blob name")]:
                    with pytest.raises(grpc.aio.AioRpcError) as err:
                        await fetch(sha_, offset)
                    assert err.value.code() == code and text in err.value.details(), err.value.details()
                reply = await stub.GetManifest(node_pb2.ManifestRequest(asset_id=m.asset_id), metadata=md)
                assert hashlib.sha256(reply.manifest).hexdigest() == m.asset_id
                with pytest.raises(grpc.aio.AioRpcError) as err:
                    await stub.GetManifest(node_pb2.ManifestRequest(asset_id="1" * 64), metadata=md)
                assert err.value.code() == grpc.StatusCode.NOT_FOUND

                wanted = stub.Wanted(node_pb2.StreamRequest(), metadata=md)
                first = await asyncio.wait_for(wanted.read(), 10)
                assert list(first.asset_ids) == [m.asset_id] and list(first.pinned_ids) == []
                other = store.add(npy_still(tmp_path / "src" / "b.npy", (4, 4, 3), 2))
                second = await asyncio.wait_for(wanted.read(), 10)   # the watchdog polls the store every second
                assert set(second.asset_ids) == {m.asset_id, other.asset_id} and second.revision > first.revision
                wanted.cancel()

        asyncio.run(go())
        assert sha256_hex(data) == sha and os.path.getsize(store.blob_path(sha)) == size
    finally:
        rig.close()


def test_a_corrupt_store_blob_is_reported_then_fetched_once_repaired(tmp_path):
    rig = make_rig(tmp_path, ["r0c0"])
    store = AssetStore(rig.rig_dir)
    m = store.add(npy_still(tmp_path / "src" / "card.npy", (90, 160, 3), 4))
    path = store.blob_path(m.blobs[0].sha256)
    good = path.read_bytes()
    os.chmod(path, 0o644)
    path.write_bytes(good[:-1] + bytes([good[-1] ^ 0xFF]))   # same size, wrong bytes: bit rot on the coordinator
    try:
        rig.start_coordinator()
        rig.start_node("r0c0")

        async def failing():
            async with await rig.client() as c:
                async def node():
                    (n,) = (await c.status()).nodes
                    return n

                return await wait_until_async(node, lambda n: n.assets and n.assets[0].error,
                                              what="r0c0 reporting an error for its asset")

        n = asyncio.run(failing())
        assert (n.assets_wanted, n.assets_ready) == (1, 0) and "failed its hash check 3 times" in n.assets[0].error
        log = rig.log("node-r0c0")
        assert log.count("failed its hash check, fetching again") == 2 and "giving up on it for now" in log
        table = rig.run_cli(["status"])
        assert "0/1 0%!" in table and f"r0c0: asset {m.asset_id[:12]} (card): blob" in table, table
        path.write_bytes(good)                                   # repaired; a new asset changes the wanted list
        other = store.add(npy_still(tmp_path / "src" / "b.npy", (4, 4, 3), 5))

        async def ready():
            async with await rig.client() as c:
                return await wait_ready(rig, c, 2)

        asyncio.run(ready())
        assert_caches_hold(store, cache_dirs(tmp_path, ["r0c0"]), [m, other])
    finally:
        rig.close()
