"""The multiplexed mode on a mesh: lifting camera positions onto the surface (against a brute-force
ray/triangle intersection), the pose fit for nearly coplanar correspondences (against the true
projection), and the whole mode on the room's bust (captures that do not grow with the projectors,
poses against the room's truth; two cameras and a lens-shifted projector)."""
from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest

from bench.calibration import (
    landmarks_from_truth,
    make_rig,
    mesh_errors,
    table_points_from_truth,
)
from imaging.calibration.alignment import sample_points
from imaging.calibration.errors import CalibrationError
from imaging.calibration.multiplex3d import fit_pose, lift, off_plane, rays
from imaging.calibration.points import write_points
from imaging.calibration.threed import (
    MeshData,
    Pinhole,
    SurfaceCaster,
    calibrate_projector,
    edge_mask,
    project,
)
from coordinator.jobs import Progress
from coordinator.rig import ProjectionPose
from shadowless.room_driver import RoomDriver
from sim.mesh import bust, save_mesh
from sim.room import Room
from sim.scene import load_layout, reference_scene

TABLE_MM = (1200.0, 600.0)


def look_at(center, target, *, f: float, size: tuple[int, int], principal=None) -> Pinhole:
    c = np.asarray(center, float)
    z = np.asarray(target, float) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 1, 0]) if abs(z[1]) < 0.99 else np.cross(z, [1, 0, 0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    w, h = size
    cx, cy = principal if principal is not None else ((w - 1) / 2, (h - 1) / 2)
    return Pinhole(np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]]), R, -R @ c, size)


def brute_force_hits(origin: np.ndarray, dirs: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The nearest intersection of each ray with every triangle (Moller-Trumbore) and with the table
    rectangle (z = 0), (M, 3); NaN where a ray hits nothing."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    out = np.full((len(dirs), 3), np.nan)
    for i, d in enumerate(dirs):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = origin - a
            u = np.einsum("ij,ij->i", s, p) / det
            q = np.cross(s, e1)
            v = (q @ d) / det
            t = np.einsum("ij,ij->i", e2, q) / det
        hit = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        best = float(t[hit].min()) if hit.any() else np.inf
        tz = -origin[2] / d[2]
        on_table = np.all(np.abs((origin + tz * d)[:2]) <= np.array(TABLE_MM) / 2)
        if 0 < tz < best and on_table:
            best = tz
        if np.isfinite(best):
            out[i] = origin + best * d
    return out


def test_lifting_matches_a_brute_force_ray_mesh_intersection():
    b = bust(segments=48, rings=60)
    cam = look_at((350, -900, 1150), (0, 0, 250), f=420.0, size=(320, 240), principal=(162.7, 117.4))
    with SurfaceCaster(MeshData(b.vertices, b.faces), table_mm=TABLE_MM) as caster:
        pts, kind = caster.cast(cam)
    usable = (kind != 0) & ~edge_mask(pts, kind)
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(0, 319, 600), rng.uniform(0, 239, 600)])
    X = lift(cam, pts, usable, xy)
    ok = np.isfinite(X).all(axis=1)
    assert ok.sum() > 200
    origin, dirs = rays(cam, xy[ok])
    truth = brute_force_hits(origin, dirs, b.vertices.astype(np.float64), b.faces.astype(np.int64))
    assert np.isfinite(truth).all()                     # nothing was lifted where the ray meets no surface
    err = np.linalg.norm(X[ok] - truth, axis=1)
    on_mesh = truth[:, 2] > 1e-6
    assert on_mesh.sum() > 50 and (~on_mesh).sum() > 50
    # a camera pixel spans ~2.5 mm there: on the table (one plane) the lift is exact, on the mesh
    # (facets meeting between the four cast points) a tenth of a pixel at most
    assert err[~on_mesh].max() < 1e-3, err[~on_mesh].max()
    assert err[on_mesh].max() < 0.3 and np.median(err[on_mesh]) < 0.03, (err[on_mesh].max(), np.median(err[on_mesh]))
    # exact on the table where interpolating the cast points is not; on the ray by construction
    interp = sample_points(pts, usable, xy[ok])
    assert np.linalg.norm(interp[~on_mesh] - truth[~on_mesh], axis=1).max() > 10 * err[~on_mesh].max()
    along = np.einsum("ij,ij->i", X[ok] - origin, dirs)
    assert np.abs(X[ok] - origin - along[:, None] * dirs).max() < 1e-6
    # positions off the surface, next to a silhouette, or outside the image are not lifted
    sil = np.argwhere((kind != 0) & ~usable)[:20][:, ::-1].astype(np.float64)
    nothing = np.argwhere(kind == 0)[:20][:, ::-1].astype(np.float64)
    out = np.array([[-3.0, 10.0], [319.5, 10.0], [10.0, 400.0], [np.nan, 5.0]])
    assert np.isnan(lift(cam, pts, usable, np.vstack([sil, nothing, out]))).all()
    with pytest.raises(ValueError):
        lift(cam, pts[..., :2], usable, xy)


