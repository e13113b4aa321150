"""`shadowless bench bust`: its surface areas against the closed form, its ray casts, touch points and
shadow regions (against OpenCV's labelling and a brute-force ray cast on the table)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench.bust_touch import (
    CAMERA_DISTANCE_MM,
    NAMED,
    PRIMARY_DROP,
    SEED_MM,
    hand_fits,
    light_spread_deg,
    pixel_areas,
    pose_hand,
    ray_mesh,
    region,
    shadow_region,
    shoulder_for,
    touch_points,
    touch_row,
)


def plane_view(f: float = 400.0, size=(160, 120), tilt_deg: float = 35.0):
    """A pinhole tilted ``tilt_deg`` from looking straight down at the plane z = 0 from 600 mm:
    per pixel the world point, the plane's pixel footprint (closed form) and the unit ray."""
    w, h = size
    a = math.radians(tilt_deg)
    R = np.array([[1, 0, 0], [0, -math.cos(a), -math.sin(a)], [0, math.sin(a), -math.cos(a)]])   # rows: x, y, z axes
    C = np.array([0.0, -600 * math.tan(a), 600.0])
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    cam = np.stack([(xs - (w - 1) / 2) / f, (ys - (h - 1) / 2) / f, np.ones_like(xs)], -1)
    cos_a = 1 / np.linalg.norm(cam, axis=-1)
    ray = (cam @ R) * cos_a[..., None]                                       # world unit rays
    t = -C[2] / ray[..., 2]
    pts = C + t[..., None] * ray
    # a pixel spans the solid angle cos^3(alpha) / f^2; on the plane it covers t^2 Omega / cos(incidence)
    closed = t ** 2 * cos_a ** 3 / f ** 2 / np.abs(ray[..., 2])
    return pts, closed, t


def test_pixel_areas_on_a_tilted_plane_are_the_closed_form():
    pts, closed, _ = plane_view()
    kind = np.ones(closed.shape, np.uint8)
    area = pixel_areas(pts, kind)
    np.testing.assert_allclose(area[1:-1, 1:-1], closed[1:-1, 1:-1], rtol=2e-3)
    np.testing.assert_allclose(area, closed, rtol=0.05)        # one-sided differences at the border


def test_a_depth_step_does_not_inflate_the_pixels_beside_it():
    """The right half of the view sees a plane 150 mm higher (the same rays, shorter): the pixels on
    either side of the step keep their own plane's footprint."""
    pts, closed, t = plane_view()
    C = np.array([0.0, -600 * math.tan(math.radians(35)), 600.0])
    ray = (pts - C) / t[..., None]
    t2 = (150 - 600.0) / ray[..., 2]
    right = np.zeros(closed.shape, bool)
    right[:, 80:] = True
    step = np.where(right[..., None], C + t2[..., None] * ray, pts)
    expected = np.where(right, closed * (t2 / t) ** 2, closed)
    kind = np.ones(closed.shape, np.uint8)
    area = pixel_areas(step, kind)
    np.testing.assert_allclose(area[1:-1, 78:82], expected[1:-1, 78:82], rtol=0.02)
    kind[:, :10] = 0                                                       # nothing there
    assert np.all(pixel_areas(np.where(kind[..., None] > 0, pts, np.nan), kind)[:, :10] == 0)


def test_rays_hit_the_triangle_where_the_closed_form_says():
    tri = np.array([[[0, 0, 0], [10, 0, 0], [0, 10, 0]], [[0, 0, 5], [10, 0, 5], [0, 10, 5]]], np.float64)
    face, bary = ray_mesh((2, 3, 20), (0, 0, -1), tri)
    assert face == 1 and bary @ tri[1] == pytest.approx([2, 3, 5])
    assert ray_mesh((20, 20, 20), (0, 0, -1), tri)[0] == -1
    assert ray_mesh((2, 3, -20), (0, 0, -1), tri)[0] == -1                 # behind the origin


