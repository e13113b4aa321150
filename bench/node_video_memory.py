"""What a node's presenter holds in memory while it plays a 1080p H.264 video (``shadowless bench node
--video`` runs this in processes of its own, one per setting).

A worker is as lean as a presenter process: it imports what :mod:`node.presenter` imports, makes a
renderer of the output size on a headless context (llvmpipe here: it stands in for the GPU driver,
and its LLVM makes the context heavy), and plays the video through the node's own frame source
(:func:`node.asset_frames.open_frames` over the asset's files, decoded ahead by
:class:`node.asset_frames.DecodeAhead` as :class:`node.timeline_player.TimelinePlayer` does, the
frames as YUV planes uploaded to the renderer's textures and rendered through a homography, one
frame after the other as fast as they come).

Resident memory (``VmRSS``, MB) is read at each step, so that it splits into: the interpreter; the
presenter's imports (numpy, PyAV, protobuf); the GL context with the output's framebuffer;
the presenter's warm-up (``warm_up``: :meth:`node.render.Renderer.warm_up`'s shader variants,
which llvmpipe compiles, and a picture of the output's size drawn and forgotten, as
:mod:`node.presenter` does at start); the preview it makes at start to time one (``preview``:
:meth:`node.preview.PreviewMaker.time_once`, the read-back); the decoder (its reference and
reordered frames, its threads' buffers, measured as the growth while the first frames decode,
less the frame queue); the frame queue (what :class:`DecodeAhead` holds, counted by construction from the frames it buffers: the
planes' own bytes when they are copies, 0 when they are views of the decoder's frames, which the
decoder's share then includes); and the textures (the growth of the first upload and draw: one
picture's planes, 3 MB at 1080p 4:2:0; before the presenter compiled its variants after the
warm-up picture, it also gave back that picture's texture, which llvmpipe frees once a draw binds
another texture, and the share was negative).
``rss_mb`` is the median over the second half of the frames (steady), ``rss_mb_after_stop`` what is
left once the show stopped (as :meth:`node.timeline_player.TimelinePlayer.mark_done` does it: the
decode thread closes the decoder, then gives the freed memory back, :mod:`node.heap_trim`);
``by_mapping_mb`` the steady memory by mapping (:func:`mappings_mb`), ``peak_rss_mb`` the
process's ``VmHWM``; ``rss_mb_without_software_gpu_libs`` is ``rss_mb`` less the resident pages
of llvmpipe's libraries (``software_gpu_libs_mb``: LLVM, Mesa's DRI driver, read from
``/proc/self/smaps`` at the end), which a GPU's driver replaces on an edge computer; ``rss_mb``
is the headline.
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path


def rss_mb(field: str = "VmRSS") -> float:
    """This process's resident memory (``VmRSS``) or its peak (``VmHWM``), MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


#: the software GPU's libraries (llvmpipe): LLVM (its code and the tables its start-up relocates),
#: Mesa's DRI driver and LLVM's solver; a GPU's driver takes their place on an edge computer
SOFTWARE_GPU_LIBS = ("libLLVM", "_dri.so", "libgallium", "libz3")


def software_gpu_mb() -> float:
    """Resident MB of this process's mappings of :data:`SOFTWARE_GPU_LIBS` (file pages, shared by
    every process on the host that maps them, and the private pages of their relocations)."""
    total = 0
    inside = False
    with open("/proc/self/smaps") as f:
        for line in f:
            head = line.split(None, 5)
            if head and "-" in head[0] and not head[0].endswith(":"):
                path = head[5].strip() if len(head) > 5 else ""
                inside = any(k in path for k in SOFTWARE_GPU_LIBS)
            elif inside and head[0] == "Rss:":
                total += int(head[1])
    return total / 1024


#: how :func:`mappings_mb` groups a mapping's path (the first key found in it names the group)
MAPPING_GROUPS = (("libLLVM", "llvmpipe: libLLVM"), ("_dri.so", "llvmpipe: Mesa's driver"),
                  ("libgallium", "llvmpipe: Mesa's driver"), ("libz3", "llvmpipe: libz3"),
                  ("libGL", "GL loaders (libGL, libEGL, libGLdispatch)"),
                  ("libEGL", "GL loaders (libGL, libEGL, libGLdispatch)"),
                  ("libglapi", "GL loaders (libGL, libEGL, libGLdispatch)"),
                  ("libGLdispatch", "GL loaders (libGL, libEGL, libGLdispatch)"),
                  ("/av/", "PyAV and FFmpeg"), ("av.libs", "PyAV and FFmpeg"), ("pyav.libs", "PyAV and FFmpeg"),
                  ("numpy", "numpy and OpenBLAS"), ("libpython", "the interpreter"), ("/bin/python", "the interpreter"),
                  ("/libc.so", "libc, libm, libstdc++"), ("libm.so", "libc, libm, libstdc++"),
                  ("libstdc++", "libc, libm, libstdc++"), ("site-packages", "other Python extensions"),
                  ("lib-dynload", "other Python extensions"), ("/usr/lib", "other system libraries"),
                  ("[heap]", "heap (brk)"), ("[stack]", "main thread's stack"))


