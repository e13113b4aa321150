"""The Room's captures against closed forms: homographies, exposure, light conservation, linearity."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from sim.errors import FrameError, UnknownSlotError
from sim.hand import Hand, HandPath
from sim.occluders import Box
from sim.room import Room
from sim.scene import SUBSETS, reference_scene


def white(room: Room, slot: str, value: int = 255) -> np.ndarray:
    w, h = room.projector_size(slot)
    return np.full((h, w, 3), value, np.uint8)


@pytest.fixture(scope="module")
def base_room() -> Room:
    room = Room(reference_scene(), seed=3)
    room.prepare()
    return room


@pytest.fixture
def room(base_room: Room) -> Room:
    """The module's room, reset: rig powered, all frames off, no occluders."""
    base_room.set_active(base_room.slots)
    base_room.set_occluders([])
    for s in base_room.all_slots:
        base_room.set_frame(s, None)
    return base_room


def table_pixel(room: Room, x: float, y: float) -> tuple[int, int]:
    H = room.truth.table_to_camera_homography()
    v = H @ [x, y, 1.0]
    return int(round(v[0] / v[2])), int(round(v[1] / v[2]))


def test_capture_is_a_quantised_float_image(room):
    room.set_frame("r2c2", white(room, "r2c2", 128))
    img = room.capture()
    W, H = room.camera_size()
    assert img.shape == (H, W, 3) and img.dtype == np.float32
    assert 0.0 <= img.min() and img.max() <= 1.0
    np.testing.assert_allclose(img * 4095, np.rint(img * 4095), atol=1e-3)
    assert img.max() > 0


def test_full_white_rig_reaches_the_target_level_and_p1_matches_it(room):
    for s in room.all_slots:
        room.set_frame(s, white(room, s))
    x, y = table_pixel(room, 0.0, 0.0)
    rig = room.render_linear()[y - 1 : y + 2, x - 1 : x + 2].mean()
    assert rig == pytest.approx(0.8, rel=0.01)
    room.set_active(SUBSETS["P1"])
    bright = room.render_linear()[y - 1 : y + 2, x - 1 : x + 2].mean()
    assert bright == pytest.approx(rig, rel=0.01)
    room.set_active(["r0c0"])
    assert room.render_linear()[y, x].mean() < 0.08  # one of 25 gives a fraction of it


def test_planar_projector_content_to_camera_matches_the_analytic_homography(room):
    """Lit projector pixels land where H_cam(table) . H_proj(table)^-1 puts them (closed form K [r1 r2 t])."""
    slot = "r0c4"  # an oblique corner unit
    t = room.truth.projector(slot)
    c = room.truth.camera()
    Hp = t.K @ np.column_stack([t.R[:, 0], t.R[:, 1], t.t])
    Hc = c.K @ np.column_stack([c.R[:, 0], c.R[:, 1], c.t])
    H = Hc @ np.linalg.inv(Hp)
    w, h = room.projector_size(slot)
    frame = np.zeros((h, w, 3), np.uint8)
    pts = np.array([(u, v) for u in range(40, w - 30, 40) for v in range(30, h - 20, 35)], np.float64)
    # 2x2 blocks: the block centre is at (u + 0.5, v + 0.5)
    for u, v in pts.astype(int):
        frame[v : v + 2, u : u + 2] = 255
    room.set_active([slot])
    room.set_frame(slot, frame)
    img = room.render_linear().mean(axis=2)
    room.set_frame(slot, np.zeros_like(frame))
    img = img - room.render_linear().mean(axis=2)  # remove the black level
    errors = []
    for u, v in pts + 0.5:
        p = H @ [u, v, 1.0]
        px, py = p[0] / p[2], p[1] / p[2]
        x0, y0 = int(px) - 6, int(py) - 6
        win = img[y0 : y0 + 14, x0 : x0 + 14]
        if win.shape != (14, 14) or win.sum() <= 0:
            continue
        cy, cx = ndimage.center_of_mass(win)
        errors.append(np.hypot(x0 + cx - px, y0 + cy - py))
    assert len(errors) >= 15
    assert max(errors) < 0.12, errors


