"""Coverage from poses and a mesh: closed forms on planes, and the virtual room's ground truth on the bust."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imaging.calibration.threed import Pinhole
from coordinator.coverage import (
    CoverageModel,
    Projector,
    irradiance,
    projector_from_pose,
    texel_area,
)
from coordinator.coverage_store import load_coverage, save_coverage


def quad(x0, x1, y0, y1, z, *, first=0):
    """Vertices (4, 3), faces (2, 3) wound upwards (+z), uvs of a rectangle at height z."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]]) + first
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float64)
    return v, f, uv


def looking_down(x, y, height, *, size=(200, 200), focal=300.0) -> Pinhole:
    """A pinhole at (x, y, height) looking straight down, image x along world +x."""
    R = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    C = np.array([x, y, height], np.float64)
    K = np.array([[focal, 0, (size[0] - 1) / 2], [0, focal, (size[1] - 1) / 2], [0, 0, 1.0]])
    return Pinhole(K, R, -R @ C, size)


def test_irradiance_of_a_plane_below_a_projector_is_the_closed_form():
    dev = looking_down(0, 0, 1000.0)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-400, 400, 50), rng.uniform(-400, 400, 50), np.zeros(50)])
    up = np.tile([0.0, 0.0, 1.0], (50, 1))
    d = np.linalg.norm(X - dev.center, axis=1)
    # cos(incidence) = cos(off-axis) = H / d: E = (H/d) (1000/d)^2 (H/d)^(f-3)
    for f in (1.0, 0.0, 4.0):
        np.testing.assert_allclose(irradiance(dev, X, up, falloff=f), (1000 / d) ** (f - 2) * (1000 / d) ** 2, rtol=1e-12)
    assert np.all(irradiance(dev, X, -up) == 0)                       # facing away
    np.testing.assert_allclose(irradiance(dev, X, up, gain=2.5), 2.5 * irradiance(dev, X, up))


def test_texel_areas_add_up_to_the_surface():
    v, f, uv = quad(-200, 200, -100, 100, 0.0)
    per_face = texel_area(v, f, uv, (64, 32))
    np.testing.assert_allclose(per_face, 400 * 200 / (64 * 32))
    with CoverageModel(v, f, uv, [Projector("a", looking_down(0, 0, 1000.0))]) as m:
        cov = m.texture((64, 32))
    assert cov.mask.all()
    assert cov.area.sum() == pytest.approx(400 * 200, rel=1e-5)
    # texel (row i, col j) is uv ((j + 0.5) / w, (i + 0.5) / h): x grows with j, y falls with i
    assert cov.points[0, 0, :2] == pytest.approx([-200 + 400 / 128, 100 - 200 / 64], abs=1e-3)
    assert cov.count.min() == 1 and cov.summary()["lit_pct"] == 100.0


def test_a_plate_shadows_the_plane_below_it_where_the_closed_form_says():
    """A 100 x 100 mm plate 300 mm above a plane; a projector 1000 mm above the plane: the plate's
    shadow on the plane is the plate scaled by 1000 / (1000 - 300) about the projector's foot."""
    v1, f1, uv1 = quad(-300, 300, -300, 300, 0.0)
    v2, f2, uv2 = quad(-50, 50, 20, 120, 300.0, first=4)
    v, f, uv = np.vstack([v1, v2]), np.vstack([f1, f2]), np.vstack([uv1, uv2])
    dev = looking_down(0, 0, 1000.0, size=(400, 400), focal=300.0)
    k = 1000 / 700
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-250, 250, 4000), rng.uniform(-250, 250, 4000), np.zeros(4000)])
    n = np.tile([0.0, 0.0, 1.0], (4000, 1))
    in_shadow = (np.abs(X[:, 0]) < 50 * k) & (X[:, 1] > 20 * k) & (X[:, 1] < 120 * k)
    clear = np.abs(X[:, 0]) > 50 * k + 3
    clear |= (X[:, 1] < 20 * k - 3) | (X[:, 1] > 120 * k + 3)
    inner = (np.abs(X[:, 0]) < 50 * k - 3) & (X[:, 1] > 20 * k + 3) & (X[:, 1] < 120 * k - 3)
    with CoverageModel(v, f, uv, [Projector("a", dev)]) as m:
        pc = m.at_points(X, n)
        top = m.at_points(np.array([[0.0, 70.0, 300.0]]), np.array([[0.0, 0.0, 1.0]]))
    assert inner.sum() > 100 and clear.sum() > 1000
    assert not pc.reach[0, inner].any()
    assert pc.reach[0, clear].all()
    assert top.count[0] == 1                                         # the plate itself is lit
    assert pc.reach[0, in_shadow].mean() < 0.05


