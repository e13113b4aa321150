"""Reading a blob capture on a mesh: each blob's lamp light, the surface's shading taken out pixel by pixel.

On a mesh the light of one blob changes across it with the surface (the cosine of the light's incidence
and the distance, :mod:`imaging.blending.mesh`), and a disc drawn in the projector's pixels lands on a
slanted surface as a narrow ellipse, which a round window in the camera overshoots. So a blob is read on
a grid over the camera image (``xy``, ``shading``: :func:`imaging.blending.mesh.mesh_placement` at that
grid) from the grid pixels around its site that the blob's own projector lights **inside the disc**
(their projector pixel within ``inner`` of the disc's radius of its centre, clear of its blurred rim, and the
projector pixels around it all inside the disc as it is drawn: :func:`_whole_pixels`),
each divided by its shading: what remains is the lamp's light (smooth in the projector's pixels). The
value is the per-channel trimmed mean (the middle 80 %) of those ratios;
:func:`imaging.blending.fit.fit_contributions` then takes the samples as they are (``shaded=True``).
"""
from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np

from imaging.blending.sample_plan import SamplePlan
from imaging.blending.samples import Samples

__all__ = ["read_capture_shaded", "match_flat_white", "MIN_PIXELS"]

#: fewer grid pixels than this inside a disc and its reading is dropped
MIN_PIXELS = 3


def read_capture_shaded(capture: np.ndarray, black: np.ndarray, plan: SamplePlan, k: int, samples: Samples,
                        xy: Mapping[str, np.ndarray], shading: Mapping[str, np.ndarray], *,
                        inner: float = 0.7) -> int:
    """Add capture ``k``'s blob readings (lamp light, shading divided out) to ``samples``; how many it read.

    Parameters
    ----------
    capture, black : (H, W, 3) float32, full camera resolution
    xy : slot -> (h, w, 2) float32, projector pixels of each pixel of a grid over the camera image (NaN
        where the slot does not light it)
    shading : slot -> (h, w) float32 on the same grid
    inner : the part of each disc's radius read
    """
    any_xy = next(iter(xy.values()))
    h, w = any_xy.shape[:2]
    H, W = capture.shape[:2]
    img = np.asarray(capture, np.float32) - np.asarray(black, np.float32)
    if (h, w) != (H, W):
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    sx, sy = w / W, h / H
    reach = plan.radius * max(sx, sy) * 1.5 + 1.0
    n = int(np.ceil(reach))
    oy, ox = np.mgrid[-n:n + 1, -n:n + 1]
    owner = plan.owner[k]
    read = 0
    for j in np.flatnonzero(owner >= 0):
        s = plan.slots[owner[j]]
        cx = (plan.sites[j, 0] + 0.5) * sx - 0.5
        cy = (plan.sites[j, 1] + 0.5) * sy - 0.5
        xs = np.rint(cx).astype(np.int64) + ox
        ys = np.rint(cy).astype(np.int64) + oy
        ok = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
        xs, ys = xs[ok], ys[ok]
        u = xy[s][ys, xs]
        g = shading[s][ys, xs]
        centre = plan.projector_xy[s][j]
        rad = inner * float(plan.projector_radius[s][j])
        full = _whole_pixels(u, centre, float(plan.projector_radius[s][j]))
        with np.errstate(invalid="ignore"):
            inside = full & (np.hypot(u[:, 0] - centre[0], u[:, 1] - centre[1]) <= rad) & (g > 0)
        if inside.sum() < MIN_PIXELS:
            continue
        ratio = np.sort(img[ys[inside], xs[inside]] / g[inside][:, None], axis=0)
        cut = int(len(ratio) * 0.1)
        samples.add(s, j, ratio[cut:len(ratio) - cut].mean(axis=0))
        read += 1
    return read


#: a point read from a disc lies this far (projector pixels) inside the pixels the disc draws
EDGE_MARGIN = 0.3


def _whole_pixels(u: np.ndarray, centre: np.ndarray, radius: float, *, margin: float = EDGE_MARGIN) -> np.ndarray:
    """``(n,) bool``: the points ``u`` ((n, 2) projector pixels, NaN allowed) whose light comes from the disc's
    pixels alone: the pixels holding ``u`` and the points ``margin`` around it on both axes all have their centres
    within ``radius`` of ``centre``, as :func:`imaging.blending.sample_plan.draw_discs` draws it (a node shows a
    pixel as a square of one value, which the lens spreads a little). A disc that a projector grazes spans a
    pixel or two across in the projector's pixels, and a point near its drawn rim reads part of it: a reading
    taken there would make the grazed surface look darker than it is."""
    ok = np.isfinite(u).all(axis=1)
    v = np.where(ok[:, None], u, 0.0)
    full = ok.copy()
    for dx in (-margin, margin):
        for dy in (-margin, margin):
            px = np.floor(v[:, 0] + dx + 0.5)
            py = np.floor(v[:, 1] + dy + 0.5)
            full &= (px - centre[0]) ** 2 + (py - centre[1]) ** 2 <= radius * radius
    return full


def match_flat_white(white: Mapping[str, np.ndarray], flat: np.ndarray, surface: np.ndarray, *,
                     limits: tuple[float, float] = (0.5, 2.0)) -> dict[str, np.ndarray]:
    """Each projector's modelled light scaled, point by point, so that their sum is the captured flat white.

    The blobs tell the projectors' shares apart but read a curved surface only so well; the flat white (every
    projector at full white, the blend's ``before`` capture less the black one) measures their sum at every
    grid point exactly, blur at shadow edges included. Where the model and the capture disagree the lights
    are scaled together by ``k = flat / sum(white)`` per channel (within ``limits``; 1 off the ``surface`` and
    where either is dark).

    Parameters
    ----------
    white : slot -> (h, w, 3) float32 modelled light above black at full white, on the grid
    flat : (h, w, 3) float32 the flat white above black on the same grid
    surface : (h, w) bool
    """
    slots = list(white)
    total = np.zeros_like(np.asarray(white[slots[0]], np.float64))
    for s in slots:
        total += white[s]
    f = np.asarray(flat, np.float64)
    ok = np.asarray(surface, bool)[..., None] & (total > 1e-6 * max(float(total.max()), 1e-30)) & (f > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(ok, f / np.where(ok, total, 1.0), 1.0)
    k = np.clip(k, *limits).astype(np.float32)
    return {s: (np.asarray(white[s], np.float32) * k).astype(np.float32) for s in slots}
