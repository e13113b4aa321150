"""``compensate_video --cluster`` on a local Dask cluster of 2 worker processes (127.0.0.1 only),
against single-machine runs of the same segments on a small room rig (4 projectors, 160x80
content, a 24-frame H.264 video with a keyframe every 5 frames, so that segments start between
keyframes and the workers seek).

Checked: a cluster run gives the bytes of a local ``--segment-frames`` run (the same asset), and
each segment is what ``compensate_sequence`` (an independent path: the frames sent as images)
computes from a cold start for that segment's frames alone; without segments the bytes differ; a
worker killed mid-segment (SIGKILL, found from the workers' own frame events) has its segment
solved again elsewhere, to the same bytes; when every worker is killed, the scattered ``L`` and
source are lost with them and sent again, to the same bytes; a cancelled cluster run resumes without solving its
finished segments again; without ``distributed`` the job fails with one line naming the extra.

The module's tests share one calibrated rig, one local run of 12-frame segments (the bytes the kill
tests' runs must give) and one cluster; each test starts and ends with both workers running, so the
tests pass alone and in any order."""
from __future__ import annotations

import asyncio
import os
import signal
import sys
import threading
import time
from fractions import Fraction

import av
import dask
import numpy as np
import pytest

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import demo_image, points_doc
from coordinator.assets import AssetStore
from coordinator.compensation.cluster_segment import TOPIC, segments
from coordinator.compensation.image_param import encode_image_array
from coordinator.jobs import JobError
from node.asset_decode import VideoDecoder, video_demuxer
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import reference_scene
from waits import wait_until, wait_until_async

distributed = pytest.importorskip("distributed")

SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]
CONTENT = (160, 80)
RATE = Fraction(24000, 1001)
FRAMES = 24
SOURCE = (192, 96)
#: a restarted worker is back in 2-4 s at load 9 on 2 cores, 10 s on a slowed host: the deadline is for a hang
RESTART_S = 180.0
# a segment's cold start: 10 iterations (not the job's default) are plenty here, where what is checked is that
# a cluster run gives the bytes of a local one, not how well a frame converges
SOLVE = {"iterations": 3, "first_iterations": 10}


def run(driver: RoomDriver, params: dict, kind: str = "compensate_video") -> dict:
    return asyncio.run(driver.run(kind, params))


def sha(store: AssetStore, name: str) -> str:
    return store.get(name).blobs[0].sha256


def decoded(store: AssetStore, name: str) -> list[np.ndarray]:
    """A compensated asset's frames through the node's own decoder."""
    m = store.get(name)
    blob = m.blobs[0]
    dec = VideoDecoder(store.blob_path(blob.sha256), frames=m.frames, channels=m.channels, bit_depth=16, rate=RATE,
                       demuxer=video_demuxer(blob.name, m.extra.get("container")))
    try:
        return [dec.read(k) for k in range(m.frames)]
    finally:
        dec.close()


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    work = tmp_path_factory.mktemp("cluster")
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=1)
    rig = make_rig(work / "rig", room, SLOTS, content_size=CONTENT)
    driver = RoomDriver(room, rig)
    run(driver, {"mode": "multiplexed", "settle_s": 0.0, "table_points": points_doc(table_points_from_truth(room))},
        "calibrate")
    run(driver, {"settle_s": 0.0}, "transport")
    wide = demo_image((SOURCE[0] + 3 * FRAMES, SOURCE[1]))
    frames = [np.ascontiguousarray(wide[:, 3 * k:3 * k + SOURCE[0]]) for k in range(FRAMES)]
    clip = work / "clip.mp4"
    with av.open(str(clip), "w") as c:
        s = c.add_stream("libx264" if "libx264" in av.codecs_available else "mpeg4", rate=RATE)
        s.height, s.width = SOURCE[1], SOURCE[0]
        s.pix_fmt = "yuv420p"
        s.options = {"g": "5"}
        for f in frames:
            for pkt in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    with av.open(str(clip)) as c:
        source_frames = [f.to_ndarray(format="rgb24") for f in c.decode(c.streams.video[0])]
    AssetStore(rig.path).add(clip, name="clip")
    return rig, driver, source_frames


@pytest.fixture(scope="module")
def local_12(setup) -> str:
    """The SHA-256 of a single-machine run of 12-frame segments (the asset "local 12"), which the
    cluster runs of the kill and resume tests must give."""
    rig, driver, _ = setup
    run(driver, {"asset": "clip", **SOLVE, "segment_frames": 12, "name": "local 12"})
    return sha(AssetStore(rig.path), "local 12")


