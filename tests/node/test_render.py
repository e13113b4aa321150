"""The node renderer on a real GL context (EGL, Mesa llvmpipe here), against the project's
definition of the warp and an independent cross-check.

References:
* :func:`protos.spaces.warp_content` (with :func:`~protos.spaces.lut_lookup`): the node's warp
  convention, defined once for every process, in float64 numpy. The shader must compute
  exactly this, so it is compared everywhere, on sharp random content too: max |diff| <= 1
  level (float32 on the GPU against float64 at rounding ties) on a small share of the values.
  :func:`~protos.spaces.projector_samples` says where each projector pixel samples the content
  (for the masks below).
* ``cv2.warpPerspective(content, H, size, INTER_LINEAR, BORDER_CONSTANT, 0)`` on float32
  content, then :func:`~protos.spaces.lut_lookup`: an independent implementation of the same
  convention. OpenCV quantises source coordinates to 1/32 px, so it is compared on smooth
  content, away from the 1-px band around the content's edge (a hard step there): max
  |diff| <= 1 level (2 with a LUT), mean <= 0.1 level. On sharp random content its grid costs
  up to 6 levels (mean <= 0.3).
* For meshes, the vertices are projected with P in numpy: a flat mesh must render the
  homography of its plane, a two-layer mesh the nearer layer where it covers.
"""
from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from node.render import Mesh, Renderer
from protos.spaces import lut_lookup, projector_samples, warp_content

PW, PH = 160, 120  # projector pixels
CW, CH = 120, 80  # content pixels
MM_PER_PX = 5.0  # content grid on the table: 600 x 400 mm centred on the origin
RNG = np.random.default_rng(7)


# ----------------------------------------------------------------------------- geometry helpers


def look_at(position, target, *, f: float = 150.0, size=(PW, PH)) -> np.ndarray:
    """(3, 4) float64 projection matrix K [R | -R C] of a pinhole at ``position`` aimed at ``target``."""
    c = np.asarray(position, float)
    z = np.asarray(target, float) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])
    k = np.array([[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1]])
    return k @ np.hstack([r, (-r @ c)[:, None]])


P_TILTED = look_at((250.0, -150.0, 600.0), (0.0, 0.0, 0.0))


def content_to_plane(x0, y0, x1, y1, u0=0.0, v0=0.0, u1=1.0, v1=1.0, *, size=(CW, CH)) -> np.ndarray:
    """(3, 3): content pixels -> world (X, Y, 1) for a rectangle [x0, x1] x [y0, y1] carrying uv [u0, u1] x [v0, v1].

    Content pixel x = u * W - 0.5, so u = (x + 0.5) / W.
    """
    w, h = size
    sx = (x1 - x0) / ((u1 - u0) * w)
    sy = (y1 - y0) / ((v1 - v0) * h)
    return np.array([[sx, 0, x0 + (0.5 / w - u0) * sx * w], [0, sy, y0 + (0.5 / h - v0) * sy * h], [0, 0, 1]])


def plane_homography(p: np.ndarray, z: float, a: np.ndarray) -> np.ndarray:
    """(3, 3): content pixels -> projector pixels through the plane at height z."""
    return np.column_stack([p[:, 0], p[:, 1], z * p[:, 2] + p[:, 3]]) @ a


H_TILTED = plane_homography(P_TILTED, 0.0, content_to_plane(-300, -200, 300, 200))


def quad_mesh(x0, y0, x1, y1, z, u0=0.0, v0=0.0, u1=1.0, v1=1.0, *, n=(4, 3)) -> Mesh:
    """A flat rectangle at height z split into an n[0] x n[1] grid of quads (2 triangles each)."""
    gx, gy = n
    s, t = np.meshgrid(np.linspace(0, 1, gx + 1), np.linspace(0, 1, gy + 1))
    s, t = s.ravel(), t.ravel()
    vertices = np.stack([x0 + s * (x1 - x0), y0 + t * (y1 - y0), np.full_like(s, z)], axis=1)
    uvs = np.stack([u0 + s * (u1 - u0), v0 + t * (v1 - v0)], axis=1)
    faces = []
    for j in range(gy):
        for i in range(gx):
            a = j * (gx + 1) + i
            faces += [(a, a + 1, a + gx + 2), (a, a + gx + 2, a + gx + 1)]
    return Mesh(vertices, uvs, np.array(faces))


# ----------------------------------------------------------------------------- pixel references


