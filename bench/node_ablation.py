"""`shadowless bench node --ablate`: what llvmpipe's draw of one output pixel is made of.

The node's warp (pipeline.glsl) is compiled again with one piece taken out at a time (text edits
of the shader: the LUT's fetches, three of the content's four bilinear fetches, the chroma, the
YUV matrix, the content, everything but the write), and each ablated program draws the same
frames as the whole one, in one process, all of them in turn round after round so that they see
the same load; the figure is llvmpipe's rasterizer CPU (its ``llvmpipe-N`` threads, as
:mod:`bench.node_variants` counts it) per output pixel, ns, the median over the rounds (and the
least). A piece costs about the whole's figure less its ablation's. The ablated programs draw
wrong pictures: this measures, it changes nothing the node draws.

Variants: RGB, planar YUV as the renderer draws it on llvmpipe (chroma interleaved,
:attr:`node.render.Renderer.interleave_chroma`), the same with its planar textures (eight chroma
fetches, as a GPU draws it), and NV12; 1920x1080 content through a homography, a LUT and a gain.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

_LUT = """    int i = min(int(t), lut_size - 2);
    vec2 y = texelFetch(lut, ivec2(i, channel), 0).rg;
    return mix(y.x, y.y, t - float(i));"""
_BILINEAR = """    vec4 top = w0.x * texelFetch(tex, q0, 0) + w1.x * texelFetch(tex, ivec2(q1.x, q0.y), 0);
    vec4 bottom = w0.x * texelFetch(tex, ivec2(q0.x, q1.y), 0) + w1.x * texelFetch(tex, q1, 0);"""
_CHROMA = "    vec2 uv = mode == 2 ? sample_clamped(cu, c).rg : sample_clamped2(cu, cv, c);"
_CONTENT = "vec3 sample_faded(vec2 xy) {\n    vec3 value = sample_content(xy);"
_NO_CONTENT = "vec3 sample_faded(vec2 xy) {\n    vec3 value = vec3(fract(xy * 1e-3), 0.5);"
#: name -> (what is taken out, [(text, replacement), ...] in pipeline.glsl)
ABLATIONS: dict[str, tuple[str, list[tuple[str, str]]]] = {
    "whole": ("nothing", []),
    "no_lut_fetch": ("the LUT's three fetches and its interpolation", [(_LUT, "    return t;")]),
    "content_1_fetch": ("three of the content's (luma's) four bilinear fetches",
                        [(_BILINEAR, "    vec4 top = texelFetch(tex, q0, 0);\n    vec4 bottom = top;")]),
    "no_chroma": ("the chroma's fetches (4 or 8) and its bilinear weights",
                  [(_CHROMA, "    vec2 uv = c * 1e-6 + 0.5;")]),
    "no_yuv_matrix": ("the YUV matrix and offset", [("    return m * vec3(y, uv * weight) + o * weight;",
                                                      "    return vec3(y, uv * weight);")]),
    "no_content": ("the content's sampling (every fetch but the LUT's)", [(_CONTENT, _NO_CONTENT)]),
    "no_content_no_lut": ("every fetch: the homography, gain, quantisation and write remain",
                          [(_CONTENT, _NO_CONTENT), (_LUT, "    return t;")]),
    "write_only": ("all but the homography and the write",
                   [(_CONTENT, _NO_CONTENT),
                    ("vec4 finish(vec3 value) {", "vec4 finish(vec3 value) {\n    return vec4(value, 1.0);")]),
}
#: name -> (content kind as bench.node_variants._content makes it, interleave planar chroma)
VARIANTS = {"rgb": ("rgb", True), "yuv_planar": ("yuv1", True), "yuv_planar_8_chroma_fetches": ("yuv1", False),
            "yuv_nv12": ("yuv2", True)}


def ablated(source: str, name: str) -> str:
    """pipeline.glsl's ``source`` with ablation ``name`` applied (ValueError if it no longer applies)."""
    for old, new in ABLATIONS[name][1]:
        if old not in source:
            raise ValueError(f"ablation {name!r} no longer applies to pipeline.glsl: {old[:60]!r}...")
        source = source.replace(old, new)
    return source


