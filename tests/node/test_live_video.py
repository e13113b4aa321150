"""Live video on a node: pictures are decoded only from a keyframe on, never as garbage, and a
frame whose picture could not be decoded is dropped as missing content.

The pictures come from the coordinator's real encoder (:mod:`coordinator.live_video`); the
presenter runs with a real renderer (EGL, llvmpipe) and an offscreen output, on a clock the test
moves (as in ``test_presenter.py``).
"""
from __future__ import annotations

import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio

from coordinator.live_video import EncodedPicture, LiveEncoder
from node.clock import ClockEstimate, LocalClock
from node.live_video import LiveDecoder, VideoChunk
from node.outputs import OffscreenOutput
from node.presenter import Presenter
from node.records import DropReason, NodeAssignment
from node.wire import live_packet_from_bytes, packet_from_bytes
from protos import node_pb2

W, H = 64, 48
MS = 1_000_000
START_NS = 5_000_000_000_000


def moving_frames(n: int, w: int = W, h: int = H) -> list[np.ndarray]:
    """``n`` frames (h, w, 3) uint8: smooth colour gradients moving right, a square moving down."""
    yy, xx = np.mgrid[0:h, 0:w]
    out = []
    for i in range(n):
        f = np.stack([(xx * 3 + i * 5) % 256, (yy * 4) % 256, np.full_like(xx, 90)], axis=2).astype(np.uint8)
        f[(i * 2) % (h - 8):(i * 2) % (h - 8) + 8, 20:28] = 250
        out.append(f)
    return out


def encode(frames, *, keyframe_at=(), fps=30) -> list[EncodedPicture]:
    h, w, c = frames[0].shape
    enc = LiveEncoder(width=w, height=h, channels=c, bit_depth=8, fps=fps)
    return [enc.encode(f, keyframe=i in keyframe_at) for i, f in enumerate(frames)]


def chunk(pic: EncodedPicture, **changes) -> VideoChunk:
    fields = dict(stream_id=pic.stream_id, sequence=pic.sequence, keyframe=pic.keyframe, data=pic.data,
                  width=pic.width, height=pic.height, channels=pic.channels, bit_depth=pic.bit_depth,
                  codec=pic.codec, content_id=pic.content_id)
    fields.update(changes)
    return VideoChunk(**fields)


# ----------------------------------------------------------------------------- the decoder


def test_a_decoder_that_joins_mid_gop_waits_for_the_next_keyframe():
    frames = moving_frames(12)
    pics = encode(frames, keyframe_at=(7,), fps=30)
    assert [p.keyframe for p in pics].count(True) == 2
    dec = LiveDecoder()
    got = [dec.feed(chunk(p)) for p in pics[3:]]          # joined at picture 3
    assert all(g is None for g in got[:4])                # 3..6: no reference pictures, nothing shown
    for frame, g in zip(frames[7:], got[4:]):             # from the keyframe on: every picture, correct
        assert g is not None and peak_signal_noise_ratio(frame, g, data_range=255) > 35
    assert (dec.decoded, dec.skipped) == (5, 4)


def test_a_gap_in_the_sequence_waits_for_a_keyframe_and_a_new_stream_starts_afresh():
    frames = moving_frames(10)
    pics = encode(frames, keyframe_at=(6,))
    dec = LiveDecoder()
    assert dec.feed(chunk(pics[0])) is not None and dec.feed(chunk(pics[1])) is not None
    assert dec.feed(chunk(pics[3])) is None               # 2 was lost: 3 would reference it
    assert dec.feed(chunk(pics[4])) is None and dec.feed(chunk(pics[5])) is None
    assert dec.feed(chunk(pics[6])) is not None and dec.feed(chunk(pics[7])) is not None
    other = encode(moving_frames(3))
    assert dec.feed(chunk(other[1])) is None              # another stream: from its keyframe only
    assert dec.feed(chunk(other[0])) is not None
    dec.reset()                                           # a new coordinator instance
    assert dec.feed(chunk(pics[8])) is None


def test_malformed_pictures_are_skipped_without_an_exception():
    pics = encode(moving_frames(3))
    dec = LiveDecoder()
    assert dec.feed(chunk(pics[0], data=b"\x00\x00\x00\x01garbage")) is None
    assert dec.feed(chunk(pics[1])) is None               # the chain is broken: wait for a keyframe
    assert dec.feed(chunk(pics[0], width=100_000)) is None
    assert dec.feed(chunk(pics[0], codec="vp9")) is None
    assert dec.feed(chunk(pics[0], bit_depth=12)) is None
    assert dec.feed(chunk(pics[0], width=W + 8)) is None  # the picture is not what the packet says
    assert dec.feed(chunk(pics[0])) is not None


