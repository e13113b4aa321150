"""The bust: rasterised visibility (camera hits, self-occlusion) against brute-force ray/triangle tests."""
from __future__ import annotations

import numpy as np
import pytest

from sim.room import MESH, TABLE, Room
from sim.scene import reference_scene


def ray_triangle(origins: np.ndarray, dirs: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Möller-Trumbore, brute force: nearest hit distance (N,) of rays against all triangles (F, 3, 3)."""
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    best = np.full(len(origins), np.inf)
    for k in range(len(origins)):
        p = np.cross(dirs[k], e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origins[k] - v0
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ dirs[k]) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
        if hit.any():
            best[k] = t[hit].min()
    return best


@pytest.fixture(scope="module")
def bust_room() -> Room:
    room = Room(reference_scene(projector_scale=0.25, camera_scale=0.125, surface="bust"), seed=0)
    room.prepare()
    return room


def test_camera_sees_the_mesh_where_brute_force_rays_hit_it(bust_room):
    cam = bust_room.truth.camera()
    surf = bust_room.truth.surface()
    tri = bust_room.scene.mesh.triangles()
    rng = np.random.default_rng(0)
    # Pixels around the bust's image (hits and misses).
    ys, xs = np.nonzero(surf.kind == MESH)
    y0, y1, x0, x1 = ys.min() - 5, ys.max() + 5, xs.min() - 5, xs.max() + 5
    py = rng.integers(y0, y1, 300)
    px = rng.integers(x0, x1, 300)
    device = bust_room.scene.cameras[0].pinhole
    dirs = device.rays(np.column_stack([px, py]).astype(np.float64))
    t = ray_triangle(np.broadcast_to(cam.center, dirs.shape), dirs, tri)
    brute_hit = np.isfinite(t)
    room_hit = surf.kind[py, px] == MESH
    assert (brute_hit == room_hit).mean() >= 0.98
    both = brute_hit & room_hit
    assert both.sum() > 100
    brute_points = cam.center + t[both, None] * dirs[both]
    np.testing.assert_allclose(surf.points[py[both], px[both]], brute_points, atol=0.5)


@pytest.mark.parametrize("slot", ["r0c0", "r4c2", "r2c4"])
def test_mesh_self_occlusion_matches_brute_force_ray_casts(bust_room, slot):
    """Which surface points (bust and the table around it) a projector lights, against exact ray casts."""
    surf = bust_room.truth.surface()
    coords = bust_room.truth.projector_coordinates(slot)
    irr = bust_room.truth.irradiance(slot, occluders=False)
    C = bust_room.truth.projector(slot).center
    tri = bust_room.scene.mesh.triangles()
    rng = np.random.default_rng(1)
    ys, xs = np.nonzero(surf.kind == MESH)
    ty, tx = np.nonzero(surf.kind == TABLE)
    near_table = np.flatnonzero(np.hypot(surf.points[ty, tx, 0], surf.points[ty, tx, 1]) < 450)
    pick_m = rng.choice(len(ys), 250, replace=False)
    pick_t = rng.choice(near_table, 150, replace=False)
    py = np.concatenate([ys[pick_m], ty[pick_t]])
    px = np.concatenate([xs[pick_m], tx[pick_t]])
    X = surf.points[py, px].astype(np.float64)
    n = surf.normals[py, px].astype(np.float64)
    to_c = C - X
    dist = np.linalg.norm(to_c, axis=1)
    d = to_c / dist[:, None]
    start = X + 0.05 * n  # off the surface so a point does not hit its own triangle
    t = ray_triangle(start, d, tri)
    faces = (n * d).sum(axis=1) > 0.02
    brute_lit = faces & ~(t < dist - 0.1)
    room_lit = np.isfinite(coords[py, px, 0]) & (irr[py, px] > 0)
    agree = (brute_lit == room_lit).mean()
    assert agree >= 0.96, agree
    assert (~brute_lit).sum() > 20 and brute_lit.sum() > 100  # both cases are present


def test_illumination_count_shows_where_few_projectors_reach(bust_room):
    """The paper's heat map: the crown sees nearly all 25, the underside of the jaw few."""
    count = bust_room.truth.illumination_count()
    surf = bust_room.truth.surface()
    z = surf.points[..., 2]
    n = surf.normals
    crown = (surf.kind == MESH) & (z > 580)
    assert crown.any() and np.median(count[crown]) >= 23
    flank = (surf.kind == MESH) & (np.abs(n[..., 2]) < 0.3) & (z > 100) & (z < 300)
    assert flank.any() and np.median(count[flank]) < np.median(count[crown])
    table_far = (surf.kind == TABLE) & (np.hypot(surf.points[..., 0], surf.points[..., 1]) > 500)
    assert np.median(count[table_far]) == 25
