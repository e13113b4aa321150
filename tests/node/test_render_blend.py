"""Blend maps in the node's shader, on a real GL context (EGL, Mesa llvmpipe), against the numpy
reference of protos/spaces.py (:func:`~protos.spaces.blended_output`, :func:`~protos.spaces.warp_content`
with ``blend=``): ``LUT(clamp(gain * (alpha * value + beta)))``, the maps bilinear on their grid, a
4x4 ordered dither before the 8-bit output.

The node samples the maps with the texture unit's bilinear filter (LINEAR, CLAMP_TO_EDGE, one
fetch); the reference interpolates between texel centres with indices clamped, and is itself
checked against an independent bilinear, OpenCV's ``resize`` (INTER_LINEAR), as is the GL output.
llvmpipe's filter weights are float; a GPU whose sub-texel weights have 8 bits moves an alpha by at
most 1/512 of the step between two neighbouring texels (none at all for maps at a quarter of the
output's resolution, whose weights 1/8, 3/8, 5/8, 7/8 are exact in 8 bits).

The GPU computes in float32 and the reference in float64, so a value whose ``255 v + t`` lands a
hair from an integer may come out one level apart: at most 1 level, on at most 0.2 % of the values
(measured: under 0.01 %). Without maps, or for frames that do not apply the LUT (patterns), the
output is the one without blending, bit for bit. The dither is shown to remove banding: a slow ramp
halved by the maps keeps a flat run of at most 8 pixels in its 4x4 block means, where rounding
leaves runs of 24 and more.

The module runs again in child processes on an emulated OpenGL 3.1 (a Raspberry Pi's V3D) and on
OpenGL ES 3 (see the last tests).
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
from protos.spaces import blend_sample, blended_output, dither_thresholds, quantise, warp_content

HERE = Path(__file__).resolve().parent
PW, PH = 160, 120
CW, CH = 120, 90
RNG = np.random.default_rng(37)
H_POSE = np.array([[1.25, 0.05, 3.0], [0.02, 1.15, -2.0], [1e-4, 2e-4, 1.0]])
LUT = np.stack([np.linspace(0, 1, 33) ** (1 / g) for g in (2.1, 2.2, 2.3)]).astype(np.float32)
#: the largest share of values one level apart from the reference (float32 against float64)
SHARE = 0.002


def random_maps(w: int, h: int, *, beta_max: float = 0.2) -> BlendMaps:
    return BlendMaps(RNG.random((h, w, 3), dtype=np.float32), RNG.random((h, w), dtype=np.float32) * beta_max)


def smooth_maps(w: int, h: int) -> BlendMaps:
    """Maps like a blend's: a ramp across an overlap and a gentle black offset."""
    x = np.linspace(0, 1, w, dtype=np.float32)
    y = np.linspace(0, 1, h, dtype=np.float32)[:, None]
    alpha = np.stack([np.clip(1.2 - x, 0, 1) * (0.9 + 0.1 * y), np.clip(1.1 - x, 0, 1) + 0 * y,
                      np.clip(1.0 - 0.8 * x, 0, 1) + 0 * y], axis=2)
    return BlendMaps(alpha.astype(np.float32), (0.02 + 0.05 * x * y).astype(np.float32))


def close(got: np.ndarray, want: np.ndarray, *, share: float = SHARE) -> None:
    diff = np.abs(got.astype(np.int32) - want.astype(np.int32))
    assert diff.max() <= 1, f"max |diff| {diff.max()} levels > 1 ({(diff > 1).sum()} values)"
    assert (diff > 0).mean() <= share, f"{(diff > 0).sum()} of {diff.size} values differ (> {share:.2%})"


@pytest.fixture(scope="module")
def renderer():
    r = Renderer.standalone(PW, PH)
    expected = os.environ.get("SHADOWLESS_TEST_GL_VERSION")
    if expected:
        assert r.ctx.version_code == int(expected), r.gl_profile
    yield r
    r.release()


@pytest.fixture
def r(renderer):
    renderer.resize(PW, PH)
    renderer.set_blend(None)
    renderer.set_lut(None)
    renderer.set_gain(1.0)
    renderer.set_homography(H_POSE, (CW, CH))
    for cid in renderer.content_ids:
        renderer.forget(cid)
    return renderer


