"""The touch study of `shadowless bench bust`: where a person touches, how, and the shadow a viewer sees.

:mod:`bench.bust` states the measure (its docstring, written before any figure was measured);
this module carries it out: the contact points (:func:`touch_points`, spread over the surface a
hand can reach), the participant's natural pose (:func:`shoulder_for`, then
:meth:`sim.touch.TouchingHand.reaching`), the shadow region (:func:`shadow_region`), one row of
the issue's table per touch (:func:`touch_row`), the same touches on the table
(:func:`planar_rows`), and the statistics (:func:`summarize`).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import replace

import numpy as np
from scipy import ndimage

from coordinator.coverage import CoverageModel
from coordinator.coverage_gl import vertex_normals
from sim.geometry import Pinhole, intrinsics, look_at
from sim.precompute import MESH
from sim.room import Room
from sim.scene import CameraSpec
from sim.touch import TouchingHand, inside

#: named contacts: (name, ray origin, ray direction) cast onto the bust (it faces +y, stands on z = 0)
NAMED = (
    ("head", (0.0, 30.0, 1000.0), (0.0, 0.0, -1.0)),
    ("chest", (0.0, 1000.0, 200.0), (0.0, -1.0, 0.0)),
    ("back_of_head", (0.0, -1000.0, 430.0), (0.0, 1.0, 0.0)),
)
POSES = ("reach", "normal", "above")
#: the participant's shoulder: this far from the bust's axis, this high above the table top (a
#: shoulder 1.4 m above the floor with the bust on a 0.75 m table)
SHOULDER_DISTANCE_MM = 600.0
SHOULDER_Z_MM = 650.0
#: the viewer looks at the contact along the normal from this far
CAMERA_DISTANCE_MM = 450.0
#: a shadow region is one that reaches this close to the contact (the fingertip is 8.5 mm round)
SEED_MM = 20.0
#: the shadow is where the light drops by more than this (primary), or this (secondary)
PRIMARY_DROP = 0.5
SECONDARY_DROP = 0.3
NEAR_CONTACT_MM = 30.0
#: four table points for the planar reference, the person standing at the table's front (-y) edge
PLANAR_POINTS = ((-300.0, 150.0), (300.0, 150.0), (-300.0, -150.0), (300.0, -150.0))


def log(text: str) -> None:
    print(f"bench bust: {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------- geometry helpers
def pixel_areas(points: np.ndarray, kind: np.ndarray, *, jump: float = 4.0) -> np.ndarray:
    """mm^2 of surface each camera pixel sees, from the surface points of neighbouring pixels.

    ``|dP/dx x dP/dy|`` with central differences where both neighbours see the same kind of
    surface without a depth jump (a step longer than ``jump`` times the median step), one-sided
    where only one does; pixels with no usable neighbour along an axis get the median area.

    Parameters
    ----------
    points : (H, W, 3) float world mm, NaN where nothing
    kind : (H, W) uint8, 0 where nothing

    Returns
    -------
    (H, W) float64, 0 where nothing
    """
    P = np.asarray(points, np.float64)
    valid = (kind > 0) & np.all(np.isfinite(P), axis=-1)
    steps = []
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(P, axis=axis), axis=-1)
        both = valid[1:] & valid[:-1] if axis == 0 else valid[:, 1:] & valid[:, :-1]
        same = (kind[1:] == kind[:-1]) if axis == 0 else (kind[:, 1:] == kind[:, :-1])
        steps.append((d, both & same))
    typical = np.median(np.concatenate([d[ok] for d, ok in steps])) if any(ok.any() for _, ok in steps) else 1.0
    grads = []
    for axis, (d, ok) in enumerate(steps):
        ok = ok & (d < jump * typical)
        diff = np.diff(np.nan_to_num(P), axis=axis)
        fwd = np.zeros_like(P)
        bwd = np.zeros_like(P)
        has_f = np.zeros(valid.shape, bool)
        has_b = np.zeros(valid.shape, bool)
        if axis == 0:
            fwd[:-1], has_f[:-1] = diff, ok
            bwd[1:], has_b[1:] = diff, ok
        else:
            fwd[:, :-1], has_f[:, :-1] = diff, ok
            bwd[:, 1:], has_b[:, 1:] = diff, ok
        g = np.where((has_f & has_b)[..., None], (fwd + bwd) / 2, np.where(has_f[..., None], fwd, bwd))
        grads.append((g, has_f | has_b))
    (gy, oky), (gx, okx) = grads
    area = np.linalg.norm(np.cross(gx, gy), axis=-1)
    good = valid & okx & oky
    fill = float(np.median(area[good])) if good.any() else 0.0
    return np.where(valid, np.where(good, area, fill), 0.0)


def ray_mesh(origin, direction, triangles: np.ndarray) -> tuple[int, np.ndarray]:
    """Nearest hit of one ray with triangles (F, 3, 3) (Möller-Trumbore): (face, barycentric (3,)); face -1 on a miss."""
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - v0
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
    if not hit.any():
        return -1, np.zeros(3)
    k = int(np.flatnonzero(hit)[np.argmin(t[hit])])
    return k, np.array([1 - u[k] - v[k], u[k], v[k]])


def surface_at(mesh, normals: np.ndarray, face: int, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point (3,) and interpolated unit normal (3,) of barycentric ``bary`` on ``face``."""
    f = mesh.faces[face]
    X = bary @ mesh.vertices[f].astype(np.float64)
    n = bary @ normals[f].astype(np.float64)
    return X, n / np.linalg.norm(n)


