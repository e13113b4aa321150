"""The ``compensate_video`` job on a small in-process room rig (4 projectors, 160x80 content): a
generated 8-frame video asset compensated into a 16-bit FFV1 asset that the store lists, whose
frames the node's own decoder gives back bit-exactly as the solutions (the same frames
``compensate_sequence`` plays), at the source's exact frame rate; refusals; a cancelled run
leaves nothing in the store and resumes to the same bytes; the command line; a node process
playing the asset by timeline; and the FFV1 writer's round trip and segment joining.

The tests of this module share one calibrated rig with a measured light transport and run in
file order."""
from __future__ import annotations

import argparse
import asyncio
import io
import json
import re
from fractions import Fraction

import av
import numpy as np
import pytest

from bench.calibration import make_rig, table_points_from_truth
from bench.compensation_room import demo_image, points_doc
from coordinator.asset_probe import probe_video
from coordinator.assets import AssetStore
from rigctl import compensation_cli as cli
from coordinator.compensation.image_param import encode_image_array
from coordinator.compensation.options import VideoOptions
from coordinator.compensation.video_io import Ffv1Writer, join_segments
from coordinator.jobs import JobError
from coordinator.jobs.options import parse_options
from coordinator.show import manifest_rate
from node.asset_decode import VideoDecoder, video_demuxer
from shadowless.local import LocalRig
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import reference_scene
from waits import wait_until_async

SLOTS = ["r1c1", "r1c3", "r3c1", "r3c3"]
CONTENT = (160, 80)
RATE = Fraction(24000, 1001)
FRAMES = 8
SOURCE = (192, 96)   # not the content size: frames are resized as the other jobs do
SWAP = re.compile(r"timing frame (\d+): swap")


class WatchedEvents(list):
    """A driver's event list that sets :attr:`seen` once an event satisfies ``done`` (a job delivers its
    events on the loop, so the test's coroutine wakes on the very event)."""

    def __init__(self, done) -> None:
        super().__init__()
        self.done, self.seen = done, asyncio.Event()

    def append(self, event) -> None:
        super().append(event)
        if self.done(event):
            self.seen.set()


def write_source(path, frames: list[np.ndarray], rate: Fraction = RATE) -> None:
    """An H.264 (or MPEG-4) yuv420p video of ``frames`` (H, W, 3) uint8."""
    codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=rate)
        s.height, s.width = frames[0].shape[:2]
        s.pix_fmt = "yuv420p"
        for f in frames:
            for pkt in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)


def decoded_source(path) -> list[np.ndarray]:
    """The source's frames as the job decodes them (rgb24, in order)."""
    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(c.streams.video[0])]


def run(driver: RoomDriver, kind: str, params: dict) -> dict:
    return asyncio.run(driver.run(kind, params))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    work = tmp_path_factory.mktemp("video")
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=1)
    rig = make_rig(work / "rig", room, SLOTS, content_size=CONTENT)
    driver = RoomDriver(room, rig)
    run(driver, "calibrate", {"mode": "multiplexed", "settle_s": 0.0,
                              "table_points": points_doc(table_points_from_truth(room))})
    run(driver, "transport", {"settle_s": 0.0})
    wide = demo_image((SOURCE[0] + 3 * FRAMES, SOURCE[1]))
    frames = [np.ascontiguousarray(wide[:, 3 * k:3 * k + SOURCE[0]]) for k in range(FRAMES)]
    clip = work / "clip.mp4"
    write_source(clip, frames)
    source = AssetStore(rig.path).add(clip, name="clip")
    return work, rig, driver, clip, source