def draw(r: Renderer, content: np.ndarray, **kwargs) -> np.ndarray:
    cid = f"c{RNG.integers(1 << 62)}"
    r.upload(cid, content)
    r.render(cid, **kwargs)
    out = r.read().copy()
    r.forget(cid)
    return out


# ----------------------------------------------------------------------------- the reference itself


def test_the_reference_samples_the_maps_on_their_grid():
    """Texel centres land where protos/blend.py says; in between, bilinear; beyond, the edge texel."""
    alpha = np.zeros((3, 4, 3), np.float32)
    alpha[..., 0] = np.arange(4)[None, :] / 4.0         # columns 0, .25, .5, .75
    beta = np.repeat(np.array([0.0, 0.5, 1.0], np.float32)[:, None], 4, axis=1)
    a, b = blend_sample(alpha, beta, (16, 12))          # 4 px per texel
    # texel j's centre is pixel (j + .5) * 4 - .5 = 1.5, 5.5, ...: pixel 1 and 2 straddle it equally
    assert a[0, 1, 0] == pytest.approx(0.0) and a[0, 2, 0] == pytest.approx(1 / 32)
    assert a[0, 3, 0] == pytest.approx(0.25 * 1.5 / 4) and a[0, 15, 0] == pytest.approx(0.75)   # clamped
    assert b[0, 0] == 0.0 and b[11, 0] == 1.0 and b[5, 3] == pytest.approx(0.875 * 0.5)   # row 5: 0.875 of the way to row 1
    # one texel: the whole frame
    a1, b1 = blend_sample(np.full((1, 1, 3), 0.25, np.float32), np.full((1, 1), 0.5, np.float32), (7, 5))
    assert (a1 == 0.25).all() and (b1 == 0.5).all()


def cv2_maps(maps: BlendMaps, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The maps at every pixel of an output of ``size`` (W, H) by OpenCV's bilinear resize, from the
    float16 values a node holds: alpha (H, W, 3), beta (H, W), float64."""
    import cv2

    stack = np.concatenate([maps.alpha, maps.beta[:, :, None]], axis=2).astype(np.float16).astype(np.float32)
    out = cv2.resize(stack, size, interpolation=cv2.INTER_LINEAR).astype(np.float64)
    return out[:, :, :3], out[:, :, 3]


@pytest.mark.parametrize("map_size", [(40, 30), (37, 23), (1, 1), (160, 120)])
def test_the_reference_samples_as_an_independent_bilinear(map_size):
    maps = random_maps(*map_size)
    a, b = blend_sample(maps.alpha, maps.beta, (PW, PH))
    ca, cb = cv2_maps(maps, (PW, PH))
    assert np.abs(a - ca).max() < 1e-5 and np.abs(b - cb).max() < 1e-5


def test_the_dither_keeps_each_blocks_mean():
    """Each 4x4 block holds every threshold once: a value k + f shows k + 1 on a share f of it."""
    t = dither_thresholds((8, 8))
    assert sorted(t[:4, :4].ravel()) == [(i + 0.5) / 16 for i in range(16)]
    assert (t[:4, :4] == t[4:, 4:]).all()
    for f in (0.0, 0.3, 0.5, 0.9):
        out = blended_output(np.full((8, 8, 3), (100 + f) / 255), np.ones((1, 1, 3)), np.zeros((1, 1)))
        assert abs(out[:4, :4].mean() - (100 + f)) <= 1 / 32


# ----------------------------------------------------------------------------- GL against the reference


@pytest.mark.parametrize("map_size", [(1, 1), (7, 5), (40, 30), (160, 120), (333, 250)])
def test_random_maps_on_random_content_match_the_reference(r, map_size):
    content = RNG.random((CH, CW, 3), dtype=np.float32)
    maps = random_maps(*map_size)
    r.set_lut(LUT)
    r.set_gain(0.9)
    r.set_blend(maps)
    got = draw(r, content)
    want = warp_content(content, H_POSE, (PW, PH), lut=LUT, gain=0.9, blend=(maps.alpha, maps.beta))
    close(got, want)
    # the maps really act: without them the picture is another one
    r.set_blend(None)
    assert (np.abs(draw(r, content).astype(int) - want) > 1).mean() > 0.5


@pytest.mark.parametrize("map_size", [(40, 30), (37, 23)])
def test_the_maps_on_screen_are_an_independent_bilinear_of_them(r, map_size):
    """Full white through the maps, no LUT: each pixel shows floor(255 (alpha + beta) + t), alpha and
    beta from OpenCV's resize of the maps (a quarter of the output's resolution, and an odd ratio)."""
    maps = random_maps(*map_size, beta_max=0.1)
    r.set_blend(maps)
    got = draw(r, np.ones((PH, PW, 3), np.float32), space="projector")
    a, b = cv2_maps(maps, (PW, PH))
    want = np.floor(np.clip(a + b[:, :, None], 0, 1) * 255 + dither_thresholds((PW, PH))[:, :, None])
    close(got, want.astype(np.uint8))


def test_ramps_through_smooth_maps_match_the_reference(r):
    """Ramps in every channel, projector space and warped, through maps shaped like a blend's."""
    ramp = np.linspace(0, 1, PW, dtype=np.float32)[None, :, None] * np.linspace(0.2, 1, PH, dtype=np.float32)[:, None, None]
    ramp = np.concatenate([ramp, ramp[::-1], ramp[:, ::-1]], axis=2)
    maps = smooth_maps(48, 27)
    r.set_lut(LUT)
    r.set_blend(maps)
    got = draw(r, ramp, space="projector")
    close(got, blended_output(ramp, maps.alpha, maps.beta, lut=LUT))
    content = ramp[:CH, :CW]
    close(draw(r, content), warp_content(content, H_POSE, (PW, PH), lut=LUT, blend=(maps.alpha, maps.beta)))


