"""A mesh rig's placement of each projector's pixels on the blend's camera grid.

On a mesh the camera and a projector meet in the texture: the camera's view gives the texel each
camera pixel sees; every texel's world point (the mesh's atlas) projected through a projector's
3x4 pose gives where that projector shows it, kept where its own view's depth says it is the
surface the projector lights (:func:`imaging.compensation.texture_space.texel_camera_map`, the
shadow-map test). Looking that table up at each grid point's texel gives the grid point's
projector coordinates, NaN where the projector does not reach the surface point the camera sees
there. These are :class:`~imaging.blending.contributions.Contributions`' ``projector_xy``.
"""
from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np

from imaging.blending.contributions import grid_to_camera
from imaging.compensation.texture_space import texel_camera_map

__all__ = ["texel_projector_table", "mesh_projector_xy"]


def texel_projector_table(atlas: np.ndarray, P: np.ndarray, view, *, min_cos: float = 0.05) -> np.ndarray:
    """``(Ch, Cw, 2) float32``: the projector pixel showing each texel, NaN where the projector does not light it.

    ``atlas``: (Ch, Cw, 3) world point per texel; ``P``: the projector's (3, 4) pose; ``view``: its view of the
    mesh (a :class:`~imaging.compensation.texture_space.DeviceView` at its size)."""
    m = texel_camera_map(atlas, P, view, min_cos=min_cos)
    pos = np.where(m.visible[:, None], m.position, np.nan)
    return pos.reshape(*atlas.shape[:2], 2).astype(np.float32)


def mesh_projector_xy(camera_x: np.ndarray, camera_y: np.ndarray, tables: Mapping[str, np.ndarray],
                      grid: tuple[int, int]) -> dict[str, np.ndarray]:
    """Each slot's ``(h, w, 2) float32`` projector coordinates on the grid ``(h, w)`` over the camera image.

    ``camera_x, camera_y``: (H, W) content coordinates each camera pixel sees (NaN off the mesh);
    ``tables``: slot -> its :func:`texel_projector_table`."""
    H, W = camera_x.shape
    pts = grid_to_camera((W, H), grid)
    cx = np.clip(np.rint(pts[..., 0]).astype(np.int64), 0, W - 1)
    cy = np.clip(np.rint(pts[..., 1]).astype(np.int64), 0, H - 1)
    gx = camera_x[cy, cx].astype(np.float32)
    gy = camera_y[cy, cx].astype(np.float32)
    bad = ~(np.isfinite(gx) & np.isfinite(gy))
    gx[bad], gy[bad] = -10.0, -10.0
    out = {}
    for s, table in tables.items():
        xy = cv2.remap(table, gx, gy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan))
        # next to a texel the projector does not light (an island's edge in the atlas), the nearest texel's
        near = cv2.remap(table, gx, gy, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan))
        xy = np.where(np.isfinite(xy), xy, near)
        xy[bad] = np.nan
        out[s] = xy.astype(np.float32)
    return out