def look_camera(name: str, eye, target, *, px: int, half_mm: float) -> CameraSpec:
    """A square camera at ``eye`` looking at ``target``, ``half_mm`` either side at the target."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    view = target - eye
    up = (0.0, 0.0, 1.0) if abs(view[2]) < 0.9 * np.linalg.norm(view) else (0.0, 1.0, 0.0)
    R, t = look_at(eye, target, up=up)
    f = (px / 2) * float(np.linalg.norm(view)) / half_mm
    dev = Pinhole(intrinsics((px, px), focal=f), R, t, (px, px))
    return CameraSpec(name, dev, dev, 1.0)


# ---------------------------------------------------------------------- where and how a person touches
def shoulder_for(point, normal, axis_xy=(0.0, 0.0), *, distance: float = SHOULDER_DISTANCE_MM,
                 z: float = SHOULDER_Z_MM) -> np.ndarray:
    """(3,) world mm: the shoulder of a participant standing on the contact's side of the bust.

    The side is the azimuth of the normal's horizontal part where the surface faces sideways
    (horizontal part > 0.3), else the azimuth of the point about the axis (the top of the head),
    else the front (+y).
    """
    X = np.asarray(point, np.float64)
    n = np.asarray(normal, np.float64)
    side = n[:2]
    if np.linalg.norm(side) <= 0.3:
        side = X[:2] - np.asarray(axis_xy, np.float64)
        if np.linalg.norm(side) < 20.0:
            side = np.array([0.0, 1.0])
    side = side / np.linalg.norm(side)
    xy = np.asarray(axis_xy, np.float64) + distance * side
    return np.array([xy[0], xy[1], z])


def finger(pose: str, n: np.ndarray) -> np.ndarray | None:
    """The index finger's direction for the unnatural poses: ``normal`` along the inward normal;
    ``above`` halfway between it and straight down."""
    if pose == "normal":
        return None
    g = -n - np.array([0.0, 0.0, 1.0])
    return g / np.linalg.norm(g) if np.linalg.norm(g) > 1e-6 else -n


def pose_hand(pose: str, X: np.ndarray, n: np.ndarray, shoulder: np.ndarray) -> TouchingHand:
    """The touching hand of ``pose`` (one of :data:`POSES`) at contact ``X`` with outward normal ``n``."""
    if pose == "reach":
        return TouchingHand.reaching(X, n, shoulder)
    if pose in ("normal", "above"):
        return TouchingHand(X, n, direction=finger(pose, n))
    raise ValueError(f"unknown pose {pose!r}; one of {POSES}")


def hand_fits(hand: TouchingHand, vertices: np.ndarray, X: np.ndarray, eye: np.ndarray) -> bool:
    """The hand clear of the object (no vertex farther than 20 mm from the contact inside it), of
    the table (5 mm), and of the viewer's eye."""
    far = np.linalg.norm(vertices - X, axis=1) > 20.0
    return hand.lowest_z() >= 5.0 and not inside(hand, vertices[far]).any() and not inside(hand, eye[None])[0]


def region(X: np.ndarray, n: np.ndarray) -> str:
    """Which part of the procedural bust (:func:`sim.mesh.bust`, facing +y) the point is on."""
    z = float(X[2])
    if z >= 390.0:
        if n[2] > 0.7:
            return "top_of_head"
        return "face" if n[1] > 0.5 else "back_of_head" if n[1] < -0.5 else "side_of_head"
    if z >= 320.0:
        return "neck"
    if z >= 240.0:
        return "shoulders"
    return "chest" if n[1] > 0.5 else "back" if n[1] < -0.5 else "side"