def worker(size: tuple[int, int], rounds: int, frames: int, content: tuple[int, int] = (1920, 1080)) -> dict:
    """ns of llvmpipe's rasterizer CPU per output pixel, per variant and ablation: the median and the
    least over ``rounds`` of ``frames`` frames each (and a first round dropped), at output ``size``."""
    from bench.node_variants import _content, _raster_ns
    from node.render import Renderer
    from node.render.shaders import load_shader

    w, h = size
    cw, ch = content
    base = load_shader("pipeline.glsl")
    r = Renderer.standalone(w, h)
    own = r._programs                                      # the renderer's own, released with it
    programs: dict[str, dict] = {}
    try:
        s = min(w / cw, h / ch)
        r.set_homography(np.array([[s, 0.02 * s, 3.0], [-0.01 * s, s, 2.0], [1e-7, 2e-7, 1.0]]), (cw, ch))
        r.set_lut(np.stack([np.linspace(0, 1, 256) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32))
        r.set_gain(0.9)
        for name, (kind, interleave) in VARIANTS.items():
            r.interleave_chroma = interleave
            r.upload(name, _content(kind, (cw, ch), 1))
        samples: dict[tuple[str, str], list[float]] = {}
        for k in range(rounds + 1):                        # round 0 compiles and warms up, uncounted
            for ab in ABLATIONS:
                if ab not in programs:
                    programs[ab] = {}
                    r.ctx.includes["pipeline.glsl"] = ablated(base, ab)
                r._programs = programs[ab]                 # this ablation's compiled programs
                for name in VARIANTS:
                    for _ in range(2):
                        r.render(name)
                        r.ctx.finish()
                    ras0, _ = _raster_ns()
                    for _ in range(frames):
                        r.render(name)
                        r.ctx.finish()
                    ras1, _ = _raster_ns()
                    if k:
                        samples.setdefault((name, ab), []).append((ras1 - ras0) / frames / (w * h))
        out: dict = {}
        for (name, ab), v in samples.items():
            out.setdefault(name, {})[ab] = {"median_ns": round(float(np.median(v)), 2), "min_ns": round(min(v), 2)}
        return out
    finally:
        for progs in programs.values():
            for entry in progs.values():
                if entry[3] is not None:
                    entry[3].release()
                entry[0].release()
        r._programs = own
        r.release()


def ablate(sizes: list[tuple[int, int]], rounds: int, frames: int) -> dict:
    """The figures per output size (one worker process each, desktop OpenGL)."""
    result: dict = {}
    for w, h in sizes:
        print(f"bench node --ablate: {w}x{h}, {rounds} rounds of {frames} frames", file=sys.stderr, flush=True)
        t0 = time.monotonic()
        code = ("import json, sys; sys.path.insert(0, %r); from bench.node_ablation import worker; "
                "print(json.dumps(worker(%r, %d, %d)))" % (str(REPO), (w, h), rounds, frames))
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800,
                              cwd=str(REPO), env={**os.environ, "SHADOWLESS_GL": "gl"})
        if done.returncode != 0:
            raise RuntimeError(f"the ablation worker failed:\n{done.stderr[-3000:]}")
        result[f"{w}x{h}"] = {"seconds": round(time.monotonic() - t0, 1),
                              "ns_per_pixel": json.loads(done.stdout.strip().splitlines()[-1])}
    return {"rounds": rounds, "frames": frames, "content": "1920x1080",
            "ablations": {k: v[0] for k, v in ABLATIONS.items()}, "sizes": result}


def summary(res: dict) -> list[str]:
    """One line per size and variant: the whole's ns per pixel and what each ablation saves."""
    lines = []
    for size, per in res["sizes"].items():
        for name, abl in per["ns_per_pixel"].items():
            whole = abl["whole"]["median_ns"]
            parts = ", ".join(f"{ab} {e['median_ns'] - whole:+.1f}" for ab, e in abl.items() if ab != "whole")
            lines.append(f"{size} {name}: {whole:.1f} ns/pixel; without a piece: {parts}")
    return lines
