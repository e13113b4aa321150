"""A video's YUV planes reach the renderer without a copy: where a decoded frame's rows are
unpadded, :func:`node.yuv.yuv_planes` hands them over as read-only views of the decoder's
buffers, which keep their pixels while the decoder goes on (FFmpeg counts references to them);
padded rows, and ``copy=True``, give contiguous copies of the same samples."""
from __future__ import annotations

import av
import numpy as np

from node.asset_decode import VideoDecoder
from node.yuv import yuv_planes


def _video(path, w: int, h: int, n: int = 12) -> None:
    rng = np.random.default_rng(1)
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.options = {"preset": "ultrafast", "bf": "2", "g": "6"}
        for _ in range(n):
            img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)


def test_unpadded_planes_are_views_that_keep_their_pixels_while_decoding_goes_on(tmp_path):
    path = tmp_path / "v.mp4"
    _video(path, 128, 64)
    with av.open(str(path)) as c:
        held = []
        for f in c.decode(video=0):
            assert f.planes[0].line_size == 128          # unpadded rows (a multiple of FFmpeg's alignment)
            view, copy = yuv_planes(f), yuv_planes(f, copy=True)
            held.append((view, copy))
    for view, copy in held:                              # every frame decoded, every view still its own
        for v, c_ in zip(view.planes, copy.planes):
            assert v.base is not None and not v.flags.writeable and v.flags.c_contiguous
            assert c_.base is None and c_.flags.writeable                 # a copy of its own
            np.testing.assert_array_equal(v, c_)
    assert len({bytes(v.planes[0]) for v, _ in held}) == len(held)   # twelve different pictures


def test_padded_rows_are_copied_contiguous_and_the_decoder_hands_over_the_same_samples(tmp_path):
    path = tmp_path / "v.mp4"
    _video(path, 72, 40, n=4)                            # 72 and 36 columns: FFmpeg pads the rows
    with av.open(str(path)) as c:
        f = next(iter(c.decode(video=0)))
        assert f.planes[0].line_size > 72
        pic = yuv_planes(f)
        row = np.frombuffer(f.planes[0], np.uint8, count=f.planes[0].line_size)[:72]
        assert all(p.flags.c_contiguous for p in pic.planes) and pic.planes[0].shape == (40, 72)
        np.testing.assert_array_equal(pic.planes[0][0], row)
    dec = VideoDecoder(path, frames=4, channels=3, bit_depth=8, yuv=True)
    try:
        frames = [dec.read(k) for k in range(4)]
        assert [p.planes[0].shape for p in frames] == [(40, 72)] * 4
        np.testing.assert_array_equal(frames[0].planes[0][0], row)
    finally:
        dec.close()
