"""`shadowless bench node --variants`: llvmpipe's CPU per frame for each kind of frame the node's
warp draws (RGB, grey, planar YUV, NV12; with a fade, blend maps, without the LUT), at the output
sizes given, and optionally the same for the renderer of another commit in the same run.

For each size, a worker process makes a renderer on a headless context, a homography pose (from
content of ``--content``'s size, 1920x1080 by default), a LUT
and a gain, and for each variant (all of them twice, the first pass dropped) uploads its content, draws
three warm-up frames, then
draws frames waiting for each (``finish``), counting the CPU of llvmpipe's rasterizer threads
(``llvmpipe-N`` in ``/proc/self/task``: they stand in for the GPU here) and of the calling thread.
``--against COMMIT`` extracts that commit's ``node/`` and ``protos/`` into a temporary directory
and runs the same worker against them, the two renderers taking turns per round, so both see the
same load; ``ratio`` is the current renderer's rasterizer CPU over the other's, per variant.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: frames counted per variant and round
FRAMES = 20
#: the variants, in order: name -> (content kind, fade from (kind or None), blend, apply_lut)
VARIANTS = {
    "rgb": ("rgb", None, False, True),
    "rgb_no_lut": ("rgb", None, False, False),
    "grey": ("grey", None, False, True),
    "yuv_planar": ("yuv1", None, False, True),
    "yuv_nv12": ("yuv2", None, False, True),
    "rgb_blend": ("rgb", None, True, True),
    "yuv_blend": ("yuv1", None, True, True),
    "rgb_fade_rgb": ("rgb", "rgb", False, True),
    "rgb_fade_black": ("rgb", "black", False, True),
    "yuv_fade_yuv": ("yuv1", "yuv1", False, True),
    "yuv_fade_yuv_blend": ("yuv1", "yuv1", True, True),
}
REPO = Path(__file__).resolve().parent.parent


def _raster_ns() -> tuple[int, int]:
    """(CPU ns of llvmpipe's threads, CPU ns of the calling thread)."""
    raster = 0
    for task in os.scandir("/proc/self/task"):
        try:
            with open(f"{task.path}/comm") as f:
                name = f.read().strip()
            if name.startswith("llvmpipe"):
                with open(f"{task.path}/schedstat") as f:
                    raster += int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            continue
    return raster, time.thread_time_ns()


def _content(kind: str, size: tuple[int, int], seed: int):
    """Content of ``kind`` at ``size`` (w, h): an RGB or grey uint8 image, or a YuvFrame."""
    from protos.yuv import YuvFrame

    w, h = size
    rng = np.random.default_rng(seed)
    if kind == "rgb":
        return rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    if kind == "grey":
        return rng.integers(0, 256, (h, w), dtype=np.uint8)
    y = rng.integers(16, 236, (h, w), dtype=np.uint8)
    c = rng.integers(16, 241, (h // 2, w // 2, 2), dtype=np.uint8)
    if kind == "yuv1":
        planes = (y, np.ascontiguousarray(c[:, :, 0]), np.ascontiguousarray(c[:, :, 1]))
        return YuvFrame(planes=planes, layout="planar")
    return YuvFrame(planes=(y, c), layout="semiplanar")


def worker(size: tuple[int, int], frames: int, content: tuple[int, int] = (1920, 1080)) -> dict:
    """Per variant: llvmpipe's CPU ms per frame and the calling thread's, at output ``size``, the
    content (and a video's planes) ``content`` (w, h) pixels."""
    from node.render import Renderer
    from protos.blend import BlendMaps

    w, h = size
    cw, ch = content
    r = Renderer.standalone(w, h)
    try:
        s = min(w / cw, h / ch)
        r.set_homography(np.array([[s, 0.02 * s, 3.0], [-0.01 * s, s, 2.0], [1e-7, 2e-7, 1.0]]), (cw, ch))
        r.set_lut(np.stack([np.linspace(0, 1, 256) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32))
        r.set_gain(0.9)
        bw, bh = max(1, w // 4), max(1, h // 4)
        maps = BlendMaps(np.full((bh, bw, 3), 0.8, np.float32), np.full((bh, bw), 0.02, np.float32))
        out = {}
        # twice over: the first pass's figures (the process's and the driver's first frames) are dropped
        for name, (kind, fade_from, blend, lut) in [*VARIANTS.items(), *VARIANTS.items()]:
            r.upload(name, _content(kind, (cw, ch), 1))
            fade = None
            if fade_from == "black":
                fade = ("", 0.5)
            elif fade_from is not None:
                r.upload(name + "_from", _content(fade_from, (cw, ch), 2))
                fade = (name + "_from", 0.5)
            r.set_blend(maps if blend else None)
            for _ in range(3):
                r.render(name, apply_lut=lut, fade=fade)
                r.ctx.finish()
            ras0, cpu0 = _raster_ns()
            for _ in range(frames):
                r.render(name, apply_lut=lut, fade=fade)
                r.ctx.finish()
            ras1, cpu1 = _raster_ns()
            out[name] = {"rasterizer_ms": (ras1 - ras0) / 1e6 / frames, "thread_ms": (cpu1 - cpu0) / 1e6 / frames}
            r.forget(name)
            r.forget(name + "_from")
        r.set_blend(None)
        return out
    finally:
        r.release()


def _run_worker(size: tuple[int, int], frames: int, tree: Path | None, content: tuple[int, int]) -> dict:
    """One worker process, on this tree's renderer or on ``tree``'s (its node/ and protos/ first)."""
    path = [str(tree)] if tree is not None else []
    code = ("import json, sys; sys.path[:0] = %r; sys.path.append(%r); from bench.node_variants import worker; "
            "print(json.dumps(worker(%r, %d, %r)))" % (path, str(REPO), tuple(size), frames, tuple(content)))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800,
                          cwd=str(tree) if tree is not None else str(REPO), env={**os.environ, "SHADOWLESS_GL": "gl"})
    if done.returncode != 0:
        raise RuntimeError(f"the variants worker failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _extract(commit: str, into: Path) -> None:
    """``commit``'s node/ and protos/ packages into ``into`` (git archive)."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit, "node", "protos"], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)


def variants(sizes: list[tuple[int, int]], rounds: int, frames: int, against: str | None,
             content: tuple[int, int] = (1920, 1080)) -> dict:
    """The figures per size and variant (medians over ``rounds``), with ``against``'s beside them."""
    tmp = Path(tempfile.mkdtemp(prefix="shadowless-variants-")) if against else None
    try:
        if tmp is not None:
            _extract(against, tmp)
        result: dict = {}
        for w, h in sizes:
            runs: dict[str, list[dict]] = {"now": [], "before": []}
            for k in range(rounds):
                print(f"bench node --variants: {w}x{h}, round {k + 1}/{rounds}", file=sys.stderr, flush=True)
                runs["now"].append(_run_worker((w, h), frames, None, content))
                if tmp is not None:
                    runs["before"].append(_run_worker((w, h), frames, tmp, content))
            per: dict = {}
            for name in VARIANTS:
                entry = {}
                for which, rs in runs.items():
                    if rs:
                        entry[which] = {key: round(float(np.median([r[name][key] for r in rs])), 3)
                                        for key in ("rasterizer_ms", "thread_ms")}
                if "before" in entry and entry["before"]["rasterizer_ms"] > 0:
                    entry["ratio"] = round(entry["now"]["rasterizer_ms"] / entry["before"]["rasterizer_ms"], 3)
                per[name] = entry
            result[f"{w}x{h}"] = per
        return {"against": against, "rounds": rounds, "frames": frames, "content": "{}x{}".format(*content),
                "variants": result}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def summary(res: dict) -> list[str]:
    """One line per size and variant: rasterizer ms per frame now (and before, and the ratio)."""
    lines = []
    for size, per in res["variants"].items():
        for name, e in per.items():
            text = f"{size} {name:>20}: rasterizer {e['now']['rasterizer_ms']:7.2f} ms/frame"
            if "before" in e:
                text += f", before {e['before']['rasterizer_ms']:7.2f} ms ({e.get('ratio', float('nan')):.2f}x)"
            lines.append(text)
    return lines
