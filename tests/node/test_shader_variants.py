"""Every compiled form of the node's warp shader against numpy, on a real GL context (EGL, llvmpipe).

The renderer compiles one program per combination of the frame's content kind (RGB, grey, planar
YUV, NV12), the picture a fade starts from (none, black, or any kind), blend maps and the LUT
(pipeline.glsl's #defines). Each combination of content and fade is drawn here, with the LUT,
with blend maps, or without the LUT in turn, and compared with :func:`protos.spaces.warp_content`
of the same pictures mixed by :func:`protos.fade.mix_reference`: a program that took another
path (a grey picture's channel, the wrong picture before, no dither, no LUT) lands many levels
off. YUV pictures carry one chroma value each, so their conversion is affine in Y and the
reference converts them first (:func:`protos.yuv.to_rgb`). The grid runs again in a child process
on a bare OpenGL ES 3.0; OpenGL 3.1 runs the shaders through the render, YUV, fade and blend tests'
child processes.
"""
from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from node.render import Renderer
from protos.blend import BlendMaps
from protos.fade import mix_reference
from protos.spaces import as_linear, warp_content
from protos.yuv import YuvFrame, to_rgb

HERE = Path(__file__).resolve().parent
PW, PH = 48, 36
CW, CH = 40, 30
POSE = np.array([[1.1, 0.04, 2.0], [0.03, 1.05, -1.0], [1e-4, 2e-4, 1.0]])
LUT = np.stack([np.linspace(0, 1, 33) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32)
KINDS = ("rgb", "grey", "yuv_planar", "nv12")
#: (blend maps, apply_lut) taken in turn over the content and fade combinations
MODES = ((False, True), (True, True), (False, False))


def picture(kind: str, seed: int):
    """(what is uploaded, its linear RGB (CH, CW, 3) float64) for a picture of ``kind``."""
    rng = np.random.default_rng(seed)
    if kind == "rgb":
        img = rng.integers(0, 256, (CH, CW, 3), dtype=np.uint8)
        return img, as_linear(img).astype(np.float64)
    if kind == "grey":
        img = rng.integers(0, 256, (CH, CW), dtype=np.uint8)
        return img, np.repeat(as_linear(img).astype(np.float64)[:, :, None], 3, axis=2)
    y = rng.integers(40, 200, (CH, CW), dtype=np.uint8)
    u, v = np.full((CH // 2, CW // 2), 120, np.uint8), np.full((CH // 2, CW // 2), 136, np.uint8)
    if kind == "yuv_planar":
        frame = YuvFrame(planes=(y, u, v), layout="planar")
    else:
        frame = YuvFrame(planes=(y, np.ascontiguousarray(np.stack([u, v], axis=2))), layout="semiplanar")
    return frame, to_rgb(frame)


@pytest.fixture(scope="module")
def r():
    renderer = Renderer.standalone(PW, PH)
    renderer.set_homography(POSE, (CW, CH))
    renderer.set_lut(LUT)
    renderer.set_gain(0.9)
    yield renderer
    renderer.release()


def test_every_content_and_fade_variant_draws_what_numpy_computes(r):
    pictures = {kind: picture(kind, k) for k, kind in enumerate(KINDS)}
    befores = {kind: picture(kind, 10 + k) for k, kind in enumerate(KINDS)}
    rng = np.random.default_rng(39)
    maps = BlendMaps(0.5 + 0.5 * rng.random((9, 12, 3), dtype=np.float32), rng.random((9, 12), dtype=np.float32) * 0.1)
    blend = (maps.alpha.astype(np.float32), maps.beta.astype(np.float32))
    for kind in KINDS:
        r.upload(kind, pictures[kind][0])
        r.upload("before_" + kind, befores[kind][0])
    failures = []
    combos = list(itertools.product(KINDS, (None, "black", *KINDS)))
    for i, (kind, before) in enumerate(combos):
        blended, lut = MODES[(i + KINDS.index(kind)) % len(MODES)]
        r.set_blend(maps if blended else None)
        fade = None if before is None else ("" if before == "black" else "before_" + before, 0.4)
        r.render(kind, apply_lut=lut, fade=fade)
        got = r.read().astype(np.int32)
        content = pictures[kind][1]
        if before is not None:
            start = np.zeros_like(content) if before == "black" else befores[before][1]
            content = mix_reference(start, content, 0.4)
        want = warp_content(content.astype(np.float32), POSE, (PW, PH), lut=LUT, gain=0.9, apply_lut=lut,
                            blend=blend if blended else None).astype(np.int32)
        diff = np.abs(got - want)
        if diff.max() > 1 or (diff > 0).mean() > 0.01:
            failures.append(f"{kind} from {before} blend={blended} lut={lut}: max {diff.max()}, "
                            f"{(diff > 0).mean():.3f} differ")
    r.set_blend(None)
    assert not failures, "\n".join(failures)
    assert len(combos) == 24


def test_warming_up_changes_neither_the_picture_nor_the_content(r):
    img, _ = picture("rgb", 5)
    r.upload("still", img)
    r.set_blend(None)
    r.render("still")
    before = r.read().copy()
    r.warm_up()
    assert r.has("still") and r.read().max() == 0      # the framebuffer is left cleared
    r.render("still")
    assert np.array_equal(r.read(), before)


CHILD = """
import sys
sys.path.insert(0, {tests!r})
import test_shader_variants as t
r = next(t.r.__wrapped__())
t.test_every_content_and_fade_variant_draws_what_numpy_computes(r)
print("ok", r.ctx.version_code)
"""


@pytest.mark.skipif(bool(os.environ.get("SHADOWLESS_GL")), reason="a child of this test, or a chosen API")
def test_every_variant_compiles_and_draws_alike_on_a_bare_opengl_es_3_0():
    # GLSL ES 3.00 is the strictest of the three languages the shaders are compiled as
    env = {k: v for k, v in os.environ.items() if not k.startswith("MESA_")}
    extra = {"SHADOWLESS_GL": "gles", "MESA_GLES_VERSION_OVERRIDE": "3.0",
             "MESA_EXTENSION_OVERRIDE": "-GL_EXT_texture_norm16 -GL_OES_texture_float_linear"}
    done = subprocess.run([sys.executable, "-c", CHILD.format(tests=str(HERE))], capture_output=True, text=True,
                          env={**env, **extra}, cwd=HERE.parents[1], timeout=600)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert done.stdout.split() == ["ok", "300"], done.stdout + done.stderr
