"""Live sequences as video: a played sequence's frames encoded once, for every node, with H.264.

Content that cannot be prepared ahead (``shadowless play FOLDER``, generated frames) streams on
the Frames RPC. Sent as lossless images a 1920x1080 RGB frame is 6.2 MB; as H.264 it is a few
tens of kB. :class:`LiveEncoder` turns ``(H, W, C)`` frames into one encoded picture each
(:class:`EncodedPicture`), with what low latency needs: no B-frames and no look-ahead
(``tune=zerolatency``: each frame comes out as soon as it goes in), an IDR keyframe with its
parameter sets at least every second, and a keyframe on demand (a node joined mid-sequence).
8-bit content is encoded as 8-bit 4:2:0; 16-bit and float content as 10-bit (x264's High 10
profile), and the node gets uint16 pictures back. :class:`LiveStream` runs the encoder on a
worker thread of its own so the coordinator's event loop never waits for it.

The node's side is :mod:`node.live_video`. Quality: :data:`CRF` keeps natural 1080p video at
about 40 dB PSNR against its source (``tests/coordinator/test_live_video.py`` measures it).
"""
from __future__ import annotations

import asyncio
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

#: the encoder (PyAV's libx264: 8-bit and 10-bit 4:2:0 in one library)
CODEC = "libx264"
#: x264's constant-rate factor (lower: better and larger): natural 1080p video at ~40.5 dB PSNR
#: and 1/57 of its raw size (18: 39.5 dB, 1/72); smaller frames hold more detail per pixel and
#: score lower (320x180: ~34 dB at any CRF, 4:2:0 chroma bounds it)
CRF = 16
#: x264's speed preset: the fastest (~30 ms of one core per 1080p frame here, RGB -> YUV included)
PRESET = "ultrafast"
#: smallest side a sequence must have to go as video (smaller frames go as lossless images)
MIN_SIDE = 16


@dataclass(frozen=True)
class EncodedPicture:
    """One encoded frame of a live stream: an H.264 access unit (Annex B).

    ``width`` x ``height`` is the picture as the node must show it (the encoder pads odd
    sizes by one row or column, the decoder crops them); the node gets ``(height, width,
    channels)`` uint8 (``bit_depth`` 8) or uint16 (``bit_depth`` 10) content.
    """

    stream_id: str
    sequence: int                 # 0, 1, 2, … within the stream
    keyframe: bool                # decodable on its own
    data: bytes
    width: int
    height: int
    channels: int                 # 1 or 3
    bit_depth: int                # 8 or 10
    codec: str = "h264"

    @property
    def content_id(self) -> str:
        """The id the decoded picture takes on the node (a Frame references it)."""
        return f"live:{self.stream_id}:{self.sequence}"


def video_eligible(images: list[np.ndarray]) -> bool:
    """Whether frames shaped ``(H, W, C)`` can go as video: C is 1 or 3, both sides >= MIN_SIDE,
    every frame the same size (RGBA and tiny frames go as lossless images)."""
    if not images:
        return False
    h, w = images[0].shape[:2]
    return all(im.ndim == 3 and im.shape[2] in (1, 3) and im.shape[:2] == (h, w) for im in images) \
        and min(h, w) >= MIN_SIDE


def bit_depth_for(images: list[np.ndarray]) -> int:
    """8 when every frame is uint8, else 10 (16-bit and float content keeps more than 8 bits)."""
    return 8 if all(im.dtype == np.uint8 for im in images) else 10