def test_pose_fit_frees_the_intrinsics_only_when_points_leave_the_plane():
    rng = np.random.default_rng(3)
    table = np.column_stack([rng.uniform(-550, 550, 60), rng.uniform(-280, 280, 60), np.zeros(60)])
    above = np.column_stack([rng.uniform(-150, 150, 40), rng.uniform(-120, 120, 40), rng.uniform(30, 550, 40)])
    probe = np.column_stack([rng.uniform(-150, 150, 500), rng.uniform(-120, 120, 500), rng.uniform(0, 600, 500)])
    assert off_plane(np.vstack([table, above[:5]])) == 5 and off_plane(table) == 0
    # a lens-shifted projector (principal point near the bottom edge) seen through table and object points
    shifted = look_at((-250, 300, 1400), (0, 0, 0), f=310.0, size=(320, 200), principal=(158.0, 190.0))
    X = np.vstack([table, above])
    fit, free = fit_pose(X, shifted.project(X)[0], shifted.size, threshold=1.0)
    assert free and fit.count == len(X)
    assert np.abs(project(fit.device.P, probe)[0] - shifted.project(probe)[0]).max() < 1e-3
    # the table and one or two points on the object: the DLT is degenerate or at the mercy of noise there ...
    centred = look_at((250, -250, 1400), (0, 0, 0), f=310.0, size=(320, 200))
    with pytest.raises(CalibrationError, match="coplanar"):
        calibrate_projector(np.vstack([table, above[:1]]), centred.project(np.vstack([table, above[:1]]))[0], centred.size)
    few = np.vstack([table, above[:2]])
    x = centred.project(few)[0]
    noisy = x + np.random.default_rng(4).normal(0.0, 0.1, x.shape)
    dlt = calibrate_projector(few, noisy, centred.size).device
    fit, free = fit_pose(few, noisy, centred.size, threshold=1.0)
    assert not free
    err_dlt = np.abs(project(dlt.P, probe)[0] - centred.project(probe)[0]).max()
    err_fixed = np.abs(project(fit.device.P, probe)[0] - centred.project(probe)[0]).max()
    assert err_fixed < 0.6 and err_fixed < err_dlt / 2, (err_fixed, err_dlt)   # good enough to plan the lattice
    # ... so the principal point is fixed at the centre and the rest fitted: exact for such a projector
    fit, free = fit_pose(few, x, centred.size, threshold=1.0)
    assert not free and fit.count == len(few)
    assert np.abs(project(fit.device.P, probe)[0] - centred.project(probe)[0]).max() < 1e-3
    # the table alone, seen straight down (Zhang's focal estimate degenerates): still a projection through them
    down = look_at((0, 0, 1400), (0, 1e-3, 0), f=330.0, size=(320, 200))
    fit, free = fit_pose(table, down.project(table)[0], down.size, threshold=1.0)
    assert not free and fit.rms < 1e-3
    with pytest.raises(CalibrationError, match="at least 6"):
        fit_pose(table[:5], down.project(table[:5])[0], down.size)


# ---------------------------------------------------------------------- the mode on the room's bust
SMALL, LARGER = ["r1c1", "r3c3"], ["r0c0", "r0c4", "r2c2", "r4c0", "r4c4"]


@pytest.fixture(scope="module")
def bust_room():
    """The bust in the reference room, small projectors (128x80) and the default camera (648x486); only the
    projectors the test uses are mounted (the room prepares each one it holds)."""
    scene = reference_scene(surface="bust", projector_scale=0.1, camera_scale=0.25)
    return Room(dataclasses.replace(scene, projectors=tuple(p for p in scene.projectors if p.slot in SMALL + LARGER)))