def test_maps_follow_a_resize_of_the_output(r):
    maps = smooth_maps(20, 15)
    r.set_blend(maps)
    r.resize(96, 64)
    content = RNG.random((64, 96, 3), dtype=np.float32)
    close(draw(r, content, space="projector"), blended_output(content, maps.alpha, maps.beta))


def test_a_mesh_is_blended_alike(r):
    """The mesh program shares the pipeline: flat grey content on a plane filling the view."""
    f = 150.0
    p = np.array([[f, 0, (PW - 1) / 2, 0], [0, f, (PH - 1) / 2, 0], [0, 0, 1, 600.0]])
    v = np.array([[-1000, -1000, 0], [1000, -1000, 0], [1000, 1000, 0], [-1000, 1000, 0]], np.float32)
    mesh = Mesh(v, np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.uint32))
    r.set_projection(p, mesh, near=100.0, far=2000.0)
    grey = np.full((CH, CW, 3), 0.5, np.float32)
    plain = draw(r, grey)
    assert (plain == 128).all()
    maps = random_maps(30, 20)
    r.set_blend(maps)
    close(draw(r, grey), blended_output(np.full((PH, PW, 3), 0.5), maps.alpha, maps.beta))


# ----------------------------------------------------------------------------- what stays as it was


def test_without_maps_and_for_patterns_the_output_is_unchanged_bit_for_bit(r):
    content = RNG.random((CH, CW, 3), dtype=np.float32)
    pattern = RNG.integers(0, 256, (PH, PW, 3), dtype=np.uint8)
    r.set_lut(LUT)
    r.set_gain(0.8)
    before = draw(r, content)
    before_pattern = draw(r, pattern, space="projector", apply_lut=False)
    assert (before_pattern == pattern).all()
    r.set_blend(random_maps(16, 12))
    assert (draw(r, pattern, space="projector", apply_lut=False) == pattern).all(), "a pattern is never blended"
    assert not (draw(r, content) == before).all()
    r.set_blend(None)
    assert (draw(r, content) == before).all()
    close(before, warp_content(content, H_POSE, (PW, PH), lut=LUT, gain=0.8))


