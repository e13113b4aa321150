"""Shadows against independent geometry: a box's outline, a plate's blocked fraction, the hand at 0.2 m."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.hand import Hand
from sim.occluders import Box
from sim.room import Room
from sim.scene import SUBSETS, load_layout, reference_scene


def _table_points(room: Room) -> tuple[np.ndarray, np.ndarray]:
    """Table point (H, W, 3) behind every camera pixel and a mask of pixels on the table."""
    surf = room.truth.surface()
    on = surf.kind == 1
    return surf.points.astype(np.float64), on


def test_box_shadow_under_a_point_projector_matches_its_analytic_outline(tmp_path):
    layout = tmp_path / "one.toml"
    layout.write_text(
        """
[table]
[[projector]]
slot = "solo"
position = [150, -80, 1400]
focal_px = 1100
aperture_mm = 0
[[camera]]
position = [0, -125, 1400]
focal_px = 2600
"""
    )
    room = Room(load_layout(layout, projector_scale=0.25, camera_scale=0.25), seed=0)
    w, h = room.projector_size("solo")
    room.set_frame("solo", np.full((h, w, 3), 255, np.uint8))
    free = room.render_linear()[..., 0]
    box = Box.yawed((-60.0, 40.0, 150.0), (140.0, 90.0, 40.0), yaw_deg=25.0)
    room.set_occluders([box])
    shadowed = room.render_linear()[..., 0]
    mask = room.truth.shadow_mask("solo")
    sees_box = room.truth.occluder_mask()
    # Analytic outline: the box's corners projected from the projector centre onto z = 0, convex hull.
    C = room.truth.projector("solo").center
    corners = box.corners()
    s = C[2] / (C[2] - corners[:, 2])
    ground = C[:2] + s[:, None] * (corners[:, :2] - C[:2])
    hull = cv2.convexHull(ground.astype(np.float32)).reshape(-1, 2)
    pts, on = _table_points(room)
    ys, xs = np.nonzero(on & ~sees_box)
    inside = np.array([cv2.pointPolygonTest(hull, (float(pts[y, x, 0]), float(pts[y, x, 1])), True) for y, x in zip(ys, xs)])
    px_mm = 2.2  # a camera pixel spans ~2.1 mm on the table at this scale
    deep_in = inside > px_mm
    far_out = inside < -px_mm
    assert deep_in.sum() > 300
    # Ground truth visibility: exact except on the outline itself.
    assert mask[ys[deep_in], xs[deep_in]].all()
    assert not mask[ys[far_out], xs[far_out]].any()
    # The capture: dark inside (no other projector), lit outside but for the pixel footprint at the edge.
    margin = inside > 2 * px_mm + 4.5  # + half a projector pixel
    assert shadowed[ys[margin], xs[margin]].max() <= 1e-6
    outside = inside < -(2 * px_mm + 4.5)
    np.testing.assert_allclose(shadowed[ys[outside], xs[outside]], free[ys[outside], xs[outside]], rtol=1e-6)


@pytest.fixture(scope="module")
def rig() -> Room:
    room = Room(reference_scene(camera_scale=0.25), seed=0, noise=False)
    for s in room.all_slots:
        w, h = room.projector_size(s)
        room.set_frame(s, np.full((h, w, 3), 255, np.uint8))
    room.prepare()
    return room


def test_flat_occluder_drops_the_fraction_of_light_whose_line_of_sight_it_blocks(rig):
    """Brute force: each point's segment to each projector centre, crossed with the plate's plane."""
    rig.set_active(SUBSETS["P25"])
    rig.set_occluders([])
    free = rig.render_linear()[..., 1].astype(np.float64)
    z_plate, half = 200.0, np.array([90.0, 60.0])
    centre = np.array([40.0, -30.0])
    rig.set_occluders([Box((*centre, z_plate), (*(2 * half), 0.5))])
    occluded = rig.render_linear()[..., 1].astype(np.float64)
    truth = rig.truth.light_drop()
    sees_plate = rig.truth.occluder_mask()
    pts, on = _table_points(rig)
    rng = np.random.default_rng(0)
    ys, xs = np.nonzero(on & ~sees_plate)
    near = np.abs(pts[ys, xs, 0] - centre[0]) < 400
    pick = rng.choice(np.flatnonzero(near), 400, replace=False)
    centres = np.array([rig.truth.projector(s).center for s in SUBSETS["P25"]])
    specs = [rig.projector(s) for s in SUBSETS["P25"]]

    def blocked(X, z=z_plate):
        s = (z - X[2]) / (centres[:, 2] - X[2])
        hit = X[:2] + s[:, None] * (centres[:, :2] - X[:2])
        return np.all(np.abs(hit - centre) <= half, axis=1)

    def irradiance(X):
        v = centres - X
        d = np.linalg.norm(v, axis=1)
        cos_t = v[:, 2] / d
        cos_a = np.array([-(vi @ p.pinhole.axis) / di for vi, di, p in zip(v, d, specs)])
        return np.array([p.peak for p in specs]) * cos_t * cos_a ** (1.0 - 3.0) * (1000.0 / d) ** 2

    checked = 0
    for k in pick:
        y, x = ys[k], xs[k]
        X = pts[y, x]
        b = blocked(X)
        if not np.array_equal(blocked(X, z_plate - 0.25), blocked(X, z_plate + 0.25)):
            continue  # within a hair of an edge of the 0.5 mm plate
        e = irradiance(X)
        fraction = float((b * e).sum() / e.sum())
        assert truth[y, x] == pytest.approx(fraction, abs=1e-5)
        # Away from every shadow edge (same blocked set 6 mm around), the captured light drops by it too.
        stable = all(np.array_equal(blocked(X + np.array([dx, dy, 0.0])), b) for dx in (-6, 6) for dy in (-6, 6))
        if stable:
            assert 1.0 - occluded[y, x] / free[y, x] == pytest.approx(fraction, abs=2e-3)
            checked += 1
    assert checked > 200
    assert truth.max() > 0.2  # the plate really blocks several projectors somewhere


def _drop_stats(room: Room) -> dict:
    drop = room.truth.light_drop().astype(np.float64)
    on = room.truth.surface().kind == 1
    d = np.where(on, drop, 0.0)
    step = max(np.abs(np.diff(d, axis=0)).max(), np.abs(np.diff(d, axis=1)).max())
    return {"max": float(d.max()), "umbra_px": int((d >= 0.9).sum()), "step": float(step)}


def test_hand_at_20cm_leaves_an_umbra_under_one_projector_and_none_under_25(rig):
    """The paper's central observation (Fig. 'planar_result', top), in numbers."""
    rig.set_occluders([Hand(position=(0.0, 0.0), height=200.0)])
    rig.set_active(SUBSETS["P1"])
    one = _drop_stats(rig)
    rig.set_active(SUBSETS["P25"])
    all25 = _drop_stats(rig)
    assert one["max"] == 1.0 and one["umbra_px"] > 1000  # ~ the hand's size: a hard black shadow
    assert one["step"] == 1.0  # a hard edge: lit next to black
    assert all25["umbra_px"] == 0 and all25["max"] < 0.9  # no point loses 90 % of its light
    # No hard edge: each projector's shadow is a small step. (A forearm parallel to the grid lines
    # up the edges of the 5 projectors of a column: steps of about 5/25, never the full drop.)
    assert all25["step"] < 0.35
    # The capture agrees: under P1 the umbra is black; under P25 every table point keeps light.
    rig.set_occluders([])
    free = rig.render_linear()[..., 1]
    rig.set_occluders([Hand(position=(0.0, 0.0), height=200.0)])
    lit = rig.render_linear()[..., 1]
    on = (rig.truth.surface().kind == 1) & ~rig.truth.occluder_mask()
    assert (lit[on] / free[on]).min() > 0.1


def test_touching_the_table_casts_an_umbra_even_under_25_projectors(rig):
    rig.set_active(SUBSETS["P25"])
    rig.set_occluders([Hand(position=(100.0, 50.0), height=0.0, pose="point")])
    s = _drop_stats(rig)
    assert s["max"] > 0.9  # right under the fingertip every projector is blocked
    rig.set_occluders([Hand(position=(100.0, 50.0), height=200.0)])
    assert _drop_stats(rig)["max"] < s["max"]
