"""YUV planes converted in the node's shader, on a real GL context (EGL, Mesa llvmpipe), against
protos/yuv.py's numpy reference (itself checked against swscale in tests/protos/test_yuv.py).

At the content's own pixels (projector space) the shader samples luma at texel centres and chroma
as the reference does, and must land on the reference's 8-bit level exactly, save a float32
rounding on a rare value (at most 1 level, on 0.2 % of the values). Scaled by the warp (the planes
at the video's size, the pose at the content's), it is compared with the renderer's RGB path fed
the reference picture through the same homography, within 1 level (chroma sampled at the point
rather than at the luma texels around it, on ramps). The module runs again in child processes on
an emulated OpenGL 3.1 (a Raspberry Pi's V3D) and on a bare OpenGL ES 3.0 without 16-bit
normalised textures (10-bit planes go up as float32 there).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest

from node.render import Mesh, Renderer
from node.yuv import yuv_planes
from protos.spaces import warp_content
from protos.yuv import to_rgb

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "protos"))
from test_yuv import bars_and_ramps  # noqa: E402  (the same bars and ramps as the reference's test)

PW, PH = 98, 58
CASES = [("yuv420p", "bt709", False), ("nv12", "bt601", True), ("yuv422p", "bt2020", False),
         ("yuv420p10le", "bt2020", False), ("p010le", "bt709", True), ("yuv444p", "bt601", False)]


@pytest.fixture(scope="module")
def r():
    renderer = Renderer.standalone(PW, PH)
    expected = os.environ.get("SHADOWLESS_TEST_GL_VERSION")
    if expected:
        assert renderer.ctx.version_code == int(expected), renderer.gl_profile
    yield renderer
    renderer.release()


def planes(fmt: str, matrix: str, full: bool, w: int = PW, h: int = PH, img: np.ndarray | None = None):
    src = av.VideoFrame.from_ndarray(bars_and_ramps(w, h) if img is None else img, format="rgb24")
    f = src.reformat(format=fmt, dst_colorspace={"bt709": "ITU709", "bt601": "ITU601", "bt2020": "BT2020"}[matrix],
                     dst_color_range="JPEG" if full else "MPEG")
    return yuv_planes(f)


def levels(rgb: np.ndarray) -> np.ndarray:
    return np.floor(np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.int32)


def test_the_shader_converts_every_layout_as_the_reference_does(r):
    for fmt, matrix, full in CASES + CASES[:2]:       # the last two reuse a forgotten frame's textures
        y = planes(fmt, matrix, full)
        r.upload("yuv", y)
        try:
            r.render("yuv", space="projector", apply_lut=False)
            diff = np.abs(r.read().astype(np.int32) - levels(to_rgb(y)))
        finally:
            r.forget("yuv")
        assert diff.max() <= 1 and (diff > 0).mean() <= 0.002, f"{fmt} {matrix}: max {diff.max()}"


def test_the_warp_scales_the_planes_to_the_content_and_fades_from_them(r):
    # a 4:2:0 picture (smooth ramps) twice the content's size, warped: as the RGB path warps the
    # reference picture
    lw, lh, cw, ch = 160, 96, 80, 48
    x, v = np.linspace(0, 1, lw), np.linspace(0, 1, lh)[:, None]
    ramps = np.stack([np.broadcast_to(x, (lh, lw)), 0.2 + 0.6 * v * (1 - x), np.broadcast_to(v, (lh, lw))], axis=-1)
    y = planes("nv12", "bt709", False, lw, lh, img=np.round(ramps * 255).astype(np.uint8)).at_size((cw, ch))
    ref = np.clip(to_rgb(y), 0.0, 1.0).astype(np.float32)
    pose = np.array([[1.1, 0.04, 2.0], [0.03, 1.05, -1.0], [1e-4, 2e-4, 1.0]])
    to_content = np.array([[cw / lw, 0, 0.5 * cw / lw - 0.5], [0, ch / lh, 0.5 * ch / lh - 0.5], [0, 0, 1.0]])
    r.set_homography(pose, (cw, ch))
    r.upload("yuv", y)
    r.upload("grey", np.full((ch, cw), 0.5, np.float32))
    try:
        r.render("yuv")
        got = r.read().astype(np.int32)
        want = warp_content(ref, pose @ to_content, (PW, PH)).astype(np.int32)
        diff = np.abs(got - want)
        assert diff.max() <= 1 and (diff > 0).mean() <= 0.05, f"max {diff.max()}, {(diff > 0).mean():.3f} differ"
        # a crossfade from the YUV picture to a grey one, halfway: the mean of the two
        r.render("grey")
        grey = r.read().astype(np.int32)
        r.render("grey", fade=("yuv", 0.5))
        mixed = r.read().astype(np.int32)
        assert np.abs(mixed - (got + grey) / 2.0).max() <= 1.0
        # on a mesh the planes are addressed through the texture coordinates: as the reference picture is
        f = 120.0
        p = np.array([[f, 0, (PW - 1) / 2, 0], [0, f, (PH - 1) / 2, 0], [0, 0, 1, 600.0]])
        v = np.array([[-900, -700, 0], [900, -700, 0], [900, 700, 0], [-900, 700, 0]], np.float32)
        r.set_projection(p, Mesh(v, np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
                                 np.array([[0, 1, 2], [0, 2, 3]], np.uint32)), near=100.0, far=2000.0)
        r.render("yuv")
        on_mesh = r.read().astype(np.int32)
        r.upload("ref", ref)
        r.render("ref")
        diff = np.abs(on_mesh - r.read().astype(np.int32))
        assert diff.max() <= 1 and (diff > 0).mean() <= 0.05, f"max {diff.max()}, {(diff > 0).mean():.3f} differ"
        assert on_mesh.mean() > 20        # the picture is there
    finally:
        for cid in ("yuv", "grey", "ref"):
            r.forget(cid)
        r.clear_pose()


def test_planar_chroma_draws_the_same_picture_interleaved_or_not(r):
    # on llvmpipe a planar picture's U and V go up interleaved (four chroma fetches per pixel, not
    # eight); the shader's planar path, which a GPU draws, must land on the same levels, bit for bit
    pose = np.array([[1.1, 0.04, 2.0], [0.03, 1.05, -1.0], [1e-4, 2e-4, 1.0]])
    r.set_homography(pose, (PW, PH))
    default = r.interleave_chroma
    try:
        for fmt in ("yuv420p", "yuv420p10le", "yuv422p"):
            y = planes(fmt, "bt709", False)
            got = []
            for interleave in (True, False, True):     # the last one after the planar picture's textures are forgotten
                r.interleave_chroma = interleave
                r.upload("yuv", y)
                try:
                    r.render("yuv")
                    got.append(r.read().astype(np.int32))
                finally:
                    r.forget("yuv")
            for other, interleave in zip(got[1:], ("planar", "interleaved again")):
                diff = np.abs(other - got[0])
                assert diff.max() == 0, f"{fmt} {interleave}: max {diff.max()}, {(diff > 0).mean():.3f} differ"
            assert got[0].std() > 20, f"{fmt}: the picture is not there"
    finally:
        r.interleave_chroma = default
        r.clear_pose()


GL31 = {"MESA_GL_VERSION_OVERRIDE": "3.1", "MESA_GLSL_VERSION_OVERRIDE": "140", "GLCONTEXT_GLVERSION": "310",
        "SHADOWLESS_GL": "gl", "SHADOWLESS_TEST_GL_VERSION": "310"}
GLES_BARE = {"MESA_GL_VERSION_OVERRIDE": "3.0", "SHADOWLESS_GL": "gles", "MESA_GLES_VERSION_OVERRIDE": "3.0",
             "MESA_EXTENSION_OVERRIDE": "-GL_EXT_texture_norm16", "SHADOWLESS_TEST_GL_VERSION": "300"}
CHILD = """
import sys
sys.path.insert(0, {tests!r})
import test_render_yuv as t
r = next(t.r.__wrapped__())
t.test_the_shader_converts_every_layout_as_the_reference_does(r)
t.test_the_warp_scales_the_planes_to_the_content_and_fades_from_them(r)
t.test_planar_chroma_draws_the_same_picture_interleaved_or_not(r)
print("ok", r.ctx.version_code, r._norm16)
"""


@pytest.mark.skipif(bool(os.environ.get("SHADOWLESS_TEST_GL_VERSION")), reason="already in a child")
@pytest.mark.parametrize("extra", [pytest.param(GL31, id="gl3.1"), pytest.param(GLES_BARE, id="gles3.0-bare")])
def test_every_yuv_check_passes_on_opengl_3_1_and_a_bare_opengl_es_3_0(extra):
    env = {k: v for k, v in os.environ.items() if k != "SHADOWLESS_GL" and not k.startswith("MESA_")}
    r = subprocess.run([sys.executable, "-c", CHILD.format(tests=str(HERE))], capture_output=True, text=True,
                       env={**env, **extra}, cwd=HERE.parents[1], timeout=600)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    norm16 = "True" if extra is GL31 else "False"
    assert r.stdout.split() == ["ok", extra["SHADOWLESS_TEST_GL_VERSION"], norm16], r.stdout + r.stderr