# ----------------------------------------------------------------------------- the wire


def packet(pic: EncodedPicture | None, frame_id: int, pts_ns: int, *, evict=()) -> bytes:
    pkt = node_pb2.FramePacket()
    if pic is not None:
        pkt.video.CopyFrom(node_pb2.VideoPacket(
            stream_id=pic.stream_id, sequence=pic.sequence, keyframe=pic.keyframe, data=pic.data, width=pic.width,
            height=pic.height, channels=pic.channels, bit_depth=pic.bit_depth, codec=node_pb2.VIDEO_CODEC_H264,
            content_id=pic.content_id))
        pkt.frame.CopyFrom(node_pb2.Frame(frame_id=frame_id, pts_ns=pts_ns, content_id=pic.content_id,
                                          space=node_pb2.SPACE_PROJECTOR, tag="play:test"))
    if evict:
        pkt.evict.content_ids.extend(evict)
    return pkt.SerializeToString()


def test_the_wire_parses_the_video_part():
    pic = encode(moving_frames(1))[0]
    data, video = live_packet_from_bytes(packet(pic, 5, 123), "r0c0")
    assert data.frame.content_id == pic.content_id and data.contents == ()
    assert video == chunk(pic)
    assert packet_from_bytes(packet(pic, 5, 123), "r0c0") == data


# ----------------------------------------------------------------------------- through the presenter


class ManualClock:
    """Host time in ns that moves only when told to, or when someone sleeps on it."""

    def __init__(self):
        self.t = START_NS

    def __call__(self) -> int:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(1, round(seconds * 1e9))


@pytest.fixture
def presenter():
    host = ManualClock()
    clock = LocalClock(source=host, sleep=host.sleep, anchor_ns=0)
    out = OffscreenOutput(slot="r0c0", keep_last=True)
    reports: list[tuple[str, object]] = []
    p = Presenter(slot="r0c0", output=out, clock=clock, report=lambda k, v: reports.append((k, v)), realtime=False)
    p.open()
    p.handle("assignment", NodeAssignment(revision=1, slot="r0c0", width=W, height=H, pose_kind="none",
                                          homography=None, projection=None, mesh=None, near_mm=100.0,
                                          far_mm=10_000.0, lut=None, gain=1.0, content_size=(W, H)))
    p.handle("clock", ClockEstimate(offset_ns=0.0, drift=0.0, ref_local_ns=float(START_NS), best_rtt_ns=100_000,
                                    samples=8))
    reports.clear()
    p.reports, p.test_clock = reports, clock
    yield p
    p.close()


def test_a_node_joining_mid_sequence_drops_frames_as_missing_until_the_keyframe(presenter):
    frames = moving_frames(10)
    pics = encode(frames, keyframe_at=(5,))
    prev = None
    for i, pic in enumerate(pics[2:], start=2):           # the node joined at picture 2
        pts = presenter.test_clock.now() + 10 * MS
        presenter.handle("packet", packet(pic, 100 + i, pts, evict=[prev] if prev else []))
        prev = pic.content_id
        if i >= 5:                                         # shown: the source frame, decoded, not garbage
            shown = presenter.out.last_image
            assert peak_signal_noise_ratio(frames[i], shown[..., :3], data_range=255) > 30
    swaps = [v.frame_id for k, v in presenter.reports if k == "swap"]
    drops = [v for k, v in presenter.reports if k == "drop"]
    assert swaps == [105, 106, 107, 108, 109]
    assert [(d.frame_id, d.reason) for d in drops] == [(i, DropReason.MISSING_CONTENT) for i in (102, 103, 104)]
    # evicted pictures are forgotten: only the one on screen is held
    assert presenter.renderer.has(pics[-1].content_id) and not presenter.renderer.has(pics[-3].content_id)


def test_a_10_bit_picture_is_shown_from_uint16_content(presenter):
    ramp = np.linspace(0.1, 0.9, W)[None, :, None] * np.ones((H, 1, 3))
    img16 = np.rint(ramp * 65535).astype(np.uint16)
    pic = LiveEncoder(width=W, height=H, channels=3, bit_depth=10, fps=30).encode(img16)
    presenter.handle("packet", packet(pic, 7, presenter.test_clock.now() + 10 * MS))
    assert [v.frame_id for k, v in presenter.reports if k == "swap"] == [7]
    want = np.rint(ramp * 255).astype(np.uint8)
    assert np.abs(presenter.out.last_image[..., :3].astype(int) - want).max() <= 2