@pytest.fixture(scope="module")
def inputs(bust_room, tmp_path_factory):
    d = tmp_path_factory.mktemp("bust")
    save_mesh(bust(), d / "bust.obj")
    table_points_from_truth(bust_room, d / "table.json", click_noise_px=0.3)
    landmarks_from_truth(bust_room, d / "landmarks.json", count=20, click_noise_px=0.5)
    return {"mesh": str(d / "bust.obj"), "table_points": str(d / "table.json"), "landmarks": str(d / "landmarks.json"),
            "settle_s": 0}


def test_multiplexed_3d_captures_do_not_grow_with_the_projectors_and_poses_match_the_truth(bust_room, inputs, tmp_path):
    captures = {}
    for slots in (SMALL, LARGER):
        rig = make_rig(tmp_path / f"rig{len(slots)}", bust_room, slots)
        driver = RoomDriver(bust_room, rig)
        result = asyncio.run(driver.run("calibrate", {**inputs, "mode": "multiplexed"}))
        assert result["mode"] == "multiplexed" and result["surface"] == "mesh" and not result["failed"]
        captures[len(slots)] = result["captures"]
        for s in slots:
            pose = rig.slot(s).pose
            assert isinstance(pose, ProjectionPose) and pose.mesh.mesh_id == rig.slot(slots[0]).pose.mesh.mesh_id
            rms, mx, n = mesh_errors(bust_room, s, pose.matrix)
            assert n > 3000 and rms < 0.5 and mx < 1.0, (s, rms, mx, n)
            doc = result["slots"][s]
            assert doc["lattice_dots"] >= 100 and doc["free_intrinsics"] and doc["rms_px"] < 0.3, doc
        stages = [e.stage for e in driver.events if isinstance(e, Progress)]
        assert {"exposure", "cameras", "coded dots", "lattice", "projectors"} <= set(stages)
    # every projector at once: 2 exposure + 20 coded + 4 lattice captures, for 2 projectors as for 5
    assert captures[2] == captures[5] == 26, captures


LENS_SHIFT = """
name = "bust, two cameras, a lens-shifted projector"
[table]
size = [1200, 600]
[mesh]
builtin = "bust"
[[projector]]
slot = "shifted"
position = [-500, -200, 1350]
target = [0, 0, 250]
principal = [489.5, 699.5]
[[projector]]
slot = "plain"
position = [450, 100, 1400]
target = [0, 0, 200]
[[camera]]
position = [-550, 650, 1150]
target = [0, 0, 250]
exposure = 0.4
[[camera]]
position = [550, 650, 1150]
target = [0, 0, 250]
exposure = 0.4
"""


def test_multiplexed_3d_pools_two_cameras_and_frees_a_lens_shifted_principal_point(tmp_path):
    """A projector whose lens is shifted (principal point 300 px below and 150 px left of the centre at its
    native 1280x800) is found as such, with coded dots decoded in both cameras."""
    (tmp_path / "room.toml").write_text(LENS_SHIFT)
    room = Room(load_layout(tmp_path / "room.toml", projector_scale=0.15, camera_scale=0.2), seed=2)
    save_mesh(bust(), tmp_path / "bust.obj")
    write_points(tmp_path / "table.json", [s for i in (0, 1) for s in table_points_from_truth(room, camera=i, seed=i)])
    write_points(tmp_path / "landmarks.json", [s for i in (0, 1) for s in landmarks_from_truth(room, camera=i, count=20, seed=i)])
    rig = make_rig(tmp_path / "rig", room, ["shifted", "plain"])
    driver = RoomDriver(room, rig, cameras=2)
    result = asyncio.run(driver.run("calibrate", {"mode": "multiplexed", "mesh": str(tmp_path / "bust.obj"), "settle_s": 0,
                                                  "table_points": str(tmp_path / "table.json"),
                                                  "landmarks": str(tmp_path / "landmarks.json")}))
    assert result["captures"] == 26
    assert sum("coded dots, camera" in e for e in driver.events if isinstance(e, str)) == 2
    for s in ("shifted", "plain"):
        doc = result["slots"][s]
        true_K = room.truth.projector(s).K
        assert doc["free_intrinsics"] and np.abs(np.array(doc["K"])[:2, 2] - true_K[:2, 2]).max() < 1.5, (doc["K"], true_K)
        for cam in (0, 1):
            rms, mx, n = mesh_errors(room, s, rig.slot(s).pose.matrix, camera=cam)
            assert n > 1000 and rms < 0.5, (s, cam, rms, mx)