def touch_points(mesh, *, sampled: int, seed: int, poses: tuple[str, ...] = ("reach",), pool: int = 3000,
                 distance: float = SHOULDER_DISTANCE_MM, z: float = SHOULDER_Z_MM) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The named contacts and ``sampled`` more: farthest-point samples (each the candidate farthest from
    every contact chosen so far) of ``pool`` area-weighted candidates above the plinth and not under an
    overhang, where every pose's hand fits (:func:`hand_fits`). Returns (name, point (3,), unit normal (3,))."""
    normals = vertex_normals(mesh.vertices, mesh.faces)
    tri = mesh.triangles()
    verts = mesh.vertices.astype(np.float64)
    axis = (mesh.bounds[0][:2] + mesh.bounds[1][:2]) / 2

    def fits(X, n):
        eye = X + CAMERA_DISTANCE_MM * n
        sh = shoulder_for(X, n, axis, distance=distance, z=z)
        return all(hand_fits(pose_hand(p, X, n, sh), verts, X, eye) for p in poses)

    out = []
    for name, o, d in NAMED:
        face, bary = ray_mesh(o, d, tri)
        if face < 0:
            raise RuntimeError(f"the ray for {name} misses the mesh")
        out.append((name, *surface_at(mesh, normals, face, bary)))
    rng = np.random.default_rng(seed)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    faces = rng.choice(len(area), size=pool, p=area / area.sum())
    ab = rng.random((pool, 2))
    ab = np.where(ab.sum(axis=1, keepdims=True) > 1, 1 - ab, ab)
    cand = [surface_at(mesh, normals, int(f), np.array([1 - a - b, a, b])) for f, (a, b) in zip(faces, ab)]
    cand = [(X, n) for X, n in cand if X[2] >= 60.0 and n[2] >= -0.3]
    P = np.array([X for X, _ in cand]).reshape(-1, 3)
    gap = np.full(len(cand), np.inf)
    for _, X, _ in out:
        gap = np.minimum(gap, np.linalg.norm(P - X, axis=1))
    while len(out) < len(NAMED) + sampled and np.isfinite(gap).any() and len(cand):
        k = int(np.argmax(gap))
        X, n = cand[k]
        gap[k] = -np.inf                       # tried: never again
        if not fits(X, n):
            continue
        out.append((f"s{len(out) - len(NAMED):02d}", X, n))
        gap = np.minimum(gap, np.linalg.norm(P - X, axis=1))
    return out


# ---------------------------------------------------------------------- the shadow a viewer sees
def shadow_region(drop: np.ndarray, surface: np.ndarray, visible: np.ndarray, dist: np.ndarray, area: np.ndarray,
                  threshold: float, *, seed_mm: float = SEED_MM) -> dict:
    """The shadow next to the contact in the viewer's image (the measure of :mod:`bench.bust`).

    The 8-connected components of ``surface & (drop > threshold)`` holding a pixel within ``seed_mm``
    of the contact; their area where the viewer sees the surface, and where the hand hides it.

    Parameters
    ----------
    drop : (H, W) float, light drop in [0, 1] at each pixel's surface point
    surface : (H, W) bool, the pixel's ray meets the object (hand or not)
    visible : (H, W) bool, the viewer sees that surface (not the hand)
    dist : (H, W) float, mm from the pixel's surface point to the contact
    area : (H, W) float, mm^2 of surface each pixel sees

    Returns
    -------
    dict: ``area_mm2`` (visible), ``hidden_mm2``, ``pixels``, ``clipped`` (the region meets the
    image's border: a lower bound)
    """
    dark = surface & (drop > threshold)
    labels, _ = ndimage.label(dark, structure=np.ones((3, 3), bool))
    seeds = np.unique(labels[dark & (dist <= seed_mm)])
    inside_region = np.isin(labels, seeds[seeds > 0])
    border = np.concatenate([inside_region[0], inside_region[-1], inside_region[:, 0], inside_region[:, -1]])
    return {"area_mm2": round(float(area[inside_region & visible].sum()), 1),
            "hidden_mm2": round(float(area[inside_region & ~visible].sum()), 1),
            "pixels": int(inside_region.sum()), "clipped": bool(border.any())}


def _subset_shadow(room: Room, slots: list[str], surface, visible, dist, area) -> dict:
    room.set_active(slots)
    drop = room.truth.light_drop()
    main = shadow_region(drop, surface, visible, dist, area, PRIMARY_DROP)
    second = shadow_region(drop, surface, visible, dist, area, SECONDARY_DROP)
    near = surface & (dist <= SEED_MM)
    return {**main, "area_drop_over_30_mm2": second["area_mm2"],
            "max_drop": round(float(drop[visible].max()), 4) if visible.any() else None,
            "max_drop_near_contact": round(float(drop[near].max()), 4) if near.any() else None}


