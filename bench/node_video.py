"""`shadowless bench node --video`: the CPU a node spends per frame of a 1080p30 H.264 video, on the
path it had (swscale to RGB, an RGB texture) and on the one it has (the decoder's YUV planes as
textures, converted in the shader), in one run, as ratios.

The video is made here (libx264, moving bars and ramps, ``--video-frames`` frames at 30 fps) and
read through the node's own decoder (:class:`node.asset_decode.VideoDecoder`, resampled to the
content size on the RGB path as the node does; one decoder thread, so that the decoding's CPU falls
in the phase that asked for the frame: a node's frame threads spend about as much, spread over
cores); each frame is then
uploaded to a renderer of the output size and rendered through a homography, the GPU waited for
(``finish``), as before a swap. The two paths take turns in blocks of ``BLOCK`` frames, so a shared
machine's drifting load falls on both alike.

CPU is counted per thread (the calling thread's CPU clock, the others' ``/proc/self/task/*/schedstat``,
nanoseconds on the CPU; :class:`_ThreadClock`), so that llvmpipe's rasterizer threads
(``llvmpipe-N``: they stand in for the GPU here) are reported apart:
``node_cpu_ms_per_frame`` is every other thread's CPU (the calling thread, FFmpeg's decoder
threads) per frame, the sum of ``decode`` (a third decoder that only decodes, in blocks taking
turns with the two paths), ``convert`` (each path's conversion of that decoder's frames: swscale
to RGB, or the planes' copy out of the decoder's buffers), ``upload`` and
``render`` (submission and waiting); ``read_ms`` is what reading a frame through the node's decoder
cost on each path (decode and convert together, as a check of the split), and
``rasterizer_ms_per_frame`` the llvmpipe threads' CPU during the render.

The YUV path hands the decoder's planes over as views (:mod:`node.yuv`), so its ``convert`` is
building the views; ``convert_copied_ms`` is what copying them cost (the node before). Printed
apart (``split``): ``node_cpu_ms_per_frame_without_decode`` (what a hardware decoder would leave
on the CPU, less the hardware decoder's own driver calls, not measured here), and of it
``python_and_gl_calls_ms``, the per-frame work that does not grow with the picture (the same
upload and render of a 64x36 YUV picture into a 64x36 output: Python, moderngl, the driver's
fixed cost); ``rasterizer_share`` is llvmpipe's part of all the CPU a frame took;
``probe_ms_per_reading`` what one reading of the threads' CPU costs (each interval holds one, not
subtracted; the bench before 2026-12-06's evening spent ~0.4 ms per reading opening files, which
its figures counted as the node's).

Memory (``memory``): :mod:`bench.node_video_memory` in a process of its own per setting, as a
presenter plays the video, before (the decoder's two threads as frame and slice threads, FFmpeg's
"AUTO", as the node had them until 2026-12-06's late evening) and after (the node's: slice threads,
:data:`node.asset_decode.THREAD_TYPE`), both with the planes handed over as views and the
decode-ahead's byte budget (:data:`node.asset_frames.AHEAD_BYTES`), each with its resident memory
split into its parts and without llvmpipe's libraries (``rss_mb_without_software_gpu_libs``;
``rss_mb`` is the headline). A node is two processes: the presenter (measured above) and the node
process (network, session, cache), measured apart in a real ``shadowless node`` that is told of no
reachable coordinator (``node_processes``: each process's ``rss_mb``, ``anon_mb`` and ``pss_mb``);
``node_total_mb`` adds the node process to the presenter playing: ``rss_sum`` counts twice the
library pages both map, ``at_least`` adds only the node process's own heap;
``node_total_mb.without_software_gpu_libs`` the same without llvmpipe's libraries (which only the
presenter maps): what an edge computer's node holds before its GPU driver's own libraries and
buffers. The presenter's split also has ``preview``, the read-back of the preview it makes at start.
``bench node --video --memory-only`` runs the memory part alone (:func:`memory_only`, about 30 s),
with each process's memory by mapping (``by_mapping_mb``) and the presenter's after the show stops
(``rss_mb_after_stop``).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

#: frames of one path before the other takes its turn
BLOCK = 10


class _ThreadClock:
    """CPU ns per thread of this process: the calling thread's from its CPU clock
    (``CLOCK_THREAD_CPUTIME_ID``), the others' from ``/proc/self/task/*/schedstat``, read through
    file descriptors kept open (``pread``). The bench before opened two files per thread at each
    reading, ~0.4 ms of the calling thread's CPU with ten threads, which the intervals measured
    counted as the node's; and a running thread's ``schedstat`` lags its CPU clock by up to a
    scheduler tick, which moved time between the intervals (upload, render) of one frame."""

    def __init__(self) -> None:
        self._dir = os.open("/proc/self/task", os.O_RDONLY | os.O_DIRECTORY)
        self._fds: dict[str, tuple[int, int]] = {}     # tid -> (schedstat fd, comm fd)
        self._me = str(threading.get_native_id())

    def read(self) -> tuple[int, int]:
        """(CPU ns of this process's threads but the rasterizer's, CPU ns of llvmpipe's threads)."""
        other, raster = time.thread_time_ns(), 0
        tids = os.listdir(self._dir)
        for tid in tids:
            if tid == self._me:
                continue
            fds = self._fds.get(tid)
            try:
                if fds is None:
                    fds = self._fds[tid] = (os.open(f"/proc/self/task/{tid}/schedstat", os.O_RDONLY),
                                            os.open(f"/proc/self/task/{tid}/comm", os.O_RDONLY))
                ns = int(os.pread(fds[0], 64, 0).split()[0])
                name = os.pread(fds[1], 64, 0)
            except (OSError, ValueError, IndexError):
                continue       # a thread that ended meanwhile
            if name.startswith(b"llvmpipe"):
                raster += ns
            else:
                other += ns
        for tid in [t for t in self._fds if t not in tids]:    # threads that ended
            for fd in self._fds.pop(tid):
                os.close(fd)
        return other, raster


_CLOCK: _ThreadClock | None = None


def _thread_cpu_ns() -> tuple[int, int]:
    """(CPU ns of this process's threads but the rasterizer's, CPU ns of llvmpipe's threads)."""
    global _CLOCK
    if _CLOCK is None or _CLOCK._me != str(threading.get_native_id()):
        _CLOCK = _ThreadClock()
    return _CLOCK.read()


def probe_cost(readings: int = 200) -> float:
    """CPU ms one reading of :func:`_thread_cpu_ns` costs the calling thread (each interval measured
    holds one; not subtracted from the figures)."""
    _thread_cpu_ns()
    t0 = time.thread_time_ns()
    for _ in range(readings):
        _thread_cpu_ns()
    return (time.thread_time_ns() - t0) / 1e6 / readings


def make_video(path: Path, size: tuple[int, int], frames: int) -> None:
    """A ``size`` H.264 video (yuv420p, 30 fps, tagged BT.709 limited range) of moving bars and ramps."""
    import av

    w, h = size
    x = np.linspace(0, 255, w, dtype=np.float32)
    y = np.linspace(0, 255, h, dtype=np.float32)[:, None]
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.options = {"preset": "veryfast", "crf": "20", "g": "60"}
        s.codec_context.colorspace = 1         # BT.709, tagged: swscale and the shader read the same matrix
        s.codec_context.color_range = 1        # limited
        for i in range(frames):
            img = np.empty((h, w, 3), np.uint8)
            img[:, :, 0] = (x + 4 * i) % 256
            img[:, :, 1] = (y + 2 * i) % 256
            img[:, :, 2] = ((x[None, :] // 128 + y // 128 + i // 8) % 2) * 200
            yuv = av.VideoFrame.from_ndarray(img, format="rgb24").reformat(format="yuv420p", dst_colorspace="ITU709",
                                                                           dst_color_range="MPEG")
            for p in s.encode(yuv):
                c.mux(p)
        for p in s.encode():
            c.mux(p)


class _DecodeOnly:
    """Frames decoded and not converted (one thread), ``BLOCK`` at a time: the decode's share."""

    def __init__(self, path: Path) -> None:
        import av

        self._c = av.open(str(path))
        st = self._c.streams.video[0]
        st.codec_context.thread_count = 1
        self._frames = self._c.decode(st)

    def read(self, k: int):
        return next(self._frames, None)

    def close(self) -> None:
        self._c.close()


def _say(text: str) -> None:
    print(f"bench node --video: {text}", file=sys.stderr, flush=True)


def fixed_cost(frames: int = 60) -> float:
    """CPU ms per frame (this process's threads but the rasterizer's) of uploading and rendering a
    64x36 YUV picture into a 64x36 output: the per-frame cost that does not grow with pixels."""
    from node.render import Renderer
    from protos.yuv import YuvFrame

    r = Renderer.standalone(64, 36)
    try:
        r.set_homography(np.eye(3), (64, 36))
        planes = (np.full((36, 64), 120, np.uint8), np.full((18, 32), 128, np.uint8), np.full((18, 32), 128, np.uint8))
        pic = YuvFrame(planes=planes, layout="planar", sub=(2, 2), bits=8, msb=False, matrix="bt709",
                       full_range=False, siting="left", size=None)
        total = 0
        for k in range(frames + 2):
            a0, _ = _thread_cpu_ns()
            r.upload(f"f{k}", pic)
            r.render(f"f{k}")
            r.ctx.finish()
            if k:
                r.forget(f"f{k - 1}")
            a1, _ = _thread_cpu_ns()
            if k >= 2:
                total += a1 - a0
        return total / 1e6 / frames
    finally:
        r.release()


def memory(path: Path, size: tuple[int, int], content: tuple[int, int], frames: int) -> dict:
    """:mod:`bench.node_video_memory` before and after, each in a process of its own."""
    from bench.node_video_memory import node_processes
    from node.timeline_player import DECODE_THREADS, TimelinePlayer

    depth = TimelinePlayer().depth
    settings = {"before": ["--depth", str(depth), "--threads", str(DECODE_THREADS), "--thread-type", "AUTO"],
                "after": ["--depth", str(depth), "--threads", str(DECODE_THREADS)]}
    out = {}
    for name, extra in settings.items():
        _say(f"memory, {name}: a presenter-like process plays {frames} frames")
        cmd = [sys.executable, "-m", "bench.node_video_memory", str(path), "--size", "x".join(map(str, size)),
               "--content", "x".join(map(str, content)), "--frames", str(frames), *extra]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
        if done.returncode != 0:
            raise RuntimeError(f"the memory worker ({name}) failed:\n{done.stderr[-3000:]}")
        out[name] = json.loads(done.stdout.strip().splitlines()[-1])
    out["rss_mb_after_vs_before"] = round(out["after"]["rss_mb"] - out["before"]["rss_mb"], 1)
    out["target_rss_mb"] = 150.0
    _say("memory: a real node's processes (not joined, idle)")
    procs = node_processes()
    node = procs["node_process"]
    out["node_processes"] = procs
    # the whole node while it plays: the presenter's figure plus the node process's. The plain sum
    # counts twice the library pages both map; the node process's own heap (anon) is the least it adds
    out["node_total_mb"] = {"rss_sum": round(out["after"]["rss_mb"] + node["rss_mb"], 1),
                            "at_least": round(out["after"]["rss_mb"] + node["anon_mb"], 1)}
    # the same where a GPU's driver takes the place of llvmpipe's libraries (the node process maps none
    # of them): what an edge computer's node holds, before its GPU driver's own libraries and buffers
    edge = out["after"]["rss_mb_without_software_gpu_libs"]
    out["node_total_mb"]["without_software_gpu_libs"] = {"rss_sum": round(edge + node["rss_mb"], 1),
                                                         "at_least": round(edge + node["anon_mb"], 1)}
    return out


def run_video(size: tuple[int, int], content: tuple[int, int], frames: int, *, memory_frames: int = 30) -> dict:
    """The figures (see the module docstring) as a dict."""
    from node.asset_decode import VideoDecoder, frame_to_array
    from node.yuv import yuv_planes
    from node.decoders import choose, wish_from_env
    from node.render import Renderer

    w, h = size
    cw, ch = content
    with tempfile.TemporaryDirectory(prefix="bench-node-video-") as tmp:
        path = Path(tmp) / "video.mp4"
        make_video(path, content, frames)
        r = Renderer.standalone(w, h)
        try:
            scale = min(w / cw, h / ch)
            r.set_homography(np.array([[scale, 0.02, 3.0], [-0.01, scale, 2.0], [1e-6, 2e-6, 1.0]]), (cw, ch))
            r.set_lut(np.stack([np.linspace(0, 1, 256) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32))
            wish = wish_from_env()
            decoders = {
                "rgb": VideoDecoder(path, frames=frames, channels=3, bit_depth=8, rate=Fraction(30), size=(cw, ch),
                                    decoder=wish, threads=1),
                "yuv": VideoDecoder(path, frames=frames, channels=3, bit_depth=8, rate=Fraction(30), size=(cw, ch),
                                    decoder=wish, yuv=True, threads=1),
            }
            raw = _DecodeOnly(path)
            sums = {p: {"read": 0, "upload": 0, "render": 0, "raster": 0, "frames": 0} for p in decoders}
            decode = {"ns": 0, "frames": 0, "rgb": 0, "yuv": 0, "yuv_copied": 0}
            k = 0
            levels = {}
            while k < frames:
                for j in range(k, min(k + BLOCK, frames)):       # the decode alone, under the same load
                    a0, _ = _thread_cpu_ns()
                    f = raw.read(j)
                    a1, _ = _thread_cpu_ns()
                    # each path's conversion of that frame (swscale may use threads of its own)
                    t0, _ = _thread_cpu_ns()
                    frame_to_array(f, 3, 8, (cw, ch))
                    t1, _ = _thread_cpu_ns()
                    yuv_planes(f, (cw, ch))
                    t2, _ = _thread_cpu_ns()
                    yuv_planes(f, (cw, ch), copy=True)      # the node before: the planes copied
                    t3, _ = _thread_cpu_ns()
                    if j >= 2:
                        decode["ns"] += a1 - a0
                        decode["rgb"] += t1 - t0
                        decode["yuv"] += t2 - t1
                        decode["yuv_copied"] += t3 - t2
                        decode["frames"] += 1
                for name, dec in decoders.items():
                    for j in range(k, min(k + BLOCK, frames)):
                        a0, _ = _thread_cpu_ns()
                        image = dec.read(j)
                        a1, _ = _thread_cpu_ns()
                        r.upload("f", image)
                        a2, b2 = _thread_cpu_ns()
                        r.render("f")
                        r.ctx.finish()
                        a3, b3 = _thread_cpu_ns()
                        r.forget("f")
                        if j >= 2:     # the first frames open the decoder and compile the shader's variant
                            s = sums[name]
                            s["read"] += a1 - a0
                            s["upload"] += a2 - a1
                            s["render"] += a3 - a2
                            s["raster"] += b3 - b2
                            s["frames"] += 1
                        if j == frames // 2:
                            levels[name] = r.read().astype(np.float64)
                k += BLOCK
                _say(f"{min(k, frames)} of {frames} frames on both paths")
            decoder = decoders["yuv"].choice.describe()
            for dec in (*decoders.values(), raw):
                dec.close()
        finally:
            r.release()
        _say("the per-frame fixed cost (a 64x36 picture)")
        fixed = fixed_cost()
        probe = probe_cost()
        mem = memory(path, size, content, memory_frames)
    nd = max(decode["frames"], 1)
    decode_ms = decode["ns"] / 1e6 / nd
    paths = {}
    for name, s in sums.items():
        n = max(s["frames"], 1)
        read = s["read"] / 1e6 / n
        split = {"decode_ms": round(decode_ms, 3), "convert_ms": round(decode[name] / 1e6 / nd, 3),
                 "upload_ms": round(s["upload"] / 1e6 / n, 3), "render_ms": round(s["render"] / 1e6 / n, 3)}
        paths[name] = {"node_cpu_ms_per_frame": round(sum(split.values()), 3), **split,
                       "read_ms": round(read, 3), "rasterizer_ms_per_frame": round(s["raster"] / 1e6 / n, 3),
                       "frames": s["frames"]}

    def ratio(key: str) -> float | None:
        return round(paths["yuv"][key] / paths["rgb"][key], 3) if paths["rgb"][key] else None

    diff = np.abs(levels["yuv"] - levels["rgb"]) if len(levels) == 2 else None
    y = paths["yuv"]
    y["convert_copied_ms"] = round(decode["yuv_copied"] / 1e6 / nd, 3)
    without = round(y["convert_ms"] + y["upload_ms"] + y["render_ms"], 3)
    split = {
        "decode_ms": y["decode_ms"], "convert_ms": y["convert_ms"], "upload_ms": y["upload_ms"],
        "render_ms": y["render_ms"], "node_cpu_ms_per_frame_without_decode": without,
        "python_and_gl_calls_ms": round(fixed, 3),
        "pixels_ms": round(without - fixed, 3),      # what grows with the picture: the driver's copies and setup
        "rasterizer_ms_per_frame": y["rasterizer_ms_per_frame"],
        # what one reading of the threads' CPU costs the calling thread; each interval above holds one
        "probe_ms_per_reading": round(probe, 4),
        "rasterizer_share": round(y["rasterizer_ms_per_frame"] / (y["rasterizer_ms_per_frame"] + y["node_cpu_ms_per_frame"]), 3),
    }
    return {
        "size": list(size), "content": list(content), "codec": "h264", "frames": frames, "fps": 30,
        "decoder": decoder, "node_cpu_ms_per_frame": y["node_cpu_ms_per_frame"],
        "node_cpu_ms_per_frame_without_decode": without, "split": split,
        "paths": paths,
        "yuv_vs_rgb": {k: ratio(k) for k in ("node_cpu_ms_per_frame", "convert_ms", "upload_ms", "render_ms",
                                             "rasterizer_ms_per_frame")},
        # the two paths' pictures of one frame: swscale's and the shader's conversions differ by a few
        # levels at chroma edges (tests/protos/test_yuv.py), and the RGB path's area resampling
        "picture_levels_apart": None if diff is None else {"mean": round(float(diff.mean()), 3),
                                                            "p99": round(float(np.percentile(diff, 99)), 1)},
        "target_node_cpu_ms_per_frame": 3.0,
        "memory": mem,
    }


def memory_only(size: tuple[int, int], content: tuple[int, int], frames: int, *, memory_frames: int = 30) -> dict:
    """Only :func:`memory` (``bench node --video --memory-only``): the video made, the presenter-like
    worker playing its first ``memory_frames`` frames, a real node's processes."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-node-video-") as tmp:
        path = Path(tmp) / "video.mp4"
        make_video(path, content, frames)
        mem = memory(path, size, content, min(memory_frames, frames))
    return {"size": list(size), "content": list(content), "codec": "h264", "frames": frames, "fps": 30,
            "memory": mem, "seconds": round(time.perf_counter() - t0, 1)}


def timed(size, content, frames) -> dict:
    t0 = time.perf_counter()
    out = run_video(size, content, frames)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def memory_summary(m: dict) -> list[str]:
    """The figures of :func:`memory` as a few lines an operator reads."""
    a, b = m["after"], m["before"]
    parts = ", ".join(f"{k.replace('_', ' ')} {val:g}" for k, val in a["split_mb"].items() if k != "gl_context_anon")
    top = ", ".join(f"{k} {val:g}" for k, val in list(a.get("by_mapping_mb", {}).items())[:6])
    return [
        f"resident memory while playing: {b['rss_mb']:g} MB with frame threads (before), {a['rss_mb']:g} MB now (peak {a['peak_rss_mb']:g}; "
        f"target {m['target_rss_mb']:g}): {parts}; without llvmpipe's libraries (a GPU's driver replaces them) "
        f"{a['rss_mb_without_software_gpu_libs']:g} MB; once the show stopped {a.get('rss_mb_after_stop', float('nan')):g} MB",
        f"by mapping while playing (MB): {top}",
        f"the whole node while playing, with its node process ({m['node_processes']['node_process']['rss_mb']:g} MB,"
        f" {m['node_processes']['processes']} processes in all): {m['node_total_mb']['at_least']:g} to"
        f" {m['node_total_mb']['rss_sum']:g} MB; without llvmpipe's libraries"
        f" {m['node_total_mb']['without_software_gpu_libs']['at_least']:g} to"
        f" {m['node_total_mb']['without_software_gpu_libs']['rss_sum']:g} MB",
    ]


def summary(v: dict) -> list[str]:
    """The figures of :func:`run_video` as a few lines an operator reads."""
    s = v["split"]
    return [
        f"node CPU per {v['content'][0]}x{v['content'][1]} H.264 frame on the YUV path: {v['node_cpu_ms_per_frame']:.2f} ms"
        f" = decode {s['decode_ms']:.2f} + convert {s['convert_ms']:.2f} (copying the planes cost "
        f"{v['paths']['yuv']['convert_copied_ms']:.2f}) + upload {s['upload_ms']:.2f} + render {s['render_ms']:.2f}"
        f" ({v['decoder']})",
        f"without the decode (what a hardware decoder would leave): {s['node_cpu_ms_per_frame_without_decode']:.2f} ms"
        f" (target {v['target_node_cpu_ms_per_frame']:g}), of which Python and GL calls {s['python_and_gl_calls_ms']:.2f}"
        f" ms and the pixels' copies and setup {s['pixels_ms']:.2f} ms",
        f"llvmpipe's rasterizer (the GPU here): {s['rasterizer_ms_per_frame']:.1f} ms of CPU per frame, "
        f"{100 * s['rasterizer_share']:.0f} % of all the CPU a frame took",
        *memory_summary(v["memory"]),
    ]