def test_truth_homographies_agree_with_projection(room):
    xy = np.array([[0.0, 0.0], [500.0, -250.0], [-400.0, 200.0]])
    for slot in ("r0c0", "r3c1"):
        H = room.truth.table_to_projector_homography(slot)
        h = np.column_stack([xy, np.ones(3)]) @ H.T
        pix, _ = room.projector(slot).pinhole.project(np.column_stack([xy, np.zeros(3)]))
        np.testing.assert_allclose(h[:, :2] / h[:, 2:], pix, atol=1e-8)
    Hc = room.truth.content_to_projector_homography("r1c1", (1200, 600))
    # content pixel (599.5, 299.5) is the table centre
    v = Hc @ [599.5, 299.5, 1.0]
    pix, _ = room.projector("r1c1").pinhole.project(np.zeros(3))
    np.testing.assert_allclose(v[:2] / v[2], pix, atol=1e-8)


def _dot_total(room: Room, slot: str, block: tuple[int, int, int]) -> float:
    """Light of a lit block of projector pixels, summed over the camera, black level removed."""
    u0, v0, n = block
    w, h = room.projector_size(slot)
    frame = np.zeros((h, w, 3), np.uint8)
    frame[v0 : v0 + n, u0 : u0 + n] = 255
    room.set_active([slot])
    room.set_frame(slot, frame)
    lit = room.render_linear()[..., 1].astype(np.float64)
    room.set_frame(slot, np.zeros_like(frame))
    dark = room.render_linear()[..., 1].astype(np.float64)
    return float((lit - dark).sum())


def test_total_light_is_conserved_when_footprint_and_blur_change():
    slot = "r1c3"
    totals = {}
    for name, kwargs, scale, block in [
        ("sharp s=1", dict(aperture=0.0), 0.25, (150, 90, 8)),
        ("sharp s=4", dict(aperture=0.0), 0.25, (150, 90, 8)),
        ("blurred", dict(aperture=60.0), 0.25, (150, 90, 8)),
        ("very blurred", dict(aperture=400.0), 0.25, (150, 90, 8)),
        ("finer pixels", dict(aperture=10.0), 0.5, (300, 180, 16)),
    ]:
        upsample = 4 if name == "sharp s=4" else (1 if name == "sharp s=1" else None)
        room = Room(reference_scene(projector_scale=scale, camera_scale=0.125, seed=5, **kwargs), upsample=upsample)
        totals[name] = _dot_total(room, slot, block)
        sig = room.view(0).plans[slot].sigmas
        if name == "very blurred":
            assert max(sig) > 1.0  # the blur really changed
    ref = totals["sharp s=1"]
    for name, total in totals.items():
        assert total == pytest.approx(ref, rel=0.01), (name, totals)


def test_captures_are_linear_in_the_emitted_light(room):
    rng = np.random.default_rng(9)
    a, b = "r1c1", "r3c4"
    fa = rng.integers(0, 256, (*room.projector_size(a)[::-1], 3), dtype=np.uint8)
    fb = rng.integers(0, 256, (*room.projector_size(b)[::-1], 3), dtype=np.uint8)
    room.set_active([a, b])
    room.set_frame(a, fa)
    room.set_frame(b, None)
    only_a = room.render_linear()
    room.set_frame(a, None)
    room.set_frame(b, fb)
    only_b = room.render_linear()
    room.set_frame(a, fa)
    both = room.render_linear()
    np.testing.assert_allclose(both, only_a + only_b, atol=1e-6)
    np.testing.assert_allclose(room.render_linear(exposure=0.5), 0.5 * both, atol=1e-7)


def test_transport_reproduces_the_capture_with_occluders():
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125, surface="bust"), seed=1)
    rng = np.random.default_rng(10)
    slots = ["r0c0", "r2c2", "r4c3"]
    room.set_active(slots)
    room.set_occluders([Hand(position=(200.0, 60.0), height=180.0), Box((-300.0, -100.0, 120.0), (80.0, 60.0, 40.0))])
    W, H = room.camera_size()
    expected = np.zeros((H * W, 3))
    for s in slots:
        w, h = room.projector_size(s)
        frame = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        room.set_frame(s, frame)
        lum = room.projector(s).response.luminance(frame / 255.0)
        T = room.truth.transport(s)
        assert T.shape == (H * W, w * h) and T.dtype == np.float32
        expected += np.column_stack([T @ lum[..., c].ravel() for c in range(3)])
    got = room.render_linear().reshape(-1, 3)
    assert room.truth.occluder_mask().sum() > 100  # the camera sees the hand: those pixels count too
    np.testing.assert_allclose(got, expected, atol=1e-6 * got.max())


