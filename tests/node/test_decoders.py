"""Which video decoder a node uses (node/decoders.py), and the frames VideoDecoder hands the renderer.

This machine has no hardware decoder: ``auto`` must pick software here, and a hardware decoder
asked for by name must fall back to software with one log line saying why. A decoder chosen by
name that does open (libvpx's VP9 decoder, FFmpeg's second VP9 decoder) must decode the same
frames as the default one, seeks included, through the node's own codec context.
"""
from __future__ import annotations

import argparse
import glob
import logging

import av
import numpy as np
import pytest

from node.asset_decode import VideoDecoder
from node.decoders import check_wish, choose
from protos.yuv import YuvFrame, to_rgb


def make_video(path, codec: str, pix: str, n: int = 12, w: int = 96, h: int = 64) -> None:
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=30)
        s.width, s.height, s.pix_fmt = w, h, pix
        for i in range(n):
            img = np.zeros((h, w, 3), np.uint8)
            img[:, :, 0] = np.linspace(0, 255, w)
            img[:, :, 1] = 20 + 15 * i
            img[:, :, 2] = np.linspace(0, 255, h)[:, None]
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    d = tmp_path_factory.mktemp("videos")
    out = {"h264": d / "a.mp4", "12bit": d / "t.mkv", "vp9": d / "v.webm"}
    make_video(out["h264"], "libx264", "yuv420p")
    make_video(out["12bit"], "ffv1", "yuv420p12le", n=3)
    make_video(out["vp9"], "libvpx-vp9", "yuv420p")
    return out


@pytest.mark.skipif(bool(glob.glob("/dev/dri/renderD*") or glob.glob("/dev/video*")),
                    reason="this machine may have a hardware decoder")
def test_auto_picks_software_here_and_a_missing_hardware_decoder_falls_back_with_one_line(caplog):
    assert choose("h264", "auto").kind == "software"
    assert choose("h264", "auto").describe() == "software (no hardware decoder here)"
    with caplog.at_level(logging.WARNING, logger="node.decoders"):
        for _ in range(3):
            c = choose("hevc", "hevc_v4l2m2m")
            d = choose("hevc", "vaapi")
    assert c.kind == d.kind == "software" and c.name == d.name == "hevc"
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2, lines       # once each, however often a stream asks
    assert lines[0].startswith("video decoder hevc_v4l2m2m for hevc: hevc_v4l2m2m ") and "software" in lines[0]
    assert lines[1].startswith("video decoder vaapi for hevc: vaapi ") and "software" in lines[1]
    assert choose("h264", "hevc_v4l2m2m").note == "hevc_v4l2m2m does not decode h264"


def test_the_decoder_option_refuses_what_ffmpeg_does_not_know():
    from node.cli import configure

    p = argparse.ArgumentParser()
    configure(p)
    for ok in ("auto", "software", "v4l2m2m", "vaapi", "h264_v4l2m2m", "libvpx-vp9"):
        assert p.parse_args(["--slot", "r0c0", "--decoder", ok]).decoder == ok
    with pytest.raises(ValueError, match="no decoder 'bogus': use auto, software"):
        check_wish("bogus")
    with pytest.raises(ValueError):
        check_wish("libx264")            # an encoder


def test_a_decoder_by_name_decodes_the_same_frames_as_the_default(videos):
    order = (0, 1, 2, 9, 3, 11, 4)       # a jump forward and seeks back
    got = {}
    for wish in ("libvpx-vp9", "software"):
        d = VideoDecoder(videos["vp9"], frames=12, channels=3, bit_depth=8, yuv=True, decoder=wish)
        try:
            got[wish] = [d.read(k).planes[0].copy() for k in order]
            assert d.choice.name == ("libvpx-vp9" if wish != "software" else "vp9")
            assert d.choice.kind == ("decoder" if wish != "software" else "software")
        finally:
            d.close()
    for a, b in zip(*got.values()):
        assert np.array_equal(a, b)


def test_video_frames_come_as_planes_unless_the_shader_cannot_convert_them(videos, caplog):
    d = VideoDecoder(videos["h264"], frames=12, channels=3, bit_depth=8, yuv=True, decoder="auto", size=(48, 32))
    rgb = VideoDecoder(videos["h264"], frames=12, channels=3, bit_depth=8)
    try:
        f = d.read(5)
        assert isinstance(f, YuvFrame) and f.luma_size == (96, 64) and f.content_size == (48, 32)
        assert f.matrix == "bt601" and not f.full_range      # untagged SD: BT.601, limited
        # the planes stand for the picture swscale makes of the same frame (within 5 codes: see
        # tests/protos/test_yuv.py for why the two upsample chroma apart)
        levels = np.floor(np.clip(to_rgb(f), 0, 1) * 255 + 0.5)
        assert np.abs(levels - rgb.read(5)).max() <= 5
    finally:
        d.close()
        rgb.close()
    with caplog.at_level(logging.INFO, logger="node.asset_decode"):
        g = VideoDecoder(videos["12bit"], frames=3, channels=3, bit_depth=8, yuv=True)
        try:
            frames = [g.read(k) for k in range(3)]
        finally:
            g.close()
    assert all(isinstance(a, np.ndarray) and a.shape == (64, 96, 3) for a in frames)
    lines = [r.getMessage() for r in caplog.records if "swscale" in r.getMessage()]
    assert len(lines) == 1 and "pixel format yuv420p12le" in lines[0], lines


def test_live_pictures_come_as_planes_that_stand_for_the_rgb_picture():
    from coordinator.live_video import LiveEncoder
    from node.live_video import LiveDecoder, VideoChunk

    h, w = 64, 96
    yy, xx = np.mgrid[0:h, 0:w]
    frame = np.stack([xx * 2, yy * 3, np.full_like(xx, 90)], axis=2).astype(np.uint8)
    pic = LiveEncoder(width=w, height=h, channels=3, bit_depth=8, fps=30).encode(frame, keyframe=True)
    chunk = VideoChunk(stream_id=pic.stream_id, sequence=pic.sequence, keyframe=pic.keyframe, data=pic.data,
                       width=pic.width, height=pic.height, channels=3, bit_depth=8, codec=pic.codec,
                       content_id=pic.content_id)
    planes, rgb = LiveDecoder(yuv=True).feed(chunk), LiveDecoder().feed(chunk)
    assert isinstance(planes, YuvFrame) and planes.content_size == (w, h)
    # swscale's fast path and the reference upsample chroma apart by a few codes (tests/protos/test_yuv.py);
    # the wrong matrix would be tens of codes off on these colours
    diff = np.abs(np.floor(np.clip(to_rgb(planes), 0, 1) * 255 + 0.5) - rgb)
    assert diff.max() <= 8 and diff.mean() <= 1.5, (diff.max(), diff.mean())
