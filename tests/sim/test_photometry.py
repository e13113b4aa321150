"""Uneven light in the room: each cause (brightness spread, white point, hot spot, vignetting, a
dimmed or dead lamp) is visible in what the camera records and matches the room's truth; and a
room without them is the room it always was."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage

from sim.errors import LayoutError, UnknownSlotError
from sim.photometry import Photometry, Profile, spread_draw
from sim.rigs import layout_path, wall_scene
from sim.room import Room
from sim.scene import load_layout, reference_scene, write_layout

SCALE = dict(projector_scale=0.125, camera_scale=0.125)


def alone(room: Room, slot: str, value: int) -> np.ndarray:
    """The linear signal of ``slot`` alone showing a flat ``value``."""
    room.set_active([slot])
    w, h = room.projector_size(slot)
    room.set_frame(slot, np.full((h, w, 3), value, np.uint8))
    return room.render_linear()


def lit_pixels(room: Room, slot: str) -> np.ndarray:
    """(H, W) bool: camera pixels well inside ``slot``'s footprint (no edge blur)."""
    uv = room.truth.projector_coordinates(slot)
    w, h = room.projector_size(slot)
    return np.isfinite(uv[..., 0]) & (uv[..., 0] > 3) & (uv[..., 0] < w - 4) & (uv[..., 1] > 3) & (uv[..., 1] < h - 4)


def test_profile_is_its_closed_form():
    p = Profile(hotspot=0.2, hotspot_width=0.35, hotspot_center=(0.5, -0.25), vignetting=0.3)
    w, h = 320, 200
    u = np.array([-0.5 + w / 2, -0.5, 0.0, 3.0 * w / 4 - 0.5, w - 0.5])
    v = np.array([-0.5 + h / 2, -0.5, h - 0.5, 3.0 * h / 8 - 0.5, -0.5])
    x, y = 2 * (u + 0.5) / w - 1, 2 * (v + 0.5) / h - 1
    r2 = (x**2 * w**2 + y**2 * h**2) / (w**2 + h**2)
    d2 = ((x - 0.5) ** 2 * w**2 + (y + 0.25) ** 2 * h**2) / (w**2 + h**2)
    want = (1 + 0.2 * np.exp(-d2 / (2 * 0.35**2))) * (1 - 0.3 * r2)
    np.testing.assert_allclose(p.factor(u, v, (w, h)), want, rtol=1e-12)
    assert p.factor(np.array([-0.5]), np.array([-0.5]), (w, h))[0] == pytest.approx((1 - 0.3) * (1 + 0.2 * np.exp(-((1.5**2 * w**2 + 0.75**2 * h**2) / (w**2 + h**2)) / (2 * 0.35**2))))
    assert p.factor(u[3:4], v[3:4], (w, h))[0] == pytest.approx(1.2 * (1 - 0.3 * r2[3]))       # the hot spot's centre
    # resolution-free: the same image point at another resolution has the same factor
    assert p.factor(np.array([(u[3] + 0.5) * 4 - 0.5]), np.array([(v[3] + 0.5) * 4 - 0.5]), (4 * w, 4 * h))[0] == pytest.approx(p.factor(u[3:4], v[3:4], (w, h))[0])
    assert Profile().identity and not p.identity
    for bad in (dict(hotspot=-0.1), dict(vignetting=1.0), dict(hotspot_width=0.0), dict(hotspot_center=(2, 0)), dict(hotspot=float("nan"))):
        with pytest.raises(ValueError):
            Profile(**bad)
    with pytest.raises(ValueError, match="brightness_spread must be a fraction"):
        Photometry(brightness_spread=1.5)


def test_no_photometry_is_the_same_room():
    plain = reference_scene(**SCALE, seed=4)
    none = reference_scene(**SCALE, seed=4, photometry=Photometry())
    for a, b in zip(plain.projectors, none.projectors):
        assert a is b or (a.peak == b.peak and a.white is None and b.white is None and a.profile is None and b.profile is None)
    assert [c.gain for c in plain.cameras] == [c.gain for c in none.cameras]
    spread = reference_scene(**SCALE, seed=4, photometry=Photometry(brightness_spread=0.15, white_spread=0.15))
    # the geometry and responses are those of the plain room: the spread has a generator of its own
    for a, b in zip(plain.projectors, spread.projectors):
        np.testing.assert_array_equal(a.pinhole.P, b.pinhole.P)
        np.testing.assert_array_equal(a.response.gamma, b.response.gamma)
        factor, gains = spread_draw(4, a.slot, Photometry(brightness_spread=0.15, white_spread=0.15))
        assert b.peak == pytest.approx(a.peak * factor) and 0.85 <= factor <= 1.15
        np.testing.assert_allclose(b.white, gains)
        assert np.all((gains >= 0.85) & (gains <= 1.15))
    peaks = np.array([p.peak / q.peak for p, q in zip(spread.projectors, plain.projectors)])
    assert peaks.max() - peaks.min() > 0.1           # the units really differ
    again = reference_scene(**SCALE, seed=4, photometry=Photometry(brightness_spread=0.15, white_spread=0.15))
    assert [p.peak for p in again.projectors] == [p.peak for p in spread.projectors]


