"""3D numerics: mesh files (against the room's independent writer), DLT and decomposition,
projector calibration, camera posing, mesh registration and GPU ray casting."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from imaging.calibration.errors import CalibrationError
from imaging.calibration.points import PointSet
from imaging.calibration.threed import (
    MESH,
    TABLE,
    MeshData,
    Pinhole,
    SurfaceCaster,
    calibrate_projector,
    decompose,
    depth_range,
    dlt,
    edge_mask,
    gl_projection,
    load_mesh,
    pose_camera,
    project,
    register_mesh,
)
from sim.mesh import bust, save_mesh
from sim.room import Room
from sim.scene import reference_scene


def look_down(center, target=(0, 0, 0), *, f=600.0, size=(640, 400), principal=None, roll=0.0) -> Pinhole:
    c = np.asarray(center, float)
    z = np.asarray(target, float) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 1, 0]) if abs(z[1]) < 0.99 else np.cross(z, [1, 0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    if roll:
        cr, sr = math.cos(roll), math.sin(roll)
        R = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]]) @ R
    w, h = size
    cx, cy = principal or ((w - 1) / 2, (h - 1) / 2)
    K = np.array([[f, 0, cx], [0, f * 1.001, cy], [0, 0, 1.0]])
    return Pinhole(K, R, -R @ c, size)


def same_triangles(va, fa, vb, fb, tol=1e-3) -> bool:
    """Both meshes hold the same triangles (as corner coordinates, any corner order), within ``tol`` mm."""
    ta, tb = va.astype(float)[fa], vb.astype(float)[fb]
    if len(ta) != len(tb):
        return False
    d, j = cKDTree(tb.mean(axis=1)).query(ta.mean(axis=1))
    if d.max() > tol or len(set(j.tolist())) != len(j):
        return False
    return bool(np.abs(np.sort(ta.reshape(len(ta), -1), axis=1) - np.sort(tb[j].reshape(len(ta), -1), axis=1)).max() < tol)


@pytest.mark.parametrize("name,binary", [("m.obj", True), ("m.ply", True), ("m.ply", False)])
def test_meshes_read_what_the_rooms_writer_wrote(tmp_path, name, binary):
    ref = bust(segments=16, rings=24)
    save_mesh(ref, tmp_path / name, binary=binary)
    got = load_mesh(tmp_path / name)
    assert same_triangles(got.vertices, got.faces, ref.vertices, ref.faces)
    # uvs follow their vertices (v flipped back to the project's top-left convention)
    a = np.column_stack([got.vertices, 1000 * got.uvs])
    b = np.column_stack([ref.vertices, 1000 * ref.uvs])
    d, _ = cKDTree(b).query(a)
    assert d.max() < 1e-2 and got.uvs.min() >= 0 and got.uvs.max() <= 1


def test_obj_polygons_negative_indices_and_errors(tmp_path):
    f = tmp_path / "q.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf -4/-4 -3/-3 -2/-2 -1/-1\n")
    m = load_mesh(f)
    assert len(m.faces) == 2 and m.uvs is not None and len(m.vertices) == 4
    # OBJ v grows upwards; ours grows downwards
    assert {tuple(uv) for uv in m.uvs} == {(0.0, 1.0), (1.0, 1.0), (1.0, 0.0), (0.0, 0.0)}
    (tmp_path / "bad.obj").write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(CalibrationError, match="missing vertex"):
        load_mesh(tmp_path / "bad.obj")
    (tmp_path / "x.stl").write_text("solid")
    with pytest.raises(CalibrationError, match="unknown mesh format"):
        load_mesh(tmp_path / "x.stl")
    (tmp_path / "b.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n")
    with pytest.raises(CalibrationError, match="x, y, z"):
        load_mesh(tmp_path / "b.ply")
    with pytest.raises(CalibrationError, match="cannot read mesh"):
        load_mesh(tmp_path / "none.obj")


def test_dlt_and_decomposition_recover_a_projector_exactly():
    dev = look_down((300, -200, 1400), f=900, size=(1280, 800), principal=(650.0, 380.0), roll=0.05)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-600, 600, 200), rng.uniform(-300, 300, 200), rng.uniform(0, 600, 200)])
    x, _ = dev.project(X)
    P = dlt(X, x)
    np.testing.assert_allclose(project(P, X)[0], x, atol=1e-6)
    K, R, t = decompose(P)
    np.testing.assert_allclose(K, dev.K, rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(R, dev.R, atol=1e-9)
    np.testing.assert_allclose(t, dev.t, atol=1e-5)
    with pytest.raises(CalibrationError, match="coplanar"):
        dlt(np.column_stack([X[:, :2], np.zeros(200)]), x)


def test_projector_calibration_from_quantised_correspondences_with_outliers():
    dev = look_down((-250, 250, 1400), f=310, size=(320, 200), principal=(161.0, 98.5))
    rng = np.random.default_rng(1)
    n = 30000
    X = np.column_stack([rng.uniform(-600, 600, n), rng.uniform(-300, 300, n), np.where(rng.random(n) < 0.3, rng.uniform(0, 600, n), 0.0)])
    x, _ = dev.project(X)
    keep = (x[:, 0] > -0.5) & (x[:, 1] > -0.5) & (x[:, 0] < 319.5) & (x[:, 1] < 199.5)
    X, x = X[keep], np.floor(x[keep] + 0.5)          # decoded integer pixels
    bad = rng.choice(len(X), len(X) // 50, replace=False)
    x[bad] += rng.uniform(-30, 30, (len(bad), 2))     # 2 % wild decodes
    fit = calibrate_projector(X, x, (320, 200))
    probe = np.column_stack([rng.uniform(-600, 600, 2000), rng.uniform(-300, 300, 2000), rng.uniform(0, 600, 2000)])
    err = np.linalg.norm(project(fit.device.P, probe)[0] - dev.project(probe)[0], axis=1)
    assert err.max() < 0.05, err.max()
    assert abs(fit.device.K[0, 0] / dev.K[0, 0] - 1) < 2e-3
    assert 0.35 < fit.rms < 0.45 and fit.count >= len(X) - len(bad)
    with pytest.raises(CalibrationError, match="at least 12"):
        calibrate_projector(X[:5], x[:5], (320, 200))


def test_cameras_are_posed_from_known_points():
    cam = look_down((0, -125, 1400), f=650, size=(648, 486))
    rng = np.random.default_rng(2)
    table = np.column_stack([rng.uniform(-560, 560, 15), rng.uniform(-260, 260, 15), np.zeros(15)])
    marks = np.column_stack([rng.uniform(-120, 120, 20), rng.uniform(-100, 100, 20), rng.uniform(50, 580, 20)])
    noise = lambda p: p + rng.normal(0, 0.3, p.shape)  # noqa: E731
    t_set = PointSet("world", 0, tuple(f"t{i}" for i in range(15)), table, noise(cam.project(table)[0]))
    m_set = PointSet("world", 0, tuple(f"m{i}" for i in range(20)), marks, noise(cam.project(marks)[0]))
    # where it matters: the table, and the object's volume above its centre
    on_table = np.column_stack([rng.uniform(-600, 600, 300), rng.uniform(-300, 300, 300), np.zeros(300)])
    volume = np.column_stack([rng.uniform(-150, 150, 300), rng.uniform(-130, 130, 300), rng.uniform(0, 600, 300)])
    probe = np.vstack([on_table, volume])
    # landmarks off the table make a full calibration; with known intrinsics the table alone fixes the pose,
    # well on the table, less well 600 mm above it (rotation and translation trade off for a plane seen from above)
    for sets, K, tol_table, tol_volume in [([t_set, m_set], None, 1.0, 1.0), ([t_set], cam.K, 1.0, 5.0)]:
        fit = pose_camera(sets, (648, 486), K=K)
        for pts, tol in ((on_table, tol_table), (volume, tol_volume)):
            err = np.linalg.norm(fit.device.project(pts)[0] - cam.project(pts)[0], axis=1)
            assert err.max() < tol, (len(sets), K is None, err.max())
        assert fit.rms < 0.6
    # the table alone cannot give the focal length of a camera looking straight down ...
    with pytest.raises(CalibrationError, match="cannot be measured from table points alone"):
        pose_camera([t_set], (648, 486))
    # ... but can for an oblique one
    side = look_down((900, -700, 900), f=650, size=(648, 486))
    fit = pose_camera([PointSet("world", 0, t_set.names, table, noise(side.project(table)[0]))], (648, 486))
    err = np.linalg.norm(fit.device.project(probe)[0] - side.project(probe)[0], axis=1)
    assert err.max() < 3.0 and abs(fit.device.K[0, 0] / 650 - 1) < 0.03, (err.max(), fit.device.K[0, 0])
    with pytest.raises(CalibrationError, match="at least 4"):
        pose_camera([PointSet("world", 0, ("a",), table[:1], table[:1, :2])], (648, 486))


def test_mesh_registration_recovers_the_model_to_world_transform():
    cams = {0: look_down((0, -125, 1400), f=650, size=(648, 486)), 1: look_down((700, 600, 1200), f=650, size=(648, 486))}
    a = 0.4
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    t = np.array([35.0, -20.0, 5.0])
    rng = np.random.default_rng(3)
    model = np.column_stack([rng.uniform(-120, 120, 24), rng.uniform(-100, 100, 24), rng.uniform(0, 600, 24)])
    world = model @ R.T + t
    sets = [PointSet("model", i, tuple(f"l{k}" for k in range(12)), model[i * 12:(i + 1) * 12],
                     cams[i].project(world[i * 12:(i + 1) * 12])[0] + rng.normal(0, 0.4, (12, 2))) for i in (0, 1)]
    R2, t2, rms = register_mesh(sets, cams)
    np.testing.assert_allclose(model @ R2.T + t2, world, atol=1.5)
    assert rms < 1.0
    with pytest.raises(CalibrationError, match="not posed"):
        register_mesh(sets, {})


def test_rays_cast_onto_the_table_match_the_analytic_intersection():
    cam = look_down((100, -150, 1400), f=500, size=(320, 240))
    with SurfaceCaster(None, table_mm=(1200, 600)) as caster:
        pts, kind = caster.cast(cam)
    ys, xs = np.mgrid[0:240, 0:320]
    rays = np.column_stack([xs.ravel(), ys.ravel(), np.ones(xs.size)]) @ np.linalg.inv(cam.K).T @ cam.R
    s = -cam.center[2] / rays[:, 2]
    hit = (cam.center + s[:, None] * rays).reshape(240, 320, 3)
    on = (np.abs(hit[..., 0]) < 598) & (np.abs(hit[..., 1]) < 298)
    assert np.all(kind[on] == TABLE) and np.all(kind[(np.abs(hit[..., 0]) > 602) | (np.abs(hit[..., 1]) > 302)] == 0)
    assert np.nanmax(np.linalg.norm(pts[on] - hit[on], axis=-1)) < 0.05       # mm, float32 GPU interpolation


def test_rays_cast_onto_the_bust_match_the_rooms_truth():
    room = Room(reference_scene(projector_scale=0.05, camera_scale=0.15, surface="bust"))
    t = room.truth.camera(0)
    cam = Pinhole(t.K, t.R, t.t, t.size)
    b = bust()
    with SurfaceCaster(MeshData(b.vertices, b.faces, b.uvs), table_mm=(1200, 600)) as caster:
        pts, kind = caster.cast(cam)
    truth = room.truth.surface(0)
    edges = edge_mask(pts, kind)
    same = (kind == truth.kind) & ~edges & (kind > 0)
    assert np.mean(kind[~edges] == truth.kind[~edges]) > 0.999
    d = np.linalg.norm(pts[same] - truth.points[same], axis=-1)
    assert np.percentile(d, 99) < 0.1 and (kind == MESH).sum() > 1000
    near, far = depth_range(cam.P, b.vertices)
    _, depth = cam.project(b.vertices.astype(float))
    assert near < depth.min() and far > depth.max()


def test_gl_projection_puts_pixel_centres_at_window_half_integers():
    cam = look_down((0, 0, 1000), f=400, size=(64, 48), principal=(30.2, 25.7))
    X = np.array([[10.0, 20.0, 0.0], [-50.0, 5.0, 100.0]])
    px, _ = cam.project(X)
    clip = np.column_stack([X, np.ones(2)]) @ gl_projection(cam, near=10, far=2000).T
    ndc = clip[:, :2] / clip[:, 3:]
    window = (ndc + 1) / 2 * [64, 48]
    np.testing.assert_allclose(window - 0.5, px, atol=1e-9)
    with pytest.raises(ValueError):
        gl_projection(cam, near=0, far=1)


def test_bad_mesh_data_is_refused():
    with pytest.raises(CalibrationError, match="reference vertex"):
        MeshData(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    with pytest.raises(ValueError):
        MeshData(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError):
        SurfaceCaster(None)
    # cv2 and numpy agree on the rotation convention used by the registration
    r, _ = cv2.Rodrigues(np.eye(3))
    assert np.allclose(r, 0)