def test_the_compensated_video_is_a_16_bit_asset_with_the_solutions_at_the_exact_rate(setup):
    work, rig, driver, clip, source = setup
    store = AssetStore(rig.path)
    out = run(driver, "compensate_video", {"asset": "clip", "iterations": 3, "first_iterations": 40})
    # the store lists it, as a 16-bit RGB FFV1 video at the content size and the source's exact rate
    made = store.get(out["asset"]["id"])
    assert [aid for aid, m in store.list() if m.name == "clip (compensated)"] == [out["asset"]["id"]]
    assert (made.kind, made.name, made.frames, made.width, made.height) == ("video", "clip (compensated)", FRAMES,
                                                                            *CONTENT)
    assert (made.channels, made.bit_depth) == (3, 16)
    assert made.extra["codec"] == "ffv1" and made.extra["pix_fmt"] == "gbrp16le"
    assert manifest_rate(made) == manifest_rate(source) == RATE and made.extra["rate"] == "24000/1001"
    assert store.verify(made.asset_id) == []
    # the result's figures
    assert out["frames"] == FRAMES and out["source"]["name"] == "clip" and not out["truncated"]
    assert out["seconds_per_frame"] > 0 and out["ms_per_frame_mean"] < out["ms_first_frame"]
    p = out["predicted_psnr"]
    assert p["ours_mean"] > p["none_mean"] + 0.5, p
    assert json.loads((rig.path / "compensation" / "video.json").read_text())["asset"]["id"] == made.asset_id
    # nothing left behind but the asset
    assert not any((rig.path / "compensation" / "video-tmp").rglob("*.mkv"))
    # the node's own decoder gives back what compensate_sequence computes for the same frames, bit-exactly
    frames = [encode_image_array(f, f"f{k}.png") for k, f in enumerate(decoded_source(clip))]
    seq = run(driver, "compensate_sequence", {"frames": frames, "iterations": 3, "first_iterations": 40})
    assert seq["objective_mean"] == out["objective_mean"]
    blob = made.blobs[0]
    dec = VideoDecoder(store.blob_path(blob.sha256), frames=made.frames, channels=3, bit_depth=16,
                       rate=manifest_rate(made), demuxer=video_demuxer(blob.name, made.extra.get("container")))
    try:
        got = [dec.read(k) for k in range(FRAMES)]
        assert dec.read(3).dtype == np.uint16   # and a backward seek lands on the right frame
        assert np.array_equal(dec.read(3), driver.played[3])
    finally:
        dec.close()
    for k, (a, b) in enumerate(zip(got, driver.played)):
        assert a.dtype == np.uint16 and a.shape == (CONTENT[1], CONTENT[0], 3), (k, a.dtype, a.shape)
        assert np.array_equal(a, b), k
    # the probe `content add` uses (and from which play takes the frame count and rate) agrees
    copy = work / blob.name
    copy.write_bytes(store.blob_path(blob.sha256).read_bytes())
    probe = probe_video(copy)
    assert (probe.frames, probe.bit_depth, probe.channels, probe.extra["rate"]) == (FRAMES, 16, 3, "24000/1001")
    # the same run again gives the same bytes: the same asset, nothing new stored
    again = run(driver, "compensate_video", {"asset": source.asset_id[:8], "iterations": 3, "first_iterations": 40,
                                             "psnr": False, "name": "clip (compensated)"})
    assert again["asset"]["id"] == made.asset_id and again["asset"]["already_stored"]
    assert "predicted_psnr" not in again
    # the source pans 2.5 content pixels a frame, but at this resolution the correction is nearly all
    # the rig's pixel pattern, which must not move: the start that follows the motion (the default)
    # takes little of the moved correction and ends no worse than the start that keeps it in place
    still = run(driver, "compensate_video", {"asset": "clip", "iterations": 3, "first_iterations": 40,
                                             "motion": "off", "name": "clip (still start)"})
    assert (out["motion"], still["motion"]) == ("fast", "off") and "motion_share_mean" not in still
    assert 0 <= out["motion_share_mean"] < 0.2, out["motion_share_mean"]
    assert out["objective_mean"] <= 1.01 * still["objective_mean"], (out["objective_mean"], still["objective_mean"])


def test_max_frames_and_a_grey_image_sequence(setup):
    work, rig, driver, clip, source = setup
    seq_dir = work / "grey"
    seq_dir.mkdir()
    import cv2

    for k, f in enumerate(decoded_source(clip)[:3]):
        cv2.imwrite(str(seq_dir / f"{k:03d}.png"), (f[:, :, 1].astype(np.uint16) * 257))
    grey = AssetStore(rig.path).add(seq_dir, name="grey", fps=12.5, note=lambda _: None)
    assert grey.channels == 1 and grey.bit_depth == 16
    out = run(driver, "compensate_video", {"asset": "grey", "name": "grey out", "iterations": 2,
                                           "first_iterations": 10, "max_frames": 2})
    made = AssetStore(rig.path).get("grey out")
    assert (made.frames, made.channels, made.bit_depth, made.extra["pix_fmt"]) == (2, 1, 16, "gray16le")
    assert manifest_rate(made) == Fraction(25, 2)
    assert out["frames"] == 2 and "max_frames" in out["note"]


def test_refusals_name_the_problem(setup):
    work, rig, driver, clip, source = setup
    with pytest.raises(JobError, match="no asset matches 'nope'"):
        run(driver, "compensate_video", {"asset": "nope"})
    still = work / "still.png"
    import cv2

    cv2.imwrite(str(still), np.zeros((8, 8, 3), np.uint8))
    AssetStore(rig.path).add(still, name="a still")
    with pytest.raises(JobError, match="still image, not a video.*shadowless compensate IMAGE_FILE"):
        run(driver, "compensate_video", {"asset": "a still"})
    with pytest.raises(JobError, match="missing parameter"):
        run(driver, "compensate_video", {})


