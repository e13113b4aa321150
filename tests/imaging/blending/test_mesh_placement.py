"""A mesh rig's placement of each projector's pixels on the blend's camera grid, and the geometric factor of
its light there, against the room's truth: the projector coordinates of the surface point each camera pixel
sees, and the irradiance the room computes there (which must be the shading times a function of the
projector pixel alone, the lamp's smooth light)."""
from __future__ import annotations

import numpy as np

from bench.compensation_bust import make_bust_rig
from coordinator.compensation.mesh_rig import camera_projection
from imaging.blending.contributions import Contributions
from imaging.blending.fit import poly_basis
from imaging.blending.mesh import mesh_placement
from shadowless.room_driver import RoomDriver
from sim.rigs import bust_walls_scene
from sim.room import Room


def test_placement_and_shading_on_the_camera_grid_match_the_rooms_truth(tmp_path):
    room = Room(bust_walls_scene(4, projector_scale=0.125, camera_scale=0.125), seed=1)
    slots = room.slots
    rig = make_bust_rig(tmp_path / "rig", room, slots)
    W, H = room.camera_size(0)
    P, _ = camera_projection(rig.path, 0)
    mesh = rig.slot(slots[0]).pose.mesh
    poses = {s: (rig.slot(s).pose.matrix, room.projector_size(s), rig.slot(s).pose.near_mm, rig.slot(s).pose.far_mm)
             for s in slots}
    placed = mesh_placement(mesh.vertices, mesh.faces, P, (W, H), (H, W), poses)   # a grid of the camera's pixels
    on_bust = room.truth.surface(0).kind == 2
    assert (placed.surface == on_bust).mean() > 0.999
    driver = RoomDriver(room, rig)
    for s in slots:
        truth = room.truth.projector_coordinates(s, 0)
        reached = np.isfinite(truth).all(axis=-1) & on_bust
        mine = np.isfinite(placed.xy[s]).all(axis=-1)
        assert not np.any(mine & ~on_bust)                                   # nothing off the mesh
        assert (mine & ~reached).sum() < 0.01 * reached.sum(), (s, (mine & ~reached).sum(), reached.sum())
        # what the room reaches and the placement leaves out lies where the node draws nothing: the pixel holding
        # the point does not see the mesh (along the projector's own silhouette), so the node clears it to black
        drawn = driver.mesh_view(s).on_mesh
        pw, ph = room.projector_size(s)
        missed = reached & ~mine
        t = np.nan_to_num(truth[missed])
        px = np.clip(np.floor(t[:, 0] + 0.5), 0, pw - 1).astype(int)
        py = np.clip(np.floor(t[:, 1] + 0.5), 0, ph - 1).astype(int)
        assert (~drawn[py, px]).mean() > 0.95 if len(px) else True, (s, (~drawn[py, px]).mean())
        assert missed.sum() < 0.2 * reached.sum(), (s, missed.sum(), reached.sum())
        # and the shading is whole where the pixels around the point are all drawn
        near = np.ones(len(np.flatnonzero(reached)), bool)
        tr = np.nan_to_num(truth[reached])
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                qx = np.clip(np.floor(tr[:, 0] + 0.5) + dx, 0, pw - 1).astype(int)
                qy = np.clip(np.floor(tr[:, 1] + 0.5) + dy, 0, ph - 1).astype(int)
                near &= drawn[qy, qx]
        whole = np.zeros_like(reached)
        whole[reached] = near
        both = reached & mine & whole
        err = np.hypot(*(truth[both] - placed.xy[s][both]).T)
        assert np.percentile(err, 99) < 0.05, (s, np.percentile(err, 99))
        # the room's irradiance over the shading is smooth in the projector's pixels (its profile and fall-off)
        irr = room.truth.irradiance(s, 0)
        ok = both & (irr > 0) & (placed.shading[s] > 0)
        pw, ph = room.projector_size(s)
        u = placed.xy[s][ok]
        y = np.log(irr[ok] / placed.shading[s][ok])
        A = poly_basis((u[:, 0] + 0.5) / pw * 2 - 1, (u[:, 1] + 0.5) / ph * 2 - 1, 4)
        res = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
        assert np.median(np.abs(res)) < 0.005 and np.percentile(np.abs(res), 95) < 0.03, \
            (s, np.median(np.abs(res)), np.percentile(np.abs(res), 95))
        # while the shading itself is not: it changes with the surface, far from any such function
        z = np.log(placed.shading[s][ok])
        assert np.percentile(np.abs(z - A @ np.linalg.lstsq(A, z, rcond=None)[0]), 95) > 0.1
    # the placement travels with the contributions: exactly, through the store's arrays
    xy = placed.xy
    white = {s: np.where(np.isfinite(xy[s][..., :1]), 1.0, 0.0).repeat(3, axis=2).astype(np.float32) for s in slots}
    c = Contributions((W, H), 1, white, {s: 0.01 * w for s, w in white.items()}, {s: np.eye(3) for s in slots},
                      {s: room.projector_size(s) for s in slots}, xy)
    back = Contributions.from_arrays(*c.to_arrays())
    for s in slots:
        assert np.array_equal(back.projector_coords(s), c.projector_coords(s), equal_nan=True)