def incidence_deg(X: np.ndarray, n: np.ndarray, array_centre: np.ndarray) -> float:
    """Degrees between the outward normal and the direction from the point to the array's centre."""
    d = array_centre - X
    return math.degrees(math.acos(float(np.clip(d @ n / np.linalg.norm(d), -1.0, 1.0))))


def light_spread_deg(X: np.ndarray, share: np.ndarray, centres: np.ndarray) -> float:
    """How wide the cone of light reaching ``X`` is: the share-weighted RMS angle (degrees) between the
    directions to the projectors (centres (N, 3) mm, shares (N,) summing to 1 or all 0) and their
    share-weighted mean direction; 0 where one projector or none reaches. An explanatory figure: a
    hand blocks a cone of directions, so the narrower the light's cone, the more of it one hand takes."""
    w = np.asarray(share, np.float64)
    if w.sum() <= 0:
        return 0.0
    D = np.asarray(centres, np.float64) - X
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    mean = (w[:, None] * D).sum(axis=0)
    mean /= np.linalg.norm(mean)
    ang = np.arccos(np.clip(D @ mean, -1.0, 1.0))
    return math.degrees(math.sqrt(float((w * ang ** 2).sum() / w.sum())))


def touch_row(scene, subsets: dict[str, list[str]], name: str, X: np.ndarray, n: np.ndarray, *, poses: tuple[str, ...],
              px: int, half_mm: float, shoulder: np.ndarray, array_centre: np.ndarray) -> dict:
    """One touch seen along the normal: per pose, the shadow for each subset (:func:`_subset_shadow`)."""
    cam = look_camera(f"touch-{name}", X + CAMERA_DISTANCE_MM * n, X, px=px, half_mm=half_mm)
    room = Room(replace(scene, cameras=(cam,)), noise=False)
    surf = room.truth.surface()
    surface = surf.kind > 0 if scene.mesh is None else surf.kind == MESH
    area = pixel_areas(surf.points, surf.kind)
    dist = np.linalg.norm(surf.points.astype(np.float64) - X, axis=-1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    row = {"name": name, "point_mm": [round(float(v), 1) for v in X], "surface_normal": [round(float(v), 3) for v in n],
           "incidence_deg": round(incidence_deg(X, n, array_centre), 1),
           "shoulder_mm": [round(float(v), 1) for v in shoulder], "view_mm2": round(float(area[surface].sum()), 1)}
    near = surface & (dist <= SEED_MM)
    for pose in poses:
        hand = pose_hand(pose, X, n, shoulder)
        room.set_occluders([hand])
        visible = surface & ~room.truth.occluder_mask()
        g = hand.direction
        out = {"finger_into_deg": round(math.degrees(math.asin(float(np.clip(-(g @ n), -1, 1)))), 1),
               "hidden_near_contact_pct": round(100 * float(area[near & ~visible].sum() / max(area[near].sum(), 1e-9)), 1)}
        for label, slots in subsets.items():
            out[label] = _subset_shadow(room, slots, surface, visible, dist, area)
        row[pose] = out
    return row


def bust_rows(scene, model: CoverageModel, single: CoverageModel, points, subsets: dict[str, list[str]], *,
              poses: tuple[str, ...], px: int, half_mm: float, distance: float, z: float) -> list[dict]:
    """The issue's table: per touch its region, coverage and, per pose, the shadows of P1 and P25."""
    lo, hi = scene.mesh.bounds
    axis = (lo[:2] + hi[:2]) / 2
    centres = np.array([scene.projector(s).native.center for s in subsets["P25"]])
    centre = centres.mean(axis=0)
    rows = []
    for i, (name, X, n) in enumerate(points):
        t0 = time.perf_counter()
        pc = model.at_points(X[None], n[None])
        row = touch_row(scene, subsets, name, X, n, poses=poses, px=px, half_mm=half_mm,
                        shoulder=shoulder_for(X, n, axis, distance=distance, z=z), array_centre=centre)
        row = {"name": name, "region": region(X, n),
               "coverage": {"count": int(pc.count[0]), "effective": round(float(pc.effective[0]), 2),
                            "max_share_pct": round(100 * float(pc.share[:, 0].max()), 1) if pc.count[0] else None,
                            "light_spread_deg": round(light_spread_deg(X, pc.share[:, 0], centres), 1)},
               "p1_reaches_contact": bool(single.at_points(X[None], n[None]).count[0] > 0),
               **{k: v for k, v in row.items() if k != "name"}}
        row["seconds"] = round(time.perf_counter() - t0, 2)
        log(f"touch {i + 1}/{len(points)} {name} ({row['region']}): count {row['coverage']['count']}, P25 shadow "
             + ", ".join(f"{pose} {row[pose]['P25']['area_mm2']:.0f} mm^2" for pose in poses))
        rows.append(row)
    return rows


def planar_rows(scene, subsets: dict[str, list[str]], *, poses: tuple[str, ...], px: int, half_mm: float,
                distance: float, z: float) -> list[dict]:
    """The same touches on the table (``scene`` without a mesh): the person at its front edge, the
    shoulder ``distance`` towards -y from the contact."""
    centre = np.mean([scene.projector(s).native.center for s in subsets["P25"]], axis=0)
    n = np.array([0.0, 0.0, 1.0])
    rows = []
    for x, y in PLANAR_POINTS:
        X = np.array([x, y, 0.0])
        rows.append(touch_row(scene, subsets, f"table({x:+.0f},{y:+.0f})", X, n, poses=poses, px=px, half_mm=half_mm,
                              shoulder=np.array([x, y - distance, z]), array_centre=centre))
    return rows


# ---------------------------------------------------------------------- statistics
def spearman(x, y) -> dict:
    """Spearman's rho (scipy.stats.spearmanr) with its two-sided p and n; None where undefined."""
    x, y = list(x), list(y)
    if len(x) < 3 or len(set(x)) < 2 or len(set(y)) < 2:
        return {"rho": None, "p": None, "n": len(x)}
    from scipy import stats     # here: scipy.stats costs 0.6 CPU-s to import, and only this figure needs it
    res = stats.spearmanr(x, y)
    return {"rho": round(float(res.statistic), 3), "p": float(res.pvalue), "n": len(x)}


def _groups(rows: list[dict], key, pose: str) -> dict:
    out: dict[str, list[float]] = {}
    for r in rows:
        out.setdefault(key(r), []).append(r[pose]["P25"]["area_mm2"])
    return {k: {"n": len(v), "median_mm2": round(float(np.median(v)), 1), "mean_mm2": round(float(np.mean(v)), 1)}
            for k, v in sorted(out.items())}


def summarize(rows: list[dict], planar: list[dict], pose: str) -> dict:
    """The pre-stated statistic (coverage count vs the P25 shadow area), two secondary measures (the
    region at drop > 0.3; the region's area with the part the hand hides from the viewer), and the
    figures that explain it: incidence vs area and vs count, areas by count and by region, the
    planar reference."""
    count = [r["coverage"]["count"] for r in rows]
    inc = [r["incidence_deg"] for r in rows]
    area = [r[pose]["P25"]["area_mm2"] for r in rows]
    planar_max = max((r[pose]["P25"]["area_mm2"] for r in planar), default=None)

    def bin_of(r):
        c = r["coverage"]["count"]
        return "count 00-08" if c <= 8 else "count 09-16" if c <= 16 else "count 17-25"

    return {
        "primary": {"measure": "count at the contact vs P25 shadow region (drop > 0.5, visible) mm^2",
                    **spearman(count, area)},
        "secondary_drop_over_30": spearman(count, [r[pose]["P25"]["area_drop_over_30_mm2"] for r in rows]),
        "secondary_hidden_included": spearman(count, [r[pose]["P25"]["area_mm2"] + r[pose]["P25"]["hidden_mm2"] for r in rows]),
        "explain": {
            "incidence_vs_area": spearman(inc, area),
            "incidence_vs_count": spearman(inc, count),
            "effective_vs_area": spearman([r["coverage"]["effective"] for r in rows], area),
            "light_spread_vs_area": spearman([r["coverage"]["light_spread_deg"] for r in rows], area),
            "light_spread_vs_count": spearman([r["coverage"]["light_spread_deg"] for r in rows], count),
            "height_vs_area": spearman([r["point_mm"][2] for r in rows], area),
            "p1_lights_contact": {"n": sum(r["p1_reaches_contact"] for r in rows), "of": len(rows)},
            "hidden_near_contact_vs_area": spearman([r[pose]["hidden_near_contact_pct"] for r in rows], area),
            "by_count": _groups(rows, bin_of, pose),
            "by_region": _groups(rows, lambda r: r["region"], pose),
        },
        "planar_p25_mm2": [r[pose]["P25"]["area_mm2"] for r in planar],
        "bust_larger_than_planar": (None if planar_max is None else
                                    {"n": sum(a > planar_max for a in area), "of": len(area), "planar_max_mm2": planar_max}),
    }