def test_a_cancelled_run_leaves_no_asset_and_resumes_to_the_same_bytes(setup):
    work, rig, driver, clip, source = setup
    store = AssetStore(rig.path)
    before = {aid for aid, _ in store.list()}
    params = {"asset": "clip", "name": "resumed", "iterations": 3, "first_iterations": 40, "checkpoint_s": 0}

    async def cancel_after_three_frames():
        events = driver.events = WatchedEvents(lambda e: getattr(e, "stage", "") == "compensate clip" and e.done >= 3)
        task = asyncio.create_task(driver.run("compensate_video", params))
        try:
            await asyncio.wait_for(events.seen.wait(), timeout=120)
        except TimeoutError:
            raise AssertionError(f"no third compensated frame in 120 s; events: {events[-5:]}") from None
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(cancel_after_three_frames())
    driver.events = []
    assert {aid for aid, _ in store.list()} == before   # nothing in the store
    runs = list((rig.path / "compensation" / "video-tmp").iterdir())
    assert len(runs) == 1 and (runs[0] / "state.npz").is_file()
    kept = sorted(f.name for f in runs[0].glob("seg-*.mkv"))
    assert 3 <= len(kept) < FRAMES, kept                # a checkpoint after every frame; the open segment dropped
    out = run(driver, "compensate_video", params)
    assert out["resumed_from"] == len(kept) and out["frames"] == FRAMES
    assert not any((rig.path / "compensation" / "video-tmp").iterdir())
    # the same frames as the run never stopped: the same file (only the asset's name differs)
    resumed, straight = store.get("resumed"), store.get("clip (compensated)")
    assert resumed.blobs[0].sha256 == straight.blobs[0].sha256
    assert resumed.blobs[0].size == straight.blobs[0].size
    # --no-resume starts over
    driver.events.clear()
    asyncio.run(cancel_after_three_frames())
    again = run(driver, "compensate_video", {**params, "resume": False, "name": "over"})
    assert again["resumed_from"] == 0 and store.get("over").blobs[0].sha256 == straight.blobs[0].sha256


@pytest.mark.parametrize("channels", [1, 3])
def test_ffv1_writer_round_trips_every_16_bit_sample(tmp_path, channels):
    rng = np.random.default_rng(channels)
    frames = [rng.integers(0, 65536, (30, 44, channels), dtype=np.uint16) for _ in range(4)]
    frames[0][:] = 0
    frames[1][:] = 65535
    path = tmp_path / "x.mkv"
    w = Ffv1Writer(path, size=(44, 30), channels=channels, rate=Fraction(30000, 1001))
    for f in frames:
        w.write(f)
    w.close()
    with pytest.raises(ValueError, match="uint16"):
        Ffv1Writer(tmp_path / "y.mkv", size=(44, 30), channels=channels, rate=Fraction(25)).write(frames[0][:, :, 0] * 0.5)
    dec = VideoDecoder(path, frames=4, channels=channels, bit_depth=16, rate=Fraction(30000, 1001))
    try:
        for k in (0, 1, 2, 3, 1):
            assert np.array_equal(dec.read(k), frames[k]), k
    finally:
        dec.close()
    probe = probe_video(path)
    assert (probe.frames, probe.channels, probe.bit_depth, probe.extra["rate"]) == (4, channels, 16, "30000/1001")
    # segments (as a checkpointed run writes them) joined without decoding: the same bytes as in one go
    cuts = [(0, 1), (1, 3), (3, 4)]
    parts = []
    for a, b in cuts:
        seg = Ffv1Writer(tmp_path / f"seg{a}.mkv", size=(44, 30), channels=channels, rate=Fraction(30000, 1001), first=a)
        for f in frames[a:b]:
            seg.write(f)
        seg.close()
        parts.append(seg.path)
    assert join_segments(parts, tmp_path / "joined.mkv", rate=Fraction(30000, 1001)) == 4
    assert (tmp_path / "joined.mkv").read_bytes() == path.read_bytes()
    # written into memory (as a cluster worker encodes its segment): the file's bytes
    buf = io.BytesIO()
    mem = Ffv1Writer(buf, size=(44, 30), channels=channels, rate=Fraction(30000, 1001))
    for f in frames:
        mem.write(f)
    mem.close()
    assert mem.path is None and buf.getvalue() == path.read_bytes()


def parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cli.configure_compensate(p)
    return p.parse_args(argv)


def test_the_command_line_adds_a_video_file_or_names_an_asset(setup, tmp_path, capsys):
    work, rig, driver, clip, source = setup
    # a video file: added to the rig's store on this machine, then the video job on it
    kind, params = cli.compensate_request(parse([str(clip), "--rig-dir", str(rig.path), "--iterations", "3",
                                                 "--max-frames", "2", "--level", "0.8", "--no-psnr"]))
    assert kind == "compensate_video"
    assert params == {"asset": source.asset_id, "iterations": 3, "max_frames": 2, "level": 0.8, "psnr": False}
    assert "already in the store" in capsys.readouterr().err
    parse_options(VideoOptions, params)
    # an asset by name
    assert cli.compensate_request(parse(["--asset", "clip", "--name", "x"])) == (
        "compensate_video", {"asset": "clip", "name": "x"})
    # an image still goes to the image job
    image = tmp_path / "pic.npy"
    np.save(image, np.full((4, 6), 0.5, np.float32))
    kind, params = cli.compensate_request(parse([str(image), "--max-iter", "5"]))
    assert kind == "compensate" and params["max_iter"] == 5 and "image" in params
    # refusals
    with pytest.raises(SystemExit, match="--iterations appl.* to a video only"):
        cli.compensate_request(parse([str(image), "--iterations", "3"]))
    with pytest.raises(SystemExit, match="--evaluate, --max-iter appl.* to an image only"):
        cli.compensate_request(parse(["--asset", "clip", "--evaluate", "--max-iter", "3"]))
    with pytest.raises(SystemExit, match="no rig token"):        # no rig directory here: an upload, which needs one
        cli.compensate_request(parse([str(clip)]))
    with pytest.raises(SystemExit, match="no such file or folder.*--asset NAME"):
        cli.compensate_request(parse([str(tmp_path / "missing.mp4"), "--rig-dir", str(rig.path)]))
    with pytest.raises(SystemExit, match="not both"):
        cli.compensate_request(parse([str(clip), "--asset", "clip"]))
    with pytest.raises(SystemExit, match="give an image or video file, or --asset"):
        cli.compensate_request(parse([]))
    text = cli.video_report(run(driver, "compensate_video", {"asset": "clip", "max_frames": 2, "name": "two",
                                                             "first_iterations": 5}))
    assert "compensated 2 frame(s) of 'clip' at 24000/1001 fps" in text and 'shadowless play "two"' in text


@pytest.mark.allow_leaks     # node processes of the local rig
def test_nodes_play_the_compensated_asset_by_timeline(setup):
    """One node process fetches the compensated asset and swaps every frame of it at its time."""
    work, rig, driver, clip, source = setup
    made = AssetStore(rig.path).get("clip (compensated)")
    blob = made.blobs[0]
    local = LocalRig(["r0c0"], work / "local", output_size=(64, 40), content_size=CONTENT, mdns=False,
                     env={"SHADOWLESS_DEBUG_TIMING": "1"})
    local.create()
    copy = work / "out" / blob.name
    copy.parent.mkdir()
    copy.write_bytes(AssetStore(rig.path).blob_path(blob.sha256).read_bytes())
    # the same file and name give the same asset in another rig's store
    assert AssetStore(local.rig_dir).add(copy, name=made.name, rate=manifest_rate(made)).asset_id == made.asset_id

    async def go():
        async with await local.client() as c:
            async def node():
                return (await local.wait_live(c, ["r0c0"], timeout=60)).nodes[0]

            await wait_until_async(node, lambda n: n.assets_wanted == 1 and n.assets_ready == 1,
                                   what="the node to have the compensated asset")
            since = len(local.log("node-r0c0"))
            play = await c.play_asset(made.asset_id[:12], delay_s=0.5)
            assert play.frames == FRAMES and play.fps == pytest.approx(float(RATE))

            def played() -> list[int]:
                ids = [int(m.group(1)) for m in SWAP.finditer(local.log("node-r0c0")[since:])]
                return [i - play.frame_id_base for i in ids if play.frame_id_base <= i < play.frame_id_base + FRAMES]

            ticks = await wait_until_async(played, lambda t: len(t) >= FRAMES - 1,
                                           what=f"at least {FRAMES - 1} of the asset's {FRAMES} frames swapped")
            assert ticks == sorted(set(ticks)), (ticks, local.log("node-r0c0")[-2000:])
            assert "rror" not in local.log("node-r0c0")[since:], local.log("node-r0c0")[since:][-2000:]

    with local:
        asyncio.run(go())
