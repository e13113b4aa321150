"""The blend job on a mesh rig, end to end in the room: projectors around the bust with uneven light, blended
through the camera; what the camera sees of a flat white afterwards, against the light without the maps."""
from __future__ import annotations

import asyncio

import numpy as np

from bench.compensation_bust import make_bust_rig
from bench.uniformity_measure import nonuniformity
from coordinator.blend_store import load_contributions
from imaging.blending.contributions import Contributions
from imaging.blending.solve import compute_blend
from shadowless.room_driver import RoomDriver
from sim.photometry import Photometry
from sim.rigs import bust_walls_scene
from sim.room import Room


def test_a_mesh_rig_blended_through_the_camera_evens_the_light_where_projectors_overlap(tmp_path):
    light = Photometry(brightness_spread=0.15, white_spread=0.15, hotspot=0.15, vignetting=0.2)
    room = Room(bust_walls_scene(4, projector_scale=0.125, camera_scale=0.125, photometry=light), seed=2, noise=False)
    slots = room.slots
    rig = make_bust_rig(tmp_path / "bust", room, slots, content_size=(128, 96), luts=True)
    driver = RoomDriver(room, rig)
    out = asyncio.run(driver.run("blend", {"settle_s": 0.0, "experimental_mesh": True}))
    assert out["uniformity_after"] < 0.5 * out["uniformity_before"], out

    # the camera's own view of a flat white with the maps and without, against the blend's target
    c = Contributions.from_arrays(*load_contributions(rig.path))
    sol = compute_blend(c)
    W, H = room.camera_size(0)
    rows = np.minimum(((np.arange(H) + 0.5) * c.shape[0] / H).astype(int), c.shape[0] - 1)
    cols = np.minimum(((np.arange(W) + 0.5) * c.shape[1] / W).astype(int), c.shape[1] - 1)
    seen = (sol.target + sol.black_target[..., None] * sol.white_point)[rows[:, None], cols[None, :]]
    mask = sol.covered[rows[:, None], cols[None, :]] & (room.truth.illumination_count(0) >= 2) \
        & (room.truth.surface(0).kind == 2)
    cw, ch = rig.config.content_width, rig.config.content_height

    def flat_white() -> np.ndarray:
        driver.render_content(np.ones((ch, cw, 3), np.float32))
        return room.render_linear(0)

    blended = flat_white()
    kept = {s: rig.slot(s).blend for s in slots}
    for s in slots:
        driver.update_slot(s, blend=None)
    plain = flat_white()
    for s, b in kept.items():
        driver.update_slot(s, blend=b)
    before = nonuniformity(plain, seen, mask, block=4)
    after = nonuniformity(blended, seen, mask, block=4)
    assert before > 0.2 and after < 0.4 * before, (before, after)