def normalised(img: np.ndarray) -> np.ndarray:
    """Content as float64 in [0, 1] (integers divided by their maximum), shape (H, W, C)."""
    x = img.astype(np.float64)
    if np.issubdtype(img.dtype, np.integer):
        x /= np.iinfo(img.dtype).max
    return x if x.ndim == 3 else x[:, :, None]


def rgb(x: np.ndarray) -> np.ndarray:
    """(H, W, C) -> (H, W, 3) the way the renderer shows it: grey (C <= 2) replicated, alpha dropped."""
    return np.repeat(x[:, :, :1], 3, axis=2) if x.shape[2] <= 2 else x[:, :, :3]


def content_coords(hm: np.ndarray, size=(PW, PH)):
    """Content coordinates of every projector pixel (:func:`protos.spaces.projector_samples`), and
    whether its ray meets the content's plane (the samples mark the others with -10)."""
    sx, sy = projector_samples(hm, size)
    return sx, sy, ~((sx == -10.0) & (sy == -10.0))


def spaces_warp(content: np.ndarray, hm: np.ndarray, size=(PW, PH), **kwargs) -> np.ndarray:
    """What the node must output, per :func:`protos.spaces.warp_content`, as int levels (H, W, 3)."""
    return warp_content(content, hm, size, **kwargs).astype(int)


def projector_space(image: np.ndarray, **kwargs) -> np.ndarray:
    """:func:`spaces_warp` of content that already is in projector pixels (identity pose)."""
    return spaces_warp(image, np.eye(3), (image.shape[1], image.shape[0]), **kwargs)


