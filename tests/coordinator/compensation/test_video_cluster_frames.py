"""A segment's frames as a cluster worker reads them (:class:`SourceFrames`: from the file's bytes,
seeking to the segment's first frame) against the reference, every frame decoded in order from
the start of the file: H.264 with B-frames and a keyframe every 7 frames, in MP4 and Matroska
(whose millisecond timestamps are off the 24000/1001 grid by up to half a millisecond)."""
from __future__ import annotations

from fractions import Fraction

import av
import numpy as np
import pytest

from coordinator.assets import AssetStore
from coordinator.compensation.video_io import AssetFrames, SourceFrames

RATE = Fraction(24000, 1001)
FRAMES = 30


@pytest.mark.parametrize("suffix", ["mp4", "mkv"])
def test_a_segment_read_by_seeking_is_the_frames_decoded_in_order(tmp_path, suffix):
    if "libx264" not in av.codecs_available:
        pytest.skip("no libx264 (B-frames)")
    rng = np.random.default_rng(3)
    clip = tmp_path / f"clip.{suffix}"
    with av.open(str(clip), "w") as c:
        s = c.add_stream("libx264", rate=RATE)
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        s.options = {"g": "7", "bf": "2"}
        for _ in range(FRAMES):
            f = av.VideoFrame.from_ndarray((rng.random((48, 64, 3)) * 255).astype(np.uint8), format="rgb24")
            for pkt in s.encode(f):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)
    (tmp_path / "rig").mkdir()
    store = AssetStore(tmp_path / "rig")
    m = store.add(clip, name="clip")
    reference = list(AssetFrames(store, m))
    assert len(reference) == FRAMES
    data = store.blob_path(m.blobs[0].sha256).read_bytes()
    for start in (1, 6, 7, 8, 20, 29):
        frames = SourceFrames(m, lambda k: data, rate=RATE, start=start, stop=start + 6)
        got = list(frames)
        assert frames.seeked, start
        assert len(got) == min(6, FRAMES - start), start
        for k, (a, b) in enumerate(zip(got, reference[start:])):
            assert a.dtype == np.uint8 and np.array_equal(a, b), (start, k)
    # from the store's file, to the end
    assert all(np.array_equal(a, b) for a, b in zip(AssetFrames(store, m, start=13), reference[13:], strict=True))