def mappings_mb(pid: str = "self") -> dict:
    """Resident MB of process ``pid`` by mapping (``/proc/PID/smaps``): the libraries grouped by
    :data:`MAPPING_GROUPS`, the anonymous mappings apart by size (``anon, 1 MB or more``: glibc's
    mmap'd blocks and arenas, llvmpipe's buffers and textures, FFmpeg's pictures, numpy's large
    arrays; ``anon, under 1 MB``: thread stacks' touched pages, small mmaps), and ``other``."""
    groups: dict[str, int] = {}
    key = "other"
    with open(f"/proc/{pid}/smaps") as f:
        for line in f:
            head = line.split(None, 5)
            if head and "-" in head[0] and not head[0].endswith(":"):
                path = head[5].strip() if len(head) > 5 else ""
                if not path:
                    lo, hi = (int(v, 16) for v in head[0].split("-"))
                    key = "anon, 1 MB or more" if hi - lo >= 2**20 else "anon, under 1 MB"
                else:
                    key = next((g for k, g in MAPPING_GROUPS if k in path), "other")
            elif head and head[0] == "Rss:":
                groups[key] = groups.get(key, 0) + int(head[1])
    return {k: round(v / 1024, 1) for k, v in sorted(groups.items(), key=lambda kv: -kv[1])}


def _held_bytes(ahead) -> int:
    """Bytes of the frames ``ahead`` (a DecodeAhead) buffers that are its own copies (views of the
    decoder's frames count 0: they are the decoder's buffers, counted with it)."""
    total = 0
    with ahead._cond:
        frames = list(ahead._ready.values())
    for f in frames:
        planes = getattr(f, "planes", None) or (f,)
        for p in planes:
            if getattr(p, "base", None) is None or p.flags.owndata:
                total += getattr(p, "nbytes", 0)
    return total