def test_brightness_and_white_spread_show_in_captures_as_the_truth_says():
    even = Room(wall_scene(**SCALE, seed=2), noise=False)
    uneven = Room(wall_scene(**SCALE, seed=2, photometry=Photometry(brightness_spread=0.15, white_spread=0.15)), noise=False)
    for slot in even.slots:
        base, got = alone(even, slot, 255), alone(uneven, slot, 255)
        m = lit_pixels(even, slot)
        t0, t1 = even.truth.projector(slot), uneven.truth.projector(slot)
        np.testing.assert_array_equal(t0.white, np.ones(3))
        want = (t1.peak / t0.peak) * t1.white
        ratio = got[m] / base[m]                                  # (n, 3)
        np.testing.assert_allclose(ratio, np.broadcast_to(want, ratio.shape), rtol=2e-5)
        assert abs(want[0] - 1) > 1e-3 or abs(want[1] - 1) > 1e-3


def test_hot_spot_and_vignetting_follow_the_projector_coordinate():
    light = Photometry(hotspot=0.3, hotspot_width=0.3, vignetting=0.4)
    even = Room(wall_scene(**SCALE), noise=False)
    uneven = Room(wall_scene(**SCALE, photometry=light), noise=False)
    slot = "r0c1"
    base, got = alone(even, slot, 200), alone(uneven, slot, 200)
    truth = uneven.truth.projector(slot)
    assert (truth.hotspot, truth.hotspot_width, truth.vignetting, truth.hotspot_center) == (0.3, 0.3, 0.4, (0.0, 0.0))
    uv = uneven.truth.projector_coordinates(slot)
    m = lit_pixels(uneven, slot)
    want = truth.profile.factor(uv[..., 0][m], uv[..., 1][m], truth.size)
    ratio = got[m] / base[m]
    np.testing.assert_allclose(ratio, np.repeat(want[:, None], 3, axis=1), rtol=2e-5)
    assert want.max() > 1.25 and want.min() < 0.75               # both effects are there, and large
    # the centre of the image is the brightest part of the footprint, its corners the darkest
    assert got[m][np.argmax(want)].mean() > 1.2 * base[m][np.argmax(want)].mean()


def test_a_projector_of_a_layout_keeps_its_own_values(tmp_path):
    text = layout_path("wall-3x1").read_text()
    text = text.replace('slot = "r0c1"', 'slot = "r0c1"\npeak = 0.5\nwhite = [1.0, 0.5, 0.25]\nhotspot = 0.6')
    text += "\n[photometry]\nbrightness_spread = 0.2\nwhite_spread = 0.2\nvignetting = 0.25\n"
    path = tmp_path / "wall.toml"
    path.write_text(text)
    scene = load_layout(path, **SCALE, seed=3)
    mid = scene.projector("r0c1")
    assert mid.peak == 0.5 and mid.white.tolist() == [1.0, 0.5, 0.25]
    assert (mid.profile.hotspot, mid.profile.vignetting) == (0.6, 0.25)       # its own hot spot, the rig's vignetting
    left = scene.projector("r0c0")
    factor, gains = spread_draw(3, "r0c0", Photometry(brightness_spread=0.2, white_spread=0.2))
    assert left.white.tolist() == gains.tolist() and (left.profile.hotspot, left.profile.vignetting) == (0.0, 0.25)
    # the command line's values replace the file's, key by key
    flagged = load_layout(path, **SCALE, seed=3, photometry={"vignetting": 0.1, "hotspot": 0.05})
    assert (flagged.projector("r0c0").profile.vignetting, flagged.projector("r0c0").profile.hotspot) == (0.1, 0.05)
    assert flagged.projector("r0c1").profile.hotspot == 0.6
    # what write_layout writes reads back as the same units
    out = tmp_path / "out.toml"
    write_layout(scene, out)
    back = load_layout(out, **SCALE, seed=99)
    for a, b in zip(scene.projectors, back.projectors):
        assert a.peak == b.peak and a.white.tolist() == b.white.tolist() and a.profile == b.profile
    for bad, said in (("[photometry]\nbrightness = 0.1\n", r"unknown keys \['brightness'\]"),
                      ("[photometry]\nvignetting = 1.5\n", "vignetting must be a number"),
                      ('[photometry]\nhotspot = "big"\n', "hotspot must be a number")):
        p = tmp_path / "bad.toml"
        p.write_text(layout_path("wall-3x1").read_text() + "\n" + bad)
        with pytest.raises(LayoutError, match=said) as err:
            load_layout(p)
        assert str(p) in str(err.value) and "\n" not in str(err.value)
    p = tmp_path / "bad.toml"
    p.write_text(layout_path("wall-3x1").read_text().replace('slot = "r0c2"', 'slot = "r0c2"\nwhite = [1, 2]'))
    with pytest.raises(LayoutError, match=r"r0c2.*'white' must be one number or three"):
        load_layout(p)