@pytest.fixture(scope="module")
def local_cluster():
    # Dask's offload thread lives as long as the process: started here, not inside a test
    distributed.utils._offload_executor.submit(lambda: None).result()
    # A LocalCluster closes a worker's nanny for good when no worker of its name is back
    # lost-worker-timeout (15 s) after a death, and that timer is not cancelled when the worker
    # comes back: a worker killed by one test, back, then killed again by the next test had its
    # nanny closed while it was restarting on a slowed host (only 1 of 2 workers ever came back).
    # The nannies restart their workers; nothing here should give up on them.
    with dask.config.set({"distributed.deploy.lost-worker-timeout": "1 hour"}), \
            distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, host="127.0.0.1",
                                     dashboard_address=None) as c, distributed.Client(c) as client:
        yield c, client


def both_workers_running(lc, client) -> None:
    """Wait for the cluster's 2 workers to run (a killed one is restarted by its nanny); on the
    deadline, say what the scheduler and the nannies were doing."""
    def seen() -> dict:
        workers = client.scheduler_info(n_workers=-1)["workers"].values()
        return {"running": sorted(str(w["name"]) for w in workers if w["status"] == "running"),
                "nannies": {str(name): f"{n.status.name}, worker process {'alive' if n.is_alive() else 'gone'}"
                            for name, n in lc.workers.items()}}
    wait_until(seen, lambda s: len(s["running"]) == 2, what="both Dask workers running", timeout=RESTART_S)


@pytest.fixture
def cluster(local_cluster):
    """The module's cluster with both workers running, before the test and after it (a killed
    worker's restart belongs to the test that killed it)."""
    both_workers_running(*local_cluster)
    yield local_cluster
    both_workers_running(*local_cluster)


def test_segments_cut_every_n_frames():
    assert segments(10, 4) == [(0, 4), (4, 4), (8, 2)]
    assert segments(8, 4) == [(0, 4), (4, 4)] and segments(3, 10) == [(0, 3)] and segments(0, 5) == []
    for total, n in [(1, 1), (17, 5), (240, 240), (1000, 7)]:
        cut = segments(total, n)
        assert [f for s, c in cut for f in range(s, s + c)] == list(range(total))   # every frame once, in order
        assert all(s % n == 0 for s, _ in cut)


def test_a_cluster_run_gives_the_bytes_of_a_local_run_of_the_same_segments(setup, cluster):
    rig, driver, source_frames = setup
    lc, _ = cluster
    store = AssetStore(rig.path)
    local = run(driver, {"asset": "clip", **SOLVE, "segment_frames": 7, "name": "local 7"})
    out = run(driver, {"asset": "clip", **SOLVE, "segment_frames": 7, "name": "cluster 7",
                       "cluster": lc.scheduler_address})
    assert sha(store, "cluster 7") == sha(store, "local 7")
    assert out["objective_mean"] == local["objective_mean"] and out["frames"] == FRAMES
    c = out["cluster"]
    assert (c["workers"], c["segments"], c["segment_frames"], c["segments_resumed"]) == (2, 4, 7, 0)
    assert sum(w["frames"] for w in c["per_worker"].values()) == FRAMES
    # (the scale is a float64 dot product: the workers' BLAS runs 1 thread, ours maybe more)
    assert out["predicted_psnr"] == local["predicted_psnr"] and out["scale"] == pytest.approx(local["scale"], rel=1e-12)
    assert not any((rig.path / "compensation" / "video-tmp").iterdir())
    # each segment from a cold start: what compensate_sequence gives for that segment's frames alone
    got = decoded(store, "cluster 7")
    start, count = 7, 7
    frames = [encode_image_array(f, f"f{k}.png") for k, f in enumerate(source_frames[start:start + count])]
    run(driver, {"frames": frames, **SOLVE}, "compensate_sequence")
    for k in range(count):
        assert np.array_equal(got[start + k], driver.played[k]), k
    # the cut shows: warm-started from frame 6, frame 7 would be another (this one is a cold start's)
    assert not np.array_equal(got[start - 1], driver.played[0])


def _kill_mid_segment(client, killed: list, stop: threading.Event, every: bool) -> None:
    """Watch the workers' frame events; SIGKILL the first worker to report frame 1 of a segment
    (``every``: every worker then, so that the scattered ``L`` and source die with them: scattered
    data has no lineage to compute it again from). ``killed`` gets the addresses."""
    pids = client.run(os.getpid)
    since = time.time()
    while not stop.is_set():
        for at, msg in client.get_events(TOPIC):
            if at >= since and msg["done"] == 1 and msg["worker"] in pids:
                for worker in (pids if every else [msg["worker"]]):
                    os.kill(pids[worker], signal.SIGKILL)
                    killed.append(worker)
                return
        stop.wait(0.01)