def test_maps_loaded_ahead_show_the_same_and_bad_maps_change_nothing(r):
    content = RNG.random((CH, CW, 3), dtype=np.float32)
    first, second = random_maps(10, 8), random_maps(12, 9)
    r.set_blend(first)
    with_first = draw(r, content)
    r.load_blend(second)
    assert r.blend_id == first.blend_id and (draw(r, content) == with_first).all(), "loading ahead shows nothing"
    r.set_blend(second)
    assert r.blend_id == second.blend_id
    ahead = draw(r, content)
    r.set_blend(None)
    r.set_blend(second)                    # uploaded afresh: the same picture
    assert (draw(r, content) == ahead).all()
    with pytest.raises(ValueError, match="BlendMaps"):
        r.set_blend(np.ones((4, 4, 4), np.float32))
    with pytest.raises(ValueError, match="BlendMaps"):
        r.load_blend("maps")
    assert r.blend_id == second.blend_id and (draw(r, content) == ahead).all()


# ----------------------------------------------------------------------------- banding


def longest_flat_run(profile: np.ndarray, step: int) -> int:
    """The longest run (pixels) of equal consecutive values in ``profile``, each value ``step`` px wide."""
    best = run = 1
    for a, b in zip(profile[:-1], profile[1:]):
        run = run + 1 if a == b else 1
        best = max(best, run)
    return best * step


def test_dithering_removes_the_banding_of_a_halved_slow_ramp(r):
    """A ramp of 0..0.2 over 640 px, halved by the maps: about one 8-bit level every 25 px. Rounded,
    it stands in flat bands of 24+ px; dithered, its 4x4 block means move every block or two and
    stay within 1/8 level of the exact value."""
    w, h = 640, 16
    r.resize(w, h)
    ramp = np.repeat(np.linspace(0, 0.2, w, dtype=np.float32)[None, :], h, axis=0)
    maps = BlendMaps(np.full((4, 4, 3), 0.5, np.float32), np.zeros((4, 4), np.float32))
    r.set_blend(maps)
    got = draw(r, ramp, space="projector")[:, :, 0].astype(np.float64)
    exact = 255 * 0.5 * np.linspace(0, 0.2, w, dtype=np.float32).astype(np.float64)
    blocks = got.reshape(h // 4, 4, w // 4, 4).mean(axis=(1, 3))          # (4, 160) block means
    block_exact = exact.reshape(w // 4, 4).mean(axis=1)
    assert np.abs(blocks - block_exact).max() <= 1 / 8 + 1e-9
    assert longest_flat_run(blocks[0], 4) <= 8
    rounded = quantise(0.5 * ramp).astype(np.float64)     # what rounding would give
    rounded_blocks = rounded.reshape(h // 4, 4, w // 4, 4).mean(axis=(1, 3))
    assert longest_flat_run(rounded_blocks[0], 4) >= 24, "the measure sees bands where there are"
    assert np.abs(rounded_blocks - block_exact).max() >= 0.4


# ----------------------------------------------------------------------------- other GL profiles

GL31 = {"MESA_GL_VERSION_OVERRIDE": "3.1", "MESA_GLSL_VERSION_OVERRIDE": "140", "GLCONTEXT_GLVERSION": "310",
        "SHADOWLESS_GL": "gl", "SHADOWLESS_TEST_GL_VERSION": "310"}
GLES = {"MESA_GL_VERSION_OVERRIDE": "3.0", "SHADOWLESS_TEST_GL_VERSION": "320"}


@pytest.mark.skipif(bool(os.environ.get("SHADOWLESS_TEST_GL_VERSION")), reason="already in a child")
@pytest.mark.parametrize("extra", [pytest.param(GL31, id="gl3.1"), pytest.param(GLES, id="gles3.2")])
def test_every_blend_check_passes_on_opengl_3_1_and_opengl_es(extra):
    env = {k: v for k, v in os.environ.items() if k != "SHADOWLESS_GL" and not k.startswith("MESA_")}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", "not opengl_es",
                        str(Path(__file__))], capture_output=True, text=True, env={**env, **extra},
                       cwd=HERE.parents[1], timeout=600)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and "failed" not in r.stdout