def test_a_lamp_dims_and_dies_while_the_frame_stays():
    room = Room(wall_scene(**SCALE, photometry=Photometry(white_spread=0.1)), noise=False)
    slot = "r0c2"
    m = lit_pixels(room, slot)
    full = alone(room, slot, 180)
    black = alone(room, slot, 0)
    room.set_frame(slot, np.full((*room.projector_size(slot)[::-1], 3), 180, np.uint8))
    assert room.set_lamp(slot, 0.5).tolist() == [0.5, 0.5, 0.5]
    np.testing.assert_allclose(room.render_linear()[m], 0.5 * full[m], rtol=2e-5)
    room.set_lamp(slot, [1.0, 0.25, 0.0])
    np.testing.assert_allclose(room.render_linear()[m], full[m] * [1.0, 0.25, 0.0], rtol=2e-5, atol=1e-9)
    assert room.truth.projector(slot).lamp.tolist() == [1.0, 0.25, 0.0]
    room.set_lamp(slot, 0)                                        # dead: not even its black level
    assert not room.render_linear().any() and black[m].min() > 0
    assert room.frame(slot) is not None                           # it still shows its frame
    for bad in (-0.1, 1.5, float("nan"), [0.5, 0.5], "dim"):
        with pytest.raises(ValueError, match="lamp gain"):
            room.set_lamp(slot, bad)
    with pytest.raises(UnknownSlotError):
        room.set_lamp("zz", 0.5)
    assert room.lamp(slot).tolist() == [0.0, 0.0, 0.0]            # refusals changed nothing
    room.set_lamp(slot, 1)
    np.testing.assert_array_equal(room.render_linear(), full)


def test_contribution_is_a_real_render_of_the_projector_alone():
    light = Photometry(brightness_spread=0.15, white_spread=0.15, hotspot=0.2, vignetting=0.3)
    room = Room(wall_scene(**SCALE, seed=5, photometry=light), noise=False)
    room.set_lamp("r0c0", [0.9, 0.6, 0.8])
    for slot in room.slots:
        want = room.truth.contribution(slot)
        assert want.shape == (*room.camera_size()[::-1], 3) and want.dtype == np.float32
        got = alone(room, slot, 255) - alone(room, slot, 0)
        np.testing.assert_allclose(want, got, atol=2e-6)
        assert want.max() > 0.2
        inside = np.isfinite(room.truth.projector_coordinates(slot)[..., 0])
        outside = ~scipy.ndimage.binary_dilation(inside, iterations=3)    # beyond the blur of its edge
        assert inside.any() and not want[outside].any()
    # with every projector back, the sum of the contributions is the flat white above the black
    room.set_active(room.slots)
    for s in room.slots:
        room.set_frame(s, np.full((*room.projector_size(s)[::-1], 3), 255, np.uint8))
    white = room.render_linear()
    for s in room.slots:
        room.set_frame(s, np.zeros((*room.projector_size(s)[::-1], 3), np.uint8))
    np.testing.assert_allclose(sum(room.truth.contribution(s) for s in room.slots), white - room.render_linear(), atol=5e-6)


def test_transport_with_a_white_point_is_the_capture():
    room = Room(wall_scene(**SCALE, seed=1, photometry=Photometry(white_spread=0.2, hotspot=0.2)), noise=False)
    room.set_lamp("r0c1", 0.7)
    rng = np.random.default_rng(3)
    total = np.zeros((*room.camera_size()[::-1], 3), np.float64)
    for slot in room.slots:
        w, h = room.projector_size(slot)
        frame = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        room.set_frame(slot, frame)
        spec = room.projector(slot)
        lum = spec.response.luminance(frame / 255.0) * (spec.white_gains * room.lamp(slot))
        T = room.truth.transport(slot)
        for c in range(3):
            total[..., c] += (T @ lum[..., c].ravel()).reshape(total.shape[:2])
    np.testing.assert_allclose(room.render_linear(), total, atol=2e-5)


def test_the_camera_level_holds_with_uneven_light():
    """The reference rig's camera is set so the powered projectors at full white reach 0.8 on its
    axis; with spread units and hot spots it still is (or a hot spot would clip)."""
    from sim.rigs import BENCH_LIGHT, scene

    for light in (None, BENCH_LIGHT):
        room = Room(scene("table", photometry=light, **SCALE), noise=False)
        for s in room.slots:
            room.set_frame(s, np.full((*room.projector_size(s)[::-1], 3), 255, np.uint8))
        img = room.render_linear()
        K = room.scene.cameras[0].pinhole.K
        axis = img[int(round(K[1, 2])), int(round(K[0, 2]))]
        np.testing.assert_allclose(axis.mean(), 0.8, atol=0.003)
        assert img.max() < 0.85
