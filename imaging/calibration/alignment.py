"""The alignment check's numerics: how far each projector's image lands from where its pose says.

The job that runs it on a rig is :mod:`coordinator.calibration.alignment_job`.

Every projector shows, at the same time, a lattice of small dots drawn
*through its current pose* at table sites shared out between the projectors
so that no two dots overlap (the interleaved lattice of
:mod:`imaging.calibration.multiplex`). The camera measures where each dot
really lands; mapped back through the camera's table mapping and the
projector's pose, that is the projector pixel which actually lit the site's
point, and its distance from the pixel that was drawn is the residual
misalignment in projector pixels (what blurs the synthetic aperture).

For projectors with a 3D pose (a mesh), the sites are points of the object's
surface the camera sees (camera rays cast onto the mesh), each given to one of
the projectors that sees it; a dot's landing point is the surface point under
its camera centroid, and the residual is that point's projection through the
pose minus the drawn pixel.

The result gives per projector the RMS, 95th percentile and maximum residual
and where the worst one is, and a heat map (the largest residual of any
projector at each point) saved as ``calibration/alignment.png`` beside
``calibration/alignment.json``: over the table in the content image's frame
for planar poses, over the camera image for 3D poses
(``alignment-mesh.png`` when a rig has both).
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import QhullError, cKDTree

from imaging.calibration import multiplex, planar, threed
from imaging.calibration.errors import CalibrationError
from imaging.calibration.heatmap_figure import colourise

#: Heat-map colour scale: residuals at or above this many projector pixels are full red.
HEATMAP_FULL_SCALE_PX = 1.0


def residuals(table_to_projector: np.ndarray, table_to_camera: np.ndarray, measured: np.ndarray,
              drawn: np.ndarray) -> np.ndarray:
    """Residual misalignment of dots, in projector pixels.

    Parameters
    ----------
    table_to_projector : (3, 3) float64 the projector's current pose, table mm -> projector px
    table_to_camera : (3, 3) float64
    measured : (M, 2) float64 camera centroids of the dots
    drawn : (M, 2) float64 projector centres the dots were drawn at

    Returns
    -------
    (M, 2) float64: pose(where the dot landed) - drawn
    """
    landed = planar.apply_homography(np.linalg.inv(table_to_camera), measured)
    return planar.apply_homography(table_to_projector, landed) - np.asarray(drawn, np.float64)


def heatmap(points: dict[str, np.ndarray], values: dict[str, np.ndarray], *,
            extent: tuple[float, float, float, float], width: int = 600, step: int = 4) -> np.ndarray:
    """Largest residual of any projector at each point of a rectangle, interpolated between the dots.

    Each projector's residuals are interpolated linearly inside its dots' hull
    (Delaunay, ``scipy.interpolate.LinearNDInterpolator``) and extended with
    the nearest dot's value outside it, on a grid ``step`` times coarser than
    the map (the field is smooth at the dot spacing), then upsampled.

    Parameters
    ----------
    points : dict slot -> (M, 2) positions of the measured dots (table mm, or camera px)
    values : dict slot -> (M,) residual magnitudes (projector px)
    extent : (left, right, top, bottom)
        Coordinates of the map's left and right edges and of its top and bottom
        rows, e.g. ``(-600, 600, 300, -300)`` for a 1200 x 600 mm table seen from
        above (row 0 at +y, like the content image), ``(-0.5, W - 0.5, -0.5, H - 0.5)``
        for a camera image.
    width : int
        Width of the map in pixels (height follows the extent's aspect).

    Returns
    -------
    (h, width) float32; NaN where no projector has dots.
    """
    left, right, top, bottom = (float(v) for v in extent)
    height = max(2, int(round(width * abs(bottom - top) / abs(right - left))))
    cw, ch = max(2, width // step), max(2, height // step)
    xs = left + (np.arange(cw) + 0.5) / cw * (right - left)
    ys = top + (np.arange(ch) + 0.5) / ch * (bottom - top)
    q = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    out = np.full(len(q), np.nan, np.float32)
    for slot, pts in points.items():
        v = np.asarray(values[slot], np.float64)
        if len(pts) == 0:
            continue
        grid = v[cKDTree(pts).query(q)[1]]
        if len(pts) >= 3:
            try:
                lin = LinearNDInterpolator(pts, v)(q)
                grid = np.where(np.isfinite(lin), lin, grid)
            except QhullError:   # collinear dots: nearest values only
                pass
        out = np.fmax(out, grid.astype(np.float32))
    coarse = out.reshape(ch, cw)
    up = cv2.resize(np.nan_to_num(coarse, nan=0.0), (width, height), interpolation=cv2.INTER_LINEAR)
    mask = cv2.resize(np.isfinite(coarse).astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
    return np.where(mask, up, np.nan).astype(np.float32)


def plan_surface_lattice(projectors: dict[str, threed.Pinhole], camera: threed.Pinhole, camera_points: np.ndarray,
                         usable: np.ndarray, projector_points: dict[str, np.ndarray], *, rounds: int = 2,
                         dot_px: int = 3, spacing_px: float | None = None, visible_mm: float = 3.0) -> multiplex.Lattice:
    """Share sites on a 3D surface out between projectors that see them (the alignment pattern for 3D poses).

    Sites are camera pixels on a lattice over the surface the camera sees
    (``usable``); a site belongs, round by round, to one of the projectors whose
    own view of the surface reaches the same point (within ``visible_mm``:
    not hidden by the object), which draws a dot where its pose puts it.

    Parameters
    ----------
    projectors : dict slot -> Pinhole from each projector's current 3x4 pose
    camera : Pinhole of the camera
    camera_points : (H, W, 3) float64 world point per camera pixel (NaN where nothing)
    usable : (H, W) bool camera pixels to put sites on (the object, away from silhouettes)
    projector_points : dict slot -> (h, w, 3) world point each projector pixel lights (NaN: nothing)
    """
    slots = tuple(projectors)
    W, H = camera.size
    # how many camera pixels a projector pixel spans on the surface (focal length over distance, both devices)
    probe = camera_points[usable]
    if len(probe) == 0:
        raise ValueError("the camera sees none of the surface")
    probe = probe[:: max(1, len(probe) // 2000)]
    cam_scale = camera.K[0, 0] / np.maximum(camera.project(probe)[1], 1e-6)
    ratios = [np.median(cam_scale / (d.K[0, 0] / np.maximum(d.project(probe)[1], 1e-6))) for d in projectors.values()]
    dot_cam = dot_px * float(max(ratios))
    radius = int(np.ceil(dot_cam / 2 + 2.5))
    if spacing_px is None:
        spacing_px = max(12.0, 2 * radius + 4.0)
    edge = radius + 3
    # a dot's whole footprint must sit on usable surface (no silhouette or depth step under it)
    usable = ndimage.binary_erosion(usable, iterations=radius)
    n = len(slots)
    q = multiplex._lattice_multiplier(n)
    na, nb = int((W - 2 * edge) // spacing_px) + 1, int((H - 2 * edge) // spacing_px) + 1
    a, b = np.meshgrid(np.arange(na), np.arange(nb), indexing="xy")
    a, b = a.ravel(), b.ravel()
    shifts = [(0.0, 0.0), (0.5, 0.5), (0.5, 0.0), (0.0, 0.5)]
    lattice = multiplex.Lattice(slots, {s: projectors[s].size for s in slots}, dot_px, float("nan"), float(spacing_px), radius)
    for r in range(rounds):
        sx, sy = shifts[r % 4]
        px = np.rint(edge + (a + sx) * spacing_px).astype(np.int64)
        py = np.rint(edge + (b + sy) * spacing_px).astype(np.int64)
        ok = (px < W - edge) & (py < H - edge)
        px, py, aa, bb = px[ok], py[ok], a[ok], b[ok]
        on = usable[py, px]
        px, py, aa, bb = px[on], py[on], aa[on], bb[on]
        X = camera_points[py, px]
        # which projectors see each site, and where they would draw it
        sees = np.zeros((len(X), n), bool)
        centres = np.zeros((len(X), n, 2))
        landed = np.full((len(X), n, 3), np.nan)
        for i, s in enumerate(slots):
            dev = projectors[s]
            w, h = dev.size
            c = multiplex.snap_centre(dev.project(X)[0], dot_px)
            half = (dot_px - 1) / 2 + 1
            inside = np.isfinite(c).all(axis=1) & (c[:, 0] >= half) & (c[:, 1] >= half) & (c[:, 0] <= w - 1 - half) & (c[:, 1] <= h - 1 - half)
            ix = np.clip(np.rint(np.nan_to_num(c[:, 0])).astype(np.int64), 0, w - 1)
            iy = np.clip(np.rint(np.nan_to_num(c[:, 1])).astype(np.int64), 0, h - 1)
            hit = projector_points[s][iy, ix]
            # the snapped pixel lights a point up to a pixel's footprint away from the site; farther means hidden
            tol = visible_mm + 1.5 * np.abs(dev.project(X)[1]) / dev.K[0, 0]
            near = inside & np.isfinite(hit).all(axis=1) & (np.linalg.norm(np.nan_to_num(hit, nan=1e9) - X, axis=1) < tol)
            sees[:, i] = near
            centres[:, i] = c
            landed[:, i] = hit
        count = sees.sum(axis=1)
        pick = np.full(len(X), -1)
        for k in np.flatnonzero(count):
            vis = np.flatnonzero(sees[k])
            pick[k] = vis[(aa[k] + q * bb[k] + r * (n // max(rounds, 1) + 1)) % len(vis)]
        rc, re, rs = {}, {}, {}
        for i, s in enumerate(slots):
            sel = pick == i
            e, _ = camera.project(landed[sel, i])
            good = np.isfinite(e).all(axis=1) & (e[:, 0] >= edge) & (e[:, 1] >= edge) & (e[:, 0] < W - edge) & (e[:, 1] < H - edge)
            rc[s], re[s], rs[s] = centres[sel, i][good], e[good], landed[sel, i][good]
        lattice.rounds.append(multiplex.LatticeRound(rc, re, rs))
    return lattice


def sample_points(points: np.ndarray, usable: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear world points (M, 3) at sub-pixel camera positions ``xy`` (M, 2); NaN unless all four
    neighbouring pixels are ``usable``."""
    H, W = usable.shape
    x, y = xy[:, 0], xy[:, 1]
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < W - 1) & (y0 < H - 1)
    x0, y0 = np.where(ok, x0, 0), np.where(ok, y0, 0)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    for dy in (0, 1):
        for dx in (0, 1):
            ok &= usable[y0 + dy, x0 + dx]
    p = (points[y0, x0] * (1 - fx) * (1 - fy) + points[y0, x0 + 1] * fx * (1 - fy)
         + points[y0 + 1, x0] * (1 - fx) * fy + points[y0 + 1, x0 + 1] * fx * fy)
    p[~ok] = np.nan
    return p


def render_heatmap(values: np.ndarray, *, full_scale: float = HEATMAP_FULL_SCALE_PX) -> bytes:
    """PNG bytes of a heat map: 0 px dark blue ... ``full_scale`` px and more red (OpenCV's TURBO map), NaN grey."""
    ok, buf = cv2.imencode(".png", colourise(values, full_scale))
    if not ok:  # pragma: no cover
        raise CalibrationError("cannot encode the heat map")
    return buf.tobytes()