def test_touch_points_lie_on_the_bust_spread_out_and_leave_room_for_the_reaching_arm():
    from sim.mesh import bust

    mesh = bust()
    pts = touch_points(mesh, sampled=6, seed=1, poses=("reach", "normal"), pool=400)
    assert [p[0] for p in pts[:3]] == [name for name, _, _ in NAMED]
    head, chest, back = (p[1] for p in pts[:3])
    assert head[2] > 590 and chest[1] > 100 and 400 < back[2] < 460 and back[1] < -40
    assert [region(X, n) for _, X, n in pts[:3]] == ["top_of_head", "chest", "back_of_head"]
    v = mesh.vertices.astype(np.float64)
    P = np.array([X for _, X, _ in pts])
    gaps = np.linalg.norm(P[:, None] - P[None], axis=-1) + np.eye(len(P)) * 1e9
    assert len(pts) == 9 and gaps.min() > 60                             # farthest-point samples stay apart
    for name, X, n in pts:
        assert np.min(np.linalg.norm(v - X, axis=1)) < 15                  # on the surface
        assert abs(np.linalg.norm(n) - 1) < 1e-9
        sh = shoulder_for(X, n)
        assert np.hypot(*sh[:2]) == pytest.approx(600.0) and sh[2] == 650.0
        assert (sh[:2] - X[:2]) @ n[:2] >= 0 or np.linalg.norm(n[:2]) <= 0.3   # on the contact's side
        for pose in ("reach", "normal"):
            assert hand_fits(pose_hand(pose, X, n, sh), v, X, X + CAMERA_DISTANCE_MM * n)


def test_the_shadow_region_is_opencvs_8_connected_components_that_reach_the_contact():
    import cv2

    rng = np.random.default_rng(3)
    drop = rng.random((60, 80)).astype(np.float32) * 0.4                 # below the threshold
    drop[10:20, 10:20] = 0.9                                               # at the contact
    k = np.arange(20, 30)
    drop[k, k] = 0.8                                                       # a diagonal chain (8- but not 4-connected) ...
    drop[30:40, 30:35] = 0.7                                               # ... to a patch beyond the seed distance
    drop[40:50, 60:70] = 0.95                                              # far: another shadow
    drop[12, 20:60] = 0.8                                                  # a streak, its first pixels behind the hand
    surface = np.ones(drop.shape, bool)
    surface[:, 75:] = False                                                # nothing there
    visible = surface.copy()
    visible[12, 20:25] = False                                             # the viewer sees the hand there
    yy, xx = np.mgrid[0:60, 0:80]
    dist = np.hypot(yy - 15, xx - 15) * 2.0                                # 2 mm per pixel
    area = rng.uniform(3.0, 5.0, drop.shape)
    got = shadow_region(drop, surface, visible, dist, area, PRIMARY_DROP)
    _, labels = cv2.connectedComponents((surface & (drop > PRIMARY_DROP)).astype(np.uint8), connectivity=8)
    keep = np.isin(labels, np.unique(labels[(dist <= SEED_MM) & (labels > 0)]))
    assert keep[35, 32] and keep[12, 59] and not keep[45, 65] and dist[30, 30] > SEED_MM
    assert got["pixels"] == int(keep.sum())
    assert got["area_mm2"] == pytest.approx(area[keep & visible].sum(), abs=0.06)
    assert got["hidden_mm2"] == pytest.approx(area[keep & ~visible].sum(), abs=0.06)
    assert not got["clipped"]
    drop[10:20, 0:10] = 0.9                                                # now it meets the border
    assert shadow_region(drop, surface, visible, dist, area, PRIMARY_DROP)["clipped"]