def cv2_warp(content: np.ndarray, hm: np.ndarray, size=(PW, PH)) -> np.ndarray:
    """cv2.warpPerspective (float32, INTER_LINEAR, BORDER_CONSTANT 0) -> (H, W, 3) float64."""
    x = rgb(normalised(content)).astype(np.float32)
    out = cv2.warpPerspective(x, hm, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(np.float64)


def edge_band(hm: np.ndarray, size=(PW, PH), *, content_size=(CW, CH)) -> np.ndarray:
    """(H, W) bool: projector pixels within 1 px of the content's edge (where it steps to 0)."""
    sx, sy, _ = content_coords(hm, size)
    w, h = content_size
    inside = (sx >= 0.5) & (sx <= w - 1.5) & (sy >= 0.5) & (sy <= h - 1.5)
    outside = (sx <= -1.5) | (sx >= w + 0.5) | (sy <= -1.5) | (sy >= h + 0.5)
    return ~inside & ~outside


def levels(v: np.ndarray, *, lut: np.ndarray | None = None, gain: float = 1.0) -> np.ndarray:
    """The node's luminance pipeline on linear values (:func:`protos.spaces.lut_lookup`), as int."""
    return lut_lookup(lut, v, gain=gain).astype(int)


def smooth_content(dtype=np.uint8, channels=3, *, lo=0.0, hi=1.0, shape=(CH, CW)) -> np.ndarray:
    """Blurred noise stretched to [lo, hi] of the dtype's range: gradients of a few levels per pixel."""
    noise = RNG.random((*shape, channels)).astype(np.float32)
    blurred = cv2.GaussianBlur(noise, (0, 0), 3.0).reshape(*shape, channels)
    blurred = (blurred - blurred.min()) / np.ptp(blurred)
    v = lo + (hi - lo) * blurred
    if np.issubdtype(dtype, np.integer):
        v = np.round(v * np.iinfo(dtype).max)
    out = v.astype(dtype)
    return out[:, :, 0] if channels == 1 else out


def sharp_content(dtype=np.uint8, channels=3, shape=(CH, CW)) -> np.ndarray:
    out = RNG.integers(0, np.iinfo(dtype).max + 1, size=(*shape, channels), dtype=dtype)
    return out[:, :, 0] if channels == 1 else out


def assert_levels_close(got: np.ndarray, want: np.ndarray, *, mask=None, max_diff: int, mean_diff: float):
    diff = np.abs(got.astype(int) - want.astype(int))
    if mask is not None:
        diff = diff[mask]
    assert diff.max() <= max_diff, f"max |diff| {diff.max()} levels > {max_diff} ({(diff > max_diff).sum()} values)"
    assert diff.mean() <= mean_diff, f"mean |diff| {diff.mean():.4f} levels > {mean_diff}"


def assert_matches_spaces(got: np.ndarray, want: np.ndarray, *, mask=None, share: float = 0.001):
    """The shader computes :func:`protos.spaces.warp_content`: equal, but for 1 level on a few values
    (rounding ties, float32 against float64): at most ``share`` of them."""
    diff = np.abs(got.astype(int) - want.astype(int))
    if mask is not None:
        diff = diff[mask]
    assert diff.max() <= 1, f"max |diff| {diff.max()} levels > 1 ({(diff > 1).sum()} values)"
    assert (diff > 0).mean() <= share, f"{(diff > 0).sum()} of {diff.size} values differ (> {share:.2%})"


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def shared_renderer():
    r = Renderer.standalone(PW, PH)
    # tests/node/test_render_gl31.py runs this module again on an emulated OpenGL 3.1 (a Pi's V3D)
    expected = os.environ.get("SHADOWLESS_TEST_GL_VERSION")
    if expected:
        assert r.ctx.version_code == int(expected), r.gl_profile
    yield r
    r.release()


@pytest.fixture
def renderer(shared_renderer):
    r = shared_renderer
    r.resize(PW, PH)
    r.clear_pose()
    r.set_lut(None)
    r.set_gain(1.0)
    for cid in r.content_ids:
        r.forget(cid)
    return r


def render_image(r: Renderer, content: np.ndarray, **kwargs) -> np.ndarray:
    cid = f"c{RNG.integers(1 << 62)}"
    r.upload(cid, content)
    r.render(cid, **kwargs)
    return r.read().copy()


# ----------------------------------------------------------------------------- homography


CONTENT_KINDS = {
    "uint8-rgb": lambda: smooth_content(np.uint8),
    "uint16-rgb": lambda: smooth_content(np.uint16),
    "uint8-grey-2d": lambda: smooth_content(np.uint8, 1),
    "uint16-grey-1ch": lambda: smooth_content(np.uint16, 1)[:, :, None],
    "uint8-grey-alpha": lambda: smooth_content(np.uint8, 2),
    "uint8-rgba": lambda: smooth_content(np.uint8, 4),
    "float32-rgb": lambda: smooth_content(np.float32),
    "float16-rgb": lambda: smooth_content(np.float16),
}


@pytest.mark.parametrize("kind", sorted(CONTENT_KINDS))
def test_homography_warp_matches_cv2_warp_perspective(renderer, kind):
    content = CONTENT_KINDS[kind]()
    renderer.set_homography(H_TILTED, (CW, CH))
    got = render_image(renderer, content, apply_lut=False)
    band = edge_band(H_TILTED)
    assert (~band).sum() > 0.9 * band.size and (got.max(axis=2) > 0).mean() > 0.3  # a real, partly covered warp
    assert_levels_close(got, levels(cv2_warp(content, H_TILTED)), mask=~band, max_diff=1, mean_diff=0.1)
    assert_matches_spaces(got, spaces_warp(content, H_TILTED, apply_lut=False))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_homography_warp_is_exact_on_sharp_content(renderer, dtype):
    content = sharp_content(dtype)
    renderer.set_homography(H_TILTED, (CW, CH))
    got = render_image(renderer, content, apply_lut=False)
    assert_matches_spaces(got, spaces_warp(content, H_TILTED, apply_lut=False))


def test_magnifying_rotating_homography(renderer):
    # content enlarged 2.3x, rotated 20 degrees, shifted: every output pixel interpolates
    a = np.deg2rad(20)
    hm = np.array([[2.3 * np.cos(a), -2.3 * np.sin(a), 40.0], [2.3 * np.sin(a), 2.3 * np.cos(a), -30.0], [0, 0, 1]])
    content = sharp_content(np.uint8, shape=(40, 50))
    cw, ch = 50, 40
    renderer.set_homography(hm, (cw, ch))
    got = render_image(renderer, content, apply_lut=False)
    ref = cv2.warpPerspective(content.astype(np.float32) / 255, hm, (PW, PH), flags=cv2.INTER_LINEAR)
    assert_matches_spaces(got, spaces_warp(content, hm, apply_lut=False))
    # sharp content: cv2's 1/32-px coordinate grid costs up to a few levels, but only a few
    assert_levels_close(got, levels(ref), max_diff=6, mean_diff=0.3)


def test_horizon_inside_the_image_is_black_beyond_it(renderer):
    # a grazing projector: the table's horizon crosses its image
    p = look_at((0.0, -900.0, 120.0), (0.0, 0.0, 60.0), f=120.0)
    hm = plane_homography(p, 0.0, content_to_plane(-300, -200, 300, 200))
    _, _, front = content_coords(hm)
    assert 0.1 < front.mean() < 0.9, "the horizon must cross the projector image for this test"
    content = smooth_content(np.uint8, lo=0.3, hi=1.0)
    renderer.set_homography(hm, (CW, CH))
    got = render_image(renderer, content, apply_lut=False)
    assert_matches_spaces(got, spaces_warp(content, hm, apply_lut=False))
    assert got[~front].max() == 0
    # a homography is defined up to scale, sign included
    renderer.set_homography(-2.5 * hm, (CW, CH))
    again = render_image(renderer, content, apply_lut=False)
    np.testing.assert_array_equal(again, got)


def test_lut_and_gain_match_numpy(renderer):
    content = smooth_content(np.uint16, lo=0.25, hi=0.95)
    grid = np.linspace(0, 1, 256)
    lut = np.stack([0.004 + 0.996 * grid ** (1 / g) for g in (2.0, 2.2, 2.4)]).astype(np.float32)
    renderer.set_homography(H_TILTED, (CW, CH))
    renderer.set_lut(lut)
    renderer.set_gain(0.8)
    got = render_image(renderer, content)
    band = edge_band(H_TILTED)
    assert_levels_close(got, levels(cv2_warp(content, H_TILTED), lut=lut, gain=0.8), mask=~band, max_diff=2,
                        mean_diff=0.1)
    assert_matches_spaces(got, spaces_warp(content, H_TILTED, lut=lut, gain=0.8))
    # outside the content the value is 0, so the pixel shows LUT(0) per channel
    sx, sy, _ = content_coords(H_TILTED)
    far_outside = (sx < -2) | (sx > CW + 1) | (sy < -2) | (sy > CH + 1)
    assert far_outside.any()
    np.testing.assert_array_equal(got[far_outside], np.broadcast_to(levels(np.zeros(3), lut=lut), (far_outside.sum(), 3)))


def test_sixteen_bit_content_keeps_its_precision_through_gain(renderer):
    # values in the lowest 5 % of the range, amplified 18x: an 8-bit path would be off by up to ~9 levels
    content = smooth_content(np.uint16, lo=0.0, hi=0.05)
    renderer.set_homography(H_TILTED, (CW, CH))
    renderer.set_gain(18.0)
    got = render_image(renderer, content)
    want = spaces_warp(content, H_TILTED, gain=18.0)
    assert want.max() > 200
    assert_matches_spaces(got, want)
    eight_bit = spaces_warp((content // 257).astype(np.uint8), H_TILTED, gain=18.0)
    assert np.abs(eight_bit - want).max() >= 4  # the test would notice an 8-bit texture


# ----------------------------------------------------------------------------- LUT details (projector space: exact)


def ramp(width=PW, height=PH) -> np.ndarray:
    """Every uint8 level, several times, in a projector-size RGB image (channels shifted)."""
    v = (np.arange(width * height) % 256).reshape(height, width)
    return np.stack([v, (v + 85) % 256, (v + 170) % 256], axis=-1).astype(np.uint8)


@pytest.mark.parametrize("samples", [2, 5, 256, 4096])
@pytest.mark.parametrize("rows", [1, 3])
def test_lut_interpolates_between_its_samples(renderer, samples, rows):
    # random, so not monotonic and, with many samples, very steep: float32 rounding of
    # v * (E - 1) then tips a few percent of the values over a rounding tie
    lut = RNG.random((rows, samples)).astype(np.float32)
    renderer.set_lut(lut)
    image = ramp()
    got = render_image(renderer, image, space="projector")
    want = projector_space(image, lut=lut)
    assert_levels_close(got, want, max_diff=1, mean_diff=0.03)


def test_identity_lut_and_no_lut_are_exact_in_projector_space(renderer):
    image = ramp()
    np.testing.assert_array_equal(render_image(renderer, image, space="projector"), image)
    renderer.set_lut(np.array([[0.0, 1.0]], np.float32))
    np.testing.assert_array_equal(render_image(renderer, image, space="projector"), image)
    # apply_lut=False skips gain and LUT
    renderer.set_lut(np.array([[1.0, 0.0]], np.float32))
    renderer.set_gain(0.3)
    np.testing.assert_array_equal(render_image(renderer, image, space="projector", apply_lut=False), image)


def test_gain_clamps_before_the_lut(renderer):
    image = np.full((PH, PW, 3), 200, np.uint8)
    lut = np.array([[0.0, 0.5, 0.6]], np.float32)
    renderer.set_lut(lut)
    renderer.set_gain(3.0)  # 3 * 200/255 > 1 -> clamp to 1 -> LUT(1) = 0.6
    got = render_image(renderer, image, space="projector")
    assert (got == 153).all()
    renderer.set_gain(0.0)
    assert (render_image(renderer, image, space="projector") == 0).all()


def test_float_content_outside_unit_range_is_clamped(renderer):
    image = np.linspace(-0.5, 1.5, PW * PH * 3, dtype=np.float32).reshape(PH, PW, 3)
    for dtype in (np.float32, np.float16):
        got = render_image(renderer, image.astype(dtype), space="projector", apply_lut=False)
        assert_matches_spaces(got, projector_space(image.astype(dtype), apply_lut=False))
        assert got.min() == 0 and got.max() == 255


# ----------------------------------------------------------------------------- projector space, black, buffers


def test_projector_space_is_pixel_exact_at_odd_sizes(renderer):
    renderer.set_homography(H_TILTED, (CW, CH))  # ignored in projector space
    for w, h in [(161, 97), (33, 7), (1, 1)]:
        renderer.resize(w, h)
        image = sharp_content(np.uint8, shape=(h, w))
        np.testing.assert_array_equal(render_image(renderer, image, space="projector", apply_lut=False), image)
        grey16 = sharp_content(np.uint16, 1, shape=(h, w))
        got = render_image(renderer, grey16, space="projector", apply_lut=False)
        np.testing.assert_array_equal(got, projector_space(grey16, apply_lut=False))


def test_projector_space_size_mismatch_names_both_sizes(renderer):
    renderer.upload("small", np.zeros((50, 100, 3), np.uint8))
    with pytest.raises(ValueError, match=r"100x50.*160x120"):
        renderer.render("small", space="projector")


def test_black_without_content_or_pose(renderer):
    image = np.full((PH, PW, 3), 255, np.uint8)
    renderer.upload("white", image)
    renderer.set_lut(np.array([[0.5, 1.0]], np.float32))  # LUT(0) = 0.5: black is black, not LUT(0)
    for cid in (None, ""):
        renderer.render("white", space="projector")
        renderer.render(cid)
        assert renderer.read().max() == 0
    renderer.render("white")  # no pose yet
    assert renderer.read().max() == 0
    renderer.set_homography(np.eye(3), (PW, PH))
    renderer.render("white")
    assert renderer.read().min() == 255
    renderer.clear_pose()
    renderer.render("white")
    assert renderer.read().max() == 0


def test_homography_pose_rejects_content_of_another_size(renderer):
    renderer.set_homography(np.eye(3), (CW, CH))
    renderer.upload("other", np.zeros((CH + 1, CW, 3), np.uint8))
    with pytest.raises(ValueError, match=r"120x81.*120x80"):
        renderer.render("other")


def test_read_has_row_zero_at_the_top_and_reuses_its_buffer(renderer):
    image = np.zeros((PH, PW, 3), np.uint8)
    image[0, :, 0] = 255  # top row red
    image[:, 0, 2] = 255  # left column blue
    first = render_image(renderer, image, space="projector")
    np.testing.assert_array_equal(first, image)
    a = renderer.read()
    b = renderer.read()
    assert a is b and a.flags.c_contiguous and a.shape == (PH, PW, 3) and a.dtype == np.uint8
    renderer.render(None)
    assert renderer.read() is a and a.max() == 0  # overwritten in place: callers copy what they keep


def test_rows_read_alone_and_a_preview_read_by_bands_are_the_full_read_back(renderer):
    """read() reads in strips and a preview (node.preview) by bands of rows, so that neither holds a
    second full-size picture: every row and the preview must be what one full read-back gives. 331 x
    250: several strips and bands, the last of each cut short, and preview blocks of 3 x 3 pixels."""
    from node.preview import downscale, downscale_rendered

    w, h = 331, 250
    renderer.resize(w, h)
    image = RNG.integers(0, 256, (h, w, 3), dtype=np.uint8)
    full = render_image(renderer, image, space="projector").copy()
    np.testing.assert_array_equal(full, image)
    for top, rows in ((0, 1), (h - 1, 1), (0, h), (37, 100), (200, 50)):
        np.testing.assert_array_equal(renderer.read_rows(top, rows), image[top:top + rows], err_msg=f"{top}+{rows}")
    small = downscale_rendered(renderer)
    assert small.shape == (84, 111, 3)
    np.testing.assert_array_equal(small, downscale(image))
    for top, rows in ((-1, 2), (0, 0), (h - 1, 2)):
        with pytest.raises(ValueError, match="within the output"):
            renderer.read_rows(top, rows)


def test_upload_of_a_known_id_is_not_repeated(renderer):
    one = np.full((PH, PW, 3), 10, np.uint8)
    two = np.full((PH, PW, 3), 20, np.uint8)
    renderer.upload("x", one)
    renderer.upload("x", two)  # same id: ignored, content ids are immutable
    renderer.render("x", space="projector")
    assert (renderer.read() == 10).all()
    with pytest.raises(ValueError, match="immutable"):
        renderer.upload("x", np.zeros((PH, PW), np.uint8))
    assert renderer.has("x") and renderer.content_ids == ("x",)
    renderer.forget("x")
    renderer.forget("x")  # unknown: no error
    assert not renderer.has("x")
    with pytest.raises(KeyError, match="not uploaded"):
        renderer.render("x", space="projector")
    renderer.upload("x", two)
    renderer.render("x", space="projector")
    assert (renderer.read() == 20).all()


def test_a_forgotten_texture_is_reused_for_the_next_content_of_its_size_and_type(renderer):
    """A video's frames, one uploaded as the previous is forgotten, write into one texture:
    each renders its own pixels (bit-exact in projector space), grey and 16-bit alike."""
    frames = [sharp_content(np.uint8, shape=(PH, PW)) ^ np.uint8(k * 37) for k in range(3)]
    seen = []
    for k, img in enumerate(frames):
        renderer.upload(f"f{k}", img)
        seen.append(renderer._contents[f"f{k}"].texture)
        np.testing.assert_array_equal(render_image_id(renderer, f"f{k}"), img)
        if k:
            renderer.forget(f"f{k - 1}")
    assert seen[2] is seen[0]                      # f0's texture came back for f2
    grey16 = sharp_content(np.uint16, 1, shape=(PH, PW))
    renderer.upload("g", grey16)                   # another type: a texture of its own
    got = render_image_id(renderer, "g")
    np.testing.assert_array_equal(got, projector_space(grey16, apply_lut=False))
    renderer.forget("g")
    renderer.upload("g2", grey16[::-1].copy())
    np.testing.assert_array_equal(render_image_id(renderer, "g2"), projector_space(grey16[::-1], apply_lut=False))


def render_image_id(renderer, cid: str) -> np.ndarray:
    renderer.render(cid, space="projector", apply_lut=False)
    return renderer.read()


def test_resize_keeps_the_pose(renderer):
    content = smooth_content(np.uint8)
    renderer.set_homography(H_TILTED, (CW, CH))
    renderer.upload("c", content)
    renderer.resize(200, 150)
    assert (renderer.width, renderer.height) == (200, 150)
    assert renderer.framebuffer.size == (200, 150)
    renderer.render("c", apply_lut=False)
    got = renderer.read()
    assert got.shape == (150, 200, 3)
    assert_matches_spaces(got, spaces_warp(content, H_TILTED, (200, 150), apply_lut=False))


# ----------------------------------------------------------------------------- mesh (projection pose)


def test_flat_mesh_renders_the_homography_of_its_plane(renderer):
    content = smooth_content(np.uint8)
    mesh = quad_mesh(-300, -200, 300, 200, 0.0)
    renderer.set_projection(P_TILTED, mesh, near=100.0, far=3000.0)
    got = render_image(renderer, content, apply_lut=False)
    sx, sy, _ = content_coords(H_TILTED)
    band = edge_band(H_TILTED)
    outside = ((sx < -0.5) | (sx > CW - 0.5) | (sy < -0.5) | (sy > CH - 0.5)) & ~band
    assert outside.any() and (~outside & ~band).mean() > 0.3
    assert got[outside].max() == 0  # no mesh there
    inside = ~outside & ~band
    assert_matches_spaces(got, spaces_warp(content, H_TILTED, apply_lut=False), mask=inside)
    assert_levels_close(got, levels(cv2_warp(content, H_TILTED)), mask=inside, max_diff=1, mean_diff=0.1)
    # the same through the homography pose, in the same renderer
    renderer.set_homography(H_TILTED, (CW, CH))
    warped = render_image(renderer, content, apply_lut=False)
    assert_levels_close(got, warped, mask=inside, max_diff=1, mean_diff=0.02)


def test_projection_scale_and_sign_do_not_matter(renderer):
    content = smooth_content(np.uint8)
    mesh = quad_mesh(-300, -200, 300, 200, 0.0, n=(1, 1))
    renderer.set_projection(P_TILTED, mesh, near=100.0, far=3000.0)
    ref = render_image(renderer, content, apply_lut=False)
    renderer.set_projection(-0.01 * P_TILTED, mesh, near=100.0, far=3000.0)
    np.testing.assert_array_equal(render_image(renderer, content, apply_lut=False), ref)


def test_two_layer_mesh_shows_the_nearer_layer(renderer):
    content = sharp_content(np.uint8)
    z_top = 150.0
    lower = quad_mesh(-300, -200, 300, 200, 0.0)
    upper_uv = (0.1, 0.5, 0.45, 0.95)
    upper = quad_mesh(-120, -90, 90, 80, z_top, *upper_uv, n=(2, 2))
    # the upper layer comes FIRST in the face list: only the depth test can keep it in front
    n_up = len(upper.vertices)
    mesh = Mesh(
        np.concatenate([upper.vertices, lower.vertices]),
        np.concatenate([upper.uvs, lower.uvs]),
        np.concatenate([upper.faces, lower.faces + n_up]),
    )
    renderer.set_projection(P_TILTED, mesh, near=100.0, far=3000.0)
    got = render_image(renderer, content, apply_lut=False)

    h_low = H_TILTED
    h_up = plane_homography(P_TILTED, z_top, content_to_plane(-120, -90, 90, 80, *upper_uv))
    sx, sy, _ = content_coords(h_up)
    u0, v0, u1, v1 = upper_uv
    lo_x, hi_x, lo_y, hi_y = u0 * CW - 0.5, u1 * CW - 0.5, v0 * CH - 0.5, v1 * CH - 0.5
    on_top = (sx > lo_x + 1) & (sx < hi_x - 1) & (sy > lo_y + 1) & (sy < hi_y - 1)
    near_edge = (sx > lo_x - 1.5) & (sx < hi_x + 1.5) & (sy > lo_y - 1.5) & (sy < hi_y + 1.5) & ~on_top
    assert on_top.mean() > 0.1
    top = spaces_warp(content, h_up, apply_lut=False)
    bottom = spaces_warp(content, h_low, apply_lut=False)
    assert np.abs(top - bottom)[on_top].mean() > 40  # the layers really differ there
    low_sx, low_sy, _ = content_coords(h_low)
    on_bottom = ~on_top & ~near_edge & ~edge_band(h_low) & (low_sx > 0) & (low_sx < CW - 1)
    on_bottom &= (low_sy > 0) & (low_sy < CH - 1)
    assert on_bottom.mean() > 0.1
    assert_levels_close(got, top, mask=on_top, max_diff=1, mean_diff=0.05)
    assert_levels_close(got, bottom, mask=on_bottom, max_diff=1, mean_diff=0.05)


def test_mesh_outside_near_far_is_clipped(renderer):
    content = np.full((CH, CW, 3), 255, np.uint8)
    mesh = quad_mesh(-300, -200, 300, 200, 0.0, n=(1, 1))
    renderer.upload("white", content)
    for near, far, visible in [(100.0, 3000.0, True), (100.0, 300.0, False), (2000.0, 3000.0, False)]:
        renderer.set_projection(P_TILTED, mesh, near=near, far=far)
        renderer.render("white", apply_lut=False)
        assert (renderer.read().max() == 255) == visible, (near, far)


def test_mesh_pose_accepts_any_content_size_and_grey(renderer):
    mesh = quad_mesh(-300, -200, 300, 200, 0.0)
    renderer.set_projection(P_TILTED, mesh, near=100.0, far=3000.0)
    small = smooth_content(np.uint16, 1, shape=(CH // 2, CW // 2))
    got = render_image(renderer, small, apply_lut=False)
    h_small = plane_homography(P_TILTED, 0.0, content_to_plane(-300, -200, 300, 200, size=(CW // 2, CH // 2)))
    sx, sy, _ = content_coords(h_small)
    inside = (sx > 0.5) & (sx < CW // 2 - 1.5) & (sy > 0.5) & (sy < CH // 2 - 1.5)
    assert inside.mean() > 0.2
    assert_matches_spaces(got, spaces_warp(small, h_small, apply_lut=False), mask=inside)


# ----------------------------------------------------------------------------- validation


def test_mesh_validates_its_arrays():
    v = np.zeros((4, 3), np.float32)
    uv = np.zeros((4, 2), np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = Mesh(v.astype(np.float64), uv, f.astype(np.int64))
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.uint32
    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        Mesh(np.zeros((4, 2)), uv, f)
    with pytest.raises(ValueError, match=r"\(V, 2\)"):
        Mesh(v, np.zeros((3, 2)), f)
    with pytest.raises(ValueError, match=r"\(F, 3\)"):
        Mesh(v, uv, np.zeros((2, 4), int))
    with pytest.raises(ValueError, match="only 4 vertices"):
        Mesh(v, uv, np.array([[0, 1, 4]]))
    with pytest.raises(ValueError, match="integer"):
        Mesh(v, uv, f.astype(float))
    with pytest.raises(ValueError, match="finite"):
        Mesh(np.full((4, 3), np.nan), uv, f)


def test_setters_reject_bad_input(renderer):
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        renderer.set_homography(np.eye(4), (CW, CH))
    with pytest.raises(ValueError, match="singular"):
        renderer.set_homography(np.zeros((3, 3)), (CW, CH))
    with pytest.raises(ValueError, match="finite"):
        renderer.set_homography(np.full((3, 3), np.nan), (CW, CH))
    with pytest.raises(ValueError, match="content_size"):
        renderer.set_homography(np.eye(3), (0, 5))
    mesh = quad_mesh(-1, -1, 1, 1, 0)
    with pytest.raises(ValueError, match=r"\(3, 4\)"):
        renderer.set_projection(np.eye(3), mesh, near=1, far=2)
    with pytest.raises(ValueError, match="near < far"):
        renderer.set_projection(P_TILTED, mesh, near=10, far=5)
    with pytest.raises(ValueError, match="Mesh"):
        renderer.set_projection(P_TILTED, (mesh.vertices, mesh.uvs, mesh.faces), near=1, far=2)
    with pytest.raises(ValueError, match=r"\(C, E\)"):
        renderer.set_lut(np.zeros((2, 10), np.float32))
    with pytest.raises(ValueError, match=r"\(C, E\)"):
        renderer.set_lut(np.zeros((3, 1), np.float32))
    with pytest.raises(ValueError, match="finite"):
        renderer.set_lut(np.full((1, 4), np.inf, np.float32))
    for gain in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="gain"):
            renderer.set_gain(gain)
    with pytest.raises(ValueError, match="dtype"):
        renderer.upload("a", np.zeros((4, 4), np.float64))
    with pytest.raises(ValueError, match="C in 1..4"):
        renderer.upload("a", np.zeros((4, 4, 5), np.uint8))
    with pytest.raises(ValueError, match="content_id"):
        renderer.upload("", np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="space"):
        renderer.render(None, space="camera")
    for size in [(0, 10), (10.5, 10), (True, 3)]:
        with pytest.raises(ValueError, match="output size"):
            renderer.resize(*size)
    assert not renderer.content_ids


def test_release_is_idempotent_and_context_manager():
    with Renderer.standalone(8, 8) as r:
        r.upload("a", np.zeros((8, 8), np.uint8))
        r.render("a", space="projector")
        assert r.read().shape == (8, 8, 3)
    r.release()


def test_unusable_gl_is_reported_with_what_to_do(monkeypatch):
    from types import SimpleNamespace

    import moderngl

    from node.render import RenderError

    old = SimpleNamespace(version_code=210, info={"GL_RENDERER": "ancient"})
    with pytest.raises(RenderError, match=r"3\.1 or newer.*2\.1 \(ancient\)"):
        Renderer(old, 8, 8)

    def no_egl(**kwargs):
        raise Exception("eglInitialize failed")

    monkeypatch.setattr(moderngl, "create_standalone_context", no_egl)
    with pytest.raises(RenderError, match="eglInitialize failed.*libegl1"):
        Renderer.standalone(8, 8)
