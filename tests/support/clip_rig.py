"""A local rig of real processes playing a small generated clip: the clip writer and the rig setup that
the show and rejoin tests share."""
from __future__ import annotations

from pathlib import Path

import av
import numpy as np

from coordinator.assets import AssetStore
from shadowless.local import LocalRig


def write_clip(path, *, size: tuple[int, int], fps: int, seconds: float, shift: int = 0) -> None:
    """An H.264 (or MPEG-4 where libx264 is missing) clip of ``size`` (w, h): frame i is a flat grey
    ``(3 i + shift) % 256`` with a white column at ``i % w``, so that every frame differs."""
    w, h = size
    codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=fps)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        for i in range(int(fps * seconds)):
            arr = np.full((h, w, 3), (i * 3 + shift) % 256, np.uint8)
            arr[:, (i % w)] = 255
            for pkt in s.encode(av.VideoFrame.from_ndarray(arr, format="rgb24")):
                c.mux(pkt)
        for pkt in s.encode():
            c.mux(pkt)


def clip_rig(slots: list[str], work: Path, *, size: tuple[int, int], fps: int, seconds: float) -> LocalRig:
    """A created (not started) LocalRig of ``slots`` without mDNS, output and content of ``size``, its nodes
    logging their swaps' timing, with the clip "clip" in its asset store."""
    rig = LocalRig(slots, work, output_size=size, content_size=size, mdns=False, env={"SHADOWLESS_DEBUG_TIMING": "1"})
    rig.create()
    clip = work / "clip.mp4"
    write_clip(clip, size=size, fps=fps, seconds=seconds)
    AssetStore(rig.rig_dir).add(clip, name="clip")
    return rig
