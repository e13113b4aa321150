"""Crossfades in the node's shader, on a real GL context (EGL, Mesa llvmpipe), against numpy.

A fade's step mixes the picture before into the frame's own content on the linear values,
``before * (1 - m) + after * m`` (:func:`protos.fade.mix_reference`), before the gain, the blend
maps and the LUT. The warp is linear in the content, so the reference warps the mixed content
with :func:`protos.spaces.warp_content` (float64): the GPU's float32 may land one level apart on
a few values, as for the blend. The module runs again in child processes on an emulated
OpenGL 3.1 (a Raspberry Pi's V3D) and on OpenGL ES 3 (the last test).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from node.render import Mesh, Renderer
from protos.blend import BlendMaps
from protos.fade import mix_reference, step_count, step_mix, step_pts
from protos.spaces import as_linear, warp_content

HERE = Path(__file__).resolve().parent
PW, PH = 96, 72
CW, CH = 80, 60
RNG = np.random.default_rng(38)
H_POSE = np.array([[1.1, 0.04, 2.0], [0.03, 1.05, -1.0], [1e-4, 2e-4, 1.0]])
LUT = np.stack([np.linspace(0, 1, 33) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32)


def close(got: np.ndarray, want: np.ndarray, *, share: float = 0.002) -> None:
    diff = np.abs(got.astype(np.int32) - want.astype(np.int32))
    assert diff.max() <= 1, f"max |diff| {diff.max()} levels > 1 ({(diff > 1).sum()} values)"
    assert (diff > 0).mean() <= share, f"{(diff > 0).sum()} of {diff.size} values differ (> {share:.2%})"


def rgb(image: np.ndarray) -> np.ndarray:
    a = as_linear(image).astype(np.float64)
    a = a[:, :, None] if a.ndim == 2 else a
    return np.repeat(a[:, :, :1], 3, axis=2) if a.shape[2] < 3 else a[:, :, :3]


@pytest.fixture(scope="module")
def r():
    renderer = Renderer.standalone(PW, PH)
    expected = os.environ.get("SHADOWLESS_TEST_GL_VERSION")
    if expected:
        assert renderer.ctx.version_code == int(expected), renderer.gl_profile
    yield renderer
    renderer.release()


def test_the_schedule_ends_on_the_new_picture_at_the_fade_s_end():
    k = step_count(2_000_000_000)
    assert k == 60 and step_mix(0, k) == 0.0 and step_mix(k, k) == 1.0
    assert step_pts(10, 2_000_000_000, 0, k) == 10 and step_pts(10, 2_000_000_000, k, k) == 2_000_000_010
    assert step_count(1) == 1 and step_count(0) == 0


@pytest.mark.parametrize("m", [0.0, 0.25, 0.6, 1.0])
def test_a_fade_step_matches_the_reference_with_lut_gain_and_blend(r, m):
    before = RNG.random((CH, CW, 3), dtype=np.float32)
    after = RNG.integers(0, 256, (CH, CW), dtype=np.uint8)      # grey: replicated to RGB
    maps = BlendMaps(RNG.random((9, 12, 3), dtype=np.float32), RNG.random((9, 12), dtype=np.float32) * 0.1)
    r.set_homography(H_POSE, (CW, CH))
    r.set_lut(LUT)
    r.set_gain(0.9)
    r.set_blend(maps)
    r.upload("before", before)
    r.upload("after", after)
    try:
        r.render("after", fade=("before", m))
        got = r.read().copy()
        want = warp_content(mix_reference(rgb(before), rgb(after), m).astype(np.float32), H_POSE, (PW, PH), lut=LUT,
                            gain=0.9, blend=(maps.alpha.astype(np.float32), maps.beta.astype(np.float32)))
        close(got, want)
    finally:
        r.set_blend(None)
        r.forget("before")
        r.forget("after")


def test_from_black_on_a_mesh_and_without_a_fade_bit_for_bit(r):
    f = 120.0
    p = np.array([[f, 0, (PW - 1) / 2, 0], [0, f, (PH - 1) / 2, 0], [0, 0, 1, 600.0]])
    v = np.array([[-1000, -1000, 0], [1000, -1000, 0], [1000, 1000, 0], [-1000, 1000, 0]], np.float32)
    mesh = Mesh(v, np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.uint32))
    r.set_projection(p, mesh, near=100.0, far=2000.0)
    r.set_lut(None)
    r.set_gain(1.0)
    r.upload("grey", np.full((CH, CW, 3), 0.8, np.float32))
    try:
        r.render("grey")
        plain = r.read().copy()
        assert (plain == 204).all()
        r.render("grey", fade=("", 0.5))          # from black: half the value
        assert (r.read() == 102).all()
        r.render("grey")
        assert (r.read() == plain).all(), "a frame without a fade is as before, bit for bit"
    finally:
        r.forget("grey")


def test_a_fade_that_cannot_be_shown_is_refused(r):
    r.set_homography(H_POSE, (CW, CH))
    r.upload("a", np.zeros((CH, CW, 3), np.uint8))
    r.upload("small", np.zeros((CH // 2, CW // 2, 3), np.uint8))
    try:
        with pytest.raises(ValueError, match="0..1"):
            r.render("a", fade=("", 1.5))
        with pytest.raises(ValueError, match="to fade from"):
            r.render("a", fade=("small", 0.5))
        with pytest.raises(KeyError):
            r.render("a", fade=("gone", 0.5))
    finally:
        r.forget("a")
        r.forget("small")


GL31 = {"MESA_GL_VERSION_OVERRIDE": "3.1", "MESA_GLSL_VERSION_OVERRIDE": "140", "GLCONTEXT_GLVERSION": "310",
        "SHADOWLESS_GL": "gl", "SHADOWLESS_TEST_GL_VERSION": "310"}
GLES = {"MESA_GL_VERSION_OVERRIDE": "3.0", "SHADOWLESS_GL": "gles", "SHADOWLESS_TEST_GL_VERSION": "320"}
#: the checks above, run in a child without pytest's start-up (a child per profile: Mesa reads the
#: overrides when a process makes its first context)
CHILD = """
import sys
sys.path.insert(0, {tests!r})
import test_render_fade as t
r = next(t.r.__wrapped__())
for m in (0.0, 0.25, 0.6, 1.0):
    t.test_a_fade_step_matches_the_reference_with_lut_gain_and_blend(r, m)
t.test_from_black_on_a_mesh_and_without_a_fade_bit_for_bit(r)
t.test_a_fade_that_cannot_be_shown_is_refused(r)
print("ok", r.ctx.version_code)
"""


@pytest.mark.skipif(bool(os.environ.get("SHADOWLESS_TEST_GL_VERSION")), reason="already in a child")
@pytest.mark.parametrize("extra", [pytest.param(GL31, id="gl3.1"), pytest.param(GLES, id="gles3.2")])
def test_every_fade_check_passes_on_opengl_3_1_and_opengl_es(extra):
    env = {k: v for k, v in os.environ.items() if k != "SHADOWLESS_GL" and not k.startswith("MESA_")}
    r = subprocess.run([sys.executable, "-c", CHILD.format(tests=str(HERE))], capture_output=True, text=True,
                       env={**env, **extra}, cwd=HERE.parents[1], timeout=600)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert r.stdout.split() == ["ok", extra["SHADOWLESS_TEST_GL_VERSION"]], r.stdout + r.stderr
