"""`bench uniformity --only bust --diagnose DIR`: where the mesh blend's model of each projector's light and the
room disagree, by incidence angle, and what that costs the blended light; a picture and a JSON document.

After the bust part's blend, the room renders each projector alone (no noise), showing what its node shows: full
white on the pixels it draws (those whose centre sees the mesh), then its blend maps. Against it:

* **the light** (``by_angle``): the job's stored contribution of each projector (its model after the flat white's
  matching) over the room's, on the blend's camera grid, pooled over projectors in bins of the angle between the
  surface's normal and the ray to the projector. ``ratio`` is the raw ratio's median; ``partition`` is the ratio
  over its light-weighted mean among the projectors reaching the same point (the flat white's matching makes the
  sum right, so only how the sum is split between projectors can make the blend wrong): its median, p5 and p95;
* **the blended light** (``blended``): p99 of the light over the target (block means as the bust part measures
  them) as the model predicts it (``predicted``) and as the room renders it without noise (``rendered``).

The picture (``bust_diagnosis.png``): rendered and predicted blended light over the target, then each
projector's modelled light over the room's; grey is 1, red brighter, blue darker, full colour at +-5 %.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bench.uniformity_measure import nonuniformity, resize_to
from coordinator.blend_store import load_blend, load_contributions
from coordinator.rig import Rig
from imaging.blending.contributions import Contributions
from imaging.blending.metrics import to_grid
from imaging.blending.predict import predict
from imaging.blending.solve import compute_blend
from protos.spaces import blend_sample
from shadowless.room_driver import RoomDriver
from sim.room import Room

__all__ = ["diagnose", "ANGLE_BINS"]

#: incidence angle bins, degrees from the surface's normal
ANGLE_BINS = (0, 40, 55, 65, 70, 75, 80, 90)
#: a projector's light below this share of its brightest is left out of the ratios (its footprint's fringe)
DIM = 0.05


def _incidence(room: Room, slot: str, shape: tuple[int, int]) -> np.ndarray:
    """``(h, w)`` degrees between the room's surface normal and the ray to ``slot``, on the grid (NaN off it)."""
    view = room.view(0)
    x0, y0, x1, y1 = view.roi
    W, H = room.camera_size(0)
    pts = np.full((H, W, 3), np.nan)
    nrm = np.full((H, W, 3), np.nan)
    pts[y0:y1, x0:x1] = view.points
    nrm[y0:y1, x0:x1] = view.normals
    centre = room.truth.projector(slot).center
    ray = centre - pts
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.einsum("...i,...i->...", nrm, ray) / np.linalg.norm(ray, axis=-1)
    deg = np.degrees(np.arccos(np.clip(np.nan_to_num(cos, nan=-1.0), -1.0, 1.0)))
    return to_grid(np.where(np.isfinite(cos), deg, 180.0).astype(np.float32), shape)


def _colour(ratio: np.ndarray, mask: np.ndarray, span: float = 0.05) -> np.ndarray:
    """``(h, w, 3) uint8`` BGR: grey at 1, red above, blue below, full at ``1 +- span``; black off ``mask``."""
    v = np.clip((np.nan_to_num(ratio, nan=1.0) - 1.0) / span, -1.0, 1.0)
    img = np.empty((*ratio.shape, 3), np.uint8)
    img[..., 2] = (128 + 127 * v).astype(np.uint8)
    img[..., 1] = (128 - 127 * np.abs(v)).astype(np.uint8)
    img[..., 0] = (128 - 127 * v).astype(np.uint8)
    img[~mask] = 0
    return img