def measure(video: Path, *, size: tuple[int, int], content: tuple[int, int], frames: int, depth: int,
            threads: int, copy: bool, ahead_bytes: int | None = None, thread_type: str | None = None) -> dict:
    """Play ``frames`` frames of ``video`` as a presenter would, reading its memory (see the module docstring).
    ``depth``: frames decoded ahead; ``threads``: decoder threads (0: FFmpeg's choice); ``copy``:
    the planes copied out of the decoder's frames (the node before) or handed over as views;
    ``ahead_bytes``: the decode-ahead's byte budget (None: the node's,
    :data:`node.asset_frames.AHEAD_BYTES`; the node before had none); ``thread_type``: how the
    decoder's threads share the work (None: the node's, :data:`node.asset_decode.THREAD_TYPE`;
    "AUTO", frame and slice threads, before 2026-12-06's late evening)."""
    r0 = rss_mb()
    import numpy as np

    import node.presenter  # noqa: F401 - what a presenter process imports
    from node.asset_frames import DecodeAhead, open_frames
    from node.decoders import wish_from_env
    from node.heap_trim import trim_now
    from node.preview import PreviewMaker
    from node.records import AssetFiles
    from node.render import Renderer
    from node.timeline_player import AssetFilesView
    from node import yuv as node_yuv
    from protos.asset_manifest import Blob, Manifest, sha256_hex

    r_imports = rss_mb()
    w, h = size
    cw, ch = content
    anon_before_context = rss_mb("RssAnon")
    r = Renderer.standalone(w, h)
    try:
        scale = min(w / cw, h / ch)
        lut = np.stack([np.linspace(0, 1, 256) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32)
        r.render(None)
        r.ctx.finish()
        r_context = rss_mb()
        anon_context = rss_mb("RssAnon") - anon_before_context
        # the presenter's warm-up (node/render/warm_start.py): a picture of the output's size drawn in content
        # and projector space, then forgotten, and the shader variants a show draws compiled after it (their
        # draws bind other textures, so llvmpipe lets the picture's texture go)
        picture = np.zeros((h, w, 3), np.uint8)
        r.upload("__warm__", picture)
        r.set_homography(np.eye(3), (w, h))
        r.render("__warm__", space="content")
        r.render("__warm__", space="projector", apply_lut=False)
        r.ctx.finish()
        r.forget("__warm__", reuse=False)
        del picture
        r.warm_up()
        r.ctx.finish()
        r_warm = rss_mb()
        # the preview the presenter makes at open to time one (node/presenter.py, PreviewMaker.time_once):
        # its read-back stays with the process
        PreviewMaker(time.monotonic_ns).time_once(r)
        r_preview = rss_mb()
        r.set_homography(np.array([[scale, 0.02, 3.0], [-0.01, scale, 2.0], [1e-6, 2e-6, 1.0]]), (cw, ch))
        r.set_lut(lut)
        node_yuv.COPY_PLANES = copy
        import node.asset_decode

        if thread_type is not None:
            node.asset_decode.THREAD_TYPE = thread_type
        if ahead_bytes is not None:
            import node.asset_frames

            node.asset_frames.AHEAD_BYTES = ahead_bytes
        sha = sha256_hex(video.read_bytes())
        m = Manifest(kind="video", name=video.name, blobs=(Blob(sha, video.stat().st_size, video.name),),
                     width=cw, height=ch, channels=3, bit_depth=8, frames=frames, fps=30.0)
        files = AssetFiles(asset_id=m.asset_id, manifest=m.canonical(), blob_paths={sha: str(video)})
        ahead = DecodeAhead(open_frames(AssetFilesView(files), m.asset_id, threads=threads, size=(cw, ch), yuv=True,
                                        decoder=wish_from_env()), depth=depth)
        try:
            ahead.want(0)
            ahead.get(0, 60.0)
            ahead.wait_ahead(60.0)
            r_decoder = rss_mb()
            queue_mb = _held_bytes(ahead) / 2**20
            steady, t0 = [], time.perf_counter()
            r_textures = None
            for k in range(frames):
                frame = ahead.get(k, 60.0)
                r.upload(f"f{k}", frame)
                r.render(f"f{k}")
                r.ctx.finish()
                if k:
                    r.forget(f"f{k - 1}")
                if r_textures is None:
                    r_textures = rss_mb()
                if k >= frames // 2:
                    steady.append(rss_mb())
                if k == frames - 1:
                    by_mapping = mappings_mb()
            seconds = time.perf_counter() - t0
            # the show stops: the presenter blacks out, forgets the video's texture and has the decode
            # thread close the decoder and give the freed memory back (TimelinePlayer.mark_done)
            r.forget(f"f{frames - 1}")
            r.render(None)
            r.ctx.finish()
            trimmed = threading.Event()
            ahead.close(wait=False, then=lambda: (trim_now(), trimmed.set()))
            if not trimmed.wait(60.0):
                raise RuntimeError("the decode thread did not close the decoder within 60 s of the stop")
            r_stopped = rss_mb()
        finally:
            ahead.close()
    finally:
        r.release()
    software_gpu = software_gpu_mb()
    decoder_and_queue = r_decoder - r_preview
    return {
        "settings": {"depth": depth, "threads": threads, "thread_type": node.asset_decode.THREAD_TYPE, "planes": "copied" if copy else "views of the decoder's frames",
                     "ahead_mb": round((ahead_bytes if ahead_bytes is not None else _node_ahead_bytes()) / 2**20, 1)},
        "rss_mb": round(statistics.median(steady), 1),
        # once the show stopped (the decoder closed and its memory given back, node/timeline_player.py)
        "rss_mb_after_stop": round(r_stopped, 1), "peak_rss_mb": round(max(rss_mb("VmHWM"), *steady), 1),
        # of the resident memory at the end: the process's own (heap, buffers) and the files it maps
        # (shared libraries: the same pages serve every process on the host that maps them)
        "rss_anon_mb": round(rss_mb("RssAnon"), 1), "rss_file_mb": round(rss_mb("RssFile"), 1),
        # llvmpipe's libraries' pages (SOFTWARE_GPU_LIBS), and the resident memory without them: what
        # is left where a GPU's driver replaces the software one (rss_mb stays the figure to meet)
        "software_gpu_libs_mb": round(software_gpu, 1),
        "rss_mb_without_software_gpu_libs": round(statistics.median(steady) - software_gpu, 1),
        "split_mb": {"interpreter": round(r0, 1), "imports": round(r_imports - r0, 1),
                     "gl_context": round(r_context - r_imports, 1), "gl_context_anon": round(anon_context, 1),
                     "warm_up": round(r_warm - r_context, 1), "preview": round(r_preview - r_warm, 1),
                     "decoder": round(decoder_and_queue - queue_mb, 1), "frame_queue": round(queue_mb, 1),
                     "textures": round(r_textures - r_decoder, 1),
                     "playing": round(statistics.median(steady) - r_textures, 1)},
        # where the steady memory is, by mapping, at the last frame (before anything is released)
        "by_mapping_mb": by_mapping,
        "frames": frames, "fps_reached": round(frames / seconds, 1),
    }


def _process_memory(pid: int) -> dict:
    """Resident memory of process ``pid``: ``rss_mb`` (VmRSS), ``anon_mb`` (RssAnon), ``pss_mb`` (its
    proportional share: a page mapped by n processes counts 1/n; /proc/PID/smaps_rollup) and
    ``by_mapping_mb`` (:func:`mappings_mb`)."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "RssAnon"):
            out["rss_mb" if key == "VmRSS" else "anon_mb"] = round(int(value.split()[0]) / 1024, 1)
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        if line.startswith("Pss:"):
            out["pss_mb"] = round(int(line.split()[1]) / 1024, 1)
    out["by_mapping_mb"] = mappings_mb(str(pid))
    return out


def node_processes(timeout: float = 300.0) -> dict:
    """The processes of a real node (``shadowless node``, offscreen, told of a coordinator that is not
    there, so it never joins) once it said READY (its presenter made its context and warmed up):
    how many there are and each one's memory (:func:`_process_memory`). The node process (network,
    session, cache) does not decode or draw, so its memory is what it adds to the presenter's."""
    from protos import auth
    from shadowless.process_stop import stop_process

    with tempfile.TemporaryDirectory(prefix="bench-node-processes-") as tmp:
        token = Path(tmp) / "token"
        token.write_text(auth.new_token() + "\n")
        token.chmod(0o600)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(str(Path(tmp) / "notify"))
        env = {**os.environ, "NOTIFY_SOCKET": str(Path(tmp) / "notify")}
        env.pop("WATCHDOG_USEC", None)
        proc = subprocess.Popen([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--coordinator",
                                 "127.0.0.1:1", "--token-file", str(token), "--cache-dir", str(Path(tmp) / "cache"),
                                 "-q"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + timeout
            ready = False
            while not ready and time.monotonic() < deadline and proc.poll() is None:
                sock.settimeout(1.0)
                try:
                    ready = b"READY=1" in sock.recv(4096)
                except socket.timeout:
                    pass
            if not ready:
                raise RuntimeError(f"the node did not say READY within {timeout:g} s: {proc.stderr.read()[-2000:]}"
                                   if proc.poll() is not None else f"the node did not say READY within {timeout:g} s")
            kids = [int(k) for k in Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()]
            out = {"processes": 1 + len(kids), "node_process": _process_memory(proc.pid)}
            for k in kids:
                cmd = Path(f"/proc/{k}/cmdline").read_bytes()
                out["presenter_idle" if b"child_main" in cmd else f"child_{k}"] = _process_memory(k)
            return out
        finally:
            sock.close()
            stop_process(proc, timeout=30)


def _node_ahead_bytes() -> int:
    from node.asset_frames import AHEAD_BYTES

    return AHEAD_BYTES


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="bench.node_video_memory")
    p.add_argument("video", type=Path)
    p.add_argument("--size", default="1920x1080")
    p.add_argument("--content", default="1920x1080")
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--depth", type=int, required=True)
    p.add_argument("--threads", type=int, required=True)
    p.add_argument("--copy", action="store_true")
    p.add_argument("--ahead-mb", type=float, default=None,
                   help="the decode-ahead's byte budget in MB (default: the node's; the node before had none)")
    p.add_argument("--thread-type", choices=("SLICE", "FRAME", "AUTO"), default=None,
                   help="how the decoder's threads share the work (default: the node's)")
    a = p.parse_args(argv)
    size = tuple(int(v) for v in a.size.split("x"))
    content = tuple(int(v) for v in a.content.split("x"))
    print(json.dumps(measure(a.video, size=size, content=content, frames=a.frames, depth=a.depth, threads=a.threads,
                             copy=a.copy, ahead_bytes=None if a.ahead_mb is None else int(a.ahead_mb * 2**20),
                             thread_type=a.thread_type)))
    return 0


if __name__ == "__main__":   # a process as lean as a presenter (bench/node_video.py starts it)
    sys.exit(main())