def test_a_reaching_touch_on_the_table_casts_the_region_a_brute_force_ray_cast_finds():
    """The table under P25, a person at the front edge touching (100, 50): per 1.5 mm cell, the light
    drop from rays to every projector's centre against the hand's primitives (weights from the
    irradiance formula), the viewer's rays against the hand, OpenCV's components; the bench's region
    (the room's truth through its camera) agrees within the cells' and pixels' resolution."""
    import cv2

    from sim.occluders import cast_rays
    from sim.optics import irradiance_factor
    from sim.scene import SUBSETS, reference_scene

    scene = reference_scene(projector_scale=0.125, camera_scale=0.125)
    X = np.array([100.0, 50.0, 0.0])
    n = np.array([0.0, 0.0, 1.0])
    shoulder = np.array([100.0, -550.0, 650.0])
    centre = np.mean([scene.projector(s).native.center for s in SUBSETS["P25"]], axis=0)
    row = touch_row(scene, {"P25": SUBSETS["P25"]}, "t", X, n, poses=("reach",), px=120, half_mm=100.0,
                    shoulder=shoulder, array_centre=centre)
    got = row["reach"]["P25"]
    assert row["incidence_deg"] == pytest.approx(np.degrees(np.arccos(np.dot(centre - X, n) / np.linalg.norm(centre - X))), abs=0.06)

    hand = pose_hand("reach", X, n, shoulder).primitives()
    cell = 1.5
    c = np.arange(-100.0, 100.0 + 1e-9, cell)
    gx, gy = np.meshgrid(X[0] + c, X[1] - c)
    P = np.stack([gx, gy, np.zeros_like(gx)], -1).reshape(-1, 3)
    total = np.zeros(len(P))
    kept = np.zeros(len(P))
    for s in SUBSETS["P25"]:
        p = scene.projector(s)
        w = p.peak * irradiance_factor(p.native.center, p.native.axis, P, np.broadcast_to(n, P.shape), falloff=p.falloff)
        d = p.native.center - P
        t, _ = cast_rays(P, d / np.linalg.norm(d, axis=1, keepdims=True), hand)
        total += w
        kept += np.where(t < np.linalg.norm(d, axis=1), 0.0, w)
    drop = (1 - kept / total).reshape(gx.shape)
    eye = X + CAMERA_DISTANCE_MM * n
    d = eye - P
    t, _ = cast_rays(P, d / np.linalg.norm(d, axis=1, keepdims=True), hand)
    visible = (t >= np.linalg.norm(d, axis=1)).reshape(gx.shape)
    _, labels = cv2.connectedComponents((drop > PRIMARY_DROP).astype(np.uint8), connectivity=8)
    near = np.hypot(gx - X[0], gy - X[1]) <= SEED_MM
    keep = np.isin(labels, np.unique(labels[near & (labels > 0)]))
    want_visible = float((keep & visible).sum()) * cell ** 2
    want_hidden = float((keep & ~visible).sum()) * cell ** 2
    assert want_visible > 100 and want_hidden > 100                       # both parts are there to compare
    assert got["area_mm2"] == pytest.approx(want_visible, rel=0.1)
    assert got["hidden_mm2"] == pytest.approx(want_hidden, rel=0.1)
    assert got["max_drop_near_contact"] == pytest.approx(float(drop[near].max()), abs=0.02)


def test_the_light_spread_is_the_closed_form_rms_angle():
    X = np.array([0.0, 0.0, 0.0])
    a = np.radians(20.0)
    pair = np.array([[np.sin(a), 0.0, np.cos(a)], [-np.sin(a), 0.0, np.cos(a)]]) * 1000.0
    assert light_spread_deg(X, np.array([0.5, 0.5]), pair) == pytest.approx(20.0)
    # shares 3:1 at +-20 deg: the mean direction is off the axis; the RMS angle about it by hand
    d = pair / 1000.0
    m = 0.75 * d[0] + 0.25 * d[1]
    m /= np.linalg.norm(m)
    want = np.degrees(np.sqrt(0.75 * np.arccos(d[0] @ m) ** 2 + 0.25 * np.arccos(d[1] @ m) ** 2))
    assert light_spread_deg(X, np.array([0.75, 0.25]), pair) == pytest.approx(want)
    assert light_spread_deg(X, np.array([1.0, 0.0]), pair) == 0.0
    assert light_spread_deg(X, np.zeros(2), pair) == 0.0
