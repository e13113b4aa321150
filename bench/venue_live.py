"""`shadowless bench venue`, part 3: live frames, compressed on the wire.

A natural-looking sequence (a slow camera pan across photographs, cross-fading from one to the
next; scikit-image's sample images, upscaled) at the test video's size is played through the
venue's rig as a live sequence (``shadowless play FOLDER``: the coordinator encodes it once, as
H.264, and streams it on every node's Frames stream). The rig's content size is set to the
sequence's size first (the coordinator is restarted on its rig directory; the nodes rejoin by
themselves), so the frames travel at their own resolution, not scaled to the nodes' outputs.

* ``bytes_per_frame``: the coordinator's ``frame_bytes_sent`` counter over the play (every Frames
  packet: the encoded picture, the frame, the evictions), over frames sent x nodes;
* ``raw_bytes_per_frame``: W x H x 3, one raw RGB frame; ``ratio`` = raw / bytes_per_frame;
* ``psnr_db_min`` / ``psnr_db_mean``: the same frames through the same encoder settings and the
  node's decoder (:mod:`coordinator.live_video`, :mod:`node.live_video`) in this process,
  against the source frames (scikit-image's PSNR);
* ``encode_ms_per_frame``: the coordinator's CPU time encoding the sequence (its ``encode_cpu_s``,
  video and packets), per frame; ``encode_ms_per_frame_here``: the encoder's CPU time per frame
  in this process;
* ``frames_sent``, ``frames_shown`` (by every node), ``frames_late``, ``frames_dropped``.
"""
from __future__ import annotations

import re
import sys
import time

import numpy as np

from shadowless.local import LocalRig

#: the live play's latency budget: nodes decode a 1080p picture before they render it
LATENCY_MS = 250.0


def natural_video(n: int, size: tuple[int, int]) -> list[np.ndarray]:
    """``n`` frames (H, W, 3) uint8: a slow pan (4 px right, 2 px down a frame at 1080p, scaled
    with the size) across an upscaled photograph, cross-fading into a second one."""
    import cv2
    from skimage import data

    w, h = size
    sx, sy = max(1, round(4 * w / 1920)), max(1, round(2 * h / 1080))
    big = (w + sx * n + 8, h + sy * n + 8)
    a = cv2.resize(data.astronaut(), big, interpolation=cv2.INTER_CUBIC).astype(np.float32)
    b = cv2.resize(data.coffee(), big, interpolation=cv2.INTER_CUBIC).astype(np.float32)
    out = []
    for i in range(n):
        x, y, t = sx * i, sy * i, 0.5 * i / max(1, n - 1)
        f = a[y:y + h, x:x + w] * (1 - t) + b[y:y + h, x:x + w] * t
        out.append(np.clip(np.rint(f), 0, 255).astype(np.uint8))
    return out


def quality(frames: list[np.ndarray], fps: float) -> dict:
    """The frames through the coordinator's encoder and the node's decoder, here: PSNR and costs."""
    from skimage.metrics import peak_signal_noise_ratio

    from coordinator.live_video import LiveEncoder
    from node.live_video import LiveDecoder, VideoChunk

    h, w, c = frames[0].shape
    enc, dec = LiveEncoder(width=w, height=h, channels=c, bit_depth=8, fps=fps), LiveDecoder()
    psnr, sizes = [], []
    t_dec = 0.0
    for f in frames:
        pic = enc.encode(f)
        sizes.append(len(pic.data))
        t0 = time.thread_time()
        back = dec.feed(VideoChunk(stream_id=pic.stream_id, sequence=pic.sequence, keyframe=pic.keyframe,
                                   data=pic.data, width=pic.width, height=pic.height, channels=pic.channels,
                                   bit_depth=pic.bit_depth, codec=pic.codec, content_id=pic.content_id))
        t_dec += time.thread_time() - t0
        psnr.append(peak_signal_noise_ratio(f, back, data_range=255) if back is not None else 0.0)
    return {"psnr_db_min": round(float(min(psnr)), 2), "psnr_db_mean": round(float(np.mean(psnr)), 2),
            "video_bytes_per_frame": round(float(np.mean(sizes))),
            "encode_ms_per_frame_here": round(enc.cpu_s / len(frames) * 1e3, 2),
            "decode_ms_per_frame_here": round(t_dec / len(frames) * 1e3, 2)}


def set_content_size(rig: LocalRig, size: tuple[int, int]) -> bool:
    """Write ``size`` as the rig's content size into rig.toml; whether it changed."""
    path = rig.rig_dir / "rig.toml"
    text = path.read_text()
    new, n1 = re.subn(r"(?m)^content_width\s*=.*$", f"content_width = {size[0]}", text, count=1)
    new, n2 = re.subn(r"(?m)^content_height\s*=.*$", f"content_height = {size[1]}", new, count=1)
    if not (n1 and n2):
        raise RuntimeError(f"{path}: no content_width / content_height line to set")
    if new == text:
        return False
    path.write_text(new)
    return True


async def measure(rig: LocalRig, *, size: tuple[int, int], fps: float, seconds: float) -> dict:
    from coordinator.api import PlaySettings

    n = max(2, round(seconds * fps))
    frames = natural_video(n, size)
    if set_content_size(rig, size):
        print(f"bench venue: content size {size[0]}x{size[1]} for the live frames: restarting the coordinator …",
              file=sys.stderr, flush=True)
        rig.stop_coordinator()
        rig.start_coordinator()
    async with await rig.client(timeout=60.0) as c:
        await rig.wait_live(c, timeout=120.0)
        before = await c.status()
        r = await c.play(PlaySettings(fps=fps, wait=True, latency_ms=LATENCY_MS), frames)
        after = await c.status()
    sent = after.frame_bytes_sent - before.frame_bytes_sent
    node_frames = max(1, r.frames_sent * max(1, r.nodes))
    raw = size[0] * size[1] * 3
    per_frame = sent / node_frames
    return {
        "size": f"{size[0]}x{size[1]}", "fps": fps, "frames": n, "nodes": r.nodes,
        "bytes_per_frame": round(per_frame),
        "raw_bytes_per_frame": raw,
        "ratio": round(raw / per_frame, 1) if per_frame else None,
        "frame_bytes_sent": sent,
        "encode_ms_per_frame": round(r.encode_cpu_s / max(1, r.frames_sent) * 1e3, 2),
        "frames_sent": r.frames_sent, "frames_shown": r.frames_shown, "frames_late": r.frames_late,
        "frames_dropped": r.frames_dropped,
        **quality(frames, fps),
    }
