"""A rig's light taken from the virtual room's truth instead of a measurement: each projector's
contribution on a camera grid (:class:`imaging.blending.contributions.Contributions`), for tests
of what uses a blend (failover, the watchdog) apart from how well the blend job measures it."""
from __future__ import annotations

import numpy as np

from imaging.blending.contributions import Contributions, grid_shape
from imaging.blending.watchdog import grid_mean


def truth_contributions(room, slots: list[str], scale: int = 2) -> Contributions:
    """Each projector's light from ``room``'s truth: its full white above black (the room's
    contribution, area-averaged onto the grid), its black share (the response's black level in the
    same proportion), camera -> projector through the table's plane."""
    cam = room.camera_size(0)
    shape = grid_shape(cam, scale)
    t2c = room.truth.table_to_camera_homography(0)
    white, black, c2p, sizes = {}, {}, {}, {}
    for s in slots:
        white[s] = grid_mean(room.truth.contribution(s), shape)
        b = room.truth.projector(s).black
        black[s] = (white[s] * (b / (1.0 - b))[None, None, :]).astype(np.float32)
        c2p[s] = room.truth.table_to_projector_homography(s) @ np.linalg.inv(t2c)
        sizes[s] = room.projector_size(s)
    return Contributions(cam, scale, white, black, c2p, sizes)