def test_noise_is_seeded_and_switchable():
    def make():
        r = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), seed=42)
        r.set_frame("r2c2", np.full((100, 160, 3), 200, np.uint8))
        return r

    a, b = make(), make()
    first = a.capture()
    np.testing.assert_array_equal(first, b.capture())
    assert not np.array_equal(first, a.capture())  # the next capture draws new noise
    np.testing.assert_array_equal(a.capture(noise=False), a.capture(noise=False))


def test_off_unpowered_and_black_projectors(room):
    room.set_active(["r2c2"])
    room.set_frame("r2c2", None)
    assert room.render_linear().max() == 0.0
    room.set_frame("r2c2", white(room, "r2c2", 0))
    black = room.render_linear().max()
    assert 0.0 < black < 0.01  # the black level glows
    room.set_frame("r1c1", white(room, "r1c1"))  # not powered
    assert room.render_linear().max() == pytest.approx(black)


def test_frame_and_slot_errors_say_what_is_wrong(room):
    with pytest.raises(FrameError, match=r"must be 320x200"):
        room.set_frame("r0c0", np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(FrameError, match="uint8"):
        room.set_frame("r0c0", np.zeros((200, 320, 3), np.float32))
    with pytest.raises(UnknownSlotError, match="no projector 'r7c7'.*r0c0"):
        room.set_frame("r7c7", None)
    with pytest.raises(UnknownSlotError):
        room.set_active(["r0c0", "nope"])
    room.set_frame("r0c0", np.zeros((200, 320), np.uint8))  # grey frames are accepted
    assert room.frame("r0c0").shape == (200, 320, 3)


def test_a_hand_path_follows_the_clock():
    now = [0.0]
    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125), clock=lambda: now[0])
    for s in room.slots:
        room.set_frame(s, np.full((100, 160, 3), 255, np.uint8))
    room.set_occluders(HandPath.sweep((-300.0, 0.0), (300.0, 0.0), height=200.0, period=2.0))
    first = room.truth.occluder_mask()
    now[0] = 1.0
    second = room.truth.occluder_mask()
    xs1 = np.nonzero(first)[1].mean()
    xs2 = np.nonzero(second)[1].mean()
    assert xs2 - xs1 > 100  # 600 mm to the right, ~1 px per 2 mm at this scale... at 1/8 scale ~ 0.24 px/mm
    a = room.capture(noise=False, time=0.0)
    b = room.capture(noise=False, time=1.0)
    assert np.abs(a - b).max() > 0.1


def test_drop_and_shadow_truth_follow_occluders(room):
    for s in room.slots:
        room.set_frame(s, white(room, s))
    assert room.truth.light_drop().max() == 0.0
    room.set_occluders([Box((0.0, 0.0, 300.0), (50.0, 50.0, 5.0))])
    drop = room.truth.light_drop()
    assert 0.0 < drop.max() < 0.5  # a small plate: only a few projectors at a time
    masks = [room.truth.shadow_mask(s) for s in room.slots]
    assert all(m.any() for m in masks)
    x, y = table_pixel(room, 0.0, 0.0)
    assert masks[SUBSETS["P25"].index("r2c2")][y, x]
    count = room.truth.illumination_count()
    assert count[y, x] == 25
    assert room.truth.illumination_count(occluders=True)[y, x] < 25


def test_precomputed_state_is_public_and_cached(room):
    view = room.view(0)
    assert view is room.view(0) and set(view.plans) == set(room.all_slots)
    x0, y0, x1, y1 = view.roi
    assert view.shape == (y1 - y0, x1 - x0)
    with room.lock, room.lock:  # re-entrant: truth queries nest inside it
        dyn = room.dynamic_state(view)
        assert dyn is room.dynamic_state(view) and len(dyn.hand_index) == 0
    room.set_occluders([Hand(position=(0.0, 0.0), height=200.0)])
    dyn = room.dynamic_state(view)
    assert len(dyn.hand_index) > 0 and any(len(b) for b in dyn.blocked.values())
    samples = room.occluder_samples(view, dyn, "r2c2")
    assert samples is room.occluder_samples(view, dyn, "r2c2")
    assert samples.weight.shape == (len(dyn.hand_index),) and samples.weight.max() > 0


def test_truth_reads_the_room_through_its_public_methods():
    """Truth gets what it needs from the Room's public methods (no cycle, no private state;
    tests/test_imports.py checks the cycle for the whole project)."""
    from pathlib import Path

    source = (Path(__file__).resolve().parents[2] / "sim" / "truth.py").read_text()
    assert "from sim.room" not in source and "import sim.room" not in source and "room._" not in source