def test_a_point_counts_only_inside_the_projector_image():
    """Pixel centres at integers: the image spans u in [-0.5, w - 0.5] exactly."""
    v, f, uv = quad(-500, 500, -500, 500, 0.0)
    dev = looking_down(0, 0, 1000.0, size=(100, 80), focal=200.0)   # 1 px = 5 mm on the plane
    xs = np.linspace(-300, 300, 601)
    X = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    n = np.tile([0.0, 0.0, 1.0], (len(xs), 1))
    with CoverageModel(v, f, uv, [Projector("a", dev)]) as m:
        pc = m.at_points(X, n)
    u = dev.project(X)[0][:, 0]
    np.testing.assert_array_equal(pc.reach[0], (u >= -0.5) & (u <= 99.5))
    assert 0 < pc.reach.mean() < 1


def test_a_pose_matrix_gives_back_its_pinhole():
    dev = looking_down(100, -50, 1400.0, size=(320, 200))
    p = projector_from_pose("r0c0", 3.7 * dev.P, dev.size, gain=0.8)
    np.testing.assert_allclose(p.device.P / np.linalg.norm(p.device.P), dev.P / np.linalg.norm(dev.P), atol=1e-12)
    np.testing.assert_allclose(p.device.center, dev.center, atol=1e-9)
    assert p.gain == 0.8 and p.device.size == (320, 200)


@pytest.fixture(scope="module")
def bust():
    from sim.room import Room
    from sim.scene import SUBSETS, reference_scene

    room = Room(reference_scene(projector_scale=0.125, camera_scale=0.125, surface="bust"), noise=False)
    room.prepare()
    slots = SUBSETS["P25"]
    truths = [room.truth.projector(s) for s in slots]
    projectors = [Projector(t.slot, Pinhole(t.K, t.R, t.t, t.size), t.peak) for t in truths]
    m = room.scene.mesh
    with CoverageModel(m.vertices, m.faces, m.uvs, projectors) as model:
        surf = room.truth.surface()
        on = surf.kind == 2
        pc = model.at_points(surf.points[on], surf.normals[on])
        cov = model.texture((512, 512))
        small = model.texture((128, 96))
    irr = np.stack([room.truth.irradiance(s, occluders=False)[on] for s in slots]).astype(np.float64)
    yield {"count": room.truth.illumination_count()[on], "uv": surf.uv[on], "points": pc, "cov": cov, "small": small, "irr": irr}


def test_the_count_agrees_with_the_room_on_the_bust(bust):
    """The room's truth (its own rasteriser and shadow maps) against the coverage from poses + mesh."""
    truth = bust["count"]
    assert len(truth) > 4000 and truth.min() <= 10 and truth.max() == 25
    assert (bust["points"].count == truth).mean() >= 0.99           # at the very points the camera sees
    rc = bust["cov"].lookup(bust["uv"])
    stored = bust["cov"].count[rc[:, 0], rc[:, 1]]
    assert (stored == truth).mean() >= 0.95                         # the stored texel map at the camera's uvs
    assert np.abs(stored.astype(int) - truth).max() <= 25 and np.abs(stored.astype(int) - truth).mean() < 0.1


def test_each_projector_share_is_the_room_irradiance_share(bust):
    """With each unit's peak as its gain the model is the room's photometry: the same shares."""
    irr = bust["irr"]
    pc = bust["points"]
    ok = (pc.count == bust["count"]) & (irr.sum(axis=0) > 0)
    np.testing.assert_allclose(pc.share[:, ok], irr[:, ok] / irr[:, ok].sum(axis=0), atol=1e-4)
    assert np.all(pc.effective[ok] <= pc.count[ok] + 1e-9)              # never more than the count


def test_the_stored_coverage_reads_back(bust, tmp_path):
    cov = bust["small"]
    summary = cov.summary()
    npz, _ = save_coverage(tmp_path, cov, summary)
    back = load_coverage(npz)
    assert back.slots == cov.slots and back.size == cov.size
    np.testing.assert_array_equal(back.reach, cov.reach)
    np.testing.assert_array_equal(back.count, cov.count)
    np.testing.assert_allclose(back.irradiance, cov.irradiance, rtol=2e-3, atol=1e-6)
    assert sorted(p.name for p in tmp_path.joinpath("coverage").iterdir()) == ["coverage.json", "coverage.npz"]
    assert sum(float(v) for v in summary["count_area_mm2"].values()) == pytest.approx(summary["surface_mm2"], rel=1e-4)
    # a projector's area is the area of the texels it reaches; the counts' mean is their sum over the lit area
    reach_sum = sum(s["reach_mm2"] for s in summary["per_slot"].values())
    lit = summary["surface_mm2"] * summary["lit_pct"] / 100
    assert reach_sum / lit == pytest.approx(summary["count_mean"], rel=1e-3)
    assert not math.isnan(summary["effective_mean"])
