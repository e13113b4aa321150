"""A mesh rig's placement of each projector's pixels on the blend's camera grid (through the texture and
the mesh's atlas) against the room's truth: the projector coordinates of the surface point each camera
pixel sees."""
from __future__ import annotations

import numpy as np

from bench.compensation_bust import make_bust_rig
from coordinator.compensation.mesh_rig import mesh_geometry
from imaging.blending.contributions import Contributions, grid_shape, grid_to_camera
from imaging.blending.mesh import mesh_projector_xy, texel_projector_table
from imaging.compensation.texture_space import MeshCaster
from sim.rigs import bust_walls_scene
from sim.room import Room


def test_projector_coordinates_through_the_texture_match_the_truth(tmp_path):
    room = Room(bust_walls_scene(4, projector_scale=0.125, camera_scale=0.125), seed=1)
    slots = room.slots
    content = (128, 96)
    rig = make_bust_rig(tmp_path / "rig", room, slots, content_size=content)
    cam = room.camera_size(0)
    geo = mesh_geometry(rig, slots, 0, projectors=True, camera_size=cam)
    with MeshCaster(geo.mesh.vertices, geo.mesh.uvs, geo.mesh.faces) as caster:
        atlas = caster.atlas(content)
    tables = {s: texel_projector_table(atlas, rig.slot(s).pose.matrix, geo.projectors[s]) for s in slots}
    shape = grid_shape(cam, 1)
    xy = mesh_projector_xy(geo.view.x, geo.view.y, tables, shape)
    pts = grid_to_camera(cam, shape)
    cx = np.clip(np.rint(pts[..., 0]).astype(int), 0, cam[0] - 1)
    cy = np.clip(np.rint(pts[..., 1]).astype(int), 0, cam[1] - 1)
    on_bust = room.truth.surface(0).kind[cy, cx] == 2
    for s in slots[:2]:
        truth = room.truth.projector_coordinates(s, 0)[cy, cx]
        reached = np.isfinite(truth).all(axis=-1) & on_bust
        mine = np.isfinite(xy[s]).all(axis=-1)
        both = reached & mine
        assert both.sum() > 0.8 * reached.sum(), (s, both.sum(), reached.sum())
        assert not np.any(mine & ~on_bust)                  # nothing off the mesh
        err = np.hypot(*(truth[both] - xy[s][both]).T)
        assert np.median(err) < 0.1 and np.percentile(err, 99) < 1.0, (s, np.median(err), np.percentile(err, 99))
    # the placement travels with the contributions: exactly, through the store's arrays
    white = {s: np.where(np.isfinite(xy[s][..., :1]), 1.0, 0.0).repeat(3, axis=2).astype(np.float32) for s in slots}
    c = Contributions(cam, 1, white, {s: 0.01 * w for s, w in white.items()}, {s: np.eye(3) for s in slots},
                      {s: room.projector_size(s) for s in slots}, xy)
    back = Contributions.from_arrays(*c.to_arrays())
    for s in slots:
        assert np.array_equal(back.projector_coords(s), c.projector_coords(s), equal_nan=True)
