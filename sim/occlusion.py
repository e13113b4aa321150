"""Occluders (hands, boxes) in a precomputed view: what they hide, and how they are lit.

Occluders only change visibility. :func:`occlude` finds, for one
:class:`~sim.precompute.View` and one set of occluder primitives:

* the camera pixels that see an occluder (exact ray tests over the primitives'
  projected bounding boxes), with the occluder's surface point and normal;
* per projector, the camera pixels whose static surface point has its line of
  sight to the projector crossed by an occluder (exact ray tests, culled through
  the tile index of the projector image that :class:`~sim.precompute.Plan` keeps).

:func:`occluder_samples` then samples one projector on the occluder surface the
camera sees (lit, and shadowed, by the same projectors, with the occluder's albedo),
the same way :func:`sim.precompute.build_plan` samples the static surface.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from sim.geometry import Pinhole
from sim.occluders import Primitive
from sim.optics import blend_levels
from sim.precompute import (
    CAMERA_SIGMA_LIMIT,
    MeshMaps,
    Plan,
    View,
    blend_coefficients,
    device_geometry,
    footprint_area,
)
from sim.scene import ProjectorSpec

__all__ = [
    "OccluderSamples",
    "DynamicState",
    "occlude",
    "occluder_samples",
    "cone_candidates",
    "projected_bboxes",
    "projected_bbox",
    "pixel_box",
    "in_boxes",
]

#: Offset (mm) along the normal before testing an occluder point's own shadows.
_SELF_OFFSET = 0.5


@dataclass(eq=False)
class OccluderSamples:
    """Sampling of one projector at a flat list of points (camera pixels that see an occluder)."""

    mapx: np.ndarray  # (1, n) float32
    mapy: np.ndarray
    weight: np.ndarray  # (n,) float32
    lo: np.ndarray  # (n,) int8
    alpha: np.ndarray  # (n,) float32
    coef: dict[int, np.ndarray]  # level -> (n,) float32


@dataclass(eq=False)
class DynamicState:
    """Occluder state for one view.

    ``key`` identifies the occluder state it was computed for; ``samples`` caches
    :func:`occluder_samples` per slot.
    """

    key: object
    primitives: list[Primitive]
    blocked: dict[str, np.ndarray]  # slot -> flat ROI indices whose sight line is blocked
    hand_index: np.ndarray  # (m,) flat image indices of pixels that see an occluder
    hand_roi: np.ndarray  # flat ROI indices among them
    hand_points: np.ndarray  # (m, 3)
    hand_normals: np.ndarray  # (m, 3)
    samples: dict[str, OccluderSamples] = field(default_factory=dict)


def occlude(view: View, prims: list[Primitive], key, camera: Pinhole, projectors: Mapping[str, Pinhole]) -> DynamicState:
    """What the primitives ``prims`` hide in ``view``.

    Parameters
    ----------
    view : View
        With its plans.
    prims : list of Primitive
    key : object
        Stored as :attr:`DynamicState.key`.
    camera : Pinhole
        The view's camera.
    projectors : mapping
        slot -> Pinhole of every slot in ``view.plans``.
    """
    cam = camera
    W, H = cam.size
    x0, y0, x1, y1 = view.roi
    wr = x1 - x0
    empty = np.zeros(0, np.int64)
    if not prims:
        return DynamicState(key, prims, {}, empty, empty, np.zeros((0, 3)), np.zeros((0, 3)))
    # 1. Camera pixels that see an occluder: rays over the projected boxes of the primitives.
    mask = np.zeros((H, W), bool)
    boxes = [projected_bboxes(cam, prim.cull_spheres()) for prim in prims]
    for prim_boxes in boxes:
        for bb in prim_boxes:
            if bb is None:
                mask[:] = True
                continue
            bx0, by0, bx1, by1 = pixel_box(bb, W, H)
            mask[by0:by1, bx0:bx1] = True
    idx = np.flatnonzero(mask)
    xs, ys = idx % W, idx // W
    dirs = cam.rays(np.column_stack([xs, ys]).astype(np.float64))
    best = np.full(len(idx), np.inf)
    for prim, prim_boxes in zip(prims, boxes):
        sel = np.flatnonzero(in_boxes(xs, ys, prim_boxes))
        if len(sel) == 0:
            continue
        d = dirs[sel]
        t_in, t_out = prim.interval_from(cam.center, d[:, 0], d[:, 1], d[:, 2])
        ok = (t_in > 0) & (t_in <= t_out) & (t_in < best[sel])
        best[sel[ok]] = t_in[ok]
    static = np.full(len(idx), np.inf)
    in_roi = (xs >= x0) & (xs < x1) & (ys >= y0) & (ys < y1)
    static[in_roi] = view.distance[ys[in_roi] - y0, xs[in_roi] - x0]
    seen = np.isfinite(best) & (best < static)
    hand_index = idx[seen]
    hit_dirs = dirs[seen]
    hand_points = cam.center + best[seen, None] * hit_dirs
    hand_normals = np.zeros_like(hand_points)
    bestn = np.full(len(hand_points), np.inf)
    for prim in prims:  # normals from the full test on the few hit pixels
        t_in, _, n = prim.interval(np.broadcast_to(cam.center, hit_dirs.shape).copy(), hit_dirs)
        better = (t_in > 0) & (t_in < bestn)
        bestn = np.where(better, t_in, bestn)
        hand_normals = np.where(better[:, None], n, hand_normals)
    r = in_roi[seen]
    hand_roi = (ys[seen][r] - y0) * wr + (xs[seen][r] - x0)
    # 2. Per projector: static surface points whose line of sight to it crosses an occluder.
    flat_points = view.points.reshape(-1, 3)
    n_roi = view.shape[0] * view.shape[1]
    blocked: dict[str, np.ndarray] = {}
    for slot, plan in view.plans.items():
        dev = projectors[slot]
        hit_mask = np.zeros(n_roi, bool)
        for prim in prims:
            cand = cone_candidates(plan, dev, prim.cull_spheres())
            if len(cand) == 0:
                continue
            roi_idx = plan.lit[cand]
            vec = flat_points[roi_idx] - dev.center
            dist = np.sqrt(np.einsum("ij,ij->i", vec, vec))
            vec /= dist[:, None]
            t_in, t_out = prim.interval_from(dev.center, vec[:, 0], vec[:, 1], vec[:, 2])
            hit_mask[roi_idx[(t_in < dist - 1e-6) & (t_out > 1e-6)]] = True
        blocked[slot] = np.flatnonzero(hit_mask)
    return DynamicState(key, prims, blocked, hand_index, hand_roi, hand_points, hand_normals)


def occluder_samples(
    view: View,
    dyn: DynamicState,
    spec: ProjectorSpec,
    camera: Pinhole,
    *,
    hand_albedo: float,
    mesh_maps: MeshMaps | None = None,
) -> OccluderSamples:
    """How projector ``spec`` lights the occluder surface the camera sees (cached in ``dyn.samples``).

    Parameters
    ----------
    view : View
        The view ``dyn`` was computed for; its plan for ``spec.slot`` gives the field's layout and blur.
    camera : Pinhole
        The view's camera (the footprint part of the blur).
    hand_albedo : float
        Albedo of the occluders.
    mesh_maps : MeshMaps, optional
        Given, the mesh's shadows on the occluders are applied.
    """
    slot = spec.slot
    hs = dyn.samples.get(slot)
    if hs is not None:
        return hs
    dev = spec.pinhole
    plan = view.plans[slot]
    cam = camera
    pts, nrm = dyn.hand_points, dyn.hand_normals
    g = device_geometry(dev, pts, nrm, falloff=spec.falloff)
    u, v, depth, e = g["u"], g["v"], g["depth"], g["irradiance"]
    w, h = dev.size
    lit = (depth > 0) & (e > 0) & (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
    if lit.any():
        idx = np.flatnonzero(lit)
        start = pts[idx] + _SELF_OFFSET * nrm[idx]
        vec = start - dev.center
        dist = np.linalg.norm(vec, axis=1)
        vec /= dist[:, None]
        blocked = np.zeros(len(idx), bool)
        for prim in dyn.primitives:
            # Only points whose projector pixel lies in the primitive's projected boxes can be hidden by it.
            sel = np.flatnonzero(in_boxes(u[idx], v[idx], projected_bboxes(dev, prim.cull_spheres())))
            if len(sel) == 0:
                continue
            d = vec[sel]
            t_in, t_out = prim.interval_from(dev.center, d[:, 0], d[:, 1], d[:, 2])
            blocked[sel] |= (t_in < dist[sel] - 1e-6) & (t_out > 1e-6)
        lit[idx[blocked]] = False
    if mesh_maps is not None and lit.any():
        idx = np.flatnonzero(lit)
        lit[idx[mesh_maps.shadowed(slot, pts[idx], nrm[idx])]] = False
    # Blur as in the static plan (the field is shared): clamp into its levels.
    cam_area = footprint_area(cam, pts, nrm)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isfinite(cam_area) & np.isfinite(g["area"]), cam_area / g["area"], 0.0)
    d = g["distance"]
    sigma = np.sqrt((spec.aperture * dev.K[0, 0] * np.abs(d - spec.focus) / (4.0 * spec.focus * np.maximum(d, 1e-9))) ** 2 + np.minimum(ratio / 12.0, CAMERA_SIGMA_LIMIT**2))
    if len(plan.sigmas) == 1:
        lo = np.zeros(len(pts), np.int32)
        alpha = np.zeros(len(pts), np.float32)
    else:
        lo, alpha = blend_levels(sigma, plan.sigmas)
    s, pad = plan.upsample, plan.pad
    mapx = np.where(lit, s * (u + 0.5) - 0.5 + pad, -10.0).astype(np.float32)[None, :]
    mapy = np.where(lit, s * (v + 0.5) - 0.5 + pad, -10.0).astype(np.float32)[None, :]
    light = hand_albedo * spec.peak * e
    profile = spec.profile_at(u, v)  # a hot spot and vignetting, as in the static plan
    if profile is not None:
        light = light * profile
    weight = np.where(lit, light, 0.0).astype(np.float32)
    lo8 = lo.astype(np.int8)
    alpha = np.where(lit, alpha, 0.0).astype(np.float32)
    coef = {L: c[0] for L, c in blend_coefficients(weight[None, :], lo8[None, :], alpha[None, :], len(plan.sigmas), three=False).items()}
    hs = OccluderSamples(mapx, mapy, weight, lo8, alpha, coef)
    dyn.samples[slot] = hs
    return hs


# ---------------------------------------------------------------- culling


def cone_candidates(plan: Plan, dev: Pinhole, spheres) -> np.ndarray:
    """Positions into ``plan.lit`` whose line of sight to ``dev`` may cross one of ``spheres``.

    A tile is kept when the cone of directions through it meets the cone
    that a sphere subtends from the projector's centre.

    Parameters
    ----------
    spheres : sequence of (centre (3,), radius)

    Returns
    -------
    (k,) int64 positions into ``plan.lit``.
    """
    ntx, nty, origin, T = plan.tiles
    marked = np.zeros((nty, ntx), bool)
    c0 = dev.center
    for (center, radius), bb in zip(spheres, projected_bboxes(dev, spheres)):
        q = np.asarray(center, np.float64) - c0
        D = math.sqrt(float(q @ q))
        if D <= radius * 1.001 or bb is None:
            return plan.order.astype(np.int64)
        u0, v0, u1, v1 = bb
        tx0 = min(max(int((u0 - origin) // T) - 1, 0), ntx - 1)
        tx1 = min(max(int((u1 - origin) // T) + 1, 0), ntx - 1)
        ty0 = min(max(int((v0 - origin) // T) - 1, 0), nty - 1)
        ty1 = min(max(int((v1 - origin) // T) + 1, 0), nty - 1)
        sub = plan.tile_dirs[ty0 : ty1 + 1, tx0 : tx1 + 1]
        limit = math.cos(min(math.pi, math.asin(min(1.0, radius / D)) + plan.tile_ang))
        near = (sub @ (q / D)) >= limit
        # Border tiles also hold the points clipped into them from outside the grid.
        if tx0 == 0:
            near[:, 0] = True
        if ty0 == 0:
            near[0, :] = True
        if tx1 == ntx - 1:
            near[:, -1] = True
        if ty1 == nty - 1:
            near[-1, :] = True
        marked[ty0 : ty1 + 1, tx0 : tx1 + 1] |= near
    tiles = np.flatnonzero(marked)
    first = plan.starts[tiles]
    counts = plan.starts[tiles + 1] - first
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offsets = np.repeat(first - (np.cumsum(counts) - counts), counts) + np.arange(total)
    return plan.order[offsets].astype(np.int64)


def pixel_box(bb, W: int, H: int) -> tuple[int, int, int, int]:
    """Integer pixel range (x0, y0, x1, y1), clipped to the image, covering a float box."""
    x0 = int(np.clip(math.floor(bb[0]), 0, W))
    y0 = int(np.clip(math.floor(bb[1]), 0, H))
    x1 = int(np.clip(math.ceil(bb[2]) + 1, 0, W))
    y1 = int(np.clip(math.ceil(bb[3]) + 1, 0, H))
    return x0, y0, max(x0, x1), max(y0, y1)


def in_boxes(x: np.ndarray, y: np.ndarray, boxes) -> np.ndarray:
    """Whether points (pixel coordinates) fall in any of ``boxes`` (None: a box covering everything).

    ``x``, ``y``: arrays of one shape; returns a bool array of that shape.
    """
    out = np.zeros(np.shape(x), bool)
    for bb in boxes:
        if bb is None:
            return np.ones(np.shape(x), bool)
        out |= (x >= bb[0] - 1) & (x <= bb[2] + 1) & (y >= bb[1] - 1) & (y <= bb[3] + 1)
    return out


_CUBE = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


def projected_bboxes(device: Pinhole, spheres) -> list:
    """:func:`projected_bbox` of many spheres at once (a list, one box or None per sphere)."""
    centers = np.array([c for c, _ in spheres], np.float64)
    radii = np.array([r for _, r in spheres], np.float64)
    corners = centers[:, None, :] + radii[:, None, None] * _CUBE  # (S, 8, 3)
    pix, z = device.project(corners)
    lo = pix.min(axis=1)
    hi = pix.max(axis=1)
    behind = np.any(z <= 1.0, axis=1)
    return [None if behind[k] else (float(lo[k, 0]), float(lo[k, 1]), float(hi[k, 0]), float(hi[k, 1])) for k in range(len(spheres))]


def projected_bbox(device: Pinhole, center: np.ndarray, radius: float):
    """Pixel box (u0, v0, u1, v1) holding a sphere's image, or None if the sphere reaches behind the device."""
    corners = center + radius * _CUBE
    pix, z = device.project(corners)
    if np.any(z <= 1.0):
        return None
    u0, v0 = pix.min(axis=0)
    u1, v1 = pix.max(axis=0)
    return (float(u0), float(v0), float(u1), float(v1))