def _rgb(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """``(H, W, 1|3)`` uint8/uint16/float -> ``(H', W', 3)`` uint8 (8-bit) or uint16 (10-bit), even sides."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if bit_depth == 8:
        if img.dtype != np.uint8:
            raise ValueError(f"an 8-bit stream takes uint8 frames, got {img.dtype}")
    elif img.dtype == np.uint8:
        img = img.astype(np.uint16) * np.uint16(257)
    elif img.dtype != np.uint16:
        img = np.rint(np.clip(np.nan_to_num(img.astype(np.float32)), 0.0, 1.0) * 65535.0).astype(np.uint16)
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    h, w = img.shape[:2]
    if h % 2 or w % 2:
        img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    return np.ascontiguousarray(img)


class LiveEncoder:
    """H.264 encoder for one live stream (not thread-safe: one thread calls :meth:`encode`).

    Parameters
    ----------
    width, height : int
        The frames' size (content pixels).
    channels : int
        1 or 3: the frames' channels (grey frames travel as RGB and come back grey).
    bit_depth : int
        8 (uint8 frames) or 10 (uint8, uint16 or float frames in [0, 1]).
    fps : float
        The sequence's rate: the encoder's time base and its keyframe interval (one a second).
    crf, preset : x264's quality and speed.
    """

    def __init__(self, *, width: int, height: int, channels: int, bit_depth: int, fps: float, crf: int = CRF,
                 preset: str = PRESET, stream_id: str | None = None):
        import av

        if channels not in (1, 3):
            raise ValueError(f"a live stream carries 1 or 3 channels, got {channels}")
        if bit_depth not in (8, 10):
            raise ValueError(f"bit depth must be 8 or 10, got {bit_depth}")
        if min(width, height) < MIN_SIDE:
            raise ValueError(f"frames of {width}x{height} are too small for video (at least {MIN_SIDE} px a side)")
        self.width, self.height, self.channels, self.bit_depth = int(width), int(height), int(channels), bit_depth
        self.stream_id = stream_id or uuid.uuid4().hex[:12]
        self.keyint = max(1, int(fps))                                   # a keyframe at least every second
        rate = Fraction(fps).limit_denominator(1001)
        ctx = av.CodecContext.create(CODEC, "w")
        ctx.width, ctx.height = self.width + self.width % 2, self.height + self.height % 2
        ctx.pix_fmt = "yuv420p" if bit_depth == 8 else "yuv420p10le"
        ctx.time_base = 1 / rate
        ctx.framerate = rate
        ctx.gop_size = self.keyint
        ctx.max_b_frames = 0
        # one thread: the worker's own (its CPU time is the encoder's, measured in ``cpu_s``); the
        # coordinator's other core stays free for its event loop and gRPC
        ctx.thread_count = 1
        ctx.options = {"preset": preset, "tune": "zerolatency", "crf": str(crf), "forced-idr": "1",
                       "x264-params": f"keyint={self.keyint}:min-keyint=1:scenecut=0:bframes=0:repeat-headers=1"}
        ctx.open()
        self._ctx = ctx
        self._av = av
        self._sequence = 0
        self._in_format = "rgb24" if bit_depth == 8 else "rgb48le"
        #: CPU seconds and bytes spent so far
        self.cpu_s = 0.0
        self.bytes = 0

    def encode(self, image: np.ndarray, *, keyframe: bool = False) -> EncodedPicture:
        """Encode one frame ``(H, W, C)`` (the stream's size and channels); ``keyframe`` forces an IDR."""
        t0 = time.thread_time()
        img = np.asarray(image)
        if img.ndim == 2:
            img = img[:, :, None]
        if img.shape != (self.height, self.width, self.channels):
            raise ValueError(f"frame is {img.shape}, the stream takes {(self.height, self.width, self.channels)}")
        vf = self._av.VideoFrame.from_ndarray(_rgb(img, self.bit_depth), format=self._in_format)
        vf = vf.reformat(format=self._ctx.pix_fmt)
        vf.pts = self._sequence
        if keyframe or self._sequence == 0:
            vf.pict_type = self._av.video.frame.PictureType.I
        packets = self._ctx.encode(vf)
        if len(packets) != 1:   # zerolatency, no B-frames: one access unit per frame, at once
            raise RuntimeError(f"the encoder returned {len(packets)} packets for one frame (expected 1)")
        pkt = packets[0]
        pic = EncodedPicture(stream_id=self.stream_id, sequence=self._sequence, keyframe=bool(pkt.is_keyframe),
                             data=bytes(pkt), width=self.width, height=self.height, channels=self.channels,
                             bit_depth=self.bit_depth)
        self._sequence += 1
        self.bytes += len(pic.data)
        self.cpu_s += time.thread_time() - t0
        return pic

    def close(self) -> None:
        self._ctx = None


class LiveStream:
    """A :class:`LiveEncoder` on a worker thread of its own, for the coordinator's event loop.

    The encoder is made on the worker too (opening x264 takes ~30 ms at 1080p).
    :meth:`submit` starts encoding a frame and returns an awaitable for its
    :class:`EncodedPicture` (frames are encoded in submission order); :meth:`request_keyframe`
    makes the next frame that starts encoding a keyframe (a node joined the Frames stream).
    """

    def __init__(self, *, width: int, height: int, channels: int, bit_depth: int, fps: float, **kwargs):
        if channels not in (1, 3) or bit_depth not in (8, 10) or min(width, height) < MIN_SIDE:
            raise ValueError(f"no live stream of {width}x{height}x{channels} at {bit_depth} bits")
        self.stream_id = uuid.uuid4().hex[:12]
        self.bit_depth = bit_depth
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="live-encode")
        self._encoder = self._pool.submit(LiveEncoder, width=width, height=height, channels=channels,
                                          bit_depth=bit_depth, fps=fps, stream_id=self.stream_id, **kwargs)
        self._want_key = threading.Event()
        self.frames = 0
        self.keyframes = 0

    @property
    def cpu_s(self) -> float:
        """CPU seconds the encoder spent so far (0 until it exists)."""
        enc = self._encoder
        return enc.result().cpu_s if enc.done() and enc.exception() is None else 0.0

    def request_keyframe(self) -> None:
        self._want_key.set()

    def _encode(self, image: np.ndarray) -> EncodedPicture:
        key = self._want_key.is_set()
        self._want_key.clear()
        pic = self._encoder.result().encode(image, keyframe=key)
        self.frames += 1
        self.keyframes += pic.keyframe
        return pic

    def submit(self, image: np.ndarray) -> asyncio.Future:
        """Encode ``image`` on the worker thread (call from the event loop)."""
        return asyncio.get_running_loop().run_in_executor(self._pool, self._encode, image)

    def close(self) -> None:
        """Stop the worker (a frame being encoded finishes on it, then the encoder goes)."""
        self._pool.submit(lambda: self._encoder.exception() is None and self._encoder.result().close())
        self._pool.shutdown(wait=False, cancel_futures=True)