def run_killing(driver: RoomDriver, client, params: dict, *, every: bool = False) -> tuple[dict, list]:
    """``compensate_video`` with ``params`` while :func:`_kill_mid_segment` watches: its result
    and the killed workers' addresses."""
    killed: list = []
    stop = threading.Event()
    watcher = threading.Thread(target=_kill_mid_segment, args=(client, killed, stop, every))
    watcher.start()
    try:
        return run(driver, params), killed
    finally:
        stop.set()
        watcher.join()


@pytest.mark.allow_leaks   # the restarted worker belongs to the module's cluster
def test_a_worker_killed_mid_segment_is_replaced_and_its_segment_solved_again(setup, cluster, local_12):
    rig, driver, _ = setup
    lc, client = cluster
    store = AssetStore(rig.path)
    params = {"asset": "clip", **SOLVE, "segment_frames": 12}
    out, killed = run_killing(driver, client, {**params, "name": "survived", "cluster": lc.scheduler_address})
    assert killed, "no worker reported a frame"
    assert out["cluster"]["segments_retried"] >= 1, out["cluster"]
    assert killed[0] not in out["cluster"]["per_worker"]   # its segment was delivered by another
    assert sha(store, "survived") == local_12


@pytest.mark.allow_leaks   # the restarted workers belong to the module's cluster
def test_inputs_lost_with_every_worker_are_sent_again_and_the_run_finishes(setup, cluster, local_12):
    rig, driver, _ = setup
    lc, client = cluster
    store = AssetStore(rig.path)
    driver.events.clear()
    out, killed = run_killing(driver, client, {"asset": "clip", **SOLVE, "segment_frames": 12, "name": "lost inputs",
                                               "cluster": lc.scheduler_address}, every=True)
    assert len(killed) == 2
    lines = [e for e in driver.events if isinstance(e, str) and "inputs were lost with a worker" in e]
    assert lines and all("sending L and the source again" in e for e in lines), driver.events
    assert not set(killed) & set(out["cluster"]["per_worker"])   # every segment came from a restarted worker
    assert sha(store, "lost inputs") == local_12


def test_a_cancelled_cluster_run_resumes_without_solving_its_finished_segments(setup, cluster, local_12):
    rig, driver, _ = setup
    lc, _ = cluster
    store = AssetStore(rig.path)
    params = {"asset": "clip", **SOLVE, "segment_frames": 12, "name": "resumed", "cluster": lc.scheduler_address}

    async def cancel_after_a_segment():
        task = asyncio.create_task(driver.run("compensate_video", params))
        # the segment's file is the event; polled finely, as the run's second segment follows soon after
        await wait_until_async(lambda: list((rig.path / "compensation" / "video-tmp").glob("*-cluster/seg-*.mkv")),
                               what="a finished segment of the cluster run", timeout=300, interval=0.005)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    driver.events.clear()
    asyncio.run(cancel_after_a_segment())
    runs = list((rig.path / "compensation" / "video-tmp").iterdir())
    assert len(runs) == 1 and runs[0].name.endswith("-cluster") and (runs[0] / "segments.json").is_file()
    kept = sorted(f.name for f in runs[0].glob("seg-*.mkv"))
    assert kept and not list(runs[0].glob("*.tmp")), kept
    out = run(driver, params)
    c = out["cluster"]
    assert c["segments_resumed"] == len(kept) == 1 and out["resumed_from"] == 12
    assert c["segments"] == 2 and sum(w["frames"] for w in c["per_worker"].values()) == FRAMES
    assert c["per_worker"]["(earlier run)"] == {"segments": 1, "frames": 12, "solve_s": pytest.approx(
        c["per_worker"]["(earlier run)"]["solve_s"])}
    assert sha(store, "resumed") == local_12


def test_without_distributed_the_job_names_the_extra(setup, monkeypatch):
    rig, driver, _ = setup
    monkeypatch.setitem(sys.modules, "distributed", None)   # `import distributed` raises ImportError
    with pytest.raises(JobError, match=r"^--cluster needs Dask distributed on the coordinator: "
                                       r"pip install 'shadowless\[cluster\]'$"):
        run(driver, {"asset": "clip", "cluster": "tcp://127.0.0.1:9"})
    assert not (rig.path / "compensation" / "video-tmp").exists() or not any(
        (rig.path / "compensation" / "video-tmp").iterdir())
