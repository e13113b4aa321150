"""The coverage heat map as a picture: the object seen from one or more viewpoints, each surface
point coloured by how many projectors reach it, shaded by its orientation so the shape reads,
with a colour bar of the counts (like the paper's coverage figure).

Viewpoints are virtual cameras: an azimuth and elevation around the mesh's centre
(:func:`orbit_camera`), or a calibrated camera of the rig. Drawn with OpenCV alone; the layout
(where each panel and the colour bar sit, figure pixels) is returned beside the PNG so tests
and the console can find the parts.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
from scipy import ndimage

from imaging.calibration.heatmap_figure import FONT, INK, SCALE, put_text
from imaging.calibration.threed import Pinhole
from coordinator.coverage import Coverage
from coordinator.coverage_gl import CoverageRaster

__all__ = ["orbit_camera", "count_colours", "coverage_picture", "PANEL_SIZE", "NOT_REACHED_BGR"]

PANEL_SIZE = (480, 480)
#: surface that no projector reaches
NOT_REACHED_BGR = (60, 60, 60)
BACKGROUND_BGR = (255, 255, 255)
MARGINS = (16, 34, 96, 30)      # left, top, right, bottom (figure px)
GAP = 12
BAR_GAP, BAR_WIDTH = 16, 18


def orbit_camera(vertices: np.ndarray, azimuth_deg: float, elevation_deg: float, *,
                 size: tuple[int, int] = PANEL_SIZE, margin: float = 1.08) -> Pinhole:
    """A pinhole looking at the centre of the mesh's bounding box, framing its bounding sphere.

    ``azimuth_deg`` turns about the world's vertical (+z) axis: 0 puts the camera on the +y side
    looking towards -y (the front of an object that faces +y, like the builtin bust), 90 on the
    +x side, 180 behind. ``elevation_deg`` raises it above the horizontal (90: straight down).
    Image up is world +z where that is defined (else world +y turned by the azimuth).
    """
    v = np.asarray(vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-3)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    distance = 3.0 * radius
    eye = centre + distance * direction
    z = -direction
    up = np.array([0.0, 0.0, 1.0])
    if abs(float(z @ up)) > 0.999:
        up = np.array([-math.sin(az), -math.cos(az), 0.0])
    x = np.cross(z, up)       # image x to the right, image y down (= -up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    w, h = size
    half = math.asin(min(1.0, margin * radius / distance))
    f = (min(w, h) / 2) / math.tan(half)
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    return Pinhole(K, R, -R @ eye, size)


def count_colours(n_max: int) -> np.ndarray:
    """(n_max + 1, 3) uint8 BGR: the colour of each count 0..n_max (0: :data:`NOT_REACHED_BGR`;
    1..n_max: OpenCV's TURBO from dark blue to red)."""
    n_max = max(int(n_max), 1)
    levels = np.round(np.linspace(0, 255, n_max)).astype(np.uint8)
    turbo = cv2.applyColorMap(levels.reshape(-1, 1), cv2.COLORMAP_TURBO).reshape(-1, 3)
    return np.vstack([np.array(NOT_REACHED_BGR, np.uint8)[None], turbo])


def _filled(count: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The count with every texel off the surface given its nearest surface texel's (so a view's
    nearest-texel lookup at a triangle's edge never lands on an empty texel)."""
    if mask.all() or not mask.any():
        return count
    _, (iy, ix) = ndimage.distance_transform_edt(~mask, return_indices=True)
    return count[iy, ix]


def render_panel(cov: Coverage, raster: CoverageRaster, device: Pinhole, n_max: int) -> tuple[np.ndarray, np.ndarray]:
    """(h, w, 3) uint8 BGR of the mesh seen by ``device``, coloured by count and shaded, and the
    (h, w) bool of pixels that see it."""
    uv, nrm, hit = raster.view(device)
    count = _filled(cov.count, cov.mask)
    rc = cov.lookup(uv[hit])
    colours = count_colours(n_max)
    img = np.full((*hit.shape, 3), BACKGROUND_BGR, np.uint8)
    c = colours[np.clip(count[rc[:, 0], rc[:, 1]], 0, n_max)].astype(np.float64)
    n = nrm[hit].astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    ys, xs = np.nonzero(hit)
    rays = np.column_stack([xs, ys, np.ones(len(xs))]) @ np.linalg.inv(device.K).T @ device.R   # world directions
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    lambert = np.abs(np.einsum("ij,ij->i", n, rays))
    img[hit] = np.clip(c * (0.45 + 0.55 * lambert)[:, None], 0, 255).astype(np.uint8)
    return img, hit


def coverage_picture(cov: Coverage, raster: CoverageRaster, views: list[tuple[str, Pinhole]], *,
                     title: str | None = None) -> tuple[bytes, dict]:
    """PNG bytes of the panels side by side (one per view, its label above it) and the colour
    bar of the counts 0..S, and the layout.

    Returns
    -------
    (png, layout): layout has ``size`` [W, H], ``panels`` (label -> [x0, y0, x1, y1], figure px,
    exclusive ends), ``colorbar`` [x0, y0, x1, y1] (its top row is count S, its bottom row
    count 0, in S + 1 equal bands) and ``max_count`` S.
    """
    if not views:
        raise ValueError("need at least one view")
    n_max = len(cov.slots)
    panels = [(label, *render_panel(cov, raster, dev, n_max)) for label, dev in views]
    ml, mt, mr, mb = MARGINS
    ph = max(p[1].shape[0] for p in panels)
    pw_total = sum(p[1].shape[1] for p in panels) + GAP * (len(panels) - 1)
    fig = np.full((mt + ph + mb, ml + pw_total + mr, 3), 255, np.uint8)
    boxes = {}
    x = ml
    for label, img, _ in panels:
        h, w = img.shape[:2]
        fig[mt:mt + h, x:x + w] = img
        cv2.rectangle(fig, (x - 1, mt - 1), (x + w, mt + h), (200, 200, 200), 1)
        put_text(fig, label, (x + w / 2, mt - 10), align="centre")
        boxes[label] = [x, mt, x + w, mt + h]
        x += w + GAP
    put_text(fig, title or f"projectors reaching each point of the surface ({n_max} in the rig)",
          (ml + pw_total / 2, mt + ph + mb / 2), align="centre")
    # the colour bar: S + 1 bands, count S at the top
    bx0 = ml + pw_total + BAR_GAP
    bx1 = bx0 + BAR_WIDTH
    colours = count_colours(n_max)
    band = (np.arange(ph) * (n_max + 1)) // ph            # 0 at the top row
    fig[mt:mt + ph, bx0:bx1] = colours[n_max - band][:, None, :]
    cv2.rectangle(fig, (bx0 - 1, mt - 1), (bx1, mt + ph), INK, 1)
    step = max(1, math.ceil((n_max + 1) / 12))
    for k in range(n_max + 1):
        if k % step and k != n_max:
            continue
        py = mt + (n_max - k + 0.5) * ph / (n_max + 1)
        cv2.line(fig, (bx1, int(py)), (bx1 + 4, int(py)), INK, 1)
        put_text(fig, str(k), (bx1 + 7, py))
    (tw, _), _ = cv2.getTextSize("projectors", FONT, SCALE, 1)
    put_text(fig, "projectors", (bx0 + BAR_WIDTH / 2 + max(0, tw / 2 - BAR_WIDTH), mt - 10), align="centre")
    ok, buf = cv2.imencode(".png", fig)
    if not ok:  # pragma: no cover
        raise ValueError("cannot encode the coverage picture")
    layout = {"size": [int(fig.shape[1]), int(fig.shape[0])], "panels": boxes, "colorbar": [bx0, mt, bx1, mt + ph],
              "max_count": n_max}
    return buf.tobytes(), layout