def diagnose(room: Room, rig_path: Path, mask: np.ndarray, out_dir: Path) -> dict:
    """The diagnosis of the blend stored in ``rig_path`` over camera pixels ``mask`` ((H, W) bool, the bust
    part's); writes ``out_dir / "bust_diagnosis.png"`` and returns the figures (see the module docstring)."""
    rig = Rig(rig_path, read_only=True)
    driver = RoomDriver(room, rig)
    c = Contributions.from_arrays(*load_contributions(rig.path))
    blend = load_blend(rig.path)
    shape, cam = c.shape, c.camera_size
    grid_mask = to_grid(mask.astype(np.float32), shape) > 0.99
    model, truth, angle = [], [], []
    rendered = np.zeros((*room.camera_size(0)[::-1], 3), np.float32)
    for s in c.slots:
        W, H = c.projector_size[s]
        drawn = driver.mesh_view(s).on_mesh[..., None].astype(np.float32)
        truth.append(to_grid(room.render_projector(s, np.repeat(drawn, 3, axis=2)), shape).mean(axis=-1))
        model.append(np.asarray(c.white[s]).mean(axis=-1))
        angle.append(_incidence(room, s, shape))
        a, b = blend_sample(blend.maps[s].alpha, blend.maps[s].beta, (W, H))
        rendered += room.render_projector(s, (np.clip(a + b[..., None], 0.0, 1.0) * drawn).astype(np.float32))
    model, truth, angle = np.stack(model), np.stack(truth), np.stack(angle)
    lit = (truth > DIM * truth.max(axis=(1, 2), keepdims=True)) & (model > 0) & grid_mask[None]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(lit, model / truth, np.nan)
        w = np.where(lit, truth, 0.0)
        mean = np.nansum(np.nan_to_num(ratio) * w, axis=0) / np.maximum(w.sum(axis=0), 1e-12)
        partition = ratio / mean[None]
    by_angle = []
    for lo, hi in zip(ANGLE_BINS[:-1], ANGLE_BINS[1:]):
        k = lit & (angle >= lo) & (angle < hi)
        if k.sum() < 10:
            continue
        p = partition[k]
        by_angle.append({"degrees": [lo, hi], "points": int(k.sum()), "ratio": round(float(np.median(ratio[k])), 4),
                         "partition": [round(float(v), 4) for v in np.percentile(p, [50, 5, 95])]})
    # the blended light: as predicted and as rendered, against the blend's target
    sol = compute_blend(c, headroom=None, map_scale=int(blend.info.get("map_scale") or 4))
    target = resize_to(sol.target + sol.black_target[..., None] * sol.white_point, cam)
    black = resize_to(sum(np.asarray(c.black[s]) for s in c.slots), cam)
    scored = mask & resize_to(sol.covered, cam)
    predicted = resize_to(predict(c, {s: (m.alpha, m.beta) for s, m in blend.maps.items()}, 1.0), cam)
    figures = {"by_angle": by_angle,
               "blended": {"predicted": round(nonuniformity(predicted, target, scored, block=4), 5),
                           "rendered": round(nonuniformity(rendered + black, target, scored, block=4), 5)}}
    # the picture
    ys, xs = np.nonzero(mask)
    crop = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    tl = (target @ np.array([0.2126, 0.7152, 0.0722])).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        def seen(img: np.ndarray) -> np.ndarray:    # 4 x 4 means over the scored pixels, as measured
            r = (img @ np.array([0.2126, 0.7152, 0.0722])) / np.where(tl > 0, tl, 1.0)
            num = cv2.blur(np.where(scored, r, 0.0), (4, 4))
            den = cv2.blur(scored.astype(np.float64), (4, 4))
            r = np.where(den > 0, num / np.maximum(den, 1e-12), np.nan)
            return r / np.nanmedian(r[scored])
        panels = [_colour(seen(rendered + black), scored)[crop], _colour(seen(predicted), scored)[crop]]
        for k in range(len(c.slots)):
            r = resize_to(ratio[k], cam)
            panels.append(_colour(r / np.nanmedian(r[mask]) if np.isfinite(r[mask]).any() else r,
                                  mask & np.isfinite(r))[crop])
    while len(panels) % 4:
        panels.append(np.zeros_like(panels[0]))
    rows = [np.concatenate(panels[i:i + 4], axis=1) for i in range(0, len(panels), 4)]
    out_dir.mkdir(parents=True, exist_ok=True)
    picture = out_dir / "bust_diagnosis.png"
    if not cv2.imwrite(str(picture), np.concatenate(rows, axis=0)):
        raise RuntimeError(f"could not write {picture}")
    figures["picture"] = picture.name
    return figures
