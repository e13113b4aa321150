"""Synthetic planar rigs with known contributions, for tests and benchmarks.

Each projector is an axis-aligned rectangle of the camera image (a homography of scale and shift),
its light ``peak * white_c * falloff(u) * hotspot(u)`` in its own pixels, its black a fixed fraction
of its light. The truth is exact, so the blend's figures on it are the method's alone.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from imaging.blending.contributions import Contributions, apply_homography_grid, grid_shape, grid_to_camera

__all__ = ["projector_light", "rectangle_rig", "wall_rects", "tiled_rects"]


def projector_light(u: np.ndarray, size: tuple[int, int], *, peak: float = 1.0, white=(1.0, 1.0, 1.0),
                    falloff: float = 0.3, hotspot: float = 0.1) -> np.ndarray:
    """``(h, w, 3) float32``: a projector's light at projector pixels ``u`` ((h, w, 2)); 0 outside its frame.

    ``falloff``: the fraction lost at the frame's corners (quadratic in the radius); ``hotspot``: a Gaussian
    bump of that height near the centre."""
    W, H = size
    a = (u[..., 0] + 0.5) / W * 2 - 1
    b = (u[..., 1] + 0.5) / H * 2 - 1
    inside = (np.abs(a) <= 1) & (np.abs(b) <= 1)
    rho2 = (a * a + b * b) / 2
    shape = (1 - falloff * rho2) * (1 + hotspot * np.exp(-((a - 0.1) ** 2 + (b + 0.05) ** 2) / 0.5))
    light = peak * np.nan_to_num(shape)[..., None] * np.asarray(white, np.float64)[None, None, :]
    return np.where(inside[..., None], light, 0.0).astype(np.float32)


def wall_rects(n: int, overlap: float, camera_size: tuple[int, int], *, margin: float = 0.04) -> list[tuple[float, float, float, float]]:
    """``n`` side-by-side rectangles ``(x0, y0, x1, y1)`` in camera pixels sharing ``overlap`` of their width."""
    W, H = camera_size
    usable = W * (1 - 2 * margin)
    w = usable / (n - (n - 1) * overlap)
    return [(W * margin + k * w * (1 - overlap), H * 0.1, W * margin + k * w * (1 - overlap) + w, H * 0.9) for k in range(n)]


def tiled_rects(rows: int, cols: int, camera_size: tuple[int, int], *, spread: float = 0.15,
                seed: int = 0) -> list[tuple[float, float, float, float]]:
    """``rows x cols`` rectangles that all cover most of the camera image, each shifted a little (a table rig)."""
    W, H = camera_size
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(rows * cols):
        dx, dy = rng.uniform(-spread, spread, 2) * (W * 0.1, H * 0.1)
        out.append((W * 0.02 + dx, H * 0.02 + dy, W * 0.98 + dx, H * 0.98 + dy))
    return out


def rectangle_rig(rects: Sequence[tuple[float, float, float, float]], *, camera_size: tuple[int, int] = (320, 240),
                  scale: int = 2, projector_size: tuple[int, int] = (160, 90), peaks: Sequence[float] | None = None,
                  whites: Sequence[Sequence[float]] | None = None, falloff: float = 0.3, hotspot: float = 0.1,
                  black_fraction: float = 0.003, names: Sequence[str] | None = None,
                  surface: tuple[float, float, float, float] | None = None) -> Contributions:
    """A :class:`Contributions` of projectors filling the camera rectangles ``rects``; ``surface``: the camera
    rectangle the surface fills (light falling outside it is lost; default: all of the image)."""
    shape = grid_shape(camera_size, scale)
    W, H = projector_size
    white, black, c2p, sizes = {}, {}, {}, {}
    pts = grid_to_camera(camera_size, shape)
    if surface is None:
        on = np.ones(shape, bool)
    else:
        on = (pts[..., 0] >= surface[0]) & (pts[..., 0] <= surface[2]) & (pts[..., 1] >= surface[1]) & (pts[..., 1] <= surface[3])
    for k, (x0, y0, x1, y1) in enumerate(rects):
        s = names[k] if names else f"p{k}"
        sx, sy = W / (x1 - x0), H / (y1 - y0)
        # camera pixel x0 - 0.5 is projector pixel -0.5 (the frame's edge)
        M = np.array([[sx, 0, -0.5 - sx * (x0 - 0.5)], [0, sy, -0.5 - sy * (y0 - 0.5)], [0, 0, 1]], np.float64)
        u = apply_homography_grid(M, pts)
        white[s] = projector_light(u, (W, H), peak=1.0 if peaks is None else float(peaks[k]),
                                   white=(1, 1, 1) if whites is None else whites[k], falloff=falloff, hotspot=hotspot)
        white[s] = white[s] * on[..., None]
        black[s] = white[s] * np.float32(black_fraction)
        c2p[s] = M
        sizes[s] = (W, H)
    return Contributions(camera_size, scale, white, black, c2p, sizes)
