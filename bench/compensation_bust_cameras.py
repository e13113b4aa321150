"""`bench compensation_bust --cameras 3`: one camera's compensation against three cameras', scored alike.

Each run of the ``compensate`` job scores its result from the cameras it measured with, over the
surface they see: a one-camera run from the ceiling is scored on the bust's crown and shoulders
only. To compare the two honestly, :func:`score_from_cameras` shows each result (the content of
every projector, as the nodes would) and captures it from all three cameras, and scores every
result over the same pixels against the same target, those of the three-camera measurement:
the visible surface its solve weighs (:func:`coordinator.compensation.mesh_transport.solve_weights`),
the content as the cameras would see it without blur at ``level`` times the rig's white (``L 1``),
divided by its 99th percentile (as :mod:`coordinator.compensation.mesh_compensate` scores).
"""
from __future__ import annotations

import numpy as np

from imaging.compensation.geometry import row_white
from coordinator.compensation.image_param import prepare_image
from coordinator.compensation.mesh_compensate import SCORE_PERCENTILE
from imaging.compensation.mesh_geometry import masked_quality
from coordinator.compensation.mesh_rig import mesh_cameras
from coordinator.compensation.mesh_transport import solve_weights
from coordinator.compensation.store import StoredTransport
from imaging.compensation.texture_space import content_at_view
from imaging.compensation.transport import load_transport
from shadowless.room_driver import RoomDriver

__all__ = ["score_from_cameras"]


def _captured(driver: RoomDriver, image: np.ndarray | None, cameras: list[int], frames: int,
              exposure: float = 1.0) -> np.ndarray:
    """``image`` shown (None: black), each camera's mean of ``frames`` captures at ``exposure`` times its own,
    stacked: ``(K Hc, Wc, 3)``."""
    driver.render_content(image)
    room = driver.room
    return np.concatenate([np.mean([room.capture(c, exposure=room.truth.camera(c).exposure * exposure)
                                    for _ in range(frames)], axis=0, dtype=np.float32) for c in cameras], axis=0)


def score_from_cameras(driver: RoomDriver, content: np.ndarray, results: dict[str, np.ndarray], *, level: float,
                       frames: int) -> dict:
    """PSNR / SSIM of each of ``results`` (name -> ``(H, W, 3) float32`` texture) captured by the cameras of the
    rig's stored (multi-camera) ``L``, all over that measurement's visible surface; also per camera.

    ``content``: the image the results compensate (``(H, W, 3)`` uint8, linear); ``level``: the
    compensate job's target level.
    """
    rig = driver.rig
    L, meta = load_transport(rig.path / "compensation" / "transport.npz")
    cameras = [int(c) for c in meta["cameras"]]
    shape = (int(meta["camera_size"][1]), int(meta["camera_size"][0]))
    tr = StoredTransport(L, meta, np.zeros((*shape, 3), np.float32), np.eye(3), shape, sorted(meta["slots"]), True)
    cams = mesh_cameras(rig, tr.slots, cameras)
    region = solve_weights(cams, tr) > 0
    cw, ch = rig.config.content_width, rig.config.content_height
    T = content_at_view(prepare_image(content, (cw, ch), srgb=False), cams.view)
    target = np.float32(level) * row_white(L, shape)[:, :, None] * T
    ref = np.float32(np.percentile(target[region], SCORE_PERCENTILE))
    goal = target / ref
    exposure = float(meta.get("exposure", 1.0))       # L's units: the captures it is compared with use it too
    black = _captured(driver, None, cameras, frames, exposure)
    h = shape[0] // len(cameras)
    out: dict = {"cameras": cameras, "visible_surface_pixels": int(region.sum()),
                 "per_camera_pixels": [int(region[k * h:(k + 1) * h].sum()) for k in range(len(cameras))]}
    for name, x in results.items():
        c = (_captured(driver, x, cameras, frames, exposure) - black) / ref
        s = masked_quality(goal, c, region)
        s["per_camera"] = [masked_quality(goal[k * h:(k + 1) * h], c[k * h:(k + 1) * h], region[k * h:(k + 1) * h])
                           for k in range(len(cameras))]
        out[name] = s
    return out
