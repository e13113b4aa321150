"""What the camera would see of a blended rig: the forward model the blend inverts.

``predict`` applies each projector's maps the way a node does (:mod:`protos.blend`: texel centres,
bilinear, clamped at the edges; ``y = clamp(alpha * p + beta)``) at each grid point's projector
coordinates, and sums ``black_i + T_i * y_i``. It shares no code with
:func:`~imaging.blending.solve.compute_blend`, so the tests hold the solve to it, and the job
reports the uniformity the measured contributions predict beside the one it captures.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from imaging.blending.contributions import Contributions

__all__ = ["sample_map", "predict"]


def sample_map(values: np.ndarray, u: np.ndarray, projector_size: tuple[int, int]) -> np.ndarray:
    """``values`` ((mh, mw) or (mh, mw, C) float32, a map over a projector of ``projector_size``) at projector
    pixels ``u`` ((h, w, 2)), bilinear between texel centres and clamped at the edges; NaN ``u`` gives 0."""
    import cv2  # lazy: a coordinator's start loads this module; OpenCV only when a blend is computed or sampled

    W, H = projector_size
    a = np.ascontiguousarray(np.asarray(values, np.float32))
    mh, mw = a.shape[:2]
    tx = (u[..., 0] + 0.5) * (mw / W) - 0.5
    ty = (u[..., 1] + 0.5) * (mh / H) - 0.5
    bad = ~(np.isfinite(tx) & np.isfinite(ty))
    out = cv2.remap(a, np.where(bad, 0, tx).astype(np.float32), np.where(bad, 0, ty).astype(np.float32),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = np.asarray(out, np.float32).reshape(*u.shape[:2], *a.shape[2:])
    out[bad] = 0.0
    return out


def predict(contributions: Contributions, maps: Mapping[str, tuple[np.ndarray, np.ndarray]], value: float = 1.0, *,
            lost: tuple[str, ...] | frozenset = (), gains: Mapping[str, float] | None = None) -> np.ndarray:
    """``(h, w, 3) float32``: the camera grid's light when every projector shows linear ``value``.

    Slots in ``maps`` apply their ``(alpha, beta)``; the others show ``value`` unblended; ``lost`` slots add
    nothing; ``gains`` scale a slot's light (a dimmed lamp)."""
    c = contributions
    out = np.zeros((*c.shape, 3), np.float32)
    for s in c.slots:
        if s in lost:
            continue
        g = np.float32((gains or {}).get(s, 1.0))
        if s in maps:
            alpha, beta = maps[s]
            u = c.projector_coords(s)
            a = sample_map(alpha, u, c.projector_size[s])
            b = sample_map(beta, u, c.projector_size[s])
            y = np.clip(a * np.float32(value) + b[..., None], 0.0, 1.0)
        else:
            y = np.float32(value)
        out += g * (c.black[s] + c.white[s] * y)
    return out
